"""The object follower's confidence: the probability that a label of :class:`~pcreg.pipeline.follow.ObjectFollower`
is right, a logistic regression over three features of each pixel (:func:`confidence_features`).

The fused log-odds' magnitude ``|L|`` alone calibrates (ECE 0.0024 on DAVIS 2016's val set) but does not rank: its most
confident 80% of pixels held 0.479 of the error rate of all, where the check wants at most a third. A label's error is
likelier near the labels' edge, where the flow's errors and the blur are, at any ``|L|``; the distance to the edge,
alone and times ``|L|``, carries it: 0.294 at an ECE of 0.0077 (fitted on the train set, val never fitted on;
docs/results.md, "The confidence").
Every weight is positive: more evidence, or a pixel farther from the edge, never lowers the confidence. The object's
share of the frame ranked DAVIS's errors better still, but said a large object followed well was mostly wrong, so it is
not a feature. Fitted by ``tools/fit_follow_confidence.py``.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["CONFIDENCE_FEATURES", "CONFIDENCE_WEIGHTS", "CONFIDENCE_INTERCEPT", "CONFIDENCE_SLOPE", "CONFIDENCE_OFFSET",
           "EDGE_REACH", "confidence_features", "follow_confidence", "colour_confidence"]

#: What :func:`confidence_features` gives, in its order: ``|L|``; ``e = log1p(d)`` of the distance ``d`` (px, at most
#: :data:`EDGE_REACH`) to the labels' edge; ``e |L|``.
CONFIDENCE_FEATURES = ("|L|", "log1p(edge distance)", "log1p(edge distance) |L|")
#: The distance to the labels' edge is counted up to this many px: beyond it a pixel is in the open.
EDGE_REACH = 64.0
#: The regression's weights, in the order of :data:`CONFIDENCE_FEATURES`, and its intercept: fitted on a sample of the
#: pixels of the scored frames of DAVIS 2016's train set (tools/fit_follow_confidence.py; docs/results.md).
CONFIDENCE_WEIGHTS = (0.186, 0.258, 0.178)
CONFIDENCE_INTERCEPT = -0.098
#: The confidence of a label from the colour term ``C`` alone, ``sigmoid(CONFIDENCE_SLOPE * |C| + CONFIDENCE_OFFSET)``:
#: where the labels hold no object (it left the frame), the carried terms say 'nowhere' without having seen it, so the
#: colours alone vouch (the fit of ``|L|`` alone on the train set, before the features above).
CONFIDENCE_SLOPE = 1.084
CONFIDENCE_OFFSET = 0.132


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def _edge_reach(labels: np.ndarray) -> np.ndarray:
    """(H, W) float32: ``log1p`` of each pixel's distance to the labels' edge, counted up to :data:`EDGE_REACH`."""
    edge = cv2.morphologyEx(labels.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8))
    near = np.full(labels.shape, np.log1p(EDGE_REACH), np.float32)  # no edge within reach: in the open
    x, y, w, h = cv2.boundingRect(edge)
    if w and h:  # the distances within reach of the edge, which all lie in its box grown by the reach (OpenCV's
        r = int(np.ceil(EDGE_REACH / 0.9)) + 1  # 3x3 chamfer counts a step along a row 0.955 px: 68 steps pass 64)
        box = (slice(max(0, y - r), y + h + r), slice(max(0, x - r), x + w + r))
        distance = cv2.distanceTransform((edge[box] == 0).astype(np.uint8), cv2.DIST_L2, 3)
        distance = np.minimum(distance, np.float32(EDGE_REACH), out=distance)
        distance += 1
        near[box] = np.log(distance, out=distance)  # log1p, in place: numpy's float32 log1p takes five times as long
    return near


def confidence_features(log_odds: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(3, H, W) float32: the features of :data:`CONFIDENCE_FEATURES` for each label of ``labels`` (H, W, 1 the
    object) read from the fused log-odds ``log_odds`` (H, W)."""
    magnitude = np.abs(log_odds).astype(np.float32)
    near = _edge_reach(labels)
    return np.stack([magnitude, near, near * magnitude])


def follow_confidence(log_odds: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(H, W) float32: the probability that each label of ``labels`` is right, ``sigmoid(w . f + b)`` of its features
    ``f`` (:func:`confidence_features`), ``w`` :data:`CONFIDENCE_WEIGHTS` and ``b`` :data:`CONFIDENCE_INTERCEPT`;
    summed as ``|L| (w0 + w2 e) + w1 e + b``, without the features' three frames."""
    w0, w1, w2 = (np.float32(v) for v in CONFIDENCE_WEIGHTS)
    near = _edge_reach(labels)
    z = np.abs(log_odds).astype(np.float32) * (w2 * near + w0)
    z += w1 * near
    z += np.float32(CONFIDENCE_INTERCEPT)
    return _sigmoid(z).astype(np.float32)


def colour_confidence(colour: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(H, W) float32: the confidence of ``labels`` from the colour term ``colour`` alone (an object lost): the colours'
    confidence where they say the label, one less it where they say the other."""
    sure = _sigmoid(CONFIDENCE_SLOPE * np.abs(colour) + CONFIDENCE_OFFSET)
    return np.where((colour > 0) == (labels == 1), sure, 1.0 - sure).astype(np.float32)
