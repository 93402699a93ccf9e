"""Reading a point cloud from a file, by suffix: PLY, binary PCD and Open3D's text formats (.xyz, .xyzn, .xyzrgb,
.pts) through Open3D once :mod:`pcreg.cloud_files` has checked them, ASCII PCD from its checked lines, .npy
through numpy, and a text file of columns
(.txt, .csv: what ``numpy.savetxt``, pycpd's, probreg's and libpointmatcher's data and most exports hold)
through :func:`read_columns`. Whatever a reader would fill with zeros or skip is refused in one line naming the
file (:class:`~pcreg.errors.InputError`)."""

from __future__ import annotations

import itertools
import os
import re
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from .cloud_files import _ASCII_NUMBER, PcdHeader, _scan_rows, check_cloud_file, check_npy_file, pcd_header
from .errors import InputError
from .registration.api import check_cloud
from .validation import check_point_count, max_pixels

__all__ = ["CLOUD_SUFFIXES", "TEXT_COLUMN_SUFFIXES", "load_cloud", "read_columns"]

#: The suffixes read as columns of numbers by :func:`read_columns`.
TEXT_COLUMN_SUFFIXES = (".txt", ".csv")
#: Every suffix :func:`load_cloud` reads (any case).
CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts", ".npy") + TEXT_COLUMN_SUFFIXES


def load_cloud(path: str | os.PathLike, *, max_points: int | None = None) -> np.ndarray:
    """Points (N, 3), or (N, 2) from a .npy or a text file of two columns, read by suffix (:data:`CLOUD_SUFFIXES`).

    Regular files only; the point count a PLY/PCD/NPY header declares must be within ``max_points``
    (default :func:`pcreg.validation.max_pixels`) and present in the file: a truncated file is refused
    (Open3D would pad it with zeros). A PCD's points whose coordinates are all NaN are left out: PCL marks so
    the pixels of an organised cloud (a depth camera's, HEIGHT > 1) that measured nothing. Open3D's messages go
    to stderr, never stdout.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InputError(f"{path}: unknown point-cloud format {suffix!r} (use {', '.join(CLOUD_SUFFIXES)})")
    limit = max_pixels(max_points)
    check_cloud_file(path, limit=limit)
    if suffix == ".npy":
        shape, _ = check_npy_file(path, limit)
        if len(shape) != 2 or shape[1] not in (2, 3):
            raise InputError(f"{path}: expected an (N, 2) or (N, 3) array of points, got shape {shape}")
        try:
            pts = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise InputError(f"{path}: not a numpy array file ({str(exc)[:120]})") from None
    elif suffix in TEXT_COLUMN_SUFFIXES:
        pts = read_columns(path, limit)
    else:
        header = pcd_header(path) if suffix == ".pcd" else None
        pts = _read_pcd_ascii(path, header) if header is not None and header.data == "ascii" else \
            _read_open3d(path, suffix, limit)
        if suffix == ".pcd":
            unmeasured = np.isnan(pts).all(axis=1)
            if unmeasured.all():
                raise InputError(f"{path}: every point's coordinates are NaN (no point was measured)")
            pts = pts[~unmeasured]
    return check_cloud(pts, str(path), limit=limit)


def _read_open3d(path: Path, suffix: str, limit: int) -> np.ndarray:
    import open3d as o3d

    from .quiet import capture_output_fds

    text = suffix in (".xyz", ".xyzn", ".xyzrgb", ".pts")
    expected = _check_text_cloud(path, suffix, limit) if text else 0  # before Open3D reserves a .pts's count

    with capture_output_fds() as said:  # Open3D prints its warnings on stdout (fd 1)
        try:
            pcd = o3d.io.read_point_cloud(str(path), format="auto", remove_nan_points=False,
                                          remove_infinite_points=False)
        except (RuntimeError, ValueError, MemoryError) as exc:
            raise InputError(f"{path}: cannot read point cloud ({str(exc)[:120]})") from None
    warning = _open3d_warning(said[0] if said else "")
    if warning:  # Open3D fills what it could not read with zeros and only prints a warning
        raise InputError(f"{path}: cannot read point cloud (Open3D: {warning})")
    pts = np.asarray(pcd.points)
    if pts.size == 0:
        raise InputError(f"{path}: no points could be read (empty or not a {suffix} point cloud)")
    check_point_count(len(pts), str(path), limit=limit)
    if text and len(pts) != expected:
        raise InputError(f"{path}: {expected - len(pts)} of {expected} lines are not points (damaged {suffix} file)")
    return pts


def _read_pcd_ascii(path: Path, header: PcdHeader) -> np.ndarray:
    """The x, y, z of an ASCII PCD (its lines checked against its header by :mod:`pcreg.cloud_files`), read here:
    Open3D's reader takes a line in pieces of 1,023 bytes (a point with a histogram of 125 numbers is read as
    several, or none) and leaves the points it did not fill as its memory held them, and reads an integer field
    (TYPE I or U) with C's ``strtol`` of base 0 (``010`` is 8, ``1.5`` is 1). An integer field that holds a
    number with a fraction is refused."""
    columns = [c for c in (header.column(axis) for axis in "xyz") if c is not None]
    if len(columns) < 3:
        raise InputError(f"{path}: PCD fields {' '.join(header.fields)} lack x, y or z")
    try:
        pts = _pcd_columns(path, header, columns, None)
    except ValueError:  # nan(ind) and its kind, as C's printf writes a NaN on some systems
        pts = _pcd_columns(path, header, columns, lambda word: float(word.split("(")[0]))
    for k, axis in enumerate("xyz"):
        kind = header.types[header.fields.index(axis)]
        values = pts[:, k]
        whole = np.isnan(values) | (values == np.round(values))
        if kind != "F" and not whole.all():
            row = int(np.flatnonzero(~whole)[0])
            raise InputError(f"{path}: its field {axis} holds whole numbers (TYPE {kind}), point {row + 1} has "
                             f"{axis} = {float(values[row])!r}")
    return pts


def _pcd_columns(path: Path, header: PcdHeader, columns: list[int],
                 converter: Callable[[str], float] | None) -> np.ndarray:
    """The ``columns`` of an ASCII PCD's data lines, split at newlines only (as its check and Open3D do: a CR is
    white space between numbers)."""
    with open(path, "rb") as fh, warnings.catch_warnings():  # blank lines are not counted in max_rows: no warning
        warnings.simplefilter("ignore", UserWarning)
        fh.seek(header.start)
        lines = (line.decode("latin-1").replace("\r", " ") for line in fh)
        return np.loadtxt(lines, dtype=np.float64, comments=None, usecols=columns, ndmin=2, max_rows=header.points,
                          converters=converter)


def _check_text_cloud(path: Path, suffix: str, limit: int) -> int:
    """How many points a text cloud holds, checked before Open3D reads it: Open3D reads a line with C's
    ``sscanf``, skipping a line it cannot parse and reading what a line starts with (``3,5`` as 3, ``3abc`` as
    3, ``0x10`` as 16), and reserves the points a .pts file's first line declares (a count of 20 million in a
    file of three lines took 800 MB). Every non-empty line is a point of as many plain numbers as the first
    (``.pts``: after a first line with the point count, which must be theirs); else an :class:`InputError`."""
    with open(path, "rb") as fh:  # streamed: the file may be large
        firsts = list(itertools.islice((line.strip() for line in fh if line.strip()), 2))
    header = 1 if suffix == ".pts" and firsts and firsts[0].isdigit() else 0
    if suffix == ".pts" and firsts and not header:  # Open3D read its number as the count: one point, or none
        raise InputError(f"{path}: its first line ({firsts[0][:40].decode('ascii', 'replace')!r}) is not the point "
                         "count a .pts file starts with")
    width = len(firsts[header].split()) if len(firsts) > header else 1
    count, bad = _scan_rows(path, 0, stop=1 << 62, rows=(header, 1 << 62), fields=width)
    expected = count - header
    if header and int(firsts[0]) != expected:
        raise InputError(f"{path}: the first line declares {int(firsts[0])} points, the file holds {expected} lines")
    if bad is not None:
        number, line = bad
        text = line.decode("ascii", "replace").strip()[:40]
        if number == 1:
            raise InputError(f"{path}: its first point line ({text!r}) is not numbers between white space "
                             f"(damaged {suffix} file)")
        raise InputError(f"{path}: point line {number} ({text!r}) is not {width} numbers, as the first is "
                         f"(damaged {suffix} file)")
    check_point_count(expected, str(path), limit=limit)
    return expected


def _open3d_warning(text: str) -> str:
    """The first warning or error line Open3D printed (ANSI colours removed), or ''."""
    for line in re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines():
        if "[Open3D WARNING]" in line or "[Open3D ERROR]" in line or "RPly: " in line:
            return line.split("]", 1)[1].strip()[:200] if "[Open3D" in line else line.strip()[:200]
    return ""


_NUMBER = re.compile(_ASCII_NUMBER)
#: What a spreadsheet's "CSV UTF-8" export starts with (Excel's): no part of the first line's names or numbers.
UTF8_BOM = b"\xef\xbb\xbf"


def read_columns(path: str | os.PathLike, limit: int | None = None) -> np.ndarray:
    """The points of a text file of columns: one point a line, its fields separated by commas, by semicolons
    or by spaces and tabs (which of them, the first line says); blank lines and lines starting with ``#``
    skipped. Two or three numbers a line are x, y (and z); a first line of names (``x,y,z,nx,ny,nz`` as
    libpointmatcher writes, ``//X,Y,Z,R,G,B`` as CloudCompare does) says which columns are x, y and z, in any
    number of columns. Every line must hold as many numbers as the first: a line that does not is an
    :class:`InputError` naming it (a reader that skipped it would register a cloud the file does not hold)."""
    path = Path(path)
    lim = max_pixels(limit)
    first, line_number = _first_line(path)
    if first is None:
        raise InputError(f"{path}: no points could be read (no line of numbers)")
    separator = next((s for s in (b",", b";") if s in first), None)
    fields = _split(first, separator)
    columns = _columns(path, fields)
    try:  # numpy's parser: strict (no "1_0", no "1,0" between spaces), and many times faster than a loop here
        with warnings.catch_warnings():  # blank lines not counted in max_rows, no data: said here, not on stderr
            warnings.simplefilter("ignore", UserWarning)
            with open(path, "rb") as fh:
                fh.seek(len(UTF8_BOM) if fh.read(len(UTF8_BOM)) == UTF8_BOM else 0)
                data = np.loadtxt(fh, dtype=np.float64, comments="#", delimiter=None if separator is None else
                                  separator.decode(), skiprows=line_number if columns else 0, ndmin=2,
                                  max_rows=lim + 1, encoding="latin-1")
    except ValueError as exc:
        _bad_line(path, separator, len(fields), line_number + (1 if columns else 0))
        raise InputError(f"{path}: cannot read its columns ({str(exc).split(';')[0][:120]})") from None
    if len(data) > lim:
        raise InputError(f"{path}: more than {lim} points exceed the limit (raise --max-pixels or PCREG_MAX_PIXELS)")
    if len(data) == 0:
        raise InputError(f"{path}: no points could be read (a first line of names and no line of numbers)")
    if data.shape[1] != len(fields):
        raise InputError(f"{path}: {data.shape[1]} numbers a line under a first line of {len(fields)} names")
    return np.ascontiguousarray(data[:, columns]) if columns else data


def _first_line(path: Path) -> tuple[bytes | None, int]:
    """The first line that is neither blank nor a ``#`` comment, stripped (of a byte-order mark too), and its
    number (from 1)."""
    with open(path, "rb") as fh:
        for number, raw in enumerate(fh, 1):
            line = (raw.removeprefix(UTF8_BOM) if number == 1 else raw).strip()
            if line and not line.startswith(b"#"):
                return line, number
    return None, 0


def _split(line: bytes, separator: bytes | None) -> list[bytes]:
    return [f.strip() for f in line.split(separator)] if separator else line.split()


def _bad_line(path: Path, separator: bytes | None, width: int, start: int) -> None:
    """An :class:`InputError` naming the first line from line ``start`` on that is not ``width`` numbers."""
    with open(path, "rb") as fh:
        for number, raw in enumerate(fh, 1):
            line = (raw.removeprefix(UTF8_BOM) if number == 1 else raw).strip()
            if number < start or not line or line.startswith(b"#"):
                continue
            fields = _split(line, separator)
            if len(fields) != width or not all(_NUMBER.fullmatch(f) for f in fields):
                what = "is cut short" if not raw.endswith(b"\n") else f"is not {width} numbers, as the first"
                raise InputError(f"{path}: line {number} ({line[:40].decode('ascii', 'replace')!r}) {what}")


def _columns(path: Path, fields: list[bytes]) -> list[int] | None:
    """None for a first line of numbers with two or three of them; the x, y (and z) columns of a first line of
    names; an :class:`InputError` otherwise (numbers in other counts say nothing of which are coordinates)."""
    if all(_NUMBER.fullmatch(f) for f in fields):
        if len(fields) in (2, 3):
            return None
        raise InputError(f"{path}: {len(fields)} number{'s' if len(fields) > 1 else ''} a line and no first line naming the x, y and z columns "
                         "(give one, as 'x y z ...', or keep two or three columns)")
    names = [f.decode("ascii", "replace").strip("\"'").lstrip("/").strip().lower() for f in fields]
    if "x" not in names or "y" not in names:
        text = b",".join(fields)[:60].decode("ascii", "replace")
        raise InputError(f"{path}: its first line ({text!r}) names no x and y columns")
    return [names.index(a) for a in "xyz" if a in names]
