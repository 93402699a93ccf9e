"""The sizes a stream's read-out works at: pixel sizes stated at one width, and the half-size image its
neighbourhoods are read at (:mod:`pcreg.pipeline.trust` for two classes, :mod:`pcreg.pipeline.multiclass`
for more)."""

from __future__ import annotations

import numpy as np

__all__ = ["BASE_WIDTH", "PURITY_SIDES", "AGREEMENT_SIDE", "scaled", "odd", "half", "Scratch", "empty"]

#: The width at which the rule's pixel sizes are stated; they scale with the frame's width.
BASE_WIDTH = 480.0
#: Sides (px at :data:`BASE_WIDTH`) of the neighbourhoods the confidence reads: the label's purity at
#: two sizes, and the agreement of the classifier with the carried prior.
PURITY_SIDES, AGREEMENT_SIDE = (15, 33), 33


def scaled(px: float, width: int) -> float:
    """``px`` stated at :data:`BASE_WIDTH`, at a frame ``width`` px wide."""
    return px * width / BASE_WIDTH


def odd(px: float, width: int) -> int:
    """:func:`scaled`, rounded to an odd number of pixels (a box filter's side), at least 1."""
    return max(1, int(round(scaled(px, width))) // 2 * 2 + 1)


#: The most channels OpenCV's filters and resizes take in one array (``CV_CN_MAX`` of the OpenCV that pcreg
#: pins; 512 before OpenCV 5).
MAX_CHANNELS = 128


def channelwise(fn, values: np.ndarray) -> np.ndarray:
    """``fn`` (an OpenCV filter or resize of one array, channel by channel) of (H, W, K) ``values`` as an
    (H', W', K) array: in one call up to :data:`MAX_CHANNELS` channels, beyond that in parts of that many
    (each channel's numbers the same either way)."""
    a = np.asarray(values)
    k = a.shape[2]
    if k <= MAX_CHANNELS:
        out = fn(a)
        return out.reshape(out.shape[:2] + (k,))
    parts = [fn(np.ascontiguousarray(a[:, :, i:i + MAX_CHANNELS])) for i in range(0, k, MAX_CHANNELS)]
    return np.concatenate([p.reshape(p.shape[:2] + (-1,)) for p in parts], axis=2)


def half(image: np.ndarray) -> np.ndarray:
    """The image at half its size (each pixel the mean of a 2x2 block), as float32."""
    import cv2

    a = np.asarray(image, dtype=np.float32)
    h, w = a.shape[:2]
    return cv2.resize(a, (max(1, w // 2), max(1, h // 2)), interpolation=cv2.INTER_AREA)


class Scratch:
    """Arrays that a step's read-out writes and reads again within the step, kept from one step to the next
    (a stream's frames are of one size; none is returned). Made anew in each step, 10-30 MB of them at 640x480
    with eleven classes went back to the system at the step's end and had every page faulted in again in the
    next (about 1,400 page faults a step, 8 ms of system time). Not for two threads at once: a stream's own."""

    def __init__(self) -> None:
        self._arrays: dict = {}

    def array(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        """An array of ``shape`` and ``dtype`` (its values left from its last use), the one kept as ``name``."""
        a = self._arrays.get(name)
        if a is None or a.shape != tuple(shape) or a.dtype != np.dtype(dtype):
            a = self._arrays[name] = np.empty(shape, dtype)
        return a


def empty(scratch: Scratch | None, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """``scratch``'s array ``name`` (:meth:`Scratch.array`), or a new one without a scratch."""
    return np.empty(shape, dtype) if scratch is None else scratch.array(name, shape, dtype)
