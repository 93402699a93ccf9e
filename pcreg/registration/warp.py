"""Warping between the moving and the reference image's pixel grids, by a 3x3 transform or a dense field.

A motion is a :class:`~pcreg.registration.motion.Motion`: a (3, 3) ``T_ref_mov`` or an (H, W, 2) field, the
reference coordinates of every moving pixel; anything :meth:`Motion.of <pcreg.registration.motion.Motion.of>`
takes stands for one (a registration result, a matrix, a field array). :func:`warp` brings a moving-frame
array onto the reference grid; :func:`warp_to_moving` brings a reference-frame array onto the moving grid
(labels, priors).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError
from ..validation import check_float, plain_array, short_repr
from .motion import Motion

# OpenCV's remap supports these (float16 is warped as float32; bool as uint8).
_DTYPES = tuple(np.dtype(d) for d in (np.bool_, np.uint8, np.uint16, np.int16, np.float16, np.float32, np.float64))

_INTERP = {"linear": cv2.INTER_LINEAR, "nearest": cv2.INTER_NEAREST, "cubic": cv2.INTER_CUBIC}


def warp(moving: np.ndarray, T_ref_mov, *, shape: tuple[int, ...] | None = None,
         interpolation: str = "linear", fill: float = 0) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``moving`` on the reference grid: ``warped(x) = moving(inv(T_ref_mov) x)``.

    ``T_ref_mov`` may also be a dense field (H, W, 2) of the moving image's size (or a dense result):
    it is inverted numerically (:func:`invert_field`) and the image resampled with ``cv2.remap``;
    ``valid`` then also requires the inversion to have converged there (folds and occlusions do not).

    moving : (H, W) or (H, W, C) array (uint8 images, uint8 labels with ``interpolation="nearest"``,
        float32 posteriors, bool masks: True where at least half of a pixel's interpolation is, ...), in either byte
        order (a big-endian one is warped in the machine's).
    T_ref_mov : (3, 3) maps moving pixel coordinates into reference pixel coordinates (affine or projective).
    shape : (H, W) of the reference grid (default: the moving image's).
    Returns ``(warped, valid)``: ``warped`` has the reference's size and ``moving``'s dtype and channels,
    ``fill`` outside (saturated to an integer dtype's range; beyond a float dtype's, refused); ``valid`` (H, W)
    bool marks pixels that came from inside the moving image, and of a float array are finite (a pixel
    interpolated from an inf or NaN, or a cubic's overshoot past its dtype's range, is not valid).
    """
    moving = plain_array(moving, "warp")
    if moving.ndim not in (2, 3) or moving.shape[0] == 0 or moving.shape[1] == 0:
        raise InputError(f"warp: expected an (H, W) or (H, W, C) array, got shape {moving.shape}")
    fill = _check_remap_input(moving, interpolation, fill)
    motion = _motion(T_ref_mov)
    if motion.field is not None:
        fld = check_field(motion.field, moving.shape[:2])
        h, w = _check_shape(shape if shape is not None else moving.shape[:2])
        inverse, ok = invert_field(fld, (h, w))
        warped, valid = _remap(moving, inverse, interpolation=interpolation, fill=fill)
        return _finite(warped, valid & ok)
    M = motion.matrix
    assert M is not None
    if np.max(np.abs(M)) > 1e12:  # also keeps the determinant below overflow
        raise InputError(f"warp: T_ref_mov has entries up to {np.max(np.abs(M)):.3g} (|m| <= 1e12)")
    if abs(np.linalg.det(M)) < 1e-12:
        raise InputError("warp: T_ref_mov is singular")
    h, w = _check_shape(shape if shape is not None else moving.shape[:2])
    projective = np.any(M[2, :2] != 0) or M[2, 2] != 1

    def one(img, fl, bval):
        if projective:
            return cv2.warpPerspective(img, M, (w, h), flags=fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)
        return cv2.warpAffine(img, M[:2], (w, h), flags=fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)

    return _finite(*_resample(moving, one, interpolation=interpolation, fill=fill))


def _finite(warped: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(warped, valid)`` with ``valid`` false where a float ``warped`` is not finite in every channel."""
    if warped.dtype.kind != "f":
        return warped, valid
    finite = np.isfinite(warped)
    return warped, valid & (finite.all(axis=2) if finite.ndim == 3 else finite)


def _motion(T_ref_mov) -> Motion:
    """``T_ref_mov`` as a :class:`Motion`; what is not one is an :class:`InputError` that names ``warp``."""
    try:
        return Motion.of(T_ref_mov)
    except InputError as exc:
        raise InputError(f"warp: {exc}") from None


def _check_shape(shape) -> tuple[int, int]:
    """(H, W) of the output grid: two positive integers whose product is within the pixel limit."""
    from ..validation import max_pixels

    try:
        h, w = (int(v) for v in tuple(shape)[:2])
        ok = len(tuple(shape)) >= 2 and all(float(v) == int(v) for v in tuple(shape)[:2])
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"warp: shape must be (H, W) integers, got {short_repr(shape)}") from None
    if not ok or h < 1 or w < 1 or h > 32767 or w > 32767:
        raise InputError(f"warp: shape must be (H, W) with 1 <= H, W <= 32767, got {tuple(shape)!r}")
    if h * w > max_pixels():
        raise InputError(f"warp: a {w}x{h} grid exceeds the pixel limit {max_pixels()} (PCREG_MAX_PIXELS)")
    return h, w


# ---------------------------------------------------------------------------------------------------
# dense fields
# ---------------------------------------------------------------------------------------------------

def check_field(fld: np.ndarray, shape: tuple[int, int] | None) -> np.ndarray:
    """A motion's field (checked by :class:`Motion`), of the moving grid's size where that is known."""
    if shape is not None and fld.shape[:2] != tuple(shape[:2]):
        raise InputError(f"warp: the field is {fld.shape[1]}x{fld.shape[0]} but the moving grid is "
                         f"{shape[1]}x{shape[0]}")
    return fld


def _check_remap_input(src: np.ndarray, interpolation: str, fill) -> float:
    """The checks :func:`warp` makes on its input, for the field paths; returns ``fill`` as a float."""
    if not isinstance(interpolation, str) or interpolation not in _INTERP:
        raise InputError(f"warp: interpolation must be one of {', '.join(_INTERP)}")
    if src.dtype not in _DTYPES:
        raise InputError(f"warp: unsupported dtype {src.dtype} (use {', '.join(str(np.dtype(d)) for d in _DTYPES)})")
    try:
        value = check_float(fill, "warp: fill")
    except InputError:
        raise InputError(f"warp: fill must be a finite number, got {short_repr(fill)}") from None
    if src.dtype.kind == "f" and abs(value) > float(np.finfo(src.dtype).max):  # it would fill with inf, or NaN
        raise InputError(f"warp: fill {value:g} is beyond the range of the {src.dtype} array")
    if src.dtype.kind in "biu":  # saturated here: OpenCV rounds a fill past 2^31 to 0
        info = (0, 1) if src.dtype == np.bool_ else (np.iinfo(src.dtype).min, np.iinfo(src.dtype).max)
        value = float(min(max(value, info[0]), info[1]))
    return value


def _resample(src: np.ndarray, one, *, interpolation: str, fill: float) -> tuple[np.ndarray, np.ndarray]:
    """``src`` resampled by ``one(array, flags, border_value)`` (an OpenCV warp or remap), channel groups of
    at most 4 at a time, with ``src``'s dtype and channels; and the mask of output pixels whose every
    interpolation weight fell inside ``src`` (no blend with ``fill``)."""
    flags = _INTERP[interpolation]
    # OpenCV resamples neither bool nor float16: they go through uint8 (0 and 255, a pixel True where at least half of
    # its interpolation is: as 0 and 1, a line 1 px wide shifted by half a pixel came back empty) and float32.
    mask = src.dtype == np.bool_
    img = src.astype(np.uint8) * np.uint8(255) if mask else src.astype(np.float32) if src.dtype == np.float16 else src
    fill = 255 * fill if mask else fill
    channels = 1 if img.ndim == 2 else img.shape[2]
    try:
        if channels > 4:  # OpenCV warps up to 4 channels at once
            out = np.stack([one(np.ascontiguousarray(img[:, :, c]), flags, fill) for c in range(channels)], axis=2)
        else:
            out = one(img, flags, (fill,) * min(channels, 4) if channels > 1 else fill)
    except cv2.error as exc:
        raise InputError(f"warp: OpenCV refused the input ({str(exc).strip().splitlines()[-1][:160]})") from None
    if img.ndim == 3 and out.ndim == 2:
        out = out[:, :, None]
    ones = np.ones(src.shape[:2], np.float32)
    valid = one(ones, cv2.INTER_NEAREST if interpolation == "nearest" else cv2.INTER_LINEAR, 0) > 0.999
    if mask:
        out = out >= 128
    elif src.dtype == np.float16:
        out = out.astype(np.float16)
    return out, valid


def _remap(src: np.ndarray, fld: np.ndarray, *, interpolation: str, fill: float) -> tuple[np.ndarray, np.ndarray]:
    """``out(p) = src(fld(p))`` with cv2.remap, and the mask of pixels whose every interpolation weight
    fell inside ``src``."""
    if not isinstance(interpolation, str) or interpolation not in _INTERP:
        raise InputError(f"warp: interpolation must be one of {', '.join(_INTERP)}")
    mx = np.ascontiguousarray(fld[:, :, 0])
    my = np.ascontiguousarray(fld[:, :, 1])

    def one(a, fl, bval):
        return cv2.remap(a, mx, my, fl, borderMode=cv2.BORDER_CONSTANT, borderValue=bval)

    return _resample(src, one, interpolation=interpolation, fill=fill)


def warp_to_moving(reference: np.ndarray, T_ref_mov, *, shape: tuple[int, ...] | None = None,
                   interpolation: str = "linear", fill: float = 0) -> tuple[np.ndarray, np.ndarray]:
    """Resample a reference-frame array on the moving grid: ``out(p) = reference(T_ref_mov p)``.

    T_ref_mov : (3, 3) transform, or an (H, W, 2) field (or a dense result) of the moving grid's size,
        used directly with ``cv2.remap`` (a field is already the map from moving pixels to the reference).
    shape : (H, W) of the moving grid (a field's own size; default the reference's).
    Returns ``(out, valid)`` with the semantics of :func:`warp`.
    """
    reference = plain_array(reference, "warp")
    if reference.ndim not in (2, 3) or reference.shape[0] == 0 or reference.shape[1] == 0:
        raise InputError(f"warp: expected an (H, W) or (H, W, C) array, got shape {reference.shape}")
    motion = _motion(T_ref_mov)
    if motion.field is not None:
        fld = check_field(motion.field, shape[:2] if shape is not None else None)
        fill = _check_remap_input(reference, interpolation, fill)
        return _remap(reference, fld, interpolation=interpolation, fill=fill)
    M = motion.matrix
    assert M is not None
    if abs(np.linalg.det(M)) < 1e-12:
        raise InputError("warp: T_ref_mov must be a finite invertible 3x3 matrix")
    return warp(reference, np.linalg.inv(M), shape=shape, interpolation=interpolation, fill=fill)


def invert_field(fld: np.ndarray, shape: tuple[int, int], *, iterations: int = 12, tol: float = 0.05
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of a field: for every reference pixel x (grid ``shape``), the moving p with fld(p) = x.

    An affine ``A`` is fitted to the field by least squares and the rest solved by the fixed point
    ``p <- A^-1 (x - r(p))``, ``r = fld - A`` sampled bilinearly (it converges where the field's
    non-affine part bends less than the affine part stretches). Returns ``(inverse (H, W, 2) float32,
    ok (H, W) bool)``: ``ok`` where ``|fld(p) - x| < tol`` px at the end and p is inside the field.
    """
    fld = np.asarray(fld, dtype=np.float32)
    hm, wm = fld.shape[:2]
    h, w = int(shape[0]), int(shape[1])
    step = max(1, int(np.sqrt(hm * wm / 4000)))
    ys, xs = np.mgrid[0:hm:step, 0:wm:step]
    P = np.column_stack([xs.ravel(), ys.ravel(), np.ones(xs.size)]).astype(np.float64)
    Y = fld[::step, ::step].reshape(-1, 2).astype(np.float64)
    coef, *_ = np.linalg.lstsq(P, Y, rcond=None)  # (3, 2): [x y 1] @ coef
    A = np.vstack([coef.T, [0.0, 0.0, 1.0]])
    if abs(np.linalg.det(A[:2, :2])) < 1e-9:
        return np.full((h, w, 2), -1e4, np.float32), np.zeros((h, w), bool)
    Ai = np.linalg.inv(A)
    gx, gy = np.meshgrid(np.arange(wm, dtype=np.float32), np.arange(hm, dtype=np.float32))
    resid = fld - np.dstack([A[0, 0] * gx + A[0, 1] * gy + A[0, 2], A[1, 0] * gx + A[1, 1] * gy + A[1, 2]]).astype(np.float32)
    X, Yr = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    p = np.zeros((h, w, 2), np.float32)
    r = np.zeros((h, w, 2), np.float32)
    for _ in range(iterations):
        tx, ty = X - r[:, :, 0], Yr - r[:, :, 1]
        p[:, :, 0] = Ai[0, 0] * tx + Ai[0, 1] * ty + Ai[0, 2]
        p[:, :, 1] = Ai[1, 0] * tx + Ai[1, 1] * ty + Ai[1, 2]
        r = cv2.remap(resid, p[:, :, 0], p[:, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    back = cv2.remap(fld, p[:, :, 0], p[:, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    err = np.hypot(back[:, :, 0] - X, back[:, :, 1] - Yr)
    inside = (p[:, :, 0] >= 0) & (p[:, :, 0] <= wm - 1) & (p[:, :, 1] >= 0) & (p[:, :, 1] <= hm - 1)
    return p, (err < tol) & inside
