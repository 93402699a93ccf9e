"""pcreg's reference ICP: numpy + a compiled exact nearest-neighbour KD-tree, any dimension, every motion model.

Iterative closest point after Besl & McKay (1992, "A method for registration of 3-D shapes"), with
closed-form steps from Umeyama (1991, "Least-squares estimation of transformation parameters between
two point patterns") and Horn (1987, "Closed-form solution of absolute orientation using unit
quaternions"). The loop, the stopping rule and the definitions of fitness and inlier RMSE follow
Open3D's legacy ``registration_icp`` so the two can be checked against each other:

- correspondences: each source point's nearest target point closer than ``max_correspondence_distance``
  (:class:`pcreg.registration.kdtree.KDTreeIndex`, exact; equidistant targets: the lowest index);
- fitness = correspondences / source points; inlier_rmse = sqrt(mean squared correspondence distance);
- after each update, stop when |Δfitness| < relative_fitness and |Δinlier_rmse| < relative_rmse
  (absolute changes, as Open3D compares them), or after ``max_iteration`` updates.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Callable

import numpy as np
from .._jit import njit, prange

from ..errors import InputError, RegistrationError
from . import _kd_kernels, _nn_kernels, nn
from .closed_forms import (MIN_POINTS, _dlt_normal_pairs, _umeyama, check_rank, estimate, estimate_affine,  # noqa: F401  (named here too)
                           check_support, estimate_horn_quaternion, estimate_projective, estimate_translation,
                           estimate_umeyama, paired_targets, pairs_needed, robust_weights, umeyama_from_moments)
from .icp_options import METRICS, WEIGHTS, ICPOptions  # noqa: F401  (METRICS, WEIGHTS: named here too)
from .inputs import backend_inputs
from .kdtree import KDTreeIndex
from .nn import GridIndex
from .normal_steps import RECENTRE, estimate_point_to_line, estimate_point_to_plane, normals_problem
from .result import IcpIteration, RegistrationResult
from .transforms import apply, check_model


def build_tree(target: np.ndarray, *, queries: int | None = None, max_distance: float | None = None) -> KDTreeIndex:
    """Exact nearest-neighbour index of the target (:class:`~pcreg.registration.kdtree.KDTreeIndex`).

    max_distance, queries : accepted for compatibility (the tree is the same whatever the queries).
    """
    return KDTreeIndex(target)


def _correspond(tree, pts: np.ndarray, max_dist: float):
    """(squared distances, indices, found) of each point's nearest target within ``max_dist``.

    ``tree`` is a :class:`KDTreeIndex`, a :class:`GridIndex` or anything with ``cKDTree.query``'s interface."""
    if isinstance(tree, (KDTreeIndex, GridIndex)):
        d2, idx = tree.nearest(pts, max_dist)
        return d2, idx, idx >= 0
    workers = -1 if pts.shape[0] > 20000 else 1
    dist, idx = tree.query(pts, k=1, distance_upper_bound=max_dist, workers=workers)
    ok = np.isfinite(dist)
    return np.where(ok, dist * dist, np.inf), idx, ok


def _score(d2: np.ndarray, ok: np.ndarray, n: int) -> tuple[float, float]:
    k = int(ok.sum())
    if k == 0:
        return 0.0, 0.0
    return k / n, float(np.sqrt(np.sum(d2[ok]) / k))


@njit(cache=True)
def _settled(prev_fitness: float, fitness: float, prev_rmse: float, rmse: float, relative_fitness: float,
             relative_rmse: float) -> bool:
    """Open3D's stopping rule: both the fitness and the inlier RMSE changed by less than their thresholds
    (absolute changes, despite the names). Compiled: the compiled loop (:func:`_scored`) applies it too."""
    return abs(prev_fitness - fitness) < relative_fitness and abs(prev_rmse - rmse) < relative_rmse


def _finished(T: np.ndarray, fitness: float, rmse: float, iterations: int, converged: bool,
              start: float) -> RegistrationResult:
    return RegistrationResult(matrix=T, fitness=fitness, inlier_rmse=rmse, iterations=iterations,
                              converged=converged, backend="reference", seconds=time.perf_counter() - start)


def icp_reference(source: np.ndarray, target: np.ndarray, options: ICPOptions, *, init: np.ndarray | None = None,
                  target_normals: np.ndarray | None = None, tree: KDTreeIndex | GridIndex | None = None,
                  callback: Callable[[IcpIteration], None] | None = None, level: int = 0,
                  robust_scale: float | None = None, dlt: str = "svd") -> RegistrationResult:
    """One ICP run at one scale: a :class:`RegistrationResult` whose ``matrix`` is ``T_target_source``.

    source : (N, d), target : (M, d) float64, finite; d = 2 or 3.
    options : the model, ``max_correspondence_distance`` (a number here), the stopping rule, the weights,
        metric and rotation (:class:`~pcreg.registration.icp_options.ICPOptions`; its ``schedule`` and
        ``count_iterations`` are :func:`pcreg.icp`'s and Open3D's, not read here).
    target_normals : (M, d) the target's normals, for ``metric="point_to_line"`` (2-D; without them the
        step is point-to-point) and ``metric="point_to_plane"`` (3-D, rigid; needed).
    tree : a prebuilt index of ``target`` (:func:`build_tree`, or a ``scipy.spatial.cKDTree``), reused
        across calls on the same target.
    robust_scale : the robust weights' scale (None: estimated from each iteration's distances).
    dlt : how the projective model's step is solved (:data:`~pcreg.registration.closed_forms.DLT_SOLVES`).
    """
    if options.max_correspondence_distance is None:
        raise InputError("icp_reference needs options.max_correspondence_distance (pcreg.icp chooses one)")
    start = time.perf_counter()
    source, target, T = backend_inputs(source, target, init, who="icp_reference")
    model, weights, metric, rotation = options.model, options.weights, options.metric, options.rotation
    max_correspondence_distance, max_iteration = options.max_correspondence_distance, options.max_iteration
    relative_fitness, relative_rmse = options.relative_fitness, options.stopping_rmse(source, target)
    d = source.shape[1]
    check_model(model, d)
    if tree is None:
        tree = build_tree(target, max_distance=max_correspondence_distance)
    if metric == "point_to_line" and (d != 2 or target_normals is None):
        metric = "point_to_point"
    if metric == "point_to_plane" and (d != 3 or target_normals is None or model != "rigid"):
        raise InputError("metric='point_to_plane' needs 3-D clouds, the target's normals and the rigid model")
    if (metric == "point_to_point" and weights == "none" and model in _MOMENT_MODELS and isinstance(tree, KDTreeIndex)
            and not (rotation == "quaternion" and d == 3 and model == "rigid")):
        return _icp_moments(source, target, T, tree, model=model, max_distance=max_correspondence_distance,
                            max_iteration=max_iteration, relative_fitness=relative_fitness,
                            relative_rmse=relative_rmse, callback=callback, level=level, start=start)
    if (metric == "point_to_point" and weights == "none" and model == "projective" and dlt == "normal" and d == 2
            and isinstance(tree, KDTreeIndex)):
        return _icp_projective(source, target, T, tree, max_distance=max_correspondence_distance,
                               max_iteration=max_iteration, relative_fitness=relative_fitness,
                               relative_rmse=relative_rmse, callback=callback, level=level, start=start)
    pts = apply(T, source)
    n = source.shape[0]
    d2, idx, ok = _correspond(tree, pts, max_correspondence_distance)
    fitness, rmse = _score(d2, ok, n)
    iterations, converged = 0, False

    def report(i: int) -> None:
        if callback is not None:
            callback(IcpIteration(backend="reference", level=level, iteration=i, matrix=T.copy(), fitness=fitness,
                                  inlier_rmse=rmse, source_points=pts, target_points=target,
                                  target_indices=np.where(ok, idx, -1)))

    report(0)
    for i in range(max_iteration):
        need = pairs_needed(model, d, metric)
        p, q = pts[ok], target[idx[ok]]
        w = robust_weights(np.sqrt(d2[ok]), weights, scale=robust_scale, trim_fraction=options.trim_fraction)
        if int(np.count_nonzero(w)) < need:
            break  # too few pairs for the model: the run stops where it is, not converged
        if metric == "point_to_line":
            update = estimate_point_to_line(p, q, target_normals[idx[ok]], w, model)
        elif metric == "point_to_plane":
            update = estimate_point_to_plane(p, q, target_normals[idx[ok]], w)
        else:
            update = estimate(p, q, w, model, rotation=rotation, dlt=dlt)
        if not np.all(np.isfinite(update)):
            raise RegistrationError("ICP update is not finite (degenerate correspondences)")
        T = update @ T
        pts = apply(update, pts)
        iterations = i + 1
        prev_fitness, prev_rmse = fitness, rmse
        d2, idx, ok = _correspond(tree, pts, max_correspondence_distance)
        fitness, rmse = _score(d2, ok, n)
        report(iterations)
        if _settled(prev_fitness, fitness, prev_rmse, rmse, float(relative_fitness), float(relative_rmse)):
            converged = True
            break
    return _finished(T, fitness, rmse, iterations, converged, start)


#: The steps linearised about the current pose (:mod:`~pcreg.registration.normal_steps`), which can raise the
#: distances they are meant to lower; point-to-point steps cannot (:func:`truncated_rms`).
LINEARISED_METRICS = ("point_to_line", "point_to_plane")


def truncated_rms(fitness: float, inlier_rmse: float, max_distance: float) -> float:
    """The RMS over every source point of its distance to its nearest target point, capped at ``max_distance``:
    sqrt(fitness · inlier_rmse² + (1 - fitness) · max_distance²), from two entries of an ICP's trace. Neither a
    correspondence step nor a point-to-point step raises it (Besl & McKay's monotonicity, with the points beyond
    ``max_distance`` counted at it); a linearised step can overshoot and raise it. A gate past 1e150, whose square a
    float cannot hold (``pcreg crosscheck --max-distance 1e160`` raised OverflowError), is taken without squaring."""
    if max_distance < 1e150:  # the sum of squares, as it has always been read
        return math.sqrt(fitness * inlier_rmse ** 2 + (1.0 - fitness) * max_distance ** 2)
    return math.hypot(math.sqrt(fitness) * inlier_rmse, math.sqrt(max(0.0, 1.0 - fitness)) * max_distance)


def scores_at(source: np.ndarray, target: np.ndarray, T: np.ndarray, max_distance: float) -> tuple[float, float]:
    """(fitness, inlier RMSE) of ``source`` moved by ``T``: iteration 0 of an ICP's trace from ``T``."""
    d2, _, ok = _correspond(build_tree(target), apply(T, source), max_distance)
    return _score(d2, ok, source.shape[0])


def check_progress(start: tuple[float, float], end: RegistrationResult, max_distance: float, metric: str) -> None:
    """Raise :class:`RegistrationError` when a run of linearised steps (:data:`LINEARISED_METRICS`) diverged: it
    ended with a larger :func:`truncated_rms` than it started with (``start``: iteration 0's fitness and inlier
    RMSE), by more than 1e-9 ``max_distance`` (rounding). Such a result fits the clouds worse than the initial
    guess did. (A run that loses every pair is refused before this, saying so.)

    PCL's curved PointToPlane test surface with nearest-neighbour pairs: the steps overshoot and the RMSE runs
    0.46 at the start, 0.34, 0.47, 0.51, ..., 2.1 after 10 steps and 16 at a fixed point after 22, keeping every
    pair; point-to-point ICP recovers the motion to 1e-4 there."""
    if metric not in LINEARISED_METRICS:
        return
    first, last = truncated_rms(*start, max_distance), truncated_rms(end.fitness, end.inlier_rmse, max_distance)
    if last - first > 1e-9 * max_distance:
        name = metric.replace("_", "-")
        raise RegistrationError(
            f"registration refused: the {name} ICP diverged: after {end.iterations} step(s) the source lies farther "
            f"from the target than at the start (RMS distance capped at {max_distance:g}: {first:.4g} at the start, "
            f"{last:.4g} at the end; fitness {end.fitness:.3g}, inlier RMSE {end.inlier_rmse:.4g}); its linearised "
            "steps overshoot where the surface curves within the correspondence distance: try "
            "metric='point_to_point', or an init nearer the answer")


def check_paired_normals(T: np.ndarray, source: np.ndarray, target: np.ndarray, target_normals: np.ndarray | None,
                         max_distance: float, metric: str) -> None:
    """Raise :class:`RegistrationError` when, at the result ``T``, the normals of the target points the source is
    paired with (within ``max_distance``) leave a direction free (:func:`normals_problem`): the linearised steps
    cannot fix the motion along it, and where it is free they stop and call it converged. The target's normals as
    a whole are checked when the run starts; this is for pairs that reach only part of them.

    A cylinder's side paired while the ground plane beneath it lies beyond the correspondence distance: the reference
    step's 6x6 system is singular, its step the identity, and the run "converged" after one iteration where it
    started (inlier RMSE 0.199; Open3D's moved across the axis and left the motion along it at 0)."""
    if metric not in LINEARISED_METRICS or target_normals is None:
        return
    why = normals_problem(target_normals[paired_targets(T, source, target, max_distance)])
    if why is not None:
        raise RegistrationError(f"registration refused: at the result, the target points the source is paired with "
                                f"have normals that cannot fix the motion ({why}); give target points whose "
                                "normals point every way within the correspondence distance, or "
                                "metric='point_to_point'")


_MOMENT_MODELS = ("translation", "rigid", "similarity")


def _icp_moments(source: np.ndarray, target: np.ndarray, T: np.ndarray, tree: KDTreeIndex, *, model: str,
                 max_distance: float, max_iteration: int, relative_fitness: float, relative_rmse: float,
                 callback, level: int, start: float) -> RegistrationResult:
    """The same loop as :func:`icp_reference` for point-to-point steps without weights of the models
    whose closed form needs only the pairs' moments (translation, rigid, similarity), compiled: each
    iteration's move, correspondence search, sums, closed form and stopping rule run in
    :func:`_moment_loop` without returning to Python. With a ``callback`` the loop runs one iteration a
    call, so that the callback sees each iteration as it ends.

    Where :func:`~pcreg.registration.nn.threaded` says so (large clouds, or from 1,000 source points
    on a machine with a core to spare) the loop is :func:`_moment_loop_threads`, whose moves and
    searches run on every thread: the same matches, and the moments summed on one thread in the same
    order, so the same numbers to the bit."""
    d = source.shape[1]
    n = source.shape[0]
    pts = np.ascontiguousarray(apply(T, source))
    T = np.array(T, dtype=np.float64)
    code, need = _MOMENT_MODELS.index(model), pairs_needed(model, d)
    r2 = nn.squared_bound(max_distance)  # the bound move_and_match uses
    rel_fitness, rel_rmse = float(relative_fitness), float(relative_rmse)  # one compiled signature
    d2, idx, mom = tree.move_and_match(pts, None, max_distance)
    state = np.zeros(5)  # fitness, inlier RMSE, iterations, converged, error (see _moment_loop)
    _scored(mom[0], mom[1], n, 0.0, 0.0, state)  # thresholds 0: the rule cannot hold (|x| < 0)
    loop = _moment_loop_threads if nn.threaded(n) else _moment_loop

    def run_steps(steps: int) -> None:
        loop(pts, T, steps, code, need, rel_fitness, rel_rmse, r2, *tree.search_arrays, d2, idx, tree.data,
             tree.center, state)

    return _drive(run_steps, state, T, pts, idx, target, max_iteration=max_iteration, callback=callback, level=level,
                  start=start)


#: What a compiled loop's error code (``state[4]``) means; 3 (too few pairs) ends the run where it is.
_LOOP_ERRORS = {1: "ICP update is not finite (degenerate correspondences)",
                2: "degenerate correspondences: all source points coincide", 4: "degenerate homography"}


def _drive(run_steps, state: np.ndarray, T: np.ndarray, pts: np.ndarray, idx: np.ndarray, target: np.ndarray, *,
           max_iteration: int, callback, level: int, start: float) -> RegistrationResult:
    """A compiled loop run to its end: ``run_steps(k)`` runs up to k iterations in place on ``T``, ``pts``, ``idx``
    and ``state`` (:func:`_moment_loop`'s), all at once, or one a call with a ``callback``, which sees the start and
    each iteration; an error code (:data:`_LOOP_ERRORS`) is a :class:`RegistrationError`."""
    def report() -> None:
        if callback is not None:
            callback(IcpIteration(backend="reference", level=level, iteration=int(state[2]), matrix=T.copy(),
                                  fitness=float(state[0]), inlier_rmse=float(state[1]), source_points=pts.copy(),
                                  target_points=target, target_indices=idx.copy()))

    report()
    while state[2] < max_iteration and not state[3]:
        run_steps(1 if callback is not None else max_iteration - int(state[2]))
        if int(state[4]) in _LOOP_ERRORS:
            raise RegistrationError(f"registration refused: {_LOOP_ERRORS[int(state[4])]}")
        if state[4] == 3:
            break
        report()
    return _finished(T, float(state[0]), float(state[1]), int(state[2]), bool(state[3]), start)


@njit(cache=True)
def _next_update(k, sd2, sp, sq, spp, sqp, center, model, need, T, state):
    """One iteration's update from the matched pairs' moments (:func:`pcreg.registration._nn_kernels._moments`,
    relative to ``center``; ``sd2`` unused), in the original coordinates; model 0, 1, 2 = translation,
    rigid, similarity. Applies it to ``T`` and counts the iteration in ``state`` (:func:`_moment_loop`);
    on error (1: not finite; 2: a similarity's source points all coincide; 3: fewer pairs than the model
    needs, ``need``) sets ``state[4]`` instead."""
    d = sp.shape[0]
    update = np.eye(d + 1)
    if k < need:  # too few pairs for the model: the run stops where it is, not converged
        state[4] = 3
        return update
    mp = sp / k
    mq = sq / k
    if model == 0:
        for a in range(d):
            update[a, d] = mq[a] - mp[a]
    else:
        cov = np.empty((d, d))  # Umeyama's Eq. 38
        var_p = spp / k  # Eq. 36
        for a in range(d):
            var_p -= mp[a] * mp[a]
            for b in range(d):
                cov[a, b] = sqp[a, b] / k - mq[a] * mp[b]
        update, ok = _umeyama(cov, var_p, mp, mq, model == 2)
        if not ok:
            state[4] = 2
            return update
    # back from centred coordinates: x -> A (x - c) + t + c
    for a in range(d):
        acc = 0.0
        for b in range(d):
            acc += update[a, b] * center[b]
        update[a, d] += center[a] - acc
    if not np.isfinite(update).all():
        state[4] = 1
        return update
    moved = np.empty_like(T)
    for a in range(d + 1):
        for b in range(d + 1):
            acc = 0.0
            for m in range(d + 1):
                acc += update[a, m] * T[m, b]
            moved[a, b] = acc
    T[:, :] = moved
    state[2] += 1
    return update


@njit(cache=True)
def _scored(k, sd2, n, relative_fitness, relative_rmse, state):
    """Fitness and inlier RMSE of ``k`` matches (squared distances summing to ``sd2``) among ``n`` source
    points into ``state``; True, and converged set, when Open3D's stopping rule (:func:`_settled`) holds."""
    fitness = 0.0 if k == 0 else k / n
    rmse = 0.0 if k == 0 else math.sqrt(sd2 / k)
    settled = _settled(state[0], fitness, state[1], rmse, relative_fitness, relative_rmse)
    state[0], state[1] = fitness, rmse
    if settled:
        state[3] = 1.0
    return settled


# When the matched pairs' mean lies more than RECENTRE (:mod:`~pcreg.registration.normal_steps`) of their
# spreads (standard deviation) from the centre their moments are summed about (the target's bounding box's), the
# moments are summed again about that mean: moments summed in one pass far from their points lose their precision
# (a stray target point 1e5 away put the box's centre among nothing, and the rotation came out 0.2 degrees off; at
# 1e6, 47). Near, the sums are kept as they are (the same numbers as before the rule).


@njit(cache=True)
def _centred_moments(pts, target, out_d2, out_i, center):
    """``(moments, centre)``: :func:`~pcreg.registration._nn_kernels._moments` about ``center``, or summed again
    about the matched source points' mean when that lies beyond :data:`RECENTRE` spreads from ``center``."""
    mom = _nn_kernels._moments(pts, target, out_d2, out_i, center)
    k, sp, spp = mom[0], mom[2], mom[4]
    if k == 0:
        return mom, center
    mp = sp / k
    offset = 0.0
    for a in range(mp.shape[0]):
        offset += mp[a] * mp[a]
    spread = spp / k - offset  # one-pass variance: far from its points, rounding noise, or below 0
    if offset <= RECENTRE * RECENTRE * max(spread, 0.0):
        return mom, center
    mean = center + mp
    return _nn_kernels._moments(pts, target, out_d2, out_i, mean), mean


@njit(cache=True)
def _moment_loop(pts, T, steps, model, need, relative_fitness, relative_rmse, r2, nodes, spts, sidx, depth, out_d2,
                 out_i, target, center, state):
    """Up to ``steps`` point-to-point iterations, in place: ``pts`` (the moved source), ``T``, the
    matches ``out_d2`` / ``out_i`` (on entry, those of ``pts``) and ``state`` = [fitness, inlier RMSE,
    iterations, converged, error]. Stops early on an error (:func:`_next_update`) or when the
    stopping rule holds."""
    mom, c = _centred_moments(pts, target, out_d2, out_i, center)
    for _ in range(steps):
        update = _next_update(*mom, c, model, need, T, state)
        if state[4] != 0:
            return
        _kd_kernels._move_query_serial(pts, update, True, r2, nodes, spts, sidx, depth, out_d2, out_i)
        mom, c = _centred_moments(pts, target, out_d2, out_i, center)
        if _scored(mom[0], mom[1], pts.shape[0], relative_fitness, relative_rmse, state):
            return


@njit(cache=True, parallel=True)
def _moment_loop_threads(pts, T, steps, model, need, relative_fitness, relative_rmse, r2, nodes, spts, sidx, depth,
                         out_d2, out_i, target, center, state):
    """:func:`_moment_loop` with each iteration's moves and searches on every thread (numba's
    ``prange``, written out here: a cached compiled function that calls a ``parallel=True`` one can
    crash once it is loaded back from the cache, numba bug 8578). The moments are summed on one thread,
    in point order, as there. Each thread takes chunks of :data:`~pcreg.registration._kd_kernels.CHUNK`
    queries, with one search stack a chunk."""
    d, n, chunk = pts.shape[1], pts.shape[0], _kd_kernels.CHUNK
    mom, c = _centred_moments(pts, target, out_d2, out_i, center)
    for _ in range(steps):
        update = _next_update(*mom, c, model, need, T, state)
        if state[4] != 0:
            return
        for part in prange((n + chunk - 1) // chunk):
            stack_node, stack_gap = _kd_kernels._stacks(depth)
            for t in range(part * chunk, min(n, (part + 1) * chunk)):
                _nn_kernels._move(pts, t, update, d)
                out_d2[t], out_i[t] = _kd_kernels._nearest(pts[t], r2, np.int64(-1), nodes, spts, sidx, stack_node,
                                                           stack_gap)
        mom, c = _centred_moments(pts, target, out_d2, out_i, center)
        if _scored(mom[0], mom[1], pts.shape[0], relative_fitness, relative_rmse, state):
            return


def _icp_projective(source: np.ndarray, target: np.ndarray, T: np.ndarray, tree: KDTreeIndex, *, max_distance: float,
                    max_iteration: int, relative_fitness: float, relative_rmse: float, callback, level: int,
                    start: float) -> RegistrationResult:
    """The same loop as :func:`icp_reference` for point-to-point projective steps without weights whose DLT is
    solved from its normal matrix (``dlt="normal"``, the model check's refinement), compiled: each iteration's
    DLT (:func:`~pcreg.registration.closed_forms._dlt_normal_pairs`), move, correspondence search and stopping
    rule run in :func:`_projective_loop` without returning to Python (one iteration a call with a ``callback``).
    The same homographies as the NumPy loop to rounding (the sums are taken one pair at a time)."""
    n = source.shape[0]
    pts = np.ascontiguousarray(apply(T, source))
    T = np.array(T, dtype=np.float64)
    d2, idx = tree.nearest(pts, max_distance)
    state = np.zeros(5)  # fitness, inlier RMSE, iterations, converged, error (see _moment_loop)
    ok = idx >= 0
    _scored(int(ok.sum()), float(d2[ok].sum()), n, 0.0, 0.0, state)  # thresholds 0: the rule cannot hold
    need, ones, r2 = pairs_needed("projective", 2), np.ones(n), nn.squared_bound(max_distance)

    def run_steps(steps: int) -> None:
        _projective_loop(pts, T, steps, need, float(relative_fitness), float(relative_rmse), r2, *tree.search_arrays,
                         d2, idx, tree.data, ones, state)

    return _drive(run_steps, state, T, pts, idx, target, max_iteration=max_iteration, callback=callback, level=level,
                  start=start)


@njit(cache=True, error_model="numpy")
def _projective_loop(pts, T, steps, need, relative_fitness, relative_rmse, r2, nodes, spts, sidx, depth, out_d2,
                     out_i, target, w, state):
    """Up to ``steps`` projective point-to-point iterations, in place: ``pts`` (the moved source, 2-D), ``T``,
    the matches ``out_d2`` / ``out_i`` (on entry, those of ``pts``) and ``state`` as :func:`_moment_loop`'s
    (errors: 1, not finite; 3, fewer pairs of nonzero weight ``w`` than ``need``; 4, a degenerate
    homography). A point the update sends to infinity comes out inf or NaN, as :func:`~.transforms.apply`
    makes it, and matches nothing."""
    stack_node, stack_gap = _kd_kernels._stacks(depth)
    n = pts.shape[0]
    for _ in range(steps):
        pairs = 0
        for t in range(n):
            if out_i[t] >= 0 and w[t] != 0.0:
                pairs += 1
        if pairs < need:  # too few pairs for the model: the run stops where it is, not converged
            state[4] = 3
            return
        H, error = _dlt_normal_pairs(pts, target, out_i, w)
        if error == 0 and not np.isfinite(H).all():
            error = 1
        if error != 0:
            state[4] = error
            return
        T[:, :] = H @ T
        state[2] += 1
        k, sd2 = 0, 0.0
        for t in range(n):
            x, y = pts[t, 0], pts[t, 1]
            h = H[2, 0] * x + H[2, 1] * y + H[2, 2]
            pts[t, 0] = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / h
            pts[t, 1] = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / h
            out_d2[t], out_i[t] = _kd_kernels._nearest(pts[t], r2, np.int64(-1), nodes, spts, sidx, stack_node,
                                                       stack_gap)
            if out_i[t] >= 0:
                k += 1
                sd2 += out_d2[t]
        if _scored(k, sd2, n, relative_fitness, relative_rmse, state):
            return


def warm_up() -> None:
    """Run the ICP once in 2-D and 3-D, and each of its compiled parts that Python calls directly, so
    that every compiled kernel it uses is loaded (or compiled)."""
    rng = np.random.default_rng(0)
    for d in (2, 3):
        target = rng.uniform(0, 10, (50, d))
        options = ICPOptions(max_correspondence_distance=1.0, max_iteration=2)
        icp_reference(target + 0.05, target, options)
        icp_reference(target + 0.05, target, replace(options, weights="huber"))
        if d == 2:  # the model check's compiled projective loop
            icp_reference(target + 0.05, target, replace(options, model="projective"), dlt="normal")
        estimate_umeyama(target + 0.05, target, np.ones(50), with_scale=True)
        # the threaded loop (clouds of nn.PARALLEL_MIN_QUERIES points and more, or from
        # nn.PARALLEL_MIN_QUERIES_IDLE on an idle machine), and the steps other callers use
        tree = KDTreeIndex(target)
        pts = np.ascontiguousarray(target + 0.05)
        state = np.zeros(5)
        mom = tree.move_and_match(pts, None, 1.0)[2]
        _next_update(*mom, 1, 3, np.eye(d + 1), state)
        _scored(mom[0], mom[1], 50, 0.0, 0.0, state)
        d2, idx, _ = tree.move_and_match(pts, None, 1.0)
        if not nn.can_thread():  # a child forked after its parent's OpenMP threads started
            continue
        _moment_loop_threads(pts, np.eye(d + 1), 2, 1, 3, 0.0, 0.0, 1.0, *tree.search_arrays, d2, idx, tree.data,
                             tree.center, np.zeros(5))
