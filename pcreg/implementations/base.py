"""What every ICP implementation takes and returns, and how comparable it claims to be.

An implementation receives :class:`Pinned` inputs — the same clouds, initial guess, correspondence
distance, iteration limit and stopping thresholds for all — and returns a
:class:`~pcreg.registration.result.RegistrationResult` (``T_target_source``, ``backend`` its name, a figure
it cannot report NaN, -1 or None, its iterations in ``trace`` when asked). It declares
its ``comparability`` with pcreg's reference ICP:

- ``step``: same correspondences, same closed-form step, same stopping rule: every iteration must match;
- ``fixed-point``: same objective (point-to-point least squares over nearest neighbours within the
  distance) reached by other steps or another stopping rule: the converged poses must match;
- ``objective``: a different objective (point-to-plane, GICP, a Gaussian mixture): results are compared
  with a stated tolerance only.

It also declares the settings it pins to get there (:meth:`Implementation.settings`), which the report
records next to its result.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from ..errors import InputError, PcregError
from ..registration.result import IcpIteration, RegistrationResult

STEP, FIXED_POINT, OBJECTIVE = "step", "fixed-point", "objective"
COMPARABILITY = (STEP, FIXED_POINT, OBJECTIVE)


class ImplementationError(PcregError):
    """An implementation failed on these inputs (reported as that implementation's error, in one line)."""


class MissingLibrary(ImplementationError):
    """An optional library an implementation needs is not installed."""


@dataclass(frozen=True)
class Pinned:
    """The inputs every implementation gets.

    source, target : (N, d), (M, d) float64, d = 2 or 3; init : (d+1, d+1) ``T_target_source`` guess.
    The stopping rule is Open3D's: stop after an iteration whose |Δfitness| < relative_fitness and
    |Δinlier_rmse| < relative_rmse, or after max_iterations iterations.

    Checked when made, as :func:`pcreg.icp` checks its inputs (an :class:`~pcreg.errors.InputError`): finite
    clouds of one dimension, a finite rigid ``init`` (every implementation runs the rigid ICP; Open3D and
    small_gicp returned a shear given as the guess as their converged result, and KISS-ICP's Sophus ended the
    process on a NaN one), a positive correspondence distance, at least one iteration.
    """

    source: np.ndarray
    target: np.ndarray
    init: np.ndarray
    max_correspondence_distance: float
    max_iterations: int = 30
    relative_fitness: float = 1e-6
    relative_rmse: float = 1e-6

    def __post_init__(self) -> None:
        from ..registration.inputs import backend_inputs
        from ..registration.transforms import rigid_problem
        from ..validation import check_float, check_int

        # float64 clouds are kept, not copied (a cross-check of 10^7 points pins them twice)
        source, target, init = backend_inputs(self.source, self.target, self.init, who="pinned")
        problem = rigid_problem(init)
        if problem is not None:
            raise InputError(f"{self._init_name()}: {problem}, and every implementation runs the rigid ICP")
        checked = {"source": source, "target": target, "init": init,
                   "max_correspondence_distance": check_float(self.max_correspondence_distance,
                                                              "max_correspondence_distance", lo=0, lo_open=True),
                   "max_iterations": check_int(self.max_iterations, "max_iterations", lo=1, hi=100_000),
                   "relative_fitness": check_float(self.relative_fitness, "relative_fitness", lo=0),
                   "relative_rmse": check_float(self.relative_rmse, "relative_rmse", lo=0)}
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    def _init_name(self) -> str:
        """How messages name the initial guess (a case read from files names its file)."""
        return "init"

    @property
    def dim(self) -> int:
        return int(self.source.shape[1])

    @cached_property
    def undetermined(self) -> str | None:
        """Why these clouds leave the rigid transform free (:func:`unconstrained`), or None; found once."""
        return unconstrained(self.source, self.target)

    def params(self) -> dict:
        """The scalar settings, as written to the ``{params}`` JSON file of ``cmd:`` implementations."""
        return {"max_correspondence_distance": float(self.max_correspondence_distance),
                "max_iterations": int(self.max_iterations),
                "relative_fitness": float(self.relative_fitness),
                "relative_rmse": float(self.relative_rmse)}

    def replace(self, **changes) -> "Pinned":
        kw = dict(source=self.source, target=self.target, init=self.init, **self.params())
        kw.update(changes)
        return Pinned(**kw)


class Implementation:
    """Base class of the adapters. Subclasses set the class attributes and implement :meth:`_run`."""

    name: str = ""
    comparability: str = STEP
    description: str = ""
    requires: tuple[str, ...] = ()  # importable modules
    dims: tuple[int, ...] = (2, 3)

    def missing(self) -> str | None:
        """None when usable, else why not (the missing library)."""
        import importlib.util

        for mod in self.requires:
            if importlib.util.find_spec(mod) is None:
                return f"missing optional library {mod!r} (pip install 'pcreg[crosscheck]')"
        return None

    def settings(self, pinned: Pinned) -> dict:
        """The settings this implementation pins (recorded in the report)."""
        return {}

    def run(self, pinned: Pinned, *, trace: bool = False) -> RegistrationResult:
        """This implementation's result on ``pinned``: its ``T_target_source`` (finite, of the clouds' dimension,
        neither a mirror image nor a collapse, else an :class:`ImplementationError`). On clouds that leave the rigid
        transform free (:func:`unconstrained`: too few, coincident or, in 3-D,
        collinear points) pcreg's reference ICP refuses, as :func:`pcreg.icp` does; any other returns the pose its
        library finds, one of many that fit as well, marked: ``info["unconstrained"]`` says why and
        ``trusted`` is False."""
        if not isinstance(pinned, Pinned):
            raise InputError(f"pinned must be a pcreg.implementations.Pinned, got {type(pinned).__name__}")
        why = self.missing()
        if why:
            raise MissingLibrary(why)
        if pinned.dim not in self.dims:
            raise ImplementationError(f"{self.name} handles {' and '.join(f'{d}-D' for d in self.dims)} clouds only")
        start = time.perf_counter()
        out = self._run(pinned, trace=trace)
        seconds = time.perf_counter() - start
        m = np.asarray(out.matrix, dtype=np.float64)
        d = pinned.dim
        if m.shape == (4, 4) and d == 2:
            m = project(m)
        if m.shape != (d + 1, d + 1):
            raise ImplementationError(f"returned a {m.shape} matrix, expected {d + 1}x{d + 1}")
        if not np.all(np.isfinite(m)):
            raise ImplementationError("returned a matrix with NaN or inf")
        if d == 2:
            _check_in_plane(m, (out.info or {}).get("out_of_plane"))
        det = float(np.linalg.det(m[:d, :d]))
        if not det > 1e-12:  # pycpd's scale fell to 0 on coincident points
            raise ImplementationError(f"returned a transform whose linear block has determinant {det:.3g}: "
                                      f"{'a mirror image' if det < 0 else 'a collapse of the cloud'}, no rigid motion")
        info, problem = out.info or {}, pinned.undetermined
        return replace(out, matrix=m, seconds=out.seconds or seconds, backend=self.name, frames="T_target_source",
                       info=info if problem is None else {**info, "unconstrained": problem})

    def _run(self, pinned: Pinned, *, trace: bool) -> RegistrationResult:  # pragma: no cover - abstract
        raise NotImplementedError


def unconstrained(source: np.ndarray, target: np.ndarray, names: tuple[str, str] = ("source", "target")) -> str | None:
    """Why the clouds leave the rigid transform undetermined, or None: either cloud too few, coincident
    points, or (3-D) points on one line, about which any rotation fits as well. In the words of the
    reference ICP's refusal (:func:`~pcreg.registration.closed_forms.rank_problem`), the cloud named (``names``:
    the source's and the target's, their files where they came from files). Every
    other implementation's pose on such clouds is one of many, whatever its ``converged`` says:
    :meth:`Implementation.run` marks it (``info["unconstrained"]``), a cross-check's row ``"status":
    "unconstrained"``."""
    from ..registration.closed_forms import rank_problem

    for name, points in zip(names, (source, target)):
        problem = rank_problem(points, "rigid")
        if problem is not None:
            return f"{name}: {problem}"
    return None


# ---------------------------------------------------------------------------------------------------
# Helpers shared by adapters
# ---------------------------------------------------------------------------------------------------

def _number(value: float | None) -> float:
    return float("nan") if value is None else float(value)


def result(name: str, matrix, *, iterations: int | None = None, fitness: float | None = None,
           inlier_rmse: float | None = None, converged: bool | None = None, seconds: float = 0.0,
           trace=(), info: dict | None = None) -> RegistrationResult:
    """An implementation's result: ``matrix`` is ``T_target_source``; what it does not report (None here)
    is left as RegistrationResult marks it (NaN, -1, None), and :func:`reported` reads it back as None."""
    return RegistrationResult(matrix=matrix, fitness=_number(fitness), inlier_rmse=_number(inlier_rmse),
                              iterations=-1 if iterations is None else int(iterations), converged=converged,
                              backend=name, seconds=seconds, info=info or {}, frames="T_target_source",
                              trace=tuple(trace))


def step(name: str, iteration: int, matrix, fitness: float | None = None, inlier_rmse: float | None = None,
         target_indices=None) -> IcpIteration:
    """One step of an implementation's trace: the pose after ``iteration`` updates, without point arrays."""
    return IcpIteration(backend=name, level=0, iteration=int(iteration), matrix=np.array(matrix, dtype=np.float64),
                        fitness=_number(fitness), inlier_rmse=_number(inlier_rmse),
                        target_indices=None if target_indices is None else np.array(target_indices))


def reported(value):
    """A result's or a trace step's field as a report shows it: None where the implementation did not
    report it (a NaN number, -1 iterations)."""
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, (int, np.integer)):
        return None if value < 0 else int(value)
    return None if np.isnan(value) else float(value)


def lift(points: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) on z = 0; (N, 3) unchanged."""
    p = np.asarray(points, dtype=np.float64)
    return np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p


def lift_matrix(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, dtype=np.float64)
    if m.shape == (4, 4):
        return m.copy()
    out = np.eye(4)
    out[:2, :2] = m[:2, :2]
    out[:2, 3] = m[:2, 2]
    return out


def project(m: np.ndarray) -> np.ndarray:
    """4x4 acting on z = 0 -> 3x3 (its in-plane part; what leaves the plane is reported, not hidden)."""
    m = np.asarray(m, dtype=np.float64)
    out = np.eye(3)
    out[:2, :2] = m[:2, :2]
    out[:2, 2] = m[:2, 3]
    return out


#: How far (relative to the linear part) the 3-D result of a 2-D cloud lifted to z = 0 may leave that plane
#: before there is no 2-D transform to report (as :func:`~pcreg.registration.transforms.project_to_2d`).
PLANE_TOLERANCE = 1e-6


def _check_in_plane(m: np.ndarray, leaves: float | None) -> None:
    """An :class:`ImplementationError` when a 2-D result ``m`` comes from a 3-D result that left the plane z = 0
    (``leaves``, :func:`out_of_plane`; None: the implementation ran in 2-D) or mirrors the plane. A 3-D ICP on
    2-D clouds lifted to z = 0 is free to turn the plane over about a line the points lie along (Open3D's tensor
    ICP did, on 50 points on a line): its in-plane block is then a reflection, and reporting it as a 2-D
    transform would show a mirror image as that implementation's converged result (refused by :meth:`Implementation.run`,
    as any mirror image)."""
    if leaves is not None and leaves > PLANE_TOLERANCE * max(1.0, float(np.abs(m[:2, :2]).max())):
        raise ImplementationError(f"its 3-D result leaves the plane z = 0 of the lifted 2-D clouds (out-of-plane "
                                  f"part {leaves:.2g}): it turned the plane over, which no 2-D transform describes")


def out_of_plane(m: np.ndarray) -> float:
    """How far a 4x4 leaves the plane z = 0: the largest of its z-row and z-column entries off the identity."""
    m = np.asarray(m, dtype=np.float64)
    return float(max(np.abs(m[2, :2]).max(), np.abs(m[:2, 2]).max(), abs(m[2, 2] - 1.0), abs(m[2, 3])))


def nearest(target: np.ndarray, points: np.ndarray, max_distance: float):
    """Exact nearest target point of each point within ``max_distance``: (distances, indices, ok)."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(target).query(points, k=1, distance_upper_bound=max_distance)
    ok = np.isfinite(dist)
    return dist, np.where(ok, idx, -1), ok


def score(pinned: Pinned, matrix: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Open3D's fitness and inlier RMSE of ``matrix`` on the pinned clouds, and the correspondences."""
    from ..registration.transforms import apply

    dist, idx, ok = nearest(pinned.target, apply(matrix, pinned.source), pinned.max_correspondence_distance)
    k = int(ok.sum())
    if k == 0:
        return 0.0, 0.0, idx
    return k / len(ok), float(np.sqrt(np.mean(dist[ok] ** 2))), idx


def run_quietly(implementation: Implementation, pinned: Pinned) -> tuple[RegistrationResult | Exception, list[str]]:
    """``implementation.run(pinned, trace=True)``, its result or the exception it raised, and what it said meanwhile,
    kept off the terminal: the lines its library printed (small_gicp's and Open3D's warnings, from C++) and the
    Python warnings it raised (pycpd's and probreg's RuntimeWarnings on coincident points), each once."""
    import re
    import warnings

    from ..quiet import capture_output_fds

    with warnings.catch_warnings(record=True) as warned:
        warnings.simplefilter("always")
        with capture_output_fds() as printed:
            try:
                outcome: RegistrationResult | Exception = implementation.run(pinned, trace=True)
            except Exception as exc:  # noqa: BLE001 - the caller's row reports it
                outcome = exc
    lines = [line.strip() for line in re.sub(r"\x1b\[[0-9;]*m", "", "".join(printed)).splitlines() if line.strip()]
    lines += [f"{w.category.__name__}: {w.message}" for w in warned]
    return outcome, list(dict.fromkeys(line[:200] for line in lines))[:10]


@contextlib.contextmanager
def stdout_to_stderr():
    """Send everything written to file descriptor 1 (C++ libraries' prints included) to stderr."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):
        yield
        return
    try:
        os.dup2(2, 1)
        yield
    finally:
        try:
            sys.stdout.flush()
        except (OSError, ValueError):
            pass
        os.dup2(saved, 1)
        os.close(saved)


def unpack(result: Any) -> tuple[np.ndarray, float, float, int, bool]:
    """(matrix, fitness, inlier_rmse, iterations, converged) from a backend's tuple or RegistrationResult."""
    if isinstance(result, tuple):
        return result
    return (np.asarray(result.matrix), float(result.fitness), float(result.inlier_rmse), int(result.iterations),
            bool(result.converged))
