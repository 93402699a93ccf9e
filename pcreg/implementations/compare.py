"""Comparing the implementations of a cross-check: the tolerances each comparability is held to, the
disagreement of two poses, where two runs' iterations part, and one implementation's row of the report.

Pure functions of results and clouds (:mod:`pcreg.implementations.crosscheck` runs the implementations).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..outputs import finite
from ..registration.result import RegistrationResult
from ..registration.transforms import apply, rotation_part
from .base import reported

STEP_TOLERANCE = 1e-9  # relative, on the poses about the source's centroid, against the reference run with the same settings
FIXED_POINT_TOLERANCE = 1e-6  # relative, as STEP_TOLERANCE, against the reference run to convergence
OBJECTIVE_ROTATION_DEG = 0.5  # objective rows: rotation within 0.5 degrees ...
OBJECTIVE_TRANSLATION = 0.005  # ... and the source's centroid within 0.5% of the target's bounding-box diagonal
OBJECTIVE_SCALE = 0.005  # ... and the cloud's size within 0.5% (pycpd's "rigid" model fits a scale too)
REFERENCE = "reference"


def relative_difference(A: np.ndarray, B: np.ndarray, length: float = 1.0, centre: np.ndarray | None = None) -> float:
    """The largest entry of ``A - B`` against the largest of ``A`` (at least 1): how far two poses differ, their
    translations measured in ``length`` (the clouds' extent: a cross-check's rows give the target's bounding-box
    diagonal), so that the same poses of the same clouds differ as much in any unit. In the clouds' own units a
    translation 0.3% of the extent off was 4e-7 for clouds 1.7e-4 across (within the fixed-point tolerance: an
    ICP that never moved agreed) and 0.004 for the same clouds 1.7 across. With ``centre`` (the source's centroid)
    the poses are compared about it, their translations where they put it: far from the origin a rotation's
    rounding moves the matrices' translations by itself times the distance (3.4e-6 extents for clouds 1e6 away,
    2.5 across, that both poses put within 4e-10 of the truth), not the cloud."""
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    if centre is not None:
        d = A.shape[0] - 1
        C = np.eye(d + 1)
        C[:d, d] = np.ravel(centre)
        Ci = np.eye(d + 1)
        Ci[:d, d] = -np.ravel(centre)
        A, B = Ci @ A @ C, Ci @ B @ C
    if length != 1.0:
        d = A.shape[0] - 1
        unit = np.ones_like(A)
        unit[:d, d] = 1.0 / length
        A, B = A * unit, B * unit
    return float(np.max(np.abs(A - B)) / max(1.0, float(np.max(np.abs(A)))))


def _length(diag: float) -> float:
    """The length translations are measured in: the target's diagonal, 1 for a target without extent."""
    return float(diag) if diag > 0 and np.isfinite(diag) else 1.0


def _bbox_corners(points: np.ndarray) -> np.ndarray:
    lo, hi = points.min(axis=0), points.max(axis=0)
    return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


def compare_matrices(A: np.ndarray, B: np.ndarray, source: np.ndarray, *, length: float = 1.0) -> dict:
    """Disagreement of B with A: rotation (degrees), translation (of the matrices), relative matrix difference
    (translations in ``length``, :func:`relative_difference`),
    the distance between where the two put the source's centroid and, in 2-D, the largest displacement of the
    source's bounding-box corners (px for image edge clouds).

    The matrices' translations differ by the rotations' difference times the distance of the clouds from the
    origin as well (2,468 units for a tenth of a degree, clouds 1e6 away): the centroid's displacement is the
    translation measured where the clouds are, the same wherever they lie, which an ``objective`` row is judged
    by (:data:`OBJECTIVE_TRANSLATION`). ``scale_disagreement``, the largest relative difference of the linear blocks'
    singular values, is how much B grows or shrinks the cloud against A (0 between rigid motions; pycpd's
    "rigid" model fits a scale), which an ``objective`` row is judged by too (:data:`OBJECTIVE_SCALE`): the
    rotation and the centroid see no scale."""
    d = A.shape[0] - 1
    RA, RB = rotation_part(A[:d, :d]), rotation_part(B[:d, :d])
    # The angle of RA^T RB from its chord, ||RA - RB||_F = 2 sqrt(2) sin(angle / 2) in 2-D as in 3-D (in 2-D
    # both columns move by 2 sin(angle / 2)): unlike the arccos of the trace it keeps full precision for tiny angles.
    chord = float(np.linalg.norm(RA - RB)) / (2.0 * np.sqrt(2.0))
    centre = np.asarray(source, dtype=np.float64).mean(axis=0, keepdims=True)
    out = {"rotation_disagreement_deg": float(np.degrees(2.0 * np.arcsin(min(1.0, chord)))),
           "translation_disagreement": float(np.linalg.norm(A[:d, d] - B[:d, d])),
           "centroid_disagreement": float(np.linalg.norm(apply(A, centre) - apply(B, centre))),
           "matrix_relative_disagreement": relative_difference(A, B, length),
           "pose_relative_disagreement": relative_difference(A, B, length, centre),
           "scale_disagreement": _scale_difference(A[:d, :d], B[:d, :d])}
    if d == 2:
        c = _bbox_corners(source)
        out["corner_disagreement"] = float(np.max(np.linalg.norm(apply(A, c) - apply(B, c), axis=1)))
    return out


def _scale_difference(LA: np.ndarray, LB: np.ndarray) -> float:
    """The largest ``|sigma_B / sigma_A - 1|`` over the linear blocks' singular values, each sorted."""
    sa, sb = np.linalg.svd(LA, compute_uv=False), np.linalg.svd(LB, compute_uv=False)
    return float(np.max(np.abs(sb / sa - 1.0))) if np.all(sa > 0) else float("inf")


def trace_divergence(ref_trace, trace, *, tolerance: float = STEP_TOLERANCE, source: np.ndarray | None = None,
                     target: np.ndarray | None = None, length: float = 1.0) -> dict | None:
    """First iteration at which ``trace`` leaves ``ref_trace`` and the likely cause; None when they agree.

    The pose after iteration k comes from the correspondences at the pose after k-1: when poses k-1
    agree and poses k do not, the correspondences at k-1 decide the cause (different ones: the
    neighbour search or gate; the same ones, or exact nearest neighbours of agreeing poses: the step).
    Given the pinned ``source`` and ``target``, a different step from pairs that leave the rotation
    undetermined (:func:`~pcreg.registration.closed_forms.rotation_problem`) says so: each implementation
    takes one of the rotations that fit them as well. Poses are compared with translations in ``length``
    (:func:`relative_difference`).
    """
    n = min(len(ref_trace), len(trace))
    if n == 0:
        return None
    centre = None if source is None else np.asarray(source, dtype=np.float64).mean(axis=0)
    for k in range(n):
        a, b = ref_trace[k], trace[k]
        if relative_difference(a.matrix, b.matrix, length, centre) > tolerance:
            if k == 0:
                return {"iteration": 0, "cause": "different initial pose"}
            pa, pb = ref_trace[k - 1], trace[k - 1]
            if pb.target_indices is not None and pa.target_indices is not None and \
                    not np.array_equal(pa.target_indices, pb.target_indices):
                diff = int(np.count_nonzero(pa.target_indices != pb.target_indices))
                return {"iteration": k, "cause": f"different correspondences at iteration {k - 1} "
                                                 f"({diff} source points matched differently)"}
            known = pb.target_indices is not None
            free = _free_rotation(pa, source, target)
            return {"iteration": k, "cause": "different step from the same correspondences"
                    + ("" if known else " (the poses before agree, so exact nearest neighbours are the same)")
                    + ("" if free is None else f", which leave the rotation undetermined ({free})")
                    + f": relative pose difference {relative_difference(a.matrix, b.matrix, length, centre):.1e}"}
        if b.target_indices is not None and a.target_indices is not None and \
                not np.array_equal(a.target_indices, b.target_indices):
            diff = int(np.count_nonzero(a.target_indices != b.target_indices))
            return {"iteration": k, "cause": f"different correspondences at the same pose ({diff} source points; "
                                             "ties or another neighbour search)"}
    if len(ref_trace) != len(trace):
        return {"iteration": n, "cause": f"different stopping rule: the same poses, but {len(trace) - 1} iterations "
                                         f"against the reference's {len(ref_trace) - 1}"}
    return None


def _free_rotation(at, source: np.ndarray | None, target: np.ndarray | None) -> str | None:
    """Why the pairs of the trace step ``at`` (its pose and target indices) leave the rotation undetermined, or None
    (also when the clouds or the indices are not known)."""
    if source is None or target is None or at.target_indices is None:
        return None
    from ..registration.closed_forms import rotation_problem

    ok = np.asarray(at.target_indices) >= 0
    return rotation_problem(apply(at.matrix, source)[ok], target[np.asarray(at.target_indices)[ok]])


@dataclass(frozen=True)
class CloudCrosscheck:
    """Every requested implementation on the same pinned clouds; ``rows`` keyed by name or spec string."""

    rows: dict
    settings: dict
    reference_at_convergence: dict | None
    traces: dict = field(default_factory=dict, compare=False, repr=False)
    source: np.ndarray | None = field(default=None, compare=False, repr=False)
    target: np.ndarray | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers become None, so the JSON stays valid)."""
        return finite({"kind": "clouds", "implementations": self.rows, "settings": self.settings,
                "reference_at_convergence": self.reference_at_convergence,
                "tolerances": {"step": f"relative pose difference about the source's centroid "
                                       f"(pose_relative_disagreement; translations in target diagonals) <= "
                                       f"{STEP_TOLERANCE:g} against the reference (far from the origin, 100 float64 "
                                       "roundings of the largest coordinate / extent)",
                               "fixed-point": f"relative pose difference about the source's centroid (as step) <= "
                                              f"{FIXED_POINT_TOLERANCE:g} against the reference run to convergence (far "
                                              "from the origin, at least the step's)",
                               "objective": f"rotation <= {OBJECTIVE_ROTATION_DEG:g} deg and the source's centroid "
                                            f"(centroid_disagreement) <= {OBJECTIVE_TRANSLATION:.1%} of the target's "
                                            f"bounding-box diagonal and the scale (scale_disagreement) <= "
                                            f"{OBJECTIVE_SCALE:.1%} against the reference run to convergence"}})




def step_tolerance(points: np.ndarray, diag: float) -> float:
    """The ``step`` tolerance of clouds ``points`` ``diag`` across: :data:`STEP_TOLERANCE`, or far from the origin
    100 float64 roundings of their largest coordinate over their extent (the rotation solved from such
    coordinates), on the poses compared about the source's centroid (``pose_relative_disagreement``)."""
    far = float(np.max(np.abs(points))) / diag if diag > 0 else 0.0
    return max(STEP_TOLERANCE, 100.0 * float(np.finfo(np.float64).eps) * far)


def _agrees(comparability: str, cmp: dict, diag: float, step: float = STEP_TOLERANCE) -> bool:
    """Whether a row's comparison ``cmp`` with its reference agrees, by its ``comparability``. The ``step`` allowance
    of clouds far from the origin (:func:`step_tolerance`) grows without bound as the clouds' extent shrinks against
    their coordinates (0.65 relative for clouds 1e-7 across, 1e7 away, where a row that never moved read "agrees",
    31 degrees off): a step or fixed-point row agrees no further apart than an objective row may."""
    if comparability in ("step", "fixed-point") and step > FIXED_POINT_TOLERANCE and not _objectively_close(cmp, diag):
        return False
    if comparability == "step":
        return cmp["pose_relative_disagreement"] <= step
    if comparability == "fixed-point":
        return cmp["pose_relative_disagreement"] <= max(FIXED_POINT_TOLERANCE, step)
    return _objectively_close(cmp, diag)


def _objectively_close(cmp: dict, diag: float) -> bool:
    return (cmp["rotation_disagreement_deg"] <= OBJECTIVE_ROTATION_DEG
            and cmp["centroid_disagreement"] <= OBJECTIVE_TRANSLATION * diag
            and cmp["scale_disagreement"] <= OBJECTIVE_SCALE)


#: A row that disagrees is said to fit the clouds better than the pose it is compared with (``better_fit``) when its
#: RMS distance capped at the gate (:func:`capped_rms`) is lower by more than a tenth.
BETTER_FIT = 0.9


def capped_rms(matrix: np.ndarray, source: np.ndarray, target: np.ndarray, gate: float) -> float:
    """The RMS over every point of ``source`` moved by ``matrix`` of its distance to its nearest ``target`` point,
    capped at ``gate``: what point-to-point ICP lowers at every step, its correspondences and its steps alike
    (:func:`~pcreg.registration.reference.truncated_rms`)."""
    from ..registration.reference import scores_at, truncated_rms

    return truncated_rms(*scores_at(source, target, np.asarray(matrix, dtype=np.float64), gate), gate)


def _better_fit(o, base, base_name: str, src: np.ndarray, pinned) -> dict | None:
    """What a row that disagrees with ``base`` says when its pose fits the clouds better than the base's by ICP's own
    measure (:data:`BETTER_FIT`; its nearest rigid pose about the source's centroid, for a row that scales as well):
    the base's pose is not ICP's best there (a local minimum, or a run stopped early), and "no" does not make the
    row's pose the wrong one. None otherwise."""
    from ..registration.transforms import apply, nearest_rigid

    gate = float(pinned.max_correspondence_distance)
    theirs = capped_rms(base.matrix, src, pinned.target, gate)
    rigid, d, centre = nearest_rigid(o.matrix), src.shape[1], src.mean(axis=0)
    rigid[:d, d] = apply(np.asarray(o.matrix), centre[None])[0] - rigid[:d, :d] @ centre  # its scale dropped about
    ours = capped_rms(rigid, src, pinned.target, gate)  # the source's centroid, not the origin (1e3 away: the gate)
    if not ours < BETTER_FIT * theirs:
        return None
    return {"capped_rms": ours, "compared_with_capped_rms": theirs, "compared_with": base_name}


def implementation_row(name: str, o, a, errors: dict, pinned, *, ref, conv, src: np.ndarray, diag: float,
                       truth, problem: str | None = None) -> dict:
    """One implementation's row: its outcome, compared with the reference (step for step, or at
    convergence) and with ``truth``; on clouds that leave the transform free (``problem``,
    :func:`~pcreg.implementations.base.unconstrained`) a pose is marked so, never agreeing."""
    comp = a.comparability if a is not None else "step"
    row = {"matrix": None, "iterations": None, "fitness": None, "inlier_rmse": None, "converged": None,
           "seconds": 0.0, "comparability": comp, "rotation_disagreement_deg": None,
           "translation_disagreement": None, "matrix_relative_disagreement": None, "pose_relative_disagreement": None, "agrees": False,
           "error": errors.get(name), "status": "missing" if o == "missing" else ("failed" if name in errors else "ok"),
           "compared_with": None, "divergence": None, "trace": False,
           "description": getattr(a, "description", ""), "settings": None, "unconstrained": None, "better_fit": None}
    if a is not None:
        try:
            row["settings"] = a.settings(pinned)
        except Exception:  # noqa: BLE001 - settings are informative only
            row["settings"] = None
    if not isinstance(o, RegistrationResult):
        return row
    row.update({"matrix": o.matrix.tolist(), "iterations": reported(o.iterations), "fitness": reported(o.fitness),
                "inlier_rmse": reported(o.inlier_rmse), "converged": o.converged, "seconds": float(o.seconds),
                "trace": bool(o.trace)})
    if o.info:
        row["info"] = o.info
    if problem is not None:  # one pose of many that fit as well: marked, compared with nothing
        row.update(status="unconstrained", unconstrained=problem, agrees=False,
                   info={**(o.info or {}), "unconstrained": problem})
    base, base_name = (ref, "reference") if comp == "step" else (conv, "reference at convergence")
    if name == REFERENCE:
        base, base_name = o, "reference"
    if base is not None:
        cmp = compare_matrices(base.matrix, o.matrix, src, length=_length(diag))
        row.update(cmp)
        row["compared_with"] = base_name
        step = step_tolerance(src, diag)
        row["agrees"] = problem is None and bool(_agrees(comp, cmp, diag, step))
        if problem is None and not row["agrees"] and name != REFERENCE:
            row["better_fit"] = _better_fit(o, base, base_name, src, pinned)
        if ref is not None and name != REFERENCE and o.trace and ref.trace:
            row["divergence"] = trace_divergence(ref.trace, o.trace, tolerance=step, source=src,
                                                 target=pinned.target, length=_length(diag))
    elif name != REFERENCE:
        row["error"] = row["error"] or None
        row["compared_with"] = None
    if truth is not None:
        t = compare_matrices(np.asarray(truth, dtype=np.float64), o.matrix, src)
        row["truth_rotation_deg"] = t["rotation_disagreement_deg"]
        row["truth_translation"] = t["translation_disagreement"]
    return row
