"""A frame checked once where it enters the library: :func:`as_rgb_uint8` and :class:`PreparedFrame`.

Every function that takes an image checks it with :func:`as_rgb_uint8`. A stream's frame goes through
several of them (naive Bayes, the dense registration, DIS flow, the trust map): :meth:`PreparedFrame.of`
checks it once, and each of them takes the prepared frame as it is, with no copy and no second check.
What is derived from a frame (naive Bayes' features) is made on first use and kept with it
(:meth:`PreparedFrame.derived`), so it is not computed twice for one frame.
"""

from __future__ import annotations

from typing import Callable, Hashable, TypeVar

import numpy as np

from .errors import InputError
from .validation import check_pixels, plain_array

__all__ = ["PreparedFrame", "as_rgb_uint8", "low_bits_note"]

T = TypeVar("T")


class PreparedFrame:
    """An (H, W, 3) uint8 RGB frame, checked once (:meth:`of`), read-only, and what is derived from it.

    rgb : the frame, C-contiguous and read-only (a view of the caller's array where it already was one:
        the caller keeps it unchanged while the frame is in use; :meth:`copy` for a frame kept longer).
    shape : (H, W).
    """

    __slots__ = ("rgb", "_derived")

    def __init__(self, rgb: np.ndarray) -> None:
        """Use :meth:`of`, which checks: ``rgb`` must already be C-contiguous (H, W, 3) uint8."""
        view = rgb.view()
        view.setflags(write=False)
        self.rgb = view
        self._derived: dict = {}

    @classmethod
    def of(cls, image, *, name: str = "frame", shape: tuple[int, int] | None = None) -> "PreparedFrame":
        """``image`` checked and converted once (:func:`as_rgb_uint8`; a prepared frame is itself);
        ``shape``: the (H, W) it must have (a stream's), :class:`~pcreg.errors.InputError` otherwise."""
        frame = image if isinstance(image, PreparedFrame) else cls(as_rgb_uint8(image, name=name))
        if shape is not None and frame.shape != tuple(shape):
            raise InputError(f"{name} of shape {frame.rgb.shape} in a stream of {(*shape, 3)} frames")
        return frame

    @property
    def shape(self) -> tuple[int, int]:
        return self.rgb.shape[:2]

    def check_key(self, labels: np.ndarray, unknown: int, name: str = "the key frame") -> "PreparedFrame":
        """Itself, or an :class:`~pcreg.errors.InputError` naming it ``name`` when every pixel is one colour (a black
        frame before a video starts, a blank capture) and its ``labels`` hold two classes or more besides ``unknown``:
        a key frame so holds nothing to tell them apart by, or to follow. Labelled one class (a fade to black, all
        background) it says what it holds."""
        first = self.rgb[0, 0]
        known = np.unique(labels)
        if (known != unknown).sum() >= 2 and (self.rgb == first).all():
            raise InputError(f"{name} is one colour everywhere {tuple(int(v) for v in first)}: as a key frame it "
                             "holds nothing to tell its classes apart by, or to follow; choose one that shows the scene")
        return self

    def copy(self) -> "PreparedFrame":
        """The frame over a copy of its own: for a frame kept beyond the call that prepared it (a stream's
        key frame), whose caller may write the next frame into the same array (a camera's or a decoder's
        buffer). What was derived is not carried over: it may hold views of that array (the ``rgb``
        feature is the image itself)."""
        return PreparedFrame(self.rgb.copy())

    def derived(self, key: Hashable, make: Callable[[np.ndarray], T]) -> T:
        """``make(rgb)``, made on the first call with this ``key`` and kept with the frame (a key names
        what is made, with every option it depends on)."""
        try:
            return self._derived[key]
        except KeyError:
            value = self._derived[key] = make(self.rgb)
            return value

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """The frame as numpy sees it (``np.asarray(frame)``): its read-only ``rgb``, or a copy when asked
        for one or for another dtype."""
        if copy is False and dtype is not None and np.dtype(dtype) != self.rgb.dtype:
            raise ValueError("a PreparedFrame is uint8: another dtype needs a copy")
        if copy or (dtype is not None and np.dtype(dtype) != self.rgb.dtype):
            return np.array(self.rgb, dtype=dtype, copy=True)
        return self.rgb

    def __repr__(self) -> str:
        h, w = self.shape
        return f"PreparedFrame({w}x{h})"


#: The smallest image side, in pixels, there is anything to register on.
MIN_SIDE = 8
#: What the refusal of a float image with values outside [0, 1] adds: for an array, and for an image file,
#: which a command-line user cannot divide.
FLOAT_ARRAY_HINT = "divide an array of 8-bit values by 255"
FLOAT_FILE_HINT = ("save it as an 8- or 16-bit unsigned integer image (a PNG, or a TIFF of integers), which pcreg "
                   "reads as it is, or with floats scaled to [0, 1]")


def as_rgb_uint8(image, *, name: str = "image", limit: int | None = None,
                 float_hint: str = FLOAT_ARRAY_HINT, min_side: int = MIN_SIDE) -> np.ndarray:
    """Validate and convert an image array to (H, W, 3) uint8 RGB (no copy when it already is a
    C-contiguous one; the input is never changed); a :class:`PreparedFrame` gives its checked, read-only
    ``rgb`` as it is.

    Accepts (H, W) grayscale, (H, W, 1|3|4), uint8, uint16 (scaled by 1/257) and float in [0, 1] (rounded to
    the nearest of 256 levels: values within half a level outside, rounding errors, are 0 or 255), in either
    byte order; an ndarray subclass (``np.matrix``, a masked array with nothing masked) as its data; no more
    pixels than the pixel limit (:func:`pcreg.validation.check_pixels` of ``limit``), as a file. ``float_hint``:
    what the refusal of a float image outside [0, 1] says to do (:data:`FLOAT_FILE_HINT` for a file's). ``min_side``:
    the smallest side accepted (:data:`MIN_SIDE`, an image to register; a data set's frame may be smaller).
    """
    if isinstance(image, PreparedFrame):
        return image.rgb
    if not isinstance(image, np.ndarray):
        raise InputError(f"{name}: expected a numpy array, got {type(image).__name__}")
    img = plain_array(image, name)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise InputError(f"{name}: expected an (H, W) or (H, W, 3) image, got shape {image.shape}")
    img = img[:, :, :3]
    if img.shape[0] == 0 or img.shape[1] == 0:
        raise InputError(f"{name}: empty image (shape {image.shape})")
    if img.shape[0] < min_side or img.shape[1] < min_side:
        raise InputError(f"{name}: image too small to register ({img.shape[1]}x{img.shape[0]} px)")
    check_pixels(img.shape, name, limit=limit)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    if img.dtype == np.uint16:
        return np.ascontiguousarray((img.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    if np.issubdtype(img.dtype, np.floating):
        if not np.all(np.isfinite(img)):
            raise InputError(f"{name}: image has NaN or inf values")
        lo, hi = float(img.min()), float(img.max())
        if lo < -0.5 / 255 or hi > 1.0 + 0.5 / 255:  # within half a level: rounds to 0 or 255
            raise InputError(f"{name}: a float image must hold values in [0, 1], got {lo:g}..{hi:g}; {float_hint}")
        return np.ascontiguousarray(np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8))
    if img.dtype == np.bool_:
        return np.ascontiguousarray(img.astype(np.uint8) * 255)
    raise InputError(f"{name}: unsupported image dtype {img.dtype} (pcreg reads 8- and 16-bit unsigned integers, "
                     "true/false, and floats in [0, 1]; convert a signed or 32-bit image first)")


def low_bits_note(image) -> str:
    """Why an image may read as nearly black, for a refusal of it: a 16-bit image whose values use only the
    lowest bits (at most 12 of its 16: 8-bit values stored in 16 bits, a 10- or 12-bit camera's), which
    :func:`as_rgb_uint8`'s scaling by 1/257 (documented, kept) makes 0..16 of 255 or darker:
    ``"its 16-bit values lie in 3..255, only the lowest 8 of its 16 bits, ..."``; else ``""``."""
    if not isinstance(image, np.ndarray) or image.dtype.kind != "u" or image.dtype.itemsize != 2 or image.size == 0:
        return ""
    lo, hi = int(image.min()), int(image.max())
    bits = max(1, hi.bit_length())
    if bits > 12:
        return ""
    return (f"its 16-bit values lie in {lo}..{hi}, only the lowest {bits} of its 16 bits, which read as "
            f"{(lo * 255 + 32767) // 65535}..{(hi * 255 + 32767) // 65535} of 255 (nearly black); stretch them over "
            "the 16 bits or store the image as 8-bit")
