"""The reference frame's prior carried onto the moving frame: where registration meets the fusion.

:mod:`pcreg.classification.fusion` holds the log-odds arithmetic; here the prior it builds is warped
by a motion (:class:`~pcreg.registration.motion.Motion`: a 3x3 ``T_ref_mov`` or a dense field) onto the moving
frame's pixel grid.
"""

from __future__ import annotations

import numpy as np

from ..classification.fusion import CONFIDENCE_SPAN, check_pi, fuse, labels_from_log_odds, prior_log_odds
from ..errors import InputError

__all__ = ["CONFIDENCE_SPAN", "class_prior", "fused_labels", "fused_log_odds", "pixel_weight", "prior_on_moving",
           "warp_prior", "warped_prior_log_odds"]



def class_prior(classifier) -> float:
    """A fitted two-class naive Bayes' class prior of obstacle, ``pi``."""
    prior = getattr(classifier, "class_prior_", None)
    if prior is None or np.shape(prior) != (2,):
        raise InputError("the classifier must be a fitted two-class naive Bayes (class_prior_ of ground and "
                         "obstacle)")
    return float(np.asarray(prior)[1])


def warp_prior(q: np.ndarray, motion, *, shape: tuple[int, int], pi: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Move a reference-frame prior onto the moving frame's pixel grid.

    q : (H, W) float32 probability of obstacle in the reference frame.
    motion : a :class:`~pcreg.registration.motion.Motion` or what its ``of`` takes: a (3, 3) ``T_ref_mov``
        (as :func:`pcreg.register` returns), a dense field (H, W, 2) of reference coordinates of every
        moving pixel (:func:`pcreg.register_dense`), a registration result; None = identity (the unregistered ablation; sizes must then match, or the prior is
        cropped/padded at the origin).
    shape : (H, W) of the moving frame.
    Returns ``(q_mov (H, W) float32, valid (H, W) bool)``; ``q_mov`` is ``pi`` where not valid.
    """
    from ..registration.warp import warp_to_moving

    pi = check_pi(pi)
    motion = np.eye(3) if motion is None else motion
    return warp_to_moving(np.asarray(q, dtype=np.float32), motion, shape=shape, interpolation="linear", fill=pi)


def prior_on_moving(q: np.ndarray, motion, *, shape: tuple[int, int], pi: float) -> np.ndarray:
    """:func:`warp_prior`'s ``q_mov`` alone, without its validity mask: along a dense field one
    ``cv2.remap`` (the field is its two-channel map; the same values as :func:`warp_prior`'s), else
    :func:`warp_prior`. The stream's step needs no mask: where the field leaves the key frame the prior
    is ``pi``, which carries no evidence."""
    import cv2

    from ..registration.motion import Motion
    from ..registration.warp import check_field

    m = None if motion is None else Motion.of(motion)
    if m is None or m.field is None:
        return warp_prior(q, m, shape=shape, pi=pi)[0]
    return cv2.remap(np.asarray(q, dtype=np.float32), check_field(m.field, shape), None, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=check_pi(pi))


def warped_prior_log_odds(q: np.ndarray, motion, *, shape: tuple[int, int], pi: float) -> np.ndarray:
    """The prior log-odds (H, W) float32 on the moving frame: :func:`warp_prior`, then
    :func:`~pcreg.classification.fusion.prior_log_odds`."""
    q_mov, _ = warp_prior(q, motion, shape=shape, pi=pi)
    return prior_log_odds(q_mov, pi=pi)


def pixel_weight(weight: float, confidence: np.ndarray | None) -> float | np.ndarray:
    """The prior's fusion weight: ``weight`` where there is no confidence map (a global transform, a
    composed chain), else per pixel ``weight * (lo + (hi - lo) * confidence)`` with ``(lo, hi)`` =
    :data:`CONFIDENCE_SPAN`, a (H, W) float32 map."""
    if confidence is None:
        return weight
    lo, hi = CONFIDENCE_SPAN
    c = np.clip(np.nan_to_num(np.asarray(confidence, dtype=np.float32), nan=0.0), 0.0, 1.0)  # NaN: no evidence
    return np.float32(weight) * (np.float32(lo) + np.float32(hi - lo) * c)


def fused_log_odds(log_odds: np.ndarray, q: np.ndarray, confidence: np.ndarray | None, *, weight: float,
                   pi: float) -> np.ndarray:
    """(H, W) float32: the classifier's log-odds fused with a warped prior ``q`` (:func:`fused_labels`'
    arguments), ``fuse(log_odds, prior_log_odds(q, pi=pi), weight=pixel_weight(weight, confidence))``:
    what :func:`fused_labels` takes the sign of, for a caller that needs the numbers themselves (a
    stream working below the frames' size brings them to the frames' size first)."""
    return fuse(log_odds, prior_log_odds(q, pi=pi), weight=pixel_weight(weight, confidence))


def fused_labels(log_odds: np.ndarray, q: np.ndarray, confidence: np.ndarray | None, *, weight: float,
                 pi: float) -> np.ndarray:
    """(H, W) uint8 labels of the classifier's log-odds fused with a warped prior, in one pass:
    ``labels_from_log_odds(fuse(log_odds, prior_log_odds(q, pi=pi), weight=pixel_weight(weight,
    confidence)))``, the same float32 operations pixel by pixel (a logarithm may differ in its last
    bit from numpy's, which only matters for a pixel whose fused log-odds are within a rounding of 0).

    log_odds : (H, W) float32 naive Bayes log-odds; q : (H, W) float32 warped prior probability of
    obstacle; confidence : (H, W) the dense field's confidence, or None (one weight everywhere).
    The rows are split with the helper thread (:mod:`pcreg._threads`) on large images.
    """
    from .trust import fused_labels_kernel

    d = np.ascontiguousarray(log_odds, dtype=np.float32)
    qq = np.ascontiguousarray(q, dtype=np.float32)
    if d.shape != qq.shape or d.ndim != 2:
        raise ValueError(f"log-odds {d.shape} and prior {qq.shape} must be one (H, W) shape")  # a caller's bug
    if confidence is None:
        return labels_from_log_odds(fused_log_odds(d, qq, confidence, weight=weight, pi=pi))
    c = np.ascontiguousarray(confidence, dtype=np.float32)
    if c.shape != d.shape:
        raise ValueError(f"a confidence of shape {c.shape} for log-odds of shape {d.shape}")  # a caller's bug
    return fused_labels_kernel(d, qq, c, weight=weight, pi=check_pi(pi))
