"""Label propagation through registration: a reference frame's labels (or posterior) as a prior.

Everything works in *log-odds* of the two trained classes, ``L = log p(obstacle | .) - log p(ground | .)``:
with two classes Bayes' rule is a sum of log-odds, so fusing is one multiply-add per pixel.

1. :func:`prior_from_labels` / :func:`prior_from_log_odds` turn what is known about the reference frame
   into a probability of obstacle per pixel, ``q_ref`` (H, W) float32: 1 for obstacle, 0 for ground,
   the class prior ``pi`` where the label is unknown. :func:`smooth_prior` blurs it (Gaussian, ``sigma``
   px) so that a registration error of a pixel or two near a boundary costs little, and mixes it with
   the class prior, ``q = (1 - eps) * blur(q_ref) + eps * pi``, so that no pixel is ever certain.
2. :func:`pcreg.pipeline.prior.warp_prior` moves ``q`` into the moving frame with
   ``T_mov_ref = inv(T_ref_mov)``; pixels that come from outside the reference image get ``pi`` (no
   information). This module stays with the arithmetic; it knows nothing of registration.
3. :func:`prior_log_odds` gives ``l = logit(q) - logit(pi)``: 0 where the prior says nothing beyond the
   class prior the classifier already holds, so that there the fused result equals naive Bayes.
4. :func:`fuse`: ``F = d + w * l`` where ``d`` is naive Bayes' log-odds on the moving frame; the label
   is obstacle where ``F > 0``. With ``w = 1`` and a calibrated ``q`` this is Bayes' rule for two
   conditionally independent sources of evidence that share the class prior; ``w`` (the *fusion
   weight*) corrects for the prior's miscalibration (registration error, parallax, scene change) and is
   chosen on training frames only by :func:`choose_weight` (``w = 0`` is plain naive Bayes, so the
   chosen weight is never worse than plain on the frames it was chosen on).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from ..errors import InputError

__all__ = [
    "CONFIDENCE_SPAN",
    "FusionConfig",
    "WEIGHT_GRID",
    "prior_from_labels",
    "prior_from_log_odds",
    "smooth_prior",
    "label_prior",
    "check_pi",
    "prior_log_odds",
    "fuse",
    "labels_from_log_odds",
    "choose_weight",
    "WeightChoice",
]

#: The prior's weight per pixel, as a multiple of the fusion weight, where a dense field's confidence is 0
#: and where it is 1 (linear between): a factor of two either way. Where the field has the evidence of
#: many matched samples the warped labels are trusted more, where it was interpolated over a textureless
#: or occluded area less. Measured in the stream (:mod:`pcreg.pipeline.stream`) and in the pairs of
#: ``evaluate sequence --model dense`` (:func:`pcreg.pipeline.process_pair`); a global transform has no
#: confidence map and keeps the one weight. The one home of these numbers: the stream's trust rule
#: (:mod:`pcreg.pipeline.trust`) and the pairs' weights (:func:`pcreg.pipeline.prior.pixel_weight`) read them here.
CONFIDENCE_SPAN: tuple[float, float] = (0.5, 2.0)
#: Fusion weights tried by :func:`choose_weight` (0 = naive Bayes alone).
WEIGHT_GRID: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0)
#: The largest fusion weight taken: the prior's log-odds are bounded (``eps``), so a weight far beyond the
#: grid's already lets the prior decide every pixel, and a weight near float32's largest number would
#: overflow the float32 log-odds.
MAX_WEIGHT = 1e6
#: The widest blur of the prior taken (pixels at 640 px width): a blur wider than the image already
#: smooths the prior to its mean.
MAX_SIGMA = 640.0


@dataclass(frozen=True)
class FusionConfig:
    """How a propagated prior is built and fused.

    weight : fusion weight ``w`` (None: choose it on training frames with :func:`choose_weight`).
    eps : mixing with the class prior, ``q = (1 - eps) * blur(q_ref) + eps * pi`` (bounds the prior's
        log-odds to about ``log((1 - eps) / eps)``).
    sigma : Gaussian blur of the reference prior in pixels at 640 px width (scaled with the width).
    grid : candidate weights for :func:`choose_weight`.
    """

    weight: float | None = None
    eps: float = 0.05
    sigma: float = 2.0
    grid: tuple[float, ...] = WEIGHT_GRID

    def __post_init__(self) -> None:
        from ..validation import check_float

        check_float(self.eps, "fusion eps", lo=0, lo_open=True, hi=1, hi_open=True)
        if self.weight is not None:
            check_float(self.weight, "fusion weight", lo=0, hi=MAX_WEIGHT)
        check_float(self.sigma, "fusion sigma", lo=0, hi=MAX_SIGMA)
        if not isinstance(self.grid, (tuple, list)) or not self.grid:
            raise InputError("fusion weight grid must be a non-empty sequence of numbers")
        for g in self.grid:
            check_float(g, "a fusion weight of the grid", lo=0, hi=MAX_WEIGHT)


def check_pi(pi: float) -> float:
    """``pi`` as a float when it is a class prior in (0, 1)."""
    from ..validation import check_float

    pi = check_float(pi, "class prior of obstacle")
    if not 0.0 < pi < 1.0:
        raise InputError(f"class prior of obstacle must be in (0, 1), got {pi}")
    return pi


def prior_from_labels(labels: np.ndarray, *, pi: float) -> np.ndarray:
    """(H, W) float32 probability of obstacle from a label map: 1 obstacle, 0 ground, ``pi`` unknown.

    labels : (H, W) uint8 in {0 ground, 1 obstacle, 2 unknown}. pi : class prior of obstacle.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise InputError(f"labels must be (H, W), got {labels.shape}")
    if labels.dtype != np.uint8:  # cast below: a 16-bit 256 would wrap to 0 (certain ground), a 0.9 be cut to 0
        if not (np.issubdtype(labels.dtype, np.integer) or labels.dtype == np.bool_):
            raise InputError(f"labels must be integers (0 ground, 1 obstacle, 2 unknown), got {labels.dtype}")
        if labels.size and (int(labels.min()) < 0 or int(labels.max()) > 255):
            bad = int(labels.min()) if int(labels.min()) < 0 else int(labels.max())
            raise InputError(f"label value {bad} is no label (0 ground, 1 obstacle, 2 unknown)")
    lut = np.array([0.0, 1.0, check_pi(pi)] + [check_pi(pi)] * 253, dtype=np.float32)
    return lut[labels.astype(np.uint8, copy=False)]


def prior_from_log_odds(log_odds: np.ndarray) -> np.ndarray:
    """(H, W) float32 probability of obstacle from a log-odds map (e.g. a fused posterior)."""
    L = np.asarray(log_odds, dtype=np.float32)
    if L.ndim != 2:
        raise InputError(f"log-odds must be (H, W), got {L.shape}")
    return (1.0 / (1.0 + np.exp(-np.clip(L, -60.0, 60.0)))).astype(np.float32)


def smooth_prior(q: np.ndarray, *, pi: float, eps: float = 0.05, sigma: float = 2.0) -> np.ndarray:
    """``(1 - eps) * blur(q, sigma * W / 640) + eps * pi`` as (H, W) float32 (a new array)."""
    import cv2

    q = np.asarray(q, dtype=np.float32)
    s = float(sigma) * q.shape[1] / 640.0
    if s > 0:
        q = cv2.GaussianBlur(q, (0, 0), s, borderType=cv2.BORDER_REPLICATE)
    return cv2.addWeighted(q, 1.0 - float(eps), q, 0.0, float(eps) * check_pi(pi))


def label_prior(labels: np.ndarray, *, pi: float, fusion: FusionConfig = FusionConfig()) -> np.ndarray:
    """The smoothed prior (H, W) float32 of a label map: :func:`prior_from_labels` blurred and mixed with
    the class prior by :func:`smooth_prior` with ``fusion``'s ``eps`` and ``sigma``."""
    return smooth_prior(prior_from_labels(labels, pi=pi), pi=pi, eps=fusion.eps, sigma=fusion.sigma)


def prior_log_odds(q: np.ndarray, *, pi: float) -> np.ndarray:
    """(H, W) float32 ``logit(q) - logit(pi)``: the evidence of the prior beyond the class prior."""
    pi = check_pi(pi)
    q = np.clip(np.asarray(q, dtype=np.float32), 1e-6, 1.0 - 1e-6)
    return (np.log(q / (1.0 - q)) - np.float32(np.log(pi / (1.0 - pi)))).astype(np.float32)


def fuse(log_odds: np.ndarray, prior: np.ndarray, *, weight: float | np.ndarray) -> np.ndarray:
    """(H, W) float32 fused log-odds ``log_odds + weight * prior`` (both (H, W) log-odds maps).

    weight : one number, or an (H, W) map of them (a weight per pixel), finite and >= 0.
    """
    d = np.asarray(log_odds, dtype=np.float32)
    l = np.asarray(prior, dtype=np.float32)
    if d.shape != l.shape:
        raise InputError(f"log-odds {d.shape} and prior {l.shape} differ in shape")
    if np.ndim(weight) == 0:
        from ..validation import check_float

        weight = check_float(weight.item() if isinstance(weight, np.ndarray) else weight, "weight", lo=0, hi=MAX_WEIGHT)
        if weight == 0:
            return d.copy()
        return d + np.float32(weight) * l
    w = np.asarray(weight, dtype=np.float32)
    if w.shape != d.shape:
        raise InputError(f"a weight map must have the log-odds' shape {d.shape}, got {w.shape}")
    if not (np.all(np.isfinite(w)) and float(w.min(initial=0.0)) >= 0):
        raise InputError("a weight map must be finite and >= 0")
    return d + w * l


def labels_from_log_odds(log_odds: np.ndarray) -> np.ndarray:
    """(H, W) uint8 labels: 1 obstacle where the log-odds are > 0, else 0 ground (NaN log-odds refused:
    they would read as ground)."""
    a = np.asarray(log_odds)
    if not np.issubdtype(a.dtype, np.number):
        raise InputError(f"log-odds must be a numeric array, got {a.dtype}")
    if np.issubdtype(a.dtype, np.floating) and np.isnan(a).any():
        raise InputError("log-odds hold NaN: no label can be read from them")
    return (a > 0).view(np.uint8)


@dataclass(frozen=True)
class WeightChoice:
    """The fusion weight chosen on training pairs.

    weight : the chosen ``w``; grid : the weights tried; errors : pooled error % of each on the
    training pairs (unknown truth left out); pairs : how many pairs; pixels : scored pixels.
    """

    weight: float
    grid: tuple[float, ...]
    errors: tuple[float, ...]
    pairs: int
    pixels: int

    def to_dict(self) -> dict:
        return {"weight": self.weight, "grid": list(self.grid), "errors": list(self.errors),
                "pairs": self.pairs, "pixels": self.pixels}


def choose_weight(samples: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], *,
                  grid: Sequence[float] = WEIGHT_GRID, default: float = 1.0) -> WeightChoice:
    """Choose the fusion weight with the lowest pooled error on training pairs.

    samples : iterable of ``(log_odds, prior, truth)``: naive Bayes log-odds (H, W), the propagated
        prior's log-odds (H, W) (:func:`prior_log_odds`) and the true labels (H, W) uint8 of the
        moving frame of each training pair. Unknown truth is left out.
    grid : candidate weights; ties go to the smaller weight. default : returned (with NaN errors)
        when there is no sample.
    """
    from ..validation import check_float

    if isinstance(grid, (str, bytes)) or not isinstance(grid, (Sequence, np.ndarray)) or len(grid) == 0:
        raise InputError("grid must be a non-empty sequence of weights")
    grid = tuple(check_float(g, "a weight of the grid", lo=0, hi=MAX_WEIGHT) for g in grid)
    wrong = np.zeros(len(grid), dtype=np.int64)
    total = 0
    n = 0
    for d, l, truth in samples:
        truth = np.asarray(truth)
        keep = truth < 2
        if not keep.any():
            continue
        dk = np.asarray(d, dtype=np.float32)[keep]
        lk = np.asarray(l, dtype=np.float32)[keep]
        tk = truth[keep] == 1
        for i, w in enumerate(grid):
            wrong[i] += int(np.count_nonzero(((dk + np.float32(w) * lk) > 0) != tk))
        total += int(keep.sum())
        n += 1
    if total == 0:
        return WeightChoice(float(default), grid, tuple(float("nan") for _ in grid), 0, 0)
    errors = 100.0 * wrong / total
    best = int(np.argmin(errors))  # first minimum = smallest weight among ties
    return WeightChoice(grid[best], grid, tuple(float(e) for e in errors), n, total)
