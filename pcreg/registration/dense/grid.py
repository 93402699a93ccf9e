"""The dense registration's control grid and its solver: bilinear weights of the samples on the grid,
the normal equations ``(B^T W B + alpha L + eps I) U = B^T W t`` with the membrane ``L`` (assembled and
solved by compiled code: sparse LU or Jacobi-preconditioned conjugate gradients), and the grid carried
from one pyramid level to the next."""

from __future__ import annotations

import math
from typing import Mapping

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..._threads import beside
from .robust import _robust_scale, _weigh_assemble


def _grid_shape(h: int, w: int, s: float) -> tuple[int, int]:
    return int(math.ceil((h - 1) / s)) + 1, int(math.ceil((w - 1) / s)) + 1


def _bilinear_weights(pts: np.ndarray, gshape: tuple[int, int], s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(cols (N, 4) int64, vals (N, 4) float64)``: the grid nodes (corners (i, j), (i, j + 1),
    (i + 1, j), (i + 1, j + 1) of each point's cell, ascending and distinct) and bilinear weights of
    points (level px) on a grid of spacing ``s``: the rows of :func:`_bilinear_matrix`."""
    gh, gw = gshape
    gx = np.clip(pts[:, 0] / s, 0.0, gw - 1.000001)
    gy = np.clip(pts[:, 1] / s, 0.0, gh - 1.000001)
    ix, iy = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
    fx, fy = gx - ix, gy - iy
    cols = np.stack([iy * gw + ix, iy * gw + ix + 1, (iy + 1) * gw + ix, (iy + 1) * gw + ix + 1], axis=1)
    vals = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    return cols, vals


def _bilinear_matrix(pts: np.ndarray, gshape: tuple[int, int], s: float) -> sp.csr_matrix:
    """(N, gh*gw) sparse bilinear weights of points (level px) on a grid of spacing ``s``."""
    cols, vals = _bilinear_weights(pts, gshape, s)
    n = len(pts)
    return sp.csr_matrix((vals.ravel(), (np.repeat(np.arange(n), 4), cols.ravel())), shape=(n, gshape[0] * gshape[1]))


class _NormalEquations:
    """The grid's normal equations ``(B^T W B + alpha L + eps I) U = B^T W t`` for fixed samples.

    ``B`` has four bilinear weights per sample (the corners of its grid cell), so ``B^T W B`` couples
    a node with its 8 neighbours only: the matrix has 9 diagonals (offsets 0, +-1, +-gw, +-(gw +- 1))
    and each iteration scatters the samples' weights into them with ``np.bincount`` before the
    sparse LU solve (the membrane L uses 5 of the same diagonals).
    """

    def __init__(self, pts: np.ndarray, gshape: tuple[int, int], s: float,
                 edge_weights: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.cols, self.vals = _bilinear_weights(pts, gshape, s)
        gh, gw = gshape
        m = self.m = gh * gw
        self.offsets = np.array([0, 1, -1, gw, -gw, gw + 1, -(gw + 1), gw - 1, -(gw - 1)])
        where = {int(o): k for k, o in enumerate(self.offsets)}
        # (corner p, corner q) -> diagonal of offset idx(q) - idx(p); corners (i,j), (i,j+1), (i+1,j), (i+1,j+1)
        corner = np.array([0, 1, gw, gw + 1])
        self.pairs = [(p, q, where[int(corner[q] - corner[p])]) for p in range(4) for q in range(4)]
        self.pair_k = np.array([[where[int(corner[q] - corner[p])] for q in range(4)] for p in range(4)], np.int64)
        self.offsets = self.offsets.astype(np.int64)
        # membrane: weighted node degree on the main diagonal, -weight on the 4-neighbour edges
        wh = np.ones((gh, gw - 1)) if edge_weights is None else edge_weights[0]
        wv = np.ones((gh - 1, gw)) if edge_weights is None else edge_weights[1]
        idx = np.arange(m).reshape(gh, gw)
        lap = np.zeros((len(self.offsets), m))
        deg = np.zeros((gh, gw))
        deg[:, :-1] += wh
        deg[:, 1:] += wh
        deg[:-1, :] += wv
        deg[1:, :] += wv
        lap[0] = deg.ravel()
        # dia storage: data[k, c] holds A[c - offset, c]
        lap[where[1], idx[:, 1:].ravel()] = -wh.ravel()
        lap[where[-1], idx[:, :-1].ravel()] = -wh.ravel()
        lap[where[gw], idx[1:, :].ravel()] = -wv.ravel()
        lap[where[-gw], idx[:-1, :].ravel()] = -wv.ravel()
        self.lap = lap

    def interpolate(self, U: np.ndarray) -> np.ndarray:
        """(N, 2) ``B U`` (each sample's four corners summed in order, as ``np.einsum`` does)."""
        out = np.empty((self.cols.shape[0], 2))
        return _interpolate(self.cols, self.vals, np.ascontiguousarray(U, dtype=np.float64), out)

    def solve(self, w: np.ndarray, target: np.ndarray, alpha: float, eps: float, x0: np.ndarray | None = None,
              *, maxiter: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(U (M, 2), node data weights (M,))``: sparse LU, or with ``maxiter`` > 0 at most that many
        Jacobi-preconditioned conjugate-gradient steps from ``x0`` (an inexact step of the ICP), both
        compiled with numba where it is installed (the same arithmetic as scipy's ``cg``)."""
        data, rhs, node_w = self._blank(alpha, eps)
        _assemble(self.cols, self.vals, np.ascontiguousarray(w, dtype=np.float64),
                  np.ascontiguousarray(target, dtype=np.float64), self.pair_k, data, rhs, node_w)
        return self._solve(data, rhs, x0, maxiter), node_w

    def robust_step(self, matches: np.ndarray, positions: np.ndarray, start: np.ndarray, sigma: float,
                    alpha: float, eps: float, x0: np.ndarray, *, maxiter: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, float, float, int] | None:
        """One step of the dense ICP from :func:`match_window`'s ``matches`` (N, 4) found at
        ``positions`` (N, 2), the samples' global positions ``start`` (N, 2) and the level's noise
        ``sigma``: the mutual matches weighted by Tukey's biweight (:func:`_robust_scale`), each weighted
        match's target ``match - start`` scattered into the equations in the same compiled pass as its
        weight (:func:`_weigh_assemble_py`; the same sums as :meth:`solve` with those weights), then
        solved as :meth:`solve` does.

        Returns ``(U, node data weights, sum of weights, sum of weight x squared residual (level px^2),
        samples with a weight)``, or None when no sample got a weight (the field stays as it is)."""
        m = np.ascontiguousarray(matches, dtype=np.float64)
        data, rhs, node_w = self._blank(alpha, eps)
        wts, wres = np.zeros(len(m)), np.zeros(len(m))
        inliers = _weigh_assemble(m, np.ascontiguousarray(positions, dtype=np.float64),
                                  np.ascontiguousarray(start, dtype=np.float64), _robust_scale(m, float(sigma)),
                                  self.cols, self.vals, self.pair_k, data, rhs, node_w, wts, wres)
        if inliers == 0:
            return None
        # summed by numpy (pairwise), as the weights and residuals were before they were compiled
        return self._solve(data, rhs, x0, maxiter), node_w, float(wts.sum()), float(wres.sum()), inliers

    def _blank(self, alpha: float, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The membrane's diagonals times ``alpha``, ``eps`` added to the main one, and a zero right-hand
        side and node weights: what the samples are scattered into."""
        data = alpha * self.lap
        data[0] += eps
        return data, np.zeros((self.m, 2)), np.zeros(self.m)

    def _solve(self, data: np.ndarray, rhs: np.ndarray, x0: np.ndarray | None, maxiter: int) -> np.ndarray:
        if maxiter <= 0 or x0 is None:
            offsets = self.offsets
            if len(np.unique(offsets)) < len(offsets):  # two nodes a row: gw - 1 is 1, one diagonal twice
                offsets, which = np.unique(self.offsets, return_inverse=True)
                merged = np.zeros((len(offsets), self.m))
                np.add.at(merged, which, data)
                data = merged
            A = sp.dia_matrix((data, offsets), shape=(self.m, self.m)).tocsc()
            return spla.splu(A).solve(rhs)
        out = np.empty_like(rhs)

        def column(c: int) -> None:  # the two columns are independent systems with the same matrix
            out[:, c] = _cg_dia(data, self.offsets, np.ascontiguousarray(rhs[:, c]),
                                np.array(x0[:, c], dtype=np.float64), int(maxiter), 1e-4)

        first = beside(lambda: column(0))
        column(1)
        first()
        return out


def _assemble_py(cols, vals, w, target, pair_k, data, rhs, node_w):
    """Scatter the samples into the 9 diagonals of ``B^T W B`` (``data[k, c] += w v_p v_q`` at column
    ``c = cols[q]``), into ``B^T W t`` and into the nodes' data weights."""
    n = cols.shape[0]
    for i in range(n):
        wi = w[i]
        if wi == 0.0:
            continue
        for p in range(4):
            a = cols[i, p]
            wv = wi * vals[i, p]
            node_w[a] += wv
            rhs[a, 0] += wv * target[i, 0]
            rhs[a, 1] += wv * target[i, 1]
            for q in range(4):
                data[pair_k[p, q], cols[i, q]] += wv * vals[i, q]


def _interpolate_py(cols, vals, U, out):
    """``out[i] = sum_k vals[i, k] U[cols[i, k]]``, the corners in order: (N, 2) ``B U``."""
    n = cols.shape[0]
    for i in range(n):
        for c in range(2):
            s = 0.0
            for k in range(4):
                s += vals[i, k] * U[cols[i, k], c]
            out[i, c] = s
    return out


def _cg_dia_py(data, offsets, b, x, maxiter, rtol):
    """Jacobi-preconditioned conjugate gradients on a matrix in DIA storage (``A[c - offsets[k], c] =
    data[k, c]``), from ``x``, until ``|r| <= rtol |b|`` or ``maxiter`` steps (scipy's ``cg`` rule)."""
    m = b.shape[0]
    nd = offsets.shape[0]

    def matvec(v, out):
        for r in range(m):
            out[r] = 0.0
        for k in range(nd):
            off = offsets[k]
            lo = max(0, -off)
            hi = min(m, m - off)
            for r in range(lo, hi):
                c = r + off
                out[r] += data[k, c] * v[c]

    Ax = np.empty(m)
    matvec(x, Ax)
    r = b - Ax
    bnorm = math.sqrt(float(np.dot(b, b)))
    tol = rtol * bnorm
    if bnorm == 0.0:
        return np.zeros(m)
    z = r / data[0]
    pvec = z.copy()
    rz = float(np.dot(r, z))
    Ap = np.empty(m)
    for _ in range(maxiter):
        if math.sqrt(float(np.dot(r, r))) <= tol:
            break
        matvec(pvec, Ap)
        alpha = rz / float(np.dot(pvec, Ap))
        # in place, element by element: the operations of x += alpha p, r -= alpha Ap, z = r / diag and
        # p = z + beta p without a temporary array each (0.85 of the time, the same numbers)
        for i in range(m):
            x[i] += alpha * pvec[i]
            r[i] -= alpha * Ap[i]
            z[i] = r[i] / data[0, i]
        rz_new = float(np.dot(r, z))
        beta = rz_new / rz
        for i in range(m):
            pvec[i] = z[i] + beta * pvec[i]
        rz = rz_new
    return x


try:
    from ..._jit import njit as _njit

    _assemble = _njit(cache=True, nogil=True)(_assemble_py)
    _cg_dia = _njit(cache=True, nogil=True)(_cg_dia_py)
    _interpolate = _njit(cache=True, nogil=True)(_interpolate_py)
except ImportError:  # pragma: no cover - numba is a declared dependency
    _assemble, _cg_dia, _interpolate = _assemble_py, _cg_dia_py, _interpolate_py


def _edge_weights(img: np.ndarray, gshape: tuple[int, int], s: float) -> tuple[np.ndarray, np.ndarray]:
    """Image-driven membrane weights: ``1 / (1 + (d / 2 tau)^2)`` per grid edge (Perona & Malik 1990's
    diffusivity), ``d`` the colour difference between the two nodes in the moving image blurred to the
    grid's scale and ``tau`` its robust spread over all edges (1.4826 x median). Motion is smooth within
    a surface and jumps at its outline, which is where colour changes: the field may bend there."""
    gh, gw = gshape
    blur = cv2.GaussianBlur(img, (0, 0), 0.5 * s)
    h, w = img.shape[:2]
    ys = np.clip(np.rint(np.arange(gh) * s), 0, h - 1).astype(np.intp)
    xs = np.clip(np.rint(np.arange(gw) * s), 0, w - 1).astype(np.intp)
    c = blur[ys][:, xs].astype(np.float64)
    dh = np.linalg.norm(c[:, 1:] - c[:, :-1], axis=2)
    dv = np.linalg.norm(c[1:, :] - c[:-1, :], axis=2)
    tau = 1.4826 * float(np.median(np.concatenate([dh.ravel(), dv.ravel()])))
    tau = max(tau, 1e-3)
    return 1.0 / (1.0 + (dh / (2 * tau)) ** 2), 1.0 / (1.0 + (dv / (2 * tau)) ** 2)


def _membrane(gshape: tuple[int, int]) -> sp.csr_matrix:
    """Graph Laplacian of the grid's 4-neighbour edges: ``U^T L U = sum_(a,b) |U_a - U_b|^2``."""
    gh, gw = gshape
    idx = np.arange(gh * gw).reshape(gh, gw)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    m = len(a)
    D = sp.csr_matrix((np.concatenate([np.ones(m), -np.ones(m)]), (np.tile(np.arange(m), 2), np.concatenate([a, b]))),
                      shape=(m, gh * gw))
    return (D.T @ D).tocsr()


def _read_only(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays, made read-only (a cache hands the same ones to every caller)."""
    for a in arrays:
        a.setflags(write=False)
    return arrays


#: Grid weights made once and handed to the registrations that share the shapes they depend on
#: (:func:`grid_weights`, kept by a prepared reference), by :func:`_upsample_key` / :func:`_level_key`.
GridWeights = Mapping[tuple, tuple[np.ndarray, ...]]


def _upsample_key(old_shape: tuple[int, int], old_s: float, new_shape: tuple[int, int], new_s: float,
                  factor: float) -> tuple:
    return ("upsample", tuple(old_shape), float(old_s), tuple(new_shape), float(new_s), float(factor))


def _upsample_weights(old_shape: tuple[int, int], old_s: float, new_shape: tuple[int, int], new_s: float,
                      factor: float) -> tuple[np.ndarray, ...]:
    """Read-only bilinear ``(cols, vals)`` of :func:`_upsample_grid`'s new nodes on the old grid. They
    depend on the shapes alone, so a prepared reference (a stream's key frame, whose registrations keep
    their levels' shapes) makes them once (:func:`grid_weights`)."""
    gh, gw = new_shape
    ys, xs = np.mgrid[0:gh, 0:gw].astype(np.float64)
    # new node (level l) at x_l = j s_new; in level l + 1 pixels: (x_l - 0.5) / 2
    pts = np.column_stack([((xs * new_s - 0.5) / factor).ravel(), ((ys * new_s - 0.5) / factor).ravel()])
    return _read_only(*_bilinear_weights(pts, old_shape, old_s))


def _upsample_grid(U: np.ndarray, old_shape: tuple[int, int], old_s: float, new_shape: tuple[int, int],
                   new_s: float, factor: float, known: GridWeights | None = None) -> np.ndarray:
    """Grid displacements on a finer level: the old grid interpolated at the new nodes, times ``factor``.
    Node positions are in their own level's pixels; ``factor`` is the level scale (2). ``known``: weights
    made before (:func:`grid_weights`), used where they hold these shapes."""
    key = _upsample_key(old_shape, old_s, new_shape, new_s, factor)
    cols, vals = known[key] if known and key in known else _upsample_weights(*key[1:])
    return factor * _interpolate(cols, vals, np.ascontiguousarray(U, dtype=np.float64), np.empty((len(cols), 2)))


def _level_key(finest_shape: tuple[int, int], finest: int, gshape: tuple[int, int], f: float, spacing: float) -> tuple:
    return ("level", tuple(finest_shape), int(finest), tuple(gshape), float(f), float(spacing))


def _level_weights(finest_shape: tuple[int, int], finest: int, gshape: tuple[int, int], f: float,
                   spacing: float) -> tuple[np.ndarray, ...]:
    """Read-only bilinear ``(cols, vals)`` of the nodes (``gshape``, spacing ``spacing``) of a level of
    scale ``f`` on the finest level's grid (``finest_shape``): where an earlier registration's grid
    starts this level (:func:`~pcreg.registration.dense.coarse_to_fine._grid_at_level`). Made once for a
    prepared reference, as :func:`_upsample_weights`."""
    gh, gw = gshape
    ys, xs = np.mgrid[0:gh, 0:gw].astype(np.float64)
    F = float(2 ** finest)

    def on_finest(v: np.ndarray) -> np.ndarray:
        # a node at x_l = j s of its level lies at x_0 = f x_l + (f - 1) / 2 at full size, and at
        # (x_0 - (F - 1) / 2) / F on the finest level
        return ((f * v * spacing + (f - 1) / 2.0) - (F - 1) / 2.0) / F

    pts = np.column_stack([on_finest(xs).ravel(), on_finest(ys).ravel()])
    return _read_only(*_bilinear_weights(pts, finest_shape, spacing))


def grid_weights(level_shapes: list[tuple[int, int]], spacing: float, finest: int) -> GridWeights:
    """Every grid weight a registration on levels of these (h, w) shapes (index = level) makes, with
    grid ``spacing`` and finest level ``finest``: the upsampling from each level to the next finer, and
    each level's nodes on the finest level's grid. Read-only: a prepared reference keeps them for all of
    its registrations, which use them where their options give the same grids."""
    s = float(spacing)
    gshapes = [_grid_shape(h, w, s) for h, w in level_shapes]
    made: dict[tuple, tuple[np.ndarray, ...]] = {}
    for level in range(finest, len(gshapes)):
        if level + 1 < len(gshapes):
            key = _upsample_key(gshapes[level + 1], s, gshapes[level], s, 2.0)
            made[key] = _upsample_weights(*key[1:])
        key = _level_key(gshapes[finest], finest, gshapes[level], float(2 ** level), s)
        made[key] = _level_weights(*key[1:])
    return made
