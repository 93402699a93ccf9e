"""Deterministic test images with rich, non-repeating structure."""

from __future__ import annotations

import cv2
import numpy as np

from pcreg import transforms as tf


def shapes_image(h: int = 240, w: int = 320, seed: int = 0) -> np.ndarray:
    """Random filled rectangles, circles and lines on a smooth gradient: edges in every direction."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.dstack([(60 + 60 * xx / w), (80 + 40 * yy / h), (100 + 30 * np.sin(xx / 37.0))]).astype(np.uint8)
    for _ in range(18):
        color = tuple(int(c) for c in rng.integers(0, 256, 3))
        kind = rng.integers(3)
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(10, 70)), y + int(rng.integers(10, 50))), color, -1)
        elif kind == 1:
            cv2.circle(img, (x, y), int(rng.integers(6, 35)), color, -1)
        else:
            cv2.line(img, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), color, 3)
    return cv2.GaussianBlur(img, (0, 0), 0.8)


def moved(reference: np.ndarray, T_ref_mov: np.ndarray) -> np.ndarray:
    """The moving image whose pixel x shows reference(T_ref_mov x) (black outside)."""
    h, w = reference.shape[:2]
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    if np.any(T_ref_mov[2, :2] != 0):
        return cv2.warpPerspective(reference, T_ref_mov, (w, h), flags=flags)
    return cv2.warpAffine(reference, T_ref_mov[:2], (w, h), flags=flags)


def rigid_about_centre(shape, angle: float, tx: float, ty: float) -> np.ndarray:
    return tf.about_point(tf.rigid2d(angle, tx, ty), tf.image_center(shape))
