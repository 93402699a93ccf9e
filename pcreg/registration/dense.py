"""Dense (non-rigid) registration of two images as 2-D colour clouds.

A global registration (:func:`pcreg.register`, similarity or projective) is refined into a smooth
displacement field by a non-rigid ICP, coarse to fine:

- **Clouds.** At each pyramid level the reference cloud is every pixel of the reference image, each a
  point ``(x, y, lam * colour)``; the moving cloud is every moving pixel with texture (gradient above
  the image's noise), so flat areas and edges alike carry samples, not edges alone.
- **Field.** Displacements ``U`` (M, 2) on a control grid of spacing ``grid_spacing`` pixels of the
  level, interpolated bilinearly: a moving point ``p`` lands at ``G(p) + B(p) U`` (``G`` the global
  transform, ``B`` (N, M) sparse bilinear weights). This is the free-form deformation of Rueckert et
  al. (1999, "Nonrigid registration using free-form deformations", IEEE TMI 18(8)) with first-order
  (bilinear) instead of cubic B-splines. From one level to the next the grid is interpolated and its
  displacements doubled; every level keeps the same spacing in its own pixels, so the field gets finer
  as the images do.
- **Colour.** Matching uses each level's texture part (the image minus its 4-pixel Gaussian blur, with
  a twentieth of the blur kept; Wedel et al. 2009's structure-texture split), so brightness, colour
  temperature, shadows and haze that change between frames are not read as motion.
- **Correspondences.** Each moving point's nearest neighbour in ``(x, y, lam * colour)`` among the
  reference pixels within a gate of ``radius`` pixels of the level around where the field puts it
  (an exact search over the window, compiled with numba), refined to sub-pixel by a Gauss-Newton
  step on the same cost with the reference colour linearised (Park, Zhou & Koltun 2017). The gate is ``radius * 2^level`` full-resolution
  pixels: wide at the coarsest level, narrow at the finest.
- **Robust weights.** A match gets weight 0 when it has no partner: its best candidate lies on the
  window's rim (the true partner may be outside the gate: occlusion or a motion beyond the gate) or it
  is not mutual (the reference point's own nearest moving pixel, searched back, is more than a pixel
  from the point; Zhang 1994's consistency test). The others get Tukey's biweight of their colour
  distance with a scale from its median absolute deviation (Huber and Tukey robust ICP weights).
- **Step.** The grid minimises ``sum_i w_i |B_i U - t_i|^2 + alpha * sum_(a,b) |U_a - U_b|^2`` over
  the grid's 4-neighbour edges (a membrane, as the smoothness term of Horn & Schunck 1981), with
  ``t_i`` the matched reference point minus ``G(p_i)``: a sparse symmetric positive definite system
  ``(B^T W B + alpha L + eps I) U = B^T W t`` solved with ``scipy.sparse`` (conjugate gradients
  warm-started from the last field, an inexact step inside the ICP loop, or an exact LU). ``eps`` is a tiny pull
  towards the global transform, so that a grid region without any evidence keeps it.
- **Stiffness.** ``alpha`` is a ratio of variances, as in a Gaussian prior on the field (the
  Bayesian reading of the membrane): a match is good to about ``sigma_m = 1`` pixel of its level (the
  reference cloud is the pixel grid), and neighbouring nodes, ``s`` pixels apart, may differ by
  ``sigma_s = strain * s`` pixels, ``strain`` the largest plausible motion gradient (default 0.25: a
  quarter of a pixel per pixel, the parallax of a ground plane next to a facade when a car drives a
  metre forward). So ``alpha = sigma_m^2 / sigma_s^2 = 1 / (strain * s)^2`` per unit sample weight,
  independent of the image and of its content. It is multiplied by the schedule of Amberg, Romdhani
  & Vetter (2007, "Optimal Step Nonrigid ICP Algorithms for Surface Registration", CVPR): stiff
  first (8, 4, 2, then 1 for the remaining iterations of each level), so the first steps move the
  field as a whole and the last ones let it bend.
- **Colour weight.** ``lam = 1 / (sqrt(6) sigma)`` with ``sigma`` the image noise of each level
  (Immerkaer 1996, "Fast noise variance estimation", from the Laplacian): a colour difference that
  two noisy pixels of the same point show (3 channels, two noisy pixels: ``6 sigma^2``) costs as much
  as one pixel of distance.

The field is returned at full resolution as (H, W, 2) float32 reference coordinates of every moving
pixel, with a per-pixel confidence in [0, 1]: the samples' weight near each pixel (1 where a grid cell
holds as many inlier samples as a quarter of its pixels), 0 where the field leaves the reference
image. Where there is no texture the field is the smooth interpolation of its surroundings, or the
global transform, and its confidence is low.
"""

from __future__ import annotations

import functools
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._threads import MIN_PIXELS, beside, interleave, wait_quietly
from ..errors import InputError, RegistrationError
from .clouds import magnitude, valid_region
from .motion import _field_row, field_from_matrix
from .result import RegistrationResult
from ..validation import check_bool, check_float, check_floats, check_int


__all__ = ["DenseRegistrationResult", "DenseIteration", "refine_field", "dense_options", "field_from_matrix",
           "match_window", "STIFFNESS_SCHEDULE", "DENSE_STAGES", "DenseOptions"]

#: Stiffness per iteration of a level (Amberg et al. 2007: stiff to relaxed); the last value repeats.
STIFFNESS_SCHEDULE: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
#: The global step of the dense model: a similarity (rotation, shift and the zoom of forward motion).
DENSE_GLOBAL_MODEL = "similarity"
#: Tukey's biweight constant (95% efficiency under Gaussian noise).
TUKEY_C = 4.685


@dataclass(frozen=True, repr=False)
class DenseIteration:
    """One iteration of the dense ICP, handed to the optional callback.

    level : pyramid level; iteration : index within the level; stiffness : the schedule's value;
    points : (N,) moving samples; inliers : how many got a non-zero weight; rms : weighted RMS of the
    match residuals (full-resolution px); grid : (gh, gw, 2) displacements (full-resolution px) of the
    control grid from the global transform.
    """

    level: int
    iteration: int
    stiffness: float
    points: int
    inliers: int
    rms: float
    grid: np.ndarray

    def __repr__(self) -> str:
        return (f"DenseIteration(level={self.level}, iteration={self.iteration}, stiffness={self.stiffness:g}, "
                f"points={self.points}, inliers={self.inliers}, rms={self.rms:.3g})")


@dataclass(frozen=True, repr=False)
class DenseRegistrationResult:
    """A dense registration: the global transform and the field that refines it.

    matrix : (3, 3) float64 global ``T_ref_mov`` (the start of the dense step).
    field : (H, W, 2) float32 reference coordinates (x, y) of every moving pixel.
    confidence : (H, W) float32 in [0, 1]: evidence behind the field at each pixel.
    global_result : the :class:`~pcreg.registration.result.RegistrationResult` of the global step.
    fitness : share of the finest level's samples matched with a non-zero weight.
    inlier_rmse : weighted RMS of their residuals after the last step (full-resolution px).
    iterations : dense iterations run (all levels). seconds : wall time, global step included (a given
        global result's own ``seconds`` added).
    grid : (gh, gw, 2) float32 displacements (full-resolution px) of the finest level's control grid
        from the global transform: the field is the global transform plus their bilinear interpolation.
        A later registration of the same reference can start from it (``initial`` of
        :func:`pcreg.register_dense`).
    """

    matrix: np.ndarray
    field: np.ndarray
    confidence: np.ndarray
    global_result: RegistrationResult
    fitness: float
    inlier_rmse: float
    iterations: int
    seconds: float
    backend: str = "reference"
    converged: bool = True
    grid: np.ndarray | None = None
    info: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for name in ("matrix", "field", "confidence", "grid"):
            if getattr(self, name) is None:
                continue
            a = np.array(getattr(self, name), copy=True)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def T_ref_mov(self) -> np.ndarray:
        """(3, 3) the global ``T_ref_mov`` (``matrix``) the field refines."""
        return self.matrix

    @property
    def displacement(self) -> np.ndarray:
        """(H, W, 2) float32: the field minus the global transform (full-resolution px)."""
        return self.field - field_from_matrix(self.matrix, self.field.shape[:2])

    def __repr__(self) -> str:
        h, w = self.field.shape[:2]
        return (f"DenseRegistrationResult(field={w}x{h}, fitness={self.fitness:.4f}, "
                f"inlier_rmse={self.inlier_rmse:.4g}, iterations={self.iterations}, "
                f"mean_confidence={float(self.confidence.mean()):.3f}, seconds={self.seconds:.4f}, "
                f"global={self.global_result!r})")

    def to_dict(self) -> dict:
        """JSON-ready summary (the arrays are left out; ``matrix`` is the global transform)."""
        d = self.global_result.to_dict()
        disp = np.linalg.norm(self.displacement, axis=2)
        d.update(model="dense", dense_fitness=float(self.fitness), dense_inlier_rmse=float(self.inlier_rmse),
                 dense_iterations=int(self.iterations), seconds=float(self.seconds),
                 global_seconds=float(self.global_result.seconds),
                 mean_confidence=float(self.confidence.mean()),
                 median_displacement=float(np.median(disp)), max_displacement=float(disp.max()),
                 evidence=float(self.info.get("evidence", float("nan"))))
        return d


# ---------------------------------------------------------------------------------------------------
# the compiled windowed nearest-neighbour search
# ---------------------------------------------------------------------------------------------------

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
    from .._jit import njit

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


# ---------------------------------------------------------------------------------------------------
# the grid
# ---------------------------------------------------------------------------------------------------

#: ``v / 255`` in float32 for every 8-bit value v.
_UNIT_LUT = (np.arange(256, dtype=np.float32) / 255.0).reshape(1, 256, 1)


def _unit_float(img: np.ndarray) -> np.ndarray:
    """A uint8 image as float32 in [0, 1]: ``img.astype(np.float32) / 255`` looked up in a 256-entry
    table (the same numbers, a tenth of the time at 640x480)."""
    return cv2.LUT(np.ascontiguousarray(img), _UNIT_LUT)


def _noise_sigma(gray: np.ndarray) -> float:
    """Immerkaer (1996) noise standard deviation of a [0, 1] float image from its Laplacian-difference filter."""
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(gray, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1]
    h, w = gray.shape
    return float(np.sqrt(np.pi / 2.0) * np.abs(r).sum() / (6.0 * max(w - 2, 1) * max(h - 2, 1)))


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
            A = sp.dia_matrix((data, self.offsets), shape=(self.m, self.m)).tocsc()
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
    from .._jit import njit as _njit

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


@functools.lru_cache(maxsize=32)
def _upsample_weights(old_shape: tuple[int, int], old_s: float, new_shape: tuple[int, int], new_s: float,
                      factor: float) -> tuple[np.ndarray, ...]:
    """Read-only bilinear ``(cols, vals)`` of :func:`_upsample_grid`'s new nodes on the old grid. They
    depend on the shapes alone, so the frames of a stream, whose levels keep their shapes, make them once."""
    gh, gw = new_shape
    ys, xs = np.mgrid[0:gh, 0:gw].astype(np.float64)
    # new node (level l) at x_l = j s_new; in level l + 1 pixels: (x_l - 0.5) / 2
    pts = np.column_stack([((xs * new_s - 0.5) / factor).ravel(), ((ys * new_s - 0.5) / factor).ravel()])
    return _read_only(*_bilinear_weights(pts, old_shape, old_s))


def _upsample_grid(U: np.ndarray, old_shape: tuple[int, int], old_s: float, new_shape: tuple[int, int],
                   new_s: float, factor: float) -> np.ndarray:
    """Grid displacements on a finer level: the old grid interpolated at the new nodes, times ``factor``.
    Node positions are in their own level's pixels; ``factor`` is the level scale (2)."""
    cols, vals = _upsample_weights(tuple(old_shape), float(old_s), tuple(new_shape), float(new_s), float(factor))
    return factor * _interpolate(cols, vals, np.ascontiguousarray(U, dtype=np.float64), np.empty((len(cols), 2)))


def _level_matrix(T: np.ndarray, level: int) -> np.ndarray:
    """A full-resolution 3x3 transform expressed in the coordinates of pyramid level ``level``
    (x_l = (x_0 - (2^l - 1) / 2) / 2^l)."""
    f = float(2 ** level)
    S = np.array([[1 / f, 0, -(f - 1) / (2 * f)], [0, 1 / f, -(f - 1) / (2 * f)], [0, 0, 1]])
    return S @ np.asarray(T, dtype=np.float64) @ np.linalg.inv(S)


def _apply(M: np.ndarray, p: np.ndarray) -> np.ndarray:
    den = p[:, 0] * M[2, 0] + p[:, 1] * M[2, 1] + M[2, 2]
    return np.column_stack([(p @ M[0, :2] + M[0, 2]) / den, (p @ M[1, :2] + M[1, 2]) / den])


def _samples(img: np.ndarray, sigma: float, *, max_points: int, seed: int, valid: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """Textured moving pixels of one level: gradient magnitude above 3 noise standard deviations of
    the Sobel response (and above a 2-grey-level step), a one-pixel frame dropped."""
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag = magnitude(gx, gy)
    thr = max(3.0 * math.sqrt(12.0) * sigma, 8.0 / 255.0)
    keep = mag > thr
    keep[[0, -1], :] = False
    keep[:, [0, -1]] = False
    if valid is not None:
        keep &= valid
    # the kept pixels' flat indices in row order, split into rows and columns once drawn: the same
    # pixels as np.nonzero's two index arrays in a fifth of the time (0.36 -> 0.08 ms for the 45,000
    # pixels of a 320x240 CamVid level)
    flat = np.flatnonzero(keep)
    rate = 1.0
    if flat.size > max_points:
        rate = max_points / flat.size
        flat = flat[np.sort(np.random.default_rng(seed).choice(flat.size, size=max_points, replace=False))]
    ys, xs = np.divmod(flat, keep.shape[1])
    return np.column_stack([xs, ys]).astype(np.float64), img[ys, xs].astype(np.float32), rate


def _texture(img: np.ndarray, sigma: float, structure: float = 0.05) -> np.ndarray:
    """The texture part of an image, ``I - (1 - structure) G_sigma * I`` (the structure-texture split of
    Wedel et al. 2009, "An improved algorithm for TV-L1 optical flow", keeping a twentieth of the
    structure). It removes what varies slowly across the image: brightness and colour-temperature
    changes, drifting shadows, haze, which colour matching would otherwise read as motion. With
    ``sigma`` of one pixel of the level, each pyramid level would match its own octave of detail
    alone (the band of a Laplacian pyramid, Burt & Adelson 1983); the default, 4 pixels, keeps two
    octaves more, the colour of a pole or a road marking as well as its edges, and still removes what
    varies over tens of pixels (see ``texture`` in :func:`pcreg.register_dense` for the measurements)."""
    return (img - (1.0 - structure) * cv2.GaussianBlur(img, (0, 0), sigma)).astype(np.float32)


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
    from .._jit import njit as _njit

    _mutual_distances = _njit(cache=True, nogil=True)(_mutual_distances_py)
    _weigh_assemble = _njit(cache=True, nogil=True)(_weigh_assemble_py)
except ImportError:  # pragma: no cover - numba is a declared dependency
    _mutual_distances, _weigh_assemble = _mutual_distances_py, _weigh_assemble_py


# ---------------------------------------------------------------------------------------------------
# the dense registration
# ---------------------------------------------------------------------------------------------------

#: Stages of :func:`pcreg.register_dense` timed in its result's ``info["times"]`` (seconds): pyramids,
#: noise, samples and the normal equations' set-up per level; the samples' positions under the field
#: and the windowed correspondence search; the robust weights and the grid's solve; the plausibility
#: figure; the field and its confidence at full resolution. The global step is the result's
#: ``global_result.seconds``.
DENSE_STAGES: tuple[str, ...] = ("pyramid", "search", "solve", "evidence", "field")


class _StageClock:
    """Seconds per stage: each :meth:`lap` charges the time since the last one to the stage named."""

    def __init__(self) -> None:
        self.times = dict.fromkeys(DENSE_STAGES, 0.0)
        self._t = time.perf_counter()

    def lap(self, stage: str) -> None:
        t = time.perf_counter()
        self.times[stage] += t - self._t
        self._t = t


def _plausibility(R, Mv, P, C, GP, NE, lam, radius, U) -> float:
    """The field's evidence against chance: the median colour distance of the samples' matches with
    every sample moved by half the image (wrapped onto unrelated content of the same images), divided
    by the same median under the final field. About 1 for unrelated images (1.02-1.21 measured on
    noise and on frames of different CamVid clips), 1.3-3.3 for neighbouring frames of one clip."""
    h, w = R.shape[:2]
    X = GP + NE.interpolate(U)
    # the colour distances alone: no mutual test (the same distances, half the search)
    m = match_window(R, Mv, P, X, C, radius=radius, lam=lam, mutual=False)
    Xc = np.column_stack([np.mod(X[:, 0] + 0.5 * w, w), np.mod(X[:, 1] + 0.5 * h, h)])
    mc = match_window(R, Mv, P, Xc, C, radius=radius, lam=lam, mutual=False)
    return float(_nan_median(mc[:, 2]) / max(float(_nan_median(m[:, 2])), 1e-9))


@dataclass(frozen=True)
class DenseOptions:
    """The dense step's options of :func:`pcreg.register_dense`, checked (see its docstring for each)."""

    levels: int = 5
    finest_level: int = 1
    iterations: int = 8
    grid_spacing: float = 8.0
    radius: int = 3
    fine_radius: int = 2
    max_points: int = 10000
    stiffness: tuple[float, ...] = STIFFNESS_SCHEDULE
    strain: float = 0.25
    edge_aware: bool = False
    cg_iterations: int = 30
    texture: float | None = 4.0
    chance_factor: float | None = None


def dense_options(shape: tuple[int, ...], *, levels, finest_level, iterations, grid_spacing, radius, fine_radius,
                  max_points, stiffness, strain, edge_aware, cg_iterations, texture,
                  chance_factor) -> DenseOptions:
    """The options checked, in the order their errors are reported (images of ``shape``)."""
    levels = check_int(levels, "levels", lo=1, hi=8)
    finest_level = check_int(finest_level, "finest_level", lo=0, hi=levels - 1)
    iterations = check_int(iterations, "iterations", lo=1, hi=100_000)
    radius = check_int(radius, "radius", lo=1, hi=64)
    fine_radius = check_int(fine_radius, "fine_radius", lo=1, hi=64)
    max_points = check_int(max_points, "max_points", lo=16)
    grid_spacing = check_float(grid_spacing, "grid_spacing", lo=2, hi=max(shape[:2]))
    cg_iterations = check_int(cg_iterations, "cg_iterations", lo=0, hi=100_000)
    stiffness = check_floats(stiffness, "stiffness", lo=0, lo_open=True)
    if not stiffness:
        raise InputError("stiffness must be a non-empty sequence of positive numbers")
    strain = check_float(strain, "strain", lo=0, lo_open=True, hi=100)
    edge_aware = check_bool(edge_aware, "edge_aware")
    if texture is not None:
        texture = check_float(texture, "texture", lo=0, lo_open=True, hi=max(shape[:2]))
    if chance_factor is not None:
        chance_factor = check_float(chance_factor, "chance_factor", lo=0)
    return DenseOptions(levels=levels, finest_level=finest_level, iterations=iterations, grid_spacing=grid_spacing,
                        radius=radius, fine_radius=fine_radius, max_points=max_points, stiffness=stiffness,
                        strain=strain, edge_aware=edge_aware, cg_iterations=cg_iterations, texture=texture,
                        chance_factor=chance_factor)


def _coarsest_level(shape: tuple[int, ...], options: DenseOptions) -> int:
    """The coarsest pyramid level worked at: ``levels - 1``, or finer where the image would be under 16 px."""
    coarsest = options.levels - 1
    while coarsest > options.finest_level and min(shape[:2]) >> coarsest < 16:
        coarsest -= 1
    return coarsest


@dataclass(frozen=True)
class _Pyramids:
    """Both images as float32 RGB in [0, 1] per level (0 = full size), and their valid (unpadded) masks."""

    reference: list[np.ndarray]
    moving: list[np.ndarray]
    reference_valid: list[np.ndarray]
    moving_valid: list[np.ndarray]


def _pyramid(img: np.ndarray, coarsest: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """One image as float32 RGB in [0, 1] per level 0 .. ``coarsest``, and its valid masks."""
    pyr, val = [_unit_float(img)], [valid_region(img)]
    for _ in range(coarsest):
        pyr.append(cv2.pyrDown(pyr[-1]))
        val.append(cv2.resize(val[-1].astype(np.uint8), pyr[-1].shape[1::-1], interpolation=cv2.INTER_NEAREST) > 0)
    return pyr, val


class _LastReference:
    """The pyramid of the last reference image seen, reused while the next one is the same image: a
    stream registers every frame to one key frame. Whether it is the same is decided by comparing every
    byte (a tenth of a millisecond at 640x480 against 1.5 ms for the pyramid), never by identity or a
    hash, so an image changed in place is never mistaken for the one before."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._image: np.ndarray | None = None
        self._levels: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])

    def pyramid(self, img: np.ndarray, coarsest: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
        with self._lock:
            image, (pyr, val) = self._image, self._levels
        if image is None or image.shape != img.shape or len(pyr) <= coarsest or not np.array_equal(image, img):
            pyr, val = _pyramid(img, coarsest)
            _read_only(*pyr, *val)  # shared by later registrations: nobody writes into them
            with self._lock:
                self._image, self._levels = img.copy(), (pyr, val)
        return pyr[:coarsest + 1], val[:coarsest + 1]


_LAST_REFERENCE = _LastReference()


def _pyramids(ref: np.ndarray, mov: np.ndarray, coarsest: int) -> _Pyramids:
    """Both images' pyramids to level ``coarsest`` (the reference's reused from the last call when it is
    the same image)."""
    pyr_r, val_r = _LAST_REFERENCE.pyramid(ref, coarsest)
    pyr_m, val_m = _pyramid(mov, coarsest)
    return _Pyramids(pyr_r, pyr_m, val_r, val_m)


@dataclass(frozen=True)
class _Problem:
    """One level's matching problem: the images to match (texture parts where asked), the moving
    samples ``P`` and their colours ``C``, the samples under the global transform ``GP``, the grid's
    normal equations, the colour weight, the gate and the image noise."""

    R: np.ndarray
    Mv: np.ndarray
    P: np.ndarray
    C: np.ndarray
    GP: np.ndarray
    NE: _NormalEquations
    lam: float
    radius: int
    sigma: float


@dataclass(frozen=True)
class _Level:
    """One pyramid level: its control grid (spacing, shape), the samples' rate, and its matching
    problem (None: under 16 textured samples, the level is skipped)."""

    level: int
    spacing: float
    gshape: tuple[int, int]
    rate: float
    problem: _Problem | None

    @property
    def scale(self) -> float:
        """Pixels of the full image per pixel of the level."""
        return float(2 ** self.level)


def _level_problem(pyr: _Pyramids, level: int, T: np.ndarray, options: DenseOptions, *, coarsest: int,
                   seed: int) -> _Level:
    """The level's grid, samples and equations (no problem under 16 samples)."""
    R, Mv = pyr.reference[level], pyr.moving[level]
    lh, lw = R.shape[:2]
    s = float(options.grid_spacing)
    gshape = _grid_shape(lh, lw, s)
    sigma = max(_noise_sigma(cv2.cvtColor(Mv, cv2.COLOR_RGB2GRAY)), 0.5 / 255.0)
    lam = 1.0 / (math.sqrt(6.0) * sigma)
    radius = options.radius if level == coarsest else options.fine_radius
    # pixels near black padding are not scene content
    val_m = pyr.moving_valid[level]
    valid = cv2.erode(val_m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0 if not val_m.all() else None
    P, _, rate = _samples(Mv, sigma, max_points=options.max_points, seed=seed + level, valid=valid)
    if len(P) < 16:
        return _Level(level, s, gshape, rate, None)
    if options.texture is not None:
        R, Mv = _texture(R, options.texture), _texture(Mv, options.texture)
    C = Mv[P[:, 1].astype(np.intp), P[:, 0].astype(np.intp)]
    val_r = pyr.reference_valid[level]
    R_match = R if val_r.all() else np.where(val_r[:, :, None], R, np.float32(10.0))
    NE = _NormalEquations(P, gshape, s, _edge_weights(Mv, gshape, s) if options.edge_aware else None)
    GP = _apply(_level_matrix(T, level), P)
    return _Level(level, s, gshape, rate, _Problem(R_match, Mv, P, C, GP, NE, lam, radius, sigma))


@dataclass(frozen=True)
class _LevelOutcome:
    """After a level's iterations: the grid's displacements, the nodes' data weights (None when no
    step was taken), the steps taken, and the last step's fitness and weighted rms (px of the image)."""

    U: np.ndarray
    weights_node: np.ndarray | None
    steps: int
    fitness: float
    rms: float


def _iterate_level(lv: _Level, pb: _Problem, U: np.ndarray, options: DenseOptions, *, clock: _StageClock,
                   callback: Callable[[DenseIteration], None] | None) -> _LevelOutcome:
    """The non-rigid ICP iterations of one level, from the grid ``U``; a level whose matches all fail
    stops early. ``pb``: the level's problem."""
    f = lv.scale
    base_alpha = 1.0 / (lv.spacing * options.strain) ** 2
    weights_node, steps, fitness, rms = None, 0, float("nan"), float("nan")
    for it in range(options.iterations):
        clock.lap("pyramid" if it == 0 else "solve")
        X = pb.GP + pb.NE.interpolate(U)
        m = match_window(pb.R, pb.Mv, pb.P, X, pb.C, radius=pb.radius, lam=pb.lam)
        clock.lap("search")
        k = options.stiffness[min(it, len(options.stiffness) - 1)]
        alpha = k * base_alpha
        step = pb.NE.robust_step(m, X, pb.GP, pb.sigma, alpha, 1e-4 * alpha, U, maxiter=options.cg_iterations)
        if step is None:  # no sample got a weight: the field stays
            break
        U, weights_node, sw, swr, n_inliers = step
        steps += 1
        rms = f * math.sqrt(swr / sw) if sw > 0 else 0.0
        fitness = n_inliers / len(pb.P)
        if callback is not None:
            callback(DenseIteration(level=lv.level, iteration=it, stiffness=float(k), points=len(pb.P),
                                    inliers=int(n_inliers), rms=rms,
                                    grid=(f * U).reshape(lv.gshape[0], lv.gshape[1], 2).astype(np.float32)))
    return _LevelOutcome(U, weights_node, steps, fitness, rms)


@dataclass(frozen=True)
class _Grid:
    """The control grid after every level: its displacements ``U`` (nodes, 2) in pixels of the finest
    level, the nodes' data weights, the steps taken, the last step's fitness and rms, the problem of the
    last level that took a step (``last``) and of the finest level (``finest``)."""

    U: np.ndarray
    weights_node: np.ndarray
    steps: int
    fitness: float
    rms: float
    last: _Problem
    finest: _Level


def _coarse_to_fine(pyr: _Pyramids, T: np.ndarray, options: DenseOptions, *, top: int, seed: int,
                    clock: _StageClock, callback: Callable[[DenseIteration], None] | None,
                    initial: InitialGrid | None = None) -> _Grid:
    """Every level from ``top`` to the finest, each starting from the coarser level's grid, the first
    from ``initial``'s grid or from zero (the global transform); the first level gets the wide gate
    (``options.radius``). :class:`~pcreg.errors.RegistrationError` when no level had samples to match."""
    U: np.ndarray | None = None
    prev: _Level | None = None  # the coarser level
    last: _Problem | None = None
    weights_node, steps, fitness, rms = None, 0, 0.0, 0.0
    levels = range(top, options.finest_level - 1, -1)

    def problem(level: int) -> Callable[[], _Level]:
        return lambda: _level_problem(pyr, level, T, options, coarsest=top, seed=seed)

    # a level's problem does not depend on the grid: the finer ones are made on the helper thread
    # while this one works on the coarser levels
    ahead = {level: beside(problem(level)) for level in levels[1:]}
    for level in levels:
        clock.lap("solve")  # the last iteration of the level above
        lv = problem(level)() if level == top else ahead[level]()
        if (U is None or prev is None) and initial is not None:
            U = _grid_at_level(initial.grid, options.finest_level, lv)
        elif U is None or prev is None:
            U = np.zeros((lv.gshape[0] * lv.gshape[1], 2))
        else:
            U = _upsample_grid(U, prev.gshape, prev.spacing, lv.gshape, lv.spacing, 2.0)
        prev = lv
        if lv.problem is None:
            continue
        done = _iterate_level(lv, lv.problem, U, options, clock=clock, callback=callback)
        U = done.U
        if done.steps:
            weights_node, fitness, rms, last = done.weights_node, done.fitness, done.rms, lv.problem
            steps += done.steps
    clock.lap("solve")
    if U is None or weights_node is None or last is None or prev is None:
        raise RegistrationError("dense registration found no textured samples to match")
    return _Grid(U, weights_node, steps, fitness, rms, last, prev)


@dataclass(frozen=True)
class InitialGrid:
    """Where the grid starts: ``grid`` (gh, gw, 2), the finest level's displacements in full-resolution
    px (a :attr:`DenseRegistrationResult.grid`), at pyramid ``level`` (the levels above it are skipped)."""

    grid: np.ndarray
    level: int


def _grid_at_level(grid: np.ndarray, finest: int, lv: _Level) -> np.ndarray:
    """The finest level's grid (gh, gw, 2; full-resolution px) interpolated at level ``lv``'s nodes, in
    that level's px (bilinear, the edge nodes held beyond the grid): the same grid at the finest level."""
    cols, vals = _level_weights(tuple(grid.shape[:2]), finest, tuple(lv.gshape), lv.scale, float(lv.spacing))
    flat = np.ascontiguousarray(grid.reshape(-1, 2), dtype=np.float64)
    return _interpolate(cols, vals, flat, np.empty((len(cols), 2))) / lv.scale


@functools.lru_cache(maxsize=32)
def _level_weights(finest_shape: tuple[int, int], finest: int, gshape: tuple[int, int], f: float,
                   spacing: float) -> tuple[np.ndarray, ...]:
    """Read-only bilinear ``(cols, vals)`` of :func:`_grid_at_level`: the nodes (``gshape``, spacing
    ``spacing``) of a level of scale ``f`` on the finest level's grid (``finest_shape``). Made once per
    shape, as :func:`_upsample_weights`."""
    gh, gw = gshape
    ys, xs = np.mgrid[0:gh, 0:gw].astype(np.float64)
    F = float(2 ** finest)

    def on_finest(v: np.ndarray) -> np.ndarray:
        # a node at x_l = j s of its level lies at x_0 = f x_l + (f - 1) / 2 at full size, and at
        # (x_0 - (F - 1) / 2) / F on the finest level
        return ((f * v * spacing + (f - 1) / 2.0) - (F - 1) / 2.0) / F

    pts = np.column_stack([on_finest(xs).ravel(), on_finest(ys).ravel()])
    return _read_only(*_bilinear_weights(pts, finest_shape, spacing))


def finest_grid_shape(shape: tuple[int, ...], options: DenseOptions) -> tuple[int, int]:
    """The finest level's control grid (rows, columns) for images of ``shape`` (full size)."""
    h, w = shape[:2]
    for _ in range(options.finest_level):
        h, w = (h + 1) // 2, (w + 1) // 2  # cv2.pyrDown's sizes
    return _grid_shape(h, w, float(options.grid_spacing))


def _check_evidence(evidence: float, chance_factor: float | None) -> None:
    if chance_factor is not None and evidence < chance_factor:
        raise RegistrationError(
            f"dense registration refused: the field's matches are only {evidence:.2f} times closer in colour "
            f"than matches on unrelated content (at least {chance_factor:g} required); the images do not "
            f"show the same scene")


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
    from .._jit import njit as _njit

    _cell = _njit(cache=True, nogil=True, inline="always")(_cell_py)
    # numpy's error model: a pixel on a projective transform's horizon divides by zero and gets inf or
    # NaN (and a confidence of 0), as field_from_matrix does, instead of raising
    _field_rows_jit = _njit(cache=True, nogil=True, error_model="numpy")(_field_rows_py)
except ImportError:  # pragma: no cover - numba is a declared dependency
    _cell, _field_rows_jit = _cell_py, None


def refine_field(ref: np.ndarray, mov: np.ndarray, global_result: RegistrationResult, options: DenseOptions, *,
                 backend: str, seed: int, callback: Callable[[DenseIteration], None] | None, started: float,
                 given_seconds: float = 0.0, initial: InitialGrid | None = None) -> DenseRegistrationResult:
    """The dense step of :func:`pcreg.register_dense` on checked inputs: ``ref`` and ``mov`` (H, W, 3) uint8
    of one size, the global step's result (its ``T_ref_mov`` the field's start), ``options`` from
    :func:`dense_options`; ``started`` is when the registration began (``time.perf_counter()``) and
    ``given_seconds`` the time of a global step done before it, both counted in the result's seconds;
    ``initial``: where the grid starts (None: from zero at the coarsest level)."""
    coarsest = _coarsest_level(ref.shape, options)
    top = coarsest if initial is None else min(initial.level, coarsest)  # the level the grid starts at
    T = np.asarray(global_result.matrix, dtype=np.float64)
    clock = _StageClock()
    pyr = _pyramids(ref, mov, top)
    clock.lap("pyramid")
    grid = _coarse_to_fine(pyr, T, options, top=top, seed=seed, clock=clock,
                           callback=callback, initial=initial)  # 2. the grid, coarse to fine
    # 3. the plausibility test and the field at full resolution: both follow from the final grid
    # alone, so the field is made whole on the helper thread while this one measures the evidence
    # (instead of the two one after the other, each shared in halves)
    field_later = beside(lambda: _full_field(T, grid.U, grid.weights_node, grid.finest, ref.shape[:2]))
    last = grid.last
    try:
        evidence = _plausibility(last.R, last.Mv, last.P, last.C, last.GP, last.NE, last.lam, last.radius, grid.U)
        clock.lap("evidence")
        _check_evidence(evidence, options.chance_factor)
    except BaseException:
        wait_quietly(field_later)
        raise
    full = field_later()
    clock.lap("field")
    return DenseRegistrationResult(matrix=T, field=full.field, confidence=full.confidence,
                                   global_result=global_result, fitness=grid.fitness, inlier_rmse=grid.rms,
                                   iterations=grid.steps, seconds=time.perf_counter() - started + given_seconds,
                                   backend=backend, grid=full.grid,
                                   info={"levels": (top, options.finest_level), "grid": full.grid.shape[:2],
                                         "evidence": evidence, "times": clock.times})
