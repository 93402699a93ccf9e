"""The object follower's confidence: the probability that a label of :class:`~pcreg.pipeline.follow.ObjectFollower`
is right, a logistic regression over five features of each pixel (:func:`confidence_features`).

The fused log-odds' magnitude ``|L|`` alone calibrates (ECE 0.0024 on DAVIS 2016's val set) but does not rank: its most
confident 80% of pixels held 0.479 of the error rate of all, where the check wants at most a third; with the features,
0.185 at an ECE of 0.0055 (fitted on the train set, val never fitted on). A label's error is
likelier near the labels' edge (the flow's error and the blur live there), and where the labels hold a large part of
the frame (errors gather on and about a large object, and labels that grow over the frame are wrong while ``|L|`` stays
high); the features carry both (docs/results.md, "The confidence"). Fitted by ``tools/fit_follow_confidence.py``.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["CONFIDENCE_FEATURES", "CONFIDENCE_WEIGHTS", "CONFIDENCE_INTERCEPT", "CONFIDENCE_SLOPE", "CONFIDENCE_OFFSET",
           "EDGE_REACH", "confidence_features", "follow_confidence", "colour_confidence"]

#: What :func:`confidence_features` gives, in its order: ``|L|``; ``e = log1p(d)`` of the distance ``d`` (px, at most
#: :data:`EDGE_REACH`) to the labels' edge; ``e |L|``; ``s``, the square root of the object's share of the frame's
#: labels; ``s |L|``.
CONFIDENCE_FEATURES = ("|L|", "log1p(edge distance)", "log1p(edge distance) |L|", "sqrt(object share)",
                       "sqrt(object share) |L|")
#: The distance to the labels' edge is counted up to this many px: beyond it a pixel is in the open.
EDGE_REACH = 64.0
#: The regression's weights, in the order of :data:`CONFIDENCE_FEATURES`, and its intercept: fitted on a sample of the
#: pixels of the scored frames of DAVIS 2016's train set (tools/fit_follow_confidence.py; docs/results.md).
CONFIDENCE_WEIGHTS = (1.331, 0.244, 0.203, -0.229, -3.246)
CONFIDENCE_INTERCEPT = -0.068
#: The confidence of a label from the colour term ``C`` alone, ``sigmoid(CONFIDENCE_SLOPE * |C| + CONFIDENCE_OFFSET)``:
#: where the labels hold no object (it left the frame), the carried terms say 'nowhere' without having seen it, so the
#: colours alone vouch (the fit of ``|L|`` alone on the train set, before the features above).
CONFIDENCE_SLOPE = 1.084
CONFIDENCE_OFFSET = 0.132


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def _edge_and_share(labels: np.ndarray) -> tuple[np.ndarray, np.float32]:
    """``(e, s)``: ``log1p`` of each pixel's distance to the labels' edge (at most :data:`EDGE_REACH`), and the square
    root of the object's share of the labels."""
    edge = cv2.morphologyEx(labels.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8))
    near = np.full(labels.shape, np.log1p(EDGE_REACH), np.float32)  # no edge within reach: in the open
    x, y, w, h = cv2.boundingRect(edge)
    if w and h:  # the distances within reach of the edge, which all lie in its box grown by the reach (OpenCV's
        r = int(np.ceil(EDGE_REACH / 0.9)) + 1  # 3x3 chamfer counts a step along a row 0.955 px: 67 steps reach 64)
        box = (slice(max(0, y - r), y + h + r), slice(max(0, x - r), x + w + r))
        distance = cv2.distanceTransform((edge[box] == 0).astype(np.uint8), cv2.DIST_L2, 3)
        distance = np.minimum(distance, np.float32(EDGE_REACH), out=distance)
        distance += 1
        near[box] = np.log(distance, out=distance)  # log1p, in place: numpy's float32 log1p takes five times as long
    return near, np.float32(np.sqrt(np.count_nonzero(labels == 1) / max(1, labels.size)))


def confidence_features(log_odds: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(5, H, W) float32: the features of :data:`CONFIDENCE_FEATURES` for each label of ``labels`` (H, W, 1 the
    object) read from the fused log-odds ``log_odds`` (H, W)."""
    magnitude = np.abs(log_odds).astype(np.float32)
    near, share = _edge_and_share(labels)
    return np.stack([magnitude, near, near * magnitude, np.full_like(magnitude, share), share * magnitude])


def follow_confidence(log_odds: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(H, W) float32: the probability that each label of ``labels`` is right, ``sigmoid(w . f + b)`` of its features
    ``f`` (:func:`confidence_features`), ``w`` :data:`CONFIDENCE_WEIGHTS` and ``b`` :data:`CONFIDENCE_INTERCEPT`;
    summed as ``|L| (w0 + w2 e + w4 s) + w1 e + w3 s + b``, without the features' five frames."""
    w0, w1, w2, w3, w4 = (np.float32(v) for v in CONFIDENCE_WEIGHTS)
    near, share = _edge_and_share(labels)
    z = np.abs(log_odds).astype(np.float32) * (w2 * near + (w0 + w4 * share))
    z += w1 * near
    z += w3 * share + np.float32(CONFIDENCE_INTERCEPT)
    return _sigmoid(z).astype(np.float32)


def colour_confidence(colour: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(H, W) float32: the confidence of ``labels`` from the colour term ``colour`` alone (an object lost): the colours'
    confidence where they say the label, one less it where they say the other."""
    sure = _sigmoid(CONFIDENCE_SLOPE * np.abs(colour) + CONFIDENCE_OFFSET)
    return np.where((colour > 0) == (labels == 1), sure, 1.0 - sure).astype(np.float32)
