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
from typing import Callable, Mapping, Sequence

import numpy as np

from ..errors import InputError

__all__ = ["LabelledFrame", "label_clip", "suggest", "segments", "KEY_FITS"]

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


def segments(n: int, keys: Sequence[int]) -> list[tuple[int | None, int | None, range]]:
    """The stretches between key frames: ``(earlier key or None, later key or None, frames)`` in order,
    each non-key frame of ``range(n)`` in exactly one."""
    ks = sorted(set(int(k) for k in keys))
    if not ks:
        raise InputError("at least one key frame is needed")
    if ks[0] < 0 or ks[-1] >= n:
        raise InputError(f"key frame {ks[0] if ks[0] < 0 else ks[-1]} is outside the clip's {n} frames")
    out: list[tuple[int | None, int | None, range]] = []
    if ks[0] > 0:
        out.append((None, ks[0], range(0, ks[0])))
    for a, b in zip(ks, ks[1:]):
        if b > a + 1:
            out.append((a, b, range(a + 1, b)))
    if ks[-1] < n - 1:
        out.append((ks[-1], None, range(ks[-1] + 1, n)))
    return out


def _carry(make: Callable, key_image, key_labels, images: Callable[[int], np.ndarray], order) -> dict:
    """One direction: ``{t: (log_odds, prior_term, confidence)}`` along ``order`` from the key frame (the
    first two at the propagator's working size)."""
    prop = make()
    prop.reset(key_image, key_labels)
    out = {}
    for t in order:
        prop.step(images(t))
        d = prop.last.log_odds
        out[t] = (d, prop.last.trust.prior_term(d.shape), prop.last.confidence)
    return out


def label_clip(images: Callable[[int], np.ndarray], n: int, keys: Mapping[int, np.ndarray], *, classifier=None,
               fit: str = "stretch", backend: str = "reference", scale: float = 1.0, model: str = "dense",
               on_frame: Callable[[LabelledFrame], None] | None = None) -> list[LabelledFrame]:
    """Every frame of a clip of ``n`` frames labelled from its key frames (see the module's docstring).

    images : ``images(t)`` gives frame ``t`` ((H, W, 3) uint8 RGB; asked for as each direction needs it).
    keys : ``{index: labels}``, (H, W) uint8 labels (0 ground, 1 obstacle, 2 unknown) of each key frame.
    classifier : one classifier for every stretch; when None, each stretch's is fitted
        (:func:`pcreg.fit_classifier`) on its own key frames (``fit="stretch"``, one or two) or every
        stretch's on all the key frames (``fit="all"``).
    scale, model : the working size and the motion (:class:`pcreg.Propagator`'s: ``"dense"``, ``"flow"``,
        ``"flow:fast"``, ...).
    on_frame : called with each :class:`LabelledFrame` as soon as it is done (segments in order).
    Returns the frames in index order (key frames with their own labels).
    """
    from ..classification.bayes import fit_classifier
    from ..datasets import Frame
    from .learning import STREAM_LEARNING
    from .stream import Propagator
    from .trust import STREAM_TRUST, predicted_error, read_labels, smoothed
    from .working import WorkingSize

    if not keys:
        raise InputError("at least one key frame is needed")
    if fit not in KEY_FITS:
        raise InputError(f"fit must be one of {', '.join(KEY_FITS)}, got {fit!r}")
    parts = segments(n, list(keys))

    def fitted(around) -> object:
        return fit_classifier([Frame(images(k), np.asarray(keys[k]), str(k)) for k in sorted(around)])

    if classifier is None and fit == "all":
        classifier = fitted(keys)
    done: dict[int, LabelledFrame] = {}

    def emit(frame: LabelledFrame) -> None:
        done[frame.index] = frame
        if on_frame is not None:
            on_frame(frame)

    for k in sorted(keys):
        emit(LabelledFrame(k, np.asarray(keys[k], np.uint8), None, 0.0, (k,)))
    for a, b, frames in parts:
        size = WorkingSize(np.asarray(keys[a if a is not None else int(b)]).shape[:2], scale)  # type: ignore[arg-type]
        both = a is not None and b is not None
        learning = None if both else STREAM_LEARNING
        clf = classifier if classifier is not None else fitted([k for k in (a, b) if k is not None])

        def make(learning=learning, clf=clf):
            return Propagator(clf, backend=backend, learning=learning, scale=scale, model=model)

        fwd = {} if a is None else _carry(make, images(a), keys[a], images, frames)
        bwd = {} if b is None else _carry(make, images(b), keys[b], images, frames[::-1])
        for t in frames:
            if not both:
                d, prior, conf = (fwd or bwd)[t]
                labels = (size.grow(smoothed(d + prior, STREAM_TRUST)) > 0).astype(np.uint8)  # conf: the propagator's
            else:
                d, p_a, _ = fwd[t]
                _, p_b, _ = bwd[t]
                p_a = p_a.astype(np.float16).astype(np.float32)  # as pcreg run keeps it between its two passes
                prior = p_a + p_b
                labels, conf = read_labels(d + prior, d, prior, STREAM_TRUST, size=size)
            emit(LabelledFrame(t, labels, conf, predicted_error(conf),
                               tuple(k for k in (a, b) if k is not None)))
    return [done[t] for t in range(n)]


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

    Measured on the eight shared CamVid clips against as many key frames evenly spaced from frame 0
    (docs/results.md, "Several key frames")."""
    from ..validation import check_int

    count = check_int(count, "the number of frames to suggest", lo=1)
    keyset = set(int(k) for k in keys)
    candidates = [t for t in predicted if t not in keyset]
    if count > len(candidates):
        raise InputError(f"cannot suggest {count} frames: only {len(candidates)} are not key frames")
    if not keyset:
        raise InputError("suggesting frames needs at least one key frame")
    chosen: list[int] = []
    for _ in range(count):
        taken = keyset | set(chosen)

        ends = [t for t in (min(candidates), max(candidates)) if t not in taken and (t < min(taken) or t > max(taken))]
        if ends:  # a stretch labelled from one side: its far end first
            chosen.append(max(ends, key=lambda t: (min(abs(t - k) for k in taken), -t)))
            continue

        def score(t: int) -> float:
            return float(predicted[t]) * min(abs(t - k) for k in taken)

        chosen.append(max((t for t in candidates if t not in chosen), key=lambda t: (score(t), -t)))
    return chosen
