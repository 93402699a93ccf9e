"""One motion type: where every pixel of the moving image lies in the reference image.

A :class:`Motion` is either a (3, 3) ``T_ref_mov`` (any global model) or a dense field (H, W, 2) of the
moving grid's size (:func:`pcreg.register_dense`, a flow) with, where the registration gave one, its
per-pixel confidence (H, W) in [0, 1]. :func:`pcreg.warp`, the prior of the fusion
(:func:`pcreg.pipeline.prior.warp_prior`), the temporal filter and the stream take one, or anything
:meth:`Motion.of` turns into one: a registration result, a 3x3 matrix or a field array.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError

__all__ = ["Motion", "field_from_matrix"]


@dataclass(frozen=True, eq=False, repr=False)
class Motion:
    """``matrix`` (3, 3) float64 ``T_ref_mov``, or ``field`` (H, W, 2) float32 reference coordinates of every
    moving pixel with an optional ``confidence`` (H, W) float32; exactly one of ``matrix`` and ``field``.
    Arrays are read-only copies."""

    matrix: np.ndarray | None = None
    field: np.ndarray | None = None
    confidence: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.matrix is None) == (self.field is None):
            raise InputError("a motion is a 3x3 matrix or a dense field: give exactly one")
        if self.matrix is not None:
            self._keep("matrix", _checked_matrix(self.matrix))
            if self.confidence is not None:
                raise InputError("a motion's confidence goes with a dense field, not a matrix")
            return
        fld = _checked_field(self.field)
        self._keep("field", fld)
        if self.confidence is not None:
            conf = np.asarray(self.confidence, dtype=np.float32)
            if conf.shape != fld.shape[:2]:
                raise InputError(f"a field's confidence must be (H, W) = {fld.shape[:2]}, got shape {conf.shape}")
            self._keep("confidence", conf)

    def _keep(self, name: str, value: np.ndarray) -> None:
        if value.flags.writeable:  # a caller's array: a read-only copy (a result's arrays are read-only already)
            value = value.copy()
            value.setflags(write=False)
        object.__setattr__(self, name, value)

    @classmethod
    def of(cls, motion: Any) -> "Motion":
        """``motion`` as a :class:`Motion`: itself; a dense result's field and confidence; a registration
        result's ``matrix``; a (3, 3) array; an (H, W, 2) array. Anything else is an :class:`InputError`."""
        if isinstance(motion, Motion):
            return motion
        fld = getattr(motion, "field", None)
        if fld is not None:
            return cls(field=fld, confidence=getattr(motion, "confidence", None))
        if hasattr(motion, "matrix"):
            return cls(matrix=motion.matrix)
        a = _array(motion, np.float64, "a motion must be a 3x3 matrix or a dense field")
        if a.ndim == 3 and a.shape[2] == 2:
            return cls(field=a)
        if a.shape != (3, 3):
            raise InputError(f"a motion must be a 3x3 matrix or an (H, W, 2) field, got shape {a.shape}")
        return cls(matrix=a)

    @property
    def is_field(self) -> bool:
        return self.field is not None

    def as_field(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W, 2) float32: the field, or the matrix applied to every pixel of an (H, W) ``shape`` grid."""
        if self.field is not None:
            return self.field
        assert self.matrix is not None
        return field_from_matrix(self.matrix, shape)

    def after(self, other: "Motion", shape: tuple[int, int]) -> "Motion":
        """This motion (frame b to frame a) after ``other`` (frame c to frame b): frame c to frame a.

        Two matrices compose into a matrix; otherwise the result is a field on frame c's (H, W)
        ``shape``, and points that leave frame b land far outside frame a (no prior arrives there)."""
        import cv2

        if self.matrix is not None and other.matrix is not None:
            return Motion(matrix=self.matrix @ other.matrix)
        f_cb = other.as_field(shape)
        if self.matrix is not None:
            from .transforms import apply

            return Motion(field=apply(self.matrix, f_cb.reshape(-1, 2)).reshape(f_cb.shape).astype(np.float32))
        assert self.field is not None
        # the (H, W, 2) map as it is (OpenCV rounds its two channels as it does two maps: the same field)
        return Motion(field=cv2.remap(self.field, np.ascontiguousarray(f_cb, np.float32), None, cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=(-1e6, -1e6)))

    def __repr__(self) -> str:
        if self.matrix is not None:
            return f"Motion(T_ref_mov={np.round(self.matrix, 6).tolist()})"
        assert self.field is not None
        h, w = self.field.shape[:2]
        conf = "" if self.confidence is None else f", mean_confidence={float(self.confidence.mean()):.3f}"
        return f"Motion(field={w}x{h}{conf})"


def field_from_matrix(T_ref_mov: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W, 2) float32 reference coordinates of every moving pixel under a 3x3 transform."""
    h, w = int(shape[0]), int(shape[1])
    M = np.ascontiguousarray(T_ref_mov, dtype=np.float64)
    if M.shape != (3, 3):
        raise InputError(f"T_ref_mov must be a 3x3 matrix, got shape {M.shape}")
    out = np.empty((h, w, 2), np.float32)
    if _field_jit is not None:  # one pass over the output (about a fifth of the array version's time)
        return _field_jit(M, out)
    return _field_py(M, out)


def _field_row_py(M, y, row):
    """``row[x]`` = ``M (x, y, 1)`` (projected) for one row ``y`` of a field, ``row`` (W, 2) float32: in
    float64 and rounded once to float32, the same operations in the same order as a broadcast of the
    pixel coordinates (an affine row's ``M[0, 1] y + M[0, 2]`` is the same for every pixel)."""
    w = row.shape[0]
    if M[2, 0] == 0 and M[2, 1] == 0 and M[2, 2] == 1:
        cx = M[0, 1] * y + M[0, 2]
        cy = M[1, 1] * y + M[1, 2]
        for j in range(w):
            x = float(j)
            row[j, 0] = M[0, 0] * x + cx
            row[j, 1] = M[1, 0] * x + cy
    else:
        for j in range(w):
            x = float(j)
            den = M[2, 0] * x + M[2, 1] * y + M[2, 2]
            row[j, 0] = (M[0, 0] * x + M[0, 1] * y + M[0, 2]) / den
            row[j, 1] = (M[1, 0] * x + M[1, 1] * y + M[1, 2]) / den


def _field_py(M, out):
    """``out[y, x]`` = ``M (x, y, 1)`` (projected) for every pixel, row by row (:func:`_field_row_py`)."""
    for i in range(out.shape[0]):
        _field_row(M, float(i), out[i])
    return out


try:  # compiled with numba (a declared dependency); the Python body is the same code and the fallback
    from .._jit import njit as _njit

    # numpy's error model: a pixel on a projective transform's horizon divides by zero and gets inf
    # or NaN, as in numpy, instead of raising
    _field_row = _njit(cache=True, nogil=True, inline="always", error_model="numpy")(_field_row_py)
    _field_jit = _njit(cache=True, nogil=True, error_model="numpy")(_field_py)
except ImportError:  # pragma: no cover
    _field_row, _field_jit = _field_row_py, None


def _array(x: Any, dtype: type, what: str) -> np.ndarray:
    """``x`` as an array of ``dtype``; what does not convert is an :class:`InputError` saying ``what``, and complex
    numbers (numpy would drop their imaginary parts with a warning) one naming them."""
    if np.iscomplexobj(x):
        raise InputError(f"{what}: complex numbers; give its real values")
    try:
        return np.asarray(x, dtype=dtype)
    except (TypeError, ValueError):
        raise InputError(f"{what}, got {type(x).__name__}") from None


def _checked_matrix(m: Any) -> np.ndarray:
    a = _array(m, np.float64, "T_ref_mov must be a 3x3 matrix")
    if a.shape != (3, 3):
        raise InputError(f"T_ref_mov must be a 3x3 matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError("T_ref_mov must be finite: it has NaN or inf values")
    return a


def _checked_field(f: Any) -> np.ndarray:
    a = _array(f, np.float32, "a field must be an (H, W, 2) array")
    if a.ndim != 3 or a.shape[2] != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"a field must be (H, W, 2), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError("the field has NaN or inf values")
    return a
