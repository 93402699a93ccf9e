"""pcreg.classification.fusion: priors from labels, their warp into the moving frame, fusion and the weight choice."""

from __future__ import annotations

import numpy as np
import pytest

from pcreg.errors import InputError
from pcreg.classification.fusion import (FusionConfig, choose_weight, fuse, labels_from_log_odds, prior_from_labels,
                          prior_from_log_odds, prior_log_odds, smooth_prior)
from pcreg.pipeline.prior import warp_prior
from pcreg.registration.transforms import rigid2d


def _labels(h=40, w=60):
    lab = np.zeros((h, w), np.uint8)
    lab[10:30, 20:35] = 1
    lab[:5] = 2
    return lab


def test_prior_from_labels_values():
    lab = _labels()
    q = prior_from_labels(lab, pi=0.3)
    assert q.dtype == np.float32 and q.shape == lab.shape
    assert np.all(q[lab == 1] == 1.0) and np.all(q[lab == 0] == 0.0)
    assert np.allclose(q[lab == 2], 0.3)
    with pytest.raises(InputError):
        prior_from_labels(lab, pi=1.0)


def test_prior_from_labels_refuses_values_that_are_no_label():
    # 256 and 257 (16-bit labels) wrapped to 0 and 1, certain ground and obstacle; 0.9 was cut to 0, ground
    np.testing.assert_array_equal(prior_from_labels(np.array([[0, 1, 2]], np.int64), pi=0.25), [[0.0, 1.0, 0.25]])
    np.testing.assert_array_equal(prior_from_labels(np.array([[False, True]]), pi=0.25), [[0.0, 1.0]])
    for bad, needle in ((np.array([[0, 256]], np.uint16), "256"), (np.array([[-1, 1]], np.int32), "-1"),
                        (np.array([[0.9, 1.0]]), "float64")):
        with pytest.raises(InputError, match=needle):
            prior_from_labels(bad, pi=0.3)


def test_smooth_prior_is_bounded_and_keeps_inputs():
    lab = _labels()
    q = prior_from_labels(lab, pi=0.3)
    before = q.copy()
    s = smooth_prior(q, pi=0.3, eps=0.1, sigma=0.0)
    assert np.array_equal(q, before)
    assert s.min() >= 0.1 * 0.3 - 1e-6 and s.max() <= 0.9 + 0.1 * 0.3 + 1e-6
    blurred = smooth_prior(q, pi=0.3, eps=0.1, sigma=8.0)
    # the blur softens the edge of the obstacle block but not its centre
    assert 0.1 < blurred[20, 20] < s[20, 20] and blurred[20, 27] > 0.8


def test_prior_log_odds_is_zero_at_the_class_prior():
    q = np.full((4, 5), 0.3, np.float32)
    assert np.allclose(prior_log_odds(q, pi=0.3), 0.0, atol=1e-6)
    assert np.all(prior_log_odds(np.full((2, 2), 0.9, np.float32), pi=0.3) > 0)


def test_warp_prior_moves_the_reference_into_the_moving_frame():
    # moving pixel x sees the reference at T_ref_mov x: a shift of +5 px in x.
    lab = _labels()
    q = prior_from_labels(lab, pi=0.3)
    T = rigid2d(0.0, 5.0, 0.0)
    q_mov, valid = warp_prior(q, T, shape=lab.shape, pi=0.3)
    assert np.allclose(q_mov[10:30, 15:30], 1.0)  # the block, 5 px to the left in the moving frame
    assert np.allclose(q_mov[10:30, 30:35], 0.0)
    assert not valid[:, -5:].any() and valid[:, :-5].all()
    assert np.allclose(q_mov[:, -5:], 0.3)  # outside the reference: the class prior
    q_id, valid_id = warp_prior(q, None, shape=lab.shape, pi=0.3)
    assert np.array_equal(q_id, q) and valid_id.all()


def test_fuse_and_labels():
    d = np.array([[-1.0, 2.0]], np.float32)
    l = np.array([[3.0, -3.0]], np.float32)
    assert np.array_equal(fuse(d, l, weight=0.0), d)
    f = fuse(d, l, weight=1.0)
    assert np.allclose(f, [[2.0, -1.0]])
    assert labels_from_log_odds(f).tolist() == [[1, 0]]
    with pytest.raises(InputError):
        fuse(d, l[:, :1], weight=1.0)
    assert prior_from_log_odds(np.array([[0.0, 60.0]])).tolist()[0][0] == pytest.approx(0.5)


def test_a_weight_per_pixel():
    d = np.array([[-1.0, 2.0, 0.5]], np.float32)
    l = np.array([[3.0, -3.0, 1.0]], np.float32)
    assert np.allclose(fuse(d, l, weight=np.array([[0.0, 1.0, 2.0]])), [[-1.0, -1.0, 2.5]])
    with pytest.raises(InputError, match="weight map must have the log-odds' shape"):
        fuse(d, l, weight=np.ones((1, 2)))
    with pytest.raises(InputError, match="finite and >= 0"):
        fuse(d, l, weight=np.array([[1.0, -1.0, 1.0]]))
    with pytest.raises(InputError, match="finite and >= 0"):
        fuse(d, l, weight=np.array([[1.0, np.nan, 1.0]]))


def test_the_streams_weight_follows_the_fields_confidence():
    from pcreg.pipeline.prior import CONFIDENCE_SPAN, pixel_weight

    assert CONFIDENCE_SPAN == (0.5, 2.0)
    assert pixel_weight(2.0, None) == 2.0  # a global transform: one weight
    w = pixel_weight(2.0, np.array([[0.0, 1 / 3, 1.0, 1.5, -0.2, np.nan]], np.float32))
    assert w.dtype == np.float32 and np.allclose(w, [[1.0, 2.0, 4.0, 4.0, 1.0, 1.0]])  # clipped to [0, 1]; NaN as 0


@pytest.mark.parametrize("shape", [(7, 5), (480, 640)])  # one thread; rows shared with the helper
def test_fused_labels_are_the_composed_fusion_pixel_for_pixel(shape):
    """The stream's one-pass fusion gives the labels of pixel_weight, prior_log_odds, fuse and
    labels_from_log_odds composed, with the edge cases of each: NaN and infinite confidence, a prior of
    exactly 0 or 1, confidence beyond [0, 1]."""
    from pcreg.pipeline.prior import fused_labels, pixel_weight

    rng = np.random.default_rng(shape[0])
    d = rng.normal(0, 3, shape).astype(np.float32)
    q = rng.uniform(0, 1, shape).astype(np.float32)
    c = rng.uniform(-0.2, 1.2, shape).astype(np.float32)
    q.flat[:4] = [0.0, 1.0, 0.0, 1.0]
    c.flat[:6] = [np.nan, np.inf, -np.inf, np.nan, 0.0, 1.0]
    for pi, weight in ((0.3, 2.0), (0.71, 0.5), (0.5, 0.0)):
        composed = labels_from_log_odds(fuse(d, prior_log_odds(q, pi=pi), weight=pixel_weight(weight, c)))
        one_pass = fused_labels(d, q, c, weight=weight, pi=pi)
        assert one_pass.dtype == np.uint8 and np.array_equal(one_pass, composed)
        assert np.array_equal(fused_labels(d, q, None, weight=weight, pi=pi),
                              labels_from_log_odds(fuse(d, prior_log_odds(q, pi=pi), weight=weight)))


def test_the_streams_prior_along_a_field_is_warp_priors_without_the_mask():
    from pcreg.pipeline.prior import prior_on_moving

    rng = np.random.default_rng(5)
    q = rng.uniform(0, 1, (48, 64)).astype(np.float32)
    grid = np.dstack(np.meshgrid(np.arange(64, dtype=np.float32), np.arange(48, dtype=np.float32)))
    field = grid + rng.normal(0, 4, grid.shape).astype(np.float32)
    field[0, :5] = -50.0  # off the key frame: pi there
    for motion in (field, rigid2d(0.1, 2.0, -1.5), None):
        expected, _ = warp_prior(q, motion, shape=(48, 64), pi=0.3)
        assert np.array_equal(prior_on_moving(q, motion, shape=(48, 64), pi=0.3), expected)
    assert np.all(prior_on_moving(q, field, shape=(48, 64), pi=0.3)[0, :5] == np.float32(0.3))
    with pytest.raises(InputError, match="moving grid"):
        prior_on_moving(q, field, shape=(40, 64), pi=0.3)


def test_choose_weight_trusts_a_good_prior_and_ignores_a_bad_one():
    rng = np.random.default_rng(0)
    truth = (rng.random((50, 50)) < 0.4).astype(np.uint8)
    noisy = np.where(rng.random(truth.shape) < 0.7, truth, 1 - truth)  # classifier right 70% of the time
    d = np.where(noisy == 1, 1.0, -1.0).astype(np.float32)
    good = prior_log_odds(smooth_prior(prior_from_labels(truth, pi=0.4), pi=0.4, sigma=0.0), pi=0.4)
    bad = prior_log_odds(smooth_prior(prior_from_labels(1 - truth, pi=0.4), pi=0.4, sigma=0.0), pi=0.4)
    c_good = choose_weight([(d, good, truth)])
    c_bad = choose_weight([(d, bad, truth)])
    assert c_good.weight > 0 and min(c_good.errors) < 1.0
    assert c_bad.weight == 0.0 and c_bad.errors[0] == pytest.approx(min(c_bad.errors))
    assert c_good.pairs == 1 and c_good.pixels == truth.size
    empty = choose_weight([], default=1.5)
    assert empty.weight == 1.5 and empty.pairs == 0


def test_unknown_truth_is_left_out_of_the_choice():
    truth = np.full((4, 4), 2, np.uint8)
    c = choose_weight([(np.zeros((4, 4), np.float32), np.zeros((4, 4), np.float32), truth)])
    assert c.pairs == 0


@pytest.mark.parametrize("kwargs", [{"eps": 0.0}, {"eps": 1.0}, {"sigma": -1.0}, {"weight": -1.0},
                                    {"weight": float("nan")}, {"grid": ()}])
def test_fusion_config_rejects_bad_values(kwargs):
    with pytest.raises(InputError):
        FusionConfig(**kwargs)
