"""The one propagation engine: a clip's stretches between key frames, one pass along a stretch in either
direction, and the fusion of a frame's two passes.

The people who label video label a few frames anywhere in it and fill in between. A clip is cut into
stretches at its key frames (:func:`stretches`): before the first key frame (labelled backwards from
it), between two (from both), after the last (forwards from it). A pass (:func:`propagate`) carries one
key frame's labels along a stretch, one frame after the other, in the order it is given the frames:
forwards or backwards is only the order, as in SAM2's ``propagate_in_video(..., reverse=)``. Between two
key frames each frame has two passes, and :func:`two_sided` adds their trusted priors to the frame's
naive Bayes (``F = d + P_earlier + P_later``).

``pcreg run`` (one key frame: one stretch, forwards; or a folder of key frames, resumable,
:mod:`pcreg.pipeline.keys_run`), :func:`pcreg.pipeline.keyframes.label_clip` (a clip in memory) and the
stream evaluations (:mod:`pcreg.experiments.stream`, :mod:`pcreg.experiments.stream_keys`) all label
through these three: :func:`propagate` is the one loop that steps a stretch's frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Protocol, TypeVar

import numpy as np

from ..errors import InputError

__all__ = ["Labeller", "Stretch", "stretches", "propagate", "References", "two_sided", "PRIOR_STORE_DTYPE"]

#: How a forward pass keeps each frame's prior term for the backward pass between two key frames
#: (``pcreg run`` keeps it on disk between its two passes; :func:`pcreg.pipeline.keyframes.label_clip`
#: rounds it the same way, so both give the same labels).
PRIOR_STORE_DTYPE = np.float16


#: A frame as a pass is given it: an image, or a :class:`~pcreg.frame.PreparedFrame`.
Image = TypeVar("Image")


class Labeller(Protocol):
    """What a pass steps: :class:`pcreg.Propagator`, or one of the evaluations' baselines (reset to a
    key frame beforehand; its ``step`` labels the next frame)."""

    def step(self, image) -> np.ndarray: ...


@dataclass(frozen=True)
class Stretch:
    """The frames between two key frames (positions): ``first`` the earlier key frame (None before the
    first), ``last`` the later one (None after the last); ``stop`` the position after its last frame
    (None: to the end of a video whose length is not known yet)."""

    first: int | None
    last: int | None
    stop: int | None

    @property
    def start(self) -> int:
        return 0 if self.first is None else self.first + 1

    def __contains__(self, t: int) -> bool:
        return t >= self.start and (self.stop is None or t < self.stop)

    @property
    def keys(self) -> tuple[int, ...]:
        return tuple(k for k in (self.first, self.last) if k is not None)

    @property
    def frames(self) -> range:
        """Its frames in order (a stretch whose ``stop`` is known)."""
        if self.stop is None:
            raise ValueError("a stretch to the end of a video of unknown length has no range")  # a caller's bug
        return range(self.start, self.stop)


def stretches(keys: Iterable[int], n: int | None) -> list[Stretch]:
    """The stretches of ``n`` frames (None: a video not decoded to its end) around the key frames
    ``keys`` (positions), in order, empty ones left out: every frame that is not a key frame is in
    exactly one. No key frame, or one outside the clip, is an :class:`~pcreg.errors.InputError`."""
    ks = sorted(set(int(k) for k in keys))
    if not ks:
        raise InputError("at least one key frame is needed")
    if ks[0] < 0 or (n is not None and ks[-1] >= n):
        raise InputError(f"key frame {ks[0] if ks[0] < 0 else ks[-1]} is outside the clip's {n} frames")
    out = []
    if ks[0] > 0:
        out.append(Stretch(None, ks[0], ks[0]))
    out += [Stretch(a, b, b) for a, b in zip(ks, ks[1:]) if b > a + 1]
    if n is None or ks[-1] < n - 1:
        out.append(Stretch(ks[-1], None, n))
    return out


def propagate(labeller: Labeller, frames: Iterable[tuple[int, Image]], *,
              check: Callable[[], None] | None = None,
              where: Callable[[int], object] | None = None) -> Iterator[tuple[int, Image, np.ndarray]]:
    """One pass: each ``(t, image)`` of ``frames``, in the order given (forwards or backwards along a
    stretch), labelled by ``labeller`` (already reset to the pass's key frame, or resumed); yields
    ``(t, image, labels)`` as each is done, the labeller's report of it in its ``last``.

    check : called before each step (an interruption raises there).
    where : names frame ``t``'s file for a step's :class:`~pcreg.errors.InputError` (a frame of
        another size): the error then says which file.
    """
    for t, image in frames:
        if check is not None:
            check()
        try:
            labels = labeller.step(image)
        except InputError as exc:
            if where is None:
                raise
            raise InputError(f"{where(t)}: {exc}") from None
        yield t, image, labels


class References:
    """The images a pass's steps are registered to, for a recording: its key frame (step 0) and the frame of
    the last step (a chained step's reference). :meth:`of` is a step's (None when not at hand);
    :meth:`stepped` keeps the frame a step labelled. ``carry``: a resumed pass's propagator's
    :attr:`~pcreg.pipeline.stream.Propagator.carry`; a chained one holds the frame its next step is registered
    to (at the working size: brought to the key frame's size)."""

    def __init__(self, key: np.ndarray, carry=None) -> None:
        self._key = key
        self._images: dict[int, np.ndarray] = {0: key}
        image = getattr(carry, "rgb", None)
        if image is not None and carry.frame > 0:
            if image.shape[:2] != key.shape[:2]:
                import cv2

                image = cv2.resize(image, (key.shape[1], key.shape[0]), interpolation=cv2.INTER_LINEAR)
            self._images[int(carry.frame)] = image

    def of(self, report) -> np.ndarray | None:
        return self._images.get(report.reference)

    def stepped(self, report, image: np.ndarray) -> None:
        self._images = {0: self._key, report.frame: image}


def two_sided(log_odds: np.ndarray, earlier: np.ndarray, later: np.ndarray, rule, *,
              size=None, classes=None, weights: tuple | None = None,
              cuts: tuple[bool, bool] = (False, False)) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A frame between two key frames: ``(labels, confidence, second)`` of naive Bayes' ``log_odds`` with
    the trusted prior terms of both passes added (``F = d + P_earlier + P_later``; ``earlier`` as the
    forward pass kept it, :data:`PRIOR_STORE_DTYPE`), read by the trust ``rule``
    (:func:`~pcreg.pipeline.trust.read_labels`; ``size``: the stream's working size, when the maps are at
    it). Measured against averaging the priors, weighting them by distance or by trust, and taking the
    more trusted one: adding them lowered the error most (docs/results.md, "Several key frames").
    ``classes``: with K classes their read-out (:class:`~pcreg.pipeline.multiclass.ClassRead`), the maps
    (H, W, K) class scores and evidence, read as the stream reads them
    (:func:`~pcreg.pipeline.multiclass.read_class_labels`), ``weights`` each pass's summed trust weight (H, W)
    for the class window; ``second`` is then each pixel's runner-up class (None with two classes).

    ``cuts``: whether each pass's cut test found the frame outside its key frame's scene
    (:mod:`pcreg.pipeline.cuts`). A frame both passes found so, in neither key frame's scene, is marked as a stream
    marks a cut: every confidence the least (:func:`~pcreg.pipeline.trust.least_confidence`). Its labels, and those
    of a frame only one pass found so, keep both priors, which the trust rule has faded where they do not fit:
    leaving out the prior of the pass that found a cut was measured on four shared CamVid clips each followed by
    another place's (key frames 10 frames before and 10 after the cut; docs/results.md, "Scene cuts"), 24.6% wrong
    against 24.4% with both (driving scenes share their layout: road below, sky above)."""
    from .trust import least_confidence, read_labels

    prior = np.add(np.asarray(earlier, PRIOR_STORE_DTYPE), later, dtype=np.float32)  # float16 read as float32, no copy
    second = None
    if classes is not None:
        from .multiclass import read_class_labels
        from .readout import scaled

        window = None if weights is None else (np.asarray(weights[0], np.float32) + weights[1], classes.log_pi)
        labels, confidence, second = read_class_labels(log_odds + prior, log_odds, prior, classes.classes,
                                                       smooth_px=scaled(rule.smooth, prior.shape[1]),
                                                       coefficients=classes.coefficients, size=size, window=window)
    else:
        labels, confidence = read_labels(log_odds + prior, log_odds, prior, rule, size=size)
    if cuts[0] and cuts[1]:
        n = 2 if classes is None else len(classes.classes)
        confidence = np.full(confidence.shape, least_confidence(n), np.float32)
    return labels, confidence, second
