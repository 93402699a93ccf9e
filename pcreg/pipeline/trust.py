"""Where a carried label can be trusted, and how sure each output label is.

A stream's step carries the key frame's labels into the new frame along two motions found
independently: pcreg's dense field (:func:`pcreg.register_dense`) and OpenCV's DIS optical flow at its
ultrafast preset (:func:`pcreg.registration.flow.dis_field`, about 5 ms at 640x480). Each carried prior
is trusted, pixel by pixel, by how well the key frame carried along the *same* motion matches the new
frame there (:func:`carried_residual`): where the key image lands on what the frame shows, the labels
landed right too; where it does not (an occlusion, a disocclusion, a field that slid, a scene that
changed) the prior fades and naive Bayes has the say. When the whole frame stops matching, every
pixel's trust falls, and the step is naive Bayes alone. The fused log-odds (:func:`fused_log_odds`)::

    F = d + weight * (dense * (lo + (hi - lo) c) * exp(-r_field / residual) * l_field
                      + flow * exp(-r_flow / residual) * l_flow)

with ``d`` naive Bayes' log-odds, ``l_*`` each carried prior's log-odds, ``(lo, hi)`` the span of
:data:`~pcreg.classification.fusion.CONFIDENCE_SPAN` (0.5, 2), ``c`` the dense field's own
confidence (:data:`UNKNOWN_CONFIDENCE` where it has none) and ``r_*`` each motion's residual in grey levels. The labels are the sign of ``F`` blurred
(:func:`smoothed`: a Gaussian of :attr:`TrustRule.smooth` px at :data:`BASE_WIDTH`): a pixel is labelled
by the evidence around it, not by its own alone. The rule's numbers (:class:`TrustRule`) were each
chosen with one CamVid clip left out, for each of the eight shared clips, and scored on the clip left
out (docs/results.md, "Trust" and "Smoothing").

Every output label gets a calibrated confidence, the probability that it is right
(:func:`label_confidence`), from four things a person can see: how far the fused log-odds are from 0,
how much of the label's neighbourhood has the same label at two sizes (errors sit on the boundaries
between classes), and how much of the neighbourhood's classifier agrees with the carried prior. Its
five coefficients (:data:`CONFIDENCE_COEFFICIENTS`) were fitted by logistic regression on the eight
shared clips, and checked clip by clip with each clip left out (``tools/fit_trust.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..classification.fusion import CONFIDENCE_SPAN
from ..errors import InputError
from .readout import AGREEMENT_SIDE, BASE_WIDTH, PURITY_SIDES, Scratch, half  # noqa: F401 - BASE_WIDTH: where the rule's sizes are stated
from .readout import odd as _odd
from .readout import scaled as _scaled
from .working import WorkingSize

__all__ = ["TrustRule", "STREAM_TRUST", "CLASS_TRUST", "CONFIDENCE_COEFFICIENTS", "TrustMaps", "carried_residual", "carried_log_odds",
           "residual_trust", "TrustedKey", "Trusted", "smoothed", "read_labels", "least_confidence",
           "trust_maps", "fused_log_odds", "confidence_features", "label_confidence", "predicted_error", "least_confident"]

#: Blurs (px at :data:`BASE_WIDTH`): of both images before comparing, and of the residual after.
IMAGE_SIGMA, RESIDUAL_SIGMA = 1.5, 3.0
#: The residual outside the key frame (grey levels): nothing carried there can be trusted.
OUTSIDE = 255.0
#: The confidence's logistic coefficients: intercept, then log1p(|F|), purity at 15 px, purity at 33 px,
#: agreement at 33 px; fitted on the eight shared CamVid clips (``tools/fit_trust.py``).
CONFIDENCE_COEFFICIENTS: tuple[float, ...] = (-5.001, 0.648, -2.302, 6.542, 3.339)


#: The dense field's confidence taken where it gives none (a field of unknown confidence, as DIS's flow):
#: the rule's ``dense`` weight is stated at it (:class:`TrustRule`).
UNKNOWN_CONFIDENCE = 1.0 / 3.0


#: The least confidence a label gets: it is the likelier of two classes. The logistic model's low end
#: over-predicts errors there (labels it gave 0.1-0.4 were right 39-45% of the time on the shared
#: clips); with this least value the expected calibration error over the clips, each left out, fell from
#: 0.0074 to 0.0038, and the order of the pixels by confidence is the same.
MIN_CONFIDENCE = 0.5


@dataclass(frozen=True)
class TrustRule:
    """How far each carried prior is trusted (see the module's docstring).

    dense : the dense field's prior weight, a multiple of the propagator's ``weight``, at a field
        confidence of 1/3 and a residual of 0 (from half to twice it as the confidence goes 0 to 1).
    flow : the DIS flow's prior weight, the same way (0: the flow is not computed; nor is it for frames with a
        side under 32 px, :data:`~pcreg.registration.flow.DIS_MIN_SIDE`, which DIS does not take).
    residual : grey levels of the carried key frame's mean colour difference at which a prior's trust
        falls to 1/e.
    preset : the DIS preset of the second motion.
    smooth : the blur of the fused log-odds before they are read as labels and as the labels'
        confidence (:func:`smoothed`): a Gaussian's sigma in px at :data:`BASE_WIDTH` (0: none).
    """

    dense: float = 2.0
    flow: float = 1.5
    residual: float = 40.0
    preset: str = "ultrafast"
    smooth: float = 3.0

    def __post_init__(self) -> None:
        from ..registration.flow import PRESETS
        from ..validation import check_float

        check_float(self.dense, "trust dense", lo=0, hi=1e6)
        check_float(self.flow, "trust flow", lo=0, hi=1e6)
        check_float(self.residual, "trust residual", lo=0, lo_open=True, hi=1e6)
        check_float(self.smooth, "trust smooth", lo=0, hi=1e3)
        if self.preset not in PRESETS:
            raise InputError(f"unknown DIS preset {self.preset!r}; choose one of {', '.join(PRESETS)}")


#: The stream's trust rule (chosen with each shared clip left out; docs/results.md).
STREAM_TRUST = TrustRule()
#: The trust rule with more than two classes (:mod:`pcreg.pipeline.multiclass`): the stream's, with a blur
#: of 1 px at 480 px wide before the best class is read (thin classes, a pole or a sign, vanish under the
#: two-class 3 px), DIS's medium preset without its variational refinement for the second motion (more
#: accurate here than with it, in half its time) and a residual of 25 grey levels (a carried class is
#: trusted less where the colours it lands on differ); chosen with each shared CamVid clip left out
#: (docs/results.md, "Many classes").
CLASS_TRUST = TrustRule(smooth=1.0, preset="medium-norefine", residual=25.0)


def smoothed(fused: np.ndarray, rule: TrustRule) -> np.ndarray:
    """(H, W) float32: the fused log-odds as the labels read them, blurred by a Gaussian of ``rule.smooth``
    px at :data:`BASE_WIDTH` (scaled to the frame's width; the borders reflected); ``fused`` itself (as
    float32) when ``rule.smooth`` is 0. Its sign is the label, and :func:`label_confidence` reads it."""
    import cv2

    F = np.ascontiguousarray(fused, dtype=np.float32)
    if rule.smooth <= 0:
        return F
    return cv2.GaussianBlur(F, (0, 0), _scaled(rule.smooth, F.shape[1]))


def read_labels(fused: np.ndarray, log_odds: np.ndarray, prior_term: np.ndarray, rule: TrustRule, *,
                size: WorkingSize | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(labels, confidence)`` of fused log-odds as ``rule`` reads them: (H, W) uint8, the sign of the
    :func:`smoothed` log-odds, and :func:`label_confidence` of the same (``log_odds``: naive Bayes' own,
    ``prior_term``: the priors' part of ``fused``). ``size``: the stream's working size, when the maps
    are at it: both are brought to the frames' size (:meth:`~pcreg.pipeline.working.WorkingSize.grow`),
    the labels the sign of the resized log-odds."""
    shown = smoothed(fused, rule)
    confidence = label_confidence(shown, log_odds, prior_term)
    if size is not None and size.scaled:
        shown, confidence = size.grow(shown), size.grow(confidence)
    return (shown > 0).astype(np.uint8), confidence


def blurred(image: np.ndarray) -> np.ndarray:
    """(H/2, W/2, 3) float32: the image at half size (:func:`half`), blurred by :data:`IMAGE_SIGMA` (scaled
    to the frame's full width): what residuals compare. The residual is blurred wider than a pixel
    anyway, so it is measured at half size, a quarter of the work."""
    import cv2

    width = np.shape(image)[1]
    return cv2.GaussianBlur(half(image), (0, 0), _scaled(IMAGE_SIGMA, width) / 2)


def carried_residual(key_blurred: np.ndarray, frame_blurred: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(H, W) float32: the mean absolute colour difference, in grey levels, between the frame and the key
    frame carried along ``field`` (H, W, 2: reference coordinates of every frame pixel), both
    :func:`blurred`, blurred again by :data:`RESIDUAL_SIGMA`; :data:`OUTSIDE` where the field leaves the
    key frame. Measured at half size (the field averaged over each 2x2 block, in half-size
    coordinates) and brought back to the field's size bilinearly."""
    import cv2

    fld = np.asarray(field, dtype=np.float32)
    h, w = fld.shape[:2]
    hh, hw = frame_blurred.shape[:2]
    small = (cv2.resize(fld, (hw, hh), interpolation=cv2.INTER_AREA) - np.float32(0.5)) * np.float32(0.5)
    carried = cv2.remap(key_blurred, small, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    res = cv2.transform(cv2.absdiff(carried, frame_blurred), np.full((1, 3), 1.0 / 3.0))
    x, y = small[:, :, 0], small[:, :, 1]
    inside = (x >= -0.5) & (x <= hw - 0.5) & (y >= -0.5) & (y <= hh - 0.5)  # NaN compares False: outside
    res[~inside] = OUTSIDE
    res = cv2.GaussianBlur(res, (0, 0), _scaled(RESIDUAL_SIGMA, w) / 2)
    return cv2.resize(res, (w, h), interpolation=cv2.INTER_LINEAR)


def residual_trust(reference_image: np.ndarray, moving_image: np.ndarray, field: np.ndarray,
                   rule: "TrustRule | None" = None) -> np.ndarray:
    """(H, W) float32 in [0, 1]: how far labels carried from ``reference_image`` into ``moving_image``
    along ``field`` (reference coordinates of every moving pixel) can be trusted, the stream's rule
    (``exp(-r / residual)`` of :func:`carried_residual`, 0 wholly outside the reference), for a pair."""
    r = carried_residual(blurred(reference_image), blurred(moving_image), field)
    return residual_weight(r, STREAM_TRUST if rule is None else rule).astype(np.float32)


def residual_weight(residual: np.ndarray, rule: "TrustRule") -> np.ndarray:
    """(H, W) float32 in [0, 1]: ``exp(-r / rule.residual)`` of a :func:`carried_residual`, 0 where the
    residual's neighbourhood lies wholly outside the key frame (:data:`OUTSIDE`)."""
    r = np.asarray(residual, np.float32)
    out = np.multiply(r, np.float32(-1.0 / rule.residual), out=np.empty(r.shape, np.float32))
    np.exp(out, out=out)  # in place: one float map, where np.where's made three
    np.copyto(out, np.float32(0.0), where=~(r < OUTSIDE))  # NaN compares False: 0
    return out


def carried_log_odds(log_odds: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(H, W) float32: the key frame's prior log-odds carried along ``field`` (bilinear), 0 (no evidence
    beyond the class prior) where the field leaves the key frame."""
    import cv2

    return cv2.remap(np.asarray(log_odds, np.float32), np.ascontiguousarray(field, dtype=np.float32), None,
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


@dataclass(frozen=True, eq=False)
class TrustMaps:
    """A step's trust map, per pixel (H, W) float32, its motions named by their role: the ``primary`` motion
    (the stream's own: a dense field, DIS's flow with ``model="flow"``, or a global transform) and the
    ``second`` (DIS's flow beside a registration; None with a flow, or for frames DIS does not take). For
    each, the carried prior's log-odds (``primary_prior``, ``second_prior``), the evidence for it (the key
    frame's ``primary_residual`` and ``second_residual`` along each motion, the primary field's own
    ``confidence``) and the fusion weight the rule gave it (``primary``, ``second``); None where that
    prior is absent; ``term``, the priors' part of the fused scores when the fusion made it (what
    :meth:`prior_term` gives). The names of before 0.2.0 (``dense``, ``flow``, ``dense_prior``, ...) still
    read, with a :class:`DeprecationWarning`."""

    primary: np.ndarray | None
    primary_prior: np.ndarray | None
    second: np.ndarray | None
    second_prior: np.ndarray | None
    primary_residual: np.ndarray | None = None
    second_residual: np.ndarray | None = None
    confidence: np.ndarray | None = None
    term: np.ndarray | None = field(default=None, repr=False)

    def prior_term(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) float32: the sum of weight times log-odds over the priors present; with K classes
        (priors of (H, W, K) class evidence, ``shape`` (H, W, K)) the same per class. The fusion's own
        array (:attr:`term`, the same numbers, not a copy) when it made one of that shape."""
        if self.term is not None and self.term.shape == tuple(shape):
            return self.term
        out = np.zeros(shape, np.float32)
        for w, l in ((self.primary, self.primary_prior), (self.second, self.second_prior)):
            if w is not None and l is not None:
                out += (w[..., None] if l.ndim == 3 else w) * l
        return out

    def summary(self, rule: "TrustRule", weight: float) -> dict:
        """The frame's trust in one number per motion (``primary``, ``second``: ``steps.jsonl``'s ``trust``):
        the mean of its weight over the pixels, as a share of the most the rule gives it (``weight *
        rule.dense`` times the top of :data:`~pcreg.classification.fusion.CONFIDENCE_SPAN` at full confidence,
        ``weight * rule.flow``)."""
        out = {}
        top_primary = weight * rule.dense * CONFIDENCE_SPAN[1]
        for name, w, top in (("primary", self.primary, top_primary), ("second", self.second, weight * rule.flow)):
            out[name] = None if w is None or top <= 0 else float(np.mean(w, dtype=np.float64) / top)
        return out

    def __getattr__(self, name: str):
        new = _OLD_TRUST_NAMES.get(name)
        if new is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        import warnings

        warnings.warn(f"TrustMaps.{name} is deprecated since 0.2.0 (the motions are named by their role); "
                      f"use TrustMaps.{new}", DeprecationWarning, stacklevel=2)
        return getattr(self, new)


#: :class:`TrustMaps`' names of before 0.2.0, and what they are now.
_OLD_TRUST_NAMES = {"dense": "primary", "dense_prior": "primary_prior", "dense_residual": "primary_residual",
                    "flow": "second", "flow_prior": "second_prior", "flow_residual": "second_residual"}


def trust_maps(rule: TrustRule, *, weight: float, primary_prior: np.ndarray | None,
               primary_residual: np.ndarray | None, confidence: np.ndarray | None, second_prior: np.ndarray | None,
               second_residual: np.ndarray | None) -> TrustMaps:
    """Each carried prior's weight per pixel by ``rule`` (the module's formula): the primary motion's and
    the second's (:class:`TrustMaps`); a prior given as None (its motion failed or was not computed) gets
    none, and a pixel whose residual's neighbourhood lies wholly outside the key frame (:data:`OUTSIDE`)
    gets 0."""
    wd = wf = None
    if primary_prior is not None and primary_residual is not None:
        lo, hi = CONFIDENCE_SPAN
        c = UNKNOWN_CONFIDENCE if confidence is None else np.clip(np.nan_to_num(confidence, nan=0.0), 0.0, 1.0)
        scale = np.float32(weight * rule.dense) * (np.float32(lo) + np.float32(hi - lo) * c)
        wd = residual_weight(primary_residual, rule)  # its own map, scaled in place (the same products)
        np.multiply(wd, scale, out=wd, casting="unsafe")
    if second_prior is not None and second_residual is not None:
        wf = residual_weight(second_residual, rule)
        np.multiply(wf, np.float32(weight * rule.flow), out=wf)
    return TrustMaps(wd, primary_prior, wf, second_prior, primary_residual, second_residual,
                     None if confidence is None else np.asarray(confidence, np.float32))


def fused_log_odds(log_odds: np.ndarray, maps: TrustMaps) -> np.ndarray:
    """(H, W) float32 ``F``: naive Bayes' log-odds plus every trusted prior (the module's formula)."""
    d = np.asarray(log_odds, dtype=np.float32)
    return d + maps.prior_term(d.shape)


def _neighbourhoods(fused: np.ndarray, log_odds: np.ndarray, prior_term: np.ndarray) -> list[np.ndarray]:
    """The confidence's three neighbourhood features at half size (:func:`confidence_features`)."""
    import cv2

    F = np.asarray(fused, dtype=np.float32)
    w = F.shape[1]
    lab = (F > 0).astype(np.float32)
    agree = ((np.asarray(log_odds) > 0) == (np.asarray(prior_term) > 0)).astype(np.float32)
    lab_h, agree_h = half(lab), half(agree)
    out = []
    for side, src in zip((*PURITY_SIDES, AGREEMENT_SIDE), (lab_h, lab_h, agree_h)):
        k = _odd(side / 2, w)
        m = cv2.blur(src, (k, k), borderType=cv2.BORDER_REFLECT)
        if src is lab_h:  # the share of the neighbourhood with the pixel's own label
            m = np.where(lab_h >= 0.5, m, 1.0 - m).astype(np.float32)
        out.append(m)
    return out


def confidence_features(fused: np.ndarray, log_odds: np.ndarray, prior_term: np.ndarray) -> list[np.ndarray]:
    """The confidence's four features, (H, W) float32 each: log1p(|F|), the share of the label's
    neighbourhood with the same label at the two :data:`PURITY_SIDES`, and the share of the
    :data:`AGREEMENT_SIDE` neighbourhood where naive Bayes' sign agrees with the carried prior's. The
    neighbourhoods (15-33 px) are read at half size and brought back bilinearly."""
    import cv2

    F = np.asarray(fused, dtype=np.float32)
    h, w = F.shape
    return [np.log1p(np.abs(F))] + [cv2.resize(m, (w, h), interpolation=cv2.INTER_LINEAR)
                                    for m in _neighbourhoods(F, log_odds, prior_term)]


def label_confidence(fused: np.ndarray, log_odds: np.ndarray, prior_term: np.ndarray,
                     coefficients: tuple[float, ...] = CONFIDENCE_COEFFICIENTS) -> np.ndarray:
    """(H, W) float32 in [1/2, 1]: the probability that the label ``F > 0`` is right at each pixel, by
    the logistic model over :func:`confidence_features` (:data:`CONFIDENCE_COEFFICIENTS`), never below
    :data:`MIN_CONFIDENCE`. The neighbourhoods' part of the model is summed at half size and brought
    back once (bilinear resizing is linear: the same sum, to float32 rounding)."""
    import cv2

    if len(coefficients) != 5:
        raise InputError(f"the confidence takes 5 coefficients, got {len(coefficients)}")
    F = np.ascontiguousarray(fused, dtype=np.float32)
    h, w = F.shape
    parts = _neighbourhoods(F, log_odds, prior_term)
    linear = np.zeros(parts[0].shape, np.float32)
    for a, m in zip(coefficients[2:], parts):
        linear += np.float32(a) * m
    z = cv2.resize(linear, (w, h), interpolation=cv2.INTER_LINEAR)
    t = np.abs(F)
    np.log1p(t, out=t)
    t *= np.float32(coefficients[1])
    z += t
    z += np.float32(coefficients[0])
    np.clip(z, -60.0, 60.0, out=z)
    np.negative(z, out=z)
    conf = np.exp(z, out=z)
    conf += np.float32(1.0)
    np.reciprocal(conf, out=conf)
    np.maximum(conf, np.float32(MIN_CONFIDENCE), out=conf)
    if not np.all(np.isfinite(conf)):  # finite inputs give a finite logistic: anything else is a bug
        raise AssertionError("a confidence came out NaN")
    return conf


def least_confident(trusted: "Trusted", n_classes: int) -> "Trusted":
    """``trusted`` with the same labels and every confidence the least a stream of ``n_classes`` classes gives
    (:func:`least_confidence`): a step whose confidence model does not hold (a scene cut, :mod:`pcreg.pipeline.cuts`;
    a degenerate classifier, :meth:`~pcreg.classification.bayes.NaiveBayesPixelClassifier.degenerate_classes`)."""
    return replace(trusted, confidence=np.full(trusted.confidence.shape, least_confidence(n_classes), np.float32))


def least_confidence(n_classes: int) -> float:
    """The least confidence of a stream of ``n_classes``: :data:`MIN_CONFIDENCE`, with more the larger of 1/K and CLASS_MIN_CONFIDENCE."""
    from .multiclass import CLASS_MIN_CONFIDENCE

    return MIN_CONFIDENCE if n_classes <= 2 else max(1.0 / n_classes, CLASS_MIN_CONFIDENCE)


def class_predicted_iou(labels: np.ndarray, confidence: np.ndarray, second: np.ndarray | None,
                        ids: np.ndarray | None = None) -> dict[int, float]:
    """Each class's predicted IoU (:func:`~pcreg.pipeline.multiclass.predicted_iou`) for the classes ``labels``
    hold, by class id: with K classes ``second`` is each pixel's runner-up; with two (``second`` None) it is the
    other class, and ``ids`` (when given) the table's ids of the labels' 0 and 1."""
    from .multiclass import predicted_iou

    if second is None:  # two classes: a wrong label's truth is the other one
        second = np.uint8(1) - labels
    iou = predicted_iou(labels, confidence, second)
    return iou if ids is None else {int(ids[k]): v for k, v in iou.items()}


def predicted_error(confidence: np.ndarray) -> float:
    """A frame's predicted error in percent: the mean of 1 - confidence over its pixels."""
    return float(100.0 * (1.0 - np.mean(confidence, dtype=np.float64)))


@dataclass(frozen=True, eq=False)
class Trusted:
    """A step's labels by the trust rule (:meth:`TrustedKey.fuse`): ``labels`` (H, W) uint8, the sign of
    the ``fused`` log-odds :func:`smoothed`, their ``confidence`` (:func:`label_confidence` of the same),
    the trust ``maps``, the fused log-odds themselves and the trusted priors' part of them (``prior``);
    with K classes (:mod:`pcreg.pipeline.multiclass`) ``fused`` and ``prior`` are (H, W, K) class scores
    and ``second`` each pixel's runner-up class. ``picture``: the rows and columns between a letterboxed frame's
    bars (:mod:`pcreg.pipeline.bars`), what the report's predicted error and IoU are of (None: the whole frame)."""

    labels: np.ndarray
    confidence: np.ndarray
    maps: TrustMaps
    fused: np.ndarray
    prior: np.ndarray
    second: np.ndarray | None = None
    picture: tuple[slice, slice] | None = None

    def report(self, rule: TrustRule, weight: float, cut: dict | None = None, ids: np.ndarray | None = None) -> dict:
        """What a step's report (:class:`~pcreg.pipeline.stream.StepReport`) gives of it: the confidence,
        the predicted error, the trust map and its summary (with what the step adds to it, ``cut``: the cut
        test's finding, :mod:`pcreg.pipeline.cuts`) and each class's predicted IoU
        (:func:`class_predicted_iou`; ``ids``: the table's ids of the two-class step's 0 and 1, when they are others)."""
        at = self.picture or (slice(None), slice(None))
        second = None if self.second is None else self.second[at]
        summary: dict = {**self.maps.summary(rule, weight), **(cut or {}),
                         "predicted_iou": class_predicted_iou(self.labels[at], self.confidence[at], second, ids)}
        return {"confidence": self.confidence, "predicted_error": predicted_error(self.confidence[at]),
                "trust": self.maps, "trust_summary": summary}


class TrustedKey:
    """The key frame as the trust rule reads it, made once: its prior's log-odds and its colours at half
    size, blurred (:func:`blurred`); it carries both along a motion's field into a new frame
    (:meth:`carried`) and fuses a frame's naive Bayes with what it carried (:meth:`fuse`). ``size``: the
    stream's working size when the key frame is at it (the labels and confidence come back at the frames'
    size). With K classes (``classes``, a :class:`~pcreg.pipeline.multiclass.ClassRead`, and ``log_odds``
    (H, W, K) evidence) the key frame's ``labels`` (H, W) let the evidence be carried by reading the labels
    when it is one vector per label (:func:`~pcreg.pipeline.multiclass.label_evidence`)."""

    def __init__(self, rule: TrustRule, weight: float, image: np.ndarray, log_odds: np.ndarray,
                 size: WorkingSize | None = None, *, classes=None, labels: np.ndarray | None = None) -> None:
        self.rule, self.weight, self.size = rule, float(weight), size
        self.blurred, self.log_odds = blurred(image), log_odds
        self.classes = classes
        self._by_label = None
        self._scratch: Scratch | None = None  # the many-class read-out's arrays, kept from one step to the next
        if classes is not None and labels is not None:
            from .multiclass import label_evidence

            self._by_label = label_evidence(labels, log_odds)

    def carried(self, frame_blurred: np.ndarray, field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(prior, residual)`` along ``field``: :func:`carried_log_odds` (with K classes
        :func:`~pcreg.pipeline.multiclass.carried_log_probs`) and :func:`carried_residual`."""
        if self.classes is not None:
            from .multiclass import carried_log_probs

            return (carried_log_probs(self.log_odds, field, labels=self._by_label),
                    carried_residual(self.blurred, frame_blurred, field))
        return carried_log_odds(self.log_odds, field), carried_residual(self.blurred, frame_blurred, field)

    def fuse(self, log_odds: np.ndarray, frame_blurred: np.ndarray, field: np.ndarray,
             field_confidence: np.ndarray | None, flow: tuple[np.ndarray, np.ndarray] | None, times: dict) -> Trusted:
        """Naive Bayes' ``log_odds`` with the key frame's prior carried along the dense ``field`` (its
        ``field_confidence``) and along the DIS flow (``flow``: :meth:`carried` along it, or None), each
        trusted per pixel; the times of the parts go into ``times`` (``fuse.warp``, ``fuse.trust``: the
        trust map and the fusion, one pass; ``fuse.confidence``)."""
        t0 = time.perf_counter()
        dense_prior, dense_residual = self.carried(frame_blurred, field)
        t1 = time.perf_counter()
        if self.classes is not None:
            return self._fuse_classes(log_odds, dense_prior, dense_residual, field_confidence, flow, times, t0, t1)
        maps, prior, fused = trusted_fusion(self.rule, self.weight, log_odds, dense_prior, dense_residual,
                                            field_confidence, flow)
        t2 = time.perf_counter()
        labels, confidence = read_labels(fused, log_odds, prior, self.rule, size=self.size)
        times.update({"fuse.warp": t1 - t0, "fuse.trust": t2 - t1, "fuse.confidence": time.perf_counter() - t2})
        return Trusted(labels, confidence, maps, fused, prior)

    def _fuse_classes(self, scores, dense_prior, dense_residual, field_confidence, flow, times, t0, t1) -> Trusted:
        """:meth:`fuse` with K classes (:mod:`pcreg.pipeline.multiclass`): the same trust maps, the priors'
        evidence per class, the label the best class of the blurred sum."""
        from .multiclass import fused_and_marked, read_class_labels, weight_sum

        read = self.classes
        if self._scratch is None:
            self._scratch = Scratch()
        assert read is not None  # fuse sends K classes here only
        second_prior, second_residual = (None, None) if flow is None else flow
        maps = trust_maps(self.rule, weight=self.weight, primary_prior=dense_prior, primary_residual=dense_residual,
                          confidence=field_confidence, second_prior=second_prior, second_residual=second_residual)
        w = weight_sum(maps)
        fused, prior, marks = fused_and_marked(scores, [(maps.primary, maps.primary_prior),
                                                        (maps.second, maps.second_prior)], w, read.log_pi)
        maps = replace(maps, term=prior)
        t2 = time.perf_counter()
        labels, confidence, second = read_class_labels(
            fused, scores, prior, read.classes, smooth_px=_scaled(self.rule.smooth, fused.shape[1]),
            coefficients=read.coefficients, size=self.size, window=(w, read.log_pi), marks=marks, scratch=self._scratch)
        times.update({"fuse.warp": t1 - t0, "fuse.trust": t2 - t1, "fuse.confidence": time.perf_counter() - t2})
        return Trusted(labels, confidence, maps, fused, prior, second)


def trusted_fusion(rule: TrustRule, weight: float, log_odds: np.ndarray, dense_prior: np.ndarray,
                   dense_residual: np.ndarray, confidence: np.ndarray | None,
                   flow: tuple[np.ndarray, np.ndarray] | None) -> tuple[TrustMaps, np.ndarray, np.ndarray]:
    """``(maps, prior term, fused log-odds)`` in one pass over the pixels: :func:`trust_maps`,
    :meth:`TrustMaps.prior_term` and :func:`fused_log_odds`, the same float32
    operations pixel by pixel (an exponential may differ in its last bit from numpy's). ``flow``: the
    DIS prior and its residual, or None. The rows are split with the helper thread on large frames."""
    d = np.ascontiguousarray(log_odds, dtype=np.float32)
    h, w = d.shape
    ld, rd = (np.ascontiguousarray(a, dtype=np.float32) for a in (dense_prior, dense_residual))
    c = None if confidence is None else np.ascontiguousarray(confidence, np.float32)
    lf, rf = (None, None) if flow is None else (np.ascontiguousarray(a, np.float32) for a in flow)
    wd, wf = np.empty((h, w), np.float32), None if flow is None else np.empty((h, w), np.float32)
    prior, fused = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    _fuse(d, (ld, None, rd, c, lf, rf), (weight * rule.dense, weight * rule.flow, -1.0 / rule.residual, 0.0),
          (wd, wf, prior, fused, None))
    return TrustMaps(wd, ld, wf, lf, rd, rf, c), prior, fused


def fused_labels_kernel(log_odds: np.ndarray, q: np.ndarray, confidence: np.ndarray, *, weight: float,
                        pi: float) -> np.ndarray:
    """(H, W) uint8 labels of :func:`pcreg.pipeline.prior.fused_labels` (float32, C-contiguous, one shape,
    ``pi`` checked): the one fusion kernel of :func:`trusted_fusion` with a uniform trust (no residual, no
    second motion), the prior's log-odds taken from the probability ``q`` as it goes, and only the labels kept."""
    labels = np.empty(log_odds.shape, np.uint8)
    _fuse(log_odds, (q, q, None, confidence, None, None), (weight, 0.0, 0.0, np.log(pi / (1.0 - pi))),
          (_UNUSED, None, _UNUSED, _UNUSED, labels))
    return labels


#: What stands for a map the kernel keeps in one compilation and not in another (never written).
_UNUSED = np.zeros((1, 1), np.float32)


def _fuse(d: np.ndarray, inputs: tuple, constants: tuple, outputs: tuple) -> None:
    """Run the one fusion kernel (:func:`_fusion_rows_py`) over every row, split with the helper thread on
    large frames (:mod:`pcreg._threads`). ``inputs``: (first prior's log-odds, or its probability; its
    residual; the field's confidence; the second prior's log-odds; its residual), None where absent;
    ``constants``: (first weight, second weight, the residual's scale, the class prior's logit);
    ``outputs``: (first weight map, second weight map, prior term, fused log-odds, labels), None where not
    kept. A None is known when the kernel is compiled (numba prunes the branch that an ``is None`` of a
    None argument rules out): each combination is compiled once, without the branches it does not take."""
    from .._threads import MIN_PIXELS, interleave

    lo, hi = CONFIDENCE_SPAN
    k1, k2, scale, logit_pi = (np.float32(v) for v in constants)
    consts = (k1, k2, np.float32(lo), np.float32(hi - lo), scale, logit_pi, np.float32(UNKNOWN_CONFIDENCE))
    interleave(d.size, lambda first, stride: _fusion_rows(d, *inputs, *consts, *outputs, first, stride),
               min_items=MIN_PIXELS)


#: Rows per block of :func:`_fusion_rows_py` (two threads take alternate blocks).
FUSION_BLOCK_ROWS = 16


def _fusion_rows_py(d, ld, q, rd, conf, lf, rf, kd, kf, lo, span, scale, logit_pi, unknown, wd, wf, prior, fused,
                    labels, first, stride):
    """Rows of blocks ``first``, ``first + stride``, ... of the one fusion: naive Bayes' log-odds ``d`` plus
    each carried prior's log-odds times its weight per pixel, in the order of :func:`trust_maps`
    (``kd * (lo + span * c) * exp(scale r)``, 0 where ``r`` is :data:`OUTSIDE`; the second motion's
    ``kf * exp(scale r)``), :meth:`TrustMaps.prior_term` (the first motion's term first) and the sum.

    Without residuals (``rd`` None) the trust is uniform (1); without a confidence map ``c`` is
    ``unknown``; the first prior is log-odds ``ld`` (``q`` None), or the probability ``q``, whose log-odds
    against ``logit_pi`` are taken here, once per run of equal values along a row (the warped prior is
    flat inside labelled regions: 13-28% of the pixels of streamed frames need the logarithm). Without
    ``labels`` the maps are written (``wf`` with a second motion), with it only the labels (``fused > 0``).
    Each test is ``X is None`` of an argument, so that numba drops the branch a None rules out."""
    h, w = d.shape
    zero, one = np.float32(0.0), np.float32(1.0)
    qlo, qhi = np.float32(1e-6), np.float32(1.0 - 1e-6)
    outside = np.float32(OUTSIDE)
    for b in range(first * FUSION_BLOCK_ROWS, h, stride * FUSION_BLOCK_ROWS):
        for i in range(b, min(b + FUSION_BLOCK_ROWS, h)):
            last = np.float32(np.nan)  # no pixel's clipped prior equals it
            l1 = zero
            for j in range(w):
                if conf is None:
                    c = unknown
                else:
                    c = conf[i, j]
                    c = zero if c != c else min(max(c, zero), one)  # NaN: no evidence
                if rd is None:
                    t = one
                else:
                    r = rd[i, j]
                    t = np.float32(np.exp(r * scale)) if r < outside else zero
                a = kd * (lo + span * c) * t
                if q is None:
                    l1 = ld[i, j]
                else:
                    qc = min(max(q[i, j], qlo), qhi)
                    if qc != last:  # the logarithm again only where the prior changes along the row
                        l1 = np.float32(np.log(qc / (one - qc))) - logit_pi
                        last = qc
                p = zero + a * l1
                if lf is None:
                    pass
                else:
                    r = rf[i, j]
                    t = np.float32(np.exp(r * scale)) if r < outside else zero
                    a2 = kf * t
                    wf[i, j] = a2
                    p = p + a2 * lf[i, j]
                f = d[i, j] + p
                if labels is None:
                    wd[i, j] = a
                    prior[i, j] = p
                    fused[i, j] = f
                else:
                    labels[i, j] = 1 if f > zero else 0

from .._jit import njit as _njit  # noqa: E402 - the kernel's compiler, after the pure-Python kernel it compiles

_fusion_rows = _njit(cache=True, nogil=True)(_fusion_rows_py)
