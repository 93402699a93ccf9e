"""The reference frame's prior carried onto the moving frame: where registration meets the fusion.

:mod:`pcreg.classification.fusion` holds the log-odds arithmetic; here the prior it builds is warped
by a motion (:class:`~pcreg.registration.motion.Motion`: a 3x3 ``T_ref_mov`` or a dense field) onto the moving
frame's pixel grid.
"""

from __future__ import annotations

import numpy as np

from ..classification.fusion import check_pi, prior_log_odds

__all__ = ["CONFIDENCE_SPAN", "class_prior", "pixel_weight", "warp_prior", "warped_prior_log_odds"]

#: The prior's weight per pixel, as a multiple of the fusion weight, where a dense field's confidence is 0
#: and where it is 1 (linear between): a factor of two either way. Where the field has the evidence of
#: many matched samples the warped labels are trusted more, where it was interpolated over a textureless
#: or occluded area less. Measured in the stream (:mod:`pcreg.pipeline.stream`) and in the pairs of
#: ``evaluate sequence --model dense`` (:func:`pcreg.pipeline.process_pair`); a global transform has no
#: confidence map and keeps the one weight.
CONFIDENCE_SPAN: tuple[float, float] = (0.5, 2.0)


def class_prior(classifier) -> float:
    """A fitted two-class naive Bayes' class prior of obstacle, ``pi``."""
    return float(np.asarray(classifier.class_prior_)[1])


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
