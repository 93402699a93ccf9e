"""One ICP run at one scale, per backend: the step that :func:`~pcreg.registration.api.icp`'s voxel
schedule and :func:`~pcreg.registration.api.register`'s pyramid repeat.

:func:`icp_step` looks a backend's step up once, by name, in :data:`ICP_STEPS`; every step takes the same
arguments and returns a :class:`~pcreg.registration.result.RegistrationResult` (``T_target_source``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from ..errors import InputError
from .config import BACKENDS
from .open3d_icp import icp_open3d, to_pointcloud
from .reference import icp_reference
from .result import IcpIteration, RegistrationResult


@dataclass(frozen=True)
class IcpSettings:
    """The options every step of one registration shares (distances, limits and levels vary per call).

    weights, trim_fraction, metric, rotation : the reference backend's (Open3D's step refuses any other
        than the default). stepwise : Open3D's step runs one iteration at a time even without a
        callback, so that ``iterations`` and ``converged`` are exact.
    """

    model: str
    relative_fitness: float
    weights: str = "none"
    trim_fraction: float = 0.9
    metric: str = "point_to_point"
    rotation: str = "svd"
    stepwise: bool = False


@dataclass(frozen=True)
class StepCall:
    """What varies from one call of a step to the next (a level, a candidate, a voxel size).

    level : the pyramid level (reported in each :class:`IcpIteration`). final : False skips Open3D's extra
    step that decides ``converged`` (an intermediate level's, which nobody reads). target_normals : the
    reference step's point-to-line metric. target_index : returns a prebuilt index of the target (the
    reference step; None: built there). open3d_clouds : a dict in which Open3D's copy of each array is made
    once (the candidates and levels of a registration share it; Open3D's step).
    """

    max_correspondence_distance: float
    max_iteration: int
    relative_rmse: float
    level: int = 0
    callback: Callable[[IcpIteration], None] | None = None
    final: bool = True
    target_normals: np.ndarray | None = None
    target_index: Callable[[], object] | None = None
    open3d_clouds: dict | None = None


class IcpStep(Protocol):
    """One ICP run from ``init``: ``(source, target, init, settings, call) -> RegistrationResult``."""

    def __call__(self, source: np.ndarray, target: np.ndarray, init: np.ndarray, settings: IcpSettings,
                 call: StepCall) -> RegistrationResult: ...


def reference_step(source: np.ndarray, target: np.ndarray, init: np.ndarray, settings: IcpSettings,
                   call: StepCall) -> RegistrationResult:
    """The reference ICP (:func:`~pcreg.registration.reference.icp_reference`)."""
    return icp_reference(source, target, model=settings.model,
                         max_correspondence_distance=call.max_correspondence_distance, init=init,
                         max_iteration=call.max_iteration, relative_fitness=settings.relative_fitness,
                         relative_rmse=call.relative_rmse, weights=settings.weights, metric=settings.metric,
                         target_normals=call.target_normals, callback=call.callback, level=call.level,
                         rotation=settings.rotation, tree=None if call.target_index is None else call.target_index(),
                         trim_fraction=settings.trim_fraction)


def open3d_step(source: np.ndarray, target: np.ndarray, init: np.ndarray, settings: IcpSettings,
                call: StepCall) -> RegistrationResult:
    """Open3D's point-to-point ICP (:func:`~pcreg.registration.open3d_icp.icp_open3d`); every option only
    the reference honours is refused."""
    refuse_for_open3d(weights=settings.weights, metric=settings.metric, target_normals=call.target_normals,
                      rotation=settings.rotation, trim_fraction=settings.trim_fraction)
    source_pcd = target_pcd = None
    if call.open3d_clouds is not None:
        source_pcd, target_pcd = open3d_cloud(call.open3d_clouds, source), open3d_cloud(call.open3d_clouds, target)
    return icp_open3d(source, target, model=settings.model,
                      max_correspondence_distance=call.max_correspondence_distance, init=init,
                      max_iteration=call.max_iteration, relative_fitness=settings.relative_fitness,
                      relative_rmse=call.relative_rmse, callback=call.callback, level=call.level,
                      stepwise=settings.stepwise or call.callback is not None, source_pcd=source_pcd,
                      target_pcd=target_pcd, check_convergence=call.final or call.callback is not None)


ICP_STEPS: dict[str, IcpStep] = {"reference": reference_step, "open3d": open3d_step}
if tuple(ICP_STEPS) != BACKENDS:  # one list of backends; config.py keeps it, free of the heavy imports here
    raise ImportError(f"ICP_STEPS {tuple(ICP_STEPS)} and config.BACKENDS {BACKENDS} disagree")


def icp_step(backend: str) -> IcpStep:
    """The ICP step of ``backend`` (``"reference"`` or ``"open3d"``)."""
    if backend not in ICP_STEPS:
        raise InputError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    return ICP_STEPS[backend]


def open3d_cloud(made: dict, points: np.ndarray):
    """Open3D's copy of ``points``, made once per array and kept in ``made`` (with the array, so that its
    id stays its own)."""
    if id(points) not in made:
        made[id(points)] = (points, to_pointcloud(points))
    return made[id(points)][1]


def refuse_for_open3d(*, weights: str = "none", metric: str = "point_to_point", target_normals=None,
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
