"""Robust statistics of the dense registration: Tukey's biweight of the matches' colour distances,
its scale from their median absolute deviation, and the compiled pass that weighs the matches and
scatters them into the grid's normal equations."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["TUKEY_C"]

#: Tukey's biweight constant (95% efficiency under Gaussian noise).
TUKEY_C = 4.685


def _median(values: np.ndarray) -> float:
    """``np.median`` of a 1-D float array without NaN (NaN when it is empty): the middle value, or the
    mean of the two middle ones, the lower of which is the largest value left of the upper's place
    after one ``np.partition``. numpy selects with SIMD where the CPU has it: 13 us for the 4,400
    colour distances of a level, against 60 for numba's quickselect, whose branches the data of each
    call mispredict anew (12 us when timed on one array over and over)."""
    n = values.shape[0]
    if n == 0:
        return float("nan")
    k = n // 2
    part = np.partition(values, k)
    if n % 2:
        return float(part[k])
    return (float(part[:k].max()) + float(part[k])) / 2


def _robust_scale(m: np.ndarray, sigma: float) -> float:
    """Tukey's scale for the colour distances ``m[:, 2]`` of the mutual matches of
    :func:`match_window`'s rows ``m`` (``m[:, 3] > 0``, a partner found): ``median + TUKEY_C * 1.4826
    MAD`` of those distances, at least twice the distance of two noisy pixels of one point
    (``2 sqrt(6) sigma``); 0.0 (no weights) when fewer than 8 matches are mutual."""
    g = np.empty(m.shape[0])
    g = g[:_mutual_distances(m, g)]
    if g.shape[0] < 8:
        return 0.0
    med = _median(g)
    mad = _median(np.abs(g - med)) * 1.4826
    return max(med + TUKEY_C * max(mad, 1e-6), 2.0 * math.sqrt(6.0) * sigma)


def _mutual_distances_py(m, out):
    """The colour distances ``m[:, 2]`` of the rows of ``m`` with a mutual partner and a match, in order,
    into ``out``; returns how many (a fifth of the time of numpy's masks on the columns)."""
    k = 0
    for i in range(m.shape[0]):
        if m[i, 3] > 0.0 and np.isfinite(m[i, 0]):
            out[k] = m[i, 2]
            k += 1
    return k


def _nan_median(a: np.ndarray) -> float:
    """The median of the values of ``a`` (N,) that are not NaN, NaN when there is none: ``np.nanmedian``'s
    number (:func:`_median`), in a third of its time for the 5,000 distances of a level."""
    return _median(a[~np.isnan(a)])


def _weigh_assemble_py(m, x, start, scale, cols, vals, pair_k, data, rhs, node_w, wts, wres):
    """Tukey's biweight at ``scale`` of the colour distance of each mutual match in ``m``
    (:func:`match_window`'s rows; no weight without a mutual partner, nor for any match when ``scale``
    <= 0) into ``wts`` (N,), weight x ``|m[:, :2] - x|^2`` into ``wres`` (N,) (both left 0 where there
    is no weight), and each weighted match's target ``m[:, :2] - start`` scattered into the equations as
    :func:`_assemble_py` does. Returns how many samples got a non-zero weight."""
    n = m.shape[0]
    inliers = 0
    for i in range(n):
        if not (scale > 0.0 and m[i, 3] > 0.0 and np.isfinite(m[i, 0])):
            continue
        u = m[i, 2] / scale
        if not abs(u) < 1.0:
            continue
        wi = (1.0 - u * u) ** 2
        if wi == 0.0:
            continue
        inliers += 1
        wts[i] = wi
        rx = m[i, 0] - x[i, 0]
        ry = m[i, 1] - x[i, 1]
        wres[i] = wi * (rx * rx + ry * ry)
        tx = m[i, 0] - start[i, 0]
        ty = m[i, 1] - start[i, 1]
        # the corners' columns and weights in registers, and the inner loop written out: the compiler
        # cannot tell that writes to ``data`` leave them unchanged, and read them again after each
        # write (0.79 of the time; the same sums in the same order)
        c0, c1, c2, c3 = cols[i, 0], cols[i, 1], cols[i, 2], cols[i, 3]
        v0, v1, v2, v3 = vals[i, 0], vals[i, 1], vals[i, 2], vals[i, 3]
        for p in range(4):
            a = cols[i, p]
            wv = wi * vals[i, p]
            node_w[a] += wv
            rhs[a, 0] += wv * tx
            rhs[a, 1] += wv * ty
            data[pair_k[p, 0], c0] += wv * v0
            data[pair_k[p, 1], c1] += wv * v1
            data[pair_k[p, 2], c2] += wv * v2
            data[pair_k[p, 3], c3] += wv * v3
    return inliers


try:
    from ..._jit import njit as _njit

    _mutual_distances = _njit(cache=True, nogil=True)(_mutual_distances_py)
    _weigh_assemble = _njit(cache=True, nogil=True)(_weigh_assemble_py)
except ImportError:  # pragma: no cover - numba is a declared dependency
    _mutual_distances, _weigh_assemble = _mutual_distances_py, _weigh_assemble_py
