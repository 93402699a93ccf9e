"""pcreg's file formats: reading files safely, sniffing image headers, decoding images. :func:`read_regular_file`
opens without blocking (a FIFO never hangs), accepts regular files only and reads a bounded number of bytes;
:func:`image_size` reads an image's width and height from its header so :func:`check_image_bytes` can refuse one
beyond the pixel limit (:func:`pcreg.validation.max_pixels`) *before* OpenCV decodes it. The cloud files' checks are
:mod:`pcreg.cloud_files`'s. Everything raises :class:`~pcreg.errors.InputError` (a :class:`~pcreg.errors.PcregError`).
"""

from __future__ import annotations

import os
import re
import stat
import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from ._moved import moved
from .quiet import capture_output_fds
from .validation import check_pixels, max_pixels

#: The image files pcreg reads from a folder (by suffix, any case); what decodes is checked by header.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pnm", ".pbm",
                                   ".jfif")


def max_file_bytes(limit: int) -> int:
    """Largest file accepted for a pixel limit: 8 bytes a pixel (RGBA, 16 bits) plus 16 MiB of headers."""
    return int(limit) * 8 + (16 << 20)



# --------------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------------

def resolved(path: str | os.PathLike) -> Path:
    """``path`` made absolute with its symbolic links followed (:meth:`pathlib.Path.resolve`); a loop of
    symbolic links (which ``resolve`` raises as RuntimeError) or a path the system cannot follow is an
    :class:`InputError` naming it."""
    p = Path(path)
    try:
        return p.resolve()
    except RuntimeError:
        raise InputError(f"{p}: a loop of symbolic links") from None
    except (OSError, ValueError) as exc:  # ValueError: embedded NUL
        raise InputError(f"{p}: cannot be followed ({getattr(exc, 'strerror', None) or exc})") from None


def file_of(path: Path, folder: Path) -> bool:
    """Whether ``path`` is, now, a regular file of ``folder`` (resolved): not a link to a file elsewhere, nor a pipe (a
    read of which waits for a writer), a device or a folder; a loop of links is none."""
    try:
        return path.is_file() and path.resolve().parent == folder
    except (OSError, RuntimeError):  # a loop of links
        return False


def only_files(named: list[Path], what: str) -> list[Path]:
    """``named``, entries a folder lists under the names of ``what`` (frames, key labels), when every one is
    a file (links followed); the first that is not (a folder, a link to nothing, a FIFO or a device) is an
    :class:`InputError` naming it: skipped, it would leave a frame or a key frame out without a word."""
    for p in named:
        if not p.is_file():
            raise InputError(f"{p}: named as {what} but not a file that can be read (a folder, a link to nothing, "
                             "a FIFO or a device)")
    return list(named)


def check_regular_file(path: str | os.PathLike, *, what: str = "file") -> Path:
    """``path`` if it names a regular file (symbolic links followed); an :class:`InputError` otherwise.

    Never opens the file, so a FIFO cannot block.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except (OSError, ValueError) as exc:  # ValueError: embedded NUL
        raise InputError(f"{p}: cannot read {what} ({getattr(exc, 'strerror', None) or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: is a folder, not a file ({what})")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{p}: not a regular file (a FIFO, device or socket is no {what})")
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: permission denied")
    return p


#: What a refusal of a file too large for the pixel limit adds: how to raise it.
RAISE_LIMIT = " (raise --max-pixels / PCREG_MAX_PIXELS)"


def _bytes(n: float) -> str:
    """``n`` bytes as a person reads a size: ``64 kB``, ``3 MiB``."""
    return f"{n / 2**20:.1f} MiB" if n >= 2**20 else f"{max(1, round(n / 1024))} kB"


def read_regular_file(path: str | os.PathLike, *, max_bytes: int, what: str = "file", hint: str = "") -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (opened non-blocking; FIFOs, devices and
    folders refused; a file that grows while read is cut at the bound and refused). ``hint``: what a refusal
    of a file too large adds (:data:`RAISE_LIMIT` where the bound follows the pixel limit)."""
    p = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{p}: is a folder, not a file ({what})") from None
    except PermissionError:
        raise InputError(f"{p}: permission denied") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read {what} ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise InputError(f"{p}: is a folder, not a file ({what})")
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{p}: not a regular file (a FIFO, device or socket is no {what})")
        if st.st_size > max_bytes:
            raise InputError(f"{p}: {what} of {_bytes(st.st_size)} exceeds the limit of {_bytes(max_bytes)}{hint}")
        chunks, total = [], 0
        while True:
            try:
                b = os.read(fd, min(1 << 24, max_bytes + 1 - total))
            except OSError as exc:
                raise InputError(f"{p}: cannot read {what} ({exc.strerror or exc})") from None
            if not b:
                break
            chunks.append(b)
            total += len(b)
            if total > max_bytes:
                raise InputError(f"{p}: {what} exceeds the limit of {_bytes(max_bytes)}{hint}")
        return b"".join(chunks)
    finally:
        os.close(fd)


class KeyWrittenTwice(ValueError):
    """A JSON object that holds one key twice, which :func:`json.loads` reads as the last one, silently."""


def _keys_once(pairs: list) -> dict:
    """An object's ``(key, value)`` pairs as a dict; :class:`KeyWrittenTwice` naming a key written twice."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise KeyWrittenTwice(f"the key {key!r} is written twice in one object (JSON would keep the last)")
        out[key] = value
    return out


def loads_json(text: str | bytes, *, keys_once: bool = False):
    """:func:`json.loads` of a file's text, where a document nested deeper than Python's recursion limit is a
    ValueError like any other malformed one (json raises RecursionError for it: a hostile file, not a bug);
    ``keys_once``: an object that holds a key twice is a :class:`KeyWrittenTwice` (a ValueError)."""
    import json

    try:
        return json.loads(text, object_pairs_hook=_keys_once if keys_once else None, parse_int=_json_int)
    except RecursionError:
        raise ValueError("JSON nested too deeply") from None


#: The most digits of a JSON integer pcreg reads: its own largest (nanosecond times, byte counts) have 19.
JSON_INT_DIGITS = 20


class NumberTooLong(ValueError):
    """A JSON integer of more than :data:`JSON_INT_DIGITS` digits: no count or time, and beyond a float's range."""


def _json_int(text: str) -> int:
    if (digits := len(text.lstrip("-"))) > JSON_INT_DIGITS:
        raise NumberTooLong(f"an integer of {digits} digits, longer than any pcreg writes")
    return int(text)


#: The largest JSON file pcreg reads (a run's run.json, a suite's index, a cross-check's side file).
MAX_JSON_BYTES = 64 << 20


def load_json_object(path: str | os.PathLike, *, keys_once: bool = False) -> dict:
    """The JSON object a small file holds; a ValueError saying why not for a file that cannot be read
    (missing, a folder, no permission), is not UTF-8, is not JSON, or holds another JSON value (``keys_once``: or
    an object that holds a key twice, :func:`loads_json`)."""

    try:  # a FIFO or a device refused, not read until it ends; at most MAX_JSON_BYTES
        data = read_regular_file(path, max_bytes=MAX_JSON_BYTES, what="JSON file")
    except InputError as exc:
        raise ValueError(f"unreadable ({str(exc).removeprefix(f'{Path(path)}: ')})") from None
    try:
        value = loads_json(data.decode("utf-8"), keys_once=keys_once)
    except ValueError as exc:  # UnicodeDecodeError too
        raise ValueError(f"unreadable ({exc if isinstance(exc, (NumberTooLong, KeyWrittenTwice)) else 'not JSON'})") from None
    if not isinstance(value, dict):
        raise ValueError(f"not a JSON object (a JSON {type(value).__name__})")
    return value


# --------------------------------------------------------------------------------------------------
# image headers
# --------------------------------------------------------------------------------------------------

_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        if marker == 0xD9:
            return None
        (seg,) = struct.unpack(">H", data[i + 2:i + 4])
        if seg < 2:
            return None
        if marker in _JPEG_SOF:
            if i + 9 > n:
                return None
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return w, h
        i += 2 + seg
    return None


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    end = "<" if data[:2] == b"II" else ">"
    try:
        (off,) = struct.unpack(end + "I", data[4:8])
        (count,) = struct.unpack(end + "H", data[off:off + 2])
        w = h = None
        for k in range(min(count, 4096)):
            e = off + 2 + 12 * k
            tag, typ = struct.unpack(end + "HH", data[e:e + 4])
            if tag in (256, 257):
                val = struct.unpack(end + ("H" if typ == 3 else "I"), data[e + 8:e + (10 if typ == 3 else 12)])[0]
                if tag == 256:
                    w = val
                else:
                    h = val
        return (w, h) if w is not None and h is not None else None
    except struct.error:
        return None


def tiff_tag(data: bytes, tag: int) -> tuple[int, int, int] | None:
    """``(value, at, size)`` of a SHORT or LONG ``tag`` of a TIFF's first image (``data[at:at + size]`` its value, in
    the file's byte order), or None where it has none or the directory is cut short."""
    end = "<" if data[:2] == b"II" else ">"
    try:
        (off,) = struct.unpack(end + "I", data[4:8])
        (count,) = struct.unpack(end + "H", data[off:off + 2])
        for k in range(min(count, 4096)):
            e = off + 2 + 12 * k
            found, typ = struct.unpack(end + "HH", data[e:e + 4])
            if found == tag and typ in (3, 4):  # SHORT, LONG
                size = 2 if typ == 3 else 4
                return struct.unpack(end + ("H" if typ == 3 else "I"), data[e + 8:e + 8 + size])[0], e + 8, size
    except struct.error:
        pass
    return None


def _tiff_as_stored(data: bytes) -> bytes | bytearray:
    """A TIFF's ``data`` with the Orientation tag (274) of its first image set to 1 where it says another (2..8): OpenCV's
    TIFF decoder turns and mirrors the pixels by it whatever the flags (``IMREAD_IGNORE_ORIENTATION`` and
    ``IMREAD_UNCHANGED`` included), where it leaves a JPEG's, a PNG's and a WebP's EXIF orientation alone, so that
    pcreg reads every file's pixels as stored. ``data`` itself where there is nothing to set (else one copy)."""
    found = tiff_tag(data, 274)
    if found is None or not 2 <= found[0] <= 8:
        return data
    _, at, size = found
    patched = bytearray(data)
    patched[at:at + size] = (1).to_bytes(size, "little" if data[:2] == b"II" else "big")
    return patched


def _tiff_first_reduced(data: bytes) -> bool:
    """Whether a TIFF's first image is a reduced-resolution copy (a thumbnail: NewSubfileType, tag 254, bit 0) of
    another, as :func:`_tiff_pages` leaves such images out of its count."""
    found = tiff_tag(data, 254)
    return found is not None and bool(found[0] & 1)


def _tiff_pages(data: bytes) -> int:
    """The images a TIFF file holds (Pillow's frames: the chain of its IFDs), those that are a reduced-resolution
    copy (a thumbnail) or a transparency mask of another (NewSubfileType bits 0 and 2) left out; a file Pillow
    cannot follow counts what it read, and one past Pillow's own pixel limit (about 179 Mpx a page, above pcreg's
    default) none. OpenCV decodes the first IFD alone."""
    import io
    import warnings

    from PIL import Image

    pages = 0
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's words on a damaged tag: OpenCV's refusal says it
            with Image.open(io.BytesIO(data)) as tiff:
                for k in range(getattr(tiff, "n_frames", 1)):
                    tiff.seek(k)
                    pages += not int(tiff.tag_v2.get(254, 0)) & 0b101  # NewSubfileType
    except (OSError, SyntaxError, ValueError, EOFError, Image.DecompressionBombError, TypeError):
        pass  # TypeError: Pillow's "Missing dimensions" of an image directory without its size
    return pages


def _pnm_size(data: bytes) -> tuple[int, int] | None:
    tokens: list[bytes] = []
    i = 2
    head = data[:4096]
    while len(tokens) < 2 and i < len(head):
        c = head[i:i + 1]
        if c == b"#":
            j = head.find(b"\n", i)
            i = len(head) if j < 0 else j + 1
        elif c.isspace():
            i += 1
        else:
            j = i
            while j < len(head) and not head[j:j + 1].isspace() and head[j:j + 1] != b"#":
                j += 1
            tokens.append(head[i:j])
            i = j
    try:
        return int(tokens[0]), int(tokens[1])
    except (IndexError, ValueError):
        return None


def turned_note(frame: str | os.PathLike, labels_shape: tuple, frame_shape: tuple) -> str:
    """What a refusal of labels of ``labels_shape`` (H, W) for the frame file ``frame`` of ``frame_shape`` adds
    when the labels are the frame's size turned by a quarter and the frame's EXIF orientation (5..8) has viewers
    show it so: they were drawn on the view shown, and pcreg reads the pixels as stored; else ``""``."""
    if tuple(labels_shape[:2]) != tuple(frame_shape[:2])[::-1] or labels_shape[0] == labels_shape[1]:
        return ""
    orientation = exif_orientation(frame)
    if orientation is None or not 5 <= orientation <= 8:
        return ""
    return (f" ({Path(frame).name}'s EXIF orientation {orientation} has viewers show it turned by a quarter; pcreg "
            f"reads the pixels as stored: turn the frames first ({TURN_HINT}), or draw the labels on them as stored)")


def exif_orientation(path: str | os.PathLike) -> int | None:
    """The EXIF Orientation tag (2..8: viewers show the image turned or mirrored) of an image file, or None
    where it has none, 1 (shown as stored), or cannot be read (damaged EXIF, without a word)."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        # pcreg's pixel limit holds (Pillow's lower one is for its own decoding), and damaged EXIF reads as none
        # (Pillow warns "Corrupt EXIF data" without the file's name, and the image itself reads as it is)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            warnings.simplefilter("ignore", UserWarning)
            with Image.open(path) as image:
                if image.format == "PNG" and "exif" not in image.info:
                    return None  # Pillow would decode every pixel to look for an eXIf chunk after them
                orientation = image.getexif().get(0x0112)
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError, Image.DecompressionBombError):
        return None
    return orientation if isinstance(orientation, int) and 2 <= orientation <= 8 else None


#: How viewers show an image of each EXIF orientation (2..8) against its pixels as stored.
ORIENTATION_VIEWS = {2: "mirrored", 3: "turned by a half", 4: "mirrored upside down", 5: "mirrored and turned by a quarter",
                     6: "turned by a quarter", 7: "mirrored and turned by a quarter", 8: "turned by a quarter"}
#: How to turn an image as it is shown, said wherever pcreg notes an EXIF orientation: ``exiftran`` takes JPEGs
#: alone; Pillow's ``ImageOps.exif_transpose`` any format that carries the tag (PNG, WebP, TIFF too).
TURN_HINT = "exiftran -ai for a JPEG, or Pillow's ImageOps.exif_transpose for any format"


def orientation_note(path: str | os.PathLike, what: str = "registers") -> str | None:
    """What pcreg notes of an image file whose EXIF orientation has viewers show it otherwise than stored (pcreg
    ``what`` the pixels as stored: ``T_ref_mov`` maps them, not the view shown); None for none, or orientation 1."""
    orientation = exif_orientation(path)
    if orientation is None:
        return None
    return (f"{path}'s EXIF orientation {orientation} has viewers show it {ORIENTATION_VIEWS[orientation]}; pcreg "
            f"{what} the pixels as stored, and T_ref_mov maps them, not the view shown (turn the image first to "
            f"register the view: {TURN_HINT})")


def image_size(data: bytes) -> tuple[str, tuple[int, int] | None] | None:
    """(format, (width, height)) from an image file's header, (format, None) for a known format whose
    header is damaged, or None for a format pcreg does not read."""
    if data[:8] == PNG_SIGNATURE:
        if len(data) >= 24 and data[12:16] == b"IHDR":
            return "PNG", struct.unpack(">II", data[16:24])
        return "PNG", None
    if data[:3] == b"\xff\xd8\xff":
        return "JPEG", _jpeg_size(data)
    if data[:2] == b"BM":
        if len(data) >= 26:
            w, h = struct.unpack("<ii", data[18:26])
            return "BMP", (abs(w), abs(h))
        return "BMP", None
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return "TIFF", _tiff_size(data)
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        kind = data[12:16]
        try:
            if kind == b"VP8 ":
                w, h = struct.unpack("<HH", data[26:30])
                return "WebP", (w & 0x3FFF, h & 0x3FFF)
            if kind == b"VP8L":
                b = int.from_bytes(data[21:25], "little")
                return "WebP", ((b & 0x3FFF) + 1, ((b >> 14) & 0x3FFF) + 1)
            if kind == b"VP8X":
                return "WebP", (int.from_bytes(data[24:27], "little") + 1, int.from_bytes(data[27:30], "little") + 1)
        except struct.error:
            pass
        return "WebP", None
    if len(data) >= 2 and data[0:1] == b"P" and data[1:2] in b"123456":
        return "PNM", _pnm_size(data)
    return None


def check_image_bytes(data: bytes, name: str, *, limit: int | None = None) -> tuple[int, int]:
    """(width, height) declared by an encoded image, refused when empty, of an unknown format, damaged,
    larger than the pixel limit, or a TIFF of several pages (read, its first page would be taken for the file)."""
    if not data:
        raise InputError(f"{name}: empty file")
    found = image_size(data)
    if found is None:
        raise InputError(f"{name}: not an image pcreg reads (PNG, JPEG, BMP, TIFF, WebP, PNM)")
    fmt, size = found
    if size is None or size[0] <= 0 or size[1] <= 0:
        raise InputError(f"{name}: cannot decode image (damaged {fmt} header)")
    w, h = size
    check_pixels((h, w), name, limit=limit)
    if fmt == "TIFF" and (pages := _tiff_pages(data)) > 1:
        raise InputError(f"{name}: a TIFF of {pages} pages, of which pcreg would read the first alone; split it into "
                         "one file a page (tiffsplit, or OpenCV's cv2.imreadmulti and cv2.imwrite)")
    if fmt == "TIFF" and pages == 1 and _tiff_first_reduced(data):  # OpenCV decodes the first image, not the page
        raise InputError(f"{name}: its first image is a reduced-resolution copy ({w}x{h} px), which pcreg would read, "
                         "of the image it holds after it; save that image alone (tiffsplit, or Pillow's "
                         "Image.seek(1) and save)")
    if fmt in ("PNG", "WebP") and (frames := _animation_frames(data, fmt)) > 1:
        raise InputError(f"{name}: an animated {fmt} of {frames} images, of which pcreg would read the first alone; "
                         "save the one meant as an image of its own (Pillow's ImageSequence, or ffmpeg)")
    return w, h


#: The first eight bytes of every PNG.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_chunks(data: bytes) -> tuple[list[tuple[bytes, int, int]], str | None]:
    """The chunks of the whole PNG ``data`` up to its IEND, each ``(kind, start, end)`` (``data[start:end]`` the chunk:
    its length, kind, data and CRC), and why the file is cut short: a chunk runs past its end, or it ends before its
    IEND chunk (None: it is whole). libpng (OpenCV's reader) refuses such a file, but only after it has reserved what
    the chunk declares: a 130-byte label PNG whose IDAT length a damaged byte made 3.6 GB took 3 s, most of it the
    kernel's, and as much memory."""
    chunks: list[tuple[bytes, int, int]] = []
    at = len(PNG_SIGNATURE)
    while at + 12 <= len(data):
        length = int.from_bytes(data[at:at + 4], "big")
        kind, end = data[at + 4:at + 8], at + 12 + length
        if end > len(data):
            return chunks, f"its {kind.decode('latin-1')!r} chunk runs past the end of the file"
        chunks.append((kind, at, end))
        if kind == b"IEND":
            return chunks, None
        at = end
    return chunks, "the file ends before its IEND chunk, the end of a PNG"


def _animation_frames(data: bytes, fmt: str) -> int:
    """The images an animated PNG (APNG: its acTL chunk's frame count, and its default image where that is no frame)
    or an animated WebP (its ANMF chunks) holds; 1 for a still image. OpenCV decodes the first alone."""
    if fmt == "PNG":  # acTL and the first fcTL come before the first IDAT
        pos, count, frame_first = 8, None, False
        while pos + 12 <= len(data):
            length, kind = struct.unpack(">I4s", data[pos:pos + 8])
            if kind == b"IDAT":
                break
            if kind == b"acTL":
                count = struct.unpack(">I", data[pos + 8:pos + 12])[0]
            frame_first |= kind == b"fcTL"
            pos += 12 + length
        return 1 if count is None else count + (not frame_first)
    if len(data) < 21 or data[12:16] != b"VP8X" or not data[20] & 0x02:  # no animation flag
        return 1
    pos, frames = 12, 0
    while pos + 8 <= len(data):
        kind, size = data[pos:pos + 4], struct.unpack("<I", data[pos + 4:pos + 8])[0]
        frames += kind == b"ANMF"
        pos += 8 + size + (size & 1)
    return max(frames, 1)


def decode_image(data: bytes, name: str, *, flags: int | None = None, limit: int | None = None) -> np.ndarray:
    """``cv2.imdecode`` of checked bytes; OpenCV's errors become :class:`InputError`. The pixels as the file
    stores them, whatever the flags: an EXIF orientation is never applied (``IMREAD_UNCHANGED`` ignores
    it, other flags get ``IMREAD_IGNORE_ORIENTATION``, and a TIFF's Orientation tag, which OpenCV applies whatever
    the flags, is set to 1 for the decoder: :func:`_tiff_as_stored`), so a frame and its labels share one grid
    however each is read."""
    return _decoded(data, name, flags=flags, limit=limit)[0]


def _decoded(data: bytes | bytearray, name: str, *, flags: int | None, limit: int | None) -> tuple[np.ndarray, str]:
    """:func:`decode_image`, and the last line its codec printed ("" for none)."""
    import cv2

    w, h = check_image_bytes(data, name, limit=limit)
    if data[:8] == PNG_SIGNATURE and (cut := png_chunks(data)[1]) is not None:  # before libpng reserves what it declares
        raise InputError(f"{name}: cannot decode image ({cut}: cut short?)")
    if flags is not None and flags != cv2.IMREAD_UNCHANGED:
        flags |= cv2.IMREAD_IGNORE_ORIENTATION
    if data[:4] in (b"II*\x00", b"MM\x00*"):  # OpenCV turns a TIFF by its Orientation tag whatever the flags
        data = _tiff_as_stored(data)
    img, said = imdecode_quietly(data, cv2.IMREAD_UNCHANGED if flags is None else flags)
    if img is None and _jpeg_without_its_end(data):  # refused by OpenCV, shown by viewers
        img, said = imdecode_quietly(bytes(data) + b"\xff\xd9", cv2.IMREAD_UNCHANGED if flags is None else flags)
    if isinstance(img, Exception):
        raise InputError(f"{name}: cannot decode image ({_cv2_message(img)})") from None
    if img is None or img.size == 0:
        raise InputError(f"{name}: cannot decode image ({said or 'corrupt or truncated'})")
    if img.shape[0] != h or img.shape[1] != w:
        raise InputError(f"{name}: decoded {img.shape[1]}x{img.shape[0]} px but the header says {w}x{h}")
    if data[:2] == b"BM" and img.ndim == 3 and img.shape[2] == 4 and not img[:, :, 3].any():
        # a 32-bit BMP whose fourth byte is 0 everywhere: unused (OpenCV reads it as alpha even where the file's
        # alpha mask is 0, as Windows' screenshots have it); browsers show such a BMP opaque
        img = img[:, :, :3]
    return img, said


def _jpeg_without_its_end(data: bytes | bytearray) -> bool:
    """Whether ``data`` is a JPEG with no end-of-image marker (FF D9) after its last scan (scan data cannot hold one),
    which OpenCV refuses and viewers show: with the marker put back it decodes whole, or as the part its data holds,
    the rest the decoder's guess, said as damage (``premature end of data segment``)."""
    if data[:2] != b"\xff\xd8":
        return False
    scan = data.rfind(b"\xff\xda")
    return scan > 0 and data.find(b"\xff\xd9", scan) < 0


def imdecode_quietly(data: bytes, flags: int) -> tuple:
    """``cv2.imdecode`` with what the codec libraries print (libpng's ``libpng error: ...`` on a damaged
    chunk) kept off the terminal. Returns (image, or None, or the ``cv2.error`` raised; the last line
    the codec printed, or "")."""
    import cv2

    with capture_output_fds() as said:
        try:
            img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
        except cv2.error as exc:
            img = exc
    lines = [_OPENCV_LOG_PREFIX.sub("", line).strip() for line in "".join(said).splitlines() if line.strip()]
    return img, (lines[-1][:200] if lines else "")


#: OpenCV's own log prefix, ``[ WARN:0@0.632] global grfmt_png.cpp:793 readFromStreamOrBuffer ``: where in
#: OpenCV it logged and when, which a user's one-line error does not need.
_OPENCV_LOG_PREFIX = re.compile(r"^\[\s*[A-Z]+:\d+@[\d.]+\]\s+(?:global\s+)?\S+:\d+\s+\S+\s+")


def _cv2_message(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return (text[-1] if text else type(exc).__name__).strip()[:200]


def read_image_file(path: str | os.PathLike, *, flags: int | None = None, limit: int | None = None) -> np.ndarray:
    """An image file decoded by OpenCV (``flags``; default ``IMREAD_UNCHANGED``, channels in BGR order):
    a regular file only, its size checked against the pixel ``limit`` (default
    :func:`pcreg.validation.max_pixels`) in the header before decoding."""
    return read_image_file_and_damage(path, flags=flags, limit=limit)[0]


#: The beginnings of what libjpeg prints when it decoded around damaged data (a byte changed in the scan, the
#: file cut short): it returns an image whose pixels after the damage are its guesses. Other codecs' warnings
#: (libpng's on an sRGB profile, libtiff's on an unknown tag) are about metadata, not pixels.
_DAMAGED_DATA = ("Corrupt JPEG data", "Premature end of JPEG file")


def read_image_file_and_damage(path: str | os.PathLike, *, limit: int | None = None, flags: int | None = None) -> tuple[np.ndarray, str]:
    """:func:`read_image_file` (as the file stores it, or as ``flags`` say), and what its decoder said of damaged
    pixel data it decoded around (libjpeg's ``Corrupt JPEG data: premature end of data segment``), or ``""``."""
    limit = max_pixels(limit)
    data = read_regular_file(path, max_bytes=max_file_bytes(limit), what="image", hint=RAISE_LIMIT)
    img, said = _decoded(data, str(path), flags=flags, limit=limit)
    return img, said if said.startswith(_DAMAGED_DATA) else ""


if not TYPE_CHECKING:  # a module __getattr__ would be mypy's for every name: a misspelt one would pass
    __getattr__ = moved(__name__, {n: "pcreg.cloud_files" for n in ("check_cloud_file", "check_npy_file")} | {"read_text_matrix": "pcreg.text_files"})
