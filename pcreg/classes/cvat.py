"""Key frames a person drew in CVAT, exported as "Segmentation mask 1.1": ``pcreg run --labels EXPORT.zip``
(or the unpacked folder).

The export is the Pascal VOC segmentation layout (CVAT's format page, docs.cvat.ai "Segmentation Mask";
written by Datumaro's VOC exporter)::

    EXPORT.zip
    ├── labelmap.txt                        # name:R,G,B:parts:actions, the class table
    ├── ImageSets/Segmentation/default.txt  # the frames' names, without extension
    ├── SegmentationClass/NAME.png          # each pixel in its class's colour (RGB), black unlabelled
    └── SegmentationObject/NAME.png         # instances (not read)

The class table is the ``labelmap.txt``'s (:func:`pcreg.classes.files.parse_labelmap`); with ``--classes``
too, the two must list the same classes (names and colours) and the ids are ``--classes``'s: a label map holds
no ids. A mask is read through the table's colours (RGB, or a palette PNG's colours);
a one-channel mask holds each pixel's line in ``labelmap.txt``. A mask names its frame by its file's stem:
the frame of that stem, else ``frame_NNNNNN`` (CVAT's name of a video's frame N, and of the N-th image of a
task) the source's frame N, where the run chose it (``--start``, ``--every``). A mask that is all
background is a frame nobody drew on, not a key frame; every mask has the frames' size, drawn on or not (told
from its header, before its pixels are inflated: a small archive of large black masks is no burden).

An archive is read in memory, never unpacked: members are looked up by name (Windows's ``\\`` separators
read as ``/``, UTF-8 names read as UTF-8 whether or not the archive flags them so), a name that climbs out of
the archive (``..``, an absolute path), two members of one name, or two whose data overlap (a zip bomb that
inflates one block of data under many names) are refused, and every member's size is bounded before it is read
(:data:`MAX_MEMBERS`, the pixel limit's file size; ``labelmap.txt`` a class table's); a mask's first bytes are
read first, so that a member that is no image, or a PNG larger than the pixel limit, is refused before the
rest is inflated, and a PNG is read to no more bytes than its pixels can take. An archive whose members all lie in one folder holding the export (an export zipped with its
folder around it) is read inside that folder, or in the one folder inside it, and so on (an export zipped with the
folders of its path), and so is such an archive unpacked (a folder holding only the folder of the export, or only
a folder holding only that folder); the ``__MACOSX/`` folder that macOS's Finder adds to an archive it makes is left out.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import unicodedata
import zipfile
import zlib
from pathlib import Path, PurePosixPath

import numpy as np

from ..errors import InputError
from .files import LABELMAP_FILE
from .table import ClassTable

__all__ = ["CLASS_DIR", "MAX_MEMBERS", "is_cvat_export", "wrapped_export", "CvatExport", "read_cvat_keys",
           "outside_chosen", "left_out_note", "outside_text", "source_indices",
           "chosen_around"]

#: The folder of class masks in the export.
CLASS_DIR = "SegmentationClass"
#: The most members an archive may list.
MAX_MEMBERS = 200_000
_FRAME = re.compile(r"frame_(\d{1,9})")
#: The most folders around an export, each holding nothing but the next, that it is read inside.
_MAX_WRAPPING = 16
#: The folder of file metadata macOS's Finder adds to an archive it makes (``__MACOSX/FOLDER/._NAME``): no
#: part of the export, and left out.
_MACOS_FORKS = "__MACOSX"
#: A member's general purpose flag that says its name is UTF-8 (zip's APPNOTE 4.4.4, bit 11).
_UTF8_FLAG = 0x800
#: A member's general purpose flag that says its data is encrypted (bit 0).
_ENCRYPTED = 0x1
#: The fewest bytes of a member's local header (zip's APPNOTE 4.3.7: 30 and its name).
_LOCAL_HEADER = 30
#: The bytes of a member read first, to know from its header what it is.
_HEAD = 1 << 16
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, ValueError, OSError)


def is_cvat_export(path: Path) -> bool:
    """Whether ``--labels path`` names a CVAT export: a ``.zip`` file (or a file that starts as a zip does, saved
    without its suffix), or a folder holding a ``SegmentationClass/`` folder, itself or in its one folder
    (:func:`wrapped_export`)."""
    p = Path(path)
    return (p.is_file() and (p.suffix.lower() == ".zip" or _zip_header(p))) or (p.is_dir() and (
        (p / CLASS_DIR).is_dir() or wrapped_export(p) is not None))


def _zip_header(path: Path) -> bool:
    """Whether the file starts as a zip archive does (a local file header, or the end record of an empty one)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) in (b"PK\x03\x04", b"PK\x05\x06")
    except OSError:
        return False


def wrapped_export(folder: Path) -> Path | None:
    """The folder in ``folder`` that holds an export (its ``SegmentationClass/``), when ``folder`` holds no export
    of its own and nothing but one folder, itself the export or holding nothing but one folder, and so on (hidden
    files and ``__MACOSX/`` left out): an archive of an export with its folders around it, unpacked, read as the
    archive is; else None."""
    for _ in range(_MAX_WRAPPING):
        if (folder / LABELMAP_FILE).exists() or (folder / CLASS_DIR).exists():
            return None
        try:
            inside = [p for p in folder.iterdir() if not p.name.startswith(".") and p.name != _MACOS_FORKS]
        except OSError:
            return None
        if len(inside) != 1 or not inside[0].is_dir():
            return None
        if (inside[0] / CLASS_DIR).is_dir():
            return inside[0]
        folder = inside[0]
    return None


def export_within(folder: Path, depth: int = 3) -> str:
    """What a refusal of ``--labels folder`` (no label PNG in it, no export of its own) adds when a CVAT export
    lies in a folder within it, at most ``depth`` levels down, beside other files (an export unpacked with its
    notes): where, to give ``--labels``; else ``""``."""
    level = [folder]
    for _ in range(depth):
        inner = []
        for d in level:
            with contextlib.suppress(OSError):
                inner += sorted(p for p in d.iterdir() if p.is_dir() and not p.is_symlink() and not p.name.startswith(".")
                                and p.name != _MACOS_FORKS)
        found = next((d for d in inner if (d / CLASS_DIR).is_dir()), None)
        if found is not None:
            return f"; a CVAT export lies in {found}: give --labels {found}"
        level = inner[:256]
    return ""


def _member_name(info: zipfile.ZipInfo) -> str:
    """A member's name as its maker meant it: UTF-8 bytes that the archive does not flag as UTF-8 (as many tools
    write them; Python's zipfile decodes them as cp437, and no frame's name would match) read as UTF-8, and
    Windows's ``\\`` separators (Windows PowerShell's Compress-Archive writes them) as ``/``."""
    name = info.filename
    if not info.flag_bits & _UTF8_FLAG and not name.isascii():
        with contextlib.suppress(UnicodeError):
            name = name.encode("cp437").decode("utf-8")
    return name.replace("\\", "/")


def _safe_name(name: str) -> str | None:
    """A member's name as a relative POSIX path, or None when it climbs out (``..``, absolute, a drive)."""
    if name.startswith("/") or re.match(r"[A-Za-z]:", name) or "\0" in name:
        return None
    parts = PurePosixPath(name).parts
    if any(p in ("..", "") for p in parts):
        return None
    return "/".join(p for p in parts if p != ".")


class CvatExport(contextlib.AbstractContextManager):
    """The files of an export, a zip archive or a folder, by relative name (``labelmap.txt``,
    ``SegmentationClass/NAME.png``); a context manager."""

    def __init__(self, path: str | Path, *, max_bytes: int, max_pixels: int | None = None) -> None:
        self.path, self.max_bytes, self.max_pixels = Path(path), max_bytes, max_pixels
        self._zip: zipfile.ZipFile | None = None
        self._members: dict[str, zipfile.ZipInfo] = {}
        self._prefix = ""
        self._root = self.path
        if self.path.is_dir():  # an unpacked export, read inside its one folder as an archive is
            self._root = wrapped_export(self.path) or self.path
            return
        try:
            self._zip = zipfile.ZipFile(self.path)
            infos = self._zip.infolist()
        except _ZIP_ERRORS as exc:
            raise InputError(f"{self.path}: not a readable zip archive ({exc})") from None
        if len(infos) > MAX_MEMBERS:
            self.close()
            raise InputError(f"{self.path}: {len(infos)} members; a CVAT export of at most {MAX_MEMBERS} is read")
        for info in infos:
            given = _member_name(info)
            name = _safe_name(given)
            if name is None:
                self.close()
                raise InputError(f"{self.path}: member {info.filename!r} names a path outside the archive")
            if not given.endswith("/") and name.split("/", 1)[0] != _MACOS_FORKS:
                if name in self._members:  # which one a reader takes is its own choice: no silent winner
                    self.close()
                    raise InputError(f"{self.path}: two members named {name!r}")
                self._members[name] = info
        self._check_overlaps(infos)
        self._prefix = self._wrapping_folder()
        if self._prefix:  # an export zipped with its folder around it: read inside that folder
            self._members = {n[len(self._prefix):]: info for n, info in self._members.items() if n.startswith(self._prefix)}

    def _check_overlaps(self, infos: list[zipfile.ZipInfo]) -> None:
        """An :class:`InputError` when a member's compressed data runs into the next member's header: members
        that share their data inflate it again under each name, a bomb of a small archive."""
        assert self._zip is not None
        members = sorted(infos, key=lambda i: i.header_offset)
        for info, end in zip(members, [i.header_offset for i in members[1:]] + [self._zip.start_dir]):
            if info.header_offset + _LOCAL_HEADER + info.compress_size > end:  # its header and data, at the least
                self.close()
                raise InputError(f"{self.path}: member {info.filename!r} overlaps the next member's data (a zip bomb?)")

    def _wrapping_folder(self) -> str:
        """``"NAME/"`` when every member lies in one folder NAME that holds the export (its ``labelmap.txt``
        or ``SegmentationClass/``) and the archive's top holds neither; ``"NAME/INNER/"`` when NAME holds nothing
        but the folder INNER that holds it (an export zipped with the folders of its path, ``zip -r`` from above
        them), and so on; else ``""``."""
        prefix, names = "", list(self._members)
        for _ in range(_MAX_WRAPPING + 1):
            if LABELMAP_FILE in names or any(n.startswith(f"{CLASS_DIR}/") for n in names):
                return prefix
            tops = {n.split("/", 1)[0] + "/" if "/" in n else "" for n in names}
            if len(tops) != 1 or "" in tops:
                return ""
            top = tops.pop()
            prefix, names = prefix + top, [n[len(top):] for n in names]
        return ""

    def names(self, folder: str) -> list[str]:
        """The ``.png`` files in ``folder`` and its sub-folders (a task made from nested folders of frames puts
        its masks there), by relative name, in name order; hidden ones left out. In a folder, every entry of such a
        name, a file or not (a folder, a FIFO, a link to a device), for :meth:`read` to refuse those that are not."""
        if self._zip is None:
            d = self._root / folder
            return sorted(p.relative_to(self._root).as_posix() for p in d.rglob("*")
                          if p.suffix.lower() == ".png" and not p.name.startswith(".")) if d.is_dir() else []
        return sorted(n for n in self._members if n.startswith(f"{folder}/")
                      and n.lower().endswith(".png") and not n.rsplit("/", 1)[1].startswith("."))

    def inner_archive(self) -> str:
        """What a refusal of an archive with no export in it adds when it holds a zip archive (an export zipped
        again, or with others): which one, to give ``--labels`` once taken out; or an export in a folder beside
        other files (a ``task_7/`` beside a README.txt), which it names with them; else ``""``."""
        inner = sorted(n for n in self._members if n.lower().endswith(".zip"))
        if inner:
            return (f"; it holds {inner[0]}{f' and {len(inner) - 1} more archive(s)' if len(inner) > 1 else ''}, an "
                    "archive in the archive: take the export out and give it to --labels")
        deeper = sorted((n for n in self._members if n.endswith(f"/{LABELMAP_FILE}") or f"/{CLASS_DIR}/" in n),
                        key=lambda n: (n.count("/"), n))
        if self._zip is None or not deeper:
            return ""
        folder = deeper[0].split(f"/{CLASS_DIR}/")[0] if f"/{CLASS_DIR}/" in deeper[0] else deeper[0].rsplit("/", 1)[0]
        beside = sorted(n for n in self._members if not n.startswith(f"{folder}/"))
        return (f"; the export lies in {folder}/, beside {beside[0]}{f' and {len(beside) - 1} more' if len(beside) > 1 else ''}: "
                "an export in a folder is read when nothing else lies beside that folder (unpack it and give "
                f"--labels the folder {folder})") if beside else ""

    def has(self, name: str) -> bool:
        """Whether the export holds ``name``: in a folder, any entry of that name (:meth:`read` refuses one that
        is no regular file, saying what it is)."""
        p = self._root / name
        return os.path.lexists(p) if self._zip is None else name in self._members

    def where(self, name: str) -> str:
        """How an error names a member: ``EXPORT.zip:NAME`` or the file's path."""
        return str(self._root / name) if self._zip is None else f"{self.path}:{self._prefix}{name}"

    def read(self, name: str, *, max_bytes: int | None = None, what: str = "a label image") -> bytes:
        """The bytes of ``name``, no more than ``max_bytes`` (default the export's; read so, whatever the
        archive declares); ``what`` the file is, for the message of one too large."""
        from ..formats import read_regular_file

        limit = self.max_bytes if max_bytes is None else max_bytes
        if self._zip is None:
            return read_regular_file(self._root / name, max_bytes=limit, what="CVAT export file")
        info = self._members[name]
        if stat.S_ISLNK(info.external_attr >> 16):  # its data is the path it points to, which is not followed
            raise InputError(f"{self.where(name)}: a symbolic link in the archive, not a file; zip the export's files")
        if info.flag_bits & _ENCRYPTED:
            raise InputError(f"{self.where(name)}: encrypted (the archive has a password); zip the export without one")
        if info.file_size > limit:
            raise InputError(f"{self.where(name)}: {info.file_size} bytes, more than the {limit} {what} may have")
        try:
            with self._zip.open(info) as fh:
                data = fh.read(min(_HEAD, limit + 1))
                if max_bytes is None and len(data) == _HEAD:  # an image: its header first
                    limit = self._image_bound(data, name, limit)
                data += fh.read(limit + 1 - len(data))
        except InputError:
            raise
        except _ZIP_ERRORS as exc:
            raise InputError(f"{self.where(name)}: unreadable in the archive ({exc})") from None
        if len(data) > limit:
            raise InputError(f"{self.where(name)}: larger than the {limit} bytes {what} may have")
        return data

    def _image_bound(self, head: bytes, name: str, limit: int) -> int:
        """The most bytes a member whose first bytes are ``head`` may have: a PNG's for its declared pixels
        (a PNG larger than the pixel limit, or a member that is no image, refused before it is inflated)."""
        from ..formats import check_image_bytes, image_size, max_file_bytes

        found = image_size(head)
        if found is None or found[0] == "PNG":
            w, h = check_image_bytes(head, self.where(name), limit=self.max_pixels)
            return min(limit, max_file_bytes(w * h))
        return limit

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()

    def __exit__(self, *exc) -> None:  # entering gives the export itself (AbstractContextManager)
        self.close()


def _table(export: CvatExport, classes: str | None) -> tuple[ClassTable, ClassTable, list[int]]:
    """The export's table (``labelmap.txt``; with ``--classes`` too, they must agree), the same table in the
    colours its masks hold (``--classes``'s as pcreg's export writes it, where that recoloured it:
    :func:`_named_table`) and each labelmap line's class id, in the file's order (for one-channel masks)."""
    from .files import MAX_TABLE_BYTES, class_table, labelmap_lines, parse_labelmap
    if not export.has(LABELMAP_FILE):
        if classes is None:
            raise InputError(f"{export.where(LABELMAP_FILE)}: missing (the export's class table; or name one with "
                             f"--classes){export.inner_archive()}")
        table = class_table(classes)
        return table, table, [table.unknown, *table.known_ids]
    try:
        text = export.read(LABELMAP_FILE, max_bytes=MAX_TABLE_BYTES, what="a class table").decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{export.where(LABELMAP_FILE)}: not UTF-8 text") from None
    read = parse_labelmap(text, export.where(LABELMAP_FILE))
    table = read if classes is None else class_table(classes)
    coloured = read if classes is None else _named_table(table, f"--classes {classes}", read, export.where(LABELMAP_FILE))
    colour_of = {c.name: c.colour for c in read.classes}
    id_of = {c.colour: c.id for c in coloured.classes}  # a colour is one class's in both tables
    order = [id_of[colour_of[ln.split(":")[0].strip()]] for ln in labelmap_lines(text)
             if ln.strip() and not ln.strip().startswith("#")]
    return table, coloured, order


def _named_table(given: ClassTable, given_where: str, read: ClassTable, where: str) -> ClassTable:
    """``given`` (``--classes``) in the colours of the export's label map ``read`` when that lists the same classes
    by name and colour and the same colour for the unknown, whatever their order, or the colours pcreg's export
    writes ``given`` in (:func:`~pcreg.classes.files.cvat_table`: its unknown black, a black known class in a colour of its
    own), so that a run's own export reads back under its own table: a label map holds no ids, so the ids are
    ``given``'s (a table whose unknown is 0, as ADE20K's, or whose ids have gaps, reads back as itself).
    Else an :class:`InputError` naming ``where`` and a class that one of them lacks."""
    from .files import cvat_table

    theirs = {(c.name, c.colour) for c in read.known}
    for coloured in (given, cvat_table(given)):
        if {(c.name, c.colour) for c in coloured.known} == theirs and coloured.unknown_class.colour == read.unknown_class.colour:
            return coloured
    mine = {(c.name, c.colour) for c in given.known}
    if mine == theirs:
        how = f"the unknown is {given.unknown_class.colour} in one and {read.unknown_class.colour} in the other"
    else:
        name, colour = min(mine ^ theirs)
        how = f"class {name!r} {colour} is in {where if (name, colour) in theirs else given_where} only"
    raise InputError(f"{where}: its class table disagrees with {given_where}'s ({how})")


def _decode_mask(data: bytes, name: str, table: ClassTable, order: list[int], limit: int) -> np.ndarray:
    """A CVAT class mask's class ids: colours (RGB, or a palette's) through the table, one channel as
    labelmap lines."""
    from ..formats import check_image_bytes, decode_image
    from .png import alpha_from_trns, check_lossless, is_palette_png, palette_image, stored_grey

    check_image_bytes(data, name, limit=limit)
    check_lossless(data, name)  # a JPEG's colours at every edge are no class's: say so, not which colour
    if is_palette_png(data):
        idx, pal = palette_image(data, name)
        return table.ids_from_colours(pal[idx], name)
    img = decode_image(data, name, limit=limit)
    if img.ndim == 3 and img.dtype == np.uint8 and img.shape[2] in (3, 4):
        if img.shape[2] == 4 and (img[:, :, 3] != 255).any() and not alpha_from_trns(data):  # as a key label image
            raise InputError(f"{name}: a class mask with transparent pixels (an alpha channel below 255)")
        return table.ids_from_colours(np.ascontiguousarray(img[:, :, 2::-1]), name)
    if img.ndim == 2 and img.dtype in (np.uint8, np.uint16):  # 16-bit too, as a key label image's ids
        img = stored_grey(data, img)
        beyond = img[img >= len(order)]
        if beyond.size:
            raise InputError(f"{name}: value {int(beyond[0])} is no line of the labelmap.txt ({len(order)} classes)")
        return np.asarray(order, np.uint8)[img]
    raise InputError(f"{name}: not a class mask ({img.shape[2] if img.ndim == 3 else 1} channel(s) of {img.dtype}; "
                     "a mask is 8-bit RGB colours of labelmap.txt, or one channel of its lines)")


def _nfc(name: str) -> str:
    """``name`` in Unicode's composed form (NFC): macOS writes names decomposed (NFD: ``e`` and a combining accent for
    ``é``), so a zip made there, or labels copied from there, name a frame in other code points than the frame's file."""
    return unicodedata.normalize("NFC", name)


def frame_positions(frames, *, left_out: bool = True):
    """A function of a label file's stem to the position of the run's frame it names, or None: a folder's
    frame by its file's stem (or, where none has that stem, by the one stem that is the same text composed otherwise,
    :func:`_nfc`), any run's source frame ``i`` (counted before ``--start``/``--every``) by ``frame_NNNNNN`` (CVAT's
    names), and a video's by its index in digits (up to nine, as ``frame_NNNNNN``'s). A stem that names a frame file
    of the folder that the selection leaves out names no frame (None), never the source frame of its number: files
    numbered from 1 (``frame_000001.png``, as ffmpeg writes them) would put its labels on the next file. Not
    ``left_out``: such a stem read as CVAT's number all the same (what :func:`placed` tells two ways of naming by)."""
    s = frames.selection
    by_stem = {frames.stem(t): t for t in range(len(frames))} if frames.kind == "folder" else {}
    composed: dict[str, list[int]] = {}  # the composed form of each stem: the frames of that text
    for stem, t in by_stem.items():
        composed.setdefault(_nfc(stem), []).append(t)
    # the folder's frame files that the selection leaves out: a stem naming one names that file, never a number
    unchosen = {_nfc(p.stem) for p in getattr(frames, "files", ())} - set(composed) if frames.kind == "folder" else set()

    def source_index(i: int) -> int | None:
        if not s.chosen(i):
            return None
        t = (i - s.start) // s.every
        if frames.kind == "folder":
            return t if t < len(frames) else None
        return None if frames.declared is not None and i >= frames.declared else t

    def where(stem: str) -> int | None:
        if stem in by_stem:
            return by_stem[stem]
        if len(composed.get(_nfc(stem), ())) == 1:
            return composed[_nfc(stem)][0]
        if left_out and _nfc(stem) in unchosen:
            return None
        number = _frame_number(stem, frames.kind)
        return None if number is None else source_index(number)

    return where


def _frame_number(stem: str, kind: str) -> int | None:
    """The source frame a stem names by its number: CVAT's ``frame_NNNNNN``, or a video's (``kind``) index in digits
    (up to nine, as ``frame_NNNNNN``'s); None for another stem."""
    m = _FRAME.fullmatch(stem)
    if m is not None:
        return int(m.group(1))
    if kind != "folder" and stem.isascii() and stem.isdigit() and len(stem) <= 9:
        return int(stem)
    return None


def placed(frames, stems: list[str], source) -> list[int | None]:
    """The position of the run's frame that each label file's stem names (:func:`frame_positions`), or None;
    an :class:`InputError` naming ``source`` when the stems name frames two ways, some ``frame_NNNNNN`` by a
    frame file of that name and others by CVAT's frame number NNNNNN (frames numbered from 1, CVAT's from 0):
    one export would be read two ways, and a key frame placed one frame off."""
    where = frame_positions(frames)
    positions = [where(stem) for stem in stems]
    if frames.kind == "folder":
        # a stem that names a frame file left out of the selection is none of the run's frames, yet by its number it
        # may be one: the names are told two ways all the same
        numbered = frame_positions(frames, left_out=False)
        named_as = [numbered(stem) for stem in stems]
        names = {_nfc(frames.stem(t)) for t in range(len(frames))}
        by_name = [s for s, t in zip(stems, named_as) if t is not None and _nfc(s) in names and _FRAME.fullmatch(s)]
        by_number = [s for s, t in zip(stems, named_as) if t is not None and _nfc(s) not in names]
        if by_name and by_number:
            t = named_as[stems.index(by_number[0])]
            raise InputError(f"{source}: its label files name frames two ways: {by_name[0]} the frame file of that name, "
                             f"{by_number[0]} CVAT's frame number (the frame {frames.name(t)}), which count from "
                             "different first numbers; rename the frames or the label files so that one way names them all")
    return positions


def source_indices(frames):
    """A function of a label file's stem to the index of the source frame it names (before ``--start`` and ``--every``),
    None where it names none: a folder's frame file, CVAT's ``frame_NNNNNN`` or a video's index in digits, within
    the source. The folder's file names are looked up once, here."""
    total = len(frames.files) if frames.kind == "folder" else frames.declared
    files: dict[str, int] = {}
    if frames.kind == "folder":
        for i, p in enumerate(frames.files):
            files.setdefault(_nfc(p.stem), i)

    def index_of(stem: str) -> int | None:
        index = files.get(_nfc(stem))
        if index is None:
            index = _frame_number(stem, frames.kind)
        return None if index is None or (total is not None and index >= total) else index

    return index_of


def outside_chosen(frames):
    """A function of a label file's stem (naming no chosen frame) to whether it names a frame of the run's source
    (:func:`source_indices`) before ``--start`` or at or after ``--stop``. A run of one stretch of a long video leaves
    out such key labels (one folder or export holds the whole video's); a frame ``--every`` steps over, inside the
    stretch, is not outside it (its labels would be lost)."""
    s, index_of = frames.selection, source_indices(frames)

    def outside(stem: str) -> bool:
        index = index_of(stem)
        return index is not None and (index < s.start or (s.stop is not None and index >= s.stop))

    return outside


def chosen_around(frames, stem: str) -> str:
    """Where ``stem`` names a source frame inside the chosen stretch that ``--every`` steps over, ``; --every N
    chooses A and B around it`` (the chosen frames before and after it), for the refusal to say; else ``""``."""
    s = frames.selection
    index = source_indices(frames)(stem)
    if index is None or s.every == 1 or index < s.start or (s.stop is not None and index >= s.stop):
        return ""
    first = (index - s.start) // s.every
    n = len(frames) if frames.kind == "folder" else frames.count()
    around = [frames.stem(p) for p in (first, first + 1) if n is None or p < n]
    return (f"; --every {s.every} chooses {' and '.join(around)} around it: label one of those, or choose --start and "
            "--every so that it is chosen") if around else ""


def left_out_note(source, names: list[str], selection) -> str | None:
    """The note of a run that leaves out the key labels ``names`` of ``source`` (:func:`outside_chosen`); None
    for none."""
    if not names:
        return None
    n = len(names)
    return f"{source}: {n} key label{'s' if n > 1 else ''} of frames outside those chosen left out {outside_text(names, selection)}"


def outside_text(names: list[str], selection) -> str:
    """``(--start S --stop E): NAMES``, how the notes and refusals of key labels outside the chosen stretch end."""
    from ..validation import listed

    chosen = f"--start {selection.start}" + ("" if selection.stop is None else f" --stop {selection.stop}")
    return f"({chosen}): {listed(names)}"


def named_frames(frames) -> str:
    """How the run's frames are named: the first and the last."""
    n = len(frames) if frames.kind == "folder" else frames.count()
    first = frames.stem(0)
    if frames.kind == "folder":
        return f"{first} ... {frames.stem(len(frames) - 1)}"
    return f"{first} ... {frames.stem(n - 1)}" if n else f"{first} ..."


def read_cvat_keys(path: Path, frames, shape: tuple[int, int], classes: str | None = None, *,
                   mapping: str = "none", limit: int | None = None,
                   left_out: list[str] | None = None) -> tuple[ClassTable, dict[int, np.ndarray]]:
    """``(table, {position: labels})`` of the CVAT export at ``path`` (the module's docstring) for the run's
    ``frames`` (:mod:`pcreg.datasets.sources`), every key frame of ``shape`` (H, W). One line naming the
    file: a malformed archive or mask, a mask of another size than the frames (from its header, drawn on or not:
    its pixels are not inflated), a colour not in ``labelmap.txt``, masks whose names match no frame (saying how
    both are named), a labelled mask of no chosen frame, two masks of one frame, none drawn on. Given a ``left_out``
    list, a drawn mask of a frame outside the chosen stretch (:func:`outside_chosen`) is left out, its name added to
    the list, not refused."""
    from ..formats import check_image_bytes, max_file_bytes
    from ..validation import max_pixels

    if mapping != "none":
        raise InputError(f"--mapping {mapping}: the masks of a CVAT export ({path}) are read through its labelmap.txt")
    lim = max_pixels(limit)
    with CvatExport(path, max_bytes=max_file_bytes(lim), max_pixels=lim) as export:
        table, coloured, order = _table(export, classes)
        masks = export.names(CLASS_DIR)
        if not masks:
            raise InputError(f"{export.where(CLASS_DIR)}: no class mask (a CVAT 'Segmentation mask 1.1' export holds "
                             f"{CLASS_DIR}/NAME.png){export.inner_archive()}")
        stems = [PurePosixPath(m).stem for m in masks]
        positions = placed(frames, stems, path)
        index_of = source_indices(frames)
        if all(t is None for t in positions) and all(index_of(stem) is None for stem in stems):
            raise InputError(f"{path}: its masks are named {stems[0]} ... {stems[-1]}, the frames of "
                             f"{frames.path} {named_frames(frames)}: no mask names a frame")
        keys: dict[int, np.ndarray] = {}
        seen: dict[int, str] = {}
        outside = outside_chosen(frames)
        for m, t in zip(masks, positions):
            data = export.read(m)
            w, h = check_image_bytes(data, export.where(m), limit=lim)
            if (h, w) != shape:  # said from its header, before its pixels are inflated, drawn on or not
                raise InputError(f"{export.where(m)}: the mask is {w}x{h}, the frames {shape[1]}x{shape[0]}")
            lab = _decode_mask(data, export.where(m), coloured, order, lim)
            if (lab == table.unknown).all():
                continue  # a frame nobody drew on
            if t is None and left_out is not None and outside(PurePosixPath(m).stem):
                left_out.append(PurePosixPath(m).name)
                continue
            if t is None:
                raise InputError(f"{export.where(m)}: names no frame of {frames.path}"
                                 + ("" if frames.selection.to_dict() is None else " among those chosen")
                                 + chosen_around(frames, PurePosixPath(m).stem))
            if t in seen:
                raise InputError(f"{export.where(m)}: a second mask of the frame {frames.name(t)} (also {seen[t]})")
            keys[t], seen[t] = lab, m
    if not keys and left_out:
        raise InputError(f"{path}: every mask drawn on names a frame outside those chosen "
                         f"{outside_text(left_out, frames.selection)}")
    if not keys:
        raise InputError(f"{path}: every mask is background only: no key frame drawn")
    return table, {t: keys[t] for t in sorted(keys)}
