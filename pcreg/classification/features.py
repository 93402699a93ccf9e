"""Per-pixel features for the naive Bayes terrain classifier, chosen by name.

Every feature is an 8-bit plane (values 0..255), so a Gaussian naive Bayes model over them can be
evaluated exactly through 256-entry lookup tables (see :mod:`pcreg.classification.bayes`).

| name      | planes | what |
|-----------|--------|------|
| `thesis`  | 1 | the thesis's single feature ``w_r R + w_g G + w_b B`` (weights normalised to sum 1), rounded to 8 bits as MATLAB's uint8 arithmetic does |
| `rgb`     | 3 | R, G, B |
| `hsv`     | 3 | OpenCV's 8-bit HSV (H in 0..179, S and V in 0..255) |
| `lab`     | 3 | OpenCV's 8-bit CIE L*a*b* |
| `texture` | 1 | local contrast: 2 x the standard deviation of grey levels in a 7x7 window, clipped to 255 |
| `row`     | 1 | normalised row position ``y / (H - 1)`` in 256 levels (0 top, 255 bottom) |
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from ..errors import InputError
from ..frame import PreparedFrame
from ..validation import short_repr

FEATURES: dict[str, tuple[str, ...]] = {
    "thesis": ("wRGB",),
    "rgb": ("R", "G", "B"),
    "hsv": ("H", "S", "V"),
    "lab": ("L", "a", "b"),
    "texture": ("contrast",),
    "row": ("row",),
}
TEXTURE_WINDOW = 7
DEFAULT_WEIGHTS = (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)
#: The features pcreg's classifier uses unless told otherwise: colour (RGB and HSV) and image row.
DEFAULT_FEATURES: tuple[str, ...] = ("rgb", "hsv", "row")


def parse_features(features: str | Iterable[str]) -> tuple[str, ...]:
    """Feature names as a tuple; accepts ``("rgb", "hsv")``, ``"rgb+hsv"`` or ``"rgb,hsv"``."""
    if isinstance(features, str):
        names = [f for f in features.replace(",", "+").split("+")]
    else:
        try:
            names = list(features)
        except TypeError:
            names = None
        if names is None or not all(isinstance(n, str) for n in names):
            raise InputError(f"features must be a string or a sequence of feature names, got {short_repr(features)}")
    names = [n.strip().lower() for n in names if n.strip()]
    if not names:
        raise InputError("no features given (choose from " + ", ".join(FEATURES) + ")")
    bad = [n for n in names if n not in FEATURES]
    if bad:
        raise InputError(f"unknown feature {bad[0]!r} (choose from {', '.join(FEATURES)})")
    if len(set(names)) != len(names):
        raise InputError(f"feature listed twice in {'+'.join(names)}")
    return tuple(names)


def normalise_weights(weights: Sequence[float] | None) -> tuple[float, float, float]:
    """The thesis feature's (w_r, w_g, w_b), non-negative and scaled to sum to 1."""
    if weights is None:
        return DEFAULT_WEIGHTS
    try:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"thesis weights must be 3 non-negative numbers, got {weights!r:.60}") from None
    if w.shape != (3,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.max() <= 0:
        raise InputError(f"thesis weights must be 3 non-negative numbers, not all zero (got {list(np.ravel(weights))})")
    with np.errstate(over="ignore"):
        if not np.isfinite(w.sum()):  # each finite, their sum beyond float64: scaled by the largest first
            w = w / w.max()
    w = w / w.sum()
    return (float(w[0]), float(w[1]), float(w[2]))


def feature_names(features: str | Iterable[str]) -> tuple[str, ...]:
    """Column names of the feature matrix, e.g. ``("R", "G", "B", "H", "S", "V", "row")``."""
    return tuple(c for f in parse_features(features) for c in FEATURES[f])


def check_image(image) -> np.ndarray:
    """``image`` as a C-contiguous (H, W, 3) uint8 array (no copy when it already is one); a
    :class:`~pcreg.frame.PreparedFrame` is its ``rgb``, checked already."""
    if isinstance(image, PreparedFrame):
        return image.rgb
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise InputError(f"image is empty: {image.shape}")
    return np.ascontiguousarray(image)


def row_levels(height: int) -> np.ndarray:
    """(height,) uint8: the `row` feature of each image row, ``round(255 * y / (H - 1))``."""
    if height <= 1:
        return np.zeros(max(height, 0), dtype=np.uint8)
    return np.rint(np.arange(height, dtype=np.float64) * (255.0 / (height - 1))).astype(np.uint8)


def feature_groups(image: np.ndarray, features: str | Iterable[str] = DEFAULT_FEATURES, *,
                   weights: Sequence[float] | None = None) -> list[tuple[str, np.ndarray]]:
    """Each named feature's planes, computed once.

    image : (H, W, 3) uint8 RGB.
    Returns a list of ``(name, planes)``; ``planes`` is (H, W, c) uint8 for image features and
    (H,) uint8 for `row` (one value per row, to be broadcast along x).
    """
    import cv2

    image = check_image(image)
    names = parse_features(features)
    out: list[tuple[str, np.ndarray]] = []
    gray = None
    for name in names:
        if name == "rgb":
            planes = image
        elif name == "hsv":
            planes = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
        elif name == "lab":
            planes = cv2.cvtColor(image, cv2.COLOR_RGB2Lab)
        elif name == "thesis":
            w = np.asarray(normalise_weights(weights), dtype=np.float64).reshape(1, 3)
            planes = cv2.transform(image, w)  # rounds and saturates to uint8
            planes = planes.reshape(image.shape[0], image.shape[1], 1)
        elif name == "texture":
            if gray is None:
                gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
            k = (TEXTURE_WINDOW, TEXTURE_WINDOW)
            mean = cv2.boxFilter(gray, cv2.CV_32F, k)
            mean_sq = cv2.sqrBoxFilter(gray, cv2.CV_32F, k)
            # np.maximum, not cv2.max: OpenCV reads a 1x1 array beside a number as a scalar (a (4, 1) result)
            var = np.maximum(cv2.subtract(mean_sq, cv2.multiply(mean, mean)), np.float32(0.0))
            # 2 x std, rounded and saturated to 8 bits (values are non-negative, so abs is a no-op)
            planes = cv2.convertScaleAbs(cv2.sqrt(var), alpha=2.0).reshape(image.shape[0], image.shape[1], 1)
        else:  # row
            planes = row_levels(image.shape[0])
        out.append((name, planes))
    return out


def frame_features(image, features: str | Iterable[str] = DEFAULT_FEATURES, *,
                   weights: Sequence[float] | None = None) -> list[tuple[str, np.ndarray]]:
    """:func:`feature_groups` of an (H, W, 3) uint8 image; a :class:`~pcreg.frame.PreparedFrame`'s are made
    once and kept with it, so every classifier of these features finds them there."""
    if isinstance(image, PreparedFrame):
        key = ("features", parse_features(features), normalise_weights(weights))
        return image.derived(key, lambda rgb: feature_groups(rgb, features, weights=weights))
    return feature_groups(image, features, weights=weights)


def table_sum(image, tables: np.ndarray, features: str | Iterable[str] = DEFAULT_FEATURES, *,
              weights: Sequence[float] | None = None, groups=None) -> np.ndarray:
    """(H, W) sum over the image's features of ``tables[f][x_f]``: one 256-entry table (F, 256) float32 or
    float64 per feature, looked up at each pixel's 8-bit value (what a naive Bayes over these features
    sums). groups : the image's :func:`frame_features`, when already computed."""
    import cv2

    image = check_image(image)
    h, w = image.shape[:2]
    acc = None
    row_term = None
    f = 0
    if groups is None:
        groups = frame_features(image, features, weights=weights)
    for name, planes in groups:
        if name == "row":
            row_term = tables[f][planes]
            f += 1
            continue
        c = planes.shape[-1]
        lut = np.ascontiguousarray(tables[f:f + c].T.reshape(1, 256, c))
        looked = cv2.LUT(planes, lut)
        if c > 1:
            looked = cv2.transform(looked, np.ones((1, c), dtype=np.float64))
        elif looked.ndim == 3:
            looked = looked[:, :, 0]
        acc = looked if acc is None else cv2.add(acc, looked)
        f += c
    if acc is None:
        acc = np.zeros((h, w), dtype=tables.dtype)
    if row_term is not None:
        acc = acc + row_term[:, None].astype(acc.dtype)
    return acc


def feature_planes(image: np.ndarray, features: str | Iterable[str] = DEFAULT_FEATURES, *,
                   weights: Sequence[float] | None = None) -> np.ndarray:
    """All features of every pixel as one (H, W, F) uint8 array (F = ``len(feature_names(features))``)."""
    image = check_image(image)
    h, w = image.shape[:2]
    parts = []
    for name, planes in feature_groups(image, features, weights=weights):
        if name == "row":
            planes = np.broadcast_to(planes[:, None, None], (h, w, 1))
        parts.append(planes)
    return np.concatenate(parts, axis=2)


def feature_matrix(image: np.ndarray, features: str | Iterable[str] = DEFAULT_FEATURES, *,
                   weights: Sequence[float] | None = None) -> np.ndarray:
    """(H*W, F) float64, pixels in row-major order: the same numbers as :func:`feature_planes`,
    laid out for scikit-learn."""
    planes = feature_planes(image, features, weights=weights)
    return planes.reshape(-1, planes.shape[2]).astype(np.float64)
