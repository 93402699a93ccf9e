"""The built-in implementations: pcreg's reference ICP, Open3D (legacy and tensor), small_gicp,
KISS-ICP, and coherent point drift (pycpd, probreg).

Settings each adapter pins, and why:

- fixed-point adapters run "to convergence": at least ``CONVERGED_ITERATIONS`` iterations and
  tolerances near machine precision, since their own defaults (small_gicp: 20 iterations, 0.1° / 1 mm;
  KISS-ICP: 1e-4 on the step) stop early;
- no library downsamples, rejects or re-weights: every adapter sees exactly the pinned clouds
  (small_gicp's numpy overload voxel-downsamples by 0.25 by default; pcreg uses its PointCloud overload);
- one thread wherever a library offers the choice, for deterministic results.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .base import (FIXED_POINT, OBJECTIVE, STEP, ImplementationError, Implementation, Pinned, lift, lift_matrix,
                   out_of_plane, project, result, score, step, unpack)
from ..registration.icp_options import ICPOptions
from ..registration.transforms import about_point, rotation_part

CONVERGED_ITERATIONS = 200


def pinned_options(pinned: Pinned, *, backend: str = "reference", count_iterations: bool = True) -> ICPOptions:
    """pcreg's ICP as the cross-check pins it: rigid, point to point, ``pinned``'s correspondence distance
    and stopping rule."""
    return ICPOptions(backend=backend, model="rigid", max_correspondence_distance=pinned.max_correspondence_distance,
                      max_iteration=pinned.max_iterations, relative_fitness=pinned.relative_fitness,
                      relative_rmse=pinned.relative_rmse, count_iterations=count_iterations)


def _converged_iterations(pinned: Pinned) -> int:
    return max(int(pinned.max_iterations), CONVERGED_ITERATIONS)


class Reference(Implementation):
    name = "reference"
    comparability = STEP
    description = "pcreg's reference ICP (compiled exact KD-tree, Umeyama closed form, Open3D's stopping rule)"

    def settings(self, pinned):
        return {"model": "rigid", "weights": "none", "metric": "point_to_point", "rotation": "svd",
                **pinned.params()}

    def _run(self, pinned, *, trace):
        from ..registration.api import icp

        steps: list = []

        def cb(it):
            steps.append(step(self.name, it.iteration, it.matrix, it.fitness, it.inlier_rmse, it.target_indices))

        r = icp(pinned.source, pinned.target, pinned_options(pinned), init=pinned.init, callback=cb if trace else None)
        m, fit, rmse, it, conv = unpack(r)
        return result(self.name, m, iterations=it, fitness=fit, inlier_rmse=rmse, converged=conv,
                      seconds=float(getattr(r, "seconds", 0.0)), trace=tuple(steps))


class _Open3D(Implementation):
    """Open3D's point-to-point ICPs: the same step as the reference, so compared step by step."""

    comparability = STEP
    requires = ("open3d",)


class Open3DLegacy(_Open3D):
    name = "open3d"
    description = "Open3D legacy registration_icp, TransformationEstimationPointToPoint"

    def settings(self, pinned):
        return {"estimation": "TransformationEstimationPointToPoint(with_scaling=False)",
                "criteria": "ICPConvergenceCriteria(relative_fitness, relative_rmse, max_iteration)",
                "2-D": "lifted to z = 0", **pinned.params(),
                "iterations": "counted by a second run, one iteration per call with Open3D's rule between "
                              "calls (registration_icp reports none); the matrix is the single call's"}

    def _run(self, pinned, *, trace):
        from ..registration.open3d_icp import icp_open3d

        options = pinned_options(pinned, backend="open3d", count_iterations=False)
        start = time.perf_counter()
        m, fit, rmse, _, conv = unpack(icp_open3d(pinned.source, pinned.target, options, init=pinned.init))
        seconds = time.perf_counter() - start
        steps: list = []

        def cb(it):
            steps.append(step(self.name, it.iteration, it.matrix, it.fitness, it.inlier_rmse, it.target_indices))

        m2, _, _, iterations, conv2 = unpack(icp_open3d(pinned.source, pinned.target, replace(options, count_iterations=True),
                                                        init=pinned.init, callback=cb))
        info = {}
        gap = float(np.max(np.abs(m - m2)))
        if gap > 0:
            info["stepwise_gap"] = gap
        return result(self.name, m, iterations=iterations, fitness=fit, inlier_rmse=rmse, converged=conv2,
                      seconds=seconds, trace=tuple(steps) if trace else (), info=info)


class Open3DTensor(_Open3D):
    name = "open3d-tensor"
    description = "Open3D tensor pipelines.registration.icp in Float64 on the CPU"

    def settings(self, pinned):
        return {"dtype": "Float64", "device": "CPU:0", "voxel_size": -1,
                "estimation": "TransformationEstimationPointToPoint", "2-D": "lifted to z = 0", **pinned.params()}

    def _run(self, pinned, *, trace):
        import open3d as o3d

        treg = o3d.t.pipelines.registration
        dev = o3d.core.Device("CPU:0")
        src = o3d.t.geometry.PointCloud(o3d.core.Tensor(lift(pinned.source), o3d.core.float64, dev))
        tgt = o3d.t.geometry.PointCloud(o3d.core.Tensor(lift(pinned.target), o3d.core.float64, dev))
        crit = treg.ICPConvergenceCriteria(relative_fitness=pinned.relative_fitness,
                                           relative_rmse=pinned.relative_rmse, max_iteration=int(pinned.max_iterations))
        init = o3d.core.Tensor(lift_matrix(pinned.init), o3d.core.float64, dev)
        d = pinned.dim
        back = project if d == 2 else (lambda x: x)
        steps = [step(self.name, 0, pinned.init)]

        def cb(info):
            steps.append(step(self.name, len(steps), back(info["transformation"].numpy()),
                              float(info["fitness"].item()), float(info["inlier_rmse"].item())))

        start = time.perf_counter()
        r = treg.icp(src, tgt, float(pinned.max_correspondence_distance), init,
                     treg.TransformationEstimationPointToPoint(), crit, -1.0, cb if trace else None)
        seconds = time.perf_counter() - start
        m = r.transformation.numpy()
        info = {}
        if d == 2:
            info["out_of_plane"] = out_of_plane(m)
        return result(self.name, back(m), iterations=int(r.num_iterations), fitness=float(r.fitness),
                      inlier_rmse=float(r.inlier_rmse), converged=bool(r.converged), seconds=seconds,
                      trace=tuple(steps) if trace else (), info=info)


class SmallGicp(Implementation):
    name = "small_gicp"
    comparability = FIXED_POINT
    kind = "ICP"
    description = "small_gicp align(), registration_type='ICP' (Gauss-Newton/Levenberg-Marquardt on SE(3))"
    requires = ("small_gicp",)
    num_neighbors = 20

    def settings(self, pinned):
        s = {"registration_type": self.kind, "downsampling": "none (PointCloud overload)",
             "max_correspondence_distance": pinned.max_correspondence_distance,
             "max_iterations": _converged_iterations(pinned), "rotation_epsilon": 1e-12,
             "translation_epsilon": 1e-12 * self._scale(pinned), "num_threads": 1, "2-D": "lifted to z = 0",
             "centred": "both clouds moved by minus the target's centroid (and divided by its extent where that is "
                        "under 1), the pose moved (and scaled) back (its Gauss-Newton steps about the origin stopped "
                        "0.027 degrees from the fixed point on a LiDAR pair 1e5 away; on clouds 1e-12 across, 4 degrees "
                        "off at iteration 4)"}
        if self.kind != "ICP":
            s["normals_covariances"] = f"estimate_normals_covariances, num_neighbors={self.num_neighbors}"
        return s

    @staticmethod
    def _scale(pinned):
        """The target's extent about its centroid (its largest coordinate from it; 1 for a target of one point): the
        translation's criterion is relative to it, and clouds of an extent under 1 are given to small_gicp in it, since its damping is
        absolute (the criterion floored at 1, clouds 1e-12 across stopped at iteration 0, 2.9 degrees off; with it
        not floored, 4 degrees off at iteration 4: the rotation's part of its system is the extent squared)."""
        extent = float(np.abs(pinned.target - pinned.target.mean(axis=0)).max())
        return extent if extent > 0 else 1.0

    def _run(self, pinned, *, trace):
        import small_gicp

        if self.kind != "ICP" and pinned.dim == 2:
            raise ImplementationError(f"{self.kind} needs surfaces: a 2-D cloud lifted to z = 0 has every "
                                      "normal along z")
        s = self.settings(pinned)
        source, target, c = _centred(pinned.source, pinned.target)
        k = min(1.0, self._scale(pinned))  # larger clouds in their own units, as they always were
        src = small_gicp.PointCloud(lift(source / k))
        tgt = small_gicp.PointCloud(lift(target / k))
        tree = small_gicp.KdTree(tgt)
        if self.kind != "ICP":
            small_gicp.estimate_normals_covariances(tgt, tree, num_neighbors=self.num_neighbors)
            small_gicp.estimate_normals_covariances(src, small_gicp.KdTree(src), num_neighbors=self.num_neighbors)
        if self.kind == "PLANE_ICP":
            _check_plane_normals(np.asarray(tgt.normals())[:, :3])
        start = time.perf_counter()
        r = small_gicp.align(tgt, src, tree, init_T_target_source=lift_matrix(_in_unit(about_point(pinned.init, -c), 1 / k)),
                             registration_type=self.kind, max_correspondence_distance=pinned.max_correspondence_distance / k,
                             num_threads=1, max_iterations=s["max_iterations"], rotation_epsilon=s["rotation_epsilon"],
                             translation_epsilon=s["translation_epsilon"] / k)
        seconds = time.perf_counter() - start
        m = _in_unit(np.asarray(r.T_target_source), k)
        # its sum of squared distances in the clouds' units (GICP's, through covariances scaled alike, has none)
        info = {"num_inliers": int(r.num_inliers), "error": float(r.error) * (1.0 if self.kind == "GICP" else k * k)}
        if pinned.dim == 2:
            info["out_of_plane"] = out_of_plane(m)
            m = project(m)
        m = about_point(m, c)
        fit, rmse, _ = score(pinned, m)
        info["fitness_from"] = "pcreg (Open3D's definition at the returned pose)"
        return result(self.name, m, iterations=int(r.iterations), fitness=fit, inlier_rmse=rmse,
                      converged=bool(r.converged), seconds=seconds, info=info)


def _check_plane_normals(normals: np.ndarray) -> None:
    """An :class:`ImplementationError` when the target's estimated normals cannot fix a motion (all along one
    line or in one plane: a planar target), as pcreg's own point-to-plane ICP refuses such normals: on a plane
    small_gicp's point-to-plane ICP slid along it and reported a transform 3 degrees off as converged."""
    from ..registration.normal_steps import normals_problem

    problem = normals_problem(normals)
    if problem is not None:
        raise ImplementationError(f"point-to-plane cannot register this target (normals estimated from its "
                                  f"neighbours): {problem}")


class _SmallGicpSurface(SmallGicp):
    """small_gicp's surface objectives: they need normals or covariances, so 3-D only, and they minimise
    another objective than point-to-point ICP (compared by objective, not by fixed point)."""

    comparability = OBJECTIVE
    dims = (3,)


class SmallGicpPlane(_SmallGicpSurface):
    name, kind = "small_gicp-plane", "PLANE_ICP"
    description = "small_gicp align(), registration_type='PLANE_ICP' (point-to-plane)"


class SmallGicpGicp(_SmallGicpSurface):
    name, kind = "small_gicp-gicp", "GICP"
    description = "small_gicp align(), registration_type='GICP' (generalized ICP, plane-to-plane)"


def _big(count: int) -> str:
    """A count, which may be past what a float holds (a map under a gate of 1e160), in three figures."""
    digits = len(str(count))
    return f"{count:.3g}" if digits < 300 else f"{str(count)[0]}.{str(count)[1:3]}e+{digits - 1}"


class KissIcp(Implementation):
    name = "kiss-icp"
    comparability = FIXED_POINT
    description = ("KISS-ICP's registration step (Registration.align_points_to_map) on a voxel hash map of the "
                   "target, for a single pair")
    requires = ("kiss_icp",)
    #: The most bytes KISS-ICP's map may reserve: it reserves room for max_points_per_voxel points (24 bytes
    #: each) in every voxel it fills, so a dense cloud under a wide gate asks for gigabytes (28 GiB for a
    #: 70k-point LiDAR scan at a 0.95 m gate) and the row would end in std::bad_alloc instead of its reason.
    max_map_bytes = 1 << 30

    def _map_size(self, pinned) -> tuple[int, int, float]:
        """``(max_points_per_voxel, voxels, closest)``: enough points per voxel that the map's minimum spacing,
        voxel / sqrt(max_points_per_voxel), is half the distance ``closest`` between the target's closest
        distinct points, so that the map keeps every target point but repeats (a point given twice is
        dropped, and changes no nearest distance); and how many voxels the target fills."""
        from scipy.spatial import cKDTree

        t = np.unique(lift(pinned.target), axis=0)
        v = float(pinned.max_correspondence_distance)
        closest = float(cKDTree(t).query(t, k=2)[0][:, 1].min()) if len(t) > 1 else v
        voxels = len(np.unique(np.floor(t / v).astype(np.int64), axis=0))
        ratio = v / (0.5 * closest)
        if ratio > 1e150:  # its square is past a float (a gate of 1e160): Python's integers hold it, the map refuses it
            return int(np.ceil(ratio)) ** 2 + 1, voxels, closest
        return int(np.ceil(ratio ** 2 + 1)), voxels, closest

    def settings(self, pinned):
        pinned = _about_centroid(pinned)[0]
        v = float(pinned.max_correspondence_distance)
        n, voxels, _ = self._map_size(pinned)
        return {"voxel_size": v, "max_points_per_voxel": n, "map_resolution": v / np.sqrt(n),
                "map_reserved_bytes": 24 * n * voxels,
                "kernel": self._kernel(pinned), "max_num_iterations": _converged_iterations(pinned),
                "convergence_criterion": 1e-12 * max(1.0, float(np.abs(pinned.target).max())), "max_num_threads": 1,
                "max_correspondance_distance": v, "map": "target added once with add_points (no range cropping)",
                "why": "voxel = gate so the 27 neighbouring voxels hold every point within the gate; "
                       "a huge max_points_per_voxel keeps every target point (the map drops points closer "
                       "than voxel/sqrt(max_points_per_voxel) to one already in the voxel); a huge "
                       "Geman-McClure kernel makes every weight 1 (plain least squares)",
                "centred": "both clouds moved by minus the target's centroid, the pose moved back (its Gauss-Newton "
                           "steps about the origin ended 114 degrees off for two bunny scans 1e6 away)"}

    @staticmethod
    def _kernel(pinned):
        # the gate's square, capped where a float holds it 1e10 times over (a gate of 1e160 raised OverflowError);
        # residuals of clouds pcreg reads (coordinates up to 1e15) stay far below it
        return 1e10 * max(1.0, min(float(pinned.max_correspondence_distance), 1e140) ** 2)

    def _run(self, pinned, *, trace):
        from kiss_icp.mapping import VoxelHashMap
        from kiss_icp.registration import Registration

        R = lift_matrix(pinned.init)[:3, :3]
        if np.linalg.norm(R @ R.T - np.eye(3)) >= 1e-11 or np.linalg.det(R) <= 0:
            # Sophus (inside KISS-ICP) aborts the whole process on a rotation that is not orthonormal to 1e-10.
            raise ImplementationError("the initial guess's rotation is not orthonormal to 1e-11; KISS-ICP (Sophus) "
                                      "would abort the process")
        given, (pinned, c) = pinned, _about_centroid(pinned)
        n, voxels, closest = self._map_size(pinned)
        if 24 * n * voxels > self.max_map_bytes:
            raise ImplementationError(
                f"its map would reserve {_big(24 * n * voxels // 2**30)} GiB to keep every target point ({voxels} voxels "
                f"of {_big(n)} points: the closest distinct target points are {closest:.3g} apart, the gate "
                f"{float(pinned.max_correspondence_distance):.3g}); voxel-downsample the clouds (--voxel-size) or "
                "narrow the gate")
        s = self.settings(given)
        vmap = VoxelHashMap(voxel_size=s["voxel_size"], max_distance=np.inf,
                            max_points_per_voxel=s["max_points_per_voxel"])
        tgt = lift(pinned.target)
        vmap.add_points(tgt)
        kept = len(vmap.point_cloud())
        reg = Registration(max_num_iterations=s["max_num_iterations"], convergence_criterion=s["convergence_criterion"],
                           max_num_threads=1)
        start = time.perf_counter()
        m = reg.align_points_to_map(lift(pinned.source), vmap, lift_matrix(pinned.init),
                                    max_correspondance_distance=float(pinned.max_correspondence_distance),
                                    kernel=s["kernel"])
        seconds = time.perf_counter() - start
        m = np.asarray(m)
        steps, iterations, met = (), None, False
        info = {"map_points": kept, "target_points": len(tgt)}
        if trace:
            t0 = time.perf_counter()
            steps, iterations, met = self._trace(name=self.name, reg1=Registration(max_num_iterations=1, convergence_criterion=0.0,
                                                              max_num_threads=1),
                                            vmap=vmap, pinned=pinned, settings=s, given=given, c=c)
            info["trace_seconds"] = time.perf_counter() - t0  # beyond its own call's, which its row shows
        if kept != len(tgt):
            info["map_dropped_points"] = len(tgt) - kept
        if pinned.dim == 2:
            info["out_of_plane"] = out_of_plane(m)
            m = project(m)
        m = about_point(m, c)
        fit, rmse, _ = score(given, m)
        info["fitness_from"] = "pcreg (Open3D's definition at the returned pose)"
        if steps:
            gap = float(np.max(np.abs(steps[-1].matrix - m)))
            if gap > 0:
                info["stepwise_gap"] = gap
        if iterations is not None:
            info["iterations_from"] = "a second run, one Gauss-Newton step per call (each step is stateless)"
        return result(self.name, m, iterations=iterations, fitness=fit, inlier_rmse=rmse,
                      converged=None if iterations is None else met,
                      seconds=seconds, trace=steps, info=info)

    @staticmethod
    def _trace(*, name, reg1, vmap, pinned, settings, given, c):
        """Its iterations one call at a time: each KISS-ICP step is a Gauss-Newton step from the current
        pose with fresh correspondences, so chaining one-iteration calls replays its loop; it stops, as
        KISS-ICP does, once the step's norm (rotation vector, translation) is below the criterion:
        ``(steps, iterations, met)``, ``met`` whether the criterion stopped it (at the last iteration too).
        ``pinned`` the clouds about ``c``, the ``given`` target's centroid; the steps' poses are the given clouds'."""
        from scipy.spatial.transform import Rotation

        src = lift(pinned.source)
        T = lift_matrix(pinned.init)
        back = project if pinned.dim == 2 else (lambda x: x)
        fit, rmse, idx = score(given, given.init)
        steps = [step(name, 0, given.init, fit, rmse, idx)]
        for k in range(1, settings["max_num_iterations"] + 1):
            T_new = np.asarray(reg1.align_points_to_map(src, vmap, T, max_correspondance_distance=settings["voxel_size"],
                                                        kernel=settings["kernel"]))
            D = T_new @ np.linalg.inv(T)
            dx = np.concatenate([D[:3, 3], Rotation.from_matrix(rotation_part(D[:3, :3])).as_rotvec()])
            T = T_new
            M = about_point(back(T), c)
            fit, rmse, idx = score(given, M)
            steps.append(step(name, k, M, fit, rmse, idx))
            if np.linalg.norm(dx) < settings["convergence_criterion"]:
                return tuple(steps), k, True
        return tuple(steps), len(steps) - 1, False


def _subsample(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    if len(points) <= n:
        return points
    idx = np.sort(np.random.default_rng(seed).choice(len(points), n, replace=False))
    return points[idx]


class _Probabilistic(Implementation):
    comparability = OBJECTIVE
    max_points = 500
    max_em_iterations = 200
    tolerance = 1e-8

    def settings(self, pinned):
        return {"max_points": self.max_points, "subsample": "seeded random (seed 0 source, 1 target) when larger",
                "w": 0.0, "max_iterations": self.max_em_iterations, "tolerance": self.tolerance,
                "init": "source moved by the initial guess first"}


def _about_centroid(pinned):
    """``(pinned, c)``: the pinned clouds moved by ``-c``, the target's centroid, and the initial pose with them (a
    pose found between them is the given clouds' about ``c``: :func:`~pcreg.registration.transforms.about_point`)."""
    source, target, c = _centred(pinned.source, pinned.target)
    return replace(pinned, source=source, target=target, init=about_point(pinned.init, -c)), c


def _in_unit(matrix: np.ndarray, k: float) -> np.ndarray:
    """A homogeneous transform of clouds whose coordinates are multiplied by ``k``: its translation times ``k``."""
    out = np.array(matrix, dtype=float)
    out[:-1, -1] *= k
    return out


def _centred(src: np.ndarray, tgt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(source, target, c)``: both clouds moved by ``-c``, the target's centroid (a transform found between
    them is the clouds' own about ``c``: :func:`~pcreg.registration.transforms.about_point`). The probabilistic
    libraries compute in the clouds' own coordinates: far from the origin (georeferenced clouds, 5e6 m)
    probreg's FilterReg corrupted its memory and ended the process."""
    c = tgt.mean(axis=0)
    return src - c, tgt - c, c


class PyCpd(_Probabilistic):
    name = "pycpd"
    description = ("pycpd RigidRegistration: coherent point drift (Myronenko & Song 2010), a Gaussian mixture "
                   "fitted by EM; its rigid model also estimates a scale")
    requires = ("pycpd",)

    def _run(self, pinned, *, trace):
        from pycpd import RigidRegistration

        from ..registration.transforms import apply

        d = pinned.dim
        src, tgt, c = _centred(_subsample(apply(pinned.init, pinned.source), self.max_points, 0),
                               _subsample(pinned.target, self.max_points, 1))
        start = time.perf_counter()
        reg = RigidRegistration(X=tgt, Y=src, max_iterations=self.max_em_iterations, tolerance=self.tolerance, w=0.0)
        reg.register()
        seconds = time.perf_counter() - start
        s, R, t = reg.get_registration_parameters()
        M = np.eye(d + 1)
        M[:d, :d] = s * np.asarray(R).T  # pycpd maps row vectors: y -> s y R + t
        M[:d, d] = np.ravel(t)
        m = about_point(M, c) @ pinned.init
        fit, rmse, _ = score(pinned, m)
        return result(self.name, m, iterations=int(reg.iteration), fitness=fit, inlier_rmse=rmse,
                      converged=bool(reg.iteration < self.max_em_iterations), seconds=seconds,
                      info={"scale": float(s), "sigma2": float(reg.sigma2),
                            "fitness_from": "pcreg (Open3D's definition at the returned pose)"})


class _Probreg(_Probabilistic):
    """probreg's registrations on clouds lifted to 3-D (2-D clouds at z = 0): subsample, register, score."""

    requires = ("probreg",)

    def settings(self, pinned):
        return {**super().settings(pinned), **self.options, "2-D": "lifted to z = 0"}

    def _register(self, source: np.ndarray, target: np.ndarray):
        raise NotImplementedError

    def _run(self, pinned, *, trace):
        import logging

        from ..registration.transforms import apply

        logging.getLogger("probreg").setLevel(logging.ERROR)
        src, tgt, c = _centred(lift(_subsample(apply(pinned.init, pinned.source), self.max_points, 0)),
                               lift(_subsample(pinned.target, self.max_points, 1)))
        start = time.perf_counter()
        res = self._register(src, tgt)
        seconds = time.perf_counter() - start
        tf = res.transformation
        rot = np.asarray(tf.rot, dtype=np.float64)
        M = np.eye(4)
        # FilterReg composes its rotation from twist updates, which drift off orthonormal (|R^T R - I| about 1e-4):
        # the nearest rotation is its rigid answer. Kept as given, the drift scaled by the clouds' distance from the
        # origin moved the reported translation (7 units at 1e5) although the moved points agree to 1e-3.
        M[:3, :3] = float(getattr(tf, "scale", 1.0)) * rotation_part(rot)
        M[:3, 3] = np.asarray(tf.t)
        M = about_point(M, c)
        info = {"sigma2": float(res.sigma2), "rotation_drift": float(np.abs(rot.T @ rot - np.eye(3)).max())}
        if pinned.dim == 2:
            info["out_of_plane"] = out_of_plane(M)
            M = project(M)
        m = M @ pinned.init
        fit, rmse, _ = score(pinned, m)
        info["fitness_from"] = "pcreg (Open3D's definition at the returned pose)"
        return result(self.name, m, iterations=None, fitness=fit, inlier_rmse=rmse, converged=None, seconds=seconds,
                      info=info)


class ProbregCpd(_Probreg):
    name = "probreg-cpd"
    description = "probreg registration_cpd, rigid, update_scale=False (coherent point drift without scale)"
    options = {"update_scale": False}

    def _register(self, source, target):
        from probreg import cpd

        return cpd.registration_cpd(source, target, "rigid", w=0.0, maxiter=self.max_em_iterations,
                                    tol=self.tolerance, update_scale=False)


class ProbregFilterReg(_Probreg):
    name = "probreg-filterreg"
    description = ("probreg registration_filterreg, point-to-point (FilterReg, Gao & Tedrake 2019: a Gaussian mixture "
                   "on the target evaluated by a permutohedral-lattice filter), sigma^2 updated")
    options = {"objective_type": "pt2pt", "update_sigma2": True}

    def _register(self, source, target):
        from probreg import filterreg

        return filterreg.registration_filterreg(source, target, update_sigma2=True, w=0.0, objective_type="pt2pt",
                                                maxiter=self.max_em_iterations, tol=self.tolerance)


BUILTIN = {cls.name: cls for cls in (Reference, Open3DLegacy, Open3DTensor, SmallGicp, SmallGicpPlane, SmallGicpGicp,
                                     KissIcp, PyCpd, ProbregCpd, ProbregFilterReg)}
