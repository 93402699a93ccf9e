"""Hostile CVAT "Segmentation mask 1.1" archives and label PNGs, built here byte by byte: each is refused in
one line naming the file (an :class:`InputError`), or read as the export it stands for."""

from __future__ import annotations

import os
import re
import stat
import struct
import zipfile
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.classes.cvat import CvatExport
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.formats import max_file_bytes

LIMIT = 50_000_000
MASK = "SegmentationClass/f0.png"


def _export(path: Path) -> CvatExport:
    return CvatExport(path, max_bytes=max_file_bytes(LIMIT), max_pixels=LIMIT)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _mask_png(h: int = 48, w: int = 64) -> bytes:
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[: h // 2] = (128, 64, 128)
    return cv2.imencode(".png", rgb)[1].tobytes()


def test_members_sharing_their_data_are_refused(tmp_path):
    """A member whose data runs over the next member's (Fifield's overlapping zip bomb: one block inflated under
    many names) is refused when the archive is opened; Python's zipfile reads it."""
    png = _mask_png()
    second = zipfile.ZipInfo("SegmentationClass/f1.png")
    second.CRC, second.compress_size, second.file_size = zlib.crc32(png), len(png), len(png)
    header = second.FileHeader()  # the second member's local header, which the first member's data quotes
    path = tmp_path / "overlap.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        z.writestr(MASK, header + png)
    raw = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        first = z.getinfo(MASK)
    data_at = first.header_offset + 30 + len(MASK)
    cd_at = raw.index(b"PK\x01\x02")
    first_entry = bytes(raw[cd_at:raw.index(b"PK\x05\x06")])
    # the second member's central entry: its header inside the first member's data, its data the PNG
    info = zipfile.ZipInfo("SegmentationClass/f1.png")
    info.header_offset, info.CRC, info.compress_size, info.file_size = data_at, zlib.crc32(png), len(png), len(png)
    entry = struct.pack("<4s4B4HL2L5H2L", b"PK\x01\x02", 20, 0, 20, 0, 0, 0, 0, 0, info.CRC, len(png), len(png),
                        len(info.filename), 0, 0, 0, 0, 0, data_at) + info.filename.encode()
    directory = first_entry + entry
    end = struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, 2, 2, len(directory), cd_at, 0)
    path.write_bytes(bytes(raw[:cd_at]) + directory + end)
    with zipfile.ZipFile(path) as z:  # the archive reads: both members, one inside the other
        assert z.read("SegmentationClass/f1.png") == png and z.read(MASK) == header + png
    with pytest.raises(InputError, match=r"overlap\.zip: member 'SegmentationClass/f\d\.png' overlaps the next"):
        _export(path)


def test_a_mask_is_read_to_no_more_bytes_than_its_pixels_take(tmp_path):
    """A 64x48 mask with 18 MB of ancillary chunks (18 kB in the archive) is refused before it is inflated
    whole; the mask without it reads."""
    png = _mask_png()
    bloated = png[:33] + _chunk(b"zzZz", bytes(2 << 20)) * 9 + png[33:]
    assert cv2.imdecode(np.frombuffer(bloated, np.uint8), cv2.IMREAD_UNCHANGED) is not None  # a PNG libpng reads
    path = tmp_path / "bloated.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(MASK, bloated)
        z.writestr("SegmentationClass/f1.png", png)
    with _export(path) as export:
        assert export.read("SegmentationClass/f1.png") == png
        with pytest.raises(InputError, match=r"bloated\.zip:SegmentationClass/f0\.png: larger than the \d+ bytes"):
            export.read(MASK)


def test_a_member_that_is_no_image_is_refused_from_its_first_bytes(tmp_path):
    """A member of 64 MB of zeros under a mask's name is refused as no image (as before), from its first bytes."""
    path = tmp_path / "zeros.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(MASK, bytes(64 << 20))
    with _export(path) as export, pytest.raises(InputError, match=r"zeros\.zip:SegmentationClass/f0\.png: not an image"):
        export.read(MASK)


def _renamed(path: Path, names: dict[str, bytes]) -> Path:
    """An archive of a mask under each of ``names`` (an ASCII placeholder -> the bytes the archive stores as its
    name; the UTF-8 flag clear, as ASCII names leave it)."""
    with zipfile.ZipFile(path, "w") as z:
        for placeholder in names:
            z.writestr(placeholder, _mask_png())
    raw = path.read_bytes()
    for placeholder, stored in names.items():
        assert len(stored) == len(placeholder)
        raw = raw.replace(placeholder.encode(), stored)
    path.write_bytes(raw)
    return path


def test_windows_separators_are_folders(tmp_path):
    """``SegmentationClass\\f0.png`` (Windows PowerShell's Compress-Archive) is the mask ``f0``, not a path outside
    the archive; ``..\\x.png`` still is."""
    path = _renamed(tmp_path / "win.zip", {"SegmentationClass_f0.png": b"SegmentationClass\\f0.png",
                                           "ImageSets_Segmentation_default.txt": b"ImageSets\\Segmentation\\default.txt"})
    with _export(path) as export:
        assert export.names("SegmentationClass") == [MASK]
        assert export.read(MASK) == _mask_png()
    path = _renamed(tmp_path / "climbs.zip", {"__/x.png": b"..\\x.png"})
    with pytest.raises(InputError, match=r"climbs\.zip: member '\.\.\\\\x\.png' names a path outside the archive"):
        _export(path)


def test_utf8_names_without_the_utf8_flag_are_utf8(tmp_path):
    """A name stored as UTF-8 bytes without the archive's UTF-8 flag is the UTF-8 name (Python's zipfile reads
    cp437: ``fé0`` as ``f├⌐0``); a cp437 name, flag clear, is read as cp437."""
    path = _renamed(tmp_path / "utf8.zip", {"SegmentationClass/fQQ0.png": "SegmentationClass/fé0.png".encode()})
    with zipfile.ZipFile(path) as z:
        assert not z.infolist()[0].flag_bits & 0x800 and z.namelist() == ["SegmentationClass/f├⌐0.png"]
    with _export(path) as export:
        assert export.names("SegmentationClass") == ["SegmentationClass/fé0.png"]
    path = _renamed(tmp_path / "cp437.zip", {"SegmentationClass/fQ0.png": b"SegmentationClass/f\x820.png"})
    with _export(path) as export:
        assert export.names("SegmentationClass") == ["SegmentationClass/fé0.png"]


def test_a_symbolic_link_member_is_refused_as_one(tmp_path):
    """A member stored as a symbolic link (its data the path it points to) is refused as a link: read as the
    file, ``labelmap.txt`` -> ``/etc/passwd`` was a label map of one class named '/etc/passwd'."""
    path = tmp_path / "link.zip"
    info = zipfile.ZipInfo("labelmap.txt")
    info.create_system, info.external_attr = 3, (stat.S_IFLNK | 0o777) << 16
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(info, "/etc/passwd")
        z.writestr(MASK, _mask_png())
    with _export(path) as export:
        assert export.read(MASK) == _mask_png()
        with pytest.raises(InputError, match=r"link\.zip:labelmap\.txt: a symbolic link in the archive, not a file"):
            export.read("labelmap.txt", max_bytes=1 << 20, what="a class table")


def test_an_encrypted_member_is_refused_in_a_line(tmp_path):
    """A member encrypted with a password (its flag bit 0) is refused saying so, in one short line; Python's zipfile
    says so with the member's whole ZipInfo."""
    path = tmp_path / "secret.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(MASK, _mask_png())
    raw = bytearray(path.read_bytes())
    for signature, flag_at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        raw[raw.index(signature) + flag_at] |= 1
    path.write_bytes(bytes(raw))
    with _export(path) as export, pytest.raises(InputError) as refused:
        export.read(MASK)
    assert str(refused.value) == f"{path}:{MASK}: encrypted (the archive has a password); zip the export without one"


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_an_unpacked_export_entry_that_is_no_file_is_refused(tmp_path, kind):
    """In an unpacked export, a ``labelmap.txt`` or a mask that is a folder or a FIFO is refused saying what it is:
    the label map was said to be missing, and the mask was left out without a word."""
    root = tmp_path / "export"
    (root / "SegmentationClass").mkdir(parents=True)
    (root / MASK).write_bytes(_mask_png())
    for name in ("labelmap.txt", "SegmentationClass/f1.png"):
        (root / name).mkdir() if kind == "folder" else os.mkfifo(root / name)
    said = "is a folder, not a file" if kind == "folder" else "not a regular file"
    with _export(root) as export:
        assert export.has("labelmap.txt") and export.names("SegmentationClass") == [MASK, "SegmentationClass/f1.png"]
        for name in ("labelmap.txt", "SegmentationClass/f1.png"):
            with pytest.raises(InputError, match=f"{re.escape(str(root / name))}: {said}"):
                export.read(name)


def test_an_export_zipped_again_is_named(tmp_path, capsys):
    """``pcreg run --labels`` of an archive that holds the export's archive (zipped again) says which member is the
    archive inside, after what is missing."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for name in ("f0.png", "f1.png"):
        cv2.imwrite(str(frames / name), np.full((48, 64, 3), 90, np.uint8))
    inner = tmp_path / "task.zip"
    with zipfile.ZipFile(inner, "w") as z:
        z.writestr("labelmap.txt", "background:0,0,0::\nroad:128,64,128::\ncar:64,0,128::\n")
        z.writestr(MASK, _mask_png())
    outer = tmp_path / "outer.zip"
    with zipfile.ZipFile(outer, "w") as z:
        z.write(inner, "downloads/task_export.zip")
    assert main(["run", str(frames), "--labels", str(outer), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"pcreg: error: {outer}:labelmap.txt: missing (the export's class table; or name one with --classes); it holds "
        "downloads/task_export.zip, an archive in the archive: take the export out and give it to --labels"]


def test_a_mask_of_another_size_is_refused_drawn_on_or_not(tmp_path, capsys):
    """A mask of another size than the frames is refused from its header even when nothing is drawn on it: a
    black 7000x7000 mask (a 1.2 kB member) was inflated, 1.4 GB, to find it background and skip it."""
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for name in ("f0.png", "f1.png"):
        cv2.imwrite(str(frames / name), cv2.GaussianBlur(rng.integers(0, 255, (48, 64, 3), np.uint8), (5, 5), 2))
    path = tmp_path / "export.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("labelmap.txt", "background:0,0,0::\nroad:128,64,128::\ncar:64,0,128::\n")
        drawn = np.zeros((48, 64, 3), np.uint8)
        drawn[:24], drawn[24:, :32] = (128, 64, 128), (128, 0, 64)  # BGR of road and car
        z.writestr(MASK, cv2.imencode(".png", drawn)[1].tobytes())
        z.writestr("SegmentationClass/f1.png", cv2.imencode(".png", np.zeros((60, 80, 3), np.uint8))[1].tobytes())
    assert main(["run", str(frames), "--labels", str(path), "--out", str(tmp_path / "out"), "--model", "flow"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"pcreg: error: {path}:SegmentationClass/f1.png: the mask is 80x60, the frames 64x48"]


def test_masks_named_in_decomposed_unicode_name_the_frames_composed(tmp_path, capsys):
    """macOS writes names decomposed (NFD: ``e`` and a combining accent): a CVAT export zipped there, or key labels
    copied from there, named frames ``café_0`` that pcreg said named no frame, "the frames café_0 ... café_1"; they
    name the frame of the same text composed."""
    import unicodedata

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    composed = [unicodedata.normalize("NFC", f"café_{i}") for i in range(3)]
    for name in composed:
        cv2.imwrite(str(frames / f"{name}.png"), cv2.GaussianBlur(rng.integers(0, 255, (48, 64, 3), np.uint8), (5, 5), 2))
    decomposed = unicodedata.normalize("NFD", composed[0])
    assert decomposed != composed[0]
    path = tmp_path / "export.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("labelmap.txt", "background:0,0,0::\nroad:128,64,128::\ncar:64,0,128::\n")
        drawn = np.zeros((48, 64, 3), np.uint8)
        drawn[:24], drawn[24:, :32] = (128, 64, 128), (128, 0, 64)  # BGR of road and car
        z.writestr(f"SegmentationClass/{decomposed}.png", cv2.imencode(".png", drawn)[1].tobytes())
    keys = tmp_path / "keys"
    keys.mkdir()
    labels = np.zeros((48, 64), np.uint8)
    labels[24:] = 1
    cv2.imwrite(str(keys / f"{decomposed}.png"), labels)
    for given in (path, keys):
        out = tmp_path / f"out_{given.name}"
        assert main(["run", str(frames), "--labels", str(given), "--out", str(out), "--model", "flow"]) == 0, \
            capsys.readouterr().err
        assert sorted(p.name for p in out.glob("*.png")) == [f"{name}.png" for name in composed]


def test_an_export_zipped_with_the_folders_of_its_path_is_read_inside_them(tmp_path, capsys):
    """``zip -r task.zip home/me/export`` puts the export two folders down: it was refused as "labelmap.txt: missing"
    (one folder around it was read); it reads as the export, zipped or unpacked. A folder beside the path is still no
    export's."""
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for name in ("f0.png", "f1.png"):
        cv2.imwrite(str(frames / name), cv2.GaussianBlur(rng.integers(0, 255, (48, 64, 3), np.uint8), (5, 5), 2))
    drawn = np.zeros((48, 64, 3), np.uint8)
    drawn[:24], drawn[24:, :32] = (128, 64, 128), (128, 0, 64)  # BGR of road and car
    members = {"labelmap.txt": b"background:0,0,0::\nroad:128,64,128::\ncar:64,0,128::\n",
               MASK: cv2.imencode(".png", drawn)[1].tobytes()}
    path = tmp_path / "task.zip"
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(f"home/me/export/{name}", data)
    unpacked = tmp_path / "unpacked"
    for name, data in members.items():
        (unpacked / "home" / "me" / "export" / name).parent.mkdir(parents=True, exist_ok=True)
        (unpacked / "home" / "me" / "export" / name).write_bytes(data)
    for given in (path, unpacked):
        assert main(["run", str(frames), "--labels", str(given), "--out", str(tmp_path / f"out_{given.stem}"),
                     "--model", "flow"]) == 0, capsys.readouterr().err
    (unpacked / "home" / "notes").mkdir()
    assert main(["run", str(frames), "--labels", str(unpacked), "--out", str(tmp_path / "out_beside")]) == 2
    assert "holds no label PNG" in capsys.readouterr().err
