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
from .open3d_icp import icp_open3d, to_pointcloud
from .reference import WEIGHTS, METRICS, build_tree, check_rank, icp_reference
from .clouds import (SAMPLERS, ImageCloud, ImagePyramid, _cloud_at, as_rgb_uint8, check_mask, check_pyramid, per_level,
                     usable_mask)
from .result import IcpIteration, RegistrationResult
from .global_search import (GENERATORS, alignment_evidence, edge_fft_hypotheses, fourier_mellin_hypotheses,
                            gray_level, orb_hypotheses, photometric_agreement)
from .open3d_icp import check_model as check_open3d_model
from .transforms import about_point, apply, check_model, corners, image_center
from ..validation import short_repr, check_bool, check_choice, check_counts, check_float, check_floats, check_int, check_ints, check_matrix

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
    _refuse_for_open3d(weights=weights, metric=metric, target_normals=target_normals, rotation=rotation,
                       trim_fraction=trim_fraction)
    return icp_open3d(source, target, model=model, max_correspondence_distance=dist, init=init,
                      max_iteration=max_iteration, relative_fitness=relative_fitness, relative_rmse=relative_rmse,
                      callback=callback, level=level, stepwise=count_iterations or callback is not None)


def _refuse_for_open3d(*, weights: str = "none", metric: str = "point_to_point", target_normals=None,
                       rotation: str = "svd", trim_fraction: float = 0.9) -> None:
    """:class:`InputError` for every option Open3D's point-to-point ICP cannot honour (none is ignored)."""
    if weights != "none":
        raise InputError("robust weights are a reference-backend feature; Open3D's point-to-point ICP has none")
    if metric != "point_to_point":
        raise InputError(f"metric {metric!r} is a reference-backend feature; the open3d backend is point-to-point")
    if target_normals is not None:
        raise InputError("target_normals serve the reference backend's point-to-line metric; "
                         "the open3d backend (point-to-point) would ignore them")
    if rotation != "svd":
        raise InputError(f"rotation={rotation!r} chooses the reference backend's closed form; "
                         "Open3D's point-to-point estimation has its own (SVD)")
    if trim_fraction != 0.9:
        raise InputError("trim_fraction belongs to the reference backend's trimmed weights")


def _check_options(backend: str, model: str, dim: int, weights: str, metric: str) -> None:
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise InputError(f"unknown backend {short_repr(backend)}; choose one of {', '.join(BACKENDS)}")
    check_model(model, dim)
    if not isinstance(weights, str) or weights not in WEIGHTS:
        raise InputError(f"unknown robust weights {short_repr(weights)}; choose one of {', '.join(WEIGHTS)}")
    if not isinstance(metric, str) or metric not in METRICS:
        raise InputError(f"unknown metric {short_repr(metric)}; choose one of {', '.join(METRICS)}")


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
    if backend == "open3d":
        check_open3d_model(model)
        _refuse_for_open3d(weights=weights, metric=metric, target_normals=target_normals, rotation=rotation,
                           trim_fraction=trim_fraction)
    voxel_sizes = check_floats(voxel_sizes, "voxel_sizes", lo=0, lo_open=True)
    max_correspondence_distances = check_floats(max_correspondence_distances, "max_correspondence_distances",
                                                lo=0, lo_open=True)
    max_iterations = check_ints(max_iterations, "max_iterations", lo=0, hi=100_000)
    count_iterations = check_bool(count_iterations, "count_iterations")
    if callback is not None and not callable(callback):
        raise InputError(f"callback must be callable or None, got {type(callback).__name__}")
    if not isinstance(rotation, str) or rotation not in ("svd", "quaternion"):
        raise InputError(f"rotation must be 'svd' or 'quaternion', got {short_repr(rotation)}")
    if rotation == "quaternion" and (dim != 3 or model != "rigid"):
        raise InputError("rotation='quaternion' (Horn's closed form) is for the rigid model of 3-D clouds")
    if metric == "point_to_line" and (dim != 2 or target_normals is None or voxel_sizes):
        raise InputError("metric='point_to_line' needs 2-D clouds, target_normals and no voxel_sizes "
                         "(normals cannot follow a voxel downsampling)")
    if target_normals is not None and metric != "point_to_line":
        raise InputError("target_normals are used only by metric='point_to_line'")
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

DEFAULT_MIN_INLIER_RATIO = 0.15
"""Default plausibility threshold of :func:`register`: the share of tight (<= 1 px), direction-consistent
inliers an alignment must reach.

The argument: content unrelated to the reference reaches only the test's chance level, the share of
points that fall within 1 px of some reference edge times the chance that two unrelated edge directions
agree within 30° (about 1/6 for uniform directions). Measured after the full search and ICP (which
optimise the alignment, so this is the worst case), unrelated photographs, noise and procedural
textures against each other reach 0.01-0.09, and the permutation estimate of chance
(``chance_ratio``) is at most 0.20 even on dense, oriented textures (grass). True alignments of the
same content reach 0.5-0.95 on photographs and textures; consecutive street-scene frames 15 per second
apart 0.43-0.62. 0.15 lies above every unrelated alignment measured, with room below true ones; the
second test, ``inlier_ratio >= CHANCE_FACTOR x chance_ratio``, covers textures whose own chance level
comes near it. Mirror images are refused by comparison with their mirror (see :func:`register`).
"""

START_LEVEL = 0
"""Pyramid level at which rigid intensity hypotheses (within a few pixels) are refined first: full
resolution, measured 6-10% faster than level 1 and as accurate."""
CONVINCING_NCC = 0.6
"""The search stops early only at an alignment whose intensities also agree (normalised cross-correlation at
pyramid level 2 at least this); otherwise every generator runs and the best one wins."""

MIRROR_FACTOR = 1.2
"""A moving image whose mirror scores (:func:`_rank`) this much better than itself is refused as a mirror image."""

CHANCE_FACTOR = 2.0
"""A plausible alignment has at least this multiple of its chance level of inliers (true alignments
measured at >= 2.8x, unrelated content at about 1x)."""

REFINES = ("none", "point_to_line")


def _ensure_backend_options(backend: str, refine: str, weights: str) -> None:
    if refine == "point_to_line" and backend != "reference":
        raise InputError("refine='point_to_line' is a reference-backend finish (Open3D's ICP here is point-to-point); "
                         "use refine='none' with backend='open3d'")
    if weights != "none" and backend != "reference":
        raise InputError("robust weights are a reference-backend feature; Open3D's point-to-point ICP has none")


def _rank(t) -> float:
    """A refined hypothesis's score: its inlier ratio weighted by the agreement of the intensities
    (normalised cross-correlation), when measured: edges rank, intensities break the ties of patterns."""
    ratio, ncc = t[0], t[5]
    return ratio * (0.25 + max(ncc, 0.0)) if np.isfinite(ncc) else ratio


class _LazyPyramid:
    """:func:`cloud_pyramid`'s levels, each built on first access (same clouds, same seeds)."""

    def __init__(self, image: np.ndarray, *, levels: int, mask, max_points, seed: int, **kwargs):
        max_points = per_level(max_points, levels)
        mask = usable_mask(mask, image)
        self._images = [image]
        self._clouds: dict[int, ImageCloud] = {}
        # Usable pixels at full resolution (for the intensity generators): all where no mask applies.
        self.valid = np.ones(image.shape[:2], bool) if mask is None else mask
        self._levels, self._mask, self._max_points, self._seed, self._kwargs = levels, mask, max_points, seed, kwargs

    def __len__(self) -> int:
        return self._levels

    def __getitem__(self, level: int) -> ImageCloud:
        if not 0 <= level < self._levels:
            raise IndexError(level)
        if level not in self._clouds:
            while len(self._images) <= level:
                self._images.append(cv2.pyrDown(self._images[-1]))
            self._clouds[level] = _cloud_at(self._images[level], level=level, shape=self._images[0].shape[:2],
                                            mask=self._mask, max_points=self._max_points[level], seed=self._seed,
                                            **self._kwargs)
        return self._clouds[level]


class _KeptPyramid:
    """The levels of an :class:`~pcreg.registration.clouds.ImagePyramid` built by the caller, drawn on
    first access with ``_LazyPyramid``'s sizes and seeds."""

    def __init__(self, pyramid: ImagePyramid, *, levels: int, max_points, seed: int):
        self._max_points = per_level(max_points, levels)
        self._pyramid, self._levels, self._seed = pyramid, levels, seed
        self._clouds: dict[int, ImageCloud] = {}
        self.valid = pyramid.valid if pyramid.valid is not None else np.ones(pyramid.shape, bool)

    def __len__(self) -> int:
        return self._levels

    def __getitem__(self, level: int) -> ImageCloud:
        if not 0 <= level < self._levels:
            raise IndexError(level)
        if level not in self._clouds:
            self._clouds[level] = self._pyramid.cloud(level, max_points=self._max_points[level], seed=self._seed)
        return self._clouds[level]


class _MirroredPyramid:
    """The clouds of a pyramid mirrored left-right, level by level on access."""

    def __init__(self, base):
        self._base, self._clouds = base, {}
        self.valid = np.ascontiguousarray(base.valid[:, ::-1])

    def __len__(self) -> int:
        return len(self._base)

    def __getitem__(self, level: int) -> ImageCloud:
        if level not in self._clouds:
            self._clouds[level] = _mirror_cloud(self._base[level])
        return self._clouds[level]


def _mirror_cloud(c: ImageCloud) -> ImageCloud:
    """The cloud of the image mirrored left-right (x -> W - 1 - x, normals' x negated)."""
    pts = c.points.copy()
    pts[:, 0] = (c.shape[1] - 1) - pts[:, 0]
    nrm = c.normals.copy()
    nrm[:, 0] = -nrm[:, 0]
    return ImageCloud(points=pts, colors=c.colors, normals=nrm, shape=c.shape, level=c.level)


def _unseen(hyps: list[np.ndarray], seen: list[np.ndarray], shape, *, min_px: float) -> list[np.ndarray]:
    """The hypotheses whose corners are more than ``min_px`` from those of every one in ``seen`` and
    of every earlier one in ``hyps``."""
    c = corners(shape)
    out: list[np.ndarray] = []
    for h in hyps:
        pc = apply(h, c)
        if all(np.max(np.linalg.norm(pc - apply(q, c), axis=1)) > min_px for q in list(seen) + out):
            out.append(h)
    return out


def register(reference_image: np.ndarray, moving_image: np.ndarray, *, backend: str = "reference",
             model: str = "rigid", levels: int = 4, iterations: int = 14, init: str | np.ndarray = "auto",
             sampler: str = "canny", max_points: Sequence[int | None] | int | None = (2000, 800, 600, 400),
             reference_max_points: int | None = 60000, max_correspondence_distance: float = 2.5,
             refine: str | None = "none", weights: str = "none",
             relative_fitness: float = 1e-4, relative_rmse: float = 1e-3, angle_step: float = 15.0,
             n_candidates: int = 2, generators: Sequence[str] = ("fourier_mellin", "edges", "orb"),
             min_inlier_ratio: float | None = DEFAULT_MIN_INLIER_RATIO, inlier_tolerance: float = 1.0,
             reference_mask: np.ndarray | str | None = "auto", moving_mask: np.ndarray | str | None = "auto",
             canny_percentile: float = 85.0, seed: int = 0,
             callback: Callable[[IcpIteration], None] | None = None,
             reference_pyramid: ImagePyramid | None = None, moving_pyramid: ImagePyramid | None = None,
             ) -> RegistrationResult:
    """Register ``moving_image`` to ``reference_image``: the returned ``matrix`` is ``T_ref_mov``.

    Both images become edge clouds (:func:`pcreg.image_cloud`) at pyramid levels 0..levels-1.

    With ``init="auto"`` (or ``"global"``) hypotheses come from the ``generators``, tried in order
    (:mod:`pcreg.registration.global_search`) until one is convincing: ``"fourier_mellin"`` takes the
    rotation from the log-polar magnitude spectra and the translation from a phase correlation of the
    intensity images; ``"edges"`` rotates the moving edge cloud every ``angle_step`` degrees over the
    full circle and finds each rotation's translation by FFT cross-correlation (the ``n_candidates`` best
    get a short ICP at the search level, the coarsest with at least 100 points a side, and are ranked by
    their tight inliers there); ``"orb"`` matches ORB features at pyramid level 1 and fits a similarity
    by RANSAC. Intensity hypotheses (the 180° twin of Fourier-Mellin's included) are ranked by the
    normalised cross-correlation of the images they align and refined at full resolution (a first pass
    with twice the correspondence distance); the edge hypothesis from the coarsest level. Every ICP step uses the selected ``backend``; the refined hypothesis is
    measured at full resolution (``inlier_ratio``, below). A generator is convincing when its refined
    hypothesis reaches an inlier ratio of max(0.6, 2 x ``min_inlier_ratio``) and its intensities agree
    (:data:`CONVINCING_NCC`); otherwise the next one runs, so easy pairs pay for one. The winner has the
    most inliers, weighted by the intensities' agreement (edges alone cannot tell a brick wall from its
    copy shifted by a brick). ``init="identity"``, ``"center"`` (image centres aligned) or a 3x3 matrix
    replaces the search by that one hypothesis.

    Failure signal: the winner's ``inlier_ratio`` is the share of moving edge points, among those that
    land on the reference image, with a reference edge point within ``inlier_tolerance`` px whose edge
    direction agrees within 30° (measured at full resolution; on images whose full-resolution reference
    cloud hits ``reference_max_points``, at the finest level where it does not, with the tolerance scaled
    to it). ``chance_ratio`` is what unrelated content reaches at the same distances. Below
    ``min_inlier_ratio`` (see :data:`DEFAULT_MIN_INLIER_RATIO`; None turns the test off), below
    :data:`CHANCE_FACTOR` x ``chance_ratio``, with fewer than 2% of the points on the reference (no
    overlap), or when the moving image's mirror aligns clearly better (:data:`MIRROR_FACTOR`),
    :class:`~pcreg.errors.RegistrationError` is raised with a one-line reason. Unrelated images, noise
    and mirror images are refused this way.

    backend : ``"reference"`` or ``"open3d"``: the ICP of every step (candidates, levels, finish).
    refine : ``"none"`` (default) or ``"point_to_line"``: point-to-line iterations (Tukey weights) at
        full resolution after the point-to-point levels, which removes the bias of matching edge points
        sampled at different places along the same edge (reference backend only; Open3D's backend
        refuses it with :class:`~pcreg.errors.InputError`). The default is the same algorithm for both
        backends, so that their results can be compared.
    reference_image, moving_image : (H, W, 3) uint8 RGB (also gray, uint16, float in [0, 1]); the
        sizes may differ.
    max_points : moving points kept per level (finest first), at random with ``seed``.
    reference_max_points : reference points kept per level: edges of a 480x360 street scene number
        15-20k, a 512x512 texture 30-60k; a random subset of them biases nearest-neighbour matches, so
        the cap is high (it bounds the time on very large images).
    relative_fitness, relative_rmse : Open3D's stopping rule per level (absolute changes; the RMSE
        threshold is in full-resolution px, scaled by 2^level); the point-to-line finish uses at most 1e-6.
    reference_mask, moving_mask : usable pixels, ``"auto"`` (ignore black padding) or None.
    reference_pyramid, moving_pyramid : the images' :func:`pcreg.image_pyramid` (same ``levels``,
        ``sampler``, mask and ``canny_percentile``), when the caller keeps them to reuse (a frame of a
        stream is the moving image once and the reference once); None builds the clouds here. The
        clouds are the same (to OpenCV's float32 rounding of the gradient magnitude).

    Returns a :class:`RegistrationResult` with ``inlier_ratio``, ``overlap`` and ``generator`` (which
    generator's hypothesis won, or ``"init"``) besides the ICP's own figures.
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
    sampler = check_choice(sampler, "sampler", SAMPLERS)
    max_points = check_counts(max_points, "max_points")
    reference_max_points = check_counts(reference_max_points, "reference_max_points")
    check_mask(reference_mask, ref_img.shape, name="reference_mask")
    check_mask(moving_mask, mov_img.shape, name="moving_mask")
    if callback is not None and not callable(callback):
        raise InputError(f"callback must be callable or None, got {type(callback).__name__}")
    if not isinstance(init, str):
        init = check_matrix(init, "init", 3)
    if refine is None:
        refine = "none"
    refine = check_choice(refine, "refine", REFINES)
    _ensure_backend_options(backend, refine, weights)
    if backend == "open3d":
        check_open3d_model(model)
    if min_inlier_ratio is not None:
        min_inlier_ratio = check_float(min_inlier_ratio, "min_inlier_ratio", lo=0, hi=1)
    inlier_tolerance = check_float(inlier_tolerance, "inlier_tolerance", lo=0, lo_open=True)
    if isinstance(generators, str):
        generators = (generators,)
    try:
        generators = tuple(generators)
    except TypeError:
        raise InputError(f"generators must be a selection of {', '.join(GENERATORS)}, got {short_repr(generators)}") from None
    bad = [g for g in generators if not isinstance(g, str) or g not in GENERATORS]
    if bad or not generators:
        raise InputError(f"generators must be a non-empty selection of {', '.join(GENERATORS)}, got {short_repr(generators)}")
    if min(ref_img.shape[:2] + mov_img.shape[:2]) >> (levels - 1) < 8:
        raise InputError(f"images too small for {levels} pyramid levels")
    start = time.perf_counter()
    # Each level's cloud is built when first used: a search that ends at level 1 never builds levels 2-3.
    # A pyramid built by the caller is drawn from instead (a stream builds each frame's once).
    ref_levels = (_LazyPyramid(ref_img, levels=levels, mask=reference_mask, max_points=reference_max_points,
                               sampler=sampler, seed=seed, canny_percentile=canny_percentile)
                  if reference_pyramid is None else
                  _KeptPyramid(check_pyramid(ref_img, reference_pyramid, levels=levels, sampler=sampler,
                                             canny_percentile=canny_percentile, name="reference"),
                               levels=levels, max_points=reference_max_points, seed=seed))
    mov_levels = (_LazyPyramid(mov_img, levels=levels, mask=moving_mask, max_points=max_points,
                               sampler=sampler, seed=seed + 1, canny_percentile=canny_percentile)
                  if moving_pyramid is None else
                  _KeptPyramid(check_pyramid(mov_img, moving_pyramid, levels=levels, sampler=sampler,
                                             canny_percentile=canny_percentile, name="moving"),
                               levels=levels, max_points=max_points, seed=seed + 1))
    for name, lv in (("reference", ref_levels), ("moving", mov_levels)):
        if len(lv[0]) < 3:
            raise RegistrationError(f"the {name} image has no usable edges (a flat or empty image?)")
    trees: dict[int, object] = {}

    def tree(level: int):
        """The reference points' KD-tree at one level, built once (search, ICP and evidence share it)."""
        if level not in trees:
            trees[level] = build_tree(ref_levels[level].points, max_distance=max_correspondence_distance * 2**level)
        return trees[level]

    icp_model = model
    p2l = refine == "point_to_line"
    search_model = "translation" if model == "translation" else "rigid"

    pcds: dict = {}

    def pcd(cloud: ImageCloud):
        """Open3D's copy of a cloud, made once per cloud (the candidates and levels share it)."""
        if id(cloud) not in pcds:
            pcds[id(cloud)] = (cloud, to_pointcloud(cloud.points))
        return pcds[id(cloud)][1]

    def run_icp(ML, T, level, *, dist, n_iter, model_, cb=None, final=True):
        s, t = ML[level], ref_levels[level]
        if backend == "open3d":
            r = icp_open3d(s.points, t.points, model=model_, max_correspondence_distance=dist, init=T,
                           max_iteration=n_iter, relative_fitness=relative_fitness,
                           relative_rmse=relative_rmse * 2**level, callback=cb, level=level,
                           stepwise=cb is not None, source_pcd=pcd(s), target_pcd=pcd(t),
                           check_convergence=final or cb is not None)
        else:
            r = _run_backend(backend, s.points, t.points, model=model_, dist=dist, init=T, max_iteration=n_iter,
                             relative_fitness=relative_fitness, relative_rmse=relative_rmse * 2**level,
                             weights=weights, metric="point_to_point", target_normals=None, callback=cb,
                             level=level, tree=tree(level))
        return r.matrix, r.fitness, r.inlier_rmse, r.iterations, r.converged

    def refine_all(ML, T, cb=None, top=None):
        """Coarse-to-fine ICP from ``T`` (from level ``top``, default the coarsest); returns
        (T, fitness, rmse, iterations, converged)."""
        total, conv, fit, rmse = 0, False, 0.0, 0.0
        if top is not None:
            # A start already within a few cells of level ``top``: one pass there with twice the
            # correspondence distance brings it into the usual gate.
            T, fit, rmse, it, conv = run_icp(ML, T, top, dist=2.0 * max_correspondence_distance * 2**top,
                                             n_iter=iterations, model_=icp_model, cb=cb, final=False)
            total = -1 if it < 0 else it
        top = levels - 1 if top is None else top
        for level in range(top, 0 if p2l else -1, -1):
            s, t = ML[level], ref_levels[level]
            if len(s) < 3 or len(t) < 3:
                continue
            check_rank(s.points, icp_model)
            T, fit, rmse, it, conv = run_icp(ML, T, level, dist=max_correspondence_distance * 2**level,
                                             n_iter=iterations, model_=icp_model, cb=cb, final=level == 0)
            total = -1 if (it < 0 or total < 0) else total + it
        if p2l:
            s, t = ML[0], ref_levels[0]
            r = icp_reference(s.points, t.points, model=icp_model,
                                                   max_correspondence_distance=max_correspondence_distance,
                                                   init=T, max_iteration=iterations,
                                                   relative_fitness=min(relative_fitness, 1e-6),
                                                   relative_rmse=min(relative_rmse, 1e-6),
                                                   weights="tukey" if weights == "none" else weights,
                                                   metric="point_to_line", target_normals=t.normals,
                                                   callback=cb, level=0, tree=tree(0))
            T, fit, rmse, it, conv = r.matrix, r.fitness, r.inlier_rmse, r.iterations, r.converged
            total = -1 if total < 0 else total + it
        return T, fit, rmse, total, conv

    # The evidence is measured at full resolution, unless the reference cloud had to be capped there (a
    # random subset of the edges leaves gaps that true matches fall into): then at the finest level with
    # every edge, with the tolerance scaled to that level (1 px at level 1 = 2 px).
    e_level = 0
    if reference_max_points is not None:
        while e_level < levels - 1 and len(ref_levels[e_level]) >= reference_max_points:
            e_level += 1

    def evidence(ML, T):
        return alignment_evidence(T, ML[e_level], ref_levels[e_level], tree(e_level),
                                  tolerance=inlier_tolerance * 2**e_level)

    convincing = 0.6 if min_inlier_ratio is None else max(0.6, 2.0 * min_inlier_ratio)
    p_level = min(2, levels - 1)
    ref_valid = ref_levels.valid
    ref_gray, _ = gray_level(ref_img, p_level, valid=ref_valid)

    # Fourier-Mellin on a canvas of about 256-320 px: level 1 for 512-640 px images, finer or coarser
    # for smaller or larger ones (its cost grows with the canvas area, its precision with the resolution).
    big = max(ref_img.shape[:2] + mov_img.shape[:2])
    fm_level = int(min(levels - 1, max(0, np.ceil(np.log2(big / 320.0)))))

    def search(ML, MI) -> list[tuple]:
        """Every generator in turn until one is convincing: [(inlier ratio, generator, init, refined, evidence,
        photometric agreement)]."""
        MV = ML.valid
        mov_gray, mov_valid = gray_level(MI, p_level, valid=MV)
        out: list[tuple] = []

        def attempt(gen, T_start, top):
            refined = refine_all(ML, T_start, top=top)
            ev = evidence(ML, refined[0])
            ncc = photometric_agreement(refined[0], ref_gray, mov_gray, level=p_level, moving_valid=mov_valid)
            out.append((ev.inlier_ratio, gen, T_start, refined, ev, ncc, top))
            return ev.inlier_ratio >= convincing and ncc >= CONVINCING_NCC

        for gen in generators:
            if gen == "edges":
                # Rotation samples every angle_step degrees: the best few get a short ICP at the search
                # level and are ranked by their tight inliers there (ICP's fitness under its wide gate is
                # near 1 for wrong hypotheses too); the best is refined from the coarsest level.
                g_level = min(3, levels - 1)
                # The search needs enough points to tell hypotheses apart: go finer until it has them.
                while g_level > 0 and (len(ML[g_level]) < 100 or len(ref_levels[g_level]) < 100):
                    g_level -= 1
                g_tree = tree(g_level)
                angles = np.array([0.0]) if model == "translation" else np.arange(0.0, 360.0, angle_step)
                Ts, score = edge_fft_hypotheses(ref_levels[g_level], ML[g_level], angles=angles)
                best = (-1.0, None)
                for k in np.argsort(-score)[:n_candidates]:
                    Tk = run_icp(ML, Ts[k], g_level, dist=3.0 * 2**g_level, n_iter=iterations,
                                 model_=search_model, final=False)[0]
                    sc = alignment_evidence(Tk, ML[g_level], ref_levels[g_level], g_tree,
                                            tolerance=2.0**g_level).inlier_ratio
                    if sc > best[0]:
                        best = (sc, Tk)
                if attempt(gen, best[1], None):
                    return out
                continue
            if gen == "fourier_mellin":
                hyps = fourier_mellin_hypotheses(ref_img, MI, level=fm_level,
                                                 model=model if model in ("translation", "rigid") else "similarity",
                                                 reference_valid=ref_valid, moving_valid=MV)
            else:
                hyps = orb_hypotheses(ref_img, MI, level=min(1, levels - 1), model=search_model, seed=seed,
                                      reference_valid=ref_valid, moving_valid=MV)
            # Intensity hypotheses are ranked by intensity (the 180° twin of Fourier-Mellin included) and are
            # usually within a few pixels: refined at full resolution alone (a first pass with twice the
            # correspondence distance), where the coarse levels of fine repetitive patterns (bricks) cannot
            # pull them away; one that would land on an earlier result is skipped.
            done = [t[3][0] for t in out]
            hyps = _unseen(hyps, done, MI.shape, min_px=2.0)
            if not hyps:
                continue
            h = max(hyps, key=lambda H: photometric_agreement(H, ref_gray, mov_gray, level=p_level,
                                                             moving_valid=mov_valid))
            # (A scale, or more, is estimated coarse to fine: a level-1 start leaves its bias.)
            # The start level follows the hypothesis's precision: Fourier-Mellin's is about a cell of the
            # level it ran at (its rotation step is one row of its log-polar image).
            start = max(START_LEVEL, fm_level - 1) if gen == "fourier_mellin" else START_LEVEL
            if attempt(gen, h, min(start, levels - 1) if model in ("translation", "rigid") else None):
                return out
        return out

    mirror_ratio = mirror_score = None
    if isinstance(init, str):
        if init not in ("auto", "global", "identity", "center"):
            raise InputError(f"init must be 'auto', 'global', 'identity', 'center' or a 3x3 matrix, got {init!r}")
        if init in ("auto", "global"):
            tried = search(mov_levels, mov_img)
            best_ratio = max((t[0] for t in tried), default=0.0)
            sure = any(t[0] >= convincing and t[5] >= CONVINCING_NCC for t in tried)
            if (min_inlier_ratio is not None and model in ("translation", "rigid", "similarity")
                    and best_ratio >= min_inlier_ratio and not sure):
                # Not convincing: is the moving image a mirror image of the reference? Its mirror, if so,
                # aligns better than it does (a rigid or similarity motion cannot mirror).
                mirrored = _MirroredPyramid(mov_levels)
                m_tried = search(mirrored, np.ascontiguousarray(mov_img[:, ::-1]))
                if m_tried:
                    m_best = max(m_tried, key=_rank)
                    mirror_ratio, mirror_score = m_best[0], _rank(m_best)
        else:
            T0 = (about_point(np.eye(3), image_center(mov_img.shape), image_center(ref_img.shape))
                  if init == "center" else np.eye(3))
            refined = refine_all(mov_levels, T0)
            ev = evidence(mov_levels, refined[0])
            tried = [(ev.inlier_ratio, "init", T0, refined, ev, float("nan"), None)]
    else:
        T0 = init  # checked above
        refined = refine_all(mov_levels, T0)
        ev = evidence(mov_levels, refined[0])
        tried = [(ev.inlier_ratio, "init", T0, refined, ev, float("nan"), None)]
    if not tried:
        raise RegistrationError("no hypothesis could be generated (too few edges and features in the images)")
    # Edges rank the hypotheses; the intensities between them break the ties of repetitive patterns.
    ratio, gen, T0, refined, ev, ncc, top = max(tried, key=_rank)
    if callback is not None:  # replay the winner's refinement for the callback (the same steps)
        refined = refine_all(mov_levels, T0, cb=callback, top=top)
    T, fit, rmse, total, conv = refined
    seconds = time.perf_counter() - start
    overlap = ev.overlap_points / max(ev.moving_points, 1)
    need = max(10, int(np.ceil(0.02 * ev.moving_points)))
    if fit == 0.0 or ev.overlap_points < need:
        raise RegistrationError(f"registration found no overlap between the images: {ev.overlap_points} of "
                                f"{ev.moving_points} moving edge points land on the reference (at least {need} needed)")
    if mirror_score is not None and mirror_score > MIRROR_FACTOR * _rank((ratio, gen, T0, refined, ev, ncc, top)):
        raise RegistrationError(
            f"registration refused: the moving image is a mirror image of the reference (its mirror aligns "
            f"{100 * mirror_ratio:.1f}% of the edge points within {inlier_tolerance:g} px, the image itself "
            f"{100 * ratio:.1f}%, with intensities agreeing less)")
    chance = ev.chance_ratio
    if min_inlier_ratio is not None and min_inlier_ratio > 0 and ratio < CHANCE_FACTOR * chance:
        raise RegistrationError(
            f"registration refused: the best alignment's {100 * ratio:.1f}% of tight, direction-consistent edge "
            f"points is no better than chance ({100 * chance:.1f}% expected from unrelated content at the same "
            f"distances); the images do not show the same scene under a {model} motion")
    if min_inlier_ratio is not None and ratio < min_inlier_ratio:
        raise RegistrationError(
            f"registration refused: the best alignment puts only {100 * ratio:.1f}% of the overlapping edge points "
            f"within {inlier_tolerance:g} px of a reference edge of the same direction (min_inlier_ratio "
            f"{min_inlier_ratio:g}); the images do not show the same scene under a {model} motion")
    return RegistrationResult(matrix=T, fitness=fit, inlier_rmse=rmse, iterations=total, converged=conv,
                              backend=backend, seconds=seconds, inlier_ratio=ratio, chance_ratio=ev.chance_ratio,
                              overlap=overlap, generator=gen,
                              info={"moving_points": len(mov_levels[0]), "reference_points": len(ref_levels[0]),
                                    "hypotheses": [{"generator": t[1], "inlier_ratio": t[0], "photometric_ncc": t[5]}
                                                   for t in tried],
                                    "mirror_inlier_ratio": mirror_ratio})
