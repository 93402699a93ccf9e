"""A class table as a file: CVAT's ``labelmap.txt`` and a small JSON; and a table named on the command line.

``labelmap.txt`` is the label map of CVAT's "Segmentation mask 1.1" export, the Pascal VOC layout that
CVAT reads and writes through Datumaro (``VocLabelMap.parse_from_file`` / ``dump_to_file`` in
``datumaro/plugins/voc_format/format.py``)::

    # label:color_rgb:parts:actions
    background:0,0,0::
    road:128,64,128::

One class a line, ``name:R,G,B:parts:actions``; blank lines and lines starting with ``#`` skipped; parts
and actions (VOC's person layout) are read and ignored. The *background* is the class coloured
(0, 0, 0), else the one named ``background`` (Datumaro's ``find_background_label``): the pixels nobody
labelled, which CVAT's export paints black and adds a ``background`` line for. It is the table's unknown;
the other classes are known, with ids 0, 1, ... in the file's order, and the unknown's id follows them.
A file with no background gets one (``background``, black), as Datumaro's exporter adds it. A file whose
classes have no colours at all gets the VOC colour map's colours in order, as Datumaro gives them.

pcreg writes the unknown first, then the known classes in id order, every class under its own name and
colour (no extra ``background`` line beside the unknown); the unknown must be black, so that CVAT and
Datumaro take it for the background. A label map holds no ids: a table whose known ids are 0..K-1 and
whose unknown is K reads back as itself.

The JSON form (:func:`table_json`) keeps the ids::

    {"classes": [{"id": 0, "name": "ground", "colour": [34, 197, 94]}, ...], "unknown": 2}
"""

from __future__ import annotations

import errno
import json
import re
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from .table import MAX_CLASSES, TABLES, ClassTable, LabelClass
from ..formats import KeyWrittenTwice, NumberTooLong, loads_json
from ..validation import short_repr

__all__ = ["LABELMAP_FILE", "LABELMAP_HEADER", "labelmap_lines", "parse_labelmap", "read_labelmap", "labelmap_text", "write_labelmap",
           "parse_table_json", "table_json", "read_table_file", "class_table", "voc_colormap", "cvat_table"]

#: The label map's file name in a VOC / CVAT "Segmentation mask" archive.
LABELMAP_FILE = "labelmap.txt"
#: Its first line, as CVAT and Datumaro write it.
LABELMAP_HEADER = "# label:color_rgb:parts:actions"
#: The background's name and colour in CVAT's and Datumaro's label maps.
BACKGROUND = ("background", (0, 0, 0))
#: The most bytes a class table's file (a labelmap.txt, a JSON table) may have, inside a CVAT export too.
MAX_TABLE_BYTES = 1 << 20


def voc_colormap(n: int) -> np.ndarray:
    """(n, 3) uint8: the first ``n`` colours of Pascal VOC's colour map (bits of the index spread over R, G,
    B from the most significant bit down; 0 black, 1 (128, 0, 0), 2 (0, 128, 0), ...)."""
    from ..validation import check_int

    n = check_int(n, "n", lo=0)
    idx = np.arange(n, dtype=np.int64)
    out = np.zeros((n, 3), np.int64)
    for j in range(7, -1, -1):
        for c in range(3):
            out[:, c] |= ((idx >> c) & 1) << j
        idx >>= 3
    return out.astype(np.uint8)


def _colour(text: str, name: str, where: str) -> tuple[int, int, int]:
    parts = [p.strip() for p in text.split(",")]
    # decimal digits as CVAT writes them: int() alone would also take "1_0" and other scripts' digits, and refuse
    # more than 4300 digits with a ValueError of its own
    ok = all(p.isascii() and p.isdigit() and len(p.lstrip("0")) <= 3 for p in parts)
    rgb = tuple(int(p) for p in parts) if ok else ()
    if len(rgb) != 3 or any(v < 0 or v > 255 for v in rgb):
        raise InputError(f"{where}: class {short_repr(name)} has colour {short_repr(text)}, not R,G,B in 0..255")
    return rgb[0], rgb[1], rgb[2]


def labelmap_lines(text: str) -> list[str]:
    """A labelmap.txt's lines as Datumaro reads the file (a text file's line breaks: ``\\n``, ``\\r\\n``,
    ``\\r``), not as :meth:`str.splitlines` splits, which also breaks at U+0085, U+2028, U+2029 and a few
    control characters: a class name holding one would be read as two lines."""
    return re.split(r"\r\n|\r|\n", text)


#: What :meth:`str.splitlines` takes for a line break besides a text file's: a class name holding one is
#: refused, as pcreg never writes such a name (:class:`~pcreg.classes.table.ClassTable`).
_OTHER_BREAKS = "\v\f\x1c\x1d\x1e\x85\u2028\u2029"


def parse_labelmap(text: str, where: str) -> ClassTable:
    """The class table of a ``labelmap.txt``'s text (the module's rules); ``where`` names the file in
    errors: a line of more than four fields, a bad colour, two classes of one name or one colour, some
    classes with a colour and some without, fewer than two known classes."""
    entries: list[tuple[str, tuple[int, int, int] | None]] = []
    for n, raw in enumerate(labelmap_lines(text), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split(":")
        if len(fields) > 4:
            raise InputError(f"{where}: line {n} has {len(fields)} ':'-separated fields, not name:R,G,B:parts:actions")
        name = fields[0].strip()
        if not name:
            raise InputError(f"{where}: line {n} names no class")
        odd = next((ch for ch in name if ch in _OTHER_BREAKS), None)
        if odd is not None:
            raise InputError(f"{where}: line {n}: the class name {name!r} holds U+{ord(odd):04X}, a line break to "
                             "some readers; rename the label")
        if any(name == e[0] for e in entries):
            raise InputError(f"{where}: two classes named {name!r} (line {n})")
        colour = _colour(fields[1], name, where) if len(fields) > 1 and fields[1].strip() else None
        entries.append((name, colour))
    if not entries:
        raise InputError(f"{where}: no class (a labelmap.txt lists name:R,G,B:: lines)")
    given = [c for _, c in entries if c is not None]
    if not given:  # Datumaro: no colours at all, the VOC colour map's in order
        _no_colours_written(entries, where)
        entries = [(name, (int(r), int(g), int(b))) for (name, _), (r, g, b) in zip(entries, voc_colormap(len(entries)))]
    elif len(given) < len(entries):
        missing = next(name for name, c in entries if c is None)
        raise InputError(f"{where}: class {missing!r} has no colour (others have)")
    seen: dict = {}
    for name, colour in entries:
        if colour in seen:
            raise InputError(f"{where}: classes {seen[colour]!r} and {name!r} share the colour {colour}")
        seen[colour] = name
    background = next((i for i, (_, c) in enumerate(entries) if c == BACKGROUND[1]), None)
    if background is None:
        background = next((i for i, (name, _) in enumerate(entries) if name == BACKGROUND[0]), None)
    if background is None:
        entries.append(BACKGROUND)
        background = len(entries) - 1
    if len(entries) > MAX_CLASSES:  # the lines hold no ids: say how many classes, not which id is too large
        raise InputError(f"{where}: {len(entries)} classes (its background among them); a class table holds at most "
                         f"{MAX_CLASSES}, ids 0..{MAX_CLASSES - 1} of 8-bit labels")
    known = [e for i, e in enumerate(entries) if i != background]
    if len(known) < 2:  # a task of one label: its background is where nobody drew, no class of its own
        unsaid = "" if given else (f"; no line gives a colour, so its first class, {entries[background][0]!r}, took "
                                   "the VOC colour map's first, black, the background's, as Datumaro reads a table of "
                                   "names (a labelmap.txt lists name:R,G,B:: lines)")
        raise InputError(f"{where}: {len(known)} class(es) besides {entries[background][0]!r} (the pixels nobody "
                         "labelled, not a class); pcreg labels two or more: add a label for the rest (e.g. 'other') "
                         f"and draw it on the key frames{unsaid}")
    classes = [LabelClass(k, name, colour) for k, (name, colour) in enumerate(known)]  # type: ignore[arg-type]
    name, colour = entries[background]
    classes.append(LabelClass(len(known), name, colour))  # type: ignore[arg-type]
    return ClassTable(tuple(classes), len(known), where)


#: A class name that ends in three numbers of 0..255 (``road 128 64 128``, ``road,128,64,128``): a colour written
#: without the labelmap's ``:`` before it.
_COLOUR_IN_NAME = re.compile(r"(.*?\S)[\s,;]+(\d{1,3})[\s,;]+(\d{1,3})[\s,;]+(\d{1,3})")


def _no_colours_written(entries: list, where: str) -> None:
    """An :class:`InputError` for a table of names (no line holds a ``:``) one of which ends in a colour written
    without its ``:`` (:data:`_COLOUR_IN_NAME`): read as Datumaro reads it, the class would be named with its
    colour and coloured by the VOC colour map."""
    for name, _ in entries:
        m = _COLOUR_IN_NAME.fullmatch(name)
        if m is not None and all(int(v) <= 255 for v in m.groups()[1:]):
            raise InputError(f"{where}: the line {name!r} reads as a class named so, with no colour: a labelmap.txt "
                             f"line is name:R,G,B:parts:actions ('{m.group(1)}:{','.join(m.groups()[1:])}::')")


def _read_text(path: Path, what: str) -> str:
    from ..formats import image_size, read_regular_file
    from ..text_files import refuse_utf16

    data = read_regular_file(path, max_bytes=MAX_TABLE_BYTES, what=what)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        kind = ("; it is a zip archive (a CVAT export? its labelmap.txt is the table; --labels reads the export)"
                if data[:4] == b"PK\x03\x04" else "; it is an image, not a class table" if image_size(data) else "")
        if not kind:
            refuse_utf16(path, data)
        raise InputError(f"{path}: not UTF-8 text ({what}){kind}") from None
    if "\0" in text:  # UTF-16 without a byte-order mark decodes, a zero beside each character
        refuse_utf16(path, data)
    return text


def read_labelmap(path: str | Path) -> ClassTable:
    """The class table of a ``labelmap.txt`` file (:func:`parse_labelmap`)."""
    path = Path(path)
    return parse_labelmap(_read_text(path, "label map"), str(path))


def labelmap_text(table: ClassTable) -> str:
    """The ``labelmap.txt`` of ``table``: the header, the unknown, then the known classes in id order.

    Refused (:class:`InputError`) when the unknown is not black: CVAT and Datumaro would take another class,
    or an extra ``background`` they add, for the pixels left unlabelled."""
    if table.unknown_class.colour != BACKGROUND[1]:
        raise InputError(f"{table.source or 'class table'}: the unknown class {table.unknown_class.name!r} is "
                         f"{table.unknown_class.colour}; a labelmap.txt needs it black, CVAT's background")
    lines = [LABELMAP_HEADER] + [f"{c.name}:{','.join(map(str, c.colour))}::" for c in (table.unknown_class, *table.known)]
    return "\n".join(lines) + "\n"


def write_labelmap(path: str | Path, table: ClassTable) -> Path:
    """Write :func:`labelmap_text` to ``path`` atomically."""
    from ..outputs import atomic_write_bytes

    return atomic_write_bytes(path, labelmap_text(table).encode("utf-8"))


def table_json(table: ClassTable) -> str:
    """The JSON form of ``table`` (the module's docstring)."""
    doc = {"classes": [{"id": c.id, "name": c.name, "colour": list(c.colour)} for c in table.classes],
           "unknown": table.unknown}
    return json.dumps(doc, indent=1) + "\n"


def parse_table_json(text: str | dict, where: str) -> ClassTable:
    """The class table of :func:`table_json`'s text (or of the document already read from it); a class's
    ``id`` may be left out (its position); a key written twice in one object is refused, naming it."""
    try:
        doc = text if isinstance(text, dict) else loads_json(text, keys_once=True)
    except (KeyWrittenTwice, NumberTooLong) as exc:
        raise InputError(f"{where}: {exc}") from None
    except ValueError as exc:
        raise InputError(f"{where}: not JSON ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("classes"), list) or "unknown" not in doc:
        raise InputError(f'{where}: a class table is {{"classes": [{{"id", "name", "colour"}}, ...], "unknown": ID}}')
    classes = []
    for i, c in enumerate(doc["classes"]):
        if not isinstance(c, dict) or not {"name", "colour"} <= set(c) or not set(c) <= {"id", "name", "colour"}:
            odd = sorted(set(c) - {"id", "name", "colour"}, key=repr) if isinstance(c, dict) else []
            lacks = sorted({"name", "colour"} - set(c)) if isinstance(c, dict) else []
            said = "; ".join(filter(None, (f"it has {', '.join(map(repr, odd))}" if odd else "",
                                           f"it lacks {', '.join(map(repr, lacks))}" if lacks else "")))
            raise InputError(f"{where}: class {i} is not {{\"id\", \"name\", \"colour\"}}{f' ({said})' if said else ''}")
        colour = c["colour"]
        if not isinstance(colour, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in colour):
            raise InputError(f"{where}: class {short_repr(c.get('name'))} has colour {short_repr(colour)}, not [R, G, B] integers")
        classes.append(LabelClass(c.get("id", i), c["name"], tuple(colour)))
    unknown = doc["unknown"]
    if isinstance(unknown, str):  # the unknown class by name
        unknown = next((c.id for c in classes if c.name == unknown), unknown)
    return ClassTable(tuple(classes), unknown, where)


def read_table_file(path: str | Path) -> ClassTable:
    """A class table from a file: ``.json``, or any file whose text is a JSON object, a JSON table
    (:func:`parse_table_json`); anything else a ``labelmap.txt``; a folder, its ``labelmap.txt`` (an
    unpacked CVAT export)."""
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / LABELMAP_FILE
    if p.suffix.lower() == ".json":
        return parse_table_json(_read_text(p, "class table"), str(p))
    text = _read_text(p, "label map")
    doc, why = _json_object(text, str(p))
    if doc is not None:
        return parse_table_json(doc, str(p))
    try:
        return parse_labelmap(text, str(p))
    except InputError:
        if why is None:
            raise
        # a JSON table cut short or mistyped, not named .json: its JSON error, not a label map's
        raise InputError(f"{p}: neither a label map nor a JSON table (not JSON: {why})") from None


def _json_object(text: str, where: str) -> tuple[dict | None, str | None]:
    """``(doc, why)``: the JSON object ``text`` holds (a JSON table under another name than ``.json``) or None, and
    why a text that opens as a JSON object (``{``) is not JSON (else None); an :class:`InputError` naming ``where``
    for one that holds a key twice."""
    if not text.lstrip().startswith("{"):
        return None, None
    try:
        doc = loads_json(text, keys_once=True)
    except KeyWrittenTwice as exc:
        raise InputError(f"{where}: {exc}") from None
    except ValueError as exc:
        return None, str(exc)
    return (doc, None) if isinstance(doc, dict) else (None, None)


def class_table(spec: str | Path | ClassTable | None) -> ClassTable:
    """The table ``--classes`` names: a :class:`ClassTable` as it is, None the default (``lagr``), a
    built-in's name (:data:`~pcreg.classes.table.TABLES`), or a file (:func:`read_table_file`)."""
    from .table import DEFAULT_TABLE

    if spec is None:
        return DEFAULT_TABLE
    if isinstance(spec, ClassTable):
        return spec
    if not isinstance(spec, (str, os.PathLike)):
        raise InputError(f"classes must be a pcreg.classes.ClassTable, a built-in table's name ({', '.join(TABLES)}) "
                         f"or a table file's path, got {type(spec).__name__}")
    if isinstance(spec, str) and spec in TABLES:
        return TABLES[spec]
    if isinstance(spec, str) and not spec.strip():
        raise InputError(f"--classes {spec!r}: empty; name a built-in class table ({', '.join(TABLES)}) or a file")
    p = Path(spec).expanduser()
    try:
        found = p.exists()
    except ValueError:  # a zero byte in the name
        found = False
    except OSError as exc:  # a name too long for a file, else named (a folder that cannot be entered)
        if exc.errno != errno.ENAMETOOLONG:
            raise
        found = False
    if not found and isinstance(spec, str) and ("\n" in spec or spec.lstrip().startswith("{")):  # a table's text
        raise InputError(f"classes: the text of a class table ({short_repr(spec)}), not a table's name or file; read "
                         "it with pcreg.classes.parse_labelmap(text, where) or parse_table_json(text, where)")
    if not found:
        named = str(spec) if len(str(spec)) <= 120 else short_repr(str(spec))
        raise InputError(f"{named}: neither a built-in class table ({', '.join(TABLES)}) nor a file")
    return read_table_file(p)


def cvat_table(table: ClassTable) -> ClassTable:
    """``table`` as the archive writes it: its unknown class black, the background CVAT's import leaves
    unlabelled (a table whose unknown had another colour, a task's ``background`` of (10, 10, 10) say, was
    refused after its run was labelled). A known class in black (the background of a VOC palette, a class of its
    own under a table whose unknown is void) is written in the first colour of VOC's colour map that no known class
    has (the unknown's own, freed as it goes black, among them): it was refused after its run was labelled, and
    CVAT's import matches a class to the task's label by name, the colours only telling the archive's classes
    apart."""
    from dataclasses import replace

    black = BACKGROUND[1]
    if table.unknown_class.colour == black:
        return table
    free = None
    if any(c.colour == black for c in table.known):  # the unknown's own colour is freed by its going black
        # ids are 0-255 and one is the unknown's: black and at most 254 other known colours, of VOC's 255
        taken = {c.colour for c in table.known}
        free = next(rgb for rgb in (tuple(int(v) for v in c) for c in voc_colormap(256)[1:]) if rgb not in taken)

    def written(c):
        return replace(c, colour=black if c.id == table.unknown else free if c.colour == black else c.colour)

    return replace(table, classes=tuple(written(c) for c in table.classes))
