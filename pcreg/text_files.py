"""Small text files: a text matrix (an initial guess, a ground truth), and text saved in an encoding no reader of
numbers or names here reads, UTF-16 or UTF-32 (Notepad's "Unicode", PowerShell's default), named as such rather
than quoted as bytes."""

from __future__ import annotations

import os

import numpy as np

from .errors import InputError

__all__ = ["read_text_matrix", "refuse_utf16", "text_matrix"]


def refuse_utf16(path: str | os.PathLike, data: bytes) -> None:
    """An :class:`InputError` naming ``path`` when ``data``, a text file's first bytes, is UTF-16 or UTF-32, which no
    reader of numbers or names reads: a byte-order mark (FF FE, FE FF; FF FE 00 00, 00 00 FE FF), or zero bytes at
    every other place of its first 64 bytes (at least 4) and not between (three of every four: UTF-32). Bytes all zero (what a
    crash can leave) are no text of any kind: left to the reader's own message."""
    head = data[:64]
    if data.startswith((b"\xff\xfe\0\0", b"\0\0\xfe\xff")):
        kind = "UTF-32"
    elif data.startswith((b"\xff\xfe", b"\xfe\xff")):
        kind = "UTF-16"
    elif len(head) < 4 or not head.strip(b"\0"):
        return
    elif sum(not head[i::4].strip(b"\0") for i in range(4)) == 3:
        kind = "UTF-32"
    elif sum(not head[i::2].strip(b"\0") for i in range(2)) == 1:
        kind = "UTF-16"
    else:
        return
    raise InputError(f"{path}: it is {kind} text (as some Windows programs save it); save it as UTF-8 or ASCII")


def text_matrix(data: bytes) -> np.ndarray:
    """The 2-D float64 matrix a small text holds, its numbers separated by whitespace, or by commas as a CSV
    file and ``numpy.savetxt(..., delimiter=",")`` write them (spaces beside the commas allowed); '#' starts a
    comment, whose commas say nothing of the numbers'. A ValueError (numpy's) when it holds another text."""
    import io

    commas = any(b"," in line.partition(b"#")[0] for line in data.splitlines())
    return np.loadtxt(io.BytesIO(data), dtype=np.float64, ndmin=2, delimiter="," if commas else None)


def read_text_matrix(path: str | os.PathLike, *, what: str = "matrix") -> np.ndarray:
    """A small text matrix (an initial guess, a ground truth) from a regular file of at most 64 kB, as a finite
    2-D float64 array (:func:`text_matrix`: spaces or commas between the numbers)."""
    from .formats import read_regular_file

    data = read_regular_file(path, max_bytes=1 << 16, what=what).removeprefix(b"\xef\xbb\xbf")  # Notepad's mark
    if not data.strip():  # numpy would warn of it and give an empty array
        raise InputError(f"{path}: the {what} file is empty")
    refuse_utf16(path, data)
    try:
        m = text_matrix(data)
    except (ValueError, IndexError, TypeError) as exc:
        raise InputError(f"{path}: not a text matrix ({' '.join(str(exc).split())[:160]})") from None
    if m.size == 0 or not np.all(np.isfinite(m)):
        raise InputError(f"{path}: the {what} must hold finite numbers")
    return m
