"""Procedural terrain-like textures (seeded): material for registration where edges are dense and repetitive.

Each generator returns an (H, W, 3) uint8 RGB image that depends only on its arguments and ``seed``:

- ``noise``: white noise band-pass filtered at several scales (Gaussian octaves, 1/f-like weights);
- ``grass``: thousands of thin blades, near-vertical, in varied greens over dark soil;
- ``gravel``: packed stones (filled ellipses, shaded, random greys and browns) over sand;
- ``brick``: a running-bond wall of bricks with colour jitter, mortar joints and surface noise;
- ``leaves``: overlapping leaf-like ellipses in autumn colours (occlusion everywhere).

They are not photographs: the benchmark uses them beside real photographs, and the tests use them to
check that registration works, and refuses, where the edge cloud alone is ambiguous.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

KINDS = ("noise", "grass", "gravel", "brick", "leaves")


def _octave_noise(rng: np.random.Generator, h: int, w: int, scales=(1.0, 2.0, 4.0, 8.0, 16.0)) -> np.ndarray:
    """Sum of Gaussian-filtered white noise at ``scales`` (px), each octave normalised to unit std and
    weighted by its scale (a 1/f-like spectrum); result scaled to [0, 1]."""
    acc = np.zeros((h, w), np.float32)
    for s in scales:
        n = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), s)
        acc += (s ** 0.5) * n / max(float(n.std()), 1e-6)
    acc -= acc.min()
    return acc / max(float(acc.max()), 1e-6)


def _noise(rng, h, w):
    n = _octave_noise(rng, h, w)
    tint = rng.uniform(0.6, 1.0, 3).astype(np.float32)
    return np.clip(n[..., None] * tint * 255.0, 0, 255).astype(np.uint8)


def _grass(rng, h, w):
    soil = _octave_noise(rng, h, w, scales=(2.0, 8.0))
    img = np.dstack([60 + 40 * soil, 45 + 30 * soil, 25 + 20 * soil]).astype(np.uint8)
    n = int(h * w / 40)
    x0 = rng.uniform(-5, w + 5, n)
    y0 = rng.uniform(-5, h + 20, n)
    length = rng.uniform(8, 28, n)
    ang = np.deg2rad(rng.normal(-90, 18, n))
    x1 = x0 + length * np.cos(ang)
    y1 = y0 + length * np.sin(ang)
    g = rng.uniform(90, 210, n)
    for i in range(n):
        col = (int(g[i] * rng.uniform(0.35, 0.6)), int(g[i]), int(g[i] * rng.uniform(0.15, 0.35)))
        cv2.line(img, (int(x0[i]), int(y0[i])), (int(x1[i]), int(y1[i])), col, 1, cv2.LINE_AA)
    return img


def _gravel(rng, h, w):
    sand = _octave_noise(rng, h, w, scales=(1.0, 3.0))
    img = np.dstack([150 + 50 * sand, 135 + 45 * sand, 110 + 40 * sand]).astype(np.uint8)
    n = int(h * w / 90)
    for _ in range(n):
        cx, cy = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        a, b = int(rng.uniform(3, 10)), int(rng.uniform(2, 7))
        base = rng.uniform(60, 200)
        col = tuple(int(np.clip(base * f, 0, 255)) for f in rng.uniform(0.8, 1.15, 3))
        cv2.ellipse(img, (cx, cy), (a, b), float(rng.uniform(0, 180)), 0, 360, col, -1, cv2.LINE_AA)
        dark = tuple(int(c * 0.6) for c in col)
        cv2.ellipse(img, (cx, cy), (a, b), float(rng.uniform(0, 180)), 20, 160, dark, 1, cv2.LINE_AA)
    grain = rng.normal(0, 6, (h, w, 1))
    return np.clip(img + grain, 0, 255).astype(np.uint8)


def _brick(rng, h, w):
    mortar = np.array([190, 185, 175], np.float32)
    img = np.empty((h, w, 3), np.float32)
    img[:] = mortar
    bh, bw, joint = int(rng.integers(14, 22)), int(rng.integers(36, 56)), 3
    for r, y in enumerate(range(-bh, h + bh, bh)):
        off = (bw // 2) * (r % 2) + int(rng.integers(-3, 4))
        for x in range(-bw - off, w + bw, bw):
            col = np.array([150, 70, 50], np.float32) * rng.uniform(0.7, 1.2) + rng.normal(0, 12, 3)
            x1, y1 = x + joint // 2, y + joint // 2
            x2, y2 = x + bw - (joint + 1) // 2, y + bh - (joint + 1) // 2
            cv2.rectangle(img, (x1, y1), (x2, y2), tuple(float(c) for c in col), -1)
    grain = _octave_noise(rng, h, w, scales=(1.0, 2.0, 6.0))
    img *= (0.75 + 0.5 * grain)[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def _leaves(rng, h, w):
    img = np.dstack([_octave_noise(rng, h, w, scales=(4.0, 16.0)) * 60 + 30] * 3).astype(np.uint8)
    n = int(h * w / 120)
    palette = np.array([[170, 80, 30], [200, 140, 40], [120, 60, 30], [160, 150, 60], [90, 40, 20]], np.float32)
    for _ in range(n):
        cx, cy = int(rng.uniform(-10, w + 10)), int(rng.uniform(-10, h + 10))
        a, b = int(rng.uniform(6, 16)), int(rng.uniform(3, 7))
        col = palette[rng.integers(len(palette))] * rng.uniform(0.75, 1.2)
        ang = float(rng.uniform(0, 180))
        cv2.ellipse(img, (cx, cy), (a, b), ang, 0, 360, tuple(float(c) for c in np.clip(col, 0, 255)), -1,
                    cv2.LINE_AA)
        t = np.deg2rad(ang)
        cv2.line(img, (int(cx - a * np.cos(t)), int(cy - a * np.sin(t))), (int(cx + a * np.cos(t)),
                 int(cy + a * np.sin(t))), tuple(float(c) * 0.6 for c in col), 1, cv2.LINE_AA)
    return img


_GENERATORS = {"noise": _noise, "grass": _grass, "gravel": _gravel, "brick": _brick, "leaves": _leaves}


def texture(kind: str, *, height: int = 384, width: int = 512, seed: int = 0) -> np.ndarray:
    """An (height, width, 3) uint8 RGB procedural texture of ``kind`` (one of :data:`KINDS`)."""
    if kind not in _GENERATORS:
        raise InputError(f"unknown texture {kind!r}; choose one of {', '.join(KINDS)}")
    if height < 16 or width < 16:
        raise InputError(f"texture size must be at least 16x16, got {width}x{height}")
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    return np.ascontiguousarray(_GENERATORS[kind](rng, int(height), int(width)))
