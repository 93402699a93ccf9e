"""The dense registration's driver: the non-rigid ICP of each pyramid level, coarse to fine, from a
global ``T_ref_mov`` (or an earlier registration's grid), the plausibility figure, and the field at
full resolution (:func:`refine_field`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..._threads import beside, wait_quietly
from ...errors import RegistrationError
from ..result import RegistrationResult
from .field import _full_field
from .grid import GridWeights, _interpolate, _level_key, _level_weights, _upsample_grid
from .levels import DenseReference, _Level, _level_problem, _Problem, _Pyramids, _pyramids
from .options import DenseOptions, _coarsest_level
from .result import DenseIteration, DenseRegistrationResult
from .robust import _nan_median
from .window import match_window

__all__ = ["DENSE_STAGES", "InitialGrid", "refine_field"]


#: Stages of :func:`pcreg.register_dense` timed in its result's ``info["times"]`` (seconds): pyramids,
#: noise, samples and the normal equations' set-up per level; the samples' positions under the field
#: and the windowed correspondence search; the robust weights and the grid's solve; the plausibility
#: figure; the field and its confidence at full resolution. The global step is the result's
#: ``global_result.seconds``.
DENSE_STAGES: tuple[str, ...] = ("pyramid", "search", "solve", "evidence", "field")


class _StageClock:
    """Seconds per stage: each :meth:`lap` charges the time since the last one to the stage named."""

    def __init__(self) -> None:
        self.times = dict.fromkeys(DENSE_STAGES, 0.0)
        self._t = time.perf_counter()

    def lap(self, stage: str) -> None:
        t = time.perf_counter()
        self.times[stage] += t - self._t
        self._t = t


def _plausibility(R, Mv, P, C, GP, NE, lam, radius, U) -> float:
    """The field's evidence against chance: the median colour distance of the samples' matches with
    every sample moved by half the image (wrapped onto unrelated content of the same images), divided
    by the same median under the final field. About 1 for unrelated images (1.02-1.21 measured on
    noise and on frames of different CamVid clips), 1.3-3.3 for neighbouring frames of one clip."""
    h, w = R.shape[:2]
    X = GP + NE.interpolate(U)
    # the colour distances alone: no mutual test (the same distances, half the search)
    m = match_window(R, Mv, P, X, C, radius=radius, lam=lam, mutual=False)
    Xc = np.column_stack([np.mod(X[:, 0] + 0.5 * w, w), np.mod(X[:, 1] + 0.5 * h, h)])
    mc = match_window(R, Mv, P, Xc, C, radius=radius, lam=lam, mutual=False)
    return float(_nan_median(mc[:, 2]) / max(float(_nan_median(m[:, 2])), 1e-9))


@dataclass(frozen=True)
class _LevelOutcome:
    """After a level's iterations: the grid's displacements, the nodes' data weights (None when no
    step was taken), the steps taken, and the last step's fitness and weighted rms (px of the image)."""

    U: np.ndarray
    weights_node: np.ndarray | None
    steps: int
    fitness: float
    rms: float


def _iterate_level(lv: _Level, pb: _Problem, U: np.ndarray, options: DenseOptions, *, clock: _StageClock,
                   callback: Callable[[DenseIteration], None] | None) -> _LevelOutcome:
    """The non-rigid ICP iterations of one level, from the grid ``U``; a level whose matches all fail
    stops early. ``pb``: the level's problem."""
    f = lv.scale
    membrane = options.membrane
    base_alpha = 1.0 / (lv.spacing * membrane.strain) ** 2
    weights_node, steps, fitness, rms = None, 0, float("nan"), float("nan")
    for it in range(options.iterations):
        clock.lap("pyramid" if it == 0 else "solve")
        X = pb.GP + pb.NE.interpolate(U)
        m = match_window(pb.R, pb.Mv, pb.P, X, pb.C, radius=pb.radius, lam=pb.lam)
        clock.lap("search")
        k = membrane.stiffness[min(it, len(membrane.stiffness) - 1)]
        alpha = k * base_alpha
        step = pb.NE.robust_step(m, X, pb.GP, pb.sigma, alpha, 1e-4 * alpha, U, maxiter=membrane.cg_iterations)
        if step is None:  # no sample got a weight: the field stays
            break
        U, weights_node, sw, swr, n_inliers = step
        steps += 1
        rms = f * math.sqrt(swr / sw) if sw > 0 else 0.0
        fitness = n_inliers / len(pb.P)
        if callback is not None:
            callback(DenseIteration(level=lv.level, iteration=it, stiffness=float(k), points=len(pb.P),
                                    inliers=int(n_inliers), rms=rms,
                                    grid=(f * U).reshape(lv.gshape[0], lv.gshape[1], 2).astype(np.float32)))
    return _LevelOutcome(U, weights_node, steps, fitness, rms)


@dataclass(frozen=True)
class _Grid:
    """The control grid after every level: its displacements ``U`` (nodes, 2) in pixels of the finest
    level, the finest level's nodes' data weights, the steps taken, the finest level's last fitness and
    rms (zeros, as its weights, where the finest level took no step), the problem of the last level that
    took a step (``last``) and its grid after its steps (``last_U``, in its own pixels), and the finest
    level (``finest``)."""

    U: np.ndarray
    weights_node: np.ndarray
    steps: int
    fitness: float
    rms: float
    last: _Problem
    last_U: np.ndarray
    finest: _Level


def _coarse_to_fine(pyr: _Pyramids, T: np.ndarray, options: DenseOptions, *, top: int,
                    clock: _StageClock, callback: Callable[[DenseIteration], None] | None,
                    initial: InitialGrid | None = None) -> _Grid:
    """Every level from ``top`` to the finest, each starting from the coarser level's grid, the first
    from ``initial``'s grid or from zero (the global transform); the first level gets the wide gate
    (``options.radius``). :class:`~pcreg.errors.RegistrationError` when no level had samples to match; a
    finest level without samples, or whose matches all failed, leaves no evidence at its nodes (weights,
    fitness and rms 0) while the coarser levels' steps shape the field."""
    U: np.ndarray | None = None
    prev: _Level | None = None  # the coarser level
    last: _Problem | None = None
    last_U: np.ndarray | None = None
    weights_node, steps, fitness, rms = None, 0, 0.0, 0.0
    levels = range(top, options.finest_level - 1, -1)

    def problem(level: int) -> Callable[[], _Level]:
        return lambda: _level_problem(pyr, level, T, options, coarsest=top)

    # a level's problem does not depend on the grid: the finer ones are made on the helper thread
    # while this one works on the coarser levels
    ahead = {level: beside(problem(level)) for level in levels[1:]}
    for level in levels:
        clock.lap("solve")  # the last iteration of the level above
        lv = problem(level)() if level == top else ahead[level]()
        if (U is None or prev is None) and initial is not None:
            U = _grid_at_level(initial.grid, options.finest_level, lv, pyr.grid_weights)
        elif U is None or prev is None:
            U = np.zeros((lv.gshape[0] * lv.gshape[1], 2))
        else:
            U = _upsample_grid(U, prev.gshape, prev.spacing, lv.gshape, lv.spacing, 2.0, pyr.grid_weights)
        prev = lv
        if lv.problem is None:
            continue
        done = _iterate_level(lv, lv.problem, U, options, clock=clock, callback=callback)
        U = done.U
        if done.steps:
            weights_node, fitness, rms, last, last_U = done.weights_node, done.fitness, done.rms, lv.problem, U
            steps += done.steps
    clock.lap("solve")
    if U is None or weights_node is None or last is None or last_U is None or prev is None:
        raise RegistrationError("dense registration found no textured samples to match")
    if last is not prev.problem:  # the finest level took no step: a coarser level's weights are not its nodes'
        weights_node, fitness, rms = np.zeros(prev.gshape[0] * prev.gshape[1]), 0.0, 0.0
    return _Grid(U, weights_node, steps, fitness, rms, last, last_U, prev)


@dataclass(frozen=True)
class InitialGrid:
    """Where the grid starts: ``grid`` (gh, gw, 2), the finest level's displacements in full-resolution
    px (a :attr:`DenseRegistrationResult.grid`), at pyramid ``level`` (the levels above it are skipped)."""

    grid: np.ndarray
    level: int


def _grid_at_level(grid: np.ndarray, finest: int, lv: _Level, known: GridWeights | None = None) -> np.ndarray:
    """The finest level's grid (gh, gw, 2; full-resolution px) interpolated at level ``lv``'s nodes, in
    that level's px (bilinear, the edge nodes held beyond the grid): the same grid at the finest level.
    ``known``: weights made before (:func:`~pcreg.registration.dense.grid.grid_weights`)."""
    key = _level_key(grid.shape[:2], finest, lv.gshape, lv.scale, lv.spacing)
    cols, vals = known[key] if known and key in known else _level_weights(*key[1:])
    flat = np.ascontiguousarray(grid.reshape(-1, 2), dtype=np.float64)
    return _interpolate(cols, vals, flat, np.empty((len(cols), 2))) / lv.scale


def _check_evidence(evidence: float, chance_factor: float | None) -> None:
    if chance_factor is not None and evidence < chance_factor:
        raise RegistrationError(
            f"dense registration refused: the field's matches are only {evidence:.2f} times closer in colour "
            f"than matches on unrelated content (at least {chance_factor:g} required); the images do not "
            f"show the same scene")


def refine_field(ref: np.ndarray, mov: np.ndarray, global_result: RegistrationResult, options: DenseOptions, *,
                 callback: Callable[[DenseIteration], None] | None, started: float,
                 given_seconds: float = 0.0, initial: InitialGrid | None = None,
                 prepared: DenseReference | None = None) -> DenseRegistrationResult:
    """The dense step of :func:`pcreg.register_dense` on checked inputs: ``ref`` and ``mov`` (H, W, 3) uint8
    of one size, the global step's result (its ``T_ref_mov`` the field's start), ``options`` (checked
    against the images' shape); ``started`` is when the registration began (``time.perf_counter()``) and
    ``given_seconds`` the time of a global step done before it, both counted in the result's seconds;
    ``initial``: where the grid starts (None: from zero at the coarsest level); ``prepared``: ``ref``'s
    pyramid, checked against it (:func:`~pcreg.registration.dense.levels.check_prepared`), or None to
    build it here."""
    coarsest = _coarsest_level(ref.shape, options)
    top = coarsest if initial is None else min(initial.level, coarsest)  # the level the grid starts at
    T = np.asarray(global_result.matrix, dtype=np.float64)
    clock = _StageClock()
    pyr = _pyramids(ref if prepared is None else prepared, mov, top)
    clock.lap("pyramid")
    grid = _coarse_to_fine(pyr, T, options, top=top, clock=clock,
                           callback=callback, initial=initial)  # 2. the grid, coarse to fine
    # 3. the plausibility test and the field at full resolution: both follow from the final grid
    # alone, so the field is made whole on the helper thread while this one measures the evidence
    # (instead of the two one after the other, each shared in halves)
    field_later = beside(lambda: _full_field(T, grid.U, grid.weights_node, grid.finest, ref.shape[:2]))
    last = grid.last
    try:
        evidence = _plausibility(last.R, last.Mv, last.P, last.C, last.GP, last.NE, last.lam, last.radius, grid.last_U)
        clock.lap("evidence")
        _check_evidence(evidence, options.chance_factor)
    except BaseException:
        wait_quietly(field_later)
        raise
    full = field_later()
    clock.lap("field")
    return DenseRegistrationResult(matrix=T, field=full.field, confidence=full.confidence,
                                   global_result=global_result, fitness=grid.fitness, inlier_rmse=grid.rms,
                                   iterations=grid.steps, seconds=time.perf_counter() - started + given_seconds,
                                   backend=options.global_step.backend, grid=full.grid,
                                   info={"levels": (top, options.finest_level), "grid": full.grid.shape[:2],
                                         "evidence": evidence, "times": clock.times})
