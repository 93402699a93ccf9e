"""The exact windowed nearest-neighbour search of the dense registration (compiled with numba): each
moving sample's best reference pixel in ``(x, y, lam * colour)`` within a square gate, refined to
sub-pixel, and the mutual test that searches back."""

from __future__ import annotations

import math

import numpy as np

from ..._threads import interleave

__all__ = ["MATCH_BLOCK", "SPLIT_MIN_SAMPLES", "match_window"]


def _cost_py(img, qx, qy, x, dy2, src, sy, sx, lam2):
    """``(qx - x)^2 + dy2 + lam2 |img[qy, qx] - src[sy, sx]|^2``, ``dy2`` the row's ``(qy - y)^2``: the
    float32 colour differences squared and summed in float64, channel by channel."""
    s = 0.0
    for k in range(img.shape[2]):
        d = img[qy, qx, k] - src[sy, sx, k]
        s += d * d
    return (qx - x) * (qx - x) + dy2 + lam2 * s


def _cost3_py(img, qx, qy, x, dy2, src, sy, sx, lam2):
    """:func:`_cost_py` for three channels, unrolled (a quarter faster): the same sum in the same order."""
    s = 0.0
    d = img[qy, qx, 0] - src[sy, sx, 0]
    s += d * d
    d = img[qy, qx, 1] - src[sy, sx, 1]
    s += d * d
    d = img[qy, qx, 2] - src[sy, sx, 2]
    s += d * d
    return (qx - x) * (qx - x) + dy2 + lam2 * s


def _scan_py(img, x, y, src, sy, sx, radius, lam2, cost):
    """:func:`_best_in_window_py` with the pixels' ``cost`` function (:func:`_cost_py` or :func:`_cost3_py`).

    The scan skips rows that cannot hold the answer: every pixel of a row costs at least the row's
    ``dy2``, so a row is skipped when ``dy2`` is no less than the best cost so far (only a strictly
    smaller cost replaces it) or greater than the cost of the window's centre (a pixel of the window,
    computed by the same function, so the least cost is at most that). The rows are still read in
    order and every pixel of a row read is compared as before, so the answer is the same, ties
    included. A good match costs a few units (a pixel of distance, the noise of two pixels' colours),
    and the centre is near it once the field is close (always for the mutual test's search back, which
    starts at the sample itself), so most far rows are skipped: 0.75-0.80 of the time of the full scan
    on streamed CamVid and synthetic frames, the same matches. Skipping single pixels by their
    horizontal distance as well read fewer pixels but took longer: it breaks the tight loop over a row.
    """
    h, w = img.shape[0], img.shape[1]
    cx = int((x + 0.5) // 1.0)  # the nearest pixel, halves up
    cy = int((y + 0.5) // 1.0)
    x0, x1 = max(cx - radius, 0), min(cx + radius, w - 1)
    y0, y1 = max(cy - radius, 0), min(cy + radius, h - 1)
    best, bx, by = np.inf, -1, -1
    bound = np.inf  # a NaN cost at the centre skips no row: no comparison with NaN holds
    if x0 <= cx <= x1 and y0 <= cy <= y1:
        bound = cost(img, cx, cy, x, (cy - y) * (cy - y), src, sy, sx, lam2)
    for qy in range(y0, y1 + 1):
        dy2 = (qy - y) * (qy - y)
        if dy2 >= best or dy2 > bound:  # every pixel of the row costs at least dy2
            continue
        for qx in range(x0, x1 + 1):
            c = cost(img, qx, qy, x, dy2, src, sy, sx, lam2)
            if c < best:
                best, bx, by = c, qx, qy
    return bx, by, cx, cy


def _best_in_window_py(img, x, y, src, sy, sx, radius, lam2):
    """The pixel of ``img`` (H, W, C) within ``radius`` (per axis) of the pixel nearest (x, y) with the least
    ``|q - (x, y)|^2 + lam2 |img[q] - src[sy, sx]|^2`` (:func:`_cost_py`): ``(qx, qy, cx, cy)``, (cx, cy)
    the window's centre; qx = qy = -1 when the window holds no pixel of the image (ties: the first in row
    order; :func:`_scan_py`). The colour is read in place from ``src`` (..., C), so no array view is made
    per call."""
    if img.shape[2] == 3:  # a separate loop for the common case: a branch inside it made it slower
        return _scan(img, x, y, src, sy, sx, radius, lam2, _cost3)
    return _scan(img, x, y, src, sy, sx, radius, lam2, _cost)


#: Samples per block of :func:`_match_window_py`: two threads take alternate blocks, so each gets
#: samples from all over the image (a search costs more where there is texture to match) without
#: writing to the same cache lines (32 rows of 32 bytes).
MATCH_BLOCK = 32


def _match_window_py(ref, mov, px, py, x, y, cols, radius, lam2, mutual, out, first, stride):
    """Pure-Python body of :func:`match_window` (compiled with numba when it is installed): the samples
    of blocks ``first``, ``first + stride``, ... of :data:`MATCH_BLOCK` samples."""
    h, w, nc = ref.shape
    n = x.shape[0]
    cols3 = cols.reshape(n, 1, nc)  # each point's colour as a one-pixel row, read in place by the search
    for b in range(first * MATCH_BLOCK, n, stride * MATCH_BLOCK):
        for i in range(b, min(b + MATCH_BLOCK, n)):
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            out[i, 2] = np.inf
            out[i, 3] = 0.0
            xi, yi = x[i], y[i]
            if not (xi > -radius and yi > -radius and xi < w - 1 + radius and yi < h - 1 + radius):
                continue
            bx, by, cx, cy = _best_in_window(ref, xi, yi, cols3, i, 0, radius, lam2)
            if bx < 0:
                continue
            # the best candidate on the gate's rim (not the image's): its partner may lie outside the gate
            rim = ((bx == cx - radius and bx > 0) or (bx == cx + radius and bx < w - 1)
                   or (by == cy - radius and by > 0) or (by == cy + radius and by < h - 1))
            # sub-pixel: one Gauss-Newton step on the same cost with the reference colour linearised at
            # the best pixel (central differences), ``(lam2 J^T J + I) d = -lam2 J^T r - (q - x)``: the
            # colour term of Park, Zhou & Koltun (2017, "Colored point cloud registration revisited"),
            # free of the pull to whole pixels that a parabola through the costs has
            ox = 0.0
            oy = 0.0
            if 0 < bx < w - 1 and 0 < by < h - 1:
                a11 = 1.0
                a12 = 0.0
                a22 = 1.0
                b1 = -(bx - xi)
                b2 = -(by - yi)
                for k in range(nc):
                    jx = 0.5 * (ref[by, bx + 1, k] - ref[by, bx - 1, k])
                    jy = 0.5 * (ref[by + 1, bx, k] - ref[by - 1, bx, k])
                    r = ref[by, bx, k] - cols[i, k]
                    a11 += lam2 * jx * jx
                    a12 += lam2 * jx * jy
                    a22 += lam2 * jy * jy
                    b1 -= lam2 * jx * r
                    b2 -= lam2 * jy * r
                det = a11 * a22 - a12 * a12
                if det > 1e-12:
                    ox = min(max((a22 * b1 - a12 * b2) / det, -0.5), 0.5)
                    oy = min(max((a11 * b2 - a12 * b1) / det, -0.5), 0.5)
            out[i, 0] = bx + ox
            out[i, 1] = by + oy
            s = 0.0
            for k in range(nc):
                d = ref[by, bx, k] - cols[i, k]
                s += d * d
            out[i, 2] = math.sqrt(s)
            if rim or not mutual:
                continue
            # mutual test: the reference point's nearest moving pixel, searched back around where the
            # point's own displacement says it came from, must be the point (within a pixel)
            ex = px[i] + (bx - xi)
            ey = py[i] + (by - yi)
            b2x, b2y, _, _ = _best_in_window(mov, ex, ey, ref, by, bx, radius, lam2)
            if b2x >= 0 and abs(b2x - px[i]) <= 1.0 and abs(b2y - py[i]) <= 1.0:
                out[i, 3] = 1.0
    return out


try:  # the compiled search; the pure-Python body is the same code and the fallback
    from ..._jit import njit

    _cost = njit(cache=True, nogil=True, inline="always")(_cost_py)
    _cost3 = njit(cache=True, nogil=True, inline="always")(_cost3_py)
    _scan = njit(cache=True, nogil=True, inline="always")(_scan_py)
    _best_in_window = njit(cache=True, nogil=True, inline="always")(_best_in_window_py)
    _match_window_jit = njit(cache=True, nogil=True)(_match_window_py)
except ImportError:  # pragma: no cover - numba is a declared dependency
    _cost, _cost3, _scan, _best_in_window = _cost_py, _cost3_py, _scan_py, _best_in_window_py
    _match_window_jit = None


#: From this many samples :func:`match_window` splits its samples between this thread and pcreg's
#: helper thread (:mod:`pcreg._threads`), when the process may use two CPUs.
SPLIT_MIN_SAMPLES = 1000


def match_window(reference: np.ndarray, moving: np.ndarray, sources: np.ndarray, positions: np.ndarray,
                 colours: np.ndarray, *, radius: int, lam: float, mutual: bool = True,
                 compiled: bool = True) -> np.ndarray:
    """Exact nearest neighbours in ``(x, y, lam * colour)`` within a square gate.

    reference, moving : (h, w, C) float32 images of one pyramid level (the reference cloud is every
        reference pixel; ``moving`` is searched back for the mutual test).
    sources : (N, 2) moving pixel coordinates of the samples; positions : (N, 2) where the current
        field puts them in the reference; colours : (N, C) float32 their colours.
    radius : the gate, in pixels of this level (the window is (2 radius + 1)^2 pixels).
    mutual : test each match that is not on the gate's rim for being mutual (a second window search,
        back in ``moving``); False leaves the fourth column 0 and the first three as they are.
    Returns (N, 4) float64: matched reference x, y (sub-pixel; NaN where the gate holds no pixel),
    colour distance, and 1.0 where the match is mutual and not on the gate's rim (else 0.0).
    """
    ref = np.ascontiguousarray(reference, dtype=np.float32)
    mov = np.ascontiguousarray(moving, dtype=np.float32)
    src = np.asarray(sources, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64)
    cols = np.ascontiguousarray(colours, dtype=np.float32)
    out = np.empty((len(pos), 4), dtype=np.float64)
    px, py = np.ascontiguousarray(src[:, 0]), np.ascontiguousarray(src[:, 1])
    x, y = np.ascontiguousarray(pos[:, 0]), np.ascontiguousarray(pos[:, 1])
    radius, lam2 = int(radius), float(lam) ** 2
    if not (compiled and _match_window_jit is not None):
        return _match_window_py(ref, mov, px, py, x, y, cols, radius, lam2, bool(mutual), out, 0, 1)

    def blocks(first: int, stride: int) -> None:  # each sample's match is its own: any share is independent
        _match_window_jit(ref, mov, px, py, x, y, cols, radius, lam2, bool(mutual), out, first, stride)

    interleave(len(pos), blocks, min_items=SPLIT_MIN_SAMPLES)
    return out
