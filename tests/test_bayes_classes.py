"""pcreg.classification.bayes over K classes of a class table: against scikit-learn's GaussianNB, per-class
scores and log-posteriors, the unknown left out, the two-class outputs unchanged, learning's refit keeping
the table; on synthetic eleven-class frames and on the shared CamVid clips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sklearn.naive_bayes import GaussianNB

from pcreg.classes import CAMVID11, LAGR, ClassTable, LabelClass
from pcreg.classification.bayes import NaiveBayesPixelClassifier, class_histograms, fit_classifier
from pcreg.classification.features import feature_matrix
from pcreg.classification.metrics import confusion_matrix
from pcreg.datasets import synthetic
from pcreg.errors import InputError

CAMVID = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "camvid" / "0001TP"
FEATURES = "rgb+hsv+row"


def _eleven(seed: int = 0, shape=(48, 64)):
    """Frames whose eleven classes are blocks of their own colour (plus noise), and void pixels."""
    rng = np.random.default_rng(seed)
    h, w = shape
    labels = (np.arange(w)[None, :] * 11 // w).repeat(h, axis=0).astype(np.uint8)
    labels[: h // 6] = 11  # void
    means = rng.integers(20, 235, size=(12, 3))
    image = np.clip(means[labels] + rng.normal(0, 12, size=(h, w, 3)), 0, 255).astype(np.uint8)
    return image, labels


def _sklearn(images, labels, unknown):
    x = np.concatenate([feature_matrix(im, FEATURES) for im in images])
    y = np.concatenate([lab.ravel() for lab in labels])
    return GaussianNB().fit(x[y != unknown], y[y != unknown])


def test_k_classes_match_sklearn():
    image, labels = _eleven()
    clf = NaiveBayesPixelClassifier(FEATURES, classes=CAMVID11, density="gaussian").fit(image, labels)
    assert clf.classes_.tolist() == list(range(11)) and clf.counts_.shape == (12, 7, 256)
    assert not clf.counts_[11].any()  # void never counted
    nb = _sklearn([image], [labels], 11)
    np.testing.assert_allclose(clf.theta_, nb.theta_, rtol=1e-10)
    np.testing.assert_allclose(clf.var_, nb.var_, rtol=1e-9)
    np.testing.assert_allclose(clf.class_prior_, nb.class_prior_, rtol=1e-12)
    test, _ = _eleven(1)
    x = feature_matrix(test, FEATURES)
    ref = nb.predict_log_proba(x).reshape(test.shape[0], test.shape[1], 11)
    logp = clf.log_posteriors(test)
    assert logp.shape == (*test.shape[:2], 11) and logp.dtype == np.float32
    np.testing.assert_allclose(logp, ref, atol=2e-3)
    np.testing.assert_allclose(np.exp(logp).sum(axis=-1), 1.0, atol=1e-5)
    scores = clf.class_scores(test)
    assert scores.dtype == np.float32 and scores.shape == logp.shape
    np.testing.assert_allclose(scores, clf.joint_log_likelihood(test), rtol=1e-5, atol=1e-3)
    assert (clf.predict(test) == nb.predict(x).reshape(test.shape[:2])).mean() > 0.999
    full = clf.predict_log_proba(test)
    assert full.shape[-1] == 12 and np.isneginf(full[:, :, 11]).all()
    # the features made once, handed over: the same scores
    np.testing.assert_array_equal(clf.class_scores(test, groups=clf.feature_groups(test)), scores)


def test_classes_present_only_and_errors():
    image, labels = _eleven()
    sub = np.where(labels > 4, 11, labels).astype(np.uint8)  # only sky..pavement drawn
    clf = fit_classifier([type("F", (), {"image": image, "labels": sub})()], features=FEATURES, classes="camvid11")
    assert clf.classes_.tolist() == [0, 1, 2, 3, 4] and clf.class_scores(image).shape[-1] == 5
    assert "sky" in repr(clf)
    with pytest.raises(InputError, match="2 unknown; got 3 in training pair 0"):
        NaiveBayesPixelClassifier(FEATURES).fit(image, labels)  # LAGR's table: 11 is no class
    one = np.where(labels == 3, 3, 11).astype(np.uint8)
    with pytest.raises(InputError, match=r"only one class \(road\); need at least two"):
        NaiveBayesPixelClassifier(FEATURES, classes=CAMVID11).fit(image, one)
    with pytest.raises(InputError, match=r"histograms must be \(12, 7, 256\)"):
        NaiveBayesPixelClassifier(FEATURES, classes=CAMVID11).fit_histograms(np.zeros((3, 7, 256), np.int64))
    gap = ClassTable((LabelClass(0, "a", (1, 1, 1)), LabelClass(5, "b", (2, 2, 2)), LabelClass(9, "u", (0, 0, 0))), 9)
    with pytest.raises(InputError, match="got 3"):
        class_histograms(image, np.full(labels.shape, 3, np.uint8), FEATURES, classes=gap)


def test_two_classes_scores_are_the_log_odds():
    frames = synthetic("syn2b", 3, 0, width=80, height=60)
    clf = NaiveBayesPixelClassifier(FEATURES).fit([f.image for f in frames[:2]], [f.labels for f in frames[:2]])
    assert clf.class_table is LAGR
    img = frames[2].image
    s = clf.class_scores(img)
    np.testing.assert_allclose(s[:, :, 1] - s[:, :, 0], clf.decision_function(img), atol=2e-3)
    np.testing.assert_array_equal(np.argmax(s, axis=-1).astype(np.uint8) == 1, clf.decision_function(img) > 0)


def test_class_scores_of_the_row_feature_alone():
    # the row is one value a row: the scores are each row's, the same along it (no image feature to read)
    image, labels = _eleven()
    labels = (np.arange(labels.shape[0])[:, None] * 11 // labels.shape[0]).repeat(labels.shape[1], 1).astype(np.uint8)
    clf = NaiveBayesPixelClassifier("row", classes=CAMVID11).fit(image, labels)
    s = clf.class_scores(image)
    assert s.shape == image.shape[:2] + (len(clf.classes_),) and s.dtype == np.float32
    np.testing.assert_array_equal(s, s[:, :1].repeat(s.shape[1], axis=1))
    np.testing.assert_allclose(s - s.max(axis=2, keepdims=True), clf.log_posteriors(image)
                               - clf.log_posteriors(image).max(axis=2, keepdims=True), atol=1e-3)
    np.testing.assert_array_equal(clf.classes_[np.argmax(s, axis=2)], clf.predict(image))


def test_confusion_matrix_over_a_table():
    t = np.array([[0, 3, 11], [10, 3, 3]])
    p = np.array([[0, 4, 5], [10, 3, 2]])
    conf = confusion_matrix(p, t, classes=CAMVID11)
    assert conf.shape == (12, 12) and conf.sum() == 5 and conf[3, 4] == 1 and conf[3, 3] == 1
    assert confusion_matrix(p, t, classes=CAMVID11, exclude_unknown=False).sum() == 6


def test_error_rate_takes_a_table_by_name_and_refuses_values_that_are_no_class():
    from pcreg import error_rate

    t = np.array([[0, 3, 11], [10, 3, 3]], np.uint8)
    p = np.array([[0, 4, 5], [10, 3, 2]], np.uint8)
    assert error_rate(p, t, classes="camvid11") == error_rate(p, t, classes=CAMVID11) == 40.0
    gaps = ClassTable((LabelClass(0, "road", (1, 2, 3)), LabelClass(5, "car", (4, 5, 6)),
                       LabelClass(200, "void", (0, 0, 0))), 200)
    assert error_rate(np.array([[0, 5, 5]]), np.array([[0, 5, 200]]), classes=gaps) == 0.0
    with pytest.raises(InputError, match="truth label 3 is not a class id"):  # was scored as a known pixel
        error_rate(np.array([[0, 5, 5]]), np.array([[0, 3, 5]]), classes=gaps)
    with pytest.raises(InputError, match="predicted label 7 is not a class id"):
        error_rate(np.array([[0, 7, 5]]), np.array([[0, 5, 5]]), classes=gaps)
    with pytest.raises(InputError, match="neither a built-in class table"):
        error_rate(p, t, classes="no such table")


def test_learning_refits_in_the_same_table():
    from pcreg.pipeline.learning import STREAM_LEARNING, Learner

    image, labels = _eleven()
    clf = NaiveBayesPixelClassifier(FEATURES, classes=CAMVID11).fit(image, labels)
    learner = Learner(clf, STREAM_LEARNING)
    learner.restore(clf.counts_ * 0.5)
    assert learner.classifier.class_table is CAMVID11 and learner.classifier.classes_.tolist() == list(range(11))


@pytest.mark.data
@pytest.mark.skipif(not CAMVID.is_dir(), reason="needs ../shared/data/camvid (the shared CamVid clips)")
def test_camvid_eleven_classes_against_sklearn():
    import cv2

    from types import SimpleNamespace

    from pcreg.classes import read_label_png

    names = sorted(p.name for p in (CAMVID / "labels").glob("*.png"))[:2]
    # (pcreg.datasets.Frame holds labels 0, 1, 2 only, so a plain pair of image and labels)
    key, later = (SimpleNamespace(image=cv2.imread(str(CAMVID / "images" / n))[:, :, ::-1].copy(),
                                  labels=read_label_png(CAMVID / "labels" / n, CAMVID11)) for n in names)
    clf = NaiveBayesPixelClassifier(FEATURES, classes=CAMVID11, density="gaussian").fit(key.image, key.labels)
    nb = _sklearn([key.image], [key.labels], 11)
    # the default with eleven classes, smoothed histograms, labels the next frame better than the Gaussians
    hist = fit_classifier([key], features=FEATURES, classes=CAMVID11)
    known = later.labels != 11
    right = [(c.predict(later.image) == later.labels)[known].mean() for c in (hist, clf)]
    assert right[0] > right[1] + 0.02, right
    assert clf.classes_.tolist() == nb.classes_.tolist()
    x = feature_matrix(later.image, FEATURES)
    pred = clf.predict(later.image)
    assert (pred == nb.predict(x).reshape(pred.shape)).mean() > 0.999
    logp = clf.log_posteriors(later.image)
    ref = nb.predict_log_proba(x).reshape(logp.shape)
    sure = ref.max(axis=-1) > -1e-3  # where both are far from ties, float32 agrees closely
    np.testing.assert_allclose(logp.max(axis=-1)[sure], ref.max(axis=-1)[sure], atol=2e-3)


def test_many_classes_read_smoothed_histograms():
    """With more than two classes each density is the class's smoothed histogram: a class of two colours
    (a bimodal feature, as buildings or trees are) is told from a class between them, where one Gaussian
    per class puts the middle class's colour inside the two-colour class's bell."""
    from pcreg.classification.bayes import HISTOGRAM_BANDWIDTH, NaiveBayesPixelClassifier

    rng = np.random.default_rng(3)
    h, w = 60, 90
    labels = np.repeat(np.arange(3, dtype=np.uint8), w // 3)[None, :].repeat(h, axis=0)
    grey = np.where(labels == 0, np.where(rng.random((h, w)) < 0.5, 40, 210), np.where(labels == 1, 125, 20))
    image = np.clip(grey[..., None] + rng.normal(0, 4, (h, w, 3)), 0, 255).astype(np.uint8)
    auto = NaiveBayesPixelClassifier("rgb", classes=CAMVID11).fit(image, labels)
    gauss = NaiveBayesPixelClassifier("rgb", classes=CAMVID11, density="gaussian").fit(image, labels)
    assert "density" not in repr(auto) and "density='gaussian'" in repr(gauss)
    right_auto = (auto.predict(image) == labels).mean()
    right_gauss = (gauss.predict(image) == labels).mean()
    assert right_auto > 0.99 and right_gauss < right_auto
    # the table is the log of the smoothed, normalised histogram mixed with 1% of a uniform
    from scipy.ndimage import gaussian_filter1d

    counts = auto.counts_[auto.classes_].astype(np.float64)
    smooth = gaussian_filter1d(counts, HISTOGRAM_BANDWIDTH, axis=2, mode="nearest")
    want = np.log(0.99 * smooth / smooth.sum(axis=2, keepdims=True) + 0.01 / 256)
    np.testing.assert_allclose(auto._tables64, want, rtol=1e-12)
    # two classes keep the Gaussian (every two-class result unchanged)
    two = NaiveBayesPixelClassifier("rgb", classes=CAMVID11).fit(image, np.minimum(labels, 1))
    np.testing.assert_allclose(two._tables64[0, 0, 100], -0.5 * np.log(2 * np.pi * two.var_[0, 0])
                               - 0.5 * (100 - two.theta_[0, 0]) ** 2 / two.var_[0, 0])
    with pytest.raises(InputError, match="density"):
        NaiveBayesPixelClassifier("rgb", density="kde")


def test_an_unfitted_copy_keeps_every_option_and_fits_as_the_original():
    image, labels = _eleven()
    clf = NaiveBayesPixelClassifier("rgb+hsv", weights=None, var_smoothing=1e-6, classes=CAMVID11,
                                    density="gaussian").fit(image, labels)
    copy = clf.unfitted()
    assert not hasattr(copy, "classes_") and copy is not clf
    for name in ("features", "weights", "exclude_unknown", "var_smoothing", "priors", "class_table", "density"):
        assert getattr(copy, name) == getattr(clf, name), name
    copy.fit_histograms(clf.counts_)
    np.testing.assert_array_equal(copy.class_scores(image), clf.class_scores(image))
