"""The object follower's confidence: a logistic regression over five features of each pixel (its fused log-odds'
magnitude, the distance to the labels' edge, the object's share of the frame), so that it ranks its errors as well as
it calibrates them."""

import numpy as np
import pytest

from pcreg.pipeline.follow_confidence import (CONFIDENCE_OFFSET, CONFIDENCE_SLOPE, EDGE_REACH, colour_confidence,
                                              confidence_features, follow_confidence)


def _square(h=100, w=400):
    labels = np.zeros((h, w), np.uint8)
    labels[30:70, 80:120] = 1
    return labels


def test_the_features_are_the_magnitude_the_edge_distance_the_share_and_their_products():
    labels = _square()
    log_odds = np.where(labels == 1, 3.0, -2.0).astype(np.float32)
    f = confidence_features(log_odds, labels)
    assert f.shape == (5, 100, 400) and f.dtype == np.float32
    np.testing.assert_array_equal(f[0], np.abs(log_odds))
    assert f[1][30, 100] == 0.0 and f[1][69, 100] == 0.0          # on the edge, both sides of it
    assert f[1][50, 100] == pytest.approx(np.log1p(50 - 31), abs=0.05)   # the middle: 19 px from the inner edge
    assert f[1][50, 399] == pytest.approx(np.log1p(EDGE_REACH))   # far off, counted up to the reach
    np.testing.assert_allclose(f[2], f[1] * f[0], rtol=1e-6)
    assert np.all(f[3] == pytest.approx(np.sqrt(1600 / 40000)))
    np.testing.assert_allclose(f[4], f[3] * f[0], rtol=1e-6)


def test_labels_without_an_edge_are_in_the_open_everywhere():
    for labels in (np.zeros((20, 30), np.uint8), np.ones((20, 30), np.uint8)):
        f = confidence_features(np.ones((20, 30), np.float32), labels)
        assert np.all(f[1] == pytest.approx(np.log1p(EDGE_REACH)))
        assert np.all(f[3] == float(labels.mean()))


def test_a_label_is_less_sure_near_the_edge_and_where_the_object_fills_the_frame():
    """What the regression learnt on DAVIS 2016's train set, at the same |L|: errors gather at the labels' edge and
    where the labels hold a large object (they grow over the frame while |L| stays high)."""
    labels = _square()
    log_odds = np.full(labels.shape, 2.0, np.float32)
    c = follow_confidence(log_odds, labels)
    assert c.dtype == np.float32 and np.all((c > 0) & (c < 1))
    assert c[30, 100] < c[50, 300]
    large = np.zeros_like(labels)
    large[:, :300] = 1
    assert follow_confidence(log_odds, large)[50, 380] < c[50, 380]
    assert follow_confidence(np.full_like(log_odds, 6.0), labels)[50, 300] > c[50, 300]


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
