"""The legend drawn inside each frame of the overlay video (``pcreg view RUN --overlay OUT.mp4``).

The video is the frames' own size (runs are compared frame by frame), so the legend is drawn over the frame,
in a box at its bottom-left corner, inside the blue frame of a key frame: the frame's name (and whether it is a
key frame), a row of its figures (the predicted error of a frame pcreg labelled), then each class that frame's labels
show (a swatch of the class's colour of the run's class table and its name, then its figures: its predicted IoU, in
the table's order) and, when the frame has unsure labels, what the hatching means. The rows'
height follows the frame's (:func:`row_height`): a 320x240 frame's text is 9 px high. A frame where the classes
would not fit (the box over half its height, or one entry wider than the frame) loses the classes' figures first,
then the row of figures, then the classes: its name alone (:attr:`Legend.complete` False).

Drawn with OpenCV (Hershey font: ASCII): a class's name as :func:`drawn_names` gives it (accents folded, a name of no
ASCII form as ``class ID``); another character of a title or a row is drawn as ``?``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .classes import ClassTable

__all__ = ["Legend", "row_height", "draw_legend", "legend_figures", "drawn_names"]

Box = tuple[int, int, int, int]  # x0, y0, x1, y1: the pixels x0 <= x < x1, y0 <= y < y1

#: How much of the frame stays under the legend's box (the rest is black), so its white text reads on any frame.
SHADE = 0.3
TEXT = (240, 240, 240)
#: The swatch of the hatching: a mid grey, hatched as :func:`pcreg.review.overlay` hatches.
HATCH_GREY = (160, 160, 160)


@dataclass(frozen=True)
class Legend:
    """Where a frame's legend was drawn: ``box`` the box it covers (the frame unchanged outside it);
    ``swatches`` each class listed, ``(class id, box)``, in the order listed (its colour fills the box);
    ``hatch`` the hatching's swatch (None: not listed); ``complete`` False when the frame was too small
    for the classes and only its name is drawn; ``figures`` whether the row of the frame's figures is drawn,
    ``scored`` whether each class's score follows its name."""

    box: Box
    swatches: tuple[tuple[int, Box], ...]
    hatch: Box | None
    complete: bool
    figures: bool = False
    scored: bool = False


def row_height(shape: tuple[int, ...]) -> int:
    """The height in pixels of a legend row in a frame of ``shape`` (H, W, ...): 1/24 of the frame's height,
    13 at least (a 9 px text), 36 at most."""
    return int(np.clip(shape[0] // 24, 13, 36))


def _ascii(text: str) -> str:
    return "".join(ch if " " <= ch <= "~" else "?" for ch in text)


def drawn_names(classes) -> dict[int, str]:
    """Each class's name as the legend draws it (Hershey's ASCII): accents folded (``nébo`` as ``nebo``), and a
    name with characters of no ASCII form (``道路``) as ``class ID``, where each was drawn as ``?`` and two
    classes' names could read alike; names that still read alike gain their ids."""
    import unicodedata

    letters = {"ß": "ss", "æ": "ae", "Æ": "AE", "ø": "o", "Ø": "O", "ł": "l", "Ł": "L", "œ": "oe", "Œ": "OE", "đ": "d",
               "Đ": "D", "þ": "th", "Þ": "Th", "ı": "i"}

    def one(ch: str) -> str:
        if " " <= ch <= "~":
            return ch
        if unicodedata.combining(ch):  # a mark on the letter before it (a decomposed accent): folded away, as a composed one's
            return ""
        base = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode("ascii")
        return letters.get(ch) or (base if base.strip() else "?")

    def folded(name: str) -> str:
        plain = "".join(one(ch) for ch in name)
        return "" if plain.count("?") > sum(ch.isalnum() for ch in plain) else plain

    drawn = {c.id: folded(c.name) or f"class {c.id}" for c in classes}
    twice = {n for n in drawn.values() if list(drawn.values()).count(n) > 1}
    return {i: f"{n} ({i})" if n in twice else n for i, n in drawn.items()}


def _layout(shape: tuple[int, ...], title: str, items: list[str], *, inset: int,
            figures: str | None = None) -> tuple[str, list, Box, bool]:
    """Where each of ``title``, ``figures`` (a row under the title; None: none) and ``items`` goes: ``(title,
    places, box, complete)``, the title cut to the frame's width, ``places`` one ``(x, y)`` of each entry's
    top-left (the title's first, then the figures' row when given), the items flowed into rows; without room for
    the figures' row (wider than the frame) or for the items, the title's place alone and ``complete`` False."""
    import cv2

    h, w = shape[:2]
    lh = row_height(shape)
    pad, swatch = max(2, lh // 5), round(0.7 * lh)
    scale = cv2.getFontScaleFromHeight(cv2.FONT_HERSHEY_SIMPLEX, swatch, 1)
    inner = w - 2 * inset - 2 * pad

    def width(text: str) -> int:
        return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]

    while len(title) > 3 and width(title) > inner:  # a long name cut at its start: its end tells frames apart
        title = ".." + title[3:]
    places, x, y, widest = [(0, 0)], 0, 0, min(width(title), inner)
    fits = figures is None or width(figures) <= inner
    if figures is not None:
        y += lh
        places.append((0, y))
        widest = max(widest, width(figures))
    for text in items:
        item = swatch + pad + width(text)
        if x and x + item > inner:
            x = 0
        if x == 0:
            y += lh
        places.append((x, y))
        x += item + lh // 2
        widest = max(widest, x - lh // 2)
    complete = fits and widest <= inner and (y + lh + 2 * pad) <= h // 2
    if not complete:
        places, y, widest = places[:1], 0, min(width(title), inner)
    x0, y1 = inset, h - inset
    box = (x0, max(0, y1 - y - lh - 2 * pad), min(w, x0 + widest + 2 * pad), y1)
    return title, [(box[0] + pad + px, box[1] + pad + py) for px, py in places], box, complete


def draw_legend(image: np.ndarray, labels: np.ndarray, *, title: str, table: ClassTable,
                hatched_below: float | None = None, inset: int = 0, figures: str | None = None,
                scores: dict[int, str] | None = None, scores_key: str = "") -> tuple[np.ndarray, Legend]:
    """``image`` (H, W, 3) uint8 RGB, a frame with ``labels`` (H, W) drawn over it, with its legend drawn in:
    ``title`` (the frame's name), ``figures`` (a row of the frame's figures under it; None: none), the known
    classes of ``table`` that ``labels`` holds, each followed by its text in ``scores`` (class id -> text; ``scores_key``
    is added to the figures' row to say what they are), and, when some label is hatched as unsure, what the hatching
    means: ``hatched_below``, the confidence below which a label is hatched (None: no label is). ``inset``: pixels kept
    clear at the frame's edge (a key frame's border). What does not fit goes first: the classes' scores, then the
    figures' row, then the classes (the name alone). Returns a new image and where the legend went."""
    import cv2

    present = np.bincount(labels.ravel(), minlength=256) > 0
    shown = [c for c in table.known if present[c.id]]
    hatching = [] if hatched_below is None else [f"hatched: confidence < {hatched_below:.0%}"]
    drawn = drawn_names(table.known)
    names = [drawn[c.id] for c in shown]
    scored = [_ascii(f"{drawn[c.id]} {scores[c.id]}" if c.id in scores else drawn[c.id]) for c in shown] if scores else None
    tries: list[tuple[str | None, list[str] | None]] = (
        [(figures if not scores_key else f"{figures}; {scores_key}", scored)] if figures and scored else [])
    tries += [(figures, None)] if figures else []
    tries += [(None, None)]
    for row, with_scores in tries:
        items = (with_scores or names) + hatching
        title_cut, places, (x0, y0, x1, y1), complete = _layout(image.shape, _ascii(title), items, inset=inset,
                                                                figures=None if row is None else _ascii(row))
        if complete:
            break
    lh = row_height(image.shape)
    swatch = round(0.7 * lh)
    scale = cv2.getFontScaleFromHeight(cv2.FONT_HERSHEY_SIMPLEX, swatch, 1)
    out = image.copy()
    out[y0:y1, x0:x1] = (out[y0:y1, x0:x1] * SHADE + 0.5).astype(np.uint8)
    texts = [title_cut] + ([] if row is None else [_ascii(row)]) + items
    first = len(texts) - len(items)  # the first entry with a swatch
    swatches, hatch = [], None
    for k, (x, y) in enumerate(places):
        if k >= first:
            box = (x, y + (lh - swatch) // 2, x + swatch, y + (lh - swatch) // 2 + swatch)
            if k - first < len(shown):
                out[box[1]:box[3], box[0]:box[2]] = shown[k - first].colour
                swatches.append((shown[k - first].id, box))
            else:
                yy, xx = np.mgrid[0:swatch, 0:swatch]
                out[box[1]:box[3], box[0]:box[2]] = np.where(((xx + yy) % 8 < 3)[..., None],
                                                             (np.asarray(HATCH_GREY) * 0.3).astype(np.uint8), HATCH_GREY)
                hatch = box
            x += swatch + max(2, lh // 5)
        baseline = y + (lh + swatch) // 2
        cv2.putText(out, texts[k], (x, baseline), cv2.FONT_HERSHEY_SIMPLEX, scale, TEXT, 1, cv2.LINE_AA)
    out[:y0], out[y1:], out[:, :x0], out[:, x1:] = image[:y0], image[y1:], image[:, :x0], image[:, x1:]
    return out, Legend((x0, y0, x1, y1), tuple(swatches), hatch, complete, complete and row is not None,
                       complete and with_scores is not None)


def legend_figures(error: float | None, iou: dict[int, float] | None, truth_error: float | None = None,
                   truth_iou: dict[int, float] | None = None) -> dict:
    """:func:`draw_legend`'s ``figures``, ``scores`` and ``scores_key`` of a frame whose predicted ``error`` (%) and each
    class's predicted ``iou`` (class id -> IoU; None: the step has none) are given, and, scored against the truth,
    its error (``truth_error``, %) and each class's IoU (``truth_iou``; None or empty: none) in brackets after them.
    None of them where ``error`` is None (a key frame: nothing predicted there)."""
    if error is None:
        return {}
    figures = f"predicted error {error:.1f}%" + ("" if truth_error is None else f" (truth {truth_error:.1f}%)")
    if not iou:
        return {"figures": figures}
    scores = {k: f"{v:.2f}" + ("" if truth_iou is None or k not in truth_iou else f" ({truth_iou[k]:.2f})")
              for k, v in iou.items()}
    key = "after each class its " + ("IoU, predicted (truth)" if truth_iou else "predicted IoU")
    return {"figures": figures, "scores": scores, "scores_key": key}
