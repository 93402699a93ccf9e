"""How raw label values become a class table's ids: CamVid's twelve ids read as ground and obstacle
(``--mapping camvid``), and a DAVIS 0/255 object mask (``--mapping davis``)."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import InputError

__all__ = ["CAMVID_MAPPING", "DAVIS_MAPPING", "VOID_INDEX", "mapping_lut", "palette_objects", "object_labels", "mask_hint"]

# CamVid's 12 class ids -> LAGR labels (0 ground, 1 obstacle, 2 unknown); ../shared/data/README.md.
CAMVID_MAPPING: dict[int, int] = {
    0: 2,  # sky
    1: 1,  # building
    2: 1,  # pole
    3: 0,  # road
    4: 0,  # pavement
    5: 1,  # tree
    6: 1,  # sign symbol
    7: 1,  # fence
    8: 1,  # car
    9: 1,  # pedestrian
    10: 1,  # bicyclist
    11: 2,  # void
}


def mapping_lut(mapping: str | Mapping[int, int] | None) -> np.ndarray | None:
    """256-entry table raw id -> label, 255 for ids outside the mapping; None for identity on {0,1,2};
    ``"davis"``: 0 the background (0), every other value the object (1)."""
    if mapping is None:
        lut = np.full(256, 255, dtype=np.uint8)
        lut[:3] = (0, 1, 2)
        return lut
    if isinstance(mapping, str):
        if mapping.lower() not in ("camvid", "davis"):
            raise InputError(f"unknown label mapping {mapping!r} (use 'camvid', 'davis', a dict or None)")
        if mapping.lower() == "davis":
            mapping = DAVIS_MAPPING
        else:
            mapping = CAMVID_MAPPING
    if not isinstance(mapping, Mapping):
        raise InputError(f"mapping must be 'camvid', 'davis', a dict raw id -> label or None, got {type(mapping).__name__}")
    lut = np.full(256, 255, dtype=np.uint8)
    given: dict[int, object] = {}
    for raw, lab in mapping.items():
        r, c = _whole(raw), _whole(lab)
        if r is None or c is None or not (0 <= r <= 255) or c not in (0, 1, 2):
            raise InputError(f"mapping entry {raw!r} -> {lab!r}: raw ids are whole numbers 0..255, labels 0, 1 or 2")
        if r in given:
            raise InputError(f"mapping gives raw id {r} twice ({given[r]!r} and {raw!r})")
        given[r] = raw
        lut[r] = c
    return lut


def _whole(value) -> int | None:
    """``value`` as an int when it is a whole number (an int, a float without a fraction, or its decimal digits as
    text, as a JSON object's keys are); None otherwise (a fraction, a bool, anything else)."""
    if isinstance(value, (bool, np.bool_)):
        return None
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return int(value) if np.isfinite(value) and float(value).is_integer() else None
    if isinstance(value, str) and value.strip().isascii() and value.strip().isdigit():
        return int(value.strip()) if len(value.strip()) <= 3 else 256
    return None


#: A DAVIS mask's values as pcreg's labels: 0 the background (0), anything else the object (1).
DAVIS_MAPPING: dict[int, int] = {0: 0, **{v: 1 for v in range(1, 256)}}


#: A palette mask's void index (DAVIS 2017, VOC): pixels neither an object nor the background.
VOID_INDEX = 255


def palette_objects(values: np.ndarray) -> tuple[tuple[int, ...], int | None]:
    """``(object ids, void index)`` of a palette mask's indices (H, W): DAVIS 2017's objects 1..254 in
    increasing order, 0 the background and :data:`VOID_INDEX` void (None when the mask holds no void); a mask
    of 0 and 255 alone is DAVIS 2016's one object, 255 (void None)."""
    present = set(np.unique(np.asarray(values)).tolist()) - {0}
    if present <= {VOID_INDEX}:
        return tuple(sorted(present)), None
    return tuple(sorted(present - {VOID_INDEX})), (VOID_INDEX if VOID_INDEX in present else None)


def object_labels(values: np.ndarray, obj: int | None = None, void: int | None = None) -> np.ndarray:
    """pcreg's labels (H, W) uint8 of one object of a mask's ``values``: 1 where the value is ``obj`` (None:
    any value but 0), 2 where it is ``void``, 0 elsewhere (the background, and every other object)."""
    v = np.asarray(values)
    labels = ((v != 0) if obj is None else (v == obj)).astype(np.uint8)
    if void is not None:
        labels[v == void] = 2
    return labels


#: How :func:`mask_hint` begins for a 0/255 object mask.
MASK_HINT = "; it is a 0/255 object mask (DAVIS)"


def mask_hint(raw: np.ndarray) -> str:
    """What to say of label values that are not the default table's: when ``raw`` holds a 0/255 object mask,
    which mapping reads it; when it holds more classes, how to name their table."""
    values = np.unique(np.asarray(raw))
    if values.size <= 2 and set(values.tolist()) <= {0, 255}:
        return (f"{MASK_HINT}: pcreg run's --mapping davis reads it (0 the background, 255 the object), as --data "
                "davis: does")
    if values.size and int(values.max()) > 11:  # beyond CamVid's ids: a soft-edged (resized, JPEG) object mask?
        return (f"; it holds values up to {int(values.max())}: an object mask, soft-edged or not, reads with pcreg "
                "run's --mapping davis (0 the background, anything else the object), a table of that many classes "
                "with --classes FILE (a CVAT labelmap.txt or a JSON table)")
    if values.size and int(values.max()) > 2:
        return ("; labels of other classes need their table: --classes camvid11 (CamVid's ids), --classes FILE (a "
                "CVAT labelmap.txt or a JSON table), which pcreg run and evaluate stream take; pcreg run's --mapping "
                "camvid, and --data camvid:, read CamVid's ids as ground and obstacle")
    return ""
