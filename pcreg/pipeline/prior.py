"""The reference frame's prior carried onto the moving frame: where registration meets the fusion.

:mod:`pcreg.classification.fusion` holds the log-odds arithmetic; here the prior it builds is warped
by a motion (:class:`~pcreg.registration.motion.Motion`: a 3x3 ``T_ref_mov`` or a dense field) onto the moving
frame's pixel grid.
"""

from __future__ import annotations

import numpy as np

from ..classification.fusion import check_pi, prior_log_odds

__all__ = ["class_prior", "warp_prior", "warped_prior_log_odds"]


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
