"""CamVid's 32 classes' colours read as ``camvid11``'s eleven (:data:`CAMVID32`, :func:`read_camvid_labels`): what
:mod:`pcreg.datasets.camvid` reads its download's labels with, and :mod:`pcreg.datasets.folder` a clip's
``NAME_L.png`` labels, each without reading the other. The grouping is :mod:`pcreg.datasets.camvid`'s (SegNet's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DatasetError, InputError

__all__ = ["CAMVID32", "camvid32_ids", "read_camvid_labels"]

#: CamVid's 32 classes (``label_colors.txt``): name, colour (R, G, B), and the ``camvid11`` id it is read as
#: (0 sky, 1 building, 2 pole, 3 road, 4 pavement, 5 tree, 6 sign symbol, 7 fence, 8 car, 9 pedestrian,
#: 10 bicyclist, 11 void).
CAMVID32: tuple[tuple[str, tuple[int, int, int], int], ...] = (
    ("Animal", (64, 128, 64), 9),
    ("Archway", (192, 0, 128), 1),
    ("Bicyclist", (0, 128, 192), 10),
    ("Bridge", (0, 128, 64), 1),
    ("Building", (128, 0, 0), 1),
    ("Car", (64, 0, 128), 8),
    ("CartLuggagePram", (64, 0, 192), 9),
    ("Child", (192, 128, 64), 9),
    ("Column_Pole", (192, 192, 128), 2),
    ("Fence", (64, 64, 128), 7),
    ("LaneMkgsDriv", (128, 0, 192), 3),
    ("LaneMkgsNonDriv", (192, 0, 64), 3),
    ("Misc_Text", (128, 128, 64), 6),
    ("MotorcycleScooter", (192, 0, 192), 10),
    ("OtherMoving", (128, 64, 64), 8),
    ("ParkingBlock", (64, 192, 128), 4),
    ("Pedestrian", (64, 64, 0), 9),
    ("Road", (128, 64, 128), 3),
    ("RoadShoulder", (128, 128, 192), 4),
    ("Sidewalk", (0, 0, 192), 4),
    ("SignSymbol", (192, 128, 128), 6),
    ("Sky", (128, 128, 128), 0),
    ("SUVPickupTruck", (64, 128, 192), 8),
    ("TrafficCone", (0, 0, 64), 2),
    ("TrafficLight", (0, 64, 64), 6),
    ("Train", (192, 64, 128), 8),
    ("Tree", (128, 128, 0), 5),
    ("Truck_Bus", (192, 128, 192), 8),
    ("Tunnel", (64, 0, 64), 1),
    ("VegetationMisc", (192, 192, 0), 5),
    ("Void", (0, 0, 0), 11),
    ("Wall", (64, 192, 0), 1),
)


def _colour_ids() -> tuple[list[tuple[int, int, int]], list[int]]:
    """(colours, their camvid11 ids): the 32 classes', and camvid11's own (its pavement is SegNet's colour, not
    CamVid's); where both name a colour, they name the same class."""
    from ..classes.table import CAMVID11

    pairs = {c: i for _, c, i in CAMVID32}
    for c in CAMVID11.classes:
        assert pairs.setdefault(c.colour, c.id) == c.id
    return list(pairs), list(pairs.values())


def camvid32_ids(rgb: np.ndarray, where: str) -> np.ndarray:
    """(H, W) uint8 ``camvid11`` ids of an (H, W, 3) uint8 RGB label image in CamVid's 32 classes' colours
    (or ``camvid11``'s); a :class:`DatasetError` naming ``where`` and the first colour of neither."""
    from ..classes.table import colour_ids

    labels, miss = colour_ids(np.asarray(rgb), *_colour_ids())
    if miss is not None:
        x, y, colour = miss
        raise DatasetError(f"{where}: colour {colour} (at x={x}, y={y}) is none of CamVid's 32 classes' colours "
                           f"(label_colors.txt) nor camvid11's")
    return labels


def read_camvid_labels(path: Path, table, mapping: str | None) -> np.ndarray:
    """(H, W) uint8 labels of ``table`` (``camvid11``, or ``lagr`` with ``mapping="camvid"``) of the label file at
    ``path``: as :func:`pcreg.classes.keys.read_key_labels` reads it, and else, when it is a colour image, in
    CamVid's 32 classes' colours grouped as ``camvid11``'s (:data:`CAMVID32`). What the key-label reader reads
    is read as it reads it."""
    from ..classes.keys import decode_key_labels
    from ..classes.mappings import mapping_lut
    from ..classes.png import is_palette_png
    from ..formats import RAISE_LIMIT, decode_image, max_file_bytes, read_regular_file
    from ..validation import max_pixels

    lim = max_pixels(None)
    try:
        data = read_regular_file(path, max_bytes=max_file_bytes(lim), what="image", hint=RAISE_LIMIT)
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    try:
        return decode_key_labels(data, str(path), table, "none" if mapping is None else "camvid", limit=lim)
    except InputError as exc:
        first = DatasetError(str(exc))
    if is_palette_png(data):
        raise first from None
    try:
        img = decode_image(data, str(path), limit=lim)
    except InputError:
        raise first from None
    if img.ndim != 3 or img.dtype != np.uint8 or img.shape[2] not in (3, 4) \
            or (img.shape[2] == 4 and (img[:, :, 3] != 255).any()) or (img[:, :, 1:3] == img[:, :, :1]).all():
        raise first from None  # not colours: ids, or a grey image saved in colour
    ids = camvid32_ids(np.ascontiguousarray(img[:, :, 2::-1]), str(path))
    if mapping is None:
        return ids
    lut = mapping_lut("camvid")
    assert lut is not None
    return lut[ids]
