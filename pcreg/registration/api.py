"""Registration: ``icp`` for point clouds, ``register`` for images.

Both run the ICP step of one backend (:func:`~pcreg.registration.steps.icp_step`): the reference ICP
(``backend="reference"``, :mod:`pcreg.registration.reference`) or Open3D's (``backend="open3d"``,
:mod:`pcreg.registration.open3d_icp`), and return the same :class:`~pcreg.registration.result.RegistrationResult`.
``register`` reads as its steps: cloud pyramids (:mod:`.pyramid`), the coarse-to-fine refinement
(:mod:`.refine`), the global search (:mod:`.search`) and the plausibility test (:mod:`.plausibility`).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from ..errors import InputError, RegistrationError
from ..frame import low_bits_note
from ..validation import check_callable, check_int, check_matrix, short_repr
from .clouds import ImagePyramid, as_rgb_uint8, check_pyramid
from .config import DEFAULT_MIN_INLIER_RATIO, PyramidConfig, RegisterConfig
from .dense import (DENSE_GLOBAL_MODEL, DenseIteration, DenseOptions, DenseReference, DenseRegistrationResult,
                    GlobalStep, InitialGrid, finest_grid_shape, refine_field)
from .dense.levels import check_prepared
from .features import feature_check
from .global_search import orb_fit
from .plausibility import CHANCE_FACTOR, MIRROR_FACTOR, NARROWER, RICHER_MODEL, Plausibility, model_fit
from .pyramid import CloudPyramid
from .icp_options import METRICS, WEIGHTS, ICPOptions, VoxelSchedule, refuse_a_line_for_open3d
from .inputs import check_cloud
from .reference import (LINEARISED_METRICS, check_paired_normals, check_progress, check_rank, check_support,
                        scores_at)
from .refine import CoarseToFine
from .result import IcpIteration, ImageEvidence, RegistrationResult
from .search import CONVINCING_NCC, START_LEVEL, Candidate, GlobalSearch, Hypothesis
from .steps import BACKENDS, IcpSettings, StepCall, icp_step, refuse_for_open3d
from .transforms import about_point, apply, check_model, image_center

__all__ = ["CHANCE_FACTOR", "CONVINCING_NCC", "DEFAULT_MIN_INLIER_RATIO", "MIRROR_FACTOR", "START_LEVEL",
           "check_cloud", "icp", "register", "register_dense", "voxel_downsample"]


# ---------------------------------------------------------------------------------------------------
# Point clouds
# ---------------------------------------------------------------------------------------------------

def _check_normals(normals: np.ndarray) -> None:
    """An :class:`InputError` for target normals that cannot fix a motion
    (:func:`~pcreg.registration.normal_steps.normals_problem`)."""
    from .normal_steps import normals_problem

    problem = normals_problem(normals)
    if problem is not None:
        raise InputError(f"target_normals: {problem}")


def _check_init(T: np.ndarray, model: str) -> np.ndarray:
    """``T``, an ICP's initial guess, when the ``model`` can hold it (every update keeps the kind of transform
    the guess is): rigid for ``translation`` and ``rigid`` (:func:`~pcreg.registration.transforms.rigid_problem`),
    without a projection's last row for the rest but ``projective``, a rotation times a scale for ``similarity``;
    else an :class:`InputError`."""
    from .transforms import ROTATION_TOLERANCE, rigid_problem

    d = T.shape[0] - 1
    if model in ("translation", "rigid"):
        problem = rigid_problem(T)
        if problem is not None:
            raise InputError(f"init: {problem}, and the {model} ICP would return it as one")
    elif model != "projective" and np.abs(T[d] - np.eye(d + 1)[d]).max() > 1e-12:
        raise InputError(f"init: its last row is {T[d].tolist()}, a projection's; the {model} ICP keeps it affine")
    if model == "similarity":
        det = float(np.linalg.det(T[:d, :d]))  # not 0: the init is checked invertible
        R = T[:d, :d] / abs(det) ** (1 / d)
        if det < 0 or np.abs(R.T @ R - np.eye(d)).max() > ROTATION_TOLERANCE:
            raise InputError("init: its linear block is not a rotation times a scale (a reflection, a shear or unequal "
                             "scales), and the similarity ICP would return it as one")
    return T


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


def _check_options(backend: str, model: str, dim: int, weights: str, metric: str) -> None:
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise InputError(f"unknown backend {short_repr(backend)}; choose one of {', '.join(BACKENDS)}")
    check_model(model, dim)
    if not isinstance(weights, str) or weights not in WEIGHTS:
        raise InputError(f"unknown robust weights {short_repr(weights)}; choose one of {', '.join(WEIGHTS)}")
    if not isinstance(metric, str) or metric not in METRICS:
        raise InputError(f"unknown metric {short_repr(metric)}; choose one of {', '.join(METRICS)}")


#: ``pcreg.icp``'s keyword options before 0.2.0, each now a field of :class:`ICPOptions` (or of its
#: :class:`VoxelSchedule`); still taken, with a :class:`DeprecationWarning`, until 0.3.0.
_ICP_SCHEDULE_KEYWORDS = ("voxel_sizes", "max_correspondence_distances", "max_iterations")
_ICP_LEGACY_KEYWORDS = ("backend", "model", "max_correspondence_distance", "max_iteration", "relative_fitness",
                        "relative_rmse", "weights", "trim_fraction", "metric", "rotation", "count_iterations",
                        *_ICP_SCHEDULE_KEYWORDS)


def _legacy_icp_options(options: ICPOptions | None, legacy: dict) -> ICPOptions:
    """The :class:`ICPOptions` that ``pcreg.icp``'s keywords of before 0.2.0 (``legacy``) spell, with a
    :class:`DeprecationWarning` naming the new spelling; an unknown keyword is a TypeError, as Python's own."""
    import warnings

    unknown = sorted(set(legacy) - set(_ICP_LEGACY_KEYWORDS))
    if unknown:
        raise TypeError(f"icp() got an unexpected keyword argument {unknown[0]!r}")
    if options is not None:
        raise TypeError("icp() takes its options either as an ICPOptions or as keywords, not both")
    fields = {k: v for k, v in legacy.items() if k not in _ICP_SCHEDULE_KEYWORDS}
    spelled = ", ".join(f"{k}=..." for k in fields)
    if legacy.get("voxel_sizes") is not None:
        fields["schedule"] = VoxelSchedule(legacy["voxel_sizes"], legacy.get("max_correspondence_distances"),
                                           legacy.get("max_iterations"))
        spelled += (", " if spelled else "") + "schedule=pcreg.VoxelSchedule(...)"
    elif any(legacy.get(k) is not None for k in _ICP_SCHEDULE_KEYWORDS[1:]):
        raise InputError("max_correspondence_distances and max_iterations need voxel_sizes")
    warnings.warn(f"pcreg.icp(..., {', '.join(sorted(legacy))}=...) is deprecated since 0.2.0 and will be removed in "
                  f"0.3.0; pass pcreg.icp(source, target, pcreg.ICPOptions({spelled}))",
                  DeprecationWarning, stacklevel=3)
    return ICPOptions(**fields)


def icp(source_points: np.ndarray, target_points: np.ndarray, options: ICPOptions | None = None, *,
        init: np.ndarray | None = None, target_normals: np.ndarray | None = None,
        callback: Callable[[IcpIteration], None] | None = None, **deprecated) -> RegistrationResult:
    """Register two point clouds: the transform that maps ``source_points`` onto ``target_points``.

    source_points : (N, d), target_points : (M, d) float, d = 2 or 3, finite.
    options : the backend, model, correspondence distance, stopping rule, robust weights, metric and
        coarse-to-fine schedule (:class:`~pcreg.registration.icp_options.ICPOptions`, every default there).
    init : (d+1, d+1) initial ``T_target_source`` (None: the identity).
    target_normals : (M, d) the target's normals, for ``metric="point_to_line"`` (2-D, reference backend)
        and ``metric="point_to_plane"`` (3-D, rigid, either backend); no schedule with either.
    callback : called with an :class:`~pcreg.registration.result.IcpIteration` after every iteration.
    deprecated : the keyword options of before 0.2.0 (``backend=``, ``model=``, ``max_iteration=``,
        ``voxel_sizes=``, ...): still taken until 0.3.0, with a :class:`DeprecationWarning` naming the
        :class:`ICPOptions` that spells them.

    Returns a :class:`RegistrationResult` whose ``matrix`` is (d+1, d+1) ``T_target_source``.
    """
    if deprecated:
        options = _legacy_icp_options(options, deprecated)
    elif options is None:
        options = ICPOptions()
    if not isinstance(options, ICPOptions):
        raise InputError(f"options must be a pcreg.ICPOptions, got {type(options).__name__}")
    src = check_cloud(source_points, "source")
    tgt = check_cloud(target_points, "target")
    if src.shape[1] != tgt.shape[1]:
        raise InputError(f"source is {src.shape[1]}-D but target is {tgt.shape[1]}-D")
    dim = src.shape[1]
    _check_icp_options(options, dim, target_normals)
    check_callable(callback, "callback")
    check_rank(src, options.model)
    check_rank(tgt, options.model)
    if options.backend == "open3d" and dim == 2:
        refuse_a_line_for_open3d(src, tgt)
    if target_normals is not None:
        target_normals = check_cloud(target_normals, "target_normals")
        if target_normals.shape != tgt.shape:
            raise InputError("target_normals must have the target's shape")
        _check_normals(target_normals)
    T = np.eye(dim + 1) if init is None else _check_init(check_matrix(init, "init", dim + 1), options.model)
    max_correspondence_distance = _check_distance(src, tgt, T, options.max_correspondence_distance)
    start_pose = T
    start = time.perf_counter()
    first = scores_at(src, tgt, T, max_correspondence_distance) if options.metric in LINEARISED_METRICS else None
    schedule = _voxel_schedule(src, tgt, options.schedule, distance=max_correspondence_distance,
                               max_iteration=options.max_iteration)
    if options.schedule is not None:
        _check_last_scale(schedule[-1], options.schedule.voxel_sizes[-1], options.model)
    step = icp_step(options.backend)
    settings = IcpSettings(model=options.model, relative_fitness=options.relative_fitness, weights=options.weights,
                           trim_fraction=options.trim_fraction, metric=options.metric, rotation=options.rotation,
                           stepwise=options.count_iterations)
    total_iter = 0
    for i, (s, t, d, n) in enumerate(schedule):
        r = step(s, t, T, settings, StepCall(max_correspondence_distance=d, max_iteration=n,
                                             relative_rmse=options.relative_rmse, level=len(schedule) - 1 - i,
                                             callback=callback,
                                             target_normals=target_normals if options.schedule is None else None))
        T = r.matrix
        total_iter = -1 if (r.iterations < 0 or total_iter < 0) else total_iter + r.iterations
    seconds = time.perf_counter() - start
    if r.fitness == 0:  # as Open3D, no pair moved nothing: a transform no point supports is no registration
        where = ("the ICP stopped where it started" if np.array_equal(T, start_pose) else
                 "the ICP moved the source away from the target (its steps diverged)")
        raise RegistrationError(f"registration refused: no source point lies within the correspondence distance "
                                f"{schedule[-1][2]:g} of a target point; {where} (give an init "
                                "that brings the clouds together, or a larger max_correspondence_distance)")
    check_support(T, s, t, d, options.model, converged=r.converged is not False)  # the last scale's clouds
    if first is not None:  # one scale: a linearised metric takes no schedule
        check_progress(first, r, d, options.metric)
        check_paired_normals(T, s, t, target_normals, d, options.metric)
    return RegistrationResult(matrix=T, fitness=r.fitness, inlier_rmse=r.inlier_rmse, iterations=total_iter,
                              converged=r.converged, backend=options.backend, seconds=seconds)


def _check_icp_options(options: ICPOptions, dim: int, target_normals) -> None:
    """:class:`InputError` for an option :func:`icp` cannot honour with clouds of ``dim`` dimensions
    (``options`` checked its values when it was made)."""
    check_model(options.model, dim)
    if options.backend == "open3d" and target_normals is not None:
        refuse_for_open3d(target_normals=target_normals, metric=options.metric)
    if options.rotation == "quaternion" and (dim != 3 or options.model != "rigid"):
        raise InputError("rotation='quaternion' (Horn's closed form) is for the rigid model of 3-D clouds")
    if options.metric == "point_to_line" and (dim != 2 or target_normals is None or options.schedule is not None):
        raise InputError("metric='point_to_line' needs 2-D clouds, target_normals and no schedule "
                         "(normals cannot follow a voxel downsampling)")
    if options.metric == "point_to_plane" and (dim != 3 or target_normals is None or options.schedule is not None
                                               or options.model != "rigid"):
        raise InputError("metric='point_to_plane' needs 3-D clouds, target_normals, the rigid model and no "
                         "schedule (normals cannot follow a voxel downsampling)")
    if target_normals is not None and options.metric not in ("point_to_line", "point_to_plane"):
        raise InputError("target_normals are used only by metric='point_to_line' or 'point_to_plane'")


def _check_distance(src: np.ndarray, tgt: np.ndarray, T: np.ndarray, max_correspondence_distance: float | None
                    ) -> float:
    """``max_correspondence_distance``, or where it is None the joint bounding-box diagonal of the source
    moved by ``T`` and the target, plus 1."""
    if max_correspondence_distance is None:
        both = np.vstack([apply(T, src), tgt])
        max_correspondence_distance = float(np.linalg.norm(both.max(axis=0) - both.min(axis=0))) + 1.0
    if not max_correspondence_distance > 0:
        raise InputError("max_correspondence_distance must be > 0")
    return max_correspondence_distance


def _voxel_schedule(src: np.ndarray, tgt: np.ndarray, schedule: VoxelSchedule | None, *, distance: float,
                    max_iteration: int) -> list[tuple]:
    """[(source, target, correspondence distance, iterations)] per scale, coarsest first (one scale, the
    clouds themselves, without a schedule)."""
    if schedule is None:
        return [(src, tgt, distance, max_iteration)]
    sizes = schedule.voxel_sizes
    dists = list(schedule.max_correspondence_distances or [2.0 * v for v in sizes])
    iters = list(schedule.max_iterations or [max_iteration] * len(sizes))
    return [(voxel_downsample(src, v), voxel_downsample(tgt, v), d, n) for v, d, n in zip(sizes, dists, iters)]


def _check_last_scale(scale: tuple, voxel: float, model: str) -> None:
    """An :class:`InputError` when the schedule's last voxel size, the one whose ICP gives the result, leaves
    either cloud too few or too degenerate points for the ``model`` (one point: the reference ICP returned the
    start unchanged, Open3D's a shift with no rotation, both with a fitness of 1)."""
    for name, points in (("source", scale[0]), ("target", scale[1])):
        try:
            check_rank(points, model)
        except RegistrationError as exc:
            raise InputError(f"voxel_sizes: at the last size, {voxel:g}, the {name} is downsampled to {len(points)} "
                             f"point(s): {exc}") from None


# ---------------------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------------------

def register(reference_image: np.ndarray, moving_image: np.ndarray, *, config: RegisterConfig = RegisterConfig(),
             model: str | None = None, backend: str | None = None, init: str | np.ndarray | None = None,
             reference_mask: np.ndarray | str | None = "auto", moving_mask: np.ndarray | str | None = "auto",
             reference_pyramid: ImagePyramid | None = None, moving_pyramid: ImagePyramid | None = None,
             callback: Callable[[IcpIteration], None] | None = None) -> RegistrationResult:
    """Register ``moving_image`` to ``reference_image``: the returned ``matrix`` is ``T_ref_mov``.

    Both images become edge clouds (:func:`pcreg.image_cloud`) at pyramid levels 0..levels-1
    (:class:`~pcreg.registration.pyramid.CloudPyramid`). With ``init="auto"`` (or ``"global"``) hypotheses
    come from the search's ``generators``, tried in order until one is convincing, each refined coarse to
    fine (:class:`~pcreg.registration.search.GlobalSearch`); ``init="identity"``, ``"center"`` (image
    centres aligned) or a 3x3 matrix replaces the search by that one hypothesis. The winner must pass the
    plausibility test (:mod:`pcreg.registration.plausibility`): unrelated images, noise and mirror images
    raise :class:`~pcreg.errors.RegistrationError` with a one-line reason.

    reference_image, moving_image : (H, W, 3) uint8 RGB (also gray, uint16, float in [0, 1]); the
        sizes may differ.
    config : the options, by step (:class:`~pcreg.registration.config.RegisterConfig`: the pyramid, the
        search, the ICP and its backend, the plausibility test), checked when the config was made.
        Its ``model="dense"`` returns the global similarity (this function, with the rest of the config)
        refined by a dense field (:func:`pcreg.register_dense`), a
        :class:`~pcreg.registration.dense.DenseRegistrationResult`.
    model, backend : shorthands for ``config.replace(model=..., backend=...)``; None keeps the config's.
    init : None keeps the config's ``search.init``; one of its names replaces it; a 3x3 ``T_ref_mov``
        is the one hypothesis, refined instead of searching (a transform the model can hold, as :func:`icp`'s).
    reference_mask, moving_mask : usable pixels, ``"auto"`` (ignore black padding) or None.
    reference_pyramid, moving_pyramid : the images' :func:`~pcreg.registration.clouds.image_pyramid` (same ``levels``,
        ``sampler``, mask and ``canny_percentile``), when the caller keeps them to reuse (a frame of a
        stream is the moving image once and the reference once); None builds the clouds here. The
        clouds are the same (to OpenCV's float32 rounding of the gradient magnitude).
    callback : called with each :class:`~pcreg.registration.result.IcpIteration` of the winning
        hypothesis's refinement, in order, once the search has chosen it (before the plausibility test),
        with the same numbers as without a callback.

    Returns a :class:`RegistrationResult` with ``inlier_ratio``, ``overlap`` and ``generator`` (which
    generator's hypothesis won, or ``"init"``) besides the ICP's own figures.
    """
    return _register(reference_image, moving_image, config=config, model=model, backend=backend, init=init,
                     masks=(reference_mask, moving_mask), pyramids=(reference_pyramid, moving_pyramid), callback=callback,
                     judged=False)[0]


def register_judged(reference_image: np.ndarray, moving_image: np.ndarray, *, config: RegisterConfig = RegisterConfig(),
                    backend: str | None = None, callback: Callable[[IcpIteration], None] | None = None
                    ) -> tuple[RegistrationResult, RegistrationError | None]:
    """:func:`register` with its plausibility test's refusal returned, from one search: ``(result, None)`` where
    :func:`register` returns ``result``; ``(pose, refusal)`` where it raises ``refusal``, ``pose`` as it returns it with
    the test off (``min_inlier_ratio=None``), whose refusals (a transform no view can have, too few edge points, no
    overlap) are raised. A cross-check reports a refused pair's poses so (:func:`pcreg.crosscheck`)."""
    return _register(reference_image, moving_image, config=config, model=None, backend=backend, init=None,
                     masks=("auto", "auto"), pyramids=(None, None), callback=callback, judged=True)


def _register(reference_image, moving_image, *, config: RegisterConfig, model, backend, init, masks: tuple,
              pyramids: tuple, callback, judged: bool) -> tuple:
    """:func:`register`'s steps: the result and, ``judged``, the plausibility test's refusal (else raised)."""
    config = _configured(config, model=model, backend=backend, init=init)
    reference_mask, moving_mask = masks
    start_matrix = None if init is None or isinstance(init, str) else check_matrix(init, "init", 3)
    if start_matrix is not None and config.model != "dense":  # dense: its global step's model checks it
        _check_init(start_matrix, config.model)
    if config.model == "dense":
        if any(m is not None and not isinstance(m, str) for m in (reference_mask, moving_mask)):
            raise InputError("the dense model cannot leave masked pixels out (it leaves black padding out): give "
                             "images without a mask (transparent pixels), or a global model")
        return _register_dense_model(reference_image, moving_image, config, start_matrix, judged=judged)
    ref_img, mov_img = as_rgb_uint8(reference_image, name="reference image"), as_rgb_uint8(moving_image, name="moving image")
    _check_inputs(ref_img, mov_img, config.pyramid, reference_mask, moving_mask, callback)
    start = time.perf_counter()
    p = config.pyramid
    reference, moving = _pyramids(ref_img, mov_img, *pyramids, levels=p.levels, sampler=p.sampler,
                                  canny_percentile=p.canny_percentile, seed=config.search.seed,
                                  masks=(reference_mask, moving_mask), max_points=(p.reference_max_points, p.max_points),
                                  given=(reference_image, moving_image))
    best, tried, mirror, test, search = _search(reference, moving, config, config.search.init if start_matrix is None
                                                else start_matrix, keep_iterations=callback is not None)
    if callback is not None:
        for iteration in best.iterations:
            callback(iteration)
    try:
        evidence, refusal = test.check(best, mirror=mirror, shape=mov_img.shape, moving=moving), None
    except RegistrationError as exc:  # judged: the pose as the test off returns it (what that refuses is raised)
        if not judged:
            raise
        evidence, refusal = test.off().check(best, shape=mov_img.shape, moving=moving), exc
    checks = _checks(reference, moving, config, best, test, search, mov_img.shape) if refusal is None else (None, None)
    return _result(best, evidence, tried, mirror, backend=config.backend, seconds=time.perf_counter() - start,
                   points=(len(moving[0]), len(reference[0])), checks=checks), refusal


def _checks(reference: CloudPyramid, moving: CloudPyramid, config: RegisterConfig, best: Candidate,
            test: Plausibility, search: GlobalSearch, shape: tuple[int, ...]) -> tuple:
    """With the test and ``model_check`` on ((None, None) otherwise): :func:`~.plausibility.model_fit` of a model
    narrower than the projective one (ORB's homography a second start: a wrong result is not near the projective
    fit that shows it), :func:`~.features.feature_check` of a projective result, which no richer model checks
    (run on every model it took two to four times the registration's time: docs/benchmarks.md). The model check
    shares the search's KD-trees of the reference and its ORB matches at level 1, where the search made them."""
    if not config.plausibility.model_check or config.plausibility.min_inlier_ratio is None:
        return None, None
    if config.model in NARROWER:
        # pcreg's own step (Open3D's has no projective model) onto the search's reference trees
        richer = _refiner(reference, config, RICHER_MODEL, "reference", trees=search.refiner.trees, dlt="normal")
        orb = orb_fit(search.orb_matches(moving, 1), model=RICHER_MODEL, seed=config.search.seed)
        return model_fit(best, moving, richer, test, shape, starts=tuple(orb)), None
    return None, feature_check(reference.image, moving.image, best.refined.matrix, reference_valid=reference.valid,
                               moving_valid=moving.valid, seed=config.search.seed)


def _refiner(reference: CloudPyramid, config: RegisterConfig, model: str, backend: str, *,
             point_to_line: bool = False, trees: dict | None = None, dlt: str = "svd") -> CoarseToFine:
    """The coarse-to-fine ICP of ``model`` with ``backend``'s step onto ``reference``, with ``config``'s ICP options
    (``trees``: another refinement's KD-trees of ``reference``, shared; ``dlt``: the projective step's solve)."""
    icp = config.icp
    return CoarseToFine(reference, icp_step(backend),
                        settings=IcpSettings(model=model, relative_fitness=icp.relative_fitness, weights=icp.weights, dlt=dlt),
                        max_correspondence_distance=icp.max_correspondence_distance, iterations=icp.iterations,
                        relative_rmse=icp.relative_rmse, point_to_line=point_to_line, trees=trees)


def _configured(config: RegisterConfig, *, model: str | None, backend: str | None, init) -> RegisterConfig:
    """:func:`register`'s ``config`` with its shorthands (``model``, ``backend``, an ``init`` name) set in
    it: the one place they become options, checked by the config."""
    if not isinstance(config, RegisterConfig):
        raise InputError(f"config must be a pcreg.RegisterConfig, got {type(config).__name__}")
    changes = {name: value for name, value in (("model", model), ("backend", backend)) if value is not None}
    if isinstance(init, str):
        changes["init"] = init
    return config.replace(**changes) if changes else config


def _register_dense_model(reference_image, moving_image, config: RegisterConfig, start_matrix, *, judged: bool) -> tuple:
    """``model="dense"``: the global similarity (:func:`register`, with the rest of ``config``; ``judged``: its
    refusal returned, else raised), refined by a dense field (:func:`pcreg.register_dense`); returns its
    :class:`~pcreg.registration.dense.DenseRegistrationResult` and the refusal."""
    start, refusal = _register(reference_image, moving_image, config=config.replace(model=DENSE_GLOBAL_MODEL, model_check=False),
                               model=None, backend=None, init=start_matrix, masks=("auto", "auto"), pyramids=(None, None),
                               callback=None, judged=judged)
    return register_dense(reference_image, moving_image, global_result=start,
                          options=DenseOptions(seed=config.search.seed, global_step=GlobalStep(backend=config.backend))), refusal


def register_dense(reference_image: np.ndarray, moving_image: np.ndarray, *, options: DenseOptions = DenseOptions(),
                   global_result: RegistrationResult | np.ndarray | None = None,
                   initial: DenseRegistrationResult | np.ndarray | None = None,
                   prepared: DenseReference | None = None,
                   callback: Callable[[DenseIteration], None] | None = None) -> DenseRegistrationResult:
    """Register ``moving_image`` to ``reference_image`` with a smooth dense field (:mod:`pcreg.registration.dense`).

    reference_image, moving_image : (H, W, 3) uint8 RGB of the same size (also gray, uint16, float).
    options : :class:`~pcreg.registration.dense.DenseOptions`, the dense step's and the global step's
        options (checked when made, and here against the images' size).
    global_result : the global step's result or a 3x3 ``T_ref_mov``; None runs :func:`pcreg.register`
        with the options' :class:`~pcreg.registration.dense.GlobalStep` and ``seed`` (its :class:`~pcreg.errors.RegistrationError` propagates).
    initial : start from an earlier registration of the same reference (its result or its ``grid``),
        e.g. the previous video frame's: its displacements, added to *this* registration's global
        transform (give the earlier one's), start level ``options.initial_level`` with the gate
        ``radius``, and the coarser levels are skipped, so the frame may have moved ``radius *
        2^initial_level`` px (12) from the earlier field, against 48 px from the global transform. Same
        image size, ``finest_level`` and ``membrane.grid_spacing`` (the grid's shape is checked). Measured in use:
        :class:`pcreg.pipeline.stream.DenseStep`.
    prepared : ``reference_image`` prepared once for many registrations
        (:func:`~pcreg.registration.dense.prepare_reference` with the same options), which saves building
        its pyramid each time (a stream's key frame: :class:`pcreg.Propagator`); refused when it was made
        from another image. The same result as without it.
    callback : called with a :class:`~pcreg.registration.dense.DenseIteration` after every iteration.
    Returns a :class:`~pcreg.registration.dense.DenseRegistrationResult`.
    """
    t_start = time.perf_counter()
    ref = as_rgb_uint8(reference_image, name="reference image")
    mov = as_rgb_uint8(moving_image, name="moving image")
    if ref.shape != mov.shape:
        raise InputError(f"dense registration needs images of one size, got {ref.shape[:2]} and {mov.shape[:2]}")
    if not isinstance(options, DenseOptions):
        raise InputError(f"options must be a pcreg.DenseOptions, got {type(options).__name__}")
    options.check_shape(ref.shape)
    if prepared is not None:
        check_prepared(prepared, ref, options)
    check_callable(callback, "callback")
    start = _initial_grid(initial, ref.shape, options)
    global_result, given_seconds = _global_step(ref, mov, global_result, options)
    return refine_field(ref, mov, global_result, options, callback=callback, started=t_start,
                        given_seconds=given_seconds, initial=start, prepared=prepared)


def _initial_grid(initial, shape: tuple[int, ...], options: DenseOptions) -> InitialGrid | None:
    """``register_dense``'s ``initial``, checked against the images and options, starting at
    ``options.initial_level`` (at least ``finest_level``, capped at the coarsest level)."""
    if initial is None:
        return None
    level = min(check_int(options.initial_level, "initial_level", lo=options.finest_level, hi=7), options.levels - 1)
    if isinstance(initial, DenseRegistrationResult):
        if initial.grid is None:
            raise InputError("initial: this dense result carries no grid to start from")
        grid = initial.grid
    else:
        raw = np.asarray(initial) if isinstance(initial, (np.ndarray, list, tuple)) else None
        if raw is None or raw.dtype.kind not in "iuf":
            raise InputError("initial must be a DenseRegistrationResult or a numeric (rows, columns, 2) grid of "
                             "displacements")
        grid = raw
    expected = finest_grid_shape(shape, options)
    if grid.shape != (*expected, 2):
        raise InputError(f"initial: a grid of shape {grid.shape}, but a registration of {shape[1]}x{shape[0]} "
                         f"images at finest_level {options.finest_level} and grid_spacing "
                         f"{options.membrane.grid_spacing:g} has {expected[0]}x{expected[1]} nodes: it must come from "
                         "one of the same size and options")
    with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: inf, refused below
        grid = np.array(grid, dtype=np.float32)
    if not np.all(np.isfinite(grid)):
        raise InputError("initial: the grid has non-finite displacements (or beyond float32's range)")
    return InitialGrid(grid, level)


def _given_global(global_result) -> RegistrationResult:
    """A given global step (a result, or a 3x3 ``T_ref_mov``) as a :class:`RegistrationResult`."""
    if isinstance(global_result, RegistrationResult):
        return global_result
    try:
        M = np.asarray(global_result, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("global_result must be a RegistrationResult or a finite invertible 3x3 matrix") from None
    if M.shape != (3, 3) or not np.all(np.isfinite(M)) or abs(np.linalg.det(M)) < 1e-12:
        raise InputError("global_result must be a RegistrationResult or a finite invertible 3x3 matrix")
    return RegistrationResult(matrix=M, fitness=float("nan"), inlier_rmse=float("nan"), iterations=0,
                              converged=True, backend="given", frames="T_ref_mov")


def _global_step(ref: np.ndarray, mov: np.ndarray, global_result, options: DenseOptions
                 ) -> tuple[RegistrationResult, float]:
    """The global step: the given one (with its seconds, counted in the dense result's), or
    :func:`pcreg.register`'s with ``options``' global step (its time is inside the dense step's own)."""
    if global_result is not None:
        given = _given_global(global_result)
        return given, float(given.seconds)
    step = options.global_step
    return register(ref, mov, config=step.config(options.seed), init=step.start), 0.0


def _result(best: Candidate, evidence, tried: list[Candidate], mirror: Candidate | None, *, backend: str,
            seconds: float, points: tuple[int, int], checks: tuple = (None, None)) -> RegistrationResult:
    """The winner as a :class:`RegistrationResult`; ``info`` lists every hypothesis tried."""
    r = best.refined
    return RegistrationResult(
        matrix=r.matrix, fitness=r.fitness, inlier_rmse=r.inlier_rmse, iterations=r.iterations,
        converged=r.converged, backend=backend, seconds=seconds, frames="T_ref_mov",
        evidence=ImageEvidence(evidence.inlier_ratio, evidence.chance_ratio, evidence.overlap, best.generator, *checks),
        info={"moving_points": points[0], "reference_points": points[1],
              "hypotheses": [{"generator": c.generator, "inlier_ratio": c.inlier_ratio,
                              "photometric_ncc": c.photometric_ncc} for c in tried],
              "mirror_inlier_ratio": None if mirror is None else mirror.inlier_ratio})


def _check_inputs(ref_img: np.ndarray, mov_img: np.ndarray, pyramid: PyramidConfig, reference_mask, moving_mask,
                  callback) -> None:
    """What :func:`register` takes besides its config, checked against the images (an :class:`InputError`
    for the first bad one)."""
    from .clouds import check_mask

    for img, name in ((ref_img, "the reference image"), (mov_img, "the moving image")):
        pyramid.check_shape(img.shape, name)
    check_mask(reference_mask, ref_img.shape, name="reference_mask")
    check_mask(moving_mask, mov_img.shape, name="moving_mask")
    check_callable(callback, "callback")


def _pyramids(ref_img: np.ndarray, mov_img: np.ndarray, reference_pyramid: ImagePyramid | None,
              moving_pyramid: ImagePyramid | None, *, levels: int, sampler: str, canny_percentile: float, seed: int,
              masks: tuple, max_points: tuple, given: tuple = (None, None)) -> tuple[CloudPyramid, CloudPyramid]:
    """The reference's and the moving image's cloud pyramids (seeds ``seed`` and ``seed + 1``), each level
    built when first used (a search that ends at level 1 never builds levels 2-3), drawn from the caller's
    :func:`~pcreg.registration.clouds.image_pyramid` where given. ``given``: the two images as the caller
    gave them, whose 16-bit values a refusal describes (:func:`~pcreg.frame.low_bits_note`)."""
    out = []
    for name, image, kept, mask, n, s in (("reference", ref_img, reference_pyramid, masks[0], max_points[0], seed),
                                          ("moving", mov_img, moving_pyramid, masks[1], max_points[1], seed + 1)):
        if kept is None:
            out.append(CloudPyramid.from_image(image, levels=levels, mask=mask, max_points=n, sampler=sampler,
                                               seed=s, canny_percentile=canny_percentile))
        else:
            kept = check_pyramid(image, kept, levels=levels, sampler=sampler, canny_percentile=canny_percentile,
                                 name=name)
            out.append(CloudPyramid.from_detections(image, kept, levels=levels, max_points=n, seed=s))
    for name, pyramid, image in zip(("reference", "moving"), out, given):
        if len(pyramid[0]) < 3:
            dark = low_bits_note(image)
            raise RegistrationError(f"the {name} image has no usable edges" + (f": {dark}" if dark else " (a flat or empty image?)"))
    return out[0], out[1]


def _search(reference: CloudPyramid, moving: CloudPyramid, config: RegisterConfig, init, *,
            keep_iterations: bool) -> tuple[Candidate, list[Candidate], Candidate | None, Plausibility, GlobalSearch]:
    """:func:`register`'s search: the coarse-to-fine ICP, the plausibility test and the hypotheses' search, each
    built from its part of ``config`` on the two pyramids, then the candidates refined from ``init`` (a name or a
    3x3 start, :func:`_candidates`). Returns the best candidate, every one tried, the mirrored image's best (or
    None), the test, which judges the best, and the search (whose ORB matches and reference trees the checks
    share). ``keep_iterations``: each candidate keeps its ICP iterations (a callback reports the best's, instead of
    refining it a second time)."""
    icp, plausibility, s = config.icp, config.plausibility, config.search
    refiner = _refiner(reference, config, config.model, icp.backend, point_to_line=icp.refine == "point_to_line")
    test = Plausibility(reference, refiner.tree, model=config.model, min_inlier_ratio=plausibility.min_inlier_ratio,
                        inlier_tolerance=plausibility.inlier_tolerance,
                        reference_max_points=config.pyramid.reference_max_points)
    search = GlobalSearch(refiner, test.measure, model=config.model, generators=s.generators, angle_step=s.angle_step,
                          n_candidates=s.n_candidates, seed=s.seed, convincing=test.convincing,
                          keep_iterations=keep_iterations)
    tried, mirror = _candidates(init, moving, refiner, test, search)
    if not tried:
        raise search.nothing_refined()
    best = max(tried, key=lambda c: c.score)  # edges rank the hypotheses; intensities break repetitive ties
    return best, tried, mirror, test, search


def _candidates(init, moving: CloudPyramid, refiner: CoarseToFine, test: Plausibility,
                search: GlobalSearch) -> tuple[list[Candidate], Candidate | None]:
    """The refined hypotheses (the search's, or the one ``init`` names) and, where the search was not
    convinced, the best of the mirrored image's (None when not searched)."""
    if isinstance(init, str):  # one of the config's names, checked there
        if init in ("auto", "global"):
            tried = search.run(moving)
            if not test.worth_a_mirror(tried, any(search.is_convincing(c) for c in tried)):
                return tried, None
            mirrored = search.run(moving.mirrored())
            return tried, (max(mirrored, key=lambda c: c.score) if mirrored else None)
        ref_shape = refiner.reference.image.shape
        init = (about_point(np.eye(3), image_center(moving.image.shape), image_center(ref_shape))
                if init == "center" else np.eye(3))
    refined, iterations = search.refine(moving, init)
    return [Candidate(Hypothesis("init", init), refined, test.measure(moving, refined.matrix),
                      iterations=iterations)], None
