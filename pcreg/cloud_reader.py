"""Reading a point cloud from a file, by suffix: PLY, binary PCD and Open3D's text formats (.xyz, .xyzn, .xyzrgb)
through Open3D once :mod:`pcreg.cloud_files` and :mod:`pcreg.cloud_text` have checked them, ASCII PCD from its
checked lines, .npy through numpy, a .pts cloud and a text file of columns (.txt, .csv) by
:mod:`pcreg.cloud_text`. Whatever a reader would fill with zeros or skip is refused in one line naming the
file (:class:`~pcreg.errors.InputError`)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .cloud_files import PcdHeader, _ply_header, check_cloud_file, check_npy_file, pcd_header
from .cloud_text import check_last_line, check_text_cloud, number_columns, read_columns, read_pts
from .errors import InputError
from .registration.api import check_cloud
from .validation import check_path, check_point_count, max_pixels

__all__ = ["CLOUD_SUFFIXES", "TEXT_COLUMN_SUFFIXES", "load_cloud", "read_columns"]

#: The suffixes read as columns of numbers by :func:`read_columns`.
TEXT_COLUMN_SUFFIXES = (".txt", ".csv")
#: Every suffix :func:`load_cloud` reads (any case).
CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts", ".npy") + TEXT_COLUMN_SUFFIXES


def load_cloud(path: str | os.PathLike, *, max_points: int | None = None) -> np.ndarray:
    """Points (N, 3), or (N, 2) from a .npy or a text file of two columns, read by suffix (:data:`CLOUD_SUFFIXES`).

    Regular files only; the point count a PLY/PCD/NPY header declares must be within ``max_points``
    (default :func:`pcreg.validation.max_pixels`) and present in the file: a truncated file is refused
    (Open3D would pad it with zeros). A PCD's points with a coordinate NaN are left out, as PCL's
    ``removeNaNFromPointCloud`` leaves them: PCL marks so the pixels of an organised cloud (a depth camera's,
    HEIGHT > 1) that measured nothing. Open3D's messages go
    to stderr, never stdout.
    """
    path = check_path(path, "path")
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InputError(f"{path}: unknown point-cloud format {suffix!r} (use {', '.join(CLOUD_SUFFIXES)})")
    limit = max_pixels(max_points)
    check_cloud_file(path, limit=limit)
    if _text(path, suffix):
        check_last_line(path)  # a text cloud cut inside its last number holds the right count of numbers
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
    elif suffix == ".pts":
        pts = read_pts(path, limit)
    else:
        header = pcd_header(path) if suffix == ".pcd" else None
        if header is not None:
            _check_xyz(path, header)
        pts = _read_pcd_ascii(path, header) if header is not None and header.data == "ascii" else \
            _read_open3d(path, suffix, limit)
        if suffix == ".pcd":  # PCL's removeNaNFromPointCloud leaves out a point with any coordinate NaN
            unmeasured = np.isnan(pts).any(axis=1)
            if unmeasured.all():
                if np.isnan(pts).all():
                    raise InputError(f"{path}: every point's coordinates are NaN (no point was measured)")
                raise InputError(f"{path}: every point has a coordinate that is NaN (no point was measured in full; "
                                 "PCL leaves such points out, as pcreg does)")
            pts = pts[~unmeasured]
    return check_cloud(pts, str(path), limit=limit)


def _text(path: Path, suffix: str) -> bool:
    """Whether a cloud file (checked) holds its points as text: its suffix says, or a PLY's or PCD's header."""
    if suffix == ".npy":
        return False
    if suffix == ".ply":
        return _ply_header(path)[0] == "ascii"
    return suffix != ".pcd" or pcd_header(path).data == "ascii"


def _read_open3d(path: Path, suffix: str, limit: int) -> np.ndarray:
    import open3d as o3d

    from .quiet import capture_output_fds

    text = suffix in (".xyz", ".xyzn", ".xyzrgb")
    expected = check_text_cloud(path, suffix, limit)[0] if text else 0

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
    pts = number_columns(path, columns, header.points, start=header.start)
    for k, axis in enumerate("xyz"):
        kind = header.types[header.fields.index(axis)]
        values = pts[:, k]
        whole = np.isnan(values) | (values == np.round(values))
        if kind != "F" and not whole.all():
            row = int(np.flatnonzero(~whole)[0])
            raise InputError(f"{path}: its field {axis} holds whole numbers (TYPE {kind}), point {row + 1} has "
                             f"{axis} = {float(values[row])!r}")
    return pts


def _check_xyz(path: Path, header) -> None:
    """An :class:`~pcreg.errors.InputError` for a PCD whose fields lack x, y or z (PCL's names, in lower case),
    whatever its DATA kind: a binary one's was Open3D's "[CheckHeader] Fields for point data are not complete"."""
    if all(axis in header.fields for axis in "xyz"):
        return
    if all(axis.upper() in header.fields for axis in "xyz"):
        raise InputError(f"{path}: PCD fields {' '.join(header.fields)} lack x, y or z: PCL names the coordinates in "
                         "lower case (rename the fields in its header)")
    raise InputError(f"{path}: PCD fields {' '.join(header.fields)} lack x, y or z: not a cloud of points (an image's "
                     "or descriptors' PCD?)")


def _open3d_warning(text: str) -> str:
    """The first warning or error line Open3D printed (ANSI colours removed), or ''; RPly's first, where it printed
    one: it names what it could not read ("Error reading 'z' of 'vertex' number 7", an ASCII ``inf``), where Open3D's
    own line says only "unable to read file"."""
    lines = re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines()
    for line in sorted(lines, key=lambda line: "RPly: " not in line):
        if "[Open3D WARNING]" in line or "[Open3D ERROR]" in line or "RPly: " in line:
            return line.split("]", 1)[1].strip()[:200] if "[Open3D" in line else line.strip()[:200]
    return ""


