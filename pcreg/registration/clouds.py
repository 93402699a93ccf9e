"""Images as 2-D/colour point clouds.

An :class:`ImageCloud` holds points in the full-resolution image's pixel coordinates (x right, y down,
(0, 0) the centre of the top-left pixel) whatever pyramid level they were detected at, so a transform
estimated at any level is directly the transform of the full-resolution images.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from .._calls import interrupts_unwrapped
from .._signals import _shielded, check_interrupted
from ..errors import ImageWarning, InputError, outside_pcreg
from ..frame import FLOAT_FILE_HINT, MIN_SIDE, as_rgb_uint8
from ..validation import check_bool, check_choice, check_count, check_counts, check_float, check_int, check_path

SAMPLERS = ("canny", "gradient", "grid")


@dataclass(frozen=True, repr=False)
class ImageCloud:
    """A point cloud taken from an image.

    points : (N, 2) float64 — pixel coordinates of the full-resolution image.
    colors : (N, 3) float32 — RGB in [0, 1] at each point.
    normals : (N, 2) float64 — unit image-gradient direction at each point (the edge normal).
    shape : (H, W) of the full-resolution image.
    level : pyramid level the points were detected at (0 = full resolution; level l halves l times).
    """

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    shape: tuple[int, int]
    level: int = 0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __repr__(self) -> str:
        return f"ImageCloud(n={len(self)}, shape={self.shape}, level={self.level})"


def load_image(path: str | os.PathLike, *, max_pixels: int | None = None) -> np.ndarray:
    """Read an image file as (H, W, 3) uint8 RGB (grayscale is replicated, 16-bit scaled, alpha dropped).

    Only regular files are read (a FIFO or device is refused, never waited on); the size in the header
    is checked against ``max_pixels`` (default :func:`pcreg.validation.max_pixels`) before decoding.
    Where the array is not what a viewer shows, a :class:`~pcreg.errors.ImageWarning` says so: transparent pixels
    (alpha 0), which the array keeps as pixels and a registration would match (:func:`load_image_and_mask` gives
    the mask that leaves them out); an EXIF orientation (the array is the pixels as stored); damaged data that the
    decoder guessed around.
    """
    import warnings

    from ..formats import read_image_file_and_damage

    path = check_path(path, "path")
    stored, damage = read_image_file_and_damage(path, limit=max_pixels)
    rgb, alpha = _rgb_and_alpha(stored, str(path), max_pixels)
    if alpha is not None and not np.all(alpha > 0):
        hidden = float(np.mean(alpha == 0))
        warnings.warn(f"{path}: {100 * hidden:.3g}% of its pixels are transparent (alpha 0), kept here as pixels that a "
                      "registration would match; pcreg.load_image_and_mask(path) gives the mask that leaves them out "
                      "(register(..., reference_mask=, moving_mask=))", ImageWarning, stacklevel=outside_pcreg())
    _warn_of_file(path, damage)
    return rgb


def _warn_of_file(path, damage: str) -> None:
    """An :class:`~pcreg.errors.ImageWarning`, to the first caller outside pcreg, of damaged data its decoder guessed around
    (``damage``, what it said) and of an EXIF orientation."""
    import warnings

    from ..formats import orientation_note

    for said in (f"{path}: its decoder reports damaged data ({damage}): part of the image is the decoder's guess"
                 if damage else None, orientation_note(path, "reads")):
        if said is not None:
            warnings.warn(said, ImageWarning, stacklevel=outside_pcreg())


def load_image_and_alpha(path: str | os.PathLike, *, max_pixels: int | None = None
                         ) -> tuple[np.ndarray, np.ndarray | None]:
    """``(image, alpha)``: :func:`load_image`'s image, and the file's alpha channel as stored ((H, W) uint8 or uint16),
    None without one."""
    from ..formats import read_image_file

    path = check_path(path, "path")
    return _rgb_and_alpha(read_image_file(path, limit=max_pixels), str(path), max_pixels)


def load_image_and_mask(path: str | os.PathLike, *, max_pixels: int | None = None
                        ) -> tuple[np.ndarray, np.ndarray | str]:
    """``(image, mask)``: :func:`load_image`'s image, and the pixels to register: ``"auto"`` (every pixel
    but black padding, :func:`valid_region`) for an image without transparency, else its opaque pixels
    (alpha above 0) less the padding. A viewer shows nothing where alpha is 0, so nothing there is matched:
    ``pcreg.register(ref, mov, reference_mask=ref_mask, moving_mask=mov_mask)`` registers two files as
    ``pcreg register`` does. Warns of an EXIF orientation and of damaged data as :func:`load_image` does."""
    from ..formats import read_image_file_and_damage

    path = check_path(path, "path")
    stored, damage = read_image_file_and_damage(path, limit=max_pixels)
    loaded = image_and_mask(stored, str(path), limit=max_pixels)
    _warn_of_file(path, damage)
    return loaded


def image_and_mask(img: np.ndarray, name: str, *, limit: int | None = None) -> tuple[np.ndarray, np.ndarray | str]:
    """:func:`load_image_and_mask` of an image already decoded as the file stores it (OpenCV's
    ``IMREAD_UNCHANGED``, BGR order; ``limit`` the pixel limit it was read with); ``name`` names it in errors.
    An image transparent everywhere (alpha 0) has no pixel to register: an :class:`InputError`."""
    rgb, alpha = _rgb_and_alpha(img, name, limit)
    if alpha is None or np.all(alpha > 0):
        return rgb, "auto"
    if not alpha.any():
        raise InputError(f"{name}: every pixel is transparent (alpha 0 everywhere): nothing to register")
    return rgb, (alpha > 0) & valid_region(rgb)


def _rgb_and_alpha(img: np.ndarray, name: str, limit: int | None = None, *,
                   min_side: int = MIN_SIDE) -> tuple[np.ndarray, np.ndarray | None]:
    """An image decoded as the file stores it (BGR order) as (H, W, 3) uint8 RGB (:func:`as_rgb_uint8`, its sides at
    least ``min_side``), and its alpha channel (None without one)."""
    alpha = None
    if img.ndim == 3 and img.shape[2] == 4:
        img, alpha = img[:, :, :3], img[:, :, 3]
    if img.ndim == 3:
        img = img[:, :, ::-1]  # BGR -> RGB
    return as_rgb_uint8(img, name=name, limit=limit, float_hint=FLOAT_FILE_HINT, min_side=min_side), alpha


def valid_region(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: False where the image is padding — pure black (0, 0, 0) areas of at least 3x3 px.

    Warped and rotated images carry such borders; their straight edges are not scene content and must
    not become registration points. Isolated black pixels of a real image are kept (morphological opening).
    """
    ring = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    if not np.any(np.all(ring == 0, axis=1)):  # padding touches the border by definition
        return np.ones(image.shape[:2], dtype=bool)
    black = cv2.inRange(image, (0, 0, 0), (0, 0, 0))
    black = cv2.morphologyEx(black, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    # Padding lies outside the picture, which a warp keeps convex (the image of a rectangle under an
    # affine or projective map): black areas inside the convex hull of the non-black pixels (a black
    # object, a shadow) are content and stay usable.
    nonblack = black == 0
    rows = np.flatnonzero(nonblack.any(axis=1))
    if rows.size == 0:
        return nonblack
    # The hull of the non-black pixels is the hull of each row's leftmost and rightmost ones.
    sub = nonblack[rows]
    left = np.argmax(sub, axis=1)
    right = sub.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    ends = np.concatenate([np.column_stack([left, rows]), np.column_stack([right, rows])]).astype(np.int32)
    inside = np.zeros(black.shape, np.uint8)
    cv2.fillConvexPoly(inside, cv2.convexHull(ends), 255)
    return nonblack | (inside > 0)


def _gray(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = img.shape
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    x0 = x.astype(np.intp)
    y0 = y.astype(np.intp)
    fx = x - x0
    fy = y - y0
    a = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    b = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return a * (1 - fy) + b * fy


@dataclass(frozen=True, repr=False)
class _Detection:
    """One pyramid level's detection: the level image, its gradients and the sampled pixels (all of
    them, before any subsampling), in the order ``np.nonzero`` gives."""

    image: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    mag: np.ndarray
    xs: np.ndarray
    ys: np.ndarray

    def __len__(self) -> int:
        return int(self.xs.size)


def magnitude(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``sqrt(x^2 + y^2)`` element by element (float32 in, float32 out), the same to the bit on every
    call: numpy's square root is correctly rounded. ``cv2.magnitude`` is not reproducible: its
    vectorised and scalar paths round differently and which elements take which changes from call to
    call (on a 1440x1080 Sobel response two copies of the same input gave 26,550 elements one unit
    apart in the last place), which made the same registration give different transforms in
    different processes."""
    m = np.multiply(x, x)
    m += y * y
    return np.sqrt(m, out=m)


def _detect(image: np.ndarray, *, sampler: str = "canny", valid: np.ndarray | None = None,
            max_points: int | None = None, grid_step: int = 8, top_k: int | None = None,
            canny_percentile: float = 85.0) -> _Detection:
    """Gradients (Sobel) and the sampled pixels of one pyramid level (Canny edges, strongest gradients or a grid)."""
    gray = _gray(image)
    dx = cv2.Sobel(gray, cv2.CV_16S, 1, 0, ksize=3)
    dy = cv2.Sobel(gray, cv2.CV_16S, 0, 1, ksize=3)
    gx, gy = dx.astype(np.float32), dy.astype(np.float32)
    mag = magnitude(gx, gy)
    h, w = gray.shape
    none = np.empty(0, np.intp)
    if sampler == "canny":
        sample = mag[::2, ::2]
        nz = sample[sample > 0]
        if nz.size == 0:
            return _Detection(image, gx, gy, mag, none, none)
        k = min(nz.size - 1, int(canny_percentile / 100.0 * nz.size))
        # Capped below the maximum so an image whose edges all have one strength still has edges.
        high = min(float(np.partition(nz, k)[k]), 0.8 * float(nz.max()))
        high = max(high, 8.0)  # Sobel magnitude of a faint (2 grey levels) step: no edges in flat noise
        # Shielded: cv2 reaches this (dx, dy) form after failing its first form, whose error it reads with
        # PyObject_Str, which runs a pending signal's handler; the KeyboardInterrupt raised there made it NULL,
        # which cv2 does not check (SIGSEGV instead of exit 130). Raised here instead, once Canny returns.
        # Without IPP, in this thread alone (OpenCV keeps the switch per thread): on one OpenCV thread cv::Canny hands
        # this call to IPP, which leaves out the pixels exactly at a threshold that OpenCV's own Canny (two threads or
        # more) keeps, and the percentile puts some there in every image; a one-CPU machine found fewer edges.
        with _shielded():
            ipp = cv2.ipp.useIPP()
            cv2.ipp.setUseIPP(False)
            try:
                edges = cv2.Canny(dx, dy, 0.5 * high, high, L2gradient=True)
            finally:
                cv2.ipp.setUseIPP(ipp)
        check_interrupted()
        keep = edges > 0
    elif sampler == "gradient":
        k = top_k or max_points or 5000
        flat = mag.ravel()
        keep = np.zeros(flat.size, dtype=bool)
        cand = np.flatnonzero(flat > 8.0)
        if cand.size > k:
            cand = cand[np.argpartition(flat[cand], -k)[-k:]]
        keep[cand] = True
        keep = keep.reshape(h, w)
    elif sampler == "grid":
        keep = np.zeros((h, w), dtype=bool)
        keep[grid_step // 2 :: grid_step, grid_step // 2 :: grid_step] = True
    else:
        raise InputError(f"unknown sampler {sampler!r}; choose one of {', '.join(SAMPLERS)}")
    # Points at the image border have one-sided gradients; drop a 1-px frame.
    keep[[0, -1], :] = False
    keep[:, [0, -1]] = False
    if valid is not None:
        keep &= valid
    # np.nonzero's order, from the flat indices: a third of its time (1.26 -> 0.36 ms for a 640x480 edge map)
    ys, xs = np.divmod(np.flatnonzero(keep), w)
    return _Detection(image, gx, gy, mag, xs, ys)


def _subsample(n: int, max_points: int | None, seed: int) -> np.ndarray | None:
    """Sorted indices of ``max_points`` of ``n`` items drawn with ``seed``, or None to keep all."""
    if max_points is None or n <= max_points:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, size=max_points, replace=False))


def _finish(det: _Detection, sel: np.ndarray | None, *, subpixel: bool = True, sampler: str = "canny"
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N,2), unit normals (N,2), and pixel indices (N,2 int) of the selected detected pixels."""
    xs, ys = (det.xs, det.ys) if sel is None else (det.xs[sel], det.ys[sel])
    if xs.size == 0:
        return np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2), np.intp)
    from ._subpixel import points_and_normals

    # Normals: the unit gradient. Sub-pixel: the parabola through the gradient magnitude at -1, 0, +1 px
    # along the gradient direction; the edge lies at its vertex (Devernay 1995, "A non-maxima
    # suppression method for edge detection with sub-pixel accuracy"). Compiled: one pass per point.
    pts, normals = points_and_normals(det.gx, det.gy, det.mag, xs, ys, bool(subpixel and sampler != "grid"))
    return pts, normals, np.column_stack([xs, ys])


def _level_points(image: np.ndarray, *, sampler: str = "canny", valid: np.ndarray | None = None,
                  max_points: int | None = None, grid_step: int = 8, top_k: int | None = None,
                  subpixel: bool = True, seed: int = 0, canny_percentile: float = 85.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N,2), unit normals (N,2), and pixel indices (N,2 int) at one pyramid level."""
    det = _detect(image, sampler=sampler, valid=valid, max_points=max_points, grid_step=grid_step, top_k=top_k,
                  canny_percentile=canny_percentile)
    return _finish(det, _subsample(len(det), max_points, seed), subpixel=subpixel, sampler=sampler)


def image_cloud(image: np.ndarray, *, sampler: str = "canny", max_points: int | None = None, level: int = 0,
                mask: np.ndarray | str | None = "auto", grid_step: int = 8, top_k: int | None = None,
                subpixel: bool = True, seed: int = 0, canny_percentile: float = 85.0) -> ImageCloud:
    """Turn an image into a 2-D/colour point cloud.

    image : (H, W, 3) uint8 RGB (also (H, W), uint16, float in [0, 1]).
    sampler : ``"canny"`` (edge pixels, moved to their sub-pixel position), ``"gradient"`` (the
        ``top_k`` strongest gradients) or ``"grid"`` (every ``grid_step``-th pixel).
    max_points : keep at most this many points, chosen at random with ``seed`` (deterministic).
    level : detect at pyramid level ``level`` (the image halved ``level`` times with ``cv2.pyrDown``);
        points are returned in full-resolution coordinates.
    mask : (H, W) bool of usable pixels, ``"auto"`` to ignore black padding (see :func:`valid_region`),
        or None for all pixels. Points within 2 px of an unusable pixel (at that level) are dropped.
    canny_percentile : the Canny high threshold is this percentile of the gradient magnitude
        (low = half of it), so the detector adapts to the image's contrast.
    """
    img = as_rgb_uint8(image)
    level = check_int(level, "level", lo=0, hi=16)
    max_points = check_count(max_points, "max_points")
    seed = check_int(seed, "seed", lo=0)
    _check_options(sampler=sampler, grid_step=grid_step, top_k=top_k, subpixel=subpixel,
                   canny_percentile=canny_percentile)
    mask = usable_mask(mask, img)
    lvl_img = img
    for _ in range(level):
        if min(lvl_img.shape[:2]) < 16:
            raise InputError(f"image {img.shape[1]}x{img.shape[0]} is too small for pyramid level {level}")
        lvl_img = cv2.pyrDown(lvl_img)
    with interrupts_unwrapped():  # Ctrl-C in a compiled kernel: the KeyboardInterrupt, not numba's SystemError
        return level_cloud(lvl_img, level=level, shape=img.shape[:2], mask=mask, sampler=sampler, max_points=max_points,
                           grid_step=grid_step, top_k=top_k, subpixel=subpixel, seed=seed,
                           canny_percentile=canny_percentile)


def level_cloud(lvl_img: np.ndarray, *, level: int, shape: tuple[int, int], mask: np.ndarray | None,
                **kwargs) -> ImageCloud:
    """The cloud of an image already reduced to pyramid level ``level`` (full-resolution ``shape``)."""
    pts, normals, pix = _level_points(lvl_img, valid=_level_valid(mask, lvl_img, level), **kwargs)
    return _as_cloud(lvl_img, pts, normals, pix, level=level, shape=shape)


def _level_valid(mask: np.ndarray | None, lvl_img: np.ndarray, level: int) -> np.ndarray | None:
    """Usable pixels at one level: the mask reduced to the level and eroded by 2 px (None: all)."""
    if mask is None:
        return None
    m = mask.astype(np.uint8) * 255
    if level:
        m = cv2.resize(m, (lvl_img.shape[1], lvl_img.shape[0]), interpolation=cv2.INTER_AREA)
    return cv2.erode((m == 255).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0


def _as_cloud(lvl_img: np.ndarray, pts: np.ndarray, normals: np.ndarray, pix: np.ndarray, *, level: int,
              shape: tuple[int, int]) -> ImageCloud:
    colors = lvl_img[pix[:, 1], pix[:, 0]].astype(np.float32) / 255.0 if len(pix) else np.empty((0, 3), np.float32)
    f = float(2**level)
    # Level-l pixel centre x_l sits at x_0 = 2^l x_l + (2^l - 1) / 2 in full-resolution coordinates.
    pts = pts * f + (f - 1.0) / 2.0
    return ImageCloud(points=pts, colors=colors, normals=normals, shape=(int(shape[0]), int(shape[1])), level=level)


def per_level(max_points, levels: int) -> tuple:
    """``max_points`` (one value, or one per level, finest first; the last repeats) as one per level."""
    if not isinstance(max_points, (tuple, list)):
        return (max_points,) * levels
    if not max_points:
        raise InputError("max_points must name at least one level")
    return tuple(max_points) + (max_points[-1],) * max(0, levels - len(max_points))


def usable_mask(mask, image: np.ndarray, *, name: str = "mask") -> np.ndarray | None:
    """The usable pixels of ``image``: ``"auto"`` (no black padding, :func:`valid_region`), an (H, W)
    array, or None; None also where every pixel is usable."""
    check_mask(mask, image.shape[:2], name=name)
    if isinstance(mask, str):
        mask = valid_region(image)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.all():
            mask = None
    return mask


def check_mask(mask, shape: tuple[int, int], *, name: str = "mask") -> None:
    """An :class:`InputError` unless ``mask`` is ``"auto"``, None or an array of ``shape`` (H, W), finite, with at
    least one usable (true or nonzero) pixel."""
    if isinstance(mask, str) or mask is None:
        if mask not in ("auto", None):
            raise InputError(f"{name} must be an array, 'auto' or None, got {mask!r}")
        return
    arr = np.asarray(mask) if not isinstance(mask, np.ndarray) else mask
    if arr.dtype.kind not in "biuf":
        raise InputError(f"{name} must be an array of booleans, 'auto' or None, got {type(mask).__name__}")
    if arr.shape != tuple(shape[:2]):
        raise InputError(f"{name} shape {arr.shape} does not match image shape {tuple(shape[:2])}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise InputError(f"{name} holds NaN or inf: a mask says which pixels are usable (true or nonzero)")
    if not np.any(arr):
        raise InputError(f"{name} marks no pixel usable (all false or 0): nothing to register")


_OPTIONS = ("sampler", "grid_step", "top_k", "subpixel", "canny_percentile")


def _check_options(*, sampler: str = "canny", grid_step: int = 8, top_k: int | None = None, subpixel: bool = True,
                   canny_percentile: float = 85.0) -> None:
    """An :class:`InputError` naming the first sampling option of the wrong type or value."""
    check_choice(sampler, "sampler", SAMPLERS)
    check_int(grid_step, "grid_step", lo=1)
    check_count(top_k, "top_k")
    check_bool(subpixel, "subpixel")
    check_float(canny_percentile, "canny_percentile", lo=0, hi=100)


def _image_levels(img: np.ndarray, levels: int):
    """``(level, image)`` for levels 0..levels-1 of a Gaussian pyramid (``cv2.pyrDown``), built as it is
    walked; an :class:`InputError` when a level would fall below 16 px before it is made."""
    lvl_img = img
    for level in range(levels):
        if level:
            if min(lvl_img.shape[:2]) < 16:
                raise InputError(f"image {img.shape[1]}x{img.shape[0]} is too small for {levels} pyramid levels")
            lvl_img = cv2.pyrDown(lvl_img)
        yield level, lvl_img


def cloud_pyramid(image: np.ndarray, *, levels: int = 4, max_points: int | tuple[int | None, ...] | None = None,
                  mask: np.ndarray | str | None = "auto", seed: int = 0, **kwargs) -> list[ImageCloud]:
    """The same cloud at pyramid levels 0..levels-1 (index = level; each level halves the image).

    ``max_points`` may be one number for every level or one per level; other options as :func:`image_cloud`.
    """
    levels = check_int(levels, "levels", lo=1, hi=16)
    max_points = per_level(check_counts(max_points, "max_points"), levels)
    seed = check_int(seed, "seed", lo=0)
    _check_options(**{k: v for k, v in kwargs.items() if k in _OPTIONS})
    img = as_rgb_uint8(image)
    mask = usable_mask(mask, img)
    out = []
    for level, lvl_img in _image_levels(img, levels):
        out.append(level_cloud(lvl_img, level=level, shape=img.shape[:2], mask=mask, max_points=max_points[level],
                               seed=seed, **kwargs))
    return out


# ---------------------------------------------------------------------------------------------------
# A frame's pyramid, extracted once
# ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True, repr=False)
class ImagePyramid:
    """One image's detections at every pyramid level, made once (image pyramid, Sobel gradients, Canny
    edges); clouds of any size are drawn from them by :meth:`clouds` (the sub-pixel fit runs on the
    drawn points only).

    In a stream every frame is registered twice, first as the moving image and then as the reference
    of the next frame: building its pyramid once serves both (:class:`pcreg.Propagator` does this).

    shape : (H, W) of the full-resolution image. options : the extraction options (sampler,
    canny_percentile, ...), checked when a pyramid is handed to :func:`pcreg.register`.
    """

    detections: tuple
    shape: tuple[int, int]
    options: tuple = ()
    valid: np.ndarray | None = None  # (H, W) bool usable pixels at full resolution; None: all

    def __len__(self) -> int:
        return len(self.detections)

    def __repr__(self) -> str:
        return f"ImagePyramid(shape={self.shape}, points per level={[len(d) for d in self.detections]})"

    def clouds(self, *, max_points: int | Sequence[int | None] | None = None, seed: int = 0,
               levels: int | None = None) -> list[ImageCloud]:
        """Clouds at levels 0..levels-1 with at most ``max_points`` (one, or one per level) points each,
        drawn at random with ``seed``: the same clouds as :func:`cloud_pyramid` with these options."""
        n = len(self.detections) if levels is None else int(levels)
        if not 1 <= n <= len(self.detections):
            raise InputError(f"the pyramid has {len(self.detections)} levels, {n} asked for")
        max_points = per_level(max_points, n)
        return [self.cloud(level, max_points=max_points[level], seed=seed) for level in range(n)]

    def cloud(self, level: int, *, max_points: int | None = None, seed: int = 0) -> ImageCloud:
        """The cloud of one level with at most ``max_points`` points drawn with ``seed``."""
        opts = dict(self.options)
        det = self.detections[level]
        pts, normals, pix = _finish(det, _subsample(len(det), max_points, seed),
                                    subpixel=opts.get("subpixel", True), sampler=opts.get("sampler", "canny"))
        return _as_cloud(det.image, pts, normals, pix, level=level, shape=self.shape)


def image_pyramid(image: np.ndarray, *, levels: int = 4, mask: np.ndarray | str | None = "auto",
                  sampler: str = "canny", grid_step: int = 8, top_k: int | None = None, subpixel: bool = True,
                  canny_percentile: float = 85.0) -> ImagePyramid:
    """Detect ``image``'s sample points at pyramid levels 0..levels-1, once (see :class:`ImagePyramid`).

    Options as :func:`cloud_pyramid`; ``image_pyramid(img, ...).clouds(max_points=m, seed=s)`` equals
    ``cloud_pyramid(img, ..., max_points=m, seed=s)``, except that the ``gradient`` sampler keeps the
    ``top_k`` (default 5000) strongest gradients per level before drawing rather than ``max_points``.
    """
    levels = check_int(levels, "levels", lo=1, hi=16)
    _check_options(sampler=sampler, grid_step=grid_step, top_k=top_k, subpixel=subpixel,
                   canny_percentile=canny_percentile)
    img = as_rgb_uint8(image)
    mask = usable_mask(mask, img)
    if sampler == "gradient" and top_k is None:
        top_k = 5000
    dets = []
    for level, lvl_img in _image_levels(img, levels):
        dets.append(_detect(lvl_img, sampler=sampler, valid=_level_valid(mask, lvl_img, level), grid_step=grid_step,
                            top_k=top_k, canny_percentile=canny_percentile))
    options = (("sampler", sampler), ("grid_step", grid_step), ("top_k", top_k), ("subpixel", subpixel),
               ("canny_percentile", float(canny_percentile)))
    return ImagePyramid(detections=tuple(dets), shape=(int(img.shape[0]), int(img.shape[1])), options=options,
                        valid=mask)


def check_pyramid(image: np.ndarray, pyramid: ImagePyramid, *, levels: int, sampler: str,
                  canny_percentile: float, name: str = "image") -> ImagePyramid:
    """``pyramid`` when it was built for ``image`` with enough levels and these options, else an
    :class:`~pcreg.errors.InputError`."""
    if not isinstance(pyramid, ImagePyramid):
        raise InputError(f"{name} pyramid: expected an ImagePyramid (pcreg.registration.clouds.image_pyramid), got {type(pyramid).__name__}")
    if tuple(pyramid.shape) != tuple(image.shape[:2]):
        raise InputError(f"{name} pyramid was built for a {pyramid.shape} image, not {tuple(image.shape[:2])}")
    if not np.array_equal(pyramid.detections[0].image, image):  # every byte: 0.1 ms at 640x480
        raise InputError(f"{name} pyramid was built for another image of this size, not the {name} image given")
    if len(pyramid) < levels:
        raise InputError(f"{name} pyramid has {len(pyramid)} levels, {levels} needed")
    opts = dict(pyramid.options)
    if opts.get("sampler") != sampler or opts.get("canny_percentile") != float(canny_percentile):
        raise InputError(f"{name} pyramid was built with other options ({opts}) than this registration's "
                         f"(sampler={sampler!r}, canny_percentile={canny_percentile})")
    return pyramid
