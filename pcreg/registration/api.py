"""Registration: ``icp`` for point clouds, ``register`` for images.

Both dispatch to the reference ICP (``backend="reference"``, :mod:`pcreg.registration.reference`) or to
Open3D's (``backend="open3d"``, :mod:`pcreg.registration.open3d_icp`) and return the same
:class:`~pcreg.registration.result.RegistrationResult`.
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

import cv2
import numpy as np

from ..errors import InputError, RegistrationError
from .open3d_icp import icp_open3d
from .reference import WEIGHTS, METRICS, build_tree, check_rank, icp_reference
from .clouds import ImageCloud, ImagePyramid, as_rgb_uint8, cloud_pyramid, pyramid_clouds
from .result import IcpIteration, RegistrationResult
from .transforms import about_point, apply, check_model, image_center, rigid2d
from ..validation import check_float, check_int, check_matrix

BACKENDS = ("reference", "open3d")
MAX_COORDINATE = 1e9  # squared distances stay far from overflow and float64 keeps sub-mm steps at 1e6 m


# ---------------------------------------------------------------------------------------------------
# Point clouds
# ---------------------------------------------------------------------------------------------------

def check_cloud(points: np.ndarray, name: str) -> np.ndarray:
    """(N, 2|3) finite float64 copy of ``points`` or an :class:`InputError`."""
    try:
        p = np.array(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: not a numeric array") from None
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise InputError(f"{name}: expected an (N, 2) or (N, 3) array of points, got shape {p.shape}")
    if p.shape[0] == 0:
        raise InputError(f"{name}: the cloud is empty")
    if not np.all(np.isfinite(p)):
        bad = int((~np.isfinite(p)).any(axis=1).sum())
        raise InputError(f"{name}: {bad} point(s) have NaN or inf coordinates")
    big = float(np.max(np.abs(p)))
    if big > MAX_COORDINATE:
        raise InputError(f"{name}: coordinates up to {big:.3g} are out of range (|x| <= {MAX_COORDINATE:g}; "
                         "shift the cloud towards the origin)")
    return p


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Mean of the points in each occupied cube of side ``voxel`` (as Open3D's ``voxel_down_sample``)."""
    if voxel <= 0:
        return points
    extent = float(np.max(points.max(axis=0) - points.min(axis=0))) if len(points) else 0.0
    if extent / voxel > 2.0**40:  # integer voxel keys would overflow (or be meaningless)
        raise InputError(f"voxel size {voxel:g} is too small for a cloud {extent:g} across")
    keys = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    sums = np.zeros((counts.size, points.shape[1]))
    np.add.at(sums, inverse, points)
    return sums / counts[:, None]


def _run_backend(backend: str, source: np.ndarray, target: np.ndarray, *, model: str, dist: float,
                 init: np.ndarray, max_iteration: int, relative_fitness: float, relative_rmse: float,
                 weights: str, metric: str, target_normals: np.ndarray | None, callback, level: int,
                 rotation: str = "svd", tree=None, trim_fraction: float = 0.9, count_iterations: bool = False):
    if backend == "reference":
        return icp_reference(source, target, model=model, max_correspondence_distance=dist, init=init,
                             max_iteration=max_iteration, relative_fitness=relative_fitness,
                             relative_rmse=relative_rmse, weights=weights, metric=metric,
                             target_normals=target_normals, callback=callback, level=level, rotation=rotation,
                             tree=tree, trim_fraction=trim_fraction)
    if weights != "none":
        raise InputError("robust weights are a reference-backend feature; Open3D's point-to-point ICP has none")
    return icp_open3d(source, target, model=model, max_correspondence_distance=dist, init=init,
                      max_iteration=max_iteration, relative_fitness=relative_fitness, relative_rmse=relative_rmse,
                      callback=callback, level=level, stepwise=count_iterations or callback is not None)


def _check_options(backend: str, model: str, dim: int, weights: str, metric: str) -> None:
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    check_model(model, dim)
    if weights not in WEIGHTS:
        raise InputError(f"unknown robust weights {weights!r}; choose one of {', '.join(WEIGHTS)}")
    if metric not in METRICS:
        raise InputError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")


def icp(source_points: np.ndarray, target_points: np.ndarray, *, backend: str = "reference", model: str = "rigid",
        max_correspondence_distance: float | None = None, init: np.ndarray | None = None, max_iteration: int = 30,
        relative_fitness: float = 1e-6, relative_rmse: float = 1e-6, voxel_sizes: Sequence[float] | None = None,
        max_correspondence_distances: Sequence[float] | None = None, max_iterations: Sequence[int] | None = None,
        weights: str = "none", trim_fraction: float = 0.9, metric: str = "point_to_point",
        target_normals: np.ndarray | None = None, rotation: str = "svd", count_iterations: bool = True,
        callback: Callable[[IcpIteration], None] | None = None) -> RegistrationResult:
    """Register two point clouds: the transform that maps ``source_points`` onto ``target_points``.

    source_points : (N, d), target_points : (M, d) float, d = 2 or 3, finite.
    max_correspondence_distance : pairs farther apart are ignored (default: the clouds' joint
        bounding-box diagonal, i.e. every nearest neighbour counts).
    voxel_sizes : coarse-to-fine schedule, e.g. (1.0, 0.5, 0.25): both clouds are voxel-downsampled
        identically (:func:`voxel_downsample`) at each size, and ICP runs at each in turn with
        ``max_correspondence_distances`` (default 2 x voxel) and ``max_iterations`` (default max_iteration).
    weights : robust weights (reference backend): ``none``, ``trimmed``, ``huber``, ``tukey``.
    metric : ``point_to_point`` or (2-D, reference backend, with ``target_normals``) ``point_to_line``.
    rotation : 3-D rigid closed form of the reference backend: ``svd`` (Umeyama) or ``quaternion`` (Horn).
    callback : called with an :class:`~pcreg.registration.result.IcpIteration` after every iteration.
    count_iterations : Open3D backend only: run Open3D one iteration at a time (its stopping rule
        applied between steps) so that ``iterations`` and ``converged`` are exact; False runs it in one
        call (faster) and reports ``iterations = -1``.

    Returns a :class:`RegistrationResult` whose ``matrix`` is (d+1, d+1) ``T_target_source``.
    """
    src = check_cloud(source_points, "source")
    tgt = check_cloud(target_points, "target")
    if src.shape[1] != tgt.shape[1]:
        raise InputError(f"source is {src.shape[1]}-D but target is {tgt.shape[1]}-D")
    dim = src.shape[1]
    _check_options(backend, model, dim, weights, metric)
    check_rank(src, model)
    check_rank(tgt, model if model != "translation" else "translation")
    if target_normals is not None:
        target_normals = check_cloud(target_normals, "target_normals")
        if target_normals.shape != tgt.shape:
            raise InputError("target_normals must have the target's shape")
    T = np.eye(dim + 1) if init is None else check_matrix(init, "init", dim + 1)
    max_iteration = check_int(max_iteration, "max_iteration", lo=0, hi=100_000)
    relative_fitness = check_float(relative_fitness, "relative_fitness", lo=0)
    relative_rmse = check_float(relative_rmse, "relative_rmse", lo=0)
    trim_fraction = check_float(trim_fraction, "trim_fraction", lo=0, lo_open=True, hi=1)
    if max_correspondence_distance is not None:
        max_correspondence_distance = check_float(max_correspondence_distance, "max_correspondence_distance",
                                                  lo=0, lo_open=True)
    for name, seq in (("voxel_sizes", voxel_sizes), ("max_correspondence_distances", max_correspondence_distances)):
        for v in seq or ():
            check_float(v, name, lo=0, lo_open=True)
    for v in max_iterations or ():
        check_int(v, "max_iterations", lo=0, hi=100_000)
    if max_correspondence_distance is None:
        both = np.vstack([apply(T, src), tgt])
        max_correspondence_distance = float(np.linalg.norm(both.max(axis=0) - both.min(axis=0))) + 1.0
    if not max_correspondence_distance > 0:
        raise InputError("max_correspondence_distance must be > 0")
    if max_iteration < 0:
        raise InputError("max_iteration must be >= 0")
    start = time.perf_counter()
    if voxel_sizes:
        dists = list(max_correspondence_distances or [2.0 * v for v in voxel_sizes])
        iters = list(max_iterations or [max_iteration] * len(voxel_sizes))
        if not (len(dists) == len(iters) == len(voxel_sizes)):
            raise InputError("voxel_sizes, max_correspondence_distances and max_iterations differ in length")
        schedule = [(voxel_downsample(src, v), voxel_downsample(tgt, v), d, n) for v, d, n in zip(voxel_sizes, dists, iters)]
    else:
        schedule = [(src, tgt, max_correspondence_distance, max_iteration)]
    total_iter = 0
    n_levels = len(schedule)
    for i, (s, t, d, n) in enumerate(schedule):
        r = _run_backend(backend, s, t, model=model, dist=d, init=T, max_iteration=n,
                         relative_fitness=relative_fitness, relative_rmse=relative_rmse, weights=weights,
                         metric=metric, target_normals=target_normals if not voxel_sizes else None,
                         callback=callback, level=n_levels - 1 - i, rotation=rotation,
                         trim_fraction=trim_fraction, count_iterations=count_iterations)
        T = r.matrix
        total_iter = -1 if (r.iterations < 0 or total_iter < 0) else total_iter + r.iterations
    seconds = time.perf_counter() - start
    return RegistrationResult(matrix=T, fitness=r.fitness, inlier_rmse=r.inlier_rmse, iterations=total_iter,
                              converged=r.converged, backend=backend, seconds=seconds)


# ---------------------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------------------

def _pyramid_images(img: np.ndarray, levels: int) -> list[np.ndarray]:
    out = [img]
    for _ in range(levels - 1):
        out.append(cv2.pyrDown(out[-1]))
    return out


def _rasterise(points: np.ndarray, size: int, sigma: float) -> np.ndarray:
    """Points (N, 2) in cell units around the canvas centre -> blurred (size, size) float32 density."""
    ij = np.rint(points + size / 2.0).astype(np.intp)
    keep = (ij[:, 0] >= 0) & (ij[:, 0] < size) & (ij[:, 1] >= 0) & (ij[:, 1] < size)
    flat = ij[keep, 1] * size + ij[keep, 0]
    img = np.bincount(flat, minlength=size * size).astype(np.float32).reshape(size, size)
    return cv2.GaussianBlur(img, (0, 0), sigma)


def _global_search(ref: ImageCloud, mov: ImageCloud, *, angles: np.ndarray, sigma: float = 1.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Rigid hypotheses over the full circle: for each angle, the best translation by FFT cross-correlation.

    Both clouds are rasterised at their (coarse) pyramid level and blurred; the moving cloud is rotated
    by each angle about its image centre, put on the reference centre, and the peak of its cross-
    correlation with the reference (``cv2.dft``) gives the translation and a score. Returns (K, 3, 3)
    matrices ``T_ref_mov`` and (K,) scores (correlation peaks, comparable across angles because the same
    moving points are rasterised every time).
    """
    g = float(2 ** ref.level)
    c_ref = np.array(image_center(ref.shape))
    c_mov = np.array(image_center(mov.shape))
    # The canvas holds the reference plus a margin for shifts up to a quarter of its size; moving points
    # rotated beyond it (the far corners) are dropped, which costs little correlation and halves the FFT.
    extent = 1.5 * max(ref.shape) / g
    size = cv2.getOptimalDFTSize(int(np.ceil(max(extent, 16.0))))
    R = _rasterise((ref.points - c_ref) / g, size, sigma)
    FR = cv2.dft(R)  # real input: packed (CCS) spectrum, half the work of a complex one
    pm = (mov.points - c_mov) / g
    Ts, scores = [], []
    for a in angles:
        Rot = rigid2d(a)[:2, :2]
        M = _rasterise(pm @ Rot.T, size, sigma)
        FM = cv2.dft(M)
        C = cv2.idft(cv2.mulSpectrums(FR, FM, 0, conjB=True), flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
        iy, ix = np.unravel_index(int(np.argmax(C)), C.shape)
        peak = float(C[iy, ix])
        # Sub-cell peak by a parabola through the neighbours, per axis.
        def sub(c_m, c_0, c_p):
            den = c_m - 2 * c_0 + c_p
            return 0.5 * (c_m - c_p) / den if den < 0 else 0.0
        dx = ix + sub(C[iy, ix - 1], peak, C[iy, (ix + 1) % size])
        dy = iy + sub(C[iy - 1, ix], peak, C[(iy + 1) % size, ix])
        dx = dx - size if dx > size / 2 else dx
        dy = dy - size if dy > size / 2 else dy
        T = about_point(rigid2d(a), tuple(c_mov), tuple(c_ref))
        T[:2, 2] += np.array([dx, dy]) * g
        Ts.append(T)
        scores.append(peak)
    return np.stack(Ts), np.array(scores)


def register(reference_image: np.ndarray, moving_image: np.ndarray, *, backend: str = "reference",
             model: str = "rigid", levels: int = 4, iterations: int = 14, init: str | np.ndarray = "auto",
             sampler: str = "canny", max_points: Sequence[int | None] | int | None = (1000, 800, 600, 400),
             reference_max_points: int | None = 20000, max_correspondence_distance: float = 2.5,
             refine: str | None = "point_to_line", weights: str = "none",
             relative_fitness: float = 1e-4, relative_rmse: float = 1e-3, angle_step: float = 15.0,
             n_candidates: int = 2,
             reference_mask: np.ndarray | str | None = "auto", moving_mask: np.ndarray | str | None = "auto",
             canny_percentile: float = 85.0, seed: int = 0,
             callback: Callable[[IcpIteration], None] | None = None,
             reference_pyramid: ImagePyramid | None = None, moving_pyramid: ImagePyramid | None = None,
             ) -> RegistrationResult:
    """Register ``moving_image`` to ``reference_image``: the returned ``matrix`` is ``T_ref_mov``.

    Both images become edge clouds (:func:`pcreg.image_cloud`) at pyramid levels 0..levels-1. With
    ``init="auto"`` (or ``"global"``) a global search (:func:`_global_search`) first rotates the moving
    cloud every ``angle_step`` degrees over the full circle at the coarsest level with at least 100
    points a side, finds each rotation's translation by FFT cross-correlation, gives the
    ``n_candidates`` best a short rigid ICP and keeps the one that puts most points within one cell of
    the reference, so any rotation in ±180° with shifts of ~10% of the image is found;
    ``init="identity"``, ``"center"`` (image centres aligned) or a 3x3 matrix skips it. ICP (``backend``) then refines from the
    coarsest level to the finest with ``iterations`` iterations per level and a correspondence distance
    of ``max_correspondence_distance`` px x 2^level. ``refine="point_to_line"`` (reference backend)
    finishes with point-to-line iterations at full resolution, which removes the bias of matching
    edge points sampled at different places along the same edge.

    reference_image, moving_image : (H, W, 3) uint8 RGB (also gray, uint16, float in [0, 1]); the
        sizes may differ.
    max_points : moving points kept per level (finest first), at random with ``seed``.
    reference_max_points : reference points kept per level; edges of a 480x360 street scene number
        15-20k, a noisy 640x480 texture can give 60k that cost time without adding accuracy.
    relative_fitness, relative_rmse : Open3D's stopping rule per level (absolute changes; the RMSE
        threshold is in full-resolution px, scaled by 2^level); the point-to-line finish uses at most 1e-6.
    reference_mask, moving_mask : usable pixels, ``"auto"`` (ignore black padding) or None.
    reference_pyramid, moving_pyramid : the images' :func:`pcreg.image_pyramid` (same ``levels``,
        ``sampler``, mask and ``canny_percentile``), when the caller keeps them to reuse (a frame of a
        stream is the moving image once and the reference once); None builds them here. Same result.
    """
    ref_img = as_rgb_uint8(reference_image, name="reference image")
    mov_img = as_rgb_uint8(moving_image, name="moving image")
    _check_options(backend, model, 2, weights, "point_to_point")
    levels = check_int(levels, "levels", lo=1, hi=8)
    iterations = check_int(iterations, "iterations", lo=1, hi=100_000)
    n_candidates = check_int(n_candidates, "n_candidates", lo=1, hi=360)
    seed = check_int(seed, "seed", lo=0)
    angle_step = check_float(angle_step, "angle_step", lo=0.01, hi=360)
    max_correspondence_distance = check_float(max_correspondence_distance, "max_correspondence_distance",
                                              lo=0, lo_open=True, hi=1e6)
    relative_fitness = check_float(relative_fitness, "relative_fitness", lo=0)
    relative_rmse = check_float(relative_rmse, "relative_rmse", lo=0)
    canny_percentile = check_float(canny_percentile, "canny_percentile", lo=0, hi=100)
    if not isinstance(init, str):
        init = check_matrix(init, "init", 3)
    if refine not in (None, "none", "point_to_line"):
        raise InputError(f"refine must be 'point_to_line' or None, got {refine!r}")
    if min(ref_img.shape[:2] + mov_img.shape[:2]) >> (levels - 1) < 8:
        raise InputError(f"images too small for {levels} pyramid levels")
    start = time.perf_counter()
    # Pyramids built by the caller (a stream builds each frame's once: moving first, then reference).
    ref_levels = pyramid_clouds(ref_img, reference_pyramid, levels=levels, mask=reference_mask,
                                max_points=reference_max_points, sampler=sampler, seed=seed,
                                canny_percentile=canny_percentile, name="reference")
    mov_levels = pyramid_clouds(mov_img, moving_pyramid, levels=levels, mask=moving_mask, max_points=max_points,
                                sampler=sampler, seed=seed + 1, canny_percentile=canny_percentile, name="moving")
    for name, lv in (("reference", ref_levels), ("moving", mov_levels)):
        if len(lv[0]) < 3:
            raise RegistrationError(f"the {name} image has no usable edges (a flat or empty image?)")
    trees: dict[int, object] = {}

    def tree(level: int):
        """The reference points' KD-tree at one level, built once (global search and ICP share it)."""
        if level not in trees:
            trees[level] = build_tree(ref_levels[level].points, max_distance=max_correspondence_distance * 2**level)
        return trees[level]

    T: np.ndarray
    if isinstance(init, str):
        if init not in ("auto", "global", "identity", "center"):
            raise InputError(f"init must be 'auto', 'global', 'identity', 'center' or a 3x3 matrix, got {init!r}")
        if init in ("auto", "global"):
            g_level = min(3, levels - 1)
            # The search needs enough points to tell hypotheses apart: go finer until it has them.
            while g_level > 0 and (len(mov_levels[g_level]) < 100 or len(ref_levels[g_level]) < 100):
                g_level -= 1
            angles = np.array([0.0]) if model == "translation" else np.arange(0.0, 360.0, angle_step)
            Ts, score = _global_search(ref_levels[g_level], mov_levels[g_level], angles=angles)
            # The best few hypotheses each get a short ICP at the search level. They are ranked by the
            # share of points that end within one cell of a reference point: ICP's own fitness, under
            # its wide gate, is near 1 for wrong hypotheses too.
            best = (-1.0, None)
            g_tree = tree(g_level)
            for k in np.argsort(-score)[:n_candidates]:
                Tk = icp_reference(mov_levels[g_level].points, ref_levels[g_level].points,
                                   model="rigid" if model != "translation" else "translation",
                                   max_correspondence_distance=3.0 * 2**g_level, init=Ts[k],
                                   max_iteration=iterations, relative_fitness=relative_fitness,
                                   relative_rmse=relative_rmse * 2**g_level, tree=g_tree, level=g_level).matrix
                d, _ = g_tree.query(apply(Tk, mov_levels[g_level].points), k=1)
                tight = float(np.mean(d < 2**g_level))
                if tight > best[0]:
                    best = (tight, Tk)
            T = best[1]
        elif init == "center":
            T = about_point(np.eye(3), image_center(mov_img.shape), image_center(ref_img.shape))
        else:
            T = np.eye(3)
    else:
        T = init
    total, conv, fit, rmse = 0, False, 0.0, 0.0
    p2l = refine == "point_to_line" and backend == "reference"
    for level in range(levels - 1, 0 if p2l else -1, -1):
        s, t = mov_levels[level], ref_levels[level]
        if len(s) < 3 or len(t) < 3:
            continue
        check_rank(s.points, model)
        dist = max_correspondence_distance * 2**level
        r = _run_backend(backend, s.points, t.points, model=model, dist=dist, init=T, max_iteration=iterations,
                         relative_fitness=relative_fitness, relative_rmse=relative_rmse * 2**level,
                         weights=weights, metric="point_to_point", target_normals=None, callback=callback,
                         level=level, tree=tree(level) if backend == "reference" else None)
        T, fit, rmse, conv = r.matrix, r.fitness, r.inlier_rmse, r.converged
        total = -1 if (r.iterations < 0 or total < 0) else total + r.iterations
    if p2l:
        s, t = mov_levels[0], ref_levels[0]
        r = icp_reference(s.points, t.points, model=model, max_correspondence_distance=max_correspondence_distance,
                          init=T, max_iteration=iterations, relative_fitness=min(relative_fitness, 1e-6),
                          relative_rmse=min(relative_rmse, 1e-6), weights="tukey" if weights == "none" else weights,
                          metric="point_to_line", target_normals=t.normals, callback=callback, level=0)
        T, fit, rmse, conv = r.matrix, r.fitness, r.inlier_rmse, r.converged
        total = -1 if total < 0 else total + r.iterations
    seconds = time.perf_counter() - start
    if fit == 0.0:
        raise RegistrationError("registration found no overlap between the images")
    return RegistrationResult(matrix=T, fitness=fit, inlier_rmse=rmse, iterations=total, converged=conv,
                              backend=backend, seconds=seconds,
                              info={"moving_points": len(mov_levels[0]), "reference_points": len(ref_levels[0])})
