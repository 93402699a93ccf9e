"""Black bars at a frame's edges (a letterboxed or pillarboxed video): they keep the key frame's labels.

A film shown in a wider or narrower frame than its own is padded with black rows above and below (letterbox) or
black columns left and right (pillarbox). The bars are not part of the scene: they stay where they are while the
picture between them moves. Carried along the picture's motion the key frame's labels of the bars (most often
unknown) left them, and naive Bayes labelled the black there as the class of the darkest colours the key frame
showed (building, on a letterboxed CamVid clip: every bar pixel of every frame after the key frame, at a high
confidence), and the frame's predicted error was taken over the bars too, below the picture's own.

So the key frame's bars, the whole rows and columns at two opposite edges whose pixels are all no brighter than
:data:`BLACK`, as wide at one edge as at the other (within 2 px or a tenth: a night scene's dark sky is black at one
edge, not as a centred picture's bars), are found once (:meth:`Bars.of`); a frame whose bars' pixels are still mostly black
(:meth:`Bars.held`: subtitles drawn on a bar do not end it, a picture that fills the frame does) keeps the key
frame's labels there, unmoved, at confidence 1, and its predicted error and predicted IoU are those of the
picture between the bars (:meth:`Bars.kept`). The picture's own labels are what they were: on 0001TP letterboxed
by 60 rows each side, its error against the truth was within 0.6 point of the clip's unpadded on each frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["BLACK", "Bars", "kept_between"]

#: The brightest value (of 255, in every channel) a bar's pixel may have: video black, where limited-range video
#: (BT.601 and BT.709 both) codes black, which a decoder's rounding and a codec's noise keep at or below.
BLACK = 16


@dataclass(frozen=True, eq=False)
class Bars:
    """The key frame's black bars: ``edges`` the rows above and below and the columns left and right they take
    (top, bottom, left, right), ``mask`` (H, W) bool their pixels and ``labels`` (H, W) uint8 the key frame's
    labels, in the ids the step labels in."""

    edges: tuple[int, int, int, int]
    mask: np.ndarray
    labels: np.ndarray

    @classmethod
    def of(cls, rgb: np.ndarray, labels: np.ndarray) -> "Bars | None":
        """The bars of a key frame ``rgb`` (H, W, 3) uint8 labelled ``labels``; None when it has none, or when it is
        black from edge to edge (nothing between the bars)."""
        black = rgb.max(axis=2) <= BLACK
        rows, cols = black.all(axis=1), black.all(axis=0)
        top, bottom, left, right = (_leading(rows), _leading(rows[::-1]), _leading(cols), _leading(cols[::-1]))
        top, bottom, left, right = (*_paired(top, bottom), *_paired(left, right))
        (H, W) = black.shape
        if not (top or bottom or left or right) or top + bottom >= H or left + right >= W:
            return None
        mask = np.zeros((H, W), bool)
        mask[:top], mask[H - bottom:], mask[:, :left], mask[:, W - right:] = True, True, True, True
        return cls((top, bottom, left, right), mask, np.array(labels, np.uint8))

    @property
    def picture(self) -> tuple[slice, slice]:
        """The rows and columns between the bars."""
        top, bottom, left, right = self.edges
        H, W = self.mask.shape
        return slice(top, H - bottom), slice(left, W - right)

    def held(self, rgb: np.ndarray) -> bool:
        """Whether a frame ``rgb`` of the key frame's size still shows the bars: most of their pixels black."""
        return 2 * int(np.count_nonzero(rgb[self.mask].max(axis=1) <= BLACK)) > int(np.count_nonzero(self.mask))

    def kept(self, labels: np.ndarray, trusted=None):
        """``(labels, trusted)`` with the bars' pixels the key frame's labels, at confidence 1 in ``trusted`` (a
        :class:`~pcreg.pipeline.trust.Trusted`, or None), whose report is then of the picture between them."""
        if trusted is None:
            return np.where(self.mask, self.labels, labels), None
        labels, confidence = self.maps(labels, trusted.confidence)
        return labels, replace(trusted, labels=labels, confidence=confidence, picture=self.picture)

    def maps(self, labels: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``labels`` and their ``confidence`` with the bars' pixels the key frame's labels, at confidence 1."""
        return (np.where(self.mask, self.labels, labels),
                np.where(self.mask, np.float32(1.0), confidence).astype(confidence.dtype))


def kept_between(bars: "Bars | None", rgb: np.ndarray, labels: np.ndarray, confidence: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, tuple[slice, slice]]:
    """``(labels, confidence, picture)`` of a frame ``rgb`` read another way than a step reads it (between two key
    frames): with the key frame's ``bars`` kept where the frame still shows them (:meth:`Bars.maps`), and the rows
    and columns a predicted error is of."""
    if bars is None or not bars.held(rgb):
        return labels, confidence, (slice(None), slice(None))
    return (*bars.maps(labels, confidence), bars.picture)


def _paired(a: int, b: int) -> tuple[int, int]:
    """Black rows (or columns) ``a`` and ``b`` at opposite edges as bars: only where both are there, of widths within
    2 px or a tenth of each other (a picture centred in its frame, as letterboxing pads it); a dark scene's black
    at one edge, or more at one than the other, is the picture's."""
    return (a, b) if a and b and abs(a - b) <= max(2, (a + b) / 10) else (0, 0)


def _leading(flags: np.ndarray) -> int:
    """How many of ``flags`` are true from its start."""
    off = np.flatnonzero(~flags)
    return int(off[0]) if off.size else int(flags.size)
