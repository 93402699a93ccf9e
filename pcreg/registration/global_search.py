"""Global hypotheses for image registration, and the evidence that tells a true alignment from a false one.

Generators (each returns candidate ``T_ref_mov`` matrices in full-resolution pixel coordinates):

- :func:`edge_fft_hypotheses`: the edge clouds rasterised, the moving one rotated every few degrees over
  the full circle, each rotation's translation found by FFT cross-correlation (geometry only);
- :func:`orb_hypotheses`: ORB binary features (Rublee et al. 2011) matched across the images at a reduced
  pyramid level, a similarity fitted by RANSAC (``cv2.estimateAffinePartial2D``; an affine or a homography
  for those models): intensity patterns,
  which tell apart places whose edges look alike (repetitive textures);
- :func:`fourier_mellin_hypotheses`: rotation (and scale) from the phase correlation of the log-polar
  magnitude spectra, translation from the phase correlation of the de-rotated intensity images
  (Reddy & Chatterji 1996): whole-image intensity, no features needed.

:func:`alignment_evidence` measures an alignment at one pyramid level: the share of moving edge points,
among those that land on the reference image, that have a reference edge point within ``tolerance``
px whose edge direction agrees within ``max_angle_deg``. A true alignment of the same scene puts most
points there; an alignment of unrelated content only as many as chance allows (see
:data:`DEFAULT_MIN_INLIER_RATIO` in :mod:`pcreg.registration.config`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .clouds import ImageCloud, magnitude, valid_region
from .transforms import about_point, apply, image_center, rigid2d

GENERATORS = ("fourier_mellin", "edges", "orb")


# ---------------------------------------------------------------------------------------------------
# Edge clouds: rotation search with FFT translation
# ---------------------------------------------------------------------------------------------------

def rasterise(points: np.ndarray, size: int, sigma: float) -> np.ndarray:
    """Points (N, 2) in cell units around the canvas centre -> blurred (size, size) float32 density."""
    ij = np.rint(points + size / 2.0).astype(np.intp)
    keep = (ij[:, 0] >= 0) & (ij[:, 0] < size) & (ij[:, 1] >= 0) & (ij[:, 1] < size)
    flat = ij[keep, 1] * size + ij[keep, 0]
    img = np.bincount(flat, minlength=size * size).astype(np.float32).reshape(size, size)
    return cv2.GaussianBlur(img, (0, 0), sigma)


def edge_canvas(shape: tuple[int, ...], g: float) -> float:
    """The side of :func:`edge_fft_hypotheses`' square canvas, in cells of ``g`` px, for a reference of ``shape``: the
    reference plus a margin for shifts up to a quarter of its size (moving points rotated beyond it, the far corners,
    are dropped, which costs little correlation and halves the FFT)."""
    return 1.5 * max(shape[:2]) / g


def edge_fft_hypotheses(ref: ImageCloud, mov: ImageCloud, *, angles: np.ndarray, sigma: float = 1.0,
                        cell: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid hypotheses over the full circle: for each angle, the best translation by FFT cross-correlation.

    Both clouds are rasterised at their (coarse) pyramid level and blurred; the moving cloud is rotated
    by each angle about its image centre, put on the reference centre, and the peak of its cross-
    correlation with the reference (``cv2.dft``) gives the translation and a score. Returns (K, 3, 3)
    matrices ``T_ref_mov`` and (K,) scores (correlation peaks, comparable across angles because the same
    moving points are rasterised every time). ``cell``: the canvas's cell in full-resolution px (None: a pixel of
    the clouds' level), larger to keep a long image's canvas small.
    """
    g = float(2 ** ref.level) if cell is None else float(cell)
    c_ref = np.array(image_center(ref.shape))
    c_mov = np.array(image_center(mov.shape))
    extent = edge_canvas(ref.shape, g)
    size = cv2.getOptimalDFTSize(int(np.ceil(max(extent, 16.0))))
    R = rasterise((ref.points - c_ref) / g, size, sigma)
    FR = cv2.dft(R)  # real input: packed (CCS) spectrum, half the work of a complex one
    pm = (mov.points - c_mov) / g
    Ts, scores = [], []
    for a in angles:
        Rot = rigid2d(a)[:2, :2]
        M = rasterise(pm @ Rot.T, size, sigma)
        FM = cv2.dft(M)
        C = cv2.idft(cv2.mulSpectrums(FR, FM, 0, conjB=True), flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
        iy, ix = np.unravel_index(int(np.argmax(C)), C.shape)
        peak = float(C[iy, ix])

        def sub(c_m, c_0, c_p):  # sub-cell peak by a parabola through the neighbours, per axis
            den = c_m - 2 * c_0 + c_p
            return 0.5 * (c_m - c_p) / den if den < 0 else 0.0

        dx = ix + sub(C[iy, ix - 1], peak, C[iy, (ix + 1) % size])
        dy = iy + sub(C[iy - 1, ix], peak, C[(iy + 1) % size, ix])
        dx = dx - size if dx > size / 2 else dx
        dy = dy - size if dy > size / 2 else dy
        T = about_point(rigid2d(a), tuple(c_mov), tuple(c_ref))
        T[:2, 2] += np.array([dx, dy]) * g
        Ts.append(T)
        scores.append(peak)
    return np.stack(Ts), np.array(scores)


# ---------------------------------------------------------------------------------------------------
# Intensity: ORB + RANSAC, Fourier-Mellin
# ---------------------------------------------------------------------------------------------------

def gray_level(image: np.ndarray, level: int, *, valid: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray | None]:
    """Grey image at pyramid ``level`` and its usable-pixel mask (uint8 255/0, None when all usable).

    valid : (H, W) bool usable pixels at full resolution, if already known (default :func:`valid_region`).
    """
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if valid is None:
        valid = valid_region(image)
    mask = None if valid.all() else valid.astype(np.uint8) * 255
    for _ in range(level):
        gray = cv2.pyrDown(gray)
        if mask is not None:
            mask = cv2.resize(mask, (gray.shape[1], gray.shape[0]), interpolation=cv2.INTER_AREA)
    if mask is not None:
        mask = cv2.erode((mask == 255).astype(np.uint8) * 255, np.ones((7, 7), np.uint8))
    return gray, mask


def _to_full(points: np.ndarray, level: int) -> np.ndarray:
    f = float(2 ** level)
    return points * f + (f - 1.0) / 2.0


def _fix_model(T: np.ndarray, model: str) -> np.ndarray:
    """A similarity hypothesis reduced to ``model`` (rigid: unit scale; translation: no rotation)."""
    out = np.array(T, dtype=np.float64)
    if model in ("rigid", "translation"):
        s = np.sqrt(abs(np.linalg.det(out[:2, :2])))
        if s > 0:
            out[:2, :2] /= s
    if model == "translation":
        out[:2, :2] = np.eye(2)
    return out


@dataclass(frozen=True)
class OrbMatches:
    """ORB's cross-checked matches of a pair at one pyramid ``level`` (:func:`orb_matches`): ``moving`` and
    ``reference`` (N, 2) float32, the matched keypoints in full-resolution pixel coordinates, row by row."""

    level: int
    moving: np.ndarray
    reference: np.ndarray


def orb_matches(reference_image: np.ndarray, moving_image: np.ndarray, *, level: int = 1, n_features: int = 1000,
                reference_valid: np.ndarray | None = None, moving_valid: np.ndarray | None = None
                ) -> OrbMatches | None:
    """ORB features at pyramid ``level`` (black padding masked out of the detection), matched by cross-checked
    Hamming distance; None when either image has fewer than 6 features or fewer than 6 matches survive."""
    g1, m1 = gray_level(reference_image, level, valid=reference_valid)
    g2, m2 = gray_level(moving_image, level, valid=moving_valid)
    orb = cv2.ORB_create(nfeatures=int(n_features))
    k1, d1 = orb.detectAndCompute(g1, m1)
    k2, d2 = orb.detectAndCompute(g2, m2)
    if d1 is None or d2 is None or len(k1) < 6 or len(k2) < 6:
        return None
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d2, d1)
    if len(matches) < 6:
        return None
    p_mov = _to_full(np.float32([k2[m.queryIdx].pt for m in matches]), level)
    p_ref = _to_full(np.float32([k1[m.trainIdx].pt for m in matches]), level)
    return OrbMatches(level, p_mov.astype(np.float32), p_ref.astype(np.float32))


def orb_fit(matches: OrbMatches | None, *, model: str = "rigid", ransac_px: float = 2.0, seed: int = 0
            ) -> list[np.ndarray]:
    """At most one hypothesis from ``matches`` (:func:`orb_matches`): a similarity by RANSAC
    (``cv2.estimateAffinePartial2D``, threshold ``ransac_px`` at the matches' level; for an ``affine`` ``model``
    a full affine, ``cv2.estimateAffine2D``; for ``projective`` a homography, ``cv2.findHomography``, from at
    least 8 inliers). Returns [] without matches or a model."""
    if matches is None:
        return []
    p_mov, p_ref, level = matches.moving, matches.reference, matches.level
    cv2.setRNGSeed(int(seed))
    # an affine registration gets a full affine, a projective one a homography (a shear and two scales, or a
    # perspective, which their ICP from a similarity start often did not reach: docs/algorithms.md); the
    # others a similarity
    if model == "projective":
        H, inliers = cv2.findHomography(p_mov, p_ref, cv2.RANSAC, ransac_px * 2**level, maxIters=2000, confidence=0.995)
        if H is None or inliers is None or int(inliers.sum()) < 8 or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
            return []
        return [H / H[2, 2]]
    fit = cv2.estimateAffine2D if model == "affine" else cv2.estimateAffinePartial2D
    M, inliers = fit(p_mov, p_ref, method=cv2.RANSAC, ransacReprojThreshold=ransac_px * 2**level, maxIters=2000,
                     confidence=0.995)
    if M is None or inliers is None or int(inliers.sum()) < 6 or not np.all(np.isfinite(M)):
        return []
    return [_fix_model(np.vstack([M, [0.0, 0.0, 1.0]]), model)]


def orb_hypotheses(reference_image: np.ndarray, moving_image: np.ndarray, *, level: int = 1,
                   n_features: int = 1000, model: str = "rigid", ransac_px: float = 2.0,
                   seed: int = 0, reference_valid: np.ndarray | None = None,
                   moving_valid: np.ndarray | None = None) -> list[np.ndarray]:
    """At most one hypothesis: :func:`orb_matches` at pyramid ``level`` fitted by :func:`orb_fit` (a similarity
    by RANSAC, threshold ``ransac_px`` at that level; an affine or a homography for those models).

    Black padding is masked out of the detection. Returns [] when fewer than 6 matches survive.
    """
    matches = orb_matches(reference_image, moving_image, level=level, n_features=n_features,
                          reference_valid=reference_valid, moving_valid=moving_valid)
    return orb_fit(matches, model=model, ransac_px=ransac_px, seed=seed)


def _canvas(gray: np.ndarray, mask: np.ndarray | None, size: int) -> np.ndarray:
    """``gray`` minus its mean over usable pixels, zero elsewhere, centred on a (size, size) canvas."""
    g = gray.astype(np.float32)
    use = np.ones(g.shape, bool) if mask is None else mask > 0
    g = np.where(use, g - float(g[use].mean()) if use.any() else 0.0, 0.0).astype(np.float32)
    # Taper the usable region's border (a soft mask) so that its outline does not dominate the spectrum.
    soft = cv2.GaussianBlur(use.astype(np.float32), (0, 0), 3.0) * use
    g *= soft
    out = np.zeros((size, size), np.float32)
    h, w = g.shape
    y0, x0 = (size - h) // 2, (size - w) // 2
    out[y0:y0 + h, x0:x0 + w] = g
    return out


def _spectrum_weights(size: int) -> tuple[np.ndarray, np.ndarray]:
    """The (size, size) Hanning window and the high-pass weight of the magnitude spectra (the low
    frequencies carry the window, not the content), float32. The high-pass weight is the distance from
    the centre of each (x, y) of the grid, its rows and columns broadcast (the values of a full
    ``np.mgrid``'s, made in a fraction of its time)."""
    win = cv2.createHanningWindow((size, size), cv2.CV_32F)
    ax = np.arange(size, dtype=np.float32) - size / 2
    highpass = np.clip(np.hypot(ax[None, :], ax[:, None]) / (size / 2), 0, 1) ** 2
    return win, highpass


def fourier_mellin_hypotheses(reference_image: np.ndarray, moving_image: np.ndarray, *, level: int = 2,
                              model: str = "rigid", reference_valid: np.ndarray | None = None,
                              moving_valid: np.ndarray | None = None) -> list[np.ndarray]:
    """Two hypotheses (the rotation and its 180° twin) by the Fourier-Mellin transform at ``level``.

    The magnitude spectra of both (windowed, mean-free) images are high-pass weighted and resampled to
    log-polar (``cv2.warpPolar``); the phase correlation of the two log-polar images gives the rotation
    (and, for ``model="similarity"``, the scale). The moving image is de-rotated onto the reference's
    canvas and a phase correlation (``cv2.phaseCorrelate``) gives the translation.
    """
    g1, m1 = gray_level(reference_image, level, valid=reference_valid)
    g2, m2 = gray_level(moving_image, level, valid=moving_valid)
    size = cv2.getOptimalDFTSize(max(g1.shape + g2.shape))
    win, highpass = _spectrum_weights(size)
    A = _canvas(g1, m1, size)  # also the reference side of each translation's phase correlation (copied)
    B = _canvas(g2, m2, size)

    def logpolar_magnitude(img):
        F = cv2.dft(img * win, flags=cv2.DFT_COMPLEX_OUTPUT)
        F = np.fft.fftshift(magnitude(F[..., 0], F[..., 1]))
        F = np.log1p(F * highpass)
        return cv2.warpPolar(F, (size, size), (size / 2, size / 2), size / 2,
                             cv2.WARP_POLAR_LOG | cv2.INTER_LINEAR)

    LA, LB = logpolar_magnitude(A), logpolar_magnitude(B)
    half = size // 2  # rows = angle over 360°; the spectrum is symmetric, so use one half-turn of rows
    (sx, sy), _ = cv2.phaseCorrelate(LA[:half], LB[:half])
    angle = -360.0 * sy / size
    scale = 1.0
    if model == "similarity":
        scale = float(np.exp(sx * np.log(size / 2) / size))
        if not 0.5 < scale < 2.0:
            scale = 1.0
    c_ref = image_center(reference_image.shape)
    c_mov = image_center(moving_image.shape)
    out = []
    for a in (angle, angle + 180.0):
        T0 = about_point(rigid2d(a, scale=scale), c_mov, c_ref)
        # De-rotate the moving image onto the reference grid at this level and find the translation.
        f = 2.0 ** level
        S = np.diag([f, f, 1.0])
        S[:2, 2] = (f - 1.0) / 2.0  # level -> full-resolution pixel centres
        Tl = np.linalg.inv(S) @ T0 @ S
        warped = cv2.warpAffine(g2.astype(np.float32), Tl[:2], (g1.shape[1], g1.shape[0]), flags=cv2.INTER_LINEAR)
        wm = cv2.warpAffine(np.full(g2.shape, 255, np.uint8) if m2 is None else m2, Tl[:2], (g1.shape[1], g1.shape[0]),
                            flags=cv2.INTER_NEAREST)
        wm = cv2.erode(wm, np.ones((5, 5), np.uint8))
        P = _canvas(warped, wm if m1 is None else cv2.bitwise_and(wm, m1), size)
        # a copy: with a window, cv2.phaseCorrelate multiplies its inputs by it in place (OpenCV 5.0)
        (dx, dy), _ = cv2.phaseCorrelate(P, A.copy(), win)
        T = T0.copy()
        T[:2, 2] += np.array([dx, dy]) * f
        out.append(_fix_model(T, model))
    return out


# ---------------------------------------------------------------------------------------------------
# Evidence
# ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Evidence:
    """How well ``T_ref_mov`` aligns the moving edge cloud with the reference's at one level.

    inlier_ratio : share of the overlapping moving points with a reference point within ``tolerance``
        px whose edge normal agrees within ``max_angle_deg`` (0 when nothing overlaps).
    overlap_points : moving points that land inside the reference image.
    moving_points : moving points at that level.
    chance_ratio : the inlier ratio that content unrelated in direction would reach at the same distances:
        the share of points within ``tolerance`` times the share of direction agreements between each
        such point's normal and the normal matched to another such point (a fixed permutation).
    """

    inlier_ratio: float
    overlap_points: int
    moving_points: int
    chance_ratio: float = 0.0

    @property
    def overlap(self) -> float:
        """The share of the moving points that land inside the reference image."""
        return self.overlap_points / max(self.moving_points, 1)


def alignment_evidence(T: np.ndarray, mov: ImageCloud, ref: ImageCloud, tree, *, tolerance: float,
                       max_angle_deg: float = 30.0) -> Evidence:
    """The tight-inlier share of an alignment (see :class:`Evidence`); ``tree`` indexes ``ref.points``."""
    p = apply(T, mov.points)
    h, w = ref.shape
    inside = (p[:, 0] >= -0.5) & (p[:, 0] <= w - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] <= h - 0.5)
    n_in = int(inside.sum())
    if n_in == 0:
        return Evidence(0.0, 0, len(mov))
    dist, idx = tree.query(p[inside], k=1, distance_upper_bound=tolerance)
    ok = np.isfinite(dist)
    L = T[:2, :2]
    # Normals transform by the inverse transpose of the linear part; only their direction matters.
    try:
        L_inv = np.linalg.inv(L)
    except np.linalg.LinAlgError:  # a motion that flattens the image onto a line: no normal survives it
        L_inv = np.full((2, 2), np.nan)
    with np.errstate(over="ignore", invalid="ignore"):  # a nearly singular L: normals that agree with nothing (NaN)
        n_mov = mov.normals[inside][ok] @ L_inv
        n_mov /= np.maximum(np.linalg.norm(n_mov, axis=1, keepdims=True), 1e-12)
        cos = np.einsum("ij,ij->i", n_mov, ref.normals[idx[ok]])
    c_min = np.cos(np.deg2rad(max_angle_deg))
    agree = int(np.count_nonzero(cos >= c_min))
    k = int(ok.sum())
    chance = 0.0
    if k > 1:
        perm = np.random.default_rng(0).permutation(k)
        with np.errstate(invalid="ignore"):
            cos_null = np.einsum("ij,ij->i", n_mov, ref.normals[idx[ok]][perm])
        chance = (k / n_in) * float(np.mean(cos_null >= c_min))
    return Evidence(agree / n_in, n_in, len(mov), chance)


def photometric_agreement(T: np.ndarray, reference_gray: np.ndarray, moving_gray: np.ndarray, *, level: int,
                          moving_valid: np.ndarray | None = None) -> float:
    """Zero-mean normalised cross-correlation of the reference and the moving image warped by ``T``
    (``T_ref_mov``, full-resolution pixels) over their overlap, both given at pyramid ``level``.

    Edges alone cannot tell a repetitive pattern (bricks, tiles) from its copy shifted by one period or
    turned by 180°; the intensities between the edges can. Returns -1..1 (0 when the overlap is tiny).
    """
    f = 2.0 ** level
    S = np.array([[f, 0.0, (f - 1.0) / 2.0], [0.0, f, (f - 1.0) / 2.0], [0.0, 0.0, 1.0]])
    Tl = np.linalg.inv(S) @ T @ S
    h, w = reference_gray.shape
    valid = np.full(moving_gray.shape, 255, np.uint8) if moving_valid is None else moving_valid
    if T[2, 0] == 0 and T[2, 1] == 0 and T[2, 2] == 1:  # a homography scaled by another last entry: warpPerspective
        warped = cv2.warpAffine(moving_gray, Tl[:2], (w, h), flags=cv2.INTER_LINEAR)
        wv = cv2.warpAffine(valid, Tl[:2], (w, h), flags=cv2.INTER_NEAREST) > 0
    else:  # a homography's perspective part too (its affine part alone misplaced the far side)
        warped = cv2.warpPerspective(moving_gray, Tl, (w, h), flags=cv2.INTER_LINEAR)
        wv = cv2.warpPerspective(valid, Tl, (w, h), flags=cv2.INTER_NEAREST) > 0
    if wv.sum() < 64:
        return 0.0
    a = reference_gray[wv].astype(np.float64)
    b = warped[wv].astype(np.float64)
    a -= a.mean()
    b -= b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 0 else 0.0
