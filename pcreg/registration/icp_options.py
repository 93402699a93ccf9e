"""The options of one point-cloud ICP, written once: :class:`ICPOptions` (and its coarse-to-fine
:class:`VoxelSchedule`), taken by :func:`pcreg.icp`, by each backend's ICP
(:func:`~pcreg.registration.reference.icp_reference`, :func:`~pcreg.registration.open3d_icp.icp_open3d`) and,
for the stopping rule it pins, by :func:`~pcreg.implementations.crosscheck.crosscheck_implementations`.

As Open3D's ``ICPConvergenceCriteria`` and KISS-ICP's configuration: a frozen value with its defaults in
code, each value checked once when it is made (an :class:`~pcreg.errors.InputError` names the option), and
changed with :func:`dataclasses.replace`, which checks again. What depends on the clouds (the dimension a
model or metric needs) is checked where the clouds are known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..validation import check_bool, check_float, check_floats, check_int, check_ints, short_repr
from .choices import BACKENDS, METRICS, ROTATIONS, WEIGHTS, check_open3d_model
from .transforms import MODELS

__all__ = ["ICPOptions", "METRICS", "ROTATIONS", "VoxelSchedule", "WEIGHTS", "refuse_for_open3d"]


_MAX_ITERATIONS = 100_000
#: Open3D's default threshold on the inlier RMSE's change, kept for clouds one unit across or more.
RMSE_TOLERANCE = 1e-6
#: The share of pairs the ``trimmed`` weights keep by default.
TRIM_FRACTION = 0.9


def _check_choice(value, name: str, choices: tuple[str, ...], what: str) -> str:
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"unknown {what} {short_repr(value)}; choose one of {', '.join(choices)}")
    return value


@dataclass(frozen=True)
class VoxelSchedule:
    """A coarse-to-fine schedule: both clouds voxel-downsampled identically
    (:func:`~pcreg.registration.api.voxel_downsample`) at each size, coarsest first, and the ICP run at
    each in turn.

    voxel_sizes : e.g. (1.0, 0.5, 0.25), each > 0 (the clouds' units).
    max_correspondence_distances : per size (None: 2 x the voxel size).
    max_iterations : per size (None: :attr:`ICPOptions.max_iteration` at each).

    The result's ``fitness`` and ``inlier_rmse`` are those of the last size's downsampled clouds, as Open3D's
    ``multi_scale_icp`` reports them, not of the clouds given (score those with the returned matrix to compare).
    """

    voxel_sizes: tuple[float, ...]
    max_correspondence_distances: tuple[float, ...] | None = None
    max_iterations: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        sizes = check_floats(self.voxel_sizes, "voxel_sizes", lo=0, lo_open=True)
        if not sizes:
            raise InputError("voxel_sizes: a schedule needs at least one voxel size")
        # an empty sequence, as None: the default at each size
        dists = check_floats(self.max_correspondence_distances, "max_correspondence_distances", lo=0, lo_open=True) or None
        iters = check_ints(self.max_iterations, "max_iterations", lo=0, hi=_MAX_ITERATIONS) or None
        if any(v is not None and len(v) != len(sizes) for v in (dists, iters)):
            raise InputError("voxel_sizes, max_correspondence_distances and max_iterations differ in length")
        object.__setattr__(self, "voxel_sizes", sizes)
        object.__setattr__(self, "max_correspondence_distances", dists)
        object.__setattr__(self, "max_iterations", iters)


@dataclass(frozen=True)
class ICPOptions:
    """How one ICP registers two point clouds (:func:`pcreg.icp`); every field has its default here.

    backend : ``reference`` (pcreg's ICP) or ``open3d`` (Open3D's point-to-point ICP).
    model : the motion model (``translation``, ``rigid``, ``similarity``, ``affine``, ``projective``).
    max_correspondence_distance : pairs farther apart are ignored (None, :func:`pcreg.icp`: the clouds'
        joint bounding-box diagonal plus 1, so every nearest neighbour counts; a backend's ICP needs a number).
    max_iteration, relative_fitness, relative_rmse : Open3D's stopping rule: at most ``max_iteration``
        updates, and stop once the fitness and the inlier RMSE changed by less than these (absolute changes).
        ``relative_rmse`` None (the default): Open3D's 1e-6 for clouds at least one unit across, and 1e-6 of
        their extent for smaller ones (:meth:`stopping_rmse`), whose every step changes the RMSE by less
        than 1e-6 (a cloud 2e-3 across turned 10 degrees stopped at the first, 0.4 degrees turned).
    weights : robust weights (reference backend): ``none``, ``trimmed``, ``huber``, ``tukey``;
        ``trim_fraction`` the share of pairs ``trimmed`` keeps, in (0, 1].
    metric : ``point_to_point``, or with the target's normals ``point_to_line`` (2-D, reference backend)
        or ``point_to_plane`` (3-D, rigid, either backend: Open3D's ``TransformationEstimationPointToPlane``).
    rotation : 3-D rigid closed form of the reference backend: ``svd`` (Umeyama) or ``quaternion`` (Horn).
    count_iterations : Open3D backend only: run Open3D one iteration at a time (its stopping rule applied
        between steps) so that ``iterations`` and ``converged`` are exact; False runs it in one call
        (faster), reports ``iterations = -1``, and ``converged`` says whether one more iteration from the
        returned pose meets the stopping rule (so a run that used all its iterations can read converged where
        the stepwise run reads not, and, rarely, one that Open3D stopped early can read not converged).
    schedule : a coarse-to-fine :class:`VoxelSchedule` (None: one run on the clouds themselves).

    Options only the reference backend honours are refused with the Open3D backend (never ignored).
    """

    backend: str = "reference"
    model: str = "rigid"
    max_correspondence_distance: float | None = None
    max_iteration: int = 30
    relative_fitness: float = 1e-6
    relative_rmse: float | None = None
    weights: str = "none"
    trim_fraction: float = TRIM_FRACTION
    metric: str = "point_to_point"
    rotation: str = "svd"
    count_iterations: bool = True
    schedule: VoxelSchedule | None = None

    def __post_init__(self) -> None:
        _check_choice(self.backend, "backend", BACKENDS, "backend")
        _check_choice(self.model, "model", MODELS, "motion model")
        _check_choice(self.weights, "weights", WEIGHTS, "robust weights")
        _check_choice(self.metric, "metric", METRICS, "metric")
        if not isinstance(self.rotation, str) or self.rotation not in ROTATIONS:
            raise InputError(f"rotation must be 'svd' or 'quaternion', got {short_repr(self.rotation)}")
        if self.schedule is not None and not isinstance(self.schedule, VoxelSchedule):
            raise InputError(f"schedule must be a VoxelSchedule or None, got {type(self.schedule).__name__}")
        checked = {
            "max_iteration": check_int(self.max_iteration, "max_iteration", lo=0, hi=_MAX_ITERATIONS),
            "relative_fitness": check_float(self.relative_fitness, "relative_fitness", lo=0),
            "trim_fraction": check_float(self.trim_fraction, "trim_fraction", lo=0, lo_open=True, hi=1),
            "count_iterations": check_bool(self.count_iterations, "count_iterations"),
        }
        if self.relative_rmse is not None:
            checked["relative_rmse"] = check_float(self.relative_rmse, "relative_rmse", lo=0)
        if self.max_correspondence_distance is not None:
            checked["max_correspondence_distance"] = check_float(self.max_correspondence_distance,
                                                                 "max_correspondence_distance", lo=0, lo_open=True)
        for name, value in checked.items():
            object.__setattr__(self, name, value)
        if self.backend == "open3d":
            check_open3d_model(self.model)
            refuse_for_open3d(weights=self.weights, metric=self.metric, rotation=self.rotation,
                              trim_fraction=self.trim_fraction)

    def stopping_rmse(self, *clouds: np.ndarray) -> float:
        """The stopping rule's threshold on the inlier RMSE's change for these clouds: ``relative_rmse``, or
        where it is None :data:`RMSE_TOLERANCE` times the largest cloud's bounding-box diagonal where that is
        under one unit (the threshold Open3D's absolute default is for a cloud one unit across; clouds of one point
        each, which have no size, take it unscaled)."""
        if self.relative_rmse is not None:
            return self.relative_rmse
        extent = max((float(np.linalg.norm(np.ptp(c, axis=0))) for c in clouds if len(c)), default=0.0)
        return RMSE_TOLERANCE * min(1.0, extent) if extent > 0 else RMSE_TOLERANCE  # one point: no size to scale


def refuse_for_open3d(*, weights: str = "none", metric: str = "point_to_point", target_normals=None,
                      rotation: str = "svd", trim_fraction: float = TRIM_FRACTION) -> None:
    """:class:`InputError` for every option Open3D's point-to-point ICP cannot honour (none is ignored)."""
    if weights != "none":
        raise InputError("robust weights are a reference-backend feature; Open3D's point-to-point ICP has none")
    if metric not in ("point_to_point", "point_to_plane"):
        raise InputError(f"metric {metric!r} is a reference-backend feature; the open3d backend is point-to-point "
                         "or point-to-plane")
    if target_normals is not None and metric != "point_to_plane":
        raise InputError("target_normals serve the point-to-line and point-to-plane metrics; "
                         "the open3d backend's point-to-point ICP would ignore them")
    if rotation != "svd":
        raise InputError(f"rotation={rotation!r} chooses the reference backend's closed form; "
                         "Open3D's point-to-point estimation has its own (SVD)")
    if trim_fraction != TRIM_FRACTION:
        raise InputError("trim_fraction belongs to the reference backend's trimmed weights")


def refuse_a_line_for_open3d(src: np.ndarray, tgt: np.ndarray) -> None:
    """An :class:`InputError` for 2-D clouds whose points lie on one line (two points, a scan line) with the open3d
    backend: its ICP runs on the clouds lifted to z = 0, where the rotation about that line is free, and it turned
    the image plane over for some motions and not others (refused as "mirrored" under 10 of 20 rigid motions of a line
    of 50 points); the reference ICP solves the 2-D problem, which the line fixes."""
    from .closed_forms import spread

    for name, points in (("source", src), ("target", tgt)):
        sv, least = spread(points)
        if sv[-1] <= least:
            raise InputError(f"{name}: its points lie on one line, about which the open3d backend's 3-D ICP can turn "
                             "the image plane over; use backend='reference' (--backend reference)")
