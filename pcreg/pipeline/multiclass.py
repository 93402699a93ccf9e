"""The stream's step with more than two classes: the two-class rule, class by class.

A two-class stream fuses log-odds (:mod:`pcreg.pipeline.trust`). With K classes every quantity becomes
a vector of K per pixel, and every rule of the two-class step is kept as it is stated:

- naive Bayes gives each class's joint log-likelihood ``d_k`` (:meth:`~pcreg.classification.bayes.
  NaiveBayesPixelClassifier.class_scores`), where two classes gave ``d_1 - d_0``;
- the key frame's prior is its one-hot labels blurred and mixed with the class prior ``pi`` exactly as
  :func:`~pcreg.classification.fusion.label_prior` does for one class (:func:`class_prior_maps`), and its
  evidence beyond the class prior is ``l_k = log q_k - log pi_k`` (:func:`prior_log_probs`; two classes:
  ``l_1 - l_0`` is :func:`~pcreg.classification.fusion.prior_log_odds`);
- each carried prior is trusted per pixel by the same weight maps (:func:`~pcreg.pipeline.trust.trust_maps`:
  they do not depend on the classes), so ``S_k = d_k + w_primary l_primary,k + w_second l_second,k``;
- the label is the class of the largest ``S_k`` blurred (:func:`read_class_labels`; two classes: the
  sign of ``S_1 - S_0`` blurred, as the blur is linear);
- the confidence reads the same four features, with the margin between the two best classes in place of
  ``|F|`` (at two classes the same number), the purity of each label's neighbourhood, and the share of
  the neighbourhood where naive Bayes' best class is the carried prior's; and two more, the mean of
  log1p(margin) over the pixel's connected piece of its label, alone and times the pixel's own.

Memory and time grow with K: the scores, the carried priors and their blur are (H, W, K) float32 maps,
4 K bytes a pixel each. docs/results.md ("Many classes") gives the measured figures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..classification.fusion import FusionConfig
from ..errors import InputError
from ._class_kernels import (best_agreement, carried_best, class_window, fuse_and_mark, fuse_classes,
                             iou_sums, log_margins, logistic_confidence, penalised, purities, remap_classes, remap_labels, top_two)
from ._class_regions import region_means
from .readout import AGREEMENT_SIDE, MAX_CHANNELS, PURITY_SIDES, Scratch, channelwise, half, odd

__all__ = ["CLASS_ANCHOR", "CLASS_WEIGHT_SHARE", "CLASS_CONFIDENCE_COEFFICIENTS", "CLASS_MIN_CONFIDENCE", "CLASS_PRIOR_SIGMA",
           "CLASS_WINDOW", "CLASS_PENALTY", "ClassRead", "windowed", "weight_sum",
           "fused_class_labels", "class_priors", "class_prior_maps", "prior_log_probs", "carried_log_probs",
           "label_evidence", "fused_scores", "fused_and_marked", "smoothed_scores", "read_class_labels", "class_confidence", "predicted_iou",
           "sure_labels"]

#: The least class prior taken: a class with (almost) no key-frame pixels must not give -inf evidence.
MIN_PROBABILITY = 1e-6
#: With more than two classes the carried priors are weighed at this share of the propagator's ``weight``
#: (naive Bayes' class scores are differences of K joint log-likelihoods, where two classes had one):
#: chosen on the eight shared CamVid clips with each clip left out (docs/results.md, "Many classes").
CLASS_WEIGHT_SHARE = 0.25
#: The confidence's logistic coefficients with more than two classes (intercept, then log1p of the margin
#: between the two best classes, purity at 15 px, purity at 33 px, agreement at 33 px, the mean of log1p of
#: the margin over the pixel's connected piece of its label, that mean times log1p of the margin, and the
#: mean of log1p of the margin over the whole frame): fitted by logistic regression on the eight shared
#: CamVid clips labelled in CamVid's eleven classes, from three key frames and from the first frame alone
#: together (a confidence calibrated whether a run has one key frame or several), and checked with each clip
#: left out (docs/results.md, "Many classes"). The frame's term makes every label of a frame read with small
#: margins overall less sure: the left-out calibration error went from 0.0135 to 0.0061 (three key frames)
#: and from 0.0133 to 0.0085 (the first frame alone).
CLASS_CONFIDENCE_COEFFICIENTS: tuple[float, ...] = (-3.845, -1.043, 0.855, 1.452, 0.666, -0.437, 0.784, 1.2)
#: The least confidence a label gets with many classes (or 1/K, when more): the logistic model's low end
#: over-predicts errors; chosen among 0, 0.2, 0.25, 0.3, 0.35 and 0.4 with each clip left out (0.3 in six
#: folds, 0.25 in two; with the coefficients fitted on all clips 0.3 gives the least calibration error over
#: both protocols' pixels, 0.0086), the order of the pixels by confidence unchanged above it.
CLASS_MIN_CONFIDENCE = 0.3
#: The blur (px at 640 wide, :class:`~pcreg.classification.fusion.FusionConfig`'s ``sigma``) of the key frame's
#: one-hot labels before they become a prior with many classes: none (the two-class prior's 2 px smeared
#: thin classes into their neighbours); chosen with each clip left out (docs/results.md, "Many classes").
CLASS_PRIOR_SIGMA = 0.0
#: The class window (px at :data:`~pcreg.pipeline.readout.BASE_WIDTH`): a class that the carried labels do
#: not show within this square around a pixel, where the carried priors are trusted, has its score lowered by
#: :data:`CLASS_PENALTY` before the label is read (:func:`windowed`): naive Bayes may not invent there a class
#: the key frames do not put near it (a pedestrian in the road's colours). Chosen with each clip left out.
CLASS_WINDOW = 97
#: How far a class outside the window is lowered (nats).
CLASS_PENALTY = 15.0
#: Where a stream with more than two classes registers each frame (:class:`~pcreg.pipeline.stream.Propagator`'s
#: ``anchor``): to the previous frame, the motions composed back to the key frame. At one frame a second the
#: frame-to-frame registrations composed carry the key frame's classes better than one registration across
#: seconds; chosen with each clip left out (docs/results.md, "Many classes").
CLASS_ANCHOR = "previous"
#: Below this summed trust weight the carried priors say nothing, and every class is allowed.
UNTRUSTED = 1e-3


def class_priors(classifier) -> np.ndarray:
    """(K,) float64: a fitted naive Bayes' class priors over its classes (``class_prior_``), each at least
    :data:`MIN_PROBABILITY`."""
    prior = np.asarray(getattr(classifier, "class_prior_", None), dtype=np.float64)
    if prior.ndim != 1 or prior.size < 2 or not np.all(np.isfinite(prior)):
        raise InputError("the classifier must be a fitted naive Bayes with a class prior per class")
    return np.maximum(prior, MIN_PROBABILITY)


def class_prior_maps(labels: np.ndarray, classes: np.ndarray, pi: np.ndarray, *,
                     fusion: FusionConfig = FusionConfig()) -> np.ndarray:
    """(H, W, K) float32: each class's probability from a label map, the one-hot of ``classes`` (ids, in
    the classifier's order) with ``pi`` where the label is none of them (unknown, or a class the key frame
    did not train), blurred by ``fusion.sigma * W / 640`` and mixed with ``pi`` by ``fusion.eps``, as
    :func:`~pcreg.classification.fusion.smooth_prior` does for one class."""
    import cv2

    lab = np.asarray(labels)
    lut = np.tile(np.asarray(pi, np.float32), (256, 1))
    for i, c in enumerate(classes):
        lut[int(c)] = 0.0
        lut[int(c), i] = 1.0
    q = lut[lab.astype(np.uint8, copy=False)]
    s = float(fusion.sigma) * lab.shape[1] / 640.0
    if s > 0:
        q = channelwise(lambda a: cv2.GaussianBlur(a, (0, 0), s, borderType=cv2.BORDER_REPLICATE), q)
    eps = np.float32(fusion.eps)
    return (q * (np.float32(1.0) - eps) + eps * np.asarray(pi, np.float32)).astype(np.float32)


def prior_log_probs(q: np.ndarray, pi: np.ndarray) -> np.ndarray:
    """(H, W, K) float32 ``log q_k - log pi_k``: the evidence of the prior beyond the class prior."""
    qq = np.clip(np.asarray(q, np.float32), np.float32(MIN_PROBABILITY), np.float32(1.0))
    return (np.log(qq) - np.log(np.asarray(pi, np.float32))).astype(np.float32)


def carried_log_probs(log_probs: np.ndarray, field: np.ndarray, *, labels=None) -> np.ndarray:
    """(H, W, K) float32: the key frame's prior evidence carried along ``field`` (bilinear), 0 (none
    beyond the class prior) where the field leaves the key frame; each channel as
    :func:`~pcreg.pipeline.trust.carried_log_odds` (OpenCV's ``remap``, to the bit: :func:`~pcreg.pipeline.
    _class_kernels.remap_classes`). ``labels``: :func:`label_evidence` of ``log_probs``, when it is one
    vector per label: the same numbers, read from the labels (a byte a pixel, not 4 K)."""
    if labels is not None:
        return remap_labels(labels[0], labels[1], field)
    return remap_classes(log_probs, field)


def label_evidence(labels: np.ndarray, log_probs: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(labels, table)`` when ``log_probs`` (H, W, K) is ``table[labels]``, one vector per label value
    (the evidence of unblurred one-hot labels, :data:`CLASS_PRIOR_SIGMA` 0), checked value for value;
    ``labels`` (H, W) uint8, ``table`` (256, K) float32. None when it is not, or for 1, 3 or 4 classes (which
    :func:`carried_log_probs` carries through OpenCV's own ``remap``)."""
    lab = np.ascontiguousarray(labels, np.uint8)
    lp = np.asarray(log_probs, np.float32)
    if lp.ndim != 3 or lab.shape != lp.shape[:2] or lp.shape[2] in (1, 3, 4):
        return None
    k = lp.shape[2]
    values, first = np.unique(lab.ravel(), return_index=True)
    table = np.zeros((256, k), np.float32)
    table[values] = lp.reshape(-1, k)[first]
    return (lab, table) if np.array_equal(table[lab], lp) else None


def _prior_pairs(d: np.ndarray, weighted: list) -> tuple | None:
    """The first two ``(weight, evidence)`` pairs of ``weighted`` with both, each weight an (H, W) float32 map
    (a number broadcast), the second ``(None, None)`` when there is one; None when there is none."""
    pairs = [(np.broadcast_to(np.asarray(w, np.float32), d.shape[:2]), lp) for w, lp in weighted
             if w is not None and lp is not None]
    if not pairs:
        return None
    return pairs[0], (pairs[1] if len(pairs) > 1 else (None, None))


def fused_scores(scores: np.ndarray, weighted: list[tuple[np.ndarray | float | None, np.ndarray | None]]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(fused, prior_term)``, (H, W, K) float32 each: naive Bayes' class scores plus each prior's
    evidence times its weight (a (H, W) map or a number; a pair with a None is left out)."""
    d = np.asarray(scores, np.float32)
    pairs = _prior_pairs(d, weighted)
    if pairs is None:
        return d.copy(), np.zeros(d.shape, np.float32)
    (w1, l1), (w2, l2) = pairs
    return fuse_classes(d, w1, l1, w2, l2)


def fused_and_marked(scores: np.ndarray, weighted: list, weight_sum: np.ndarray, log_pi: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """``(fused, prior_term, marks)``: :func:`fused_scores`, and in the same pass (one read of the maps) the
    ``marks`` :func:`read_class_labels` reads of them: the carried label's class index (H, W) uint8 whose
    window :func:`windowed` takes (``weight_sum``, ``log_pi`` as it takes them) and the agreement (H, W)
    float32 of naive Bayes' best class with the priors' that :func:`class_confidence` averages."""
    d = np.asarray(scores, np.float32)
    pairs = _prior_pairs(d, weighted)
    if pairs is None:
        fused, prior = fused_scores(d, weighted)
        return fused, prior, (carried_best(prior, weight_sum, log_pi), best_agreement(d, prior))
    (w1, l1), (w2, l2) = pairs
    fused, prior, carried, agree = fuse_and_mark(d, w1, l1, w2, l2, weight_sum, log_pi)
    return fused, prior, (carried, agree)


def smoothed_scores(fused: np.ndarray, sigma_px: float, *, scratch: Scratch | None = None) -> np.ndarray:
    """(H, W, K) float32: class scores blurred, each class by a Gaussian of ``sigma_px`` px (itself at 0).
    ``scratch``: where the blurred scores are kept between calls (read them before the next call)."""
    import cv2

    S = np.ascontiguousarray(fused, dtype=np.float32)
    if sigma_px <= 0:
        return S
    if scratch is not None and S.shape[2] <= MAX_CHANNELS:  # into the kept array (OpenCV's dst: the same blur)
        out = scratch.array("smoothed", S.shape, np.float32)
        return cv2.GaussianBlur(S, (0, 0), sigma_px, dst=out).reshape(S.shape)
    return channelwise(lambda a: cv2.GaussianBlur(a, (0, 0), sigma_px), S)


@dataclass(frozen=True, eq=False)
class ClassRead:
    """What the many-class read-out needs of a stream: the class ids in the order of the scores' channels,
    the log class priors, and the confidence's coefficients."""

    classes: np.ndarray
    log_pi: np.ndarray
    coefficients: tuple[float, ...] = CLASS_CONFIDENCE_COEFFICIENTS


def weight_sum(maps) -> np.ndarray:
    """(H, W) float32: the carried priors' summed trust weight of a
    :class:`~pcreg.pipeline.trust.TrustMaps` (the primary motion's and the second's)."""
    w = np.asarray(maps.primary, np.float32)
    return w if maps.second is None else w + maps.second


def windowed(fused: np.ndarray, prior_term: np.ndarray, weight_sum: np.ndarray, log_pi: np.ndarray, *,
             carried: np.ndarray | None = None, scratch: Scratch | None = None) -> np.ndarray:
    """(H, W, K) float32: ``fused`` with every class that the carried labels do not show within
    :data:`CLASS_WINDOW` of a pixel lowered by :data:`CLASS_PENALTY`. The carried label is the best class of
    the priors' evidence per unit of trust plus the class prior (``prior_term / weight_sum + log_pi``: the
    carried priors' own log-probabilities); where ``weight_sum`` is below :data:`UNTRUSTED` every class is
    allowed. ``carried``: the carried label's class index (H, W), when the fusion made it
    (:func:`fused_and_marked`). The classes within the window are found as bits
    (:func:`~pcreg.pipeline._class_kernels.class_window`), in two running passes in place of one dilation a class.
    ``scratch``: a :class:`~pcreg.pipeline.readout.Scratch` whose arrays the bits and the result are
    written into (read the result before the next call with it)."""
    w = np.asarray(weight_sum, np.float32)
    if carried is None:
        carried = carried_best(prior_term, w, log_pi)
    allowed = class_window(carried, fused.shape[2], odd(CLASS_WINDOW, fused.shape[1]), scratch=scratch)
    return penalised(fused, allowed, w, UNTRUSTED, CLASS_PENALTY, scratch=scratch)


def read_class_labels(fused: np.ndarray, scores: np.ndarray, prior_term: np.ndarray, classes: np.ndarray, *,
                      smooth_px: float, coefficients: tuple[float, ...], size=None, window=None, marks=None,
                      scratch: Scratch | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(labels, confidence, runner_up)`` of fused class scores (H, W, K): the class ids (``classes`` in the
    classifier's order) of the largest score blurred by a Gaussian of ``smooth_px`` px, the probability
    that each is right (:func:`class_confidence`), and the second likeliest class's id. ``size``: the
    stream's :class:`~pcreg.pipeline.working.WorkingSize` when the maps are at it: the blurred scores and
    the confidence are brought to the frames' size, and the labels read there. ``window``: ``(weight_sum,
    log_pi)``, the carried priors' summed trust weight (H, W) and the log class priors: the scores are
    :func:`windowed` first. ``marks``: ``(carried, agree)`` when the fusion made them (:func:`fused_and_marked`).
    ``scratch``: a stream's :class:`~pcreg.pipeline.readout.Scratch`, where the windowed and blurred
    scores are written (kept from one step to the next, not made anew; none of them is returned)."""
    carried, agree = (None, None) if marks is None else marks
    if window is not None:
        fused = windowed(fused, prior_term, *window, carried=carried, scratch=scratch)
    S = smoothed_scores(fused, smooth_px, scratch=scratch)
    best, second, margin = top_two(S)
    conf = class_confidence(margin, best, scores, prior_term, coefficients, agree=agree)
    if size is not None and size.scaled:
        best, second, _ = top_two(size.grow(S))
        conf = size.grow(conf)
    ids = np.asarray(classes, np.uint8)
    return ids[best], conf, ids[second]


def _neighbourhood_features(best: np.ndarray, k: int, scores: np.ndarray, prior_term: np.ndarray,
                            agree: np.ndarray | None, log_margin: np.ndarray) -> list[np.ndarray]:
    """The confidence's neighbourhood features at half size, as :func:`pcreg.pipeline.trust.confidence_features`
    reads them for two classes: the share of the neighbourhood with the pixel's own label at the two purity
    sides and the share of the agreement side where naive Bayes' best class is the carried prior's; then the
    mean of ``log_margin`` (log1p(margin), (H, W)) over the pixel's connected piece of its label
    (:func:`~pcreg.pipeline._class_regions.region_means`)."""
    import cv2

    w = best.shape[1]
    own, shares = purities(best, k, tuple(odd(side / 2, w) for side in PURITY_SIDES))  # at half size
    if agree is None:
        agree = best_agreement(scores, prior_term)
    out = list(shares)
    kk = odd(AGREEMENT_SIDE / 2, w)
    out.append(cv2.blur(half(agree), (kk, kk), borderType=cv2.BORDER_REFLECT))
    out.append(region_means(own, half(log_margin)))
    return out


def class_confidence(margin: np.ndarray, best: np.ndarray, scores: np.ndarray, prior_term: np.ndarray,
                     coefficients: tuple[float, ...], *, agree: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float32 in [max(1/K, :data:`CLASS_MIN_CONFIDENCE`), 1]: the probability that each pixel's label
    is right, the logistic model of :func:`pcreg.pipeline.trust.label_confidence` over log1p(margin), the
    purities, the agreement, the mean of log1p(margin) over the pixel's connected piece of its label (``r``:
    a whole piece read with small margins is a piece the motion or the colours may have got wrong) and ``r``
    times log1p(margin), and the mean of log1p(margin) over the whole frame (a frame read with small margins
    overall is less sure everywhere), with ``coefficients`` (intercept first), never below 1/K (the label is the likeliest
    of K classes) nor :data:`CLASS_MIN_CONFIDENCE`. ``agree``: :func:`~pcreg.pipeline._class_kernels.
    best_agreement` of ``scores`` and ``prior_term``, when the fusion made it."""
    import cv2

    if len(coefficients) != 8:
        raise InputError(f"the confidence takes 8 coefficients, got {len(coefficients)}")
    k = scores.shape[2]
    h, w = margin.shape
    log_margin = log_margins(margin)
    features = _neighbourhood_features(best, k, scores, prior_term, agree, log_margin)
    linear = np.zeros(features[0].shape, np.float32)
    for a, m in zip(coefficients[2:6], features):
        linear += np.float32(a) * m
    z = cv2.resize(linear, (w, h), interpolation=cv2.INTER_LINEAR)
    piece = cv2.resize(features[3], (w, h), interpolation=cv2.INTER_LINEAR)
    frame = float(np.mean(log_margin, dtype=np.float64))  # the frame's term, one number: into the intercept
    conf = logistic_confidence(z, log_margin, coefficients[1], coefficients[0] + coefficients[7] * frame,
                               max(1.0 / k, CLASS_MIN_CONFIDENCE), piece=piece, c=coefficients[6])
    if not np.all(np.isfinite(conf)):
        raise AssertionError("a confidence came out NaN")
    return conf


def predicted_iou(labels: np.ndarray, confidence: np.ndarray, second: np.ndarray, classes=None) -> dict[int, float]:
    """Each class's predicted IoU from the confidence alone: a label of class k is right with probability
    ``c``, so k's expected true positives are the sum of ``c`` over its pixels and its false positives
    the sum of ``1 - c``; a wrong label's truth is taken to be its runner-up (``second``), so k's expected
    misses are the sum of ``1 - c`` over the pixels whose runner-up is k. Of ``classes`` (None: those the labels
    hold), those with no pixel and no miss are left out. ``labels``, ``confidence`` (in [0, 1]) and ``second`` of
    one shape, else an :class:`~pcreg.errors.InputError`."""
    from ..classification.metrics import check_confidence

    lab, sec = np.asarray(labels), np.asarray(second)
    if lab.shape != sec.shape:
        raise InputError(f"the runner-up classes {sec.shape} and the labels {lab.shape} differ in shape")
    tp, fp, fn = iou_sums(lab, check_confidence(confidence, lab.shape), sec)
    out = {}
    for k in np.flatnonzero(tp + fp) if classes is None else classes:  # tp + fp: each class's count of pixels
        denom = tp[k] + fp[k] + fn[k]
        if denom > 0:
            out[int(k)] = float(tp[k] / denom)
    return out


def sure_labels(fused: np.ndarray, prior_term: np.ndarray, classes: np.ndarray, unknown: int, *,
                sure: float) -> np.ndarray:
    """(H, W) uint8: the fused label where the carried priors are sure of it (their margin between the two
    best classes beyond ``sure`` and their best class the fused one), ``unknown`` elsewhere: what naive
    Bayes learns from a frame (:class:`~pcreg.pipeline.learning.Learner`; two classes: ``|P| > sure`` and
    the signs agree)."""
    best_f = np.argmax(fused, axis=2)
    best_p, _, margin = top_two(np.asarray(prior_term, np.float32))
    ok = (margin > np.float32(sure)) & (best_p == best_f)
    ids = np.asarray(classes, np.uint8)
    return np.where(ok, ids[best_f], np.uint8(unknown)).astype(np.uint8)


def fused_class_labels(scores: np.ndarray, evidence: np.ndarray, motion, pixel_weight, weight: float,
                       classes: np.ndarray, size, times: dict) -> np.ndarray:
    """(H, W) uint8 class ids without a trust rule: the key frame's ``evidence`` per class (at the working
    size) carried along ``motion`` (unmoved when None), at ``weight`` by the field's confidence
    (``pixel_weight``: :func:`~pcreg.pipeline.prior.pixel_weight`, given by the caller: ``prior`` reads
    :mod:`~pcreg.pipeline.trust`, which reads this module), added to the class scores; the best class,
    read at the frames' size when ``size`` (a :class:`~pcreg.pipeline.working.WorkingSize`) is scaled. The
    times of the parts go into ``times`` (``fuse.warp``, ``fuse.fusion``)."""
    import time

    t0 = time.perf_counter()
    h, w = scores.shape[:2]
    lp = evidence if motion is None else carried_log_probs(evidence, motion.as_field((h, w)))
    t1 = time.perf_counter()
    wt = pixel_weight(weight, None if motion is None else motion.confidence)
    fused = scores + (np.asarray(wt, np.float32)[..., None] if np.ndim(wt) else np.float32(wt)) * lp
    if size is not None and size.scaled:
        fused = size.grow(fused)
    labels = np.asarray(classes, np.uint8)[np.argmax(fused, axis=2)]
    times.update({"fuse.warp": t1 - t0, "fuse.fusion": time.perf_counter() - t1})
    return labels
