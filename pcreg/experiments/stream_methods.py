"""The methods a stream evaluation scores (:data:`METHODS`), each a labeller with ``reset(image, labels)``
and ``step(image)`` (:func:`make_method`), and how their labels' confidence is scored
(:func:`calibration`): shared by the evaluation from one key frame (:mod:`pcreg.experiments.stream`) and from
several (:mod:`pcreg.experiments.stream_keys`), and by the sweeps in ``tools/``."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from .._progress import unit_step

__all__ = ["METHODS", "PCREG_METHODS", "OBJECT_METHOD", "BASELINES", "PRESET_OF", "CONFIDENCE_LEVELS", "calibration_counts",
           "calibration", "confidence_method", "calibration_stamp", "KeyPrior", "FixedPrior", "make_method", "Timed", "counted", "kernels_ready"]

#: Methods scored per frame, in table order.
METHODS: tuple[str, ...] = ("plain", "unregistered", "pcreg", "pcreg_half", "pcreg_flow", "dense_key", "dense_previous",
                            "similarity_key", "similarity_previous", "flow_key", "flow_previous", "flowfast_key",
                            "flowultrafast_key", "pcreg_object")
#: The ``pcreg`` methods: what ``pcreg run`` does with these options.
PCREG_METHODS: dict[str, dict] = {"pcreg": {}, "pcreg_half": {"scale": 0.5}, "pcreg_flow": {"model": "flow", "scale": 0.5}}
#: What ``pcreg run --follow object`` does: one moving object followed from the key frame's mask
#: (:class:`pcreg.pipeline.follow.ObjectFollower`).
OBJECT_METHOD = "pcreg_object"
#: The DIS baselines, and the preset of each (``flow``: medium).
BASELINES: tuple[str, ...] = ("flow_key", "flow_previous", "flowfast_key", "flowultrafast_key")
PRESET_OF: dict[str, str] = {"flow": "medium", "flowfast": "fast", "flowultrafast": "ultrafast"}


def _propagator(method: str, classifier, backend: str):
    """``pcreg``: the propagator as ``pcreg run`` makes it; the other models and anchors as ablations of
    the motion alone: the prior at the one weight, by the field's confidence (no trust rule, no learning).
    The DIS baselines are the same ablation with DIS's flow at their preset as the motion."""
    from ..pipeline.stream import Propagator

    if method in PCREG_METHODS:
        return Propagator(classifier, backend=backend, **PCREG_METHODS[method])
    model, anchor = method.split("_")
    if method in BASELINES:
        model = f"flow:{PRESET_OF[model]}"
    return Propagator(classifier, model=model, anchor=anchor, backend=backend, trust=None, learning=None)


def confidence_method(methods) -> str | None:
    """The method whose confidence an evaluation calibrates: ``pcreg`` when it runs, else :data:`OBJECT_METHOD`
    (what ``pcreg run --follow object`` writes) when it does; None when neither runs."""
    return next((m for m in ("pcreg", OBJECT_METHOD) if m in methods), None)


def calibration_stamp(methods) -> list | None:
    """What a clip's kept calibration counts must have been made with, for them to be read again (``pcreg evaluate
    stream`` resumed): ``[pcreg_object, slope, offset, *weights, intercept]`` where the follower's confidence is the
    one calibrated (its coefficients, which no option sets, may change between versions); None otherwise (nothing to
    check)."""
    if confidence_method(methods) != OBJECT_METHOD:
        return None
    from ..pipeline.follow_confidence import CONFIDENCE_INTERCEPT, CONFIDENCE_OFFSET, CONFIDENCE_SLOPE, CONFIDENCE_WEIGHTS

    return [OBJECT_METHOD, CONFIDENCE_SLOPE, CONFIDENCE_OFFSET, *CONFIDENCE_WEIGHTS, CONFIDENCE_INTERCEPT]


#: Levels of the confidence histograms (:func:`calibration_counts`): the 8-bit steps of a confidence PNG.
CONFIDENCE_LEVELS = 256


def calibration_counts(confidence: np.ndarray, labels: np.ndarray, truth: np.ndarray, unknown: int = 2) -> np.ndarray:
    """(2, 256) int64: over the known pixels (truth not ``unknown``, the class table's unknown id), how many
    labels were right (row 0) and wrong (row 1) at each 8-bit level of their confidence
    (``round(255 * confidence)``; a confidence NaN or outside [0, 1] is an :class:`~pcreg.errors.InputError`)."""
    from ..classification.metrics import check_confidence

    known = truth != unknown
    level = np.rint(check_confidence(confidence, np.shape(truth))[known] * (CONFIDENCE_LEVELS - 1)).astype(np.intp)
    wrong = labels[known] != truth[known]
    return np.stack([np.bincount(level[~wrong], minlength=CONFIDENCE_LEVELS),
                     np.bincount(level[wrong], minlength=CONFIDENCE_LEVELS)]).astype(np.int64)


def calibration(counts) -> dict:
    """From :func:`calibration_counts` (summed over frames): the expected calibration error over 10 equal
    bins of confidence (``ece``), the error % of all known pixels (``error``) and of the most confident
    80% of them (``error_top80``, the share at the cut-off level taken in proportion), their ratio, and
    the reliability curve (per bin: mean confidence, accuracy, share of pixels)."""
    c = np.asarray(counts, dtype=np.float64)
    right, wrong = c[0], c[1]
    n = right + wrong
    total = n.sum()
    if total == 0:
        return {"pixels": 0}
    conf = np.arange(CONFIDENCE_LEVELS) / (CONFIDENCE_LEVELS - 1)
    bins = np.minimum((conf * 10).astype(int), 9)
    ece, curve = 0.0, []
    for b in range(10):
        m = bins == b
        nb = n[m].sum()
        if nb == 0:
            continue
        mean_conf, acc = float((n[m] * conf[m]).sum() / nb), float(right[m].sum() / nb)
        ece += nb / total * abs(acc - mean_conf)
        curve.append({"bin": b, "confidence": mean_conf, "accuracy": acc, "share": float(nb / total)})
    keep, kept_wrong = 0.8 * total, 0.0
    for level in range(CONFIDENCE_LEVELS - 1, -1, -1):  # most confident first
        if n[level] == 0:
            continue
        take = min(n[level], keep)
        kept_wrong += wrong[level] * take / n[level]
        keep -= take
        if keep <= 0:
            break
    error, top = 100.0 * wrong.sum() / total, 100.0 * kept_wrong / (0.8 * total)
    return {"pixels": int(total), "ece": float(ece), "error": float(error), "error_top80": float(top),
            "top80_ratio": float(top / error) if error else float("nan"), "curve": curve}


class KeyPrior:
    """What the baselines share: the key frame's prior, fused with each frame's naive Bayes log-odds."""

    def __init__(self, classifier, *, weight: float) -> None:
        from ..classification.fusion import FusionConfig
        from ..pipeline.prior import class_prior

        self.classifier, self.weight, self.fusion = classifier, weight, FusionConfig()
        self._pi = class_prior(classifier)

    def reset(self, image: np.ndarray, labels: np.ndarray) -> None:
        from ..classification.fusion import label_prior, prior_log_odds

        self._prior = label_prior(labels, pi=self._pi, fusion=self.fusion)
        self._key_log_odds = prior_log_odds(self._prior, pi=self._pi)

    def fused(self, image: np.ndarray, motion) -> np.ndarray:
        """The frame's fused log-odds with the key frame's prior carried by ``motion`` (None: not moved)."""
        from ..classification.fusion import fuse
        from ..pipeline.pair import log_odds
        from ..pipeline.prior import warped_prior_log_odds

        d = log_odds(self.classifier, image)
        if motion is None:
            l_prior = self._key_log_odds
        else:
            l_prior = warped_prior_log_odds(self._prior, motion, shape=d.shape, pi=self._pi)
        return fuse(d, l_prior, weight=self.weight)

    def _labels(self, image: np.ndarray, motion) -> np.ndarray:
        """The frame's labels, each pixel read alone (:meth:`fused`)."""
        from ..classification.fusion import labels_from_log_odds

        return labels_from_log_odds(self.fused(image, motion))


class FixedPrior(KeyPrior):
    """``plain`` (weight 0) and ``unregistered`` (the key frame's prior, no motion)."""

    def step(self, image: np.ndarray) -> np.ndarray:
        return self._labels(image, None)


def make_method(method: str, classifier, backend: str):
    """A fresh labeller of ``method`` (:data:`METHODS`) with ``reset(image, labels)`` and ``step(image)``."""
    from ..pipeline.stream import STREAM_WEIGHT

    if method == "plain":
        return FixedPrior(classifier, weight=0.0)
    if method == "unregistered":
        return FixedPrior(classifier, weight=STREAM_WEIGHT)
    if method == OBJECT_METHOD:
        from ..pipeline.follow import ObjectFollower

        return ObjectFollower(classifier)
    return _propagator(method, classifier, backend)


class Timed:
    """A labeller whose steps are timed: ``seconds`` adds up the time of each; each is a step of the unit's
    work on the command's bar (:func:`pcreg._progress.unit_step`)."""

    def __init__(self, labeller) -> None:
        self.labeller, self.seconds = labeller, 0.0
        kernels_ready()

    def step(self, image: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        labels = self.labeller.step(image)
        self.seconds += time.perf_counter() - t0
        unit_step()
        return labels


_READY: list[bool] = []


def kernels_ready() -> None:
    """pcreg's compiled kernels compiled, or loaded from the cache, once in this process before a step is timed
    (:func:`pcreg.kernels.warm_up`): compiled within the first clip's steps, they read 1,819 ms a frame against
    16.6 for the same clip again, and the median over few clips with them (the key-frame and many-class protocols,
    which time :func:`~pcreg.pipeline.keyframes.label_clip` whole, 819 ms against 148-247)."""
    if not _READY:
        from ..kernels import warm_up

        warm_up()
        _READY.append(True)


def counted(keys) -> Callable:
    """:func:`~pcreg.pipeline.keyframes.label_clip`'s ``on_frame``: each frame it labels that is not one of
    ``keys`` is a step of the unit's work on the command's bar (:func:`pcreg._progress.unit_step`)."""
    keys = frozenset(keys)

    def on_frame(frame) -> None:
        if frame.index not in keys:
            unit_step()

    return on_frame
