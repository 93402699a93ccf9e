"""What one step of a stream did: :class:`StepReport` (:meth:`pcreg.Propagator.step`'s, and an object follower's,
:class:`~pcreg.pipeline.follow.ObjectFollower`), in a module of its own so that both read it without reading
each other."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..registration.result import FieldsCompared

if TYPE_CHECKING:
    from .trust import TrustMaps

__all__ = ["PriorTerms", "StepReport"]


class PriorTerms(Protocol):
    """A step's carried priors as a report gives them (:class:`~pcreg.pipeline.trust.TrustMaps`, or an
    object follower's :class:`~pcreg.pipeline.follow.FollowTerms`): their part of the fused log-odds."""

    def prior_term(self, shape: tuple[int, int]) -> np.ndarray: ...


class _Result(Protocol):
    """A registration's result as a report writes it (a matrix's, a dense field's or a flow's)."""

    def to_dict(self) -> dict: ...


@dataclass(frozen=True, eq=False)
class StepReport(FieldsCompared):
    """What one :meth:`~pcreg.pipeline.stream.Propagator.step` did.

    frame : steps since the last :meth:`~Propagator.reset` (1 for the first step).
    registration : the registration result (``T_ref_mov``, a dense result with its field, or with
        ``model="flow"`` a :class:`~pcreg.registration.flow.FlowResult`), or None when it failed. reason : why it failed (None when it did not).
    fallback : True when the key frame's labels were fused unwarped (the registration failed).
    reference : the frame (counted like ``frame``, 0 = the key frame) the new frame was registered to.
    start : how the dense registration started: ``"cold"`` (from the identity), ``"warm"`` (from the
        previous step's grid) or ``"restarted"`` (warm, then cold again by the restart rule; the
        registration kept is the one with more evidence), also when the registration then failed;
        None for a global model and a flow.
    times : seconds per stage (:data:`STEP_STAGES`), and per part of a stage (:data:`STEP_PARTS`, keys
        such as ``"register.search"``); ``fuse`` includes warping the prior.
    confidence : (H, W) float32 in [0, 1], the probability that each label is right
        (:func:`pcreg.pipeline.trust.label_confidence`), or None without a trust rule.
    predicted_error : the frame's predicted error in percent, the mean of 1 - ``confidence`` (None
        without a trust rule).
    trust : the step's trust map (:class:`~pcreg.pipeline.trust.TrustMaps`: each carried prior, its
        evidence and its weight per pixel; an object follower's: its carried terms,
        :class:`~pcreg.pipeline.follow.FollowTerms`), None without a trust rule; ``to_dict`` gives its summary
        (``trust``: each prior's mean weight as a share of the most the rule gives it; ``cut``, the cut test's
        finding, :mod:`pcreg.pipeline.cuts`; ``degenerate``, the classifier's classes fitted as spikes).
    log_odds : (H, W) float32 naive Bayes' own log-odds of the frame (the classifier as learned so
        far); ``log_odds > 0`` are its labels alone, and ``log_odds`` plus the trust map's
        :meth:`~pcreg.pipeline.trust.TrustMaps.prior_term` the fused log-odds. With more than two classes
        (H, W, K) float32 class scores (:meth:`~pcreg.classification.bayes.NaiveBayesPixelClassifier.class_scores`).
    predicted_iou : (a property) with a trust rule or an object follower, each class's predicted IoU from the
        confidence (:func:`~pcreg.pipeline.trust.class_predicted_iou`), by class id, for the classes the labels
        hold; else None.
    """

    frame: int
    registration: _Result | None
    reason: str | None
    fallback: bool
    reference: int
    times: dict = field(default_factory=dict)
    start: str | None = None
    confidence: np.ndarray | None = field(default=None, repr=False)
    predicted_error: float | None = None
    trust: "TrustMaps | PriorTerms | None" = field(default=None, repr=False)
    trust_summary: dict | None = None
    log_odds: np.ndarray | None = field(default=None, repr=False)

    def __hash__(self) -> int:
        return hash((self.frame, self.reference, self.fallback))

    @property
    def registered(self) -> bool:
        return self.registration is not None

    @property
    def cut(self) -> bool:
        """Whether the step's cut test found the frame outside its key frame's scene (:mod:`pcreg.pipeline.cuts`)."""
        return bool((self.trust_summary or {}).get("cut", False))

    @property
    def predicted_iou(self) -> dict | None:
        return None if self.trust_summary is None else self.trust_summary.get("predicted_iou")

    def to_dict(self) -> dict:
        return {"frame": self.frame, "registered": self.registered, "reason": self.reason,
                "fallback": self.fallback, "reference": self.reference, "start": self.start,
                "predicted_error": self.predicted_error,
                "trust": None if self.trust_summary is None else {k: v for k, v in self.trust_summary.items()
                                                                  if k != "predicted_iou"},
                "registration": None if self.registration is None else self.registration.to_dict(),
                "times": {k: float(v) for k, v in self.times.items()},
                **({} if self.predicted_iou is None else {"predicted_iou": {str(k): v for k, v in
                                                                            self.predicted_iou.items()}})}
