"""Registration-augmented classification: one pair, and a sequence walked with increment k.

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

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .errors import InputError, RegistrationError
from .classification.bayes import fit_classifier
from .registration.config import RegisterConfig
from .registration.result import RegistrationResult
from .classification.fusion import (FusionConfig, WeightChoice, choose_weight, fuse, labels_from_log_odds, prior_from_labels,
                     prior_from_log_odds, prior_log_odds, smooth_prior, warp_prior)

__all__ = [
    "METHODS",
    "PIPELINE_REGISTRATION",
    "PipelineConfig",
    "STAGES",
    "log_odds",
    "register_pair",
    "PairRegistration",
    "PairArrays",
    "ProcessedPair",
    "PairResult",
    "process_pair",
    "temporal_update",
    "TemporalFusion",
    "SequenceResult",
    "run_sequence",
    "pair_indices",
    "resolve_fusion_frames",
]

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
PIPELINE_REGISTRATION = RegisterConfig(model="similarity", init="identity", min_inlier_ratio=None)
#: The global step of ``model="dense"``.
DENSE_GLOBAL_MODEL = "similarity"


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
    features: tuple[str, ...] = ("rgb", "hsv", "row")
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
    def motion(self) -> np.ndarray | None:
        """What warps the pair: a dense result's field (H, W, 2), else ``matrix``."""
        return motion_of(self.result)


def motion_of(res) -> np.ndarray | None:
    """The dense field of a dense result, else the 3x3 matrix (None: no result)."""
    if res is None:
        return None
    fld = getattr(res, "field", None)
    return np.asarray(fld) if fld is not None else np.asarray(res.matrix)


def register_pair(reference_image: np.ndarray, moving_image: np.ndarray, *, config: PipelineConfig = PipelineConfig(),
                  callback: Callable | None = None) -> PairRegistration:
    """:func:`pcreg.register` with the configured options; a :class:`~pcreg.errors.RegistrationError`
    (or a degenerate transform) becomes a :class:`PairRegistration` with ``result=None`` and its reason."""
    from .registration.api import register

    t0 = time.perf_counter()
    try:
        if config.registration.model == "dense":
            from .registration.dense import register_dense

            # the global step is the dense step's start, not its answer: a 3-D scene fails a global
            # model's plausibility test by design, so the test is the dense step's own (on its field)
            start = config.registration.replace(model=DENSE_GLOBAL_MODEL, min_inlier_ratio=None)
            glob = register(reference_image, moving_image, **start.kwargs(), callback=callback)
            res = register_dense(reference_image, moving_image, global_result=glob,
                                 backend=config.registration.backend, seed=config.registration.seed)
        else:
            res = register(reference_image, moving_image, **config.registration.kwargs(), callback=callback)
    except RegistrationError as exc:
        return PairRegistration(None, str(exc), time.perf_counter() - t0)
    if not np.all(np.isfinite(res.matrix)) or abs(np.linalg.det(res.matrix[:2, :2])) < 1e-6:
        return PairRegistration(None, "registration returned a degenerate transform", time.perf_counter() - t0)
    return PairRegistration(res, None, time.perf_counter() - t0)


def flow_field(reference_image: np.ndarray, moving_image: np.ndarray) -> np.ndarray:
    """The ``augmented_flow`` baseline's field: OpenCV DIS optical flow, medium preset."""
    from .registration.flow import dis_field

    return dis_field(reference_image, moving_image, preset="medium")[0]


def _err(pred: np.ndarray, truth: np.ndarray | None, mask: np.ndarray | None = None) -> float:
    from .classification.metrics import error_rate

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


def _prior_q(source: np.ndarray, *, kind: str, pi: float, fusion: FusionConfig) -> np.ndarray:
    """Smoothed prior (H, W) float32 from labels (blurred by ``fusion.sigma``) or from a fused
    posterior's log-odds (not blurred)."""
    if kind == "labels":
        return smooth_prior(prior_from_labels(source, pi=pi), pi=pi, eps=fusion.eps, sigma=fusion.sigma)
    return smooth_prior(prior_from_log_odds(source), pi=pi, eps=fusion.eps, sigma=0.0)


def registration_supported(warped_labels: np.ndarray, labels: np.ndarray, log_odds_moving: np.ndarray) -> bool:
    """The new frame's own evidence for a registration that carries labels: the labels warped by it
    agree with naive Bayes on the new frame at least as often as the same labels not warped at all.

    warped_labels : (H, W) uint8 labels moved into the new frame (2 where none arrived); labels :
    (H, W) uint8 the same labels in the previous frame; log_odds_moving : (H, W) naive Bayes log-odds of
    the new frame. A wrong registration (a shifted or turned field) moves the labels off the objects
    and loses this test against the no-motion hypothesis; a right one wins or ties it.
    """
    nb = np.asarray(log_odds_moving) > 0
    w_known = warped_labels < 2
    i_known = labels < 2
    if not w_known.any():
        return False
    if not i_known.any():
        return True
    agree_w = float(np.mean((warped_labels[w_known] == 1) == nb[w_known]))
    agree_i = float(np.mean((labels[i_known] == 1) == nb[i_known]))
    return agree_w >= agree_i


def temporal_update(log_odds_moving: np.ndarray, labels_reference: np.ndarray, T_ref_mov: np.ndarray | None, *,
                    pi: float, weight: float, fusion: FusionConfig = FusionConfig()) -> tuple[np.ndarray, np.ndarray]:
    """One step of the temporal filter.

    log_odds_moving : (H, W) float32 naive Bayes log-odds of the new frame. labels_reference : (H, W)
    uint8 labels the chain holds for the previous frame (true labels at the chain's start, then its
    own fused labels; 2 where it knows nothing). T_ref_mov : previous -> new registration, a 3x3 matrix
    or a dense field (None: no prior). Returns ``(fused log-odds (H, W) float32, labels (H, W) uint8)``:
    the fused log-odds at ``weight``, and the label carried over from the previous frame where it
    reached the new frame and Bayes' rule at weight 1 agrees with it, 2 (unknown) elsewhere. So a
    label survives while the classifier does not overrule it, and neither
    what naive Bayes alone says about content new to the view nor a pixel it flipped is passed on as
    if it were a label (a chain that kept its own flips would lock its classifier's mistakes in and
    drift further from the truth with every frame).

    The classifier's evidence is not accumulated along the chain (as an HMM filter would): naive
    Bayes errs on the same colours in every frame, so its errors are correlated in time and adding
    them up frame after frame wears correct labels away; neither does a label fade with age (both
    measured worse: README, design notes).

    What the chain keeps is decided at weight 1, not at ``weight``: with a weight chosen on the few
    frames at a sequence's start (up to 12 on CamVid's 30-frame clips at k = 1), the prior's log-odds
    outweigh any classifier evidence, no carried label is ever overruled, and every registration error
    and disocclusion is passed on and compounds (the chain diverged to 25.4% error on CamVid 0006R0 at
    k = 1 with the dense registration, plain naive Bayes 6.0%). At weight 1 the prior is the calibrated
    probability it was built as, so the classifier can still overrule a label it contradicts strongly
    (5.7% there), and the chain's state no longer depends on a weight chosen on too few frames.
    A failed registration (``T_ref_mov`` None) ends the chain's labels: the frame falls back to plain
    naive Bayes, and so does the rest of the chain; so does a registration that the new frame's
    evidence does not support (:func:`registration_supported`): a poor registration is not carried on.
    """
    d = np.asarray(log_odds_moving, dtype=np.float32)
    if T_ref_mov is None:
        return d.copy(), np.full(d.shape, 2, np.uint8)
    from .registration.warp import warp_to_moving

    labels_reference = np.asarray(labels_reference, dtype=np.uint8)
    reached, _ = warp_to_moving(labels_reference, T_ref_mov, shape=d.shape, interpolation="nearest", fill=2)
    if not registration_supported(reached, labels_reference, d):
        return d.copy(), np.full(d.shape, 2, np.uint8)
    q_mov, _ = warp_prior(_prior_q(labels_reference, kind="labels", pi=pi, fusion=fusion), T_ref_mov,
                          shape=d.shape, pi=pi)
    l_prior = prior_log_odds(q_mov, pi=pi)
    fused = fuse(d, l_prior, weight=weight)
    judged = labels_from_log_odds(fuse(d, l_prior, weight=1.0))
    labels = np.where((reached < 2) & (judged == reached), reached, np.uint8(2)).astype(np.uint8)
    return fused, labels


@dataclass(frozen=True)
class PairArrays:
    """The arrays of one processed pair that a recording or a figure shows.

    warped : the moving image warped onto the reference grid (H, W, 3) uint8; valid : (H, W) bool, where
    it came from inside the moving image; predicted : {method: (H, W) uint8 labels} of the moving frame;
    thesis_after, thesis_after_masked : labels on the reference grid.
    motion : the registration's (3, 3) matrix or dense field (H, W, 2) (None when refused);
    warped_prior : (H, W) float32 obstacle probability of the reference labels warped into the moving
    frame; flow : the DIS field (H, W, 2) of ``augmented_flow``; confidence : a dense registration's
    per-pixel confidence (H, W) (None for a matrix).
    """

    warped: np.ndarray
    valid: np.ndarray
    predicted: dict
    thesis_after: np.ndarray
    thesis_after_masked: np.ndarray
    motion: np.ndarray | None = None
    warped_prior: np.ndarray | None = None
    flow: np.ndarray | None = None
    confidence: np.ndarray | None = None


@dataclass(frozen=True)
class ProcessedPair:
    """:func:`process_pair`'s outcome: the scores (``result``) and, when asked for, the arrays."""

    result: "PairResult"
    arrays: PairArrays | None = None


def process_pair(reference, moving, classifier, *, weight: float, config: PipelineConfig = PipelineConfig(),
                 registration: PairRegistration | None = None, temporal: "TemporalFusion | None" = None,
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
    from .datasets import relative_transform
    from .registration.transforms import max_corner_error
    from .registration.warp import warp, warp_to_moving

    if reference.shape != moving.shape:
        raise InputError(f"reference {reference.shape} and moving {moving.shape} frames differ in size")
    shape = moving.shape
    times = dict.fromkeys(STAGES, 0.0)
    reg = registration if registration is not None else register_pair(
        reference.image, moving.image, config=config, callback=callback)
    res, reason = reg.result, reg.reason
    times["register"] = reg.seconds
    T = None if res is None else np.asarray(res.matrix)
    motion = reg.motion  # a dense registration's field, else T

    t0 = time.perf_counter()
    if T is not None:
        warped, valid = warp(moving.image, motion, shape=reference.shape)
    else:
        warped, valid = moving.image, np.ones(shape, dtype=bool)
    times["warp"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    d_mov = log_odds(classifier, moving.image)
    d_warped = log_odds(classifier, warped) if T is not None else d_mov
    times["classify"] = time.perf_counter() - t0
    pred_mov = labels_from_log_odds(d_mov)
    pred_warped = labels_from_log_odds(d_warped)

    t0 = time.perf_counter()
    pi = float(np.asarray(classifier.class_prior_)[1])
    fusion = config.fusion
    q_ref = _prior_q(reference.labels, kind="labels", pi=pi, fusion=fusion)
    if T is not None:
        q_mov, prior_valid = warp_prior(q_ref, motion, shape=shape, pi=pi)
        l_reg = prior_log_odds(q_mov, pi=pi)
    else:
        l_reg = np.zeros(shape, np.float32)
    fused = fuse(d_mov, l_reg, weight=weight)
    times["fuse"] = time.perf_counter() - t0
    l_id = prior_log_odds(q_ref, pi=pi)
    fused_id = fuse(d_mov, l_id, weight=weight)
    fused_t = None if temporal is None else temporal.step(d_mov, motion, pi=pi)
    t0 = time.perf_counter()
    flow = flow_field(reference.image, moving.image) if flow is None else flow
    q_flow, _ = warp_prior(q_ref, flow, shape=shape, pi=pi)
    fused_flow = fuse(d_mov, prior_log_odds(q_flow, pi=pi), weight=weight if flow_weight is None else flow_weight)
    times["flow"] = time.perf_counter() - t0

    pred_masked = np.where(valid, pred_warped, pred_mov)
    if T is not None:
        ref_lab_mov, lab_valid = warp_to_moving(reference.labels, motion, shape=shape, interpolation="nearest",
                                                fill=2)
        propagated = np.where(lab_valid & (ref_lab_mov < 2), ref_lab_mov, pred_mov)
    else:
        propagated = pred_mov
    preds = {
        "plain": pred_mov, "augmented": labels_from_log_odds(fused),
        "augmented_unregistered": labels_from_log_odds(fused_id), "propagated": propagated,
        "augmented_flow": labels_from_log_odds(fused_flow),
    }
    if fused_t is not None:
        preds["augmented_temporal"] = labels_from_log_odds(fused_t)
    errors = {
        "plain": _err(pred_mov, moving.labels),
        "thesis_before": _err(pred_mov, reference.labels),
        "thesis_after": _err(pred_warped, reference.labels),
        "thesis_after_masked": _err(pred_masked, reference.labels),
        "thesis_after_cropped": _err(pred_warped, reference.labels, valid),
        "augmented": _err(preds["augmented"], moving.labels),
        "augmented_unregistered": _err(preds["augmented_unregistered"], moving.labels),
        "augmented_temporal": _err(preds["augmented_temporal"], moving.labels) if fused_t is not None else float("nan"),
        "propagated": _err(propagated, moving.labels),
        "augmented_flow": _err(preds["augmented_flow"], moving.labels),
    }
    truth_T = relative_transform(reference, moving)
    corner = None
    if truth_T is not None and T is not None:
        corner = max_corner_error(T, truth_T, shape)
    result = PairResult(reference=int(indices[0]), moving=int(indices[1]), names=(reference.name, moving.name),
                        registered=T is not None, reason=reason, registration=None if res is None else res.to_dict(),
                        corner_error=corner, errors=errors, times=times, valid_fraction=float(valid.mean()))
    arrays = PairArrays(warped=warped, valid=valid, predicted=preds, thesis_after=pred_warped,
                        thesis_after_masked=pred_masked, motion=motion,
                        warped_prior=q_mov if T is not None else None, flow=flow,
                        confidence=getattr(res, "confidence", None)) if keep_arrays else None
    return ProcessedPair(result, arrays)


# ---------------------------------------------------------------------------------------------------
# the temporal filter
# ---------------------------------------------------------------------------------------------------

class TemporalFusion:
    """Recursive label propagation along one chain of frames t0, t0 + k, t0 + 2k, ...

    The state is a label map of the last frame: its true labels at the start of the chain, then its
    fused labels where labels reached it (:func:`temporal_update`). :meth:`step` fuses a new frame's
    naive Bayes log-odds with the state warped into it and keeps the result.
    """

    def __init__(self, labels: np.ndarray, *, weight: float, pi: float = 0.5,
                 fusion: FusionConfig = FusionConfig()) -> None:
        self._pi = float(pi)
        self._weight = float(weight)
        self._fusion = fusion
        self._labels = np.array(labels, dtype=np.uint8)
        self._labels.setflags(write=False)

    @property
    def labels(self) -> np.ndarray:
        """(H, W) uint8 label state of the chain's last frame (read-only)."""
        return self._labels

    @property
    def weight(self) -> float:
        return self._weight

    def step(self, log_odds_moving: np.ndarray, T_ref_mov: np.ndarray | None, *, pi: float | None = None) -> np.ndarray:
        """Fuse the moving frame's log-odds (H, W) with the state warped by ``T_ref_mov`` (None: no
        prior); returns the fused log-odds (H, W) float32 and keeps the new label state.

        pi : the obstacle prior of the classifier that made the log-odds (kept for later steps); None
        keeps the last one.
        """
        if pi is not None:
            self._pi = float(pi)
        fused, labels = temporal_update(log_odds_moving, self._labels, T_ref_mov, pi=self._pi,
                                        weight=self._weight, fusion=self._fusion)
        labels.setflags(write=False)
        self._labels = labels
        return fused


# ---------------------------------------------------------------------------------------------------
# a sequence
# ---------------------------------------------------------------------------------------------------

def pair_indices(n: int, k: int) -> list[tuple[int, int]]:
    """Pairs (i, i + k) of a sequence of ``n`` frames."""
    return [(i, i + k) for i in range(max(0, n - k))]


def resolve_fusion_frames(n: int, *, fusion_frames: int | None, train: str) -> int:
    """How many frames at the start of a sequence choose the fusion weight (and are never scored).

    Default: the training frames for ``train="first:K"``, else 10% of the sequence, at least 2.
    """
    if fusion_frames is not None:
        return int(fusion_frames)
    if train.startswith("first:"):
        return int(train.split(":", 1)[1])
    return max(2, int(math.ceil(0.1 * n)))


@dataclass(frozen=True)
class SequenceResult:
    """One sequence at one increment with one backend.

    k : increment. backend : ICP backend. fusion_frames : frames 0..C-1 that chose the weight.
    weight : :class:`~pcreg.classification.fusion.WeightChoice` (``pairs == 0`` when fixed or not choosable).
    temporal_weight : the same for the recursive (temporal) fusion, chosen on the same frames.
    flow_weight : the same for ``augmented_flow``.
    pairs : scored :class:`PairResult` (moving frame >= C). means : {method: mean error % over pairs}.
    failures : [{"reference", "moving", "reason"}] of the scored pairs. notes : why pairs are missing.
    seconds : wall time.
    """

    k: int
    backend: str
    fusion_frames: int
    weight: WeightChoice
    pairs: tuple[PairResult, ...]
    means: dict
    failures: tuple[dict, ...]
    notes: tuple[str, ...]
    seconds: float
    temporal_weight: WeightChoice | None = None
    flow_weight: WeightChoice | None = None

    def to_dict(self) -> dict:
        return {"k": self.k, "backend": self.backend, "fusion_frames": self.fusion_frames,
                "weight": self.weight.to_dict(),
                "temporal_weight": None if self.temporal_weight is None else self.temporal_weight.to_dict(),
                "flow_weight": None if self.flow_weight is None else self.flow_weight.to_dict(), "means": dict(self.means),
                "failures": [dict(f) for f in self.failures], "notes": list(self.notes),
                "pairs": [p.to_dict() for p in self.pairs], "seconds": self.seconds}


def _means(pairs: Sequence[PairResult]) -> dict:
    out = {}
    for m in METHODS:
        vals = np.array([p.errors[m] for p in pairs], dtype=np.float64)
        out[m] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    return out


def _choose_temporal_weight(calib: list, frames: Sequence, *, fusion: FusionConfig) -> WeightChoice:
    """The temporal filter's weight: run the chains through the calibration pairs (in order) with each
    candidate weight, pool the errors of every fused frame, keep the best (ties: the smaller weight)."""
    grid = tuple(float(g) for g in fusion.grid)
    if not calib:
        return choose_weight([], grid=grid)
    wrong = np.zeros(len(grid), dtype=np.int64)
    total = 0
    for gi, w in enumerate(grid):
        state: dict[int, np.ndarray] = {}
        for i, j, T, d, pi in calib:
            fused, state[j] = temporal_update(d, state.get(i, frames[i].labels), T, pi=pi, weight=w, fusion=fusion)
            state.pop(i, None)
            truth = frames[j].labels
            keep = truth < 2
            wrong[gi] += int(np.count_nonzero((fused[keep] > 0) != (truth[keep] == 1)))
            if gi == 0:
                total += int(keep.sum())
    if total == 0:
        return choose_weight([], grid=grid)
    errors = 100.0 * wrong / total
    best = int(np.argmin(errors))
    return WeightChoice(grid[best], grid, tuple(float(e) for e in errors), len(calib), total)


def _odd_sized(frames: Sequence) -> dict[int, str]:
    """{index: reason} of the frames whose size differs from the sequence's most common size."""
    from collections import Counter

    if not frames:
        return {}
    (h, w), _ = Counter(f.shape for f in frames).most_common(1)[0]
    return {i: f"frame {f.name} is {f.shape[1]}x{f.shape[0]} px, the sequence's frames are {w}x{h}"
            for i, f in enumerate(frames) if f.shape != (h, w)}


def run_sequence(frames: Sequence, *, k: int, config: PipelineConfig = PipelineConfig(), train: str = "reference",
                 fusion_frames: int | None = None, on_pair: Callable | None = None,
                 icp_callback: Callable | None = None) -> SequenceResult:
    """Walk a labelled sequence with increment ``k``: every method on the pairs (i, i + k).

    frames : labelled :class:`~pcreg.datasets.Frame` of one size, in order.
    train : ``"reference"`` (naive Bayes trained on each pair's reference frame, as the thesis) or
        ``"first:K"`` (trained once on frames 0..K-1).
    fusion_frames : frames 0..C-1 choose the fusion weight (pairs among them, at increment
        min(k, C - 1), scored against their moving frame's labels); only pairs whose moving frame is
        >= C are scored (default: :func:`resolve_fusion_frames`). A fixed ``config.fusion.weight``
        skips the choice.
    on_pair : called as ``on_pair(pair_result, frames, arrays)`` for each scored pair, with the arrays
        of :func:`process_pair` (for recordings); None keeps them off the hot path.
    icp_callback : passed to :func:`pcreg.register` (per-iteration hook) for the scored pairs.

    Bad input (``k < 1``, unlabelled frames, a bad ``train``) raises :class:`~pcreg.errors.InputError`;
    a sequence too short for ``k`` gives no pairs and a note.
    """
    t_start = time.perf_counter()
    if int(k) < 1:
        raise InputError(f"increment k must be at least 1, got {k}")
    k = int(k)
    n = len(frames)
    if any(f.labels is None for f in frames):
        raise InputError("every frame needs labels to be scored")
    if train != "reference":
        if not train.startswith("first:") or not train.split(":", 1)[1].isdigit() or int(train.split(":", 1)[1]) < 1:
            raise InputError(f"train must be 'reference' or 'first:K' with K >= 1, got {train!r}")
    C = resolve_fusion_frames(n, fusion_frames=fusion_frames, train=train)
    if C < 0:
        raise InputError("fusion_frames must be >= 0")
    notes: list[str] = []
    fixed = config.fusion.weight
    empty_choice = WeightChoice(float(fixed if fixed is not None else 1.0), config.fusion.grid,
                                tuple(float("nan") for _ in config.fusion.grid), 0, 0)
    if n < 2:
        notes.append(f"{n} frame(s): no pairs")
        return SequenceResult(k, config.backend, C, empty_choice, (), _means([]), (), tuple(notes),
                              time.perf_counter() - t_start, temporal_weight=empty_choice)
    if k >= n:
        notes.append(f"increment k={k} is not shorter than the sequence ({n} frames): no pairs")
        return SequenceResult(k, config.backend, C, empty_choice, (), _means([]), (), tuple(notes),
                              time.perf_counter() - t_start, temporal_weight=empty_choice)

    shared_clf = None
    if train.startswith("first:"):
        K = int(train.split(":", 1)[1])
        if K >= n:
            raise InputError(f"train first:{K} leaves no test frame in a sequence of {n} frames")
        shared_clf = fit_classifier(frames[:K], features=config.features)
    clf_cache: dict[int, object] = {}

    def classifier(i: int):
        if shared_clf is not None:
            return shared_clf
        if i not in clf_cache:
            clf_cache.clear()
            clf_cache[i] = fit_classifier([frames[i]], features=config.features)
        return clf_cache[i]

    reg_cache: dict[tuple[int, int], PairRegistration] = {}
    odd = _odd_sized(frames)  # a frame of another size fails its own pairs only, with the reason


    def registration(i: int, j: int, callback=None):
        if (i, j) not in reg_cache:
            reg_cache[(i, j)] = register_pair(frames[i].image, frames[j].image, config=config, callback=callback)
        return reg_cache[(i, j)]

    # 1. the fusion weights (one-step and temporal), on pairs among the first C frames
    kc = min(k, C - 1)
    calib = []  # (i, j, T, d_j, pi) of the registered pairs among the first C frames, in order
    if fixed is None and kc >= 1:
        for i, j in pair_indices(C, kc):
            if i in odd or j in odd:
                continue
            clf = classifier(i)
            calib.append((i, j, registration(i, j).motion, log_odds(clf, frames[j].image),
                          float(np.asarray(clf.class_prior_)[1])))
    if fixed is not None:
        choice = temporal_choice = flow_choice = empty_choice
    else:
        samples = []
        for i, j, T, d, pi in calib:
            if T is None:
                continue
            q_mov, _ = warp_prior(_prior_q(frames[i].labels, kind="labels", pi=pi, fusion=config.fusion), T,
                                  shape=frames[j].shape, pi=pi)
            samples.append((d, prior_log_odds(q_mov, pi=pi), frames[j].labels))
        choice = choose_weight(samples, grid=config.fusion.grid)
        flow_samples = []
        for i, j, _, d, pi in calib:
            q_mov, _ = warp_prior(_prior_q(frames[i].labels, kind="labels", pi=pi, fusion=config.fusion),
                                  flow_field(frames[i].image, frames[j].image), shape=frames[j].shape, pi=pi)
            flow_samples.append((d, prior_log_odds(q_mov, pi=pi), frames[j].labels))
        flow_choice = choose_weight(flow_samples, grid=config.fusion.grid)
        temporal_choice = _choose_temporal_weight(calib, frames, fusion=config.fusion)
        if choice.pairs == 0:
            notes.append(f"no registered pair among the first {C} frames to choose the fusion weight: "
                         f"w = {choice.weight} used")
        elif kc != k:
            notes.append(f"fusion weight chosen at increment {kc} (the first {C} frames hold no pair {k} apart)")
        reg_cache = {key: v for key, v in reg_cache.items() if key[1] - key[0] == k}
    weight = choice.weight
    weight_t = temporal_choice.weight
    weight_f = flow_choice.weight

    # 2. every pair (i, i + k) in order; the temporal chains need all of them, the scores those with j >= C
    chains: deque = deque()
    scored: list[PairResult] = []
    failures: list[dict] = []
    for i, j in pair_indices(n, k):
        chain = chains.popleft() if i >= k else None
        if i in odd or j in odd:
            if j >= C:
                failures.append({"reference": i, "moving": j, "reason": odd[i if i in odd else j]})
            chains.append(None)  # the chain restarts after the odd frame
            continue
        if chain is None:
            chain = TemporalFusion(frames[i].labels, weight=weight_t, fusion=config.fusion)
        score = j >= C
        reg = registration(i, j, icp_callback if score else None)
        reg_cache.pop((i, j), None)
        clf = classifier(i)
        if score:
            done = process_pair(frames[i], frames[j], clf, weight=weight, config=config, registration=reg,
                                temporal=chain, indices=(i, j), keep_arrays=on_pair is not None, flow_weight=weight_f)
            result = done.result
            scored.append(result)
            if not result.registered:
                failures.append({"reference": i, "moving": j, "reason": result.reason})
            if on_pair is not None:
                on_pair(result, (frames[i], frames[j]), done.arrays)
        else:
            chain.step(log_odds(clf, frames[j].image), reg.motion, pi=float(np.asarray(clf.class_prior_)[1]))
        chains.append(chain)
    if not scored:
        notes.append(f"no pair with its moving frame after the {C} fusion frames")
    return SequenceResult(k, config.backend, C, choice, tuple(scored), _means(scored), tuple(failures),
                          tuple(notes), time.perf_counter() - t_start, temporal_weight=temporal_choice,
                          flow_weight=flow_choice)
