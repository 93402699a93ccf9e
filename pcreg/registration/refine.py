"""Coarse-to-fine ICP of a moving cloud pyramid onto the reference's, every step the backend's.

:class:`CoarseToFine` takes the backend's ICP step (:func:`~pcreg.registration.steps.icp_step`) and runs
it level by level, coarsest first, each level starting where the previous one ended; the reference
backend may finish with point-to-line iterations at full resolution. It also keeps the reference
cloud's KD-tree per level, which the search and the evidence share.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .pyramid import CloudPyramid
from .reference import build_tree, check_rank
from .result import IcpIteration, RegistrationResult
from .steps import IcpSettings, IcpStep, StepCall, reference_step


@dataclass(frozen=True)
class Refinement:
    """Where a coarse-to-fine ICP ended: ``matrix`` is ``T_ref_mov``; fitness and inlier RMSE of the last
    step; iterations over all levels (-1 where a step does not count them); the last step's convergence
    (None where the step does not say)."""

    matrix: np.ndarray
    fitness: float = 0.0
    inlier_rmse: float = 0.0
    iterations: int = 0
    converged: bool | None = False


def _total(total: int, r: RegistrationResult) -> int:
    """Iterations so far plus ``r``'s (-1 once any step did not count them)."""
    return -1 if (r.iterations < 0 or total < 0) else total + r.iterations


FINISH_ITERATIONS = 100
"""Iterations an affine or projective model's full-resolution level may run until its stopping rule holds:
their extra parameters settle slowly (a projective term of 1e-5 moves a corner of a 500 px image by pixels),
and the levels' 14 left them pixels off, not converged (docs/algorithms.md)."""


class CoarseToFine:
    """Coarse-to-fine ICP onto ``reference`` with ``step`` (one backend's) at every level.

    settings : the step's shared options (motion model, stopping rule, robust weights).
    max_correspondence_distance : px at full resolution, doubled per level.
    iterations : ICP iterations per level. relative_rmse : the stopping rule's RMSE change at full
        resolution (scaled by 2^level). point_to_line : finish with the reference backend's point-to-line
        iterations (Tukey weights, unless ``settings`` names others) at full resolution.
    trees : the reference's KD-trees by level (:meth:`tree`) of another refinement onto the same ``reference``,
        shared with it (a tree depends on the reference's points only, not on the model or the distance);
        None: this one builds its own.
    """

    def __init__(self, reference: CloudPyramid, step: IcpStep, *, settings: IcpSettings,
                 max_correspondence_distance: float, iterations: int, relative_rmse: float,
                 point_to_line: bool = False, trees: dict[int, object] | None = None):
        self.reference, self.step, self.settings = reference, step, settings
        self.max_correspondence_distance, self.iterations = max_correspondence_distance, iterations
        self.relative_rmse, self.point_to_line = relative_rmse, point_to_line
        self.trees: dict[int, object] = {} if trees is None else trees
        self._open3d_clouds: dict = {}

    def tree(self, level: int):
        """The reference points' KD-tree at one level, built once (search, ICP and evidence share it)."""
        if level not in self.trees:
            self.trees[level] = build_tree(self.reference[level].points,
                                           max_distance=self.max_correspondence_distance * 2**level)
        return self.trees[level]

    def at_level(self, moving: CloudPyramid, T: np.ndarray, level: int, *, dist: float, model: str | None = None,
                 callback: Callable[[IcpIteration], None] | None = None, final: bool = True,
                 iterations: int | None = None) -> RegistrationResult:
        """One ICP step at ``level`` from ``T`` with correspondence distance ``dist`` (``model`` overrides
        the settings' model, ``iterations`` the iterations per level)."""
        settings = self.settings if model is None else replace(self.settings, model=model)
        call = StepCall(max_correspondence_distance=dist, max_iteration=iterations or self.iterations,
                        relative_rmse=self.relative_rmse * 2**level, level=level, callback=callback, final=final,
                        target_index=lambda: self.tree(level), open3d_clouds=self._open3d_clouds)
        return self.step(moving[level].points, self.reference[level].points, T, settings, call)

    def refine(self, moving: CloudPyramid, T: np.ndarray, *, top: int | None = None,
               callback: Callable[[IcpIteration], None] | None = None) -> Refinement:
        """Coarse-to-fine ICP from ``T`` (from level ``top``, default the coarsest)."""
        out = Refinement(T)
        while top is not None and top > 0 and (len(moving[top]) < 3 or len(self.reference[top]) < 3):
            top -= 1  # no edge points there (an overexposed frame's coarse levels): the pass starts finer, as the loop does
        if top is not None:
            # A start already within a few cells of level ``top``: one pass there with twice the
            # correspondence distance brings it into the usual gate.
            r = self.at_level(moving, T, top, dist=2.0 * self.max_correspondence_distance * 2**top,
                              callback=callback, final=False)
            out = Refinement(r.matrix, r.fitness, r.inlier_rmse, -1 if r.iterations < 0 else r.iterations,
                             r.converged)
        top = len(self.reference) - 1 if top is None else top
        for level in range(top, 0 if self.point_to_line else -1, -1):
            if len(moving[level]) < 3 or len(self.reference[level]) < 3:
                continue
            check_rank(moving[level].points, self.settings.model)
            finish = level == 0 and self.settings.model in ("affine", "projective")
            r = self.at_level(moving, out.matrix, level, dist=self.max_correspondence_distance * 2**level,
                              callback=callback, final=level == 0,
                              iterations=max(self.iterations, FINISH_ITERATIONS) if finish else None)
            out = Refinement(r.matrix, r.fitness, r.inlier_rmse, _total(out.iterations, r), r.converged)
        if self.point_to_line:
            out = self._point_to_line(moving, out, callback)
        return out

    def _point_to_line(self, moving: CloudPyramid, start: Refinement, callback) -> Refinement:
        """The reference backend's point-to-line finish at full resolution."""
        s = self.settings
        settings = IcpSettings(model=s.model, relative_fitness=min(s.relative_fitness, 1e-6),
                               weights="tukey" if s.weights == "none" else s.weights, metric="point_to_line")
        target = self.reference[0]
        call = StepCall(max_correspondence_distance=self.max_correspondence_distance, max_iteration=self.iterations,
                        relative_rmse=min(self.relative_rmse, 1e-6), target_normals=target.normals, callback=callback,
                        level=0, target_index=lambda: self.tree(0))
        r = reference_step(moving[0].points, target.points, start.matrix, settings, call)
        return Refinement(r.matrix, r.fitness, r.inlier_rmse, -1 if start.iterations < 0 else
                          start.iterations + r.iterations, r.converged)
