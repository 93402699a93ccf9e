"""Open3D's point-to-point ICP behind pcreg's interface.

2-D clouds are lifted to the plane z = 0 and the 4x4 result is projected back, checking that its
out-of-plane part is negligible. The legacy API (``registration_icp``) reports neither iterations nor
convergence; when a per-iteration callback is asked for (recordings, cross-checks), pcreg runs it one
iteration at a time and applies Open3D's own stopping rule between steps, which gives the same
transforms at about four times the cost (to rounding: an ill-conditioned step, a point-to-plane system of three
pairs, can grow it until the two runs part, one diverging where the other converges). Without a callback it runs in one call, reports
``iterations = -1`` and decides ``converged`` by one more step (the rule holds at the returned transform).
The tensor API's ``multi_scale_icp`` (Float64) serves voxel-pyramid registration of 3-D scans.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..errors import InputError, RegistrationError
from .choices import OPEN3D_MODELS, check_open3d_model
from .inputs import backend_inputs
from .result import IcpIteration, RegistrationResult
from .transforms import lift_to_3d, project_to_2d

if TYPE_CHECKING:
    from .icp_options import ICPOptions

#: The motion models Open3D's point-to-point estimation fits (:data:`~pcreg.registration.choices.OPEN3D_MODELS`).
SUPPORTED = OPEN3D_MODELS


def _o3d():
    import open3d as o3d

    return o3d


def to_pointcloud(points: np.ndarray):
    """(N, 2|3) float64 -> ``open3d.geometry.PointCloud`` (2-D lifted to z = 0)."""
    o3d = _o3d()
    p = np.asarray(points, dtype=np.float64)
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))


check_model = check_open3d_model


def _result(matrix: np.ndarray, r, iterations: int, converged: bool, start: float) -> RegistrationResult:
    return RegistrationResult(matrix=matrix, fitness=float(r.fitness), inlier_rmse=float(r.inlier_rmse),
                              iterations=iterations, converged=converged, backend="open3d",
                              seconds=time.perf_counter() - start)


def _estimation(options: ICPOptions, target: np.ndarray, target_pcd, target_normals: np.ndarray | None):
    """``(estimation, Open3D's target cloud)`` for ``options.metric``: point-to-plane on a copy of the
    target that carries its normals (3-D, rigid), else point-to-point on ``target_pcd`` (made when None)."""
    reg = _o3d().pipelines.registration
    if options.metric == "point_to_plane":
        if target_normals is None or target.shape[1] != 3 or options.model != "rigid":
            raise InputError("Open3D's point-to-plane ICP needs 3-D clouds, the target's normals and the rigid model")
        tgt = to_pointcloud(target)  # a copy of its own: the normals go with it
        tgt.normals = _o3d().utility.Vector3dVector(np.asarray(target_normals, dtype=np.float64))
        return reg.TransformationEstimationPointToPlane(), tgt
    tgt = target_pcd if target_pcd is not None else to_pointcloud(target)
    return reg.TransformationEstimationPointToPoint(with_scaling=(options.model == "similarity")), tgt


def _check_finite(T4: np.ndarray, start: np.ndarray) -> None:
    """A :class:`RegistrationError` when Open3D's ICP, started at ``start``, returned a transform with NaN or inf
    entries: its similarity estimation divides by the spread of the pairs' target points, which is 0 once a scale
    of 0 has put every source point on one target point."""
    if np.all(np.isfinite(T4)):
        return
    scale = abs(float(np.linalg.det(start[:3, :3]))) ** (1 / 3) if np.all(np.isfinite(start)) else float("nan")
    raise RegistrationError(f"registration refused: Open3D's ICP returned a transform with NaN entries, from a pose "
                            f"of scale {scale:.3g} (a similarity scale that collapsed to 0 leaves the pairs one "
                            "target point, from which no transform follows)")


def icp_open3d(source: np.ndarray, target: np.ndarray, options: ICPOptions, *, init: np.ndarray | None = None,
               callback: Callable[[IcpIteration], None] | None = None, level: int = 0, clouds: tuple | None = None,
               check_convergence: bool = True, target_normals: np.ndarray | None = None) -> RegistrationResult:
    """One Open3D ICP run at one scale: a :class:`RegistrationResult` (``matrix`` is ``T_target_source``).

    options : the model (rigid or similarity), ``max_correspondence_distance`` (a number here) and the
        stopping rule (:class:`~pcreg.registration.icp_options.ICPOptions`); ``count_iterations`` runs
        Open3D one iteration at a time (as a ``callback`` does), so that ``iterations`` and ``converged``
        are exact.
    clouds : Open3D's copies of ``source`` and ``target`` (:func:`to_pointcloud`), made once for many
        runs (None: made here).
    ``check_convergence=False`` (one call, no callback) skips the extra step that decides ``converged``
    (reported False): for intermediate pyramid levels, whose convergence nobody reads.
    target_normals : (M, 3) with ``options.metric == "point_to_plane"``: Open3D's point-to-plane estimation
        on a copy of the target cloud that holds them.
    """
    if options.max_correspondence_distance is None:
        raise InputError("icp_open3d needs options.max_correspondence_distance (pcreg.icp chooses one)")
    model, max_correspondence_distance, max_iteration = options.model, options.max_correspondence_distance, options.max_iteration
    stepwise = options.count_iterations or callback is not None
    source_pcd, target_pcd = (None, None) if clouds is None else clouds
    start = time.perf_counter()
    check_model(model)
    source, target, T = backend_inputs(source, target, init, who="icp_open3d")
    relative_fitness, relative_rmse = options.relative_fitness, options.stopping_rmse(source, target)
    o3d = _o3d()
    reg = o3d.pipelines.registration
    d = source.shape[1]
    T4 = lift_to_3d(T) if d == 2 else T.copy()
    src = source_pcd if source_pcd is not None else to_pointcloud(source)
    est, tgt = _estimation(options, target, target_pcd, target_normals)
    back = (lambda m: project_to_2d(m)) if d == 2 else (lambda m: m)

    def step(T4, n_iter):
        crit = reg.ICPConvergenceCriteria(relative_fitness=relative_fitness, relative_rmse=relative_rmse,
                                          max_iteration=n_iter)
        r = reg.registration_icp(src, tgt, max_correspondence_distance, T4, est, crit)
        _check_finite(np.asarray(r.transformation), T4)
        return r

    def report(i, r, T4):
        if callback is None:
            return
        corr = np.asarray(r.correspondence_set)
        idx = np.full(source.shape[0], -1, dtype=np.intp)
        if corr.size:
            idx[corr[:, 0]] = corr[:, 1]
        from .transforms import apply

        M = back(T4)
        callback(IcpIteration(backend="open3d", level=level, iteration=i, matrix=M, fitness=float(r.fitness),
                              inlier_rmse=float(r.inlier_rmse), source_points=apply(M, source),
                              target_points=target, target_indices=idx))

    if not stepwise:
        r = step(T4, max_iteration)
        if not check_convergence:
            return _result(back(np.asarray(r.transformation)), r, -1, False, start)
        r_next = step(np.asarray(r.transformation), 1)
        converged = (abs(r_next.fitness - r.fitness) < relative_fitness
                     and abs(r_next.inlier_rmse - r.inlier_rmse) < relative_rmse)
        return _result(back(np.asarray(r.transformation)), r, -1, converged, start)

    r = reg.evaluate_registration(src, tgt, max_correspondence_distance, T4)
    report(0, r, T4)
    iterations, converged = 0, False
    for i in range(max_iteration):
        prev = r
        r = step(T4, 1)
        T4 = np.asarray(r.transformation)
        iterations = i + 1
        report(iterations, r, T4)
        if abs(prev.fitness - r.fitness) < relative_fitness and abs(prev.inlier_rmse - r.inlier_rmse) < relative_rmse:
            converged = True
            break
    return _result(back(T4), r, iterations, converged, start)


def multi_scale_icp_open3d(source: np.ndarray, target: np.ndarray, *, voxel_sizes: Sequence[float],
                           max_correspondence_distances: Sequence[float], max_iterations: Sequence[int],
                           init: np.ndarray | None = None, relative_fitness: float = 1e-6,
                           relative_rmse: float = 1e-6, model: str = "rigid",
                           ) -> RegistrationResult:
    """Open3D tensor ``multi_scale_icp`` (Float64, CPU) for 3-D clouds; coarse to fine over voxel sizes."""
    start = time.perf_counter()
    check_model(model)
    o3d = _o3d()
    treg = o3d.t.pipelines.registration
    if source.shape[1] != 3:
        raise RegistrationError("multi-scale Open3D ICP is for 3-D clouds")
    dev = o3d.core.Device("CPU:0")
    src = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.asarray(source, np.float64), device=dev))
    tgt = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.asarray(target, np.float64), device=dev))
    crit = [treg.ICPConvergenceCriteria(relative_fitness=relative_fitness, relative_rmse=relative_rmse,
                                        max_iteration=int(n)) for n in max_iterations]
    init_t = o3d.core.Tensor(np.eye(4) if init is None else np.asarray(init, np.float64), o3d.core.float64)
    est = treg.TransformationEstimationPointToPoint(with_scaling=(model == "similarity"))
    r = treg.multi_scale_icp(src, tgt, o3d.utility.DoubleVector(list(map(float, voxel_sizes))), crit,
                             o3d.utility.DoubleVector(list(map(float, max_correspondence_distances))), init_t, est)
    return RegistrationResult(matrix=r.transformation.numpy(), fitness=float(r.fitness),
                              inlier_rmse=float(r.inlier_rmse), iterations=int(r.num_iterations),
                              converged=bool(r.converged), backend="open3d",
                              seconds=time.perf_counter() - start)
