"""Warping a moving image onto the reference image's pixel grid."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError
from ..validation import check_float

# OpenCV's remap supports these (float16 is warped as float32; bool as uint8).
_DTYPES = tuple(np.dtype(d) for d in (np.bool_, np.uint8, np.uint16, np.int16, np.float16, np.float32, np.float64))

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
    if moving.dtype not in _DTYPES:
        raise InputError(f"warp: unsupported dtype {moving.dtype} (use {', '.join(str(np.dtype(d)) for d in _DTYPES)})")
    h, w = _check_shape(shape if shape is not None else moving.shape[:2])
    try:
        fill = check_float(fill, "warp: fill")
    except InputError:
        raise InputError(f"warp: fill must be a finite number, got {fill!r}") from None
    flags = _INTERP[interpolation]
    projective = np.any(M[2, :2] != 0) or M[2, 2] != 1
    src = moving
    if moving.dtype == np.bool_:
        src = moving.astype(np.uint8)
    elif moving.dtype == np.float16:
        src = moving.astype(np.float32)
    channels = 1 if src.ndim == 2 else src.shape[2]
    border = (fill,) * min(channels, 4) if channels > 1 else fill

    def one(img, fl, bval):
        if projective:
            return cv2.warpPerspective(img, M, (w, h), flags=fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)
        return cv2.warpAffine(img, M[:2], (w, h), flags=fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)

    try:
        if channels > 4:  # OpenCV warps up to 4 channels at once
            warped = np.stack([one(np.ascontiguousarray(src[:, :, c]), flags, fill) for c in range(channels)], axis=2)
        else:
            warped = one(src, flags, border)
    except cv2.error as exc:
        raise InputError(f"warp: OpenCV refused the input ({str(exc).strip().splitlines()[-1][:160]})") from None
    if src.ndim == 3 and warped.ndim == 2:
        warped = warped[:, :, None]
    # Valid: every interpolation weight fell inside the moving image (no blend with ``fill``).
    ones = np.ones(moving.shape[:2], np.float32)
    valid = one(ones, cv2.INTER_NEAREST if interpolation == "nearest" else cv2.INTER_LINEAR, 0) > 0.999
    if moving.dtype == np.bool_:
        warped = warped.astype(bool)
    elif moving.dtype == np.float16:
        warped = warped.astype(np.float16)
    return warped, valid


def _check_shape(shape) -> tuple[int, int]:
    """(H, W) of the output grid: two positive integers whose product is within the pixel limit."""
    from ..validation import max_pixels

    try:
        h, w = (int(v) for v in tuple(shape)[:2])
        ok = len(tuple(shape)) >= 2 and all(float(v) == int(v) for v in tuple(shape)[:2])
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"warp: shape must be (H, W) integers, got {shape!r}") from None
    if not ok or h < 1 or w < 1 or h > 32767 or w > 32767:
        raise InputError(f"warp: shape must be (H, W) with 1 <= H, W <= 32767, got {tuple(shape)!r}")
    if h * w > max_pixels():
        raise InputError(f"warp: a {w}x{h} grid exceeds the pixel limit {max_pixels()} (PCREG_MAX_PIXELS)")
    return h, w
