"""Warping a moving image onto the reference image's pixel grid."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

_INTERP = {"linear": cv2.INTER_LINEAR, "nearest": cv2.INTER_NEAREST, "cubic": cv2.INTER_CUBIC}


def warp(moving: np.ndarray, T_ref_mov: np.ndarray, *, shape: tuple[int, ...] | None = None,
         interpolation: str = "linear", fill: float = 0) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``moving`` on the reference grid: ``warped(x) = moving(inv(T_ref_mov) x)``.

    moving : (H, W) or (H, W, C) array (uint8 images, uint8 labels with ``interpolation="nearest"``,
        float32 posteriors, ...).
    T_ref_mov : (3, 3) maps moving pixel coordinates into reference pixel coordinates (affine or projective).
    shape : (H, W) of the reference grid (default: the moving image's).
    Returns ``(warped, valid)``: ``warped`` has the reference's size and ``moving``'s dtype and channels,
    ``fill`` outside; ``valid`` (H, W) bool marks pixels that came from inside the moving image.
    """
    moving = np.asarray(moving)
    if moving.ndim not in (2, 3) or moving.shape[0] == 0 or moving.shape[1] == 0:
        raise InputError(f"warp: expected an (H, W) or (H, W, C) array, got shape {moving.shape}")
    M = np.asarray(T_ref_mov, dtype=np.float64)
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise InputError("warp: T_ref_mov must be a finite 3x3 matrix")
    if abs(np.linalg.det(M)) < 1e-12:
        raise InputError("warp: T_ref_mov is singular")
    if interpolation not in _INTERP:
        raise InputError(f"warp: interpolation must be one of {', '.join(_INTERP)}")
    h, w = (shape[:2] if shape is not None else moving.shape[:2])
    flags = _INTERP[interpolation]
    projective = np.any(M[2, :2] != 0) or M[2, 2] != 1
    src = moving
    if moving.dtype == np.bool_:
        src = moving.astype(np.uint8)
    channels = 1 if src.ndim == 2 else src.shape[2]
    border = (fill,) * min(channels, 4) if channels > 1 else fill

    def one(img, fl, bval):
        if projective:
            return cv2.warpPerspective(img, M, (w, h), flags=fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)
        return cv2.warpAffine(img, M[:2], (w, h), flags=fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)

    if channels > 4:  # OpenCV warps up to 4 channels at once
        warped = np.stack([one(np.ascontiguousarray(src[:, :, c]), flags, fill) for c in range(channels)], axis=2)
    else:
        warped = one(src, flags, border)
    if src.ndim == 3 and warped.ndim == 2:
        warped = warped[:, :, None]
    # Valid: every interpolation weight fell inside the moving image (no blend with ``fill``).
    ones = np.ones(moving.shape[:2], np.float32)
    valid = one(ones, cv2.INTER_NEAREST if interpolation == "nearest" else cv2.INTER_LINEAR, 0) > 0.999
    if moving.dtype == np.bool_:
        warped = warped.astype(bool)
    return warped, valid
