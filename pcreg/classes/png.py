"""Label PNGs: the one pair that writes and reads a labelling's class ids as an image.

pcreg writes labels as *palette* (indexed) PNGs: each pixel's value is its class id, and the palette
gives each id its table's colour, so any viewer shows the classes, while a reader of the indices gets
the ids back. OpenCV cannot write a palette PNG and reads one as colour (it expands the palette), so
palette PNGs go through Pillow; the others through OpenCV as pcreg reads every image
(:func:`pcreg.formats.decode_image`: a regular file, its size checked in the header first).

:func:`read_label_png` reads a key frame's labels stored any of three ways:

- class ids, one 8-bit (or 16-bit) channel, as the shared CamVid clips store them;
- a palette PNG, as DAVIS and VOC store them: the values are the indices, and the palette's colour of
  every index the image uses must be the table's colour of that id;
- colour (RGB), each pixel in its class's table colour, as CVAT's ``SegmentationClass`` masks.

A value, or a colour, that is no class of the table is refused with one line naming the file.
"""

from __future__ import annotations

import io
import zlib
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..formats import PNG_SIGNATURE, png_chunks
from .table import ClassTable

__all__ = ["encode_label_png", "write_label_png", "decode_label_png", "read_label_png", "is_palette_png", "check_lossless",
           "alpha_from_trns", "check_png_chunks", "check_png_rows", "PNG_SIGNATURE"]

_PALETTE = 3  # IHDR colour type of an indexed PNG


def is_palette_png(data: bytes) -> bool:
    """Whether ``data`` is a PNG whose header declares a palette (indexed colour)."""
    return len(data) >= 26 and data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR" and data[25] == _PALETTE


def check_png_chunks(data: bytes, name: str) -> None:
    """An :class:`InputError` naming ``name`` when a chunk of the PNG ``data`` fails its CRC or runs past the file's
    end, or the file ends before its IEND chunk. libpng (OpenCV's reader) refuses such a file; Pillow, which reads
    palette PNGs here, does not check the image data's chunks, and read a damaged key mask as labels (a file cut
    between two chunks as "cannot identify image file <_io.BytesIO object at 0x...>", or as labels when the cut
    left its image data whole)."""
    chunks, cut = png_chunks(data)
    for kind, at, end in chunks:
        if zlib.crc32(data[at + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            raise InputError(f"{name}: a CRC error in its {kind.decode('latin-1')!r} chunk: the file is damaged")
    if cut is not None:
        raise InputError(f"{name}: {cut} (cut short?)")


#: Adam7's seven passes over an interlaced PNG: (first column, first row, column step, row step).
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # IHDR colour type -> samples a pixel


def check_png_rows(data: bytes, name: str) -> None:
    """An :class:`InputError` naming ``name`` when the image data of the PNG ``data`` (its IDAT chunks, inflated)
    ends before every row its header declares, or does not inflate. libpng refuses such a file ("Not enough image
    data"); Pillow, which reads palette PNGs here, fills the rows it lacks with index 0 when the compressed stream
    ends cleanly, and read such a key mask as labels, its missing rows the first class. Call after
    :func:`check_png_chunks` (the chunks whole)."""
    chunks, _ = png_chunks(data)
    if len(data) < 29 or data[12:16] != b"IHDR" or data[25] not in _CHANNELS:
        return  # no header to measure by: the decoder refuses it
    w, h, depth, interlaced = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), data[24], data[28]
    bits = depth * _CHANNELS[data[25]]
    passes = _ADAM7 if interlaced else ((0, 0, 1, 1),)
    need = 0
    for x0, y0, dx, dy in passes:
        pw, ph = max(0, -(-(w - x0) // dx)), max(0, -(-(h - y0) // dy))
        need += ph * (1 + (pw * bits + 7) // 8) if pw else 0
    inflate, got = zlib.decompressobj(), 0
    try:
        for kind, at, end in chunks:
            rest = data[at + 8:end - 4] if kind == b"IDAT" else b""
            while rest and got <= need:
                got += len(inflate.decompress(rest, need + 1 - got))
                rest = inflate.unconsumed_tail
    except zlib.error as exc:
        raise InputError(f"{name}: its image data does not inflate ({exc}): the file is damaged") from None
    if got < need:
        raise InputError(f"{name}: its image data ends before the {h} rows of {w} px its header declares ({got} of "
                         f"{need} bytes): the file is cut short or damaged")


def encode_label_png(labels: np.ndarray, table: ClassTable) -> bytes:
    """The bytes of a palette PNG of ``labels`` ((H, W) integers, each a class id of ``table``, else an
    :class:`InputError`): values the ids, palette the table's colours (ids that are no class: black)."""
    from PIL import Image

    lab = np.asarray(labels)
    if lab.ndim != 2 or lab.size == 0:
        raise InputError(f"labels must be a non-empty (H, W) array, got shape {lab.shape}")
    lab = np.ascontiguousarray(table.check_labels(lab, "labels"))
    im = Image.frombytes("P", (lab.shape[1], lab.shape[0]), lab.tobytes())
    im.putpalette(table.palette().tobytes(), rawmode="RGB")
    buf = io.BytesIO()
    im.save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def write_label_png(path: str | Path, labels: np.ndarray, table: ClassTable) -> Path:
    """Write :func:`encode_label_png` to ``path`` atomically (:func:`pcreg.outputs.atomic_write_bytes`)."""
    from ..outputs import atomic_write_bytes

    return atomic_write_bytes(path, encode_label_png(labels, table))


def check_lossless(data: bytes, name: str) -> None:
    """An :class:`InputError` naming ``name`` when ``data`` is a JPEG, a lossy WebP (a ``VP8 `` image, alone or
    after the ``VP8X`` header that metadata or an alpha channel bring) or a TIFF compressed as JPEG: its
    compression changes the values (and colours) at every edge, which a label image cannot have."""
    lossy = "JPEG" if data[:3] == b"\xff\xd8\xff" else "lossy WebP" if _lossy_webp(data) \
        else "TIFF compressed as JPEG" if _jpeg_tiff(data) else None
    if lossy is not None:
        raise InputError(f"{name}: a {lossy}, which changes the values at every edge; label images must be lossless (PNG)")


def alpha_from_trns(data: bytes) -> bool:
    """Whether ``data`` is a PNG of no alpha channel (grey or RGB) whose alpha, as OpenCV decodes it, comes from a
    ``tRNS`` chunk: one value marked transparent (a tool's transparent background), every pixel's value still
    stored exactly, to be read as a palette PNG's ``tRNS`` is, by its values."""
    return data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR" and data[25] in (0, 2)


def stored_grey(data: bytes, img: np.ndarray) -> np.ndarray:
    """``img``, a grey PNG ``data`` as OpenCV decodes it, with the values the file stores: libpng widens a grey
    PNG of 1, 2 or 4 bits to 8 by scaling (a 4-bit 1 read as 17, a 1-bit 1 as 255), so a label image of small
    ids saved in fewer bits read as ids it does not hold."""
    if not (data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR" and data[25] == 0 and data[24] in (1, 2, 4)):
        return img
    return img // np.uint8(255 // ((1 << data[24]) - 1))


def _lossy_webp(data: bytes) -> bool:
    """Whether ``data`` is a WebP whose image is lossy: its first image chunk ``VP8 `` (``VP8L`` is lossless),
    in an animation's first frame too."""
    if data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        return False
    at = 12
    while at + 8 <= len(data):
        kind, size = data[at:at + 4], int.from_bytes(data[at + 4:at + 8], "little")
        if kind in (b"VP8 ", b"VP8L"):
            return kind == b"VP8 "
        # an animation's first frame (ANMF) holds its image chunks after 16 bytes of place and duration
        at += 8 + 16 if kind == b"ANMF" else 8 + size + (size & 1)
    return False


#: TIFF compressions that change values: JPEG (6, the old form; 7), lossy JPEG as DNG stores it (34892).
_TIFF_JPEG = (6, 7, 34892)


def _jpeg_tiff(data: bytes) -> bool:
    """Whether ``data`` is a TIFF whose image is compressed as JPEG: its first image's Compression tag (259), read
    from the bytes as OpenCV's decoder will (a TIFF Pillow cannot open is judged too)."""
    from ..formats import tiff_tag

    found = tiff_tag(data, 259) if data[:4] in (b"II*\0", b"MM\0*") else None
    return found is not None and found[0] in _TIFF_JPEG


def palette_image(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(indices, palette)`` of a palette PNG: (H, W) uint8 and (n, 3) uint8 RGB; an :class:`InputError`
    naming it when it does not decode as one or a pixel's index is beyond its palette (a colour no viewer can
    show, which a conversion to RGB would make black)."""
    from PIL import Image

    check_png_chunks(data, name)
    check_png_rows(data, name)
    try:
        with Image.open(io.BytesIO(data)) as im:
            im.load()
            if im.mode != "P":
                raise InputError(f"{name}: a palette PNG that decodes as {im.mode}")
            idx = np.asarray(im, dtype=np.uint8).copy()
            palette = im.getpalette(rawmode="RGB") or []
    except InputError:
        raise
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise InputError(f"{name}: cannot decode image ({exc})") from None
    pal = np.asarray(palette[: len(palette) // 3 * 3], np.uint8).reshape(-1, 3)
    if idx.size and int(idx.max()) >= len(pal):
        raise InputError(f"{name}: a pixel of index {int(idx.max())}, beyond its palette of {len(pal)} colours")
    return idx, pal


def _voc_palette_hint(idx: np.ndarray, pal: np.ndarray) -> str:
    """What a refusal of a palette PNG adds when the colours of its indices are VOC's colour map, as DAVIS,
    YouTube-VOS and VOC save masks: which table reads an object mask, and that classes need theirs."""
    from .files import voc_colormap

    present = np.flatnonzero(np.bincount(idx.ravel(), minlength=256))
    if len(present) < 2 or not np.array_equal(pal[present], voc_colormap(256)[present]):
        return ""
    return ("; its colours are VOC's colour map, as DAVIS and YouTube-VOS save object masks: --classes davis reads "
            "one object's mask, and a table of the classes its indices stand for, each in its colour there (its "
            "background black; --classes FILE), reads classes")


def _decode_palette(data: bytes, name: str, table: ClassTable) -> np.ndarray:
    idx, pal = palette_image(data, name)
    lab = table.check_labels(idx, name)
    colours = {c.id: c.colour for c in table.classes}
    for v in np.flatnonzero(np.bincount(lab.ravel(), minlength=256)):
        said = tuple(int(x) for x in pal[v])
        if said != colours[int(v)]:
            raise InputError(f"{name}: its palette colours index {v} {said}, the class table "
                             f"{table.name_of(int(v))!r} {colours[int(v)]} (another class table?)"
                             + _voc_palette_hint(idx, pal))
    return lab


def decode_label_png(data: bytes, name: str, table: ClassTable, *, limit: int | None = None) -> np.ndarray:
    """(H, W) uint8 class ids of an encoded label image (the module's three ways), ``name`` naming it in
    errors; ``limit`` the pixel limit (:func:`pcreg.validation.max_pixels`)."""
    from ..formats import check_image_bytes, decode_image

    check_image_bytes(data, name, limit=limit)
    check_lossless(data, name)
    if is_palette_png(data):
        return _decode_palette(data, name, table)
    img = decode_image(data, name, limit=limit)  # IMREAD_UNCHANGED: as the file stores it, BGR(A)
    if img.ndim == 2:
        return table.check_labels(stored_grey(data, img), name)
    if img.ndim == 3 and img.dtype == np.uint8 and img.shape[2] in (3, 4):
        if img.shape[2] == 4:
            if (img[:, :, 3] != 255).any() and not alpha_from_trns(data):
                kind = "grey" if data[:8] == PNG_SIGNATURE and data[25:26] == b"\x04" else "colour"  # 4: grey and alpha
                raise InputError(f"{name}: {kind} labels with transparent pixels (an alpha channel below 255)")
            img = img[:, :, :3]
        return table.ids_from_colours(np.ascontiguousarray(img[:, :, ::-1]), name)
    raise InputError(f"{name}: not a label image (class ids in one channel, a palette, or 8-bit RGB colours)")


def read_label_png(path: str | Path, table: ClassTable, *, limit: int | None = None) -> np.ndarray:
    """(H, W) uint8 class ids of the label image at ``path`` (:func:`decode_label_png`), a regular file
    no larger than the pixel limit allows."""
    from ..formats import RAISE_LIMIT, max_file_bytes, read_regular_file
    from ..validation import max_pixels

    lim = max_pixels(limit)
    data = read_regular_file(path, max_bytes=max_file_bytes(lim), what="image", hint=RAISE_LIMIT)
    return decode_label_png(data, str(path), table, limit=lim)
