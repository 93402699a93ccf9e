"""Homogeneous transforms in pcreg's conventions.

Pixel coordinates: x to the right, y down, (0, 0) is the centre of the top-left pixel. A transform
``T_ref_mov`` maps a point in the moving frame into the reference frame; 2-D transforms are 3x3,
3-D transforms 4x4.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError, RegistrationError
from ..validation import real_matrix, short_repr

MODELS = ("translation", "rigid", "similarity", "affine", "projective")


def with_article(words: str) -> str:
    """``words`` after the article its first letter takes: "an affine motion", "a rigid transform"."""
    return ("an " if words[:1] in tuple("aeiou") else "a ") + words


def _matrix(matrix, name: str = "the matrix", sizes: tuple[int, ...] = (3, 4), *, finite: bool = True) -> np.ndarray:
    """``matrix`` as a float64 array, a homogeneous transform of one of ``sizes`` (3: 2-D, 4: 3-D), finite where
    ``finite``; else an :class:`InputError` naming ``name``."""
    m = _real(matrix, f"{name} must be a matrix of numbers, got {short_repr(matrix)}", name)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] not in sizes:
        said = " or ".join(f"{k}x{k}" for k in sizes)
        raise InputError(f"{name} must be a homogeneous {said} transform, got an array of shape {m.shape}")
    if finite and not np.isfinite(m).all():
        raise InputError(f"{name} has NaN or inf entries")
    return m


def _real(value, refusal: str, name: str) -> np.ndarray:
    """``value`` as a float64 array: itself where it is a plain one (the library's own calls, many a registration),
    else :func:`~pcreg.validation.real_matrix`'s copy."""
    if type(value) is np.ndarray and value.dtype == np.float64:
        return value
    return real_matrix(value, refusal, name)


def _number(value, name: str, **limits) -> float:
    """``value`` (a number, or a numpy array of one, shape ()) as a finite float within ``limits``
    (:func:`~pcreg.validation.check_float`)."""
    from ..validation import check_float

    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    return check_float(value, name, **limits)


def _shape(shape) -> tuple[int, int]:
    """(H, W) of an image ``shape`` (H, W, ...), or an :class:`InputError`."""
    try:
        h, w = (int(v) for v in tuple(shape)[:2])
    except (TypeError, ValueError):
        raise InputError(f"an image shape is (H, W, ...), got {short_repr(shape)}") from None
    if h < 1 or w < 1 or len(tuple(shape)) < 2:
        raise InputError(f"an image shape is (H, W, ...) of at least one pixel, got {short_repr(shape)}")
    return h, w


def check_model(model: str, dim: int = 2) -> str:
    if not isinstance(model, str) or model not in MODELS:
        raise InputError(f"unknown motion model {short_repr(model)}; choose one of {', '.join(MODELS)}")
    if model == "projective" and dim != 2:
        raise InputError("the projective model exists for 2-D clouds only")
    return model


#: How far a rigid transform's rotation block may be from orthonormal (``R^T R`` from the identity) for it to
#: be taken as a start: a matrix written with three decimals (Open3D's own test of its ICP starts from one) is
#: within 0.5%; a scale or a shear of a few percent is not. Its last row must be ``(0, ..., 0, 1)`` to
#: :data:`LAST_ROW_TOLERANCE` (a last row 0.01 off is a strong projection at 500 px).
ROTATION_TOLERANCE = 0.05
LAST_ROW_TOLERANCE = 1e-9


def rigid_problem(matrix: np.ndarray, *, tolerance: float = ROTATION_TOLERANCE,
                  row_tolerance: float = LAST_ROW_TOLERANCE) -> str | None:
    """What makes a finite homogeneous (d+1)x(d+1) ``matrix`` not a rigid transform (its last row a
    projection's, beyond ``row_tolerance``; its rotation block a scale or a shear, beyond ``tolerance``; a
    reflection), as a phrase about "it"; None when it is one."""
    m = _matrix(matrix, finite=False)
    d = m.shape[0] - 1
    if not np.isfinite(m).all():
        return "it has NaN or inf entries, not a rigid transform's"
    if np.abs(m[d] - np.eye(d + 1)[d]).max() > row_tolerance:
        return f"its last row is {m[d].tolist()}, not a rigid transform's"
    R = m[:d, :d]
    if np.linalg.det(R) < 0:
        return "it is a reflection (determinant -1), not a rigid transform"
    if np.abs(R.T @ R - np.eye(d)).max() > tolerance:
        return "its rotation block is not orthonormal (a scale or a shear): not a rigid transform"
    return None


def nearest_rigid(matrix: np.ndarray) -> np.ndarray:
    """The rigid transform nearest a (d+1)x(d+1) ``matrix`` that :func:`rigid_problem` accepts: its rotation
    block's nearest rotation (SVD), its translation, and the last row ``(0, ..., 0, 1)``."""
    m = _matrix(matrix)
    d = m.shape[0] - 1
    U, singular, Vt = np.linalg.svd(m[:d, :d])
    if singular[-1] <= 0:
        raise InputError("the matrix's rotation block is singular: no one rotation is nearest it")
    D = np.eye(d)
    D[-1, -1] = np.sign(np.linalg.det(U @ Vt))
    out = np.eye(d + 1)
    out[:d, :d] = U @ D @ Vt
    out[:d, d] = m[:d, d]
    return out


def apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (d+1, d+1) homogeneous transform to (N, d) points; projective rows divide through.

    A point that a projective transform sends to infinity comes out as inf or nan, without a warning:
    callers that search over hypotheses meet such matrices and judge them by their results."""
    matrix = _matrix(matrix, finite=False)
    points = _real(points, f"points must be an (N, d) array of numbers, got {short_repr(points)}", "points")
    d = matrix.shape[0] - 1
    if points.ndim != 2 or points.shape[1] != d:
        raise InputError(f"a {d + 1}x{d + 1} transform moves (N, {d}) points, got an array of shape {points.shape}")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = points @ matrix[:d, :d].T + matrix[:d, d]
        last = matrix[d, :d]
        if np.any(last != 0) or matrix[d, d] != 1:
            w = points @ last + matrix[d, d]
            out = out / w[:, None]
    return out


def rigid2d(angle_deg: float = 0.0, tx: float = 0.0, ty: float = 0.0, *, scale: float = 1.0) -> np.ndarray:
    """3x3 matrix of a rotation by ``angle_deg`` (counter-clockwise on screen is negative with y down;
    here the rotation is the plain mathematical one in (x, y)), uniform ``scale``, then translation."""
    a = np.deg2rad(_number(angle_deg, "angle_deg"))
    tx, ty = _number(tx, "tx"), _number(ty, "ty")
    scale = _number(scale, "scale", lo=0, lo_open=True)
    c, s = np.cos(a) * scale, np.sin(a) * scale
    return np.array([[c, -s, tx], [s, c, ty], [0.0, 0.0, 1.0]])


def about_point(matrix: np.ndarray, center_from: tuple[float, ...], center_to: tuple[float, ...] | None = None) -> np.ndarray:
    """``T(center_to) @ matrix @ T(-center_from)``: apply ``matrix`` about a point (e.g. the image centre); in
    2-D (3x3) or 3-D (4x4), by the point's dimension."""
    m = _matrix(matrix)
    d = m.shape[0] - 1
    points = []
    for name, point in (("center_from", center_from), ("center_to", center_from if center_to is None else center_to)):
        p = real_matrix(point, f"{name} must be a point of numbers, got {short_repr(point)}", name)
        if p.shape != (d,) or not np.isfinite(p).all():
            raise InputError(f"{name} must be a finite point of {d} coordinates for a {d + 1}x{d + 1} transform, "
                             f"got {short_repr(point)}")
        points.append(p)
    a = np.eye(d + 1)
    a[:d, d] = -points[0]
    b = np.eye(d + 1)
    b[:d, d] = points[1]
    return b @ m @ a


def image_center(shape: tuple[int, ...]) -> tuple[float, float]:
    """Centre (x, y) of an image of shape (H, W, ...) in pixel coordinates."""
    h, w = _shape(shape)
    return ((w - 1) / 2.0, (h - 1) / 2.0)


def corners(shape: tuple[int, ...]) -> np.ndarray:
    """(4, 2) outer corners of an image of shape (H, W, ...): pixel edges, not pixel centres."""
    h, w = _shape(shape)
    return np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])


def max_corner_error(estimate: np.ndarray, truth: np.ndarray, shape: tuple[int, ...]) -> float:
    """Largest distance (px) between the moving image's corners mapped by ``estimate`` and by ``truth``."""
    c = corners(shape)
    estimate, truth = _matrix(estimate, "estimate", (3,), finite=False), _matrix(truth, "truth", (3,), finite=False)
    return float(np.max(np.linalg.norm(apply(estimate, c) - apply(truth, c), axis=1)))


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (degrees, >= 0) of a 2x2 or 3x3 rotation matrix (a 3x3 whose last row is (0, 0, 1), a 2-D
    homogeneous transform too: the angle of its 2x2 block; a 4x4 whose last row is (0, 0, 0, 1), a 3-D
    homogeneous transform, as :func:`pcreg.icp` returns for 3-D clouds: the angle of its 3x3 block). A
    similarity's scale is left out (the block divided by it). Any other shape is an :class:`InputError`.

    In 3-D, atan2(|axis part|, cos part) of the rotation (the skew-symmetric and the trace part of R): full
    precision at every angle. The arccos of the trace alone, as before, returned 0 for a rotation of 1e-9 rad and
    9.9e-8 for one of 1e-7 rad, and 8.5e-7 degrees for an angle of 0 one rounding off the identity."""
    R = real_matrix(R, f"a rotation must be a matrix of numbers, got {short_repr(R)}", "the rotation")
    if not np.isfinite(R).all():
        raise InputError("the rotation has NaN or inf entries")
    if R.shape == (4, 4) and np.array_equal(R[3], [0.0, 0.0, 0.0, 1.0]):  # a 3-D homogeneous transform
        R = R[:3, :3]
    if R.shape == (3, 3) and R[2, 0] == 0 and R[2, 1] == 0 and R[2, 2] == 1:  # about z, or a 2-D homogeneous matrix
        R = R[:2, :2]
    if R.shape in ((2, 2), (3, 3)) and np.linalg.det(R) < 0:
        raise InputError("the matrix is a reflection (determinant below 0), not a rotation: it has no angle")
    if R.shape == (2, 2):
        return float(abs(np.degrees(np.arctan2(R[1, 0], R[0, 0]))))
    if R.shape != (3, 3):
        raise InputError(f"a rotation is a 2x2 or 3x3 matrix, or a homogeneous 3x3 or 4x4 transform (last row "
                         f"(0, ..., 0, 1)); got a {'x'.join(map(str, R.shape))} array"
                         + (" whose last row is a projection's" if R.shape == (4, 4) else ""))
    det = float(np.linalg.det(R))
    if det > 0 and not det == 1.0:  # a similarity's block s R: its rotation's angle
        R = R / np.cbrt(det)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.degrees(np.arctan2(np.linalg.norm(axis) / 2.0, (np.trace(R) - 1.0) / 2.0)))


def rotation_disagreement_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Angle (degrees) of the rotation between two homogeneous transforms' linear parts (polar-decomposed)."""
    A, B = _matrix(A, "A"), _matrix(B, "B")
    if A.shape != B.shape:
        raise InputError(f"A and B must be transforms of one dimension, got {A.shape[0]}x{A.shape[0]} and "
                         f"{B.shape[0]}x{B.shape[0]}")
    d = A.shape[0] - 1
    RA, RB = rotation_part(A[:d, :d]), rotation_part(B[:d, :d])
    return rotation_angle_deg(RA.T @ RB)


def rotation_part(M: np.ndarray) -> np.ndarray:
    """The rotation closest to the (d, d) matrix ``M`` (polar decomposition, det +1): removes a scale."""
    M = _matrix(M, "M", (2, 3))
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def lift_to_3d(matrix: np.ndarray) -> np.ndarray:
    """A 3x3 2-D affine transform as the 4x4 transform acting on the plane z = 0."""
    m = _matrix(matrix, finite=False)
    if m.shape == (4, 4):
        return m.copy()
    if np.any(m[2, :2] != 0) or m[2, 2] != 1:
        raise InputError("a projective 2-D transform cannot be lifted to a 3-D rigid transform")
    out = np.eye(4)
    out[:2, :2] = m[:2, :2]
    out[:2, 3] = m[:2, 2]
    return out


def project_to_2d(matrix: np.ndarray, *, tol: float = 1e-6) -> np.ndarray:
    """A 4x4 transform that should keep the plane z = 0 as the 3x3 2-D transform; raises when it tilts.

    The out-of-plane part (M[2, :2], M[:2, 2] and t_z) must be below ``tol`` (relative to the scale of the
    linear part), else the 3-D solution does not describe a motion in the image plane; M[2, 2] (the
    z-scale) does not act on points with z = 0 and is not checked. A mirrored plane (det < 0) is refused.
    """
    m = _matrix(matrix, "the 3-D transform", (4,), finite=False)
    scale = max(1.0, float(np.abs(m[:3, :3]).max()))
    out_of_plane = max(abs(m[2, 0]), abs(m[2, 1]), abs(m[0, 2]), abs(m[1, 2]))
    if not np.all(np.isfinite(m)):
        raise RegistrationError("the 3-D ICP result has NaN or inf entries")
    det = float(np.linalg.det(m[:2, :2]))
    if det == 0:
        raise RegistrationError("the 3-D ICP result collapses the image plane (a scale of 0)")
    if det < 0:
        raise RegistrationError("the 3-D ICP result mirrors the image plane")
    if out_of_plane > tol * scale or abs(m[2, 3]) > tol * max(1.0, float(np.abs(m[:2, 3]).max())):
        raise RegistrationError(
            f"the 3-D ICP result leaves the image plane (out-of-plane part {out_of_plane:.2e}, t_z {m[2, 3]:.2e})"
        )
    out = np.eye(3)
    out[:2, :2] = m[:2, :2]
    out[:2, 2] = m[:2, 3]
    return out


def scale_transform(matrix: np.ndarray, factor: float) -> np.ndarray:
    """The same motion expressed in coordinates scaled by ``factor`` (x' = factor * x)."""
    m, factor = _matrix(matrix, finite=False), _number(factor, "factor", lo=0, lo_open=True)
    d = m.shape[0]
    S = np.eye(d)
    S[: d - 1, : d - 1] *= factor
    Si = np.eye(d)
    Si[: d - 1, : d - 1] /= factor
    return S @ m @ Si


#: The largest change of area a 2-D transform may make to an image: a tenfold zoom either way. Beyond it
#: the two images share too few pixels at a common scale for their edges to register.
MAX_AREA_CHANGE = 100.0


def degeneracy(T_ref_mov: np.ndarray, shape: tuple[int, ...]) -> str | None:
    """Why a 3x3 ``T_ref_mov`` cannot be a view of an image of ``shape`` (H, W, ...), or None when it can.

    Degenerate: a non-finite entry; a corner sent through infinity (the homography's horizon line
    crosses the image, its homogeneous w <= 0 there); the corners' quadrilateral folded or mirrored
    (not convex with the image's orientation); an area changed by more than :data:`MAX_AREA_CHANGE`.
    """
    shape = _shape(shape)
    M = real_matrix(T_ref_mov, "the transform must be a 3x3 matrix of numbers", "the transform")
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        return "the transform is not a finite 3x3 matrix"
    c = np.concatenate([corners(shape), np.ones((4, 1))], axis=1) @ M.T
    w = c[:, 2] * np.sign(M[2, 2] if M[2, 2] != 0 else 1.0)
    # a point sent beyond 1e12 times its w is through infinity; an affine's w is its M[2, 2] at every point, and a
    # translation however far (it overlaps nothing then, which registration says) is not a horizon
    affine = M[2, 0] == M[2, 1] == 0
    far = 0.0 if affine else 1e-12 * np.abs(c[:, :2]).max(initial=1.0)
    if np.any(w <= far):
        return "the transform sends part of the image through infinity (a singular or folded homography)"
    # an affine's shape is its linear part's (a translation moves every corner alike, and far off would round the
    # corners' differences away)
    with np.errstate(over="ignore"):  # a zoom past float's range: an area of inf, refused below
        q = corners(shape) @ (M[:2, :2] / M[2, 2]).T if affine else c[:, :2] / c[:, 2:3]
        edges = np.roll(q, -1, axis=0) - q
        turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
        area = 0.5 * abs(float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])))
    h, w_img = float(shape[0]), float(shape[1])
    if not np.all(turns > 0):  # the image's own corners turn one way (y down): a fold or a mirror turns otherwise
        return "the transform folds or mirrors the image (its corners no longer form a convex quadrilateral of the same orientation)"
    ratio = area / max(h * w_img, 1.0)
    if not 1.0 / MAX_AREA_CHANGE <= ratio <= MAX_AREA_CHANGE:
        return f"the transform changes the image's area by a factor of {ratio:.3g} (at most {MAX_AREA_CHANGE:g} either way)"
    return None
