"""pcreg.classification.bayes, pcreg.classification.features, pcreg.classification.metrics: the lookup-table Gaussian NB against scikit-learn's."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.naive_bayes import GaussianNB

from pcreg.classification.bayes import NaiveBayesPixelClassifier, class_histograms
from pcreg.classification.weight_search import thesis_weight_search
from pcreg.datasets import synthetic
from pcreg.errors import InputError
from pcreg.classification.features import FEATURES, feature_groups, feature_matrix, feature_names, feature_planes, parse_features
from pcreg.classification.metrics import confusion_matrix, error_from_confusion, error_rate

W, H = 80, 60
WEIGHTS = (0.2, 0.5, 0.3)


@pytest.fixture(scope="module")
def frames():
    return synthetic("syn2b", 5, 0, width=W, height=H)


def _sklearn(frames, features, *, exclude_unknown=True, weights=WEIGHTS):
    x = np.concatenate([feature_matrix(f.image, features, weights=weights) for f in frames])
    y = np.concatenate([f.labels.ravel() for f in frames])
    keep = y < 2 if exclude_unknown else np.ones_like(y, bool)
    return GaussianNB().fit(x[keep], y[keep])


# -- features -------------------------------------------------------------------------------------

def test_parse_features_forms_and_errors():
    assert parse_features("rgb+hsv,row") == ("rgb", "hsv", "row")
    assert parse_features(["Lab", "texture"]) == ("lab", "texture")
    for bad in ("", "rgb+foo", "rgb+rgb"):
        with pytest.raises(InputError):
            parse_features(bad)
    assert feature_names("rgb+row") == ("R", "G", "B", "row")


def test_feature_planes_values(frames):
    img = frames[0].image
    planes = feature_planes(img, tuple(FEATURES), weights=WEIGHTS)
    assert planes.shape == (H, W, len(feature_names(tuple(FEATURES)))) and planes.dtype == np.uint8
    np.testing.assert_array_equal(planes[:, :, 1:4], img)  # rgb follows thesis
    thesis = img.astype(float) @ np.array(WEIGHTS)
    assert np.abs(planes[:, :, 0] - thesis).max() <= 0.5 + 1e-6
    row = planes[:, :, -1]
    assert row[0].max() == 0 and row[-1].min() == 255 and np.all(np.diff(row[:, 0].astype(int)) >= 0)
    flat = np.full((10, 12, 3), 90, np.uint8)
    assert feature_planes(flat, "texture").max() == 0
    assert np.array_equal(feature_matrix(img, "rgb+row"), feature_planes(img, "rgb+row").reshape(-1, 4))


@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (2, 1), (1, 9)])
def test_features_of_an_image_of_one_row_or_column(shape):
    # OpenCV reads a 1x1 array beside a number as a scalar of 4: the texture plane of a 1x1 image came out (4, 1)
    img = np.random.default_rng(0).integers(0, 256, shape + (3,), dtype=np.uint8)
    planes = feature_planes(img, "rgb+hsv+lab+texture+row+thesis")
    assert planes.shape == shape + (12,)
    assert feature_planes(np.full(shape + (3,), 90, np.uint8), "texture").max() == 0


def test_features_do_not_modify_the_image(frames):
    img = np.array(frames[0].image)
    before = img.copy()
    feature_groups(img, tuple(FEATURES), weights=WEIGHTS)
    np.testing.assert_array_equal(img, before)


def test_bad_images_and_weights():
    with pytest.raises(InputError):
        feature_planes(np.zeros((4, 4), np.uint8), "rgb")
    with pytest.raises(InputError):
        feature_planes(np.zeros((4, 4, 3), np.uint8), "thesis", weights=(1, -1, 0))
    with pytest.raises(InputError):
        feature_planes(np.zeros((4, 4, 3), np.uint8), "thesis", weights=(0, 0, 0))


def test_thesis_weights_whose_sum_is_beyond_float64_are_scaled_not_zeroed():
    """Three weights of 1e308 summed to inf and became (0, 0, 0): the thesis feature of every pixel 0, silently."""
    from pcreg.classification.features import normalise_weights

    assert normalise_weights((1e308, 1e308, 1e308)) == pytest.approx((1 / 3, 1 / 3, 1 / 3))
    assert normalise_weights((1e308, 1e308, 0)) == pytest.approx((0.5, 0.5, 0.0))
    img = np.random.default_rng(0).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    np.testing.assert_array_equal(feature_planes(img, "thesis", weights=(1e308,) * 3),
                                  feature_planes(img, "thesis", weights=(1, 1, 1)))


# -- classifier vs scikit-learn ----------------------------------------------------------------------

@pytest.mark.parametrize("features", ["thesis", "rgb", "hsv", "lab", "texture", "row", "rgb+hsv+row",
                                      "thesis+lab+texture+row"])
def test_matches_sklearn_gaussian_nb(frames, features):
    train, test = frames[:3], frames[3]
    clf = NaiveBayesPixelClassifier(features, weights=WEIGHTS).fit([f.image for f in train], [f.labels for f in train])
    ref = _sklearn(train, features)
    np.testing.assert_array_equal(clf.classes_, ref.classes_)
    np.testing.assert_allclose(clf.theta_, ref.theta_, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(clf.var_, ref.var_, rtol=1e-10)
    np.testing.assert_allclose(clf.class_prior_, ref.class_prior_, rtol=1e-12)
    x = feature_matrix(test.image, features, weights=WEIGHTS)
    lp = clf.predict_log_proba(test.image)
    assert lp.shape == (H, W, 3) and np.all(lp[:, :, 2] == -np.inf)
    np.testing.assert_allclose(lp[:, :, :2], ref.predict_log_proba(x).reshape(H, W, 2), rtol=1e-9, atol=1e-9)
    pred = clf.predict(test.image)
    assert pred.shape == (H, W) and pred.dtype == np.uint8
    # the fast float32 path may differ from sklearn only at near-ties
    assert (pred == ref.predict(x).reshape(H, W)).mean() > 0.999
    np.testing.assert_allclose(np.exp(lp).sum(-1), 1.0, rtol=1e-9)


def test_unknown_as_a_third_class_matches_sklearn(frames):
    clf = NaiveBayesPixelClassifier("rgb+row", exclude_unknown=False, density="gaussian").fit(
        [f.image for f in frames[:2]], [f.labels for f in frames[:2]])
    ref = _sklearn(frames[:2], "rgb+row", exclude_unknown=False)
    assert list(clf.classes_) == [0, 1, 2]
    x = feature_matrix(frames[4].image, "rgb+row")
    np.testing.assert_allclose(clf.predict_log_proba(frames[4].image), ref.predict_log_proba(x).reshape(H, W, 3),
                               rtol=1e-9, atol=1e-9)
    assert (clf.predict(frames[4].image) == ref.predict(x).reshape(H, W)).mean() > 0.999
    nb = clf.to_sklearn()
    np.testing.assert_allclose(nb.predict_log_proba(x), ref.predict_log_proba(x), rtol=1e-9, atol=1e-9)


def test_single_arrays_lists_and_histograms_agree(frames):
    a, b = frames[0], frames[1]
    one = NaiveBayesPixelClassifier("rgb").fit(a.image, a.labels)
    lst = NaiveBayesPixelClassifier("rgb").fit([a.image], [a.labels])
    np.testing.assert_array_equal(one.theta_, lst.theta_)
    both = class_histograms([a.image, b.image], [a.labels, b.labels], "rgb")
    summed = class_histograms(a.image, a.labels, "rgb") + class_histograms(b.image, b.labels, "rgb")
    np.testing.assert_array_equal(both, summed)
    assert both[2].sum() == 0


def test_inputs_are_not_modified(frames):
    img, lab = np.array(frames[0].image), np.array(frames[0].labels)
    img0, lab0 = img.copy(), lab.copy()
    clf = NaiveBayesPixelClassifier().fit([img], [lab])
    clf.predict(img)
    clf.predict_log_proba(img)
    np.testing.assert_array_equal(img, img0)
    np.testing.assert_array_equal(lab, lab0)


def test_classifier_errors(frames):
    img = frames[0].image
    with pytest.raises(InputError, match="only one class"):
        NaiveBayesPixelClassifier().fit(img, np.zeros((H, W), np.uint8))
    with pytest.raises(InputError, match="only one class"):
        NaiveBayesPixelClassifier().fit(img, np.where(frames[0].labels == 1, 1, 2).astype(np.uint8))
    with pytest.raises(InputError, match="not fitted"):
        NaiveBayesPixelClassifier().predict(img)
    with pytest.raises(InputError, match="do not match"):
        NaiveBayesPixelClassifier().fit(img, np.zeros((H, W + 1), np.uint8))
    with pytest.raises(InputError, match="0 ground"):
        NaiveBayesPixelClassifier().fit(img, np.full((H, W), 3, np.uint8))
    with pytest.raises(InputError):
        NaiveBayesPixelClassifier().fit([img, img], [frames[0].labels])


def test_classes_other_than_ground_obstacle(frames):
    lab = np.where(frames[0].labels == 1, 2, 0).astype(np.uint8)
    clf = NaiveBayesPixelClassifier("rgb", exclude_unknown=False).fit(frames[0].image, lab)
    assert list(clf.classes_) == [0, 2]
    assert set(np.unique(clf.predict(frames[1].image))) <= {0, 2}
    assert np.all(clf.predict_log_proba(frames[1].image)[:, :, 1] == -np.inf)


# -- weight search ----------------------------------------------------------------------------------

def test_weight_search_is_seeded_and_exact(frames):
    imgs, labs = [f.image for f in frames[:3]], [f.labels for f in frames[:3]]
    s = thesis_weight_search(imgs, labs, n_trials=12, seed=5)
    again = thesis_weight_search(imgs, labs, n_trials=12, seed=5)
    other = thesis_weight_search(imgs, labs, n_trials=12, seed=6)
    np.testing.assert_array_equal(s.trial_errors, again.trial_errors)
    assert not np.array_equal(s.trial_weights, other.trial_weights)
    assert s.trial_weights.shape == (12, 3) and np.allclose(s.trial_weights.sum(1), 1.0)
    assert s.error == s.trial_errors.min()
    clf = NaiveBayesPixelClassifier("thesis", weights=s.weights).fit(imgs, labs)
    assert clf.score_error(imgs, labs) == pytest.approx(s.error, abs=0.05)
    for w, e in zip(s.trial_weights[:3], s.trial_errors[:3]):
        c = NaiveBayesPixelClassifier("thesis", weights=w).fit(imgs, labs)
        assert c.score_error(imgs, labs) == pytest.approx(e, abs=0.05)


def test_weight_search_with_no_smoothing_leaves_out_the_weights_the_fit_refuses():
    """var_smoothing 0: a trial whose feature takes one value over a class cannot be fitted (the classifier
    refuses it); it was scored from NaN tables (50% error for two colours any weight tells apart)."""
    img = np.zeros((20, 20, 3), np.uint8)
    img[:10], img[10:] = (200, 10, 10), (10, 10, 200)
    lab = (np.arange(20)[:, None] >= 10).repeat(20, axis=1).astype(np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="var_smoothing > 0"):
            thesis_weight_search(img, lab, n_trials=5, var_smoothing=0)
        noisy = img.copy()
        noisy[0, :10], noisy[19, :10] = (210, 20, 10), (20, 20, 190)  # each class of two colours: a spread
        s = thesis_weight_search(noisy, lab, n_trials=8, var_smoothing=0)
    assert s.error == 0.0 and np.isfinite(s.trial_errors).sum() >= 1
    assert json.loads(json.dumps(s.to_dict(), allow_nan=False))["error"] == 0.0


def test_weight_search_with_unknown_as_a_class_scores_the_classifier_it_picks_for():
    """exclude_unknown=False with unknown pixels: three classes, which the classifier models by their smoothed
    histograms; each trial was scored with Gaussians instead (a class of two colours, dark and bright: the search
    said 1.15% for weights whose classifier is 0.02% wrong)."""
    rng = np.random.default_rng(2)
    img, lab = np.zeros((60, 80, 3), np.uint8), np.repeat(np.arange(3, dtype=np.uint8), 20)[:, None].repeat(80, axis=1)
    two = rng.normal([30, 30, 128], [6, 6, 30], (20, 80, 3))
    two[:, ::2] = rng.normal([220, 220, 128], [6, 6, 30], (20, 40, 3))
    img[:20] = two.clip(0, 255)
    img[20:40] = rng.normal([125, 125, 128], [6, 6, 30], (20, 80, 3)).clip(0, 255)
    img[40:] = rng.normal([128, 60, 60], [30, 6, 6], (20, 80, 3)).clip(0, 255)
    s = thesis_weight_search(img, lab, n_trials=30, exclude_unknown=False)
    for w, e in zip(s.trial_weights, s.trial_errors):
        clf = NaiveBayesPixelClassifier("thesis", weights=w, exclude_unknown=False).fit(img, lab)
        assert clf.score_error(img, lab, exclude_unknown=False) == pytest.approx(e, abs=0.05)


def test_the_weight_search_under_its_old_module_warns_and_is_the_same():
    import pcreg.classification.bayes as bayes
    from pcreg.classification import weight_search

    for name in ("thesis_weight_search", "WeightSearch", "colour_counts"):
        with pytest.warns(DeprecationWarning, match=f"use pcreg.classification.weight_search.{name}"):
            assert getattr(bayes, name) is getattr(weight_search, name)
    with pytest.raises(AttributeError):
        bayes.no_such_name  # noqa: B018


# -- metrics ----------------------------------------------------------------------------------------

def test_error_rate_and_confusion():
    truth = np.array([[0, 0, 1, 1], [2, 2, 0, 1]], np.uint8)
    pred = np.array([[0, 1, 1, 0], [0, 1, 0, 1]], np.uint8)
    conf = confusion_matrix(pred, truth)
    np.testing.assert_array_equal(conf, [[2, 1, 0], [1, 2, 0], [0, 0, 0]])
    assert error_rate(pred, truth) == pytest.approx(100 * 2 / 6)
    mask = np.array([[1, 0, 1, 1], [1, 1, 1, 1]], bool)
    assert error_rate(pred, truth, mask=mask) == pytest.approx(100 * 1 / 5)
    assert confusion_matrix(pred, truth, exclude_unknown=False)[2].sum() == 2
    assert np.isnan(error_rate(pred, np.full_like(truth, 2)))
    with pytest.raises(InputError):
        error_rate(pred, truth[:, :3])


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30), st.integers(0, 2**31 - 1))
def test_confusion_counts_every_scored_pixel(h, w, seed):
    rng = np.random.default_rng(seed)
    truth = rng.integers(0, 3, (h, w)).astype(np.uint8)
    pred = rng.integers(0, 2, (h, w)).astype(np.uint8)
    conf = confusion_matrix(pred, truth)
    assert conf.sum() == np.count_nonzero(truth < 2)
    e = error_from_confusion(conf)
    if conf.sum():
        assert e == pytest.approx(100 * np.mean(pred[truth < 2] != truth[truth < 2]))


def test_decision_function_is_the_log_odds_of_predict_proba():
    frames = synthetic("syn1a", 2, 3, width=96, height=72)
    clf = NaiveBayesPixelClassifier("rgb+hsv+row").fit(frames[0].image, frames[0].labels)
    d = clf.decision_function(frames[1].image)
    assert d.dtype == np.float32 and d.shape == frames[1].labels.shape
    logp = clf.predict_log_proba(frames[1].image)
    np.testing.assert_allclose(d, logp[:, :, 1] - logp[:, :, 0], atol=1e-3)
    np.testing.assert_array_equal((d > 0).astype(np.uint8), clf.predict(frames[1].image))


def test_decision_function_needs_two_classes():
    frames = synthetic("syn1a", 1, 1, width=64, height=48)
    three = NaiveBayesPixelClassifier("rgb", exclude_unknown=False).fit(frames[0].image, frames[0].labels)
    with pytest.raises(InputError, match="two-class"):
        three.decision_function(frames[0].image)


def test_no_variance_smoothing_and_a_constant_feature_is_refused_not_nan():
    """With ``var_smoothing=0`` a class whose training pixels share one value of a feature (obstacle labelled
    along one row: its row feature) has a variance of 0, and its Gaussian tables held inf and NaN: naive Bayes
    gave NaN log-odds without a word, and a stream fitted on it stopped on an AssertionError ('a confidence
    came out NaN'). It is refused, naming the class, the feature and what to do."""
    from pcreg.pipeline.stream import Propagator

    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    labels = np.zeros((48, 64), np.uint8)
    labels[30, :] = 1
    with pytest.raises(InputError, match=r"obstacle.*'row'.*var_smoothing"):
        NaiveBayesPixelClassifier(var_smoothing=0).fit(image, labels)
    with pytest.raises(InputError, match="var_smoothing"):
        Propagator(NaiveBayesPixelClassifier("rgb+hsv+row", var_smoothing=0).fit(image, labels))
    # the histogram density has no variance to divide by: taken as it is; and a smoothing > 0 is fitted finite
    for clf in (NaiveBayesPixelClassifier(var_smoothing=0, density="histogram").fit(image, labels),
                NaiveBayesPixelClassifier().fit(image, labels)):
        assert np.all(np.isfinite(clf.decision_function(image)))
