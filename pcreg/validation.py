"""Checks applied to the numbers and arrays that enter pcreg (files: :mod:`pcreg.formats`).

Limits
    ``max_pixels`` bounds the pixels of an image and the points of a cloud. The default,
    :data:`DEFAULT_MAX_PIXELS` (50 million: a 48-megapixel photo fits, a decoded RGB image of that size
    is 150 MB), can be raised per call, for a whole process (and its worker processes) with the
    environment variable ``PCREG_MAX_PIXELS``, or on the command line with ``--max-pixels``. Files are
    checked before they are decoded (:mod:`pcreg.formats`), arrays where the library converts them
    (:func:`check_pixels`, :func:`check_point_count`).

Numbers
    :func:`check_int`, :func:`check_float` (and their argparse twins in :mod:`pcreg.commands._common`)
    refuse non-finite values and values out of range with one readable line.

Everything raises :class:`~pcreg.errors.InputError` (a :class:`~pcreg.errors.PcregError`).
"""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path

import numpy as np

from .errors import InputError

DEFAULT_MAX_PIXELS = 50_000_000
MAX_UNITS = 100_000  # evaluation units one command may plan
_ENV = "PCREG_MAX_PIXELS"


# --------------------------------------------------------------------------------------------------
# numbers
# --------------------------------------------------------------------------------------------------

def range_text(lo, hi) -> str:
    """An integer range as the messages write it: ``>= 1``, ``1..8``, ``-inf..8``."""
    if hi is None:
        return f">= {lo}" if lo is not None else "any integer"
    return f"{'-inf' if lo is None else lo}..{hi}"


def check_int(value, name: str, *, lo: int | None = None, hi: int | None = None) -> int:
    """``value`` as an int (a Python or numpy integer, not a float or bool) within [lo, hi]."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise InputError(f"{name} must be an integer, got {short_repr(value)}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise InputError(f"{name} must be {'' if hi is None else 'in '}{range_text(lo, hi)}, got {v}")
    return v


def check_float(value, name: str, *, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, hi_open: bool = False) -> float:
    """``value`` as a finite float within the range (``lo_open``: value > lo, else value >= lo)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a number, got {short_repr(value)}")
    try:
        v = float(value)
    except OverflowError:  # an int beyond float's range
        raise InputError(f"{name} must be a finite number, got {short_repr(value)}") from None
    if not math.isfinite(v):
        raise InputError(f"{name} must be a finite number, got {v}")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise InputError(f"{name} must be {'>' if lo_open else '>='} {lo:g}, got {_beside(v, lo)}")
    if hi is not None and (v >= hi if hi_open else v > hi):
        raise InputError(f"{name} must be {'<' if hi_open else '<='} {hi:g}, got {_beside(v, hi)}")
    return v


def _beside(v: float, limit: float) -> str:
    """``v`` as short as it reads apart from ``limit`` (``1.0000001`` beside 1, not ``1``)."""
    return f"{v:g}" if v == limit or f"{v:g}" != f"{limit:g}" else repr(v)


def check_choice(value, name: str, choices) -> str:
    """``value`` when it is one of the strings ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{name} must be one of {', '.join(choices)}, got {short_repr(value)}")
    return value


def check_count(value, name: str) -> int | None:
    """None (no cap) or an integer >= 1: a number of points to keep."""
    return None if value is None else check_int(value, name, lo=1)


def check_counts(value, name: str) -> int | tuple[int | None, ...] | None:
    """A point cap (:func:`check_count`) or a non-empty tuple/list of them, one per pyramid level."""
    if isinstance(value, (tuple, list)):
        if not value:
            raise InputError(f"{name} must name at least one level")
        return tuple(check_count(v, name) for v in value)
    return check_count(value, name)


def check_floats(value, name: str, *, lo: float | None = None, lo_open: bool = False) -> tuple[float, ...] | None:
    """None, or a sequence (tuple, list or 1-D array) of finite numbers in the range, as a tuple."""
    if value is None:
        return None
    if isinstance(value, (str, bytes, dict, set)) or not hasattr(value, "__len__") or np.ndim(value) != 1:
        raise InputError(f"{name} must be a sequence of numbers, got {short_repr(value)}")
    return tuple(check_float(v, name, lo=lo, lo_open=lo_open) for v in value)


def check_ints(value, name: str, *, lo: int | None = None, hi: int | None = None) -> tuple[int, ...] | None:
    """None, or a sequence (tuple, list or 1-D array) of integers in [lo, hi], as a tuple."""
    if value is None:
        return None
    if isinstance(value, (str, bytes, dict, set)) or not hasattr(value, "__len__") or np.ndim(value) != 1:
        raise InputError(f"{name} must be a sequence of integers, got {short_repr(value)}")
    return tuple(check_int(v, name, lo=lo, hi=hi) for v in value)


def check_bool(value, name: str) -> bool:
    """``value`` when it is True or False (a Python or numpy bool)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name} must be True or False, got {short_repr(value)}")
    return bool(value)


def check_path(value, name: str) -> Path:
    """``value`` (a str or path-like object) as a :class:`~pathlib.Path`."""
    if not isinstance(value, (str, os.PathLike)):
        raise InputError(f"{name} must be a path (str or os.PathLike), got {type(value).__name__}")
    return Path(value)


def check_callable(value, name: str):
    """``value`` when it is None or callable."""
    if value is not None and not callable(value):
        raise InputError(f"{name} must be callable or None, got {type(value).__name__}")
    return value


def check_frame(value, name: str, *, labelled: bool = False):
    """``value`` when it has a frame's ``image`` and ``labels`` (a :class:`pcreg.Frame`), labelled if asked."""
    if not (hasattr(value, "image") and hasattr(value, "labels")):
        raise InputError(f"{name} must be a Frame (image and labels), got {type(value).__name__}")
    if labelled and value.labels is None:
        raise InputError(f"{name} has no labels")
    return value


def check_frames(value, name: str = "frames", *, labelled: bool = False):
    """``value`` when it is a list or tuple of frames (:func:`check_frame`)."""
    if not isinstance(value, (list, tuple)):
        raise InputError(f"{name} must be a list of Frame, got {type(value).__name__}")
    for i, f in enumerate(value):
        check_frame(f, f"{name}[{i}]", labelled=labelled)
    return value


#: The most items a summary line names before it counts the rest.
MOST_NAMED = 12


def listed(items: list[str]) -> str:
    """``a, b and c``; beyond :data:`MOST_NAMED` items the first of them and how many more (a table of 150
    classes is not printed on one line)."""
    if not items:
        return "none"
    if len(items) > MOST_NAMED:
        return f"{', '.join(items[:MOST_NAMED])} and {len(items) - MOST_NAMED} more"
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


def short_repr(value) -> str:
    """A one-line repr of an argument for an error message (arrays by shape)."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def check_unmasked(value, name: str) -> None:
    """An :class:`InputError` for a numpy masked array with masked values: numpy hands pcreg the values stored
    under its mask, which pcreg would read as data."""
    if isinstance(value, np.ma.MaskedArray) and np.ma.is_masked(value):
        raise InputError(f"{name}: a masked array with {int(np.ma.count_masked(value))} masked value(s), whose "
                         "stored values would be read as data; give np.ma.filled(...) or the unmasked part")


def plain_array(value, name: str) -> np.ndarray:
    """``value`` as a plain ndarray in the machine's byte order (itself when it already is one): a subclass
    (``np.matrix``, a masked array with nothing masked: :func:`check_unmasked`) as its data, a big-endian
    array (``>u2``, as FITS files and some TIFF readers give) converted."""
    check_unmasked(value, name)
    arr = np.asarray(value)
    return arr if arr.dtype.isnative else arr.astype(arr.dtype.newbyteorder("="))


def real_matrix(value, refusal: str, name: str) -> np.ndarray:
    """``value`` as a float64 array (a copy), or an :class:`InputError` saying ``refusal`` where it holds no real
    numbers (text numpy cannot read, a Python int beyond float64's range), and naming ``name`` where it is complex
    (numpy would drop the imaginary parts with a warning) or a masked array with masked entries
    (:func:`check_unmasked`)."""
    check_unmasked(value, name)
    if np.iscomplexobj(value):
        raise InputError(f"{name}: complex numbers; give its real matrix")
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):  # OverflowError: a Python int beyond float64
        raise InputError(refusal) from None


def check_matrix(value, name: str, dim: int) -> np.ndarray:
    """A finite, invertible, well-conditioned (dim x dim) float64 copy of ``value`` (a homogeneous
    transform such as an initial guess). An affine transform's conditioning is its linear block's: the whole
    matrix's grows as its translation squared (a shift of 10^6, a georeferenced cloud's, read as singular)."""
    M = real_matrix(value, f"{name} must be a {dim}x{dim} matrix of numbers", name)
    if M.shape != (dim, dim):
        last, hint = " ".join(["0"] * (dim - 1) + ["1"]), ""
        if M.shape == (dim - 1, dim):  # a pose written without its last row
            hint = f": a {dim - 1}x{dim} pose without its last row (add the row {last})"
        elif M.shape == (1, dim * (dim - 1)):  # the same on one line
            hint = (f": one line of {dim * (dim - 1)} numbers, as KITTI writes a pose? Write its {dim - 1} rows of "
                    f"{dim}, then the row {last}")
        raise InputError(f"{name} must be a finite {dim}x{dim} matrix, got shape {M.shape}{hint}")
    if not np.all(np.isfinite(M)):
        raise InputError(f"{name} must be a finite {dim}x{dim} matrix, got NaN or inf entries")
    if np.max(np.abs(M)) > 1e12:
        raise InputError(f"{name} has entries up to {np.max(np.abs(M)):.3g} (|m| <= 1e12)")
    affine = dim > 1 and np.array_equal(M[-1], np.eye(dim)[-1])
    try:
        cond = np.linalg.cond(M[:-1, :-1] if affine else M)
    except np.linalg.LinAlgError:
        cond = np.inf
    if not np.isfinite(cond) or cond > 1e12:
        raise InputError(f"{name} is singular or nearly so (condition number {cond:.3g})")
    return M


def check_units(n: int, what: str = "units") -> int:
    """Refuse a plan of more than :data:`MAX_UNITS` evaluation units (``--angles 0:360:1e-9``)."""
    if n > MAX_UNITS:
        raise InputError(f"{n} {what} requested; the limit is {MAX_UNITS} (use a coarser step or fewer values)")
    return n


# --------------------------------------------------------------------------------------------------
# limits
# --------------------------------------------------------------------------------------------------

def max_pixels(value: int | None = None) -> int:
    """The pixel (and point) limit in force: ``value``, else ``$PCREG_MAX_PIXELS``, else the default."""
    if value is not None:
        return check_int(value, "max_pixels", lo=1)
    env = os.environ.get(_ENV)
    if env:
        try:
            v = int(env)
        except ValueError:
            raise InputError(f"{_ENV} must be a positive integer, got {env!r}") from None
        if v >= 1:
            return v
        raise InputError(f"{_ENV} must be a positive integer, got {env!r}")
    return DEFAULT_MAX_PIXELS


def check_pixels(shape: tuple, name: str, *, limit: int | None = None) -> None:
    """An :class:`InputError` for an image array of ``shape`` (H, W, ...) with more pixels than the limit
    (:func:`max_pixels` of ``limit``), in the words of a file's refusal (:func:`pcreg.formats.check_image_bytes`)."""
    lim = max_pixels(limit)
    h, w = int(shape[0]), int(shape[1])
    if h * w > lim:
        raise InputError(f"{name}: {w}x{h} px exceeds the limit of {lim} pixels (raise it with {_ENV} or --max-pixels)")


def check_point_count(n: int, name: str, *, limit: int | None = None) -> None:
    """An :class:`InputError` for a cloud array of ``n`` points, more than the limit (:func:`max_pixels` of
    ``limit``), in the words of a file's refusal (:func:`pcreg.cloud_reader.load_cloud`)."""
    lim = max_pixels(limit)
    if n > lim:
        raise InputError(f"{name}: {n} points exceed the limit of {lim} points (raise it with {_ENV} or --max-pixels)")


def set_max_pixels(value: int) -> None:
    """Set the limit for this process and the worker processes it starts (through ``PCREG_MAX_PIXELS``)."""
    os.environ[_ENV] = str(check_int(value, "max_pixels", lo=1))
