"""Key labels as ``pcreg run`` reads them: a label image read through the run's class table, and the
table a run names (``--classes``, ``--mapping``) and keeps in its ``run.json``.

A label image is read three ways (:func:`pcreg.classes.png.decode_label_png`): class ids in one channel,
a palette PNG (values the ids, its colours the table's), or colours (each pixel in its class's table
colour, as CVAT's masks). pcreg's own label PNGs are palette PNGs in the table's colours, so a run's
output reads back as key labels. A grey image saved in colour (three equal channels) is read as grey
when its colours are not the table's.

``--mapping`` says how the files are coded when they are not the table's ids:

- ``none``: the table's ids (or its colours, or a palette in its colours); with ``camvid11``, also CamVid's
  own 32 classes' colours (its download's ``NAME_L.png``), grouped as ``camvid11``'s eleven
  (:data:`pcreg.classes.camvid32.CAMVID32`) when a colour is not the table's;
- ``camvid``: CamVid's twelve ids (or ``camvid11``'s colours, or CamVid's 32 classes'), mapped to ``lagr``'s ground, obstacle and
  unknown (:data:`pcreg.datasets.folder.CAMVID_MAPPING`); the table stays ``lagr``;
- ``davis``: an object mask, 0 the background and any other value (or palette index) the object: the
  ``davis`` table, whose ids are ``lagr``'s. ``--classes davis`` is the same.

A run names its table in its identity (``run.json``'s ``run.classes``, :func:`identity_classes`) only when
it is not the one its mapping implies (``lagr``, or ``davis`` with ``--mapping davis``), so that every
binary run's ``run.json`` stays as it was; readers of a run get its table from :func:`run_table`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..validation import check_unmasked
from .table import CAMVID11, DAVIS, DEFAULT_TABLE, ClassTable, listed_name

__all__ = ["check_labels", "MAPPINGS", "choose_table", "LabelCoding", "decode_key_labels", "read_key_labels", "object_values",
           "read_object_mask", "check_one_object", "identity_classes", "with_classes",
           "run_table", "all_unknown", "binary_table", "two_class_table", "lagr_ids", "TWO_CLASS_STEP"]

#: ``--mapping``'s values.
MAPPINGS: tuple[str, ...] = ("none", "camvid", "davis")


def choose_table(classes: str | None, mapping: str = "none") -> tuple[ClassTable, str]:
    """``(table, mapping)`` of ``--classes`` (None: not given) and ``--mapping``: ``--classes davis`` reads
    object masks as ``--mapping davis`` does, and ``--mapping davis`` names the ``davis`` table.
    Refused: ``--mapping camvid`` (CamVid's ids mapped to ``lagr``) with another table than ``lagr``, and
    ``--mapping davis`` with another than ``davis``."""
    from .files import class_table

    if mapping not in MAPPINGS:
        raise InputError(f"unknown --mapping {mapping!r}; choose one of {', '.join(MAPPINGS)}")
    if classes is None:
        return (DAVIS if mapping == "davis" else DEFAULT_TABLE), mapping
    table = class_table(classes)
    if table.agrees(DAVIS) and classes == "davis" and mapping == "none":
        mapping = "davis"
    if mapping == "camvid" and not table.agrees(DEFAULT_TABLE):
        raise InputError(f"--mapping camvid maps CamVid's ids to lagr's ground and obstacle, not to --classes "
                         f"{classes}; --classes camvid11 reads CamVid's eleven classes as they are")
    if mapping == "davis" and not table.agrees(DAVIS):
        raise InputError(f"--mapping davis reads an object mask (the davis table), not --classes {classes}")
    return table, mapping


@dataclass(frozen=True)
class LabelCoding:
    """How a run's label images are coded: ``classes`` (``--classes``: a built-in table's name or a table's
    file; None: not given) and ``mapping`` (``--mapping``: none, camvid or davis). Made, it holds the
    ``table`` :func:`choose_table` resolves and the ``mapping`` it reads with (``davis`` when ``classes``
    is ``davis``); a table or mapping that is none, or the two disagreeing, is an :class:`InputError`."""

    classes: str | None = None
    mapping: str = "none"
    table: ClassTable = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        table, mapping = choose_table(self.classes, self.mapping)
        object.__setattr__(self, "table", table)
        object.__setattr__(self, "mapping", mapping)


def object_values(data: bytes, name: str, *, limit: int | None = None) -> tuple[np.ndarray, bool]:
    """The values an object mask stores, and whether they are object ids, each object on its own (DAVIS 2017's,
    :func:`pcreg.classes.mappings.palette_objects`): a palette PNG's indices; a grey image's values, ids when it
    holds several values below 255 (:func:`_grey_ids`); a colour image's palette indices when its colours are
    several of DAVIS's palette (:func:`_colour_objects`), else its pixels that are not black as 1. A grey image
    saved in colour (three equal channels) is read as grey; a 16-bit grey one as 8-bit (:func:`_eight_bit`)."""
    from ..formats import check_image_bytes, decode_image
    from .png import alpha_from_trns, check_lossless, check_png_chunks, check_png_rows, is_palette_png, stored_grey

    check_image_bytes(data, name, limit=limit)
    check_lossless(data, name)  # a JPEG's edge is values 1, 2, ...: object pixels around the object
    if is_palette_png(data):
        import io

        from PIL import Image

        check_png_chunks(data, name)
        check_png_rows(data, name)
        try:
            with Image.open(io.BytesIO(data)) as im:
                im.load()
                return np.asarray(im.convert("P") if im.mode != "P" else im, dtype=np.uint8).copy(), True
        except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
            raise InputError(f"{name}: cannot decode image ({exc})") from None
    img = decode_image(data, name, limit=limit)
    if img.ndim == 2:
        img = stored_grey(data, img)  # a grey PNG of 1, 2 or 4 bits: its values, not libpng's widened ones
    if img.ndim == 3 and img.shape[2] == 4:  # an erased area keeps its colour under alpha 0: no mask to guess at
        if (img[:, :, 3] != np.iinfo(img.dtype).max).any() and not alpha_from_trns(data):
            raise InputError(f"{name}: an object mask with transparent pixels (an alpha channel below its maximum); "
                             "flatten it onto black, the background, first")
        img = np.ascontiguousarray(img[:, :, :3])
    if img.ndim == 3 and img.dtype == np.uint8 and (img[:, :, 1:3] == img[:, :, :1]).all():
        img = img[:, :, 0]  # grey saved in colour
    if img.ndim == 3:
        return _colour_objects(img, name)
    if img.dtype == np.uint16:
        img = _eight_bit(img, name)
    if img.dtype != np.uint8:
        raise InputError(f"{name}: an object mask must be an 8-bit image, got {img.dtype}")
    return img, _grey_ids(img, name)


def _eight_bit(values: np.ndarray, name: str) -> np.ndarray:
    """A 16-bit grey mask's values as 8-bit: as they are when none is above 255 (ids, or 0/255, saved in 16
    bits), 0 and 255 when it holds one value besides 0 (a 0/65535 mask: one object); other values above 255
    (object ids beyond DAVIS's 254, or a smoothed 0/65535 mask) are refused naming them."""
    top = int(values.max(initial=0))
    if top <= 255:
        return values.astype(np.uint8)
    present = np.unique(values)
    if present.size <= 2 and present[0] == 0:
        return np.where(values > 0, 255, 0).astype(np.uint8)
    raise InputError(f"{name}: a 16-bit mask of values {_listed(present[present > 0].tolist())}: not one object "
                     "(0 and one value) nor object ids up to 254; " + _SAVE_OBJECTS)


#: How to save several objects so that no reader guesses: DAVIS 2017's way.
_SAVE_OBJECTS = ("save several objects as a palette PNG (indices 1..N the objects, 0 the background, 255 void, as DAVIS "
                 "2017), or one object as 0 and 255")


def _listed(values) -> str:
    values = [str(v) for v in values]
    return ", ".join(values[:6]) + (f" and {len(values) - 6} more" if len(values) > 6 else "")


#: How far (px) from the object's 255 pixels a resized 0/255 mask's smoothed edge reaches: an object mask
#: enlarged up to 4 times with linear interpolation (or shrunk by area) grades its edge over at most 4 px.
SOFT_EDGE = 4


def _grey_ids(values: np.ndarray, name: str) -> bool:
    """Whether a grey mask's values are object ids, as a palette PNG's indices: when it holds two or more
    values between 1 and 254 (DAVIS 2017's objects saved as grey). One value (DAVIS 2016's 255, or another)
    is one object, as before; so is a 0/255 mask whose values between lie only on its edge, within
    :data:`SOFT_EDGE` px of a 255 pixel (resized: a smoothed edge, read as the object as before), or on parts of
    it at most 4 px across (shrunk: a kite's lines, read as the object; :func:`_edge_only`). Values below
    255 beyond that edge, beside 255, are refused, naming them, one such value as several: DAVIS 2017's
    objects with 255 void (one object's 1 with its void border, saved as grey), or a mask of other making,
    cannot be told apart. Without 255, a mask whose values below its largest, M, are three or more and lie only
    within :data:`SOFT_EDGE` px of M's pixels is a 0/M mask smoothed (blurred, or resized from a mask of 0 and
    M): one object, as with 255. Objects saved as grey ids 1..N would need three of them wholly within that edge of
    the last. A 0/M mask smoothed wider than that edge (:func:`_smoothed`) is refused, saying so: read as one object
    its edge would swell the object, read as ids each value of its edge would be an object of its own."""
    present = np.flatnonzero(np.bincount(values.ravel(), minlength=256))
    below = [int(v) for v in present if 0 < v < 255]
    if not below:
        return False
    if present[-1] < 255 and len(below) >= 4 and _edge_only(values, int(present[-1])):
        return False  # a 0/M mask smoothed (three or more values below M, on M's edge): one object, as with 255
    if present[-1] == 255 and _edge_only(values, 255, thin=True):
        return False  # a smoothed edge, and thin parts shrunk (a string, a pole): one object
    if _smoothed(values, [v for v in below if v < present[-1]], int(present[-1])):
        raise SmoothedMask(name, int(present[-1]))
    if present[-1] == 255:
        raise InputError(f"{name}: a grey mask of values 0, {_listed(below)} and 255, the values between beyond "
                         f"{SOFT_EDGE} px of the 255s (not a smoothed edge): "
                         f"object{'s' if len(below) > 1 else ''} {_listed(below)} with 255 void? "
                         "It is not assumed; " + _SAVE_OBJECTS)
    return len(below) > 1


def _smoothed(values: np.ndarray, between: list[int], top: int) -> bool:
    """Whether a grey mask whose values ``between`` 0 and its largest, ``top``, lie beyond :data:`SOFT_EDGE` px of
    ``top``'s pixels is a 0/``top`` mask smoothed wider than that (blurred, or resized more than 4 times): three or more
    values between, and no step from a pixel to the next larger than half of ``top`` (objects saved as ids 1..N step
    from each object to the background, 0, by its whole id)."""
    if len(between) < 3:
        return False
    v = values.astype(np.int16)
    steps = max(int(np.abs(np.diff(v, axis=0)).max(initial=0)), int(np.abs(np.diff(v, axis=1)).max(initial=0)))
    return 2 * steps <= top


class SmoothedMask(InputError):
    """A grey mask that is a 0/M mask smoothed wider than :data:`SOFT_EDGE` px (:func:`_smoothed`): neither one object
    nor objects by their ids are assumed. ``hint`` says what to do, for a refusal of the same file on other grounds."""

    def __init__(self, name: str, top: int) -> None:
        said = (f"values rising gradually from 0 to {top} over more than {SOFT_EDGE} px (a 0/{top} mask blurred, or "
                f"resized more than {SOFT_EDGE} times?)")
        advice = f"threshold it (values of {(top + 1) // 2} and more the object) and save it as 0 and 255"
        self.hint = f"it holds {said}: {advice}"
        super().__init__(f"{name}: a grey mask of {said}: neither one object nor one object per value is assumed; "
                         f"{advice}")


def _edge_only(values: np.ndarray, top: int, *, thin: bool = False) -> bool:
    """Whether every value of ``values`` between 0 and ``top`` lies within :data:`SOFT_EDGE` px of a ``top`` pixel;
    with ``thin``, or within half that of a 0 pixel: a part of the object thinner than the factor a 0/``top`` mask
    was shrunk by (a kite's lines, a pole) is values between all across, with no ``top`` beside it, where an object
    saved as a grey id has an inside, away from the background (one 5 px across or more)."""
    import cv2

    side = 2 * SOFT_EDGE + 1
    kernel = np.ones((side, side), np.uint8)
    between = (values > 0) & (values < top) & (cv2.dilate((values == top).astype(np.uint8), kernel) == 0)
    if thin and between.any():  # eroded away by a window of the edge's size: no pixel farther than it from a 0
        between &= cv2.erode((values > 0).astype(np.uint8), np.ones((3, 3), np.uint8), iterations=SOFT_EDGE // 2) > 0
    return not np.any(between)


def _colour_objects(img: np.ndarray, name: str) -> tuple[np.ndarray, bool]:
    """``(values, ids)`` of a colour mask (BGR(A), as decoded): colours all of DAVIS's palette (VOC's colour map,
    whose 255 (224, 224, 192) and white are void) are the palette's indices, read as a palette PNG's, so that
    a frame showing one of several objects still names it; else one colour besides black is one object (its
    pixels 1, as before), and several colours, one of them not of the palette, are refused naming it: one
    object drawn in several colours, or several objects?"""
    from .files import voc_colormap
    from .table import colour_ids

    union = (img[:, :, :3] != 0).any(axis=2).astype(np.uint8)
    if img.dtype != np.uint8:
        return union, False
    rgb = np.ascontiguousarray(img[:, :, 2::-1])
    colours = [(int(r), int(g), int(b)) for r, g, b in voc_colormap(256)] + [(255, 255, 255)]
    ids, miss = colour_ids(rgb, colours, [*range(256), 255])
    if miss is None:
        return ids, True
    if len(np.unique(rgb[union > 0], axis=0)) < 2:
        return union, False
    x, y, colour = miss
    raise InputError(f"{name}: a colour mask of several colours, {colour} (at x={x}, y={y}) none of DAVIS's "
                     "palette (VOC's colour map): one object or several? Neither is assumed; " + _SAVE_OBJECTS)


def read_object_mask(path: str | Path, *, limit: int | None = None) -> tuple[np.ndarray, bool]:
    """:func:`object_values` of the file at ``path`` (a regular file, no larger than the pixel limit allows)."""
    from ..formats import RAISE_LIMIT, max_file_bytes, read_regular_file
    from ..validation import max_pixels

    lim = max_pixels(limit)
    data = read_regular_file(path, max_bytes=max_file_bytes(lim), what="image", hint=RAISE_LIMIT)
    return object_values(data, str(path), limit=lim)


def _raw_values(data: bytes, name: str, *, limit: int | None) -> np.ndarray:
    """The values an object mask stores (:func:`object_values`)."""
    return object_values(data, name, limit=limit)[0]


def _one_object(data: bytes, name: str, *, limit: int | None) -> np.ndarray:
    """pcreg's labels of a one-object mask (``--mapping davis``): 1 the object, 0 the background, 2 a
    palette's void (255 beside other indices). A mask of several objects (DAVIS 2017's: a palette PNG, or its
    ids as grey values or its palette's colours, :func:`object_values`) is an :class:`InputError` naming the
    file and its object ids: merging them would follow none of them."""
    from .mappings import object_labels, palette_objects
    from .png import is_palette_png

    values, by_id = object_values(data, name, limit=limit)
    if not by_id:
        return object_labels(values)
    ids, void = palette_objects(values)
    if len(ids) > 1:
        kind = "palette indices" if is_palette_png(data) else "object ids"
        raise InputError(f"{name}: a mask of {len(ids)} objects ({kind} {', '.join(map(str, ids))}, as DAVIS 2017 "
                         "stores them); --classes davis follows one object and would merge them: save one mask "
                         "per object (0 the background, 255 the object) and run once for each")
    return object_labels(values, ids[0] if ids else None, void)


def check_one_object(paths) -> None:
    """An :class:`InputError` when the object masks at ``paths`` (a folder of key frames' masks, ``--classes davis``)
    name different objects by their ids (palette indices, or the palette's colours: YouTube-VOS saves a mask of an
    object that enters later with its own index, and DAVIS 2017 each object with its own): the run follows one
    object, and masks of two would be carried into each other. A mask that names no id (0/255, one grey value,
    one colour of no palette) is any object's."""
    from .mappings import VOID_INDEX, palette_objects

    named: dict[int, Path] = {}
    for path in paths:
        values, by_id = read_object_mask(path)
        ids = palette_objects(values)[0] if by_id else ()
        for k in (int(k) for k in ids if k != VOID_INDEX):  # a palette's 0/255 is DAVIS 2016's one object
            if named and k not in named:
                a, first = next(iter(named.items()))
                raise InputError(f"{path}: object {k}, where {first.name} shows object {a}: the key frames' masks "
                                 "follow one object; give each object's masks in a folder of their own (0 the "
                                 "background, 255 the object) and run once for each")
            named.setdefault(k, Path(path))


def _through_table(data: bytes, name: str, table: ClassTable, *, limit: int | None) -> np.ndarray:
    """Class ids of ``table`` (:func:`~pcreg.classes.png.decode_label_png`), a grey image saved in colour
    read as grey, a photograph refused with what labels are."""
    from ..formats import decode_image
    from .png import decode_label_png
    from .table import NoClassColour

    try:
        return decode_label_png(data, name, table, limit=limit)
    except NoClassColour as exc:  # a colour image's colour that is no class's (never a palette's or a grey value)
        img = decode_image(data, name, limit=limit)
        if img.ndim == 3 and (img[:, :, 1:3] == img[:, :, :1]).all():
            return table.check_labels(img[:, :, 0], name)
        _check_nearly_grey(img, name, table)
        if table.agrees(CAMVID11):  # CamVid's own 32 classes' colours (its download's NAME_L.png), as camvid11's
            return _camvid32(img, name)
        raise InputError(f"{exc}; labels are class ids in a single-channel image, a palette PNG, or the class "
                         f"table's colours{_camvid_colours_hint(img, name)}") from None


def _check_nearly_grey(img: np.ndarray, name: str, table: ClassTable) -> None:
    """An :class:`InputError` when a colour label image is grey, its values ids of ``table`` (class ids saved in
    colour), but for at most one pixel in a thousand: those are named, not the first grey pixel whose value is no
    class's colour."""
    if img.ndim != 3 or img.shape[2] < 3:
        return
    mask = (img[:, :, 1:3] != img[:, :, :1]).any(axis=2)
    odd = np.argwhere(mask)
    grey = img[:, :, 0][~mask]
    ids = {c.id for c in table.classes}
    if 0 < len(odd) <= img.shape[0] * img.shape[1] // 1000 and grey.size and all(int(v) in ids for v in np.unique(grey)):
        y, x = (int(v) for v in odd[0])
        raise InputError(f"{name}: grey (class ids saved as colour) but for {len(odd)} pixel(s), the first at x={x}, "
                         f"y={y} {tuple(int(v) for v in img[y, x, 2::-1])}: set them to their class's id")


def _camvid_colours_hint(img: np.ndarray, name: str) -> str:
    """What a refusal of a colour label image adds when its colours are CamVid's (its 32 classes', as its download's
    ``NAME_L.png``, or ``camvid11``'s): the options that read them."""
    try:
        _camvid32(img, name)
    except InputError:
        return ""
    return ("; its colours are CamVid's: --classes camvid11 reads its classes (pcreg run's --mapping camvid, and "
            "--data camvid:, read them as ground and obstacle)")


def _camvid32(img: np.ndarray, name: str) -> np.ndarray:
    """``camvid11`` ids of a colour label image (BGR(A), opaque) whose colours are CamVid's 32 classes' or
    ``camvid11``'s (:func:`pcreg.classes.camvid32.camvid32_ids`: what ``camvid11`` names is read as it
    names it); an :class:`InputError` naming ``name``, the first colour of neither and its pixel."""
    from .camvid32 import camvid32_ids

    try:
        return camvid32_ids(np.ascontiguousarray(img[:, :, 2::-1]), name)
    except InputError as exc:
        raise InputError(f"{exc}; labels are class ids in a single-channel image, a palette PNG, or the class "
                         "table's colours") from None


def decode_key_labels(data: bytes, name: str, table: ClassTable, mapping: str = "none", *,
                      limit: int | None = None) -> np.ndarray:
    """(H, W) uint8 class ids of ``table`` of an encoded label image ``name`` coded as ``mapping`` says
    (the module's docstring); one line naming ``name`` for a value or colour that is no class."""
    from .mappings import MASK_HINT, mapping_lut, mask_hint

    if mapping == "davis":
        return _one_object(data, name, limit=limit)
    if mapping == "camvid":
        try:
            raw = _through_table(data, name, CAMVID11, limit=limit)
        except InputError as exc:
            own = _own_labels(data, name, table, limit=limit)  # pcreg run's own label PNG: the table's ids already
            if own is None:
                raise exc from None
            return own
        lut = mapping_lut("camvid")
        assert lut is not None
        return lut[raw]
    try:
        return _through_table(data, name, table, limit=limit)
    except InputError as exc:
        hint = ""
        if "label value" in str(exc):
            try:
                hint = mask_hint(_raw_values(data, name, limit=limit))
            except SmoothedMask as smoothed:
                hint = f"; {smoothed.hint}"
            except InputError:
                hint = ""
        mask = hint.startswith(MASK_HINT) and table.n_known == 2  # a DAVIS mask under a two-class table of one's own
        if hint and (table.agrees(DEFAULT_TABLE) or mask):
            raise InputError(f"{exc}{hint}") from None
        raise


def _own_labels(data: bytes, name: str, table: ClassTable, *, limit: int | None) -> np.ndarray | None:
    """The class ids of a label image in ``table``'s colours, a palette PNG as pcreg writes its labels (``--mapping
    camvid`` writes ground and obstacle in ``lagr``'s) or saved again in RGB by an editor: a run's label PNG read
    back as a key frame's; None for any other image."""
    from .png import decode_label_png

    try:
        return decode_label_png(data, name, table, limit=limit)
    except InputError:
        return None


def read_key_labels(path: str | Path, table: ClassTable, mapping: str = "none", *,
                    limit: int | None = None) -> np.ndarray:
    """:func:`decode_key_labels` of the file at ``path`` (a regular file, no larger than the pixel limit
    allows)."""
    from ..formats import RAISE_LIMIT, max_file_bytes, read_regular_file
    from ..validation import max_pixels

    lim = max_pixels(limit)
    data = read_regular_file(path, max_bytes=max_file_bytes(lim), what="image", hint=RAISE_LIMIT)
    return decode_key_labels(data, str(path), table, mapping, limit=lim)


def binary_table(table: ClassTable) -> bool:
    """Whether ``table``'s ids are ``lagr``'s, two known classes 0 and 1 and the unknown 2 (``lagr``, ``davis``, a
    labelmap.txt of two classes): labels the two-class step takes as they are. A table of two known classes in other
    ids (5 and 9, or an unknown 255) runs the same step through :func:`lagr_ids` (:func:`two_class_table`)."""
    return table.known_ids == (0, 1) and table.unknown == 2


def two_class_table(table: ClassTable) -> bool:
    """Whether ``table`` has two known classes, whatever their ids: its labels are propagated by the two-class step
    (ground and obstacle), its ids mapped to ``lagr``'s on the way in and back on the way out (:func:`lagr_ids`).
    A table of more classes is labelled by the many-class step in its own ids."""
    return table.n_known == 2


def lagr_ids(table: ClassTable) -> np.ndarray | None:
    """(3,) uint8: the ids of ``table`` that the two-class step's 0, 1 and 2 stand for, its two known classes in id
    order and its unknown (road 5, car 9, void 255: ``[5, 9, 255]``); None for a table whose ids are ``lagr``'s
    (:func:`binary_table`) or of more than two known classes. ``lut = np.full(256, 2); lut[ids] = 0, 1, 2`` maps
    the table's labels in."""
    if binary_table(table) or not two_class_table(table):
        return None
    return np.array([*sorted(table.known_ids), table.unknown], np.uint8)


#: What a run's identity (run.json's ``run``) says of a table of two known classes in other ids than ``lagr``'s
#: (``"step"``): it is labelled by the two-class step. Such a run begun when the many-class step labelled it (without
#: the field) is not continued: its label files, carry and steps would mix the two steps' outputs.
TWO_CLASS_STEP = "two-class"


def all_unknown(labels: np.ndarray, table: ClassTable) -> bool:
    """Whether every pixel of ``labels`` is the table's unknown (nothing to fit or propagate)."""
    return bool((np.asarray(labels) == table.unknown).all())


def identity_classes(table: ClassTable, mapping: str) -> dict | None:
    """What a run's identity says of its table: None when it is the one ``mapping`` implies (``lagr``;
    ``davis`` with ``--mapping davis``), else the table's JSON form (:func:`~pcreg.classes.files.table_json`)."""
    from .files import table_json

    implied = DAVIS if mapping == "davis" else DEFAULT_TABLE
    if table.agrees(implied) and table.unknown_class.name == implied.unknown_class.name:
        return None
    return json.loads(table_json(table))


def with_classes(identity: dict, table: ClassTable, mapping: str) -> dict:
    """``identity`` (a run's, :func:`pcreg.runs.state.run_identity`) naming ``table`` as ``classes`` when
    :func:`identity_classes` says it must, and, for a table of two known classes in other ids than ``lagr``'s,
    its step (``"step": "two-class"``, :data:`TWO_CLASS_STEP`); a new dict."""
    named = identity_classes(table, mapping)
    out = dict(identity) if named is None else {**identity, "classes": named}
    if lagr_ids(table) is not None:
        out["step"] = TWO_CLASS_STEP
    return out


def run_table(identity: dict | None, where: str = "run.json's classes") -> ClassTable:
    """The class table of a run whose identity (``run.json``'s ``run``) is ``identity``: the one it names
    (:func:`identity_classes`), its source ``where`` (the run.json's path, for messages), else the one its
    mapping implies. A table there that is not one is an :class:`InputError` naming ``where``."""
    from .files import parse_table_json

    identity = identity or {}
    named = identity.get("classes")
    if named is None:
        return DAVIS if identity.get("mapping") == "davis" else DEFAULT_TABLE
    return parse_table_json(json.dumps(named), where)


def check_labels(labels, shape, table=None) -> np.ndarray:
    """(H, W) uint8 key labels, checked: of ``shape`` (when given), and each value a class of ``table``
    (a :class:`~pcreg.classes.ClassTable`; None: 0 ground, 1 obstacle, 2 unknown). Always an array of its own,
    never ``labels`` itself: a stream keeps it, and its caller may write the next labels into the same array."""
    check_unmasked(labels, "labels")
    lab = np.asarray(labels)
    if lab.ndim == 3 and lab.shape[2] in (1, 3, 4):
        if lab.shape[2] > 1 and not (np.array_equal(lab[:, :, 0], lab[:, :, 1]) and np.array_equal(lab[:, :, 0], lab[:, :, 2])):
            raise InputError(f"labels of shape {lab.shape} whose channels differ: a colour label image, not class ids; "
                             "give (H, W) ids, or the colours' ids by the class table (ClassTable.ids_from_colours)")
        lab = lab[:, :, 0]  # ids saved as grey in three channels (and an alpha)
    if lab.ndim != 2:
        raise InputError(f"labels must be an (H, W) array, got shape {lab.shape}")
    if shape is not None and lab.shape != tuple(shape):
        raise InputError(f"labels of shape {lab.shape} for an image of shape {tuple(shape)}")
    if not (np.issubdtype(lab.dtype, np.integer) or lab.dtype == np.bool_):
        ids = "0 ground, 1 obstacle, 2 unknown" if table is None else f"the ids of {table.source or 'the class table'}"
        raise InputError(f"labels must be integers ({ids}), got {lab.dtype}")
    if table is not None and not binary_table(table):
        return np.array(table.check_labels(lab, "the key frame's labels"))  # the table's check keeps a uint8 array
    if lab.size and (lab.min() < 0 or lab.max() > 2):
        bad = int(lab.min()) if lab.min() < 0 else int(lab.max())
        names = ("ground", "obstacle", "unknown") if table is None else tuple(map(table.name_of, (0, 1, 2)))
        hint = "; a 0/255 mask's 255 is the object: give (mask > 0) as uint8" if bad == 255 and names[1] == "object" else ""
        raise InputError(f"labels must be 0 ({names[0]}), 1 ({names[1]}) or 2 ({names[2]}); found {bad}{hint}")
    return lab.astype(np.uint8)


def check_key_classes(labels: np.ndarray, table, fitted) -> np.ndarray:
    """``labels`` (checked by :func:`check_labels`) as a stream's key frame, or an :class:`InputError` for labels its
    classifier cannot label: no known label, or a class outside ``fitted`` (the class ids it was fitted on; None: a
    classifier of two classes), which no step would give a pixel, and no word said so."""
    unknown = 2 if table is None else table.unknown
    present = np.flatnonzero(np.bincount(labels.ravel(), minlength=256))
    if not (present != unknown).any():
        raise InputError(f"the key frame's labels are all unknown ({unknown}): nothing to propagate")
    missing = [] if fitted is None or table is None else [int(c) for c in present if c != unknown and c not in fitted]
    if missing:
        named = ", ".join(f"{listed_name(table.name_of(c))} (id {c})" for c in missing)
        raise InputError(f"the key frame's labels hold {named}, which the classifier was not fitted on: no frame would "
                         "be labelled so; fit it on frames that show it (Propagator.from_key_frame of this key frame "
                         "fits one on it)")
    return labels
