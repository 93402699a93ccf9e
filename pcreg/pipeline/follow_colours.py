"""The key frame's colour model of :mod:`pcreg.pipeline.follow`: each pixel's YCrCb bin, a frame's colour histogram,
and the log-odds of a colour under the key frame's object against its background."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["BINS", "CLIP"]

#: Every log-odds term is clipped to +-CLIP.
CLIP = 4.0
#: Bins of each of Y, Cr and Cb in the key frame's colour histograms.
BINS = 16
_BIN_BITS = BINS.bit_length() - 1  # a channel's bin is its top _BIN_BITS bits (BINS a power of 2)


def _histogram(index: np.ndarray) -> np.ndarray:
    """(BINS^3,) float32: the share of the pixels in each colour bin (``index`` from :func:`_colour_index`)."""
    return (np.bincount(index.ravel(), minlength=BINS ** 3) / index.size).astype(np.float32)


def _blur_bins(h: np.ndarray) -> np.ndarray:
    """A 3-D histogram blurred once by [1 2 1] / 4 along each axis (no wrap at its ends)."""
    for ax in range(3):
        b = h * 2
        lo, hi = [slice(None)] * 3, [slice(None)] * 3
        lo[ax], hi[ax] = slice(0, -1), slice(1, None)
        b[tuple(hi)] += h[tuple(lo)]
        b[tuple(lo)] += h[tuple(hi)]
        h = b * 0.25
    return h


def _colour_index(rgb: np.ndarray) -> np.ndarray:
    """Each pixel's bin of the YCrCb histogram, (H, W) uint16: ``(Y >> s) * BINS^2 + (Cr >> s) * BINS +
    (Cb >> s)``, s = 8 - log2(BINS) (uint16 shifts: about 1 ms at 854x480, against 35 ms in int32
    arithmetic, measured in one process)."""
    c = cv2.cvtColor(rgb, cv2.COLOR_RGB2YCrCb) >> (8 - _BIN_BITS)
    c = c.astype(np.uint16)
    return (c[..., 0] << (2 * _BIN_BITS)) | (c[..., 1] << _BIN_BITS) | c[..., 2]


def _colour_table(rgb: np.ndarray, share: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(BINS^3,) float32: log p(colour | object) - log p(colour | background) of the key frame's known
    pixels (``share`` > 0.5 the object), each histogram blurred and normalised, clipped to +-CLIP. The
    pseudo-counts (0.002 a bin in all) are shared in proportion to the classes' pixels, so a colour neither
    histogram holds has a log-odds of 0: with the same pseudo-count for each, it leaned towards the smaller class."""
    idx = _colour_index(rgb).ravel()
    n = BINS ** 3
    k = known.ravel()
    fg, bg = ((share.ravel() > 0.5) & k).astype(np.float64), ((share.ravel() <= 0.5) & k).astype(np.float64)
    h1 = _blur_bins(np.bincount(idx, fg, n).reshape((BINS,) * 3)).ravel()
    h0 = _blur_bins(np.bincount(idx, bg, n).reshape((BINS,) * 3)).ravel()
    n1, n0 = h1.sum(), h0.sum()
    a1, a0 = 2e-3 * n1 / (n1 + n0), 2e-3 * n0 / (n1 + n0)
    p1, p0 = (h1 + a1) / (n1 + a1 * n), (h0 + a0) / (n0 + a0 * n)
    return np.clip(np.log(p1) - np.log(p0), -CLIP, CLIP).astype(np.float32)
