"""The dense registration's field at full resolution: the global transform plus the control grid's
displacements interpolated at every pixel, and the confidence beside it (compiled with numba)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._threads import MIN_PIXELS, interleave
from ..motion import _field_row
from .levels import _Level


@dataclass(frozen=True)
class _FullField:
    """The field (H, W, 2) float32 at full resolution, its confidence (H, W) float32, and the grid's
    displacements (gh, gw, 2) in full-image pixels."""

    field: np.ndarray
    confidence: np.ndarray
    grid: np.ndarray


def _full_field(T: np.ndarray, U: np.ndarray, weights_node: np.ndarray, lv: _Level, shape: tuple[int, int]
                ) -> _FullField:
    """The global transform plus the grid's displacements, interpolated at every full-size pixel, and
    the confidence: the nodes' data weight against a quarter of a cell's pixels (at the sampling rate),
    0 where the field leaves the reference image. ``lv``: the finest level."""
    h, w = shape
    f, s, gshape = lv.scale, lv.spacing, lv.gshape
    grid = (f * U).reshape(gshape[0], gshape[1], 2).astype(np.float32)
    cell = 0.25 * s * s * lv.rate
    conf_nodes = np.clip(weights_node / cell, 0.0, 1.0).reshape(gshape).astype(np.float32)
    M = np.ascontiguousarray(T, dtype=np.float64)
    field_full = np.empty((h, w, 2), np.float32)
    conf = np.empty((h, w), np.float32)
    if _field_rows_jit is None:  # pragma: no cover - numba is a declared dependency
        _field_rows_py(M, grid, conf_nodes, f, s, field_full, conf, 0, 1)
    else:  # shared with the helper, or whole where this runs on the helper (refine_field)
        interleave(h * w, lambda first, stride: _field_rows_jit(M, grid, conf_nodes, f, s, field_full, conf,
                                                                first, stride), min_items=MIN_PIXELS)
    return _FullField(field_full, conf, grid)


#: Rows per block of :func:`_field_rows_py` (two threads take alternate blocks).
FIELD_BLOCK_ROWS = 16


def _cell_py(g, n):
    """The cell of grid coordinate ``g`` on an axis of ``n`` nodes, the edge nodes repeated beyond it:
    ``(i0, i1, a)``, the value there being ``(1 - a) v[i0] + a v[i1]``."""
    g = min(max(g, 0.0), n - 1.0)
    i0 = min(int(g), n - 2) if n > 1 else 0
    return i0, min(i0 + 1, n - 1), g - i0


def _field_rows_py(M, grid, conf_nodes, f, s, field, conf, first, stride):
    """The rows of blocks ``first``, ``first + stride``, ... (:data:`FIELD_BLOCK_ROWS` rows each) of the
    full-size field and confidence: ``field[y, x]`` = ``M (x, y, 1)`` (projected, rounded to float32, as
    :func:`~pcreg.registration.motion.field_from_matrix`) plus the grid (gh, gw, 2) interpolated
    bilinearly (float64, rounded to float32) where the pixel lies on it, ``(x - (f - 1) / 2) / (f s)``
    cells, the edge nodes repeated beyond it; ``conf[y, x]`` the nodes' confidence (gh, gw) interpolated
    there, 0 where the field leaves the image (outside ``[-0.5, w - 0.5]`` x ``[-0.5, h - 0.5]``, or NaN).
    The interpolation is separable: each row first interpolates the grid's rows (``(1 - a) g[y0] + a
    g[y1]``), then each pixel that row's nodes."""
    h, w = field.shape[0], field.shape[1]
    gh, gw = conf_nodes.shape[0], conf_nodes.shape[1]
    half = (f - 1.0) / 2.0
    cells = 1.0 / (f * s)
    xi0 = np.empty(w, np.int64)
    xi1 = np.empty(w, np.int64)
    xa = np.empty(w)
    for j in range(w):
        xi0[j], xi1[j], xa[j] = _cell((j - half) * cells, gw)
    row = np.empty((gw, 3))  # the grid's two channels and the confidence, interpolated at this row
    for b in range(first * FIELD_BLOCK_ROWS, h, stride * FIELD_BLOCK_ROWS):
        for i in range(b, min(b + FIELD_BLOCK_ROWS, h)):
            y = float(i)
            y0, y1, ay = _cell((y - half) * cells, gh)
            for k in range(gw):
                row[k, 0] = (1.0 - ay) * grid[y0, k, 0] + ay * grid[y1, k, 0]
                row[k, 1] = (1.0 - ay) * grid[y0, k, 1] + ay * grid[y1, k, 1]
                row[k, 2] = (1.0 - ay) * conf_nodes[y0, k] + ay * conf_nodes[y1, k]
            _field_row(M, y, field[i])  # the global part of the row first (field_from_matrix's), then the grid's
            for j in range(w):
                x0, x1, ax = xi0[j], xi1[j], xa[j]
                fx = field[i, j, 0] + np.float32((1.0 - ax) * row[x0, 0] + ax * row[x1, 0])
                fy = field[i, j, 1] + np.float32((1.0 - ax) * row[x0, 1] + ax * row[x1, 1])
                field[i, j, 0] = fx
                field[i, j, 1] = fy
                c = np.float32((1.0 - ax) * row[x0, 2] + ax * row[x1, 2])
                inside = (fx >= -0.5) & (fx <= w - 0.5) & (fy >= -0.5) & (fy <= h - 0.5)
                conf[i, j] = c if inside else np.float32(0.0)
    return field


try:
    from ..._jit import njit as _njit

    _cell = _njit(cache=True, nogil=True, inline="always")(_cell_py)
    # numpy's error model: a pixel on a projective transform's horizon divides by zero and gets inf or
    # NaN (and a confidence of 0), as field_from_matrix does, instead of raising
    _field_rows_jit = _njit(cache=True, nogil=True, error_model="numpy")(_field_rows_py)
except ImportError:  # pragma: no cover - numba is a declared dependency
    _cell, _field_rows_jit = _cell_py, None

