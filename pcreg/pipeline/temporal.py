"""The temporal filter: a chain of frames, each fused with the label state of the one before."""

from __future__ import annotations

import numpy as np

from ..classification.fusion import FusionConfig, fuse, label_prior, labels_from_log_odds
from ..registration.motion import Motion
from .prior import warped_prior_log_odds

__all__ = ["registration_supported", "temporal_update", "TemporalFusion"]


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


def temporal_update(log_odds_moving: np.ndarray, labels_reference: np.ndarray, motion: Motion | None, *,
                    pi: float, weight: float, fusion: FusionConfig = FusionConfig(),
                    trust: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One step of the temporal filter.

    log_odds_moving : (H, W) float32 naive Bayes log-odds of the new frame. labels_reference : (H, W)
    uint8 labels the chain holds for the previous frame (true labels at the chain's start, then its
    own fused labels; 2 where it knows nothing). motion : previous -> new registration, a
    :class:`~pcreg.registration.motion.Motion` or what :meth:`~pcreg.registration.motion.Motion.of` takes
    (None: no prior). trust : (H, W) factors in [0, 1] on the prior's weight (and on the judging
    weight), the stream's trust in the carried labels (:func:`pcreg.pipeline.trust.residual_trust`);
    None: 1 everywhere. Returns ``(fused log-odds (H, W) float32, labels (H, W) uint8)``:
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
    A failed registration (``motion`` None) ends the chain's labels: the frame falls back to plain
    naive Bayes, and so does the rest of the chain; so does a registration that the new frame's
    evidence does not support (:func:`registration_supported`): a poor registration is not carried on.
    """
    d = np.asarray(log_odds_moving, dtype=np.float32)
    if motion is None:
        return d.copy(), np.full(d.shape, 2, np.uint8)
    from ..registration.warp import warp_to_moving

    labels_reference = np.asarray(labels_reference, dtype=np.uint8)
    reached, _ = warp_to_moving(labels_reference, motion, shape=d.shape, interpolation="nearest", fill=2)
    if not registration_supported(reached, labels_reference, d):
        return d.copy(), np.full(d.shape, 2, np.uint8)
    l_prior = warped_prior_log_odds(label_prior(labels_reference, pi=pi, fusion=fusion), motion,
                                    shape=d.shape, pi=pi)
    if trust is not None:
        l_prior = (l_prior * np.asarray(trust, np.float32)).astype(np.float32)
    fused = fuse(d, l_prior, weight=weight)
    judged = labels_from_log_odds(fuse(d, l_prior, weight=1.0))
    kept = (reached < 2) & (judged == reached)
    if trust is not None:  # a label is carried on only where it is trusted at least half
        kept &= np.asarray(trust) >= 0.5
    labels = np.where(kept, reached, np.uint8(2)).astype(np.uint8)
    return fused, labels


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

    def step(self, log_odds_moving: np.ndarray, motion: Motion | None, *, pi: float | None = None,
             trust: np.ndarray | None = None) -> np.ndarray:
        """Fuse the moving frame's log-odds (H, W) with the state warped by ``motion`` (None: no
        prior); returns the fused log-odds (H, W) float32 and keeps the new label state.

        pi : the obstacle prior of the classifier that made the log-odds (kept for later steps); None
        keeps the last one. trust : per-pixel factors on the carried labels' weight (:func:`temporal_update`).
        """
        if pi is not None:
            self._pi = float(pi)
        fused, labels = temporal_update(log_odds_moving, self._labels, motion, pi=self._pi,
                                        weight=self._weight, fusion=self._fusion, trust=trust)
        labels.setflags(write=False)
        self._labels = labels
        return fused
