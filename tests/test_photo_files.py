"""Photographs and image files as ``pcreg register``, ``pcreg crosscheck`` and the dataset readers meet them: every
reader gives the pixels the file stores, the same for one file, and a refusal names the file it is about."""

import json
import struct

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main

from _images import moved, shapes_image


def _tiff(rgb: np.ndarray, orientation: int) -> bytes:
    """A little-endian, uncompressed, one-strip TIFF of ``rgb`` ((H, W, 3) uint8 or uint16, stored as given) whose
    Orientation tag (274) is ``orientation``: the layout a camera's or a scanner's TIFF has, written byte by byte."""
    h, w, c = rgb.shape
    bits = rgb.dtype.itemsize * 8
    pixels = np.ascontiguousarray(rgb, dtype=rgb.dtype.newbyteorder("<")).tobytes()
    tags = [(256, 4, w), (257, 4, h), (258, 3, None), (259, 3, 1), (262, 3, 2), (273, 4, None), (274, 3, orientation),
            (277, 3, c), (278, 4, h), (279, 4, len(pixels)), (284, 3, 1)]
    ifd_end = 8 + 2 + 12 * len(tags) + 4
    bits_at, pixels_at = ifd_end, ifd_end + 2 * c
    out = b"II*\x00" + struct.pack("<IH", 8, len(tags))
    for tag, kind, value in tags:
        if tag == 258:
            out += struct.pack("<HHII", tag, kind, c, bits_at)
        elif tag == 273:
            out += struct.pack("<HHII", tag, kind, 1, pixels_at)
        elif kind == 3:
            out += struct.pack("<HHIHH", tag, kind, 1, value, 0)
        else:
            out += struct.pack("<HHII", tag, kind, 1, value)
    return out + struct.pack("<I", 0) + struct.pack(f"<{c}H", *[bits] * c) + pixels


@pytest.mark.parametrize("depth", [np.uint8, np.uint16])
def test_a_tiff_with_an_orientation_tag_reads_as_stored_like_a_jpeg(tmp_path, capsys, depth):
    """OpenCV's TIFF decoder turns the pixels by the file's Orientation tag whatever the flags (a JPEG's EXIF
    orientation it leaves as stored, as pcreg reads every file): orientation 3 read turned by a half, so that
    ``pcreg register`` of it against its pixels as a PNG found a half turn while its note said "pcreg registers the
    pixels as stored"; 6 and 8 were refused as "decoded 240x320 px but the header says 320x240", a damaged file."""
    rgb = shapes_image()
    stored = rgb.astype(depth) * (257 if depth is np.uint16 else 1)
    for orientation in range(1, 9):
        (tmp_path / f"o{orientation}.tif").write_bytes(_tiff(stored, orientation))
        np.testing.assert_array_equal(pcreg.load_image(tmp_path / f"o{orientation}.tif"), rgb)
    cv2.imwrite(str(tmp_path / "stored.png"), rgb[:, :, ::-1])
    for orientation in (3, 6):
        assert main(["register", str(tmp_path / "stored.png"), str(tmp_path / f"o{orientation}.tif"), "--json",
                     "--init", "identity"]) == 0
        out, err = capsys.readouterr()
        np.testing.assert_allclose(json.loads(out)["matrix"], np.eye(3), atol=1e-6)
        assert f"o{orientation}.tif's EXIF orientation {orientation} has viewers show it" in err
