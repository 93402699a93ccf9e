"""Label every frame of a clip from key frames anywhere in it, forwards and backwards, and say which frame
to label next.

The people who label video label a few frames anywhere in it and fill in between. Here each frame is
labelled from the key frames around it (:func:`label_clip`):

- between two key frames, from both: one :class:`~pcreg.Propagator` carries the earlier key frame's
  labels forwards, another the later one's backwards, and each frame fuses naive Bayes' log-odds with
  both trusted priors, their evidence added (``F = d + P_earlier + P_later``; each ``P`` is the step's
  trust map's :meth:`~pcreg.pipeline.trust.TrustMaps.prior_term`, already weighted per pixel by how
  well that key frame, carried along its motions, matches the frame);
- before the first key frame, backwards from it; after the last, forwards from it.

Measured on the eight shared CamVid clips with the first and the last frame as key frames
(docs/results.md, "Several key frames"): adding the two priors lowered the error of the frames in between
by 28.4% against the first key frame alone, more than averaging them (23.9%), weighting them by their
distance in frames (20.3%) or by their trust (26.6%), or taking the more trusted one (22.4%). The
classifier does not learn from the stream between two key frames (the two directions would teach it
differently); it learns on one-sided stretches as a single propagator does.

Each stretch's naive Bayes is fitted on its own key frames, one or two (unknown pixels left out;
``fit="stretch"``, :data:`KEY_FITS`), so that a stretch's labels depend on nothing outside it: adding a key
frame relabels only the stretch it splits, which ``pcreg run`` relies on to redo only that stretch
(:mod:`pcreg.pipeline.keys_run`). Fitted on all the key frames instead (``fit="all"``), the mean reduction
of plain's error over the eight shared CamVid clips (``pcreg evaluate stream --keys ... --methods
plain,pcreg``) was 57.9% against the stretch's own 55.9% with three key frames evenly spaced
(``spaced:3``; the two clips of 0006R0 lost most), and 53.6% against 54.1% with the three that an earlier rule of
:func:`suggest` picks (``suggest:3``): about a point either way, for labels that stay put where no key
frame changed. The forward pass's prior term is rounded to float16 before it is added, as ``pcreg run``
keeps it on disk between its two passes.

:func:`suggest` ranks the frames a person should label next, without any ground truth: the far end of
a stretch labelled from one side only first, then the frame whose predicted error (the mean of
1 - confidence) times its distance to the nearest labelled frame is largest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np

from ..errors import InputError
from .._moved import moved

__all__ = ["LabelledFrame", "label_clip", "suggest", "KEY_FITS"]

#: What each stretch's naive Bayes is fitted on: its own key frames (one or two), or all of them.
KEY_FITS: tuple[str, ...] = ("stretch", "all")


@dataclass(frozen=True, eq=False)
class LabelledFrame:
    """One frame's result: ``index``, ``labels`` (H, W) uint8, ``confidence`` (H, W) float32 (None for a
    key frame: its labels are given), ``predicted_error`` (%; 0 for a key frame) and ``keys``: the key
    frames it was labelled from."""

    index: int
    labels: np.ndarray
    confidence: np.ndarray | None
    predicted_error: float
    keys: tuple[int, ...]


def _pass(make: Callable, key_image, key_labels, images: Callable[[int], np.ndarray], order) -> tuple[dict, Any]:
    """One direction, by :func:`~pcreg.pipeline.engine.propagate`: ``{t: (log_odds, prior_term, labels,
    confidence, class weights, bars, cut)}`` along ``order`` from the key frame (the first two at the propagator's
    working size; ``bars`` the key frame's black bars where the frame shows them, :mod:`pcreg.pipeline.bars`, else
    None; ``cut`` whether the cut test found the frame outside the key frame's scene), and the propagator."""
    from .engine import propagate
    from .multiclass import weight_sum

    prop = make()
    prop.reset(key_image, key_labels)
    out = {}
    for t, image, labels in propagate(prop, ((t, images(t)) for t in order)):
        d, maps = prop.last.log_odds, prop.last.trust
        out[t] = (d, maps.prior_term(d.shape), labels, prop.last.confidence,
                  None if prop.classes is None else weight_sum(maps),
                  prop.bars if prop.bars is not None and prop.bars.held(image) else None,
                  prop.last.cut)
    return out, prop


def label_clip(images: Callable[[int], np.ndarray], n: int, keys: Mapping[int, np.ndarray], *, classifier=None,
               fit: str = "stretch", backend: str = "reference", scale: float = 1.0, model: str = "dense",
               on_frame: Callable[[LabelledFrame], None] | None = None, classes=None) -> list[LabelledFrame]:
    """Every frame of a clip of ``n`` frames labelled from its key frames (see the module's docstring).

    images : ``images(t)`` gives frame ``t`` ((H, W, 3) uint8 RGB; asked for as each direction needs it).
    keys : ``{index: labels}``, (H, W) uint8 labels (0 ground, 1 obstacle, 2 unknown) of each key frame.
    classifier : one classifier for every stretch; when None, each stretch's is fitted
        (:func:`pcreg.fit_classifier`) on its own key frames (``fit="stretch"``, one or two) or every
        stretch's on all the key frames (``fit="all"``).
    scale, model : the working size and the motion (:class:`pcreg.Propagator`'s: ``"dense"``, ``"flow"``,
        ``"flow:fast"``, ...).
    on_frame : called with each :class:`LabelledFrame` as soon as it is done (stretches in order).
    classes : the key labels' class table (:func:`pcreg.classes.class_table`'s spec; default ``lagr``).
    Returns the frames in index order (key frames with their own labels).
    """
    from ..classification.bayes import fit_classifier
    from ..datasets import Frame
    from .engine import stretches, two_sided
    from .learning import STREAM_LEARNING
    from .stream import Propagator
    from .trust import predicted_error

    n, classes = _check_clip(images, n, keys, classifier, classes)
    if fit not in KEY_FITS:
        raise InputError(f"fit must be one of {', '.join(KEY_FITS)}, got {fit!r}")
    plan = stretches(list(keys), n)

    def fitted(around) -> object:
        return fit_classifier([Frame(images(k), np.asarray(keys[k]), str(k)) for k in sorted(around)],
                              classes=classes)

    if classifier is None and fit == "all":
        classifier = fitted(keys)
    done: dict[int, LabelledFrame] = {}

    def emit(frame: LabelledFrame) -> None:
        done[frame.index] = frame
        if on_frame is not None:
            on_frame(frame)

    for k in sorted(keys):
        emit(LabelledFrame(k, np.asarray(keys[k], np.uint8), None, 0.0, (k,)))
    for s in plan:
        a, b = s.first, s.last
        learning = None if len(s.keys) == 2 else STREAM_LEARNING
        clf = classifier if classifier is not None else fitted(s.keys)

        def make(learning=learning, clf=clf):
            return Propagator(clf, backend=backend, learning=learning, scale=scale, model=model)

        fwd, prop = ({}, None) if a is None else _pass(make, images(a), keys[a], images, s.frames)
        if b is not None:  # the forward stream let go first: one stream's arrays alive at a time
            prop = None
            bwd, prop = _pass(make, images(b), keys[b], images, s.frames[::-1])
        else:
            bwd = fwd
        for t in s.frames:
            if len(s.keys) == 1:
                _, _, labels, conf, _, bars, _ = bwd[t]
            else:  # as pcreg run's backward pass between two key frames
                assert prop is not None
                d, p_a, _, _, w_a, _, cut_a = fwd[t]
                labels, conf, _ = two_sided(d, p_a, bwd[t][1], prop.trust, size=prop.working_size,
                                            classes=prop.class_read, weights=None if w_a is None else (w_a, bwd[t][4]),
                                            cuts=(cut_a, bwd[t][6]))
                bars = bwd[t][5]
                labels, conf = (labels, conf) if bars is None else bars.maps(labels, conf)  # a letterbox's bars kept
            at = (slice(None), slice(None)) if bars is None else bars.picture  # what the predicted error is of
            emit(LabelledFrame(t, labels, conf, predicted_error(conf[at]), s.keys))
    return [done[t] for t in range(n)]


def _check_clip(images, n, keys, classifier, classes) -> tuple[int, object]:
    """:func:`label_clip`'s clip checked: ``(n, the key labels' class table)``, the table the classifier's when none
    is given; an :class:`InputError` for what is no clip, or a classifier of another table than ``classes``."""
    from ..classes import DEFAULT_TABLE, class_table
    from ..validation import check_int

    if not callable(images):
        raise InputError(f"images must be a function: images(t) gives frame t (for a list, its __getitem__), got "
                         f"{type(images).__name__}")
    n = check_int(n, "the clip's frames", lo=1)
    if not isinstance(keys, Mapping):
        raise InputError(f"keys must be a mapping {{frame index: labels}}, got {type(keys).__name__}")
    if not keys:
        raise InputError("at least one key frame is needed")
    for k in keys:
        check_int(k, "a key frame's index", lo=0, hi=n - 1)
    fitted = getattr(classifier, "class_table", None)
    table = fitted if classes is None else class_table(classes)
    if fitted is not None and table is not None and not fitted.agrees(table):
        raise InputError(f"the classifier's class table ({fitted.source or fitted.describe()}) is not the key labels' "
                         f"({table.source or table.describe()}): {fitted.difference(table)}; fit it on the key labels' "
                         "table, or give the classifier's")
    for k in sorted(keys):  # named by their frame here, not by the classifier's count of what it was fitted on
        (table or DEFAULT_TABLE).check_labels(keys[k], f"key frame {k}")
    return n, table


def suggest(predicted: Mapping[int, float], keys: Sequence[int], count: int, n: int) -> list[int]:
    """The ``count`` frames to label next, best first, chosen without any ground truth.

    1. While the clip has a stretch labelled from one side only (before the first labelled frame, after
       the last), the far end of the longer such stretch: a frame between two key frames is labelled
       from both, which lowered the error by about a quarter on the shared clips.
    2. Then the frame whose predicted error (``predicted``: {index: %} of the frames that are not key
       frames, the mean of 1 - confidence, :attr:`LabelledFrame.predicted_error`) times its distance in
       frames to the nearest labelled frame (key frame or earlier pick) is the largest: a frame's labels
       help the frames around it as far as the next labelled frame, and most where they are predicted
       to be wrong.

    ``keys``: the labelled frames; ``n``: the clip's frames (a frame of ``predicted`` or ``keys`` outside
    0..n-1, or a predicted error that is not a finite number, is an :class:`~pcreg.errors.InputError`).

    Measured on the eight shared CamVid clips against as many key frames evenly spaced from frame 0
    (docs/results.md, "Several key frames")."""
    from ..validation import check_int

    count = check_int(count, "the number of frames to suggest", lo=1)
    n = check_int(n, "the clip's frames", lo=1)
    for what, frames in (("frame", predicted), ("key frame", keys)):
        outside = next((int(t) for t in frames if not 0 <= int(t) < n), None)
        if outside is not None:
            raise InputError(f"{what} {outside} is outside the clip's {n} frames")
    odd = next((t for t, e in predicted.items() if not np.isfinite(float(e))), None)
    if odd is not None:
        raise InputError(f"the predicted error of frame {odd} is {predicted[odd]}, not a finite number")
    keyset = set(int(k) for k in keys)
    items = sorted((int(t), float(e)) for t, e in predicted.items() if int(t) not in keyset)
    if count > len(items):
        raise InputError(f"cannot suggest {count} frames: only {len(items)} are not key frames")
    if not keyset:
        raise InputError("suggesting frames needs at least one key frame")
    candidates = np.array([t for t, _ in items], np.int64)
    errors = np.array([e for _, e in items], np.float64)
    labelled = np.array(sorted(keyset), np.int64)
    distance = _nearest(candidates, labelled)  # each candidate's distance to the nearest labelled frame
    lo, hi = int(labelled[0]), int(labelled[-1])
    free = np.ones(len(candidates), bool)
    chosen: list[int] = []
    for _ in range(count):
        # a stretch labelled from one side (before the first labelled frame, after the last): its far end first
        ends = [i for i in (0, len(candidates) - 1) if free[i] and not lo <= candidates[i] <= hi]
        if ends:
            i = max(ends, key=lambda i: (int(distance[i]), -int(candidates[i])))
        else:  # the largest predicted error times distance; ties to the earliest frame
            i = int(np.argmax(np.where(free, errors * distance, -np.inf)))
        t = int(candidates[i])
        chosen.append(t)
        free[i] = False
        lo, hi = min(lo, t), max(hi, t)
        np.minimum(distance, np.abs(candidates - t), out=distance)
    return chosen


def _nearest(frames: np.ndarray, labelled: np.ndarray) -> np.ndarray:
    """(N,) int64: each of ``frames``' distance in frames to the nearest of ``labelled`` (sorted, not empty)."""
    at = np.searchsorted(labelled, frames)
    after = labelled[np.minimum(at, len(labelled) - 1)]
    before = labelled[np.maximum(at - 1, 0)]
    return np.minimum(np.abs(frames - after), np.abs(frames - before))


def _segments_0_2(n: int, keys) -> list[tuple[int | None, int | None, range]]:
    """0.2.0's ``pcreg.pipeline.keyframes.segments``: the stretches between key frames, ``(earlier key or None,
    later key or None, frames)`` in order, from :func:`pcreg.pipeline.engine.stretches` (the same frames)."""
    from .engine import stretches

    return [(s.first, s.last, range(0 if s.first is None else s.first + 1, int(n) if s.stop is None else s.stop))
            for s in stretches(keys, int(n))]


if not TYPE_CHECKING:  # a module __getattr__ would be mypy's for every name: a misspelt one would pass
    __getattr__ = moved(__name__, {"segments": "pcreg.pipeline.keyframes:_segments_0_2 pcreg.pipeline.engine.stretches (Stretch: first, last, stop)"})
