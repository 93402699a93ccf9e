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
from .icp_options import ICPOptions, refuse_for_open3d
from .open3d_icp import icp_open3d, to_pointcloud
from .reference import icp_reference
from .result import IcpIteration, RegistrationResult


@dataclass(frozen=True)
class IcpSettings:
    """The options every step of one registration shares (distances, limits and levels vary per call).

    weights, trim_fraction, metric, rotation : the reference backend's (Open3D's step refuses any other
        than the default). stepwise : Open3D's step runs one iteration at a time even without a callback, so that
        ``iterations`` and ``converged`` are exact. dlt : how the reference backend solves the projective model's
        step (:data:`~pcreg.registration.closed_forms.DLT_SOLVES`).
    """

    model: str
    relative_fitness: float
    weights: str = "none"
    trim_fraction: float = 0.9
    metric: str = "point_to_point"
    rotation: str = "svd"
    stepwise: bool = False
    dlt: str = "svd"  # after stepwise, added after it: a settings made by position keeps its meaning


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


def step_options(backend: str, settings: IcpSettings, call: StepCall) -> ICPOptions:
    """The :class:`~pcreg.registration.icp_options.ICPOptions` of one step's run (``settings`` and this
    call's distance, iterations and RMSE threshold)."""
    return ICPOptions(backend=backend, model=settings.model, max_correspondence_distance=call.max_correspondence_distance,
                      max_iteration=call.max_iteration, relative_fitness=settings.relative_fitness,
                      relative_rmse=call.relative_rmse, weights=settings.weights, trim_fraction=settings.trim_fraction,
                      metric=settings.metric, rotation=settings.rotation, count_iterations=settings.stepwise)


def reference_step(source: np.ndarray, target: np.ndarray, init: np.ndarray, settings: IcpSettings,
                   call: StepCall) -> RegistrationResult:
    """The reference ICP (:func:`~pcreg.registration.reference.icp_reference`)."""
    return icp_reference(source, target, step_options("reference", settings, call), init=init,
                         target_normals=call.target_normals, callback=call.callback, level=call.level,
                         tree=None if call.target_index is None else call.target_index(), dlt=settings.dlt)


def open3d_step(source: np.ndarray, target: np.ndarray, init: np.ndarray, settings: IcpSettings,
                call: StepCall) -> RegistrationResult:
    """Open3D's point-to-point or point-to-plane ICP (:func:`~pcreg.registration.open3d_icp.icp_open3d`);
    every option only the reference honours is refused."""
    refuse_for_open3d(weights=settings.weights, metric=settings.metric, target_normals=call.target_normals,
                      rotation=settings.rotation, trim_fraction=settings.trim_fraction)
    clouds = None
    if call.open3d_clouds is not None:
        clouds = open3d_cloud(call.open3d_clouds, source), open3d_cloud(call.open3d_clouds, target)
    return icp_open3d(source, target, step_options("open3d", settings, call), init=init, callback=call.callback,
                      level=call.level, clouds=clouds, check_convergence=call.final or call.callback is not None,
                      target_normals=call.target_normals)


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
