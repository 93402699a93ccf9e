"""The dense registration's images, level by level: both images' pyramids (float32 RGB in [0, 1]), the
image noise, the textured moving samples, the texture part matched, and each level's matching problem."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import cv2
import numpy as np

from ...errors import InputError
from ..clouds import as_rgb_uint8, magnitude, valid_region
from .grid import GridWeights, _edge_weights, _grid_shape, _NormalEquations, _read_only, grid_weights
from .options import DenseOptions, _coarsest_level

__all__ = ["DenseReference", "prepare_reference"]


#: ``v / 255`` in float32 for every 8-bit value v.
_UNIT_LUT = (np.arange(256, dtype=np.float32) / 255.0).reshape(1, 256, 1)


def _unit_float(img: np.ndarray) -> np.ndarray:
    """A uint8 image as float32 in [0, 1]: ``img.astype(np.float32) / 255`` looked up in a 256-entry
    table (the same numbers, a tenth of the time at 640x480)."""
    return cv2.LUT(np.ascontiguousarray(img), _UNIT_LUT)


def _noise_sigma(gray: np.ndarray) -> float:
    """Immerkaer (1996) noise standard deviation of a [0, 1] float image from its Laplacian-difference filter."""
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(gray, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1]
    h, w = gray.shape
    return float(np.sqrt(np.pi / 2.0) * np.abs(r).sum() / (6.0 * max(w - 2, 1) * max(h - 2, 1)))


def _level_matrix(T: np.ndarray, level: int) -> np.ndarray:
    """A full-resolution 3x3 transform expressed in the pixels of pyramid level ``level`` as
    :func:`_pyramid` makes them: ``cv2.pyrDown`` keeps the even pixels, so a level's pixel ``x_l`` lies on
    full-resolution pixel ``x_0 = 2^l x_l``. (The control grid's nodes are placed by the centres of
    ``2^l``-pixel blocks, ``x_0 = 2^l x_l + (2^l - 1) / 2``: only where the smooth displacement is read,
    the same for both images. Here that rule put a level's samples ``(A - I)(2^l - 1) / 2`` px from their
    content under a transform of linear part ``A``: 1 px at the finest level under a half turn, which the
    field kept.)"""
    f = float(2 ** level)
    S = np.array([[1 / f, 0, 0], [0, 1 / f, 0], [0, 0, 1]])
    return S @ np.asarray(T, dtype=np.float64) @ np.linalg.inv(S)


def _apply(M: np.ndarray, p: np.ndarray) -> np.ndarray:
    den = p[:, 0] * M[2, 0] + p[:, 1] * M[2, 1] + M[2, 2]
    return np.column_stack([(p @ M[0, :2] + M[0, 2]) / den, (p @ M[1, :2] + M[1, 2]) / den])


def _samples(img: np.ndarray, sigma: float, *, max_points: int, seed: int, valid: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """Textured moving pixels of one level: gradient magnitude above 3 noise standard deviations of
    the Sobel response (and above a 2-grey-level step), a one-pixel frame dropped."""
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag = magnitude(gx, gy)
    thr = max(3.0 * math.sqrt(12.0) * sigma, 8.0 / 255.0)
    keep = mag > thr
    keep[[0, -1], :] = False
    keep[:, [0, -1]] = False
    if valid is not None:
        keep &= valid
    # the kept pixels' flat indices in row order, split into rows and columns once drawn: the same
    # pixels as np.nonzero's two index arrays in a fifth of the time (0.36 -> 0.08 ms for the 45,000
    # pixels of a 320x240 CamVid level)
    flat = np.flatnonzero(keep)
    rate = 1.0
    if flat.size > max_points:
        rate = max_points / flat.size
        flat = flat[np.sort(np.random.default_rng(seed).choice(flat.size, size=max_points, replace=False))]
    ys, xs = np.divmod(flat, keep.shape[1])
    return np.column_stack([xs, ys]).astype(np.float64), img[ys, xs].astype(np.float32), rate


def _texture(img: np.ndarray, sigma: float, structure: float = 0.05) -> np.ndarray:
    """The texture part of an image, ``I - (1 - structure) G_sigma * I`` (the structure-texture split of
    Wedel et al. 2009, "An improved algorithm for TV-L1 optical flow", keeping a twentieth of the
    structure). It removes what varies slowly across the image: brightness and colour-temperature
    changes, drifting shadows, haze, which colour matching would otherwise read as motion. With
    ``sigma`` of one pixel of the level, each pyramid level would match its own octave of detail
    alone (the band of a Laplacian pyramid, Burt & Adelson 1983); the default, 4 pixels, keeps two
    octaves more, the colour of a pole or a road marking as well as its edges, and still removes what
    varies over tens of pixels (see ``texture`` in :class:`~pcreg.registration.dense.options.DenseOptions` for the measurements)."""
    return (img - (1.0 - structure) * cv2.GaussianBlur(img, (0, 0), sigma)).astype(np.float32)


@dataclass(frozen=True)
class _Pyramids:
    """Both images as float32 RGB in [0, 1] per level (0 = full size), their valid (unpadded) masks, and
    the grid weights a prepared reference made once (None: none)."""

    reference: list[np.ndarray]
    moving: list[np.ndarray]
    reference_valid: list[np.ndarray]
    moving_valid: list[np.ndarray]
    grid_weights: GridWeights | None = None


def _pyramid(img: np.ndarray, coarsest: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """One image as float32 RGB in [0, 1] per level 0 .. ``coarsest``, and its valid masks."""
    pyr, val = [_unit_float(img)], [valid_region(img)]
    for _ in range(coarsest):
        pyr.append(cv2.pyrDown(pyr[-1]))
        val.append(cv2.resize(val[-1].astype(np.uint8), pyr[-1].shape[1::-1], interpolation=cv2.INTER_NEAREST) > 0)
    return pyr, val


@dataclass(frozen=True, repr=False)
class DenseReference:
    """A reference image prepared once for the dense registrations of many moving images (a stream's
    key frame; :func:`prepare_reference`), given to :func:`pcreg.register_dense` as ``prepared`` so
    that its pyramid is not built again for each. Read-only, like small_gicp's preprocessed target.

    image : (H, W, 3) uint8 RGB, a read-only copy of the reference. levels : its pyramid, float32 RGB
    in [0, 1] per level (0 = full size) to the coarsest level the options it was made for work at.
    valid : each level's valid (unpadded) mask, (h, w) bool. grid_weights : the control grids' bilinear
    weights from level to level for the options it was made for (they depend on the shapes alone; a
    registration with other grids makes its own).
    """

    image: np.ndarray
    levels: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    grid_weights: GridWeights

    def __repr__(self) -> str:
        h, w = self.image.shape[:2]
        return f"DenseReference(image={w}x{h}, levels={len(self.levels)})"

    def __reduce__(self):
        """Copied and pickled as what it holds, made again read-only (its weights' read-only view alone cannot be)."""
        return _prepared_again, (self.image, self.levels, self.valid, dict(self.grid_weights))


def _prepared_again(image: np.ndarray, levels: tuple, valid: tuple, weights: dict) -> DenseReference:
    """A :class:`DenseReference` of what one held (:meth:`DenseReference.__reduce__`)."""
    _read_only(image, *levels, *valid, *(a for arrays in weights.values() for a in arrays))
    return DenseReference(image, tuple(levels), tuple(valid), MappingProxyType(weights))


def prepare_reference(reference_image: np.ndarray, *, options: DenseOptions = DenseOptions()) -> DenseReference:
    """``reference_image`` (as :func:`pcreg.register_dense` takes it) prepared for registrations with
    ``options``: a read-only copy, its pyramid to the coarsest level they work at and its control grids'
    weights."""
    img = as_rgb_uint8(reference_image, name="reference image")
    if not isinstance(options, DenseOptions):
        raise InputError(f"options must be a pcreg.DenseOptions, got {type(options).__name__}")
    pyr, val = _pyramid(img, _coarsest_level(img.shape, options))
    image = img.copy()
    _read_only(image, *pyr, *val)  # shared by every registration it is given to: nobody writes into them
    weights = MappingProxyType(grid_weights([p.shape[:2] for p in pyr], options.membrane.grid_spacing, options.finest_level))
    return DenseReference(image, tuple(pyr), tuple(val), weights)


def check_prepared(prepared: DenseReference, image: np.ndarray, options: DenseOptions) -> None:
    """Refuse a prepared reference that is not ``image``'s (decided by comparing every byte, a tenth of
    a millisecond at 640x480 against 1.5 ms for the pyramid, never by identity, so an image changed in
    place is never mistaken for the one prepared) or that lacks a level ``options`` work at."""
    if not isinstance(prepared, DenseReference):
        raise InputError("prepared must be a DenseReference (pcreg.registration.dense.prepare_reference), "
                         f"got {type(prepared).__name__}")
    if prepared.image.shape != image.shape or not np.array_equal(prepared.image, image):
        raise InputError("prepared: made from another image than the reference image given")
    need = _coarsest_level(image.shape, options) + 1
    if len(prepared.levels) < need:
        raise InputError(f"prepared: a pyramid of {len(prepared.levels)} levels, these options work at {need}: "
                         "prepare it with the same options")


def _pyramids(reference: np.ndarray | DenseReference, mov: np.ndarray, coarsest: int) -> _Pyramids:
    """Both images' pyramids to level ``coarsest``: the reference's from its prepared pyramid where it is
    a :class:`DenseReference`, else built here (read-only as well: the kernels see the same arrays)."""
    if isinstance(reference, DenseReference):
        pyr_r, val_r = list(reference.levels[:coarsest + 1]), list(reference.valid[:coarsest + 1])
        weights: GridWeights | None = reference.grid_weights
    else:
        pyr_r, val_r = _pyramid(reference, coarsest)
        _read_only(*pyr_r, *val_r)
        weights = None
    pyr_m, val_m = _pyramid(mov, coarsest)
    return _Pyramids(pyr_r, pyr_m, val_r, val_m, weights)


@dataclass(frozen=True)
class _Problem:
    """One level's matching problem: the images to match (texture parts where asked), the moving
    samples ``P`` and their colours ``C``, the samples under the global transform ``GP``, the grid's
    normal equations, the colour weight, the gate and the image noise."""

    R: np.ndarray
    Mv: np.ndarray
    P: np.ndarray
    C: np.ndarray
    GP: np.ndarray
    NE: _NormalEquations
    lam: float
    radius: int
    sigma: float


@dataclass(frozen=True)
class _Level:
    """One pyramid level: its control grid (spacing, shape), the samples' rate, and its matching
    problem (None: under 16 textured samples, the level is skipped)."""

    level: int
    spacing: float
    gshape: tuple[int, int]
    rate: float
    problem: _Problem | None

    @property
    def scale(self) -> float:
        """Pixels of the full image per pixel of the level."""
        return float(2 ** self.level)


def _level_problem(pyr: _Pyramids, level: int, T: np.ndarray, options: DenseOptions, *, coarsest: int) -> _Level:
    """The level's grid, samples (seed ``options.seed + level``) and equations (no problem under 16 samples)."""
    R, Mv = pyr.reference[level], pyr.moving[level]
    lh, lw = R.shape[:2]
    s = float(options.membrane.grid_spacing)
    gshape = _grid_shape(lh, lw, s)
    sigma = max(_noise_sigma(cv2.cvtColor(Mv, cv2.COLOR_RGB2GRAY)), 0.5 / 255.0)
    lam = 1.0 / (math.sqrt(6.0) * sigma)
    radius = options.radius if level == coarsest else options.fine_radius
    # pixels near black padding are not scene content
    val_m = pyr.moving_valid[level]
    valid = cv2.erode(val_m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0 if not val_m.all() else None
    P, _, rate = _samples(Mv, sigma, max_points=options.max_points, seed=options.seed + level, valid=valid)
    if len(P) < 16:
        return _Level(level, s, gshape, rate, None)
    if options.texture is not None:
        R, Mv = _texture(R, options.texture), _texture(Mv, options.texture)
    C = Mv[P[:, 1].astype(np.intp), P[:, 0].astype(np.intp)]
    val_r = pyr.reference_valid[level]
    R_match = R if val_r.all() else np.where(val_r[:, :, None], R, np.float32(10.0))
    NE = _NormalEquations(P, gshape, s, _edge_weights(Mv, gshape, s) if options.membrane.edge_aware else None)
    GP = _apply(_level_matrix(T, level), P)
    return _Level(level, s, gshape, rate, _Problem(R_match, Mv, P, C, GP, NE, lam, radius, sigma))
