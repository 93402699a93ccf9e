"""A check of :func:`~pcreg.registration.api.register`'s projective result (which no richer model checks) that
does not read its edges: SIFT features of both images, matched and fitted by a homography (MAGSAC), and the
result compared with that homography where the matches are.

Edge ICP can settle off the alignment with edges that line up all the same (a zoom, a scene that is not one
plane, a whiteboard's lines), and its own evidence cannot tell; a homography of feature matches is found
another way. Where it is strongly supported (:func:`strong`: more inliers than Brown and Lowe's bound on what
chance matches give) and the result moves some point of the moving image inside the hull of those inliers by
more than :data:`AGREE_PX` from where the homography puts it, the result is marked
(:attr:`~pcreg.registration.result.RegistrationResult.features_agree` False). Where the features are weak,
nothing is said. The homography is compared only within its inliers' hull: beyond it, it extrapolates (right
results of the benchmark's views were more than 3 px from it there, none inside; docs/algorithms.md).
"""

from __future__ import annotations

import cv2
import numpy as np

from .global_search import _to_full, gray_level
from .plausibility import SHIFT_PX
from .transforms import apply

MAX_SIDE = 1000
"""Each image is read at the finest pyramid level whose longer side is at most this many px (SIFT at full size
took seconds on 1700 px photographs)."""

N_FEATURES = 4000
"""SIFT features kept an image (OpenCV's strongest)."""

RATIO = 0.8
"""Lowe's ratio test: a match is kept when its descriptor distance is under this share of the second nearest's
(Lowe 2004, Distinctive image features from scale-invariant keypoints, section 7.1)."""

MAGSAC_PX = 3.0
"""The largest residual (px at full size) MAGSAC's homography counts as an inlier's."""

SUPPORT = (8, 0.3)
"""A homography of ``n`` matches in the images' overlap is strongly supported with more than ``8 + 0.3 n``
inliers: Brown and Lowe's test of an image match against chance matches (Brown & Lowe 2007, Automatic
panoramic image stitching using invariant features, section 3.2, eq. 13)."""

AGREE_PX = SHIFT_PX
"""A result agrees with the features' homography when it puts every point of a 16 px grid of the moving image
inside the inliers' hull within this many px of where the homography puts it (the 3 px within which the benches
count a registration right)."""

GRID_PX = 16


def feature_check(reference_image: np.ndarray, moving_image: np.ndarray, T_ref_mov: np.ndarray, *,
                  reference_valid: np.ndarray, moving_valid: np.ndarray, seed: int = 0):
    """``T_ref_mov`` against the homography of the images' SIFT matches (see the module's description).

    reference_image, moving_image : (H, W, 3) uint8 RGB; reference_valid, moving_valid : (H, W) bool usable
    pixels at full size (black padding is left out of the detection).
    Returns a :class:`~pcreg.registration.result.FeatureCheck`, or None where no homography is found (fewer
    than four matches, or MAGSAC finds none)."""
    from .result import FeatureCheck

    matched = _matches(reference_image, moving_image, reference_valid, moving_valid)
    if matched is None:
        return None
    p_mov, p_ref = matched
    cv2.setRNGSeed(int(seed))
    H, mask = cv2.findHomography(p_mov, p_ref, cv2.USAC_MAGSAC, MAGSAC_PX, maxIters=10000, confidence=0.999)
    if H is None or mask is None or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return None
    H = H / H[2, 2]
    inliers = mask.ravel().astype(bool)
    overlap = int(_lands(H, p_mov, reference_image.shape).sum())
    n_inliers = int(inliers.sum())
    supported = strong(n_inliers, overlap)
    shift = _largest_shift(T_ref_mov, H, p_mov[inliers], moving_image.shape, reference_image.shape)
    agree = None if not supported else bool(shift <= AGREE_PX)
    return FeatureCheck(matches=overlap, inliers=n_inliers, largest_shift_px=shift, agree=agree)


def strong(inliers: int, matches: int) -> bool:
    """Whether ``inliers`` of ``matches`` (in the overlap) are more than chance matches give (:data:`SUPPORT`)."""
    return inliers > SUPPORT[0] + SUPPORT[1] * matches


def _level(shape: tuple[int, ...]) -> int:
    """The finest pyramid level at which an image of ``shape`` has its longer side within :data:`MAX_SIDE`."""
    level, side = 0, max(shape[:2])
    while side > MAX_SIDE:
        side, level = (side + 1) // 2, level + 1
    return level


def _matches(reference_image, moving_image, reference_valid, moving_valid):
    """The ratio-tested SIFT matches, (n, 2) float32 moving and reference points at full size; None under four."""
    sift = cv2.SIFT_create(nfeatures=N_FEATURES)
    found = []
    for image, valid in ((reference_image, reference_valid), (moving_image, moving_valid)):
        level = _level(image.shape)
        gray, mask = gray_level(image, level, valid=valid)
        keys, desc = sift.detectAndCompute(gray, mask)
        if desc is None or len(keys) < 4:
            return None
        found.append((_to_full(np.float32([k.pt for k in keys]), level), desc))
    (k_ref, d_ref), (k_mov, d_mov) = found
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(d_mov, d_ref, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < RATIO * p[1].distance]
    if len(good) < 4:
        return None
    return (np.float32([k_mov[m.queryIdx] for m in good]), np.float32([k_ref[m.trainIdx] for m in good]))


def _lands(H: np.ndarray, points: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Which ``points`` ``H`` puts in front of the camera and on an image of ``shape``."""
    q = np.c_[points, np.ones(len(points))] @ np.asarray(H, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
    h, w = shape[:2]
    return (q[:, 2] > 0) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)


def _largest_shift(T: np.ndarray, H: np.ndarray, inliers: np.ndarray, moving_shape: tuple[int, ...],
                   reference_shape: tuple[int, ...]) -> float:
    """The largest distance (px) between where ``T`` and ``H`` put the points of a 16 px grid of the moving image
    inside the hull of ``inliers`` that ``H`` puts on the reference (inf where ``T`` puts one behind the camera;
    0 without such points)."""
    h, w = moving_shape[:2]
    hull = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(hull, np.round(cv2.convexHull(inliers)).astype(np.int32), 1)
    ys, xs = np.mgrid[0:h:GRID_PX, 0:w:GRID_PX]
    inside = hull[ys, xs].ravel() > 0
    points = np.c_[xs.ravel(), ys.ravel()].astype(np.float64)[inside]
    points = points[_lands(H, points, reference_shape)]
    if not len(points):
        return 0.0
    z = np.c_[points, np.ones(len(points))] @ np.asarray(T, dtype=np.float64)[2]
    if np.any(z <= 0):
        return float("inf")
    return float(np.max(np.linalg.norm(apply(T, points) - apply(H, points), axis=1)))
