"""Registration of point clouds: :func:`icp`, its options checked, its voxel schedule run at each size (each by
the ICP step of one backend, :func:`~pcreg.registration.steps.icp_step`), and :func:`voxel_downsample`.
:mod:`pcreg.registration.api` gives them beside ``register`` for images."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from .._calls import interrupts_unwrapped
from ..errors import InputError, RegistrationError
from ..validation import check_callable, check_matrix, short_repr
from .icp_options import METRICS, WEIGHTS, ICPOptions, VoxelSchedule, refuse_a_line_for_open3d
from .inputs import check_cloud
from .closed_forms import check_paired_rotation, check_rotation_pairs
from .reference import LINEARISED_METRICS, check_paired_normals, check_progress, check_rank, check_support, scores_at
from .result import IcpIteration, RegistrationResult
from .steps import BACKENDS, IcpSettings, StepCall, icp_step, refuse_for_open3d
from .transforms import apply, check_model

__all__ = ["check_init", "icp", "voxel_downsample"]


def _check_normals(normals: np.ndarray) -> None:
    """An :class:`InputError` for target normals that cannot fix a motion
    (:func:`~pcreg.registration.normal_steps.normals_problem`)."""
    from .normal_steps import normals_problem

    problem = normals_problem(normals)
    if problem is not None:
        raise InputError(f"target_normals: {problem}")


def check_init(T: np.ndarray, model: str) -> np.ndarray:
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
    """Mean of the points in each occupied cube of side ``voxel``, the cubes starting at the cloud's lowest
    coordinates (as Open3D's ``voxel_down_sample`` averages, on another grid: its legacy one starts half a voxel
    lower, its tensor one at the origin, so the same cloud keeps other means and counts; 988, 1254 and 987 of
    5,000 random points in a cube of 10 at a voxel of 1)."""
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
    T = np.eye(dim + 1) if init is None else check_init(check_matrix(init, "init", dim + 1), options.model)
    with interrupts_unwrapped():  # Ctrl-C in a compiled kernel: the KeyboardInterrupt, not numba's SystemError
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
        tolerance = options.stopping_rmse(src, tgt)
        total_iter = 0
        for i, (s, t, d, n) in enumerate(schedule):
            scale_start = T
            r = step(s, t, T, settings, StepCall(max_correspondence_distance=d, max_iteration=n,
                                                 relative_rmse=tolerance, level=len(schedule) - 1 - i,
                                                 callback=callback,
                                                 target_normals=target_normals if options.schedule is None else None))
            T = r.matrix
            total_iter = -1 if (r.iterations < 0 or total_iter < 0) else total_iter + r.iterations
        seconds = time.perf_counter() - start
        if r.fitness == 0:  # as Open3D, no pair moved nothing: a transform no point supports is no registration
            _refuse_unpaired(np.array_equal(T, start_pose), schedule[-1][2], options, tgt)
        _check_result(T, r, (s, t, d), options, moved=not np.array_equal(T, scale_start))  # the last scale's clouds
        if first is not None:  # one scale: a linearised metric takes no schedule
            check_progress(first, r, d, options.metric)
            check_paired_normals(T, s, t, target_normals, d, options.metric)
        return RegistrationResult(matrix=T, fitness=r.fitness, inlier_rmse=r.inlier_rmse, iterations=total_iter,
                                  converged=r.converged, backend=options.backend, seconds=seconds)


def _refuse_unpaired(stayed: bool, distance: float, options: ICPOptions, target: np.ndarray) -> None:
    """Refuse a result with no pair within the correspondence ``distance``: the run ``stayed`` where it started, or
    moved the source away. Open3D's point-to-plane step linearises the rotation about the origin: a run on clouds
    further from it than they are across (an ellipsoid 2 across, 90 from it) diverges where the reference's, which
    linearises about the pairs' mean there, does not; the refusal says so rather than ask for a nearer init."""
    where = "the ICP stopped where it started" if stayed else "the ICP moved the source away from the target (its steps diverged)"
    hint = " (give an init that brings the clouds together, or a larger max_correspondence_distance)"
    centre, across = target.mean(axis=0), float(np.linalg.norm(np.ptp(target, axis=0)))
    if not stayed and options.backend == "open3d" and options.metric == "point_to_plane" and np.linalg.norm(centre) > across:
        hint = (f"{hint[:-1]}; or else: Open3D's point-to-plane step linearises the rotation about the origin, "
                f"{np.linalg.norm(centre):.3g} from these clouds ({across:.3g} across), backend='reference' linearises "
                "about their mean, or move the clouds to the origin)")
    raise RegistrationError(f"registration refused: no source point lies within the correspondence distance {distance:g} "
                            f"of a target point; {where}{hint}")


def _check_result(T: np.ndarray, r, scale: tuple, options: ICPOptions, *, moved: bool) -> None:
    """Refuse a result ``T`` (the run's last result ``r``) that its last ``scale``'s clouds and correspondence distance
    do not determine: a shrinking model's collapse (:func:`~.closed_forms.check_support`), a rigid rotation on too few
    pairs (:func:`~.closed_forms.check_rotation_pairs`) or, in 3-D, on pairs that leave it free
    (:func:`~.closed_forms.check_paired_rotation`). A run stopped by its iterations that ``moved`` the source at that
    scale took steps all the same (Open3D's takes one on any pairs): it is judged as one that ended."""
    s, t, d = scale
    dim = s.shape[1]
    check_support(T, s, t, d, options.model, converged=r.converged is not False)
    stepped = r.converged is not False or moved
    check_rotation_pairs(r.fitness, len(s), options.model, dim, d, converged=stepped, metric=options.metric)
    if stepped and dim == 3 and options.model == "rigid" and options.metric == "point_to_point":
        check_paired_rotation(T, s, t, d)


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


