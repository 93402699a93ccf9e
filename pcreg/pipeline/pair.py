"""Registration-augmented classification of one pair of frames.

Per pair (a labelled *reference* frame i and a *moving* frame i + k)::

    register (clouds + ICP)  ->  T_ref_mov (3, 3)
    warp      moving image onto the reference grid (the thesis's "after")
    classify  naive Bayes log-odds of the moving frame (and of the warped image)
    fuse      reference labels -> smoothed prior -> warped into the moving frame -> + w * prior
    score     every method against ground truth, unknown left out

The methods (keys of :data:`METHODS`), each an error rate in percent:

- ``plain``: naive Bayes on the moving frame, scored against the moving frame's labels.
- ``thesis_before``: the same prediction scored against the *reference* frame's labels (the thesis's
  "before registration").
- ``thesis_after``: naive Bayes on the moving image warped into the reference frame, black border
  included, against the reference labels (the thesis's "after").
- ``thesis_after_masked``: as ``thesis_after``, but pixels outside the valid mask are classified from
  the unwarped moving frame (every pixel scored).
- ``thesis_after_cropped``: as ``thesis_after``, scored on the valid mask only (the border left out).
- ``augmented``: naive Bayes on the moving frame fused with the reference labels warped into it as a
  prior (:mod:`pcreg.classification.fusion`), against the moving labels.
- ``augmented_unregistered``: the same fusion with the prior not warped (identity): the ablation that
  shows what registration adds.
- ``augmented_flow``: the same fusion with the prior warped by OpenCV's DIS optical flow (medium
  preset, :mod:`pcreg.registration.flow`), its weight chosen the same way: the baseline a user would
  otherwise pick.
- ``augmented_temporal``: recursive fusion along the sequence: the fused posterior of frame t - k,
  warped, is the prior of frame t; labels are used only at the start of each chain (frames 0..k-1).
- ``propagated``: the warped reference labels alone where they are known, naive Bayes elsewhere
  (label propagation without the classifier; for reference).

A registration that fails (no edges, no overlap) is recorded with its reason; that pair then does
what a running system would do without a transform: ``thesis_after*`` use the unwarped frame and the
fused methods get no prior (they equal ``plain``), so every method is still scored on every pair.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..errors import InputError
from ..validation import check_bool, check_callable, check_float, check_frame, check_ints
from ..registration.config import RegisterConfig
from ..registration.dense import DENSE_GLOBAL_MODEL
from ..registration.motion import Motion
from ..registration.result import RegistrationResult
from ..classification.features import DEFAULT_FEATURES
from ..classification.fusion import FusionConfig, fuse, label_prior, labels_from_log_odds, prior_log_odds
from .prior import class_prior, pixel_weight, warp_prior, warped_prior_log_odds

if TYPE_CHECKING:  # for the annotation only
    from .temporal import TemporalFusion

__all__ = ["METHODS", "STAGES", "PIPELINE_REGISTRATION", "DENSE_GLOBAL_MODEL", "PipelineConfig", "log_odds", "checked_scores",
           "PairRegistration", "motion_of", "register_pair", "flow_field", "PairResult", "PairArrays",
           "ProcessedPair", "process_pair"]


METHODS: tuple[str, ...] = (
    "plain", "thesis_before", "thesis_after", "thesis_after_masked", "thesis_after_cropped",
    "augmented", "augmented_unregistered", "augmented_temporal", "propagated", "augmented_flow",
)
STAGES: tuple[str, ...] = ("register", "warp", "classify", "fuse", "flow")

#: The registration a pipeline runs unless told otherwise: a similarity (rotation, shift and the zoom of
#: forward motion; a rigid model leaves the zoom as a residual of several pixels at k = 10) from the
#: identity (pairs of a sequence are close; the global search sometimes locks onto a half-turn when
#: frames are far apart). Its plausibility test is off (``min_inlier_ratio=None``): the frames of one
#: sequence are related by construction, and a camera moving through a 3-D scene fails a global
#: model's 1 px inlier test by design (on CamVid clips sampled at 1 frame/s it refuses most pairs)
#: although the transform still carries labels usefully; the fusion weight, chosen on the first frames,
#: sets how much it is trusted, and every pair records its evidence (``inlier_ratio``). A
#: :class:`pcreg.Propagator` keeps the test on and falls back to plain naive Bayes on a refusal.
PIPELINE_REGISTRATION = RegisterConfig.of(model="similarity", init="identity", min_inlier_ratio=None)


@dataclass(frozen=True)
class PipelineConfig:
    """Options of the per-pair pipeline (written to config.json by the evaluations).

    registration : :class:`~pcreg.registration.config.RegisterConfig` (:data:`PIPELINE_REGISTRATION`);
        its ``model="dense"`` runs :func:`pcreg.register_dense`: the global step with
        :data:`DENSE_GLOBAL_MODEL` (the rest of the config as given, its plausibility test off: a
        street scene seen from a moving car fails a global model's test by design), refined by a
        dense field.
    features : naive Bayes features (:mod:`pcreg.classification.features`).
    fusion : :class:`pcreg.classification.fusion.FusionConfig`.
    """

    registration: RegisterConfig = PIPELINE_REGISTRATION
    features: tuple[str, ...] = DEFAULT_FEATURES
    fusion: FusionConfig = field(default_factory=FusionConfig)

    def __post_init__(self) -> None:
        if not isinstance(self.registration, RegisterConfig):
            raise InputError("registration must be a RegisterConfig")

    @property
    def backend(self) -> str:
        return self.registration.backend


# ---------------------------------------------------------------------------------------------------
# classifier log-odds
# ---------------------------------------------------------------------------------------------------

def checked_scores(classifier, shape: tuple[int, int], k: int | None, image) -> np.ndarray:
    """A classifier's scores of ``image`` (of ``shape``): its ``decision_function``'s (H, W) log-odds with two
    classes (``k`` None), its ``class_scores``' (H, W, k) log-probabilities with more, as float32; another
    classifier than pcreg's naive Bayes returning another shape, no number or NaN is an :class:`InputError`
    naming it (its labels were returned at the wrong size, or every pixel one class, unmarked)."""
    name = type(classifier).__name__
    method = "decision_function" if k is None else "class_scores"
    raw = getattr(classifier, method)(image)
    want = tuple(shape) if k is None else (*shape, k)
    try:
        d = np.asarray(raw, dtype=np.float32)
    except (TypeError, ValueError):
        raise InputError(f"the classifier {name}'s {method} returned {type(raw).__name__} that holds no numbers; "
                         f"it must return a {want} array") from None
    if d.shape != want:
        raise InputError(f"the classifier {name}'s {method} returned shape {d.shape} for a frame of "
                         f"{shape[1]}x{shape[0]}; it must return {want}")
    if not np.isfinite(d).all():
        raise InputError(f"the classifier {name}'s {method} returned NaN or inf at {int(np.count_nonzero(~np.isfinite(d)))} "
                         "of its scores; they must be finite")
    return d


def log_odds(classifier, image: np.ndarray) -> np.ndarray:
    """Naive Bayes log-odds ``log p(obstacle | x) - log p(ground | x)`` per pixel, (H, W) float32.

    classifier : a fitted ground/obstacle model with a ``decision_function`` (as
    :class:`~pcreg.classification.bayes.NaiveBayesPixelClassifier`); ``> 0`` gives ``predict``.
    """
    classes = list(np.asarray(getattr(classifier, "classes_", [])).tolist())
    if classes != [0, 1]:
        raise InputError(f"fusion needs a ground/obstacle classifier (classes [0, 1]), got {classes}")
    return np.asarray(classifier.decision_function(image), dtype=np.float32)


# ---------------------------------------------------------------------------------------------------
# one pair
# ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PairRegistration:
    """What :func:`register_pair` found: ``result`` (None when the registration was refused, with the
    one-line ``reason``) and the wall time in seconds."""

    result: RegistrationResult | None
    reason: str | None
    seconds: float

    @property
    def matrix(self) -> np.ndarray | None:
        """``T_ref_mov`` (3, 3), or None when refused."""
        return None if self.result is None else self.result.matrix

    @property
    def motion(self) -> Motion | None:
        """What warps the pair: a dense result's field with its confidence, else ``matrix`` (None when refused)."""
        return motion_of(self.result)


def motion_of(res) -> Motion | None:
    """A registration result's :class:`~pcreg.registration.motion.Motion` (None: no result)."""
    return None if res is None else Motion.of(res)


def register_pair(reference_image: np.ndarray, moving_image: np.ndarray, *, config: PipelineConfig = PipelineConfig(),
                  callback: Callable | None = None) -> PairRegistration:
    """The pair's motion by its configured registration (:func:`~pcreg.pipeline.estimators.pair_estimator`:
    :func:`pcreg.register`, or a dense field from scratch); a :class:`~pcreg.errors.RegistrationError` (or
    a degenerate transform) becomes a :class:`PairRegistration` with ``result=None`` and its reason."""
    from .estimators import pair_estimator

    t0 = time.perf_counter()
    est = pair_estimator(config.registration, callback=callback).estimate(reference_image, moving_image)
    return PairRegistration(est.result, est.reason, time.perf_counter() - t0)


def flow_field(reference_image: np.ndarray, moving_image: np.ndarray) -> np.ndarray:
    """The ``augmented_flow`` baseline's field: OpenCV DIS optical flow, medium preset."""
    from ..registration.flow import dis_field

    return dis_field(reference_image, moving_image, preset="medium")[0]


def _err(pred: np.ndarray, truth: np.ndarray | None, mask: np.ndarray | None = None) -> float:
    from ..classification.metrics import error_rate

    if truth is None:
        return float("nan")
    return error_rate(pred, truth, mask=mask)


@dataclass(frozen=True)
class PairResult:
    """One scored pair.

    reference, moving : frame indices in the sequence; names : (reference name, moving name).
    registered : the registration succeeded; reason : why not (None when it did).
    registration : ``RegistrationResult.to_dict()`` or None. corner_error : largest corner distance
        (px) from the ground-truth transform, where poses are known (synthetic data), else None.
    errors : {method: error %} for :data:`METHODS`. times : {stage: seconds} for :data:`STAGES`.
    valid_fraction : share of the reference grid covered by the warped moving image.
    """

    reference: int
    moving: int
    names: tuple[str, str]
    registered: bool
    reason: str | None
    registration: dict | None
    corner_error: float | None
    errors: dict
    times: dict
    valid_fraction: float

    def to_dict(self) -> dict:
        return {"reference": self.reference, "moving": self.moving, "names": list(self.names),
                "registered": self.registered, "reason": self.reason, "registration": self.registration,
                "corner_error": self.corner_error, "errors": dict(self.errors), "times": dict(self.times),
                "valid_fraction": self.valid_fraction}


@dataclass(frozen=True)
class PairArrays:
    """The arrays of one processed pair that a recording or a figure shows.

    warped : the moving image warped onto the reference grid (H, W, 3) uint8; valid : (H, W) bool, where
    it came from inside the moving image; predicted : {method: (H, W) uint8 labels} of the moving frame;
    thesis_after, thesis_after_masked : labels on the reference grid.
    motion : the registration's :class:`~pcreg.registration.motion.Motion` (a 3x3 matrix, or a dense field
    with its confidence; None when refused); warped_prior : (H, W) float32 obstacle probability of the
    reference labels warped into the moving frame; flow : the DIS field (H, W, 2) of ``augmented_flow``.
    """

    warped: np.ndarray
    valid: np.ndarray
    predicted: dict
    thesis_after: np.ndarray
    thesis_after_masked: np.ndarray
    motion: Motion | None = None
    warped_prior: np.ndarray | None = None
    flow: np.ndarray | None = None


@dataclass(frozen=True)
class ProcessedPair:
    """:func:`process_pair`'s outcome: the scores (``result``) and, when asked for, the arrays."""

    result: "PairResult"
    arrays: PairArrays | None = None


def _check_pair_args(reference, moving, classifier, *, weight, config, registration, temporal, indices,
                     keep_arrays, callback, flow, flow_weight) -> None:
    """An :class:`InputError` naming the first argument of :func:`process_pair` of the wrong type or value."""
    from .temporal import TemporalFusion

    check_frame(reference, "reference", labelled=True)
    check_frame(moving, "moving", labelled=True)
    if not hasattr(classifier, "class_prior_"):
        raise InputError(f"classifier must be a fitted NaiveBayesPixelClassifier, got {type(classifier).__name__}")
    check_float(weight, "weight", lo=0)
    if not isinstance(config, PipelineConfig):
        raise InputError(f"config must be a PipelineConfig, got {type(config).__name__}")
    if registration is not None and not isinstance(registration, PairRegistration):
        raise InputError(f"registration must be a PairRegistration or None, got {type(registration).__name__}")
    if temporal is not None and not isinstance(temporal, TemporalFusion):
        raise InputError(f"temporal must be a TemporalFusion or None, got {type(temporal).__name__}")
    if len(check_ints(indices, "indices", lo=0) or ()) != 2:
        raise InputError(f"indices must be two frame numbers, got {indices!r}")
    check_bool(keep_arrays, "keep_arrays")
    check_callable(callback, "callback")
    if flow is not None and (not isinstance(flow, np.ndarray) or flow.shape != (*moving.image.shape[:2], 2)):
        raise InputError(f"flow must be an (H, W, 2) array of the moving frame's size or None, "
                         f"got {getattr(flow, 'shape', type(flow).__name__)}")
    if flow_weight is not None:
        check_float(flow_weight, "flow_weight", lo=0)


def _warp_moving(moving, motion, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The moving image on the reference grid and where it is valid (itself, all valid, unregistered)."""
    from ..registration.warp import warp

    if motion is None:
        return moving.image, np.ones(shape, dtype=bool)
    return warp(moving.image, motion, shape=shape)


@dataclass(frozen=True)
class _Fused:
    """The fusing methods' log-odds on the moving frame (``temporal`` None without a chain), the
    registered prior and the DIS field a recording shows, and the seconds of the two timed stages."""

    registered: np.ndarray
    unregistered: np.ndarray
    temporal: np.ndarray | None
    flow: np.ndarray
    warped_prior: np.ndarray | None
    flow_field: np.ndarray
    fuse_seconds: float
    flow_seconds: float


def _fuse_methods(reference, moving, d_mov: np.ndarray, motion, *, pi: float, fusion: FusionConfig, weight: float,
                  flow_weight: float, temporal, flow: np.ndarray | None) -> _Fused:
    """The reference labels' prior fused with the moving frame's log-odds ``d_mov``: carried by the
    registration's ``motion`` (None: no prior), by no motion, by the temporal chain, and by DIS flow."""
    shape = d_mov.shape
    t0 = time.perf_counter()
    q_ref = label_prior(reference.labels, pi=pi, fusion=fusion)
    q_mov = None
    if motion is not None:
        q_mov, _ = warp_prior(q_ref, motion, shape=shape, pi=pi)
        l_reg = prior_log_odds(q_mov, pi=pi)
    else:
        l_reg = np.zeros(shape, np.float32)
    # a dense field's prior is weighted per pixel by its confidence and by how well the reference carried
    # along it matches the moving frame (the stream's trust, pcreg.pipeline.trust.residual_trust)
    trust = None
    if motion is not None and motion.field is not None:
        from .trust import residual_trust

        trust = residual_trust(reference.image, moving.image, motion.field)
    w_reg = weight if motion is None else pixel_weight(weight, motion.confidence)
    fused = fuse(d_mov, l_reg, weight=w_reg if trust is None else (np.float32(w_reg) * trust).astype(np.float32))
    fuse_seconds = time.perf_counter() - t0
    fused_id = fuse(d_mov, prior_log_odds(q_ref, pi=pi), weight=weight)
    fused_t = None if temporal is None else temporal.step(d_mov, motion, pi=pi, trust=trust)
    t0 = time.perf_counter()
    flow = flow_field(reference.image, moving.image) if flow is None else flow
    fused_flow = fuse(d_mov, warped_prior_log_odds(q_ref, flow, shape=shape, pi=pi), weight=flow_weight)
    return _Fused(fused, fused_id, fused_t, fused_flow, q_mov, flow, fuse_seconds, time.perf_counter() - t0)


def _propagated(reference, motion, pred_mov: np.ndarray) -> np.ndarray:
    """The reference's known labels carried to the moving frame by ``motion``, naive Bayes elsewhere."""
    from ..registration.warp import warp_to_moving

    if motion is None:
        return pred_mov
    ref_lab_mov, lab_valid = warp_to_moving(reference.labels, motion, shape=pred_mov.shape,
                                            interpolation="nearest", fill=2)
    return np.where(lab_valid & (ref_lab_mov < 2), ref_lab_mov, pred_mov)


def _errors(preds: dict, *, reference, moving, pred_warped: np.ndarray, pred_masked: np.ndarray,
            valid: np.ndarray) -> dict:
    """{method: error %}: the moving frame's predictions against its labels, the thesis's methods
    (on the reference grid) against the reference's."""
    temporal = preds.get("augmented_temporal")
    return {
        "plain": _err(preds["plain"], moving.labels),
        "thesis_before": _err(preds["plain"], reference.labels),
        "thesis_after": _err(pred_warped, reference.labels),
        "thesis_after_masked": _err(pred_masked, reference.labels),
        "thesis_after_cropped": _err(pred_warped, reference.labels, valid),
        "augmented": _err(preds["augmented"], moving.labels),
        "augmented_unregistered": _err(preds["augmented_unregistered"], moving.labels),
        "augmented_temporal": _err(temporal, moving.labels) if temporal is not None else float("nan"),
        "propagated": _err(preds["propagated"], moving.labels),
        "augmented_flow": _err(preds["augmented_flow"], moving.labels),
    }


def _corner_error(reference, moving, T: np.ndarray | None) -> float | None:
    """The registration's largest corner distance from the true transform, where poses are known."""
    from ..datasets import relative_transform
    from ..registration.transforms import max_corner_error

    truth_T = relative_transform(reference, moving)
    if truth_T is None or T is None:
        return None
    return max_corner_error(T, truth_T, moving.shape)


def process_pair(reference, moving, classifier, *, weight: float, config: PipelineConfig = PipelineConfig(),
                 registration: PairRegistration | None = None, temporal: TemporalFusion | None = None,
                 indices: tuple[int, int] = (0, 1), keep_arrays: bool = False,
                 callback: Callable | None = None, flow: np.ndarray | None = None,
                 flow_weight: float | None = None) -> ProcessedPair:
    """Run and score every method on one pair.

    reference, moving : :class:`~pcreg.datasets.Frame` (labelled; same size). classifier : fitted naive
    Bayes (ground/obstacle). weight : fusion weight.
    registration : a precomputed :func:`register_pair`, or None to register here.
    temporal : the temporal filter of the chain that holds the reference frame; it is stepped to the
        moving frame (:meth:`TemporalFusion.step`). None leaves ``augmented_temporal`` NaN.
    keep_arrays : also return the arrays a recording shows (:class:`PairArrays`).
    flow : the pair's DIS field (:func:`flow_field`; None: computed here). flow_weight : the fusion
        weight of ``augmented_flow`` (default ``weight``).
    """
    _check_pair_args(reference, moving, classifier, weight=weight, config=config, registration=registration,
                     temporal=temporal, indices=indices, keep_arrays=keep_arrays, callback=callback, flow=flow,
                     flow_weight=flow_weight)
    if reference.shape != moving.shape:
        raise InputError(f"reference {reference.shape} and moving {moving.shape} frames differ in size")
    times = dict.fromkeys(STAGES, 0.0)
    reg = registration if registration is not None else register_pair(
        reference.image, moving.image, config=config, callback=callback)
    res = reg.result
    times["register"] = reg.seconds
    T = None if res is None else np.asarray(res.matrix)
    motion = reg.motion  # a dense registration's field (and confidence), else T; None when refused

    t0 = time.perf_counter()
    warped, valid = _warp_moving(moving, motion, reference.shape)
    times["warp"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    d_mov = log_odds(classifier, moving.image)
    d_warped = log_odds(classifier, warped) if motion is not None else d_mov
    times["classify"] = time.perf_counter() - t0
    pred_mov = labels_from_log_odds(d_mov)
    pred_warped = labels_from_log_odds(d_warped)
    fused = _fuse_methods(reference, moving, d_mov, motion, pi=class_prior(classifier), fusion=config.fusion,
                          weight=weight, flow_weight=weight if flow_weight is None else flow_weight,
                          temporal=temporal, flow=flow)
    times["fuse"], times["flow"] = fused.fuse_seconds, fused.flow_seconds

    pred_masked = np.where(valid, pred_warped, pred_mov)
    preds = {
        "plain": pred_mov, "augmented": labels_from_log_odds(fused.registered),
        "augmented_unregistered": labels_from_log_odds(fused.unregistered),
        "propagated": _propagated(reference, motion, pred_mov), "augmented_flow": labels_from_log_odds(fused.flow),
    }
    if fused.temporal is not None:
        preds["augmented_temporal"] = labels_from_log_odds(fused.temporal)
    errors = _errors(preds, reference=reference, moving=moving, pred_warped=pred_warped, pred_masked=pred_masked,
                     valid=valid)
    result = PairResult(reference=int(indices[0]), moving=int(indices[1]), names=(reference.name, moving.name),
                        registered=T is not None, reason=reg.reason, registration=None if res is None else res.to_dict(),
                        corner_error=_corner_error(reference, moving, T), errors=errors, times=times,
                        valid_fraction=float(valid.mean()))
    arrays = PairArrays(warped=warped, valid=valid, predicted=preds, thesis_after=pred_warped,
                        thesis_after_masked=pred_masked, motion=motion, warped_prior=fused.warped_prior,
                        flow=fused.flow_field) if keep_arrays else None
    return ProcessedPair(result, arrays)
