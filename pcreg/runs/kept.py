"""What a stretch's forward pass keeps for its backward pass under ``OUT/.keys/STRETCH/``
(:data:`~pcreg.runs.files.HIDDEN`), each written and read by one pair of functions here:

- each frame's prior term, ``prior-N.kept``: :func:`write_prior`, :func:`read_prior`;
- a video's decoded frames, ``frame-N.kept``: :func:`write_frame`, :func:`read_frame`.

Both are lossless, and compressed only when the run's disk needs it (``compress``; the run decides when it
opens, :func:`pcreg.runs.disk.compress_kept`): compressing costs time (at 640x480 with ``camvid11`` zlib takes
100-160 ms a frame, against a step of 150-330 ms), so a run whose stretches fit twice over in the free space
keeps the arrays' bytes as they are. Compressed (:func:`pack`), each value's bits are replaced by their difference from the pixel's
before it in its row (PNG's "Sub" filter), a prior term's (float16) bytes shuffled, as blosc does (every
value's low byte, then every high byte: the high bytes of neighbouring pixels are much alike), and the whole
compressed with zlib at level 1. Both kinds are the same format, each member's header saying what was done to
it, so reading needs no choice. A run of an earlier version kept them uncompressed (``prior-N.npz``,
``frame-N.npy``): they are read as well, so that such a run resumes.

Sizes and times at 640x480 and 1920x1080 are in docs/benchmarks.md ("What a stretch keeps on disk").
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import OutputError
from .files import UNREADABLE_CARRY

__all__ = ["PRIOR", "FRAME", "write_prior", "read_prior", "write_frame", "read_frame", "pack", "unpack"]

PRIOR = "prior-{}.kept"
FRAME = "frame-{}.kept"
#: What an earlier version kept, uncompressed (read, never written).
OLD_PRIOR, OLD_FRAME = "prior-{}.npz", "frame-{}.npy"
#: The first bytes of a ``.kept`` file, then the length of its JSON header (4 bytes, little-endian).
MAGIC = b"PCREGKEPT1\n"
#: zlib's level: 1, the fastest; higher levels gain a few per cent for several times the time.
LEVEL = 1
#: What reading a damaged kept file raises.
_UNREADABLE: tuple[type[BaseException], ...] = (OSError, ValueError, KeyError, TypeError, struct.error, zlib.error, *UNREADABLE_CARRY)


def _bits(a: np.ndarray) -> np.ndarray:
    """``a``'s bytes as unsigned integers of its item size (a view)."""
    return a.view(np.dtype(f"u{a.dtype.itemsize}"))


def pack(arrays: dict[str, np.ndarray], *, compress: bool = True, delta: bool = True) -> bytes:
    """``arrays`` (numeric, any shape) as bytes: a header naming each one's dtype and shape and what was done to
    it, then each one's bytes. Not ``compress``: the bytes as they are (C order). ``compress``: compressed with
    zlib at :data:`LEVEL`; before that, an array of two dimensions or more has each value's bits (as an unsigned
    integer) replaced by their difference, modulo 2**bits, from the value of the pixel before it in its row, the
    same channel (``delta``; PNG's "Sub" filter), and its bytes shuffled (the first byte of every value, then
    the second, ...)."""
    header, blobs = [], []
    for name, a in arrays.items():
        a = np.asarray(a, order="C")  # (np.ascontiguousarray makes a 0-d array 1-d)
        diff = compress and delta and a.ndim >= 2 and a.shape[1] > 1 and a.dtype.kind in "iuf"
        if diff:
            bits = _bits(a)
            a = bits.copy()
            a[:, 1:] -= bits[:, :-1]
        size = a.dtype.itemsize
        shuffle = compress and size > 1 and a.size > 0
        raw = a.reshape(-1).view(np.uint8).reshape(-1, size).T.tobytes() if shuffle else a.tobytes()
        blob = zlib.compress(raw, LEVEL) if compress else raw
        header.append({"name": name, "dtype": np.asarray(arrays[name]).dtype.str, "shape": list(a.shape),
                       "delta": diff, "shuffle": shuffle, "zlib": compress, "bytes": len(blob)})
        blobs.append(blob)
    head = json.dumps(header).encode()
    return b"".join([MAGIC, struct.pack("<I", len(head)), head, *blobs])


def unpack(data: bytes) -> dict[str, np.ndarray]:
    """The arrays :func:`pack` wrote, compressed or not. Bytes of anything else, or damaged, raise ValueError or
    zlib.error."""
    if not data.startswith(MAGIC):
        raise ValueError("not a kept file")
    at = len(MAGIC) + 4
    (n,) = struct.unpack_from("<I", data, len(MAGIC))
    header = json.loads(data[at:at + n])
    at += n
    out = {}
    for m in header:
        dtype, shape = np.dtype(m["dtype"]), tuple(int(s) for s in m["shape"])
        if dtype.kind not in "biuf":
            raise ValueError("not a numeric array")
        blob = data[at:at + m["bytes"]]
        raw = zlib.decompress(blob) if m.get("zlib", True) else blob
        at += m["bytes"]
        count = int(np.prod(shape, dtype=np.int64))
        if len(raw) != count * dtype.itemsize:
            raise ValueError("a member of the wrong size")
        a = np.frombuffer(raw, np.uint8)
        if m.get("shuffle", dtype.itemsize > 1 and count > 0):
            a = a.reshape(dtype.itemsize, count).T.copy()
        elif dtype.itemsize > 1:
            a = a.copy()  # writable, as a shuffled member's is
        a = a.view(dtype).reshape(shape)
        if m["delta"]:
            bits = _bits(a)
            a = np.cumsum(bits, axis=1, dtype=bits.dtype).view(dtype)  # the sums wrap as the differences did
        out[m["name"]] = a
    if at != len(data):
        raise ValueError("bytes after the last member")
    return out


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Reading what a pass kept at ``path``: missing or damaged, one line saying how to start over."""
    try:
        yield
    except _UNREADABLE:
        raise OutputError(f"{path}: missing or unreadable; use --force to start over") from None


def write_prior(folder: Path, t: int, prior: np.ndarray, fallback: bool, weight: np.ndarray | None = None, *,
                compress: bool = True, cut: bool = False) -> None:
    """Frame ``t``'s prior term (float16; with many classes also its summed trust weight, float16), whether
    its step fell back and whether its cut test found it outside the key frame's scene, atomically in ``folder``,
    compressed or not (:func:`pack`)."""
    from ..outputs import atomic_write_bytes

    kept = {"prior": prior, "fallback": np.asarray(fallback), "cut": np.asarray(cut)}
    if weight is not None:
        kept["weight"] = weight
    atomic_write_bytes(folder / PRIOR.format(t), pack(kept, compress=compress))


def read_prior(folder: Path, t: int) -> tuple[np.ndarray, bool, np.ndarray | None, bool]:
    """``(prior, fallback, weight, cut)`` :func:`write_prior` kept for frame ``t`` (or an earlier version's
    ``prior-N.npz``); ``weight`` None with two classes, ``cut`` False where an earlier version kept none."""
    path, old = folder / PRIOR.format(t), folder / OLD_PRIOR.format(t)
    if not path.is_file() and old.is_file():
        with _reading(old), np.load(old, allow_pickle=False) as z:
            return z["prior"], bool(z["fallback"]), z["weight"] if "weight" in z.files else None, False
    with _reading(path):
        z = unpack(path.read_bytes())
        return z["prior"], bool(z["fallback"]), z.get("weight"), bool(z.get("cut", False))


def write_frame(folder: Path, t: int, image: np.ndarray, *, compress: bool = True) -> None:
    """A video's decoded frame ``t`` ((H, W, 3) uint8), atomically in ``folder``, compressed or not
    (:func:`pack`)."""
    from ..outputs import atomic_write_bytes

    atomic_write_bytes(folder / FRAME.format(t), pack({"image": image}, compress=compress))


def read_frame(folder: Path, t: int) -> np.ndarray:
    """The frame :func:`write_frame` kept for ``t`` (or an earlier version's ``frame-N.npy``)."""
    path, old = folder / FRAME.format(t), folder / OLD_FRAME.format(t)
    if not path.is_file() and old.is_file():
        with _reading(old), open(old, "rb") as f:
            return np.load(io.BytesIO(f.read()), allow_pickle=False)
    with _reading(path):
        return unpack(path.read_bytes())["image"]
