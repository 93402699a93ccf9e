"""The object follower's confidence: a logistic regression over three features of each pixel (its fused log-odds'
magnitude, the distance to the labels' edge and their product), so that it ranks its errors as well as it calibrates
them, and never says a large object followed well is wrong."""

import cv2
import numpy as np
import pytest

from pcreg.pipeline.follow_confidence import (CONFIDENCE_OFFSET, CONFIDENCE_SLOPE, CONFIDENCE_WEIGHTS, EDGE_REACH,
                                              colour_confidence, confidence_features, follow_confidence)


def _square(h=100, w=400):
    labels = np.zeros((h, w), np.uint8)
    labels[30:70, 80:120] = 1
    return labels


def test_the_features_are_the_magnitude_the_edge_distance_and_their_product():
    labels = _square()
    log_odds = np.where(labels == 1, 3.0, -2.0).astype(np.float32)
    f = confidence_features(log_odds, labels)
    assert f.shape == (3, 100, 400) and f.dtype == np.float32
    np.testing.assert_array_equal(f[0], np.abs(log_odds))
    assert f[1][30, 100] == 0.0 and f[1][69, 100] == 0.0          # on the edge, both sides of it
    assert f[1][50, 100] == pytest.approx(np.log1p(50 - 31), abs=0.05)   # the middle: 19 px from the inner edge
    assert f[1][50, 399] == pytest.approx(np.log1p(EDGE_REACH))   # far off, counted up to the reach
    assert f[1][50, 120 + 66] < np.log1p(EDGE_REACH)              # 66 px along a row: the chamfer counts it 63 px
    np.testing.assert_allclose(f[2], f[1] * f[0], rtol=1e-6)


def test_labels_without_an_edge_are_in_the_open_everywhere():
    for labels in (np.zeros((20, 30), np.uint8), np.ones((20, 30), np.uint8)):
        f = confidence_features(np.ones((20, 30), np.float32), labels)
        assert np.all(f[1] == pytest.approx(np.log1p(EDGE_REACH)))


def test_more_evidence_or_a_pixel_farther_from_the_edge_never_lowers_the_confidence():
    """What the regression learnt on DAVIS 2016's train set: errors gather at the labels' edge, at any |L|. Every
    weight is positive, so the confidence grows with |L| at every distance and with the distance at every |L|."""
    assert all(w > 0 for w in CONFIDENCE_WEIGHTS)
    labels = _square()
    c = {m: follow_confidence(np.full(labels.shape, m, np.float32), labels) for m in (0.0, 2.0, 8.0, np.inf)}
    assert all(v.dtype == np.float32 and np.all((v > 0) & (v <= 1)) for v in c.values())
    assert np.all(c[0.0] <= c[2.0]) and np.all(c[2.0] <= c[8.0]) and np.all(c[8.0] <= c[np.inf])
    assert c[2.0][30, 100] < c[2.0][50, 300] and c[np.inf].min() == 1.0


def test_a_large_object_followed_well_is_not_said_to_be_wrong(shared_data):
    """goat's first frame cut to a close-up, the goat 39% of it, and the same picture again: the labels are 0.34%
    wrong, and 4.4% is predicted (pessimistic: a close-up has more edge for its size than DAVIS's frames; |L| alone
    said 0.96%). A confidence fitted with the object's share of the frame as a feature (it ranked DAVIS's errors
    better) predicted 49.7% here: DAVIS's few large objects are those lost over the frame."""
    from pcreg.pipeline.follow import ObjectFollower

    root = shared_data / "davis" / "goat"
    if not root.is_dir():
        pytest.skip(f"{root} is absent (the shared DAVIS sequences)")
    image = cv2.imread(str(root / "images" / "00000.jpg"))[:, :, ::-1]
    mask = (cv2.imread(str(root / "labels" / "00000.png"), cv2.IMREAD_UNCHANGED) > 0).astype(np.uint8)
    ys, xs = np.nonzero(mask)
    crop = (slice(max(0, ys.min() - 20), ys.max() + 20), slice(max(0, xs.min() - 20), xs.max() + 20))
    image, mask = np.ascontiguousarray(image[crop]), np.ascontiguousarray(mask[crop])
    assert mask.mean() > 0.35
    follower = ObjectFollower.from_key_frame(image, mask)
    for _ in range(3):
        labels = follower.step(image)
    wrong = 100 * float((labels != mask).mean())
    assert wrong < 1 and follower.last.predicted_error < 8, (wrong, follower.last.predicted_error)  # 0.34, 4.4


def test_the_colours_alone_vouch_for_a_lost_object():
    colour = np.array([[2.0, -2.0, 0.0]], np.float32)
    labels = np.array([[1, 1, 0]], np.uint8)
    sure = 1 / (1 + np.exp(-(CONFIDENCE_SLOPE * 2.0 + CONFIDENCE_OFFSET)))
    np.testing.assert_allclose(colour_confidence(colour, labels)[0], [sure, 1 - sure, 1 / (1 + np.exp(-CONFIDENCE_OFFSET))],
                               rtol=1e-6)


@pytest.mark.data
def test_the_most_confident_labels_hold_little_of_the_error(shared_data):
    """goat's first 30 frames: the most confident 80% of the labels hold a far smaller share of the error rate than
    with the confidence of |L| alone, which ranked the errors little (most of them sit near the labels' edge, at every
    |L|): measured 0.048 against 0.304."""
    from pcreg.datasets.davis import load_sequence
    from pcreg.experiments.stream_methods import calibration, calibration_counts
    from pcreg.pipeline.follow import ObjectFollower

    root = shared_data / "davis" / "goat"
    if not root.is_dir():
        pytest.skip(f"{root} is absent (the shared DAVIS sequences)")
    frames = load_sequence(root / "images", root / "labels", n_frames=31)
    follower = ObjectFollower.from_key_frame(frames[0].image, frames[0].labels)
    counts, alone = 0, 0
    for f in frames[1:]:
        labels = follower.step(f.image)
        counts = counts + calibration_counts(follower.last.confidence, labels, f.labels)
        magnitude = np.abs(follower.log_odds)
        alone = alone + calibration_counts(1 / (1 + np.exp(-(CONFIDENCE_SLOPE * magnitude + CONFIDENCE_OFFSET))), labels, f.labels)
    share, share_alone = (c["error_top80"] / c["error"] for c in (calibration(counts), calibration(alone)))
    assert share < 0.1 and share < 0.5 * share_alone, (share, share_alone)
