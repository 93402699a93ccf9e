"""The compiled pass of the many-class confidence's region feature (:mod:`pcreg.pipeline.multiclass`): the
mean of a map over each connected piece of one label."""

from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["region_means"]


def _root(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


def _region_means_py(labels, values, parent, out):
    h, w = labels.shape
    n = h * w
    for p in range(n):
        parent[p] = p
    for y in range(h):  # join each pixel to its left and upper neighbours of the same label
        for x in range(w):
            p = y * w + x
            if x > 0 and labels[y, x] == labels[y, x - 1]:
                a, b = _root(parent, p), _root(parent, p - 1)
                parent[max(a, b)] = min(a, b)
            if y > 0 and labels[y, x] == labels[y - 1, x]:
                a, b = _root(parent, p), _root(parent, p - w)
                parent[max(a, b)] = min(a, b)
    sums = np.zeros(n, np.float64)
    counts = np.zeros(n, np.int64)
    for p in range(n):
        a = _root(parent, p)
        parent[p] = a
        sums[a] += values[p // w, p % w]
        counts[a] += 1
    for p in range(n):
        a = parent[p]
        out[p // w, p % w] = sums[a] / counts[a]


_root = njit(cache=True, nogil=True, inline="always")(_root)
_region_means = njit(cache=True, nogil=True)(_region_means_py)


def region_means(labels: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(H, W) float32: at each pixel the mean of ``values`` (H, W) over the pixels of its connected piece of
    ``labels`` (H, W) (4-connected: the pixels reached through left, right, upper and lower neighbours of
    the same label)."""
    h, w = labels.shape
    out = np.empty((h, w), np.float32)
    _region_means(np.ascontiguousarray(labels), np.ascontiguousarray(values, np.float32),
                  np.empty(h * w, np.int64), out)
    return out
