"""pcreg.register_dense when the finest level has nothing to work on: images whose texture only the coarse
levels see (a defocused frame, one edge beside black padding)."""

from __future__ import annotations

import cv2
import numpy as np

from pcreg import register_dense


def _defocused(h=240, w=320, seed=0):
    """Noise blurred by 12 px: coarse levels find gradients above their noise, the finest none."""
    noise = np.random.default_rng(seed).integers(0, 255, (h, w, 3)).astype(np.uint8)
    return cv2.GaussianBlur(noise, (0, 0), 12)


def test_a_finest_level_without_samples_gives_a_field_marked_without_evidence():
    img = _defocused()
    levels = []
    res = register_dense(img, img, global_result=np.eye(3), callback=lambda it: levels.append(it.level))
    assert min(levels) > res.info["levels"][1]  # the finest level took no step
    assert res.field.shape == img.shape[:2] + (2,) and np.all(np.isfinite(res.field))
    assert res.confidence.shape == img.shape[:2] and float(res.confidence.max()) == 0.0
    assert res.fitness == 0.0
    xs, ys = np.meshgrid(np.arange(320), np.arange(240))
    assert np.abs(res.field - np.dstack([xs, ys])).max() < 0.5  # the same image: the field stays near identity


def test_one_edge_beside_black_padding_gives_a_field_marked_without_evidence():
    img = np.zeros((240, 320, 3), np.uint8)
    img[:, 160:] = 255  # the black half reads as padding: only the coarse levels keep samples on the edge
    res = register_dense(img, img, global_result=np.eye(3))
    assert res.field.shape == (240, 320, 2) and np.all(np.isfinite(res.field))
    assert float(res.confidence.max()) == 0.0 and res.fitness == 0.0
    assert np.isfinite(res.info["evidence"])
