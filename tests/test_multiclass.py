"""The stream with more than two classes (pcreg.pipeline.multiclass): CamVid's eleven classes on a real clip."""

from __future__ import annotations

import numpy as np
import pytest

from pcreg.classes import CAMVID11, LAGR
from pcreg.errors import InputError
from pcreg.pipeline import multiclass
from pcreg.pipeline.stream import Propagator


def _clip(shared_data, n=4):
    import cv2

    folder = shared_data / "camvid" / "0001TP"
    names = sorted(p.name for p in (folder / "images").iterdir())[:n]
    images = [cv2.imread(str(folder / "images" / m))[:, :, ::-1].copy() for m in names]
    labels = [cv2.imread(str(folder / "labels" / m), cv2.IMREAD_UNCHANGED) for m in names]
    return images, labels


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_eleven_classes_follow_the_clip(shared_data, scale):
    """Every label is one of the key frame's classes, each confidence in [1/K, 1], and the propagated
    labels are nearer the truth than the key frame's labels left where they are."""
    images, labels = _clip(shared_data)
    prop = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, scale=scale)
    trained = set(np.unique(labels[0]).tolist()) - {CAMVID11.unknown}
    errors, unmoved = [], []
    for image, truth in zip(images[1:], labels[1:]):
        out = prop.step(image)
        assert out.shape == truth.shape and out.dtype == np.uint8
        assert set(np.unique(out).tolist()) <= trained
        conf = prop.last.confidence
        k = len(trained)
        assert conf.shape == truth.shape and conf.min() >= 1.0 / k - 1e-6 and conf.max() <= 1.0
        assert prop.last.log_odds.shape[2] == k
        iou = prop.last.predicted_iou
        assert iou and all(0.0 <= v <= 1.0 for v in iou.values()) and set(iou) <= trained
        known = truth != CAMVID11.unknown
        errors.append(np.mean(out[known] != truth[known]))
        unmoved.append(np.mean(labels[0][known] != truth[known]))
    assert np.mean(errors) < np.mean(unmoved)


def test_two_classes_stay_log_odds(shared_data):
    """A LAGR key frame keeps the two-class step: (H, W) log-odds, no per-class IoU."""
    images, labels = _clip(shared_data, 2)
    lut = np.array([2, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 2] + [2] * 244, np.uint8)
    prop = Propagator.from_key_frame(images[0], lut[labels[0]], classes=LAGR)
    prop.step(images[1])
    assert prop.last.log_odds.ndim == 2 and prop.last.predicted_iou is None
    assert "predicted_iou" not in prop.last.to_dict()


def test_a_label_outside_the_table_is_refused(shared_data):
    images, labels = _clip(shared_data, 1)
    bad = labels[0].copy()
    bad[0, 0] = 40
    with pytest.raises(InputError, match="label value 40"):
        Propagator.from_key_frame(images[0], bad, classes=CAMVID11)


def test_the_prior_is_the_two_class_prior_class_by_class():
    """At two classes the evidence of class 1 over class 0 is the two-class prior's log-odds."""
    from pcreg.classification.fusion import label_prior, prior_log_odds

    rng = np.random.default_rng(0)
    lab = rng.integers(0, 3, (40, 64)).astype(np.uint8)
    pi = np.array([0.3, 0.7])
    lp = multiclass.prior_log_probs(multiclass.class_prior_maps(lab, np.array([0, 1]), pi), pi)
    two = prior_log_odds(label_prior(lab, pi=0.7), pi=0.7)
    assert np.allclose(lp[:, :, 1] - lp[:, :, 0], two, atol=1e-4)


def test_predicted_iou_counts_misses_by_the_runner_up():
    labels = np.array([[0, 0, 1, 1]], np.uint8)
    conf = np.array([[1.0, 0.5, 1.0, 1.0]], np.float32)
    second = np.array([[1, 1, 0, 0]], np.uint8)
    iou = multiclass.predicted_iou(labels, conf, second, [0, 1])
    assert iou[0] == pytest.approx(1.5 / 2.0)  # tp 1.5, fp 0.5, no miss
    assert iou[1] == pytest.approx(2.0 / 2.5)  # tp 2, a miss of 0.5
