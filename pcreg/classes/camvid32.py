"""CamVid's 32 classes (its download's ``label_colors.txt``) and the ``camvid11`` class each is read as
(:data:`CAMVID32`, :func:`camvid32_ids`): the grouping SegNet's eleven classes were made with
(:mod:`pcreg.datasets.camvid`), read by the key-label reader (:mod:`pcreg.classes.keys`), which the datasets'
label files are read with too."""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["CAMVID32", "camvid32_ids"]

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
    from .table import CAMVID11

    pairs = {c: i for _, c, i in CAMVID32}
    for c in CAMVID11.classes:
        assert pairs.setdefault(c.colour, c.id) == c.id
    return list(pairs), list(pairs.values())


def camvid32_ids(rgb: np.ndarray, where: str) -> np.ndarray:
    """(H, W) uint8 ``camvid11`` ids of an (H, W, 3) uint8 RGB label image in CamVid's 32 classes' colours
    (or ``camvid11``'s); an :class:`~pcreg.errors.InputError` naming ``where`` and the first colour of neither."""
    from .table import colour_ids

    labels, miss = colour_ids(np.asarray(rgb), *_colour_ids())
    if miss is not None:
        x, y, colour = miss
        raise InputError(f"{where}: colour {colour} (at x={x}, y={y}) is none of CamVid's 32 classes' colours "
                           f"(label_colors.txt) nor camvid11's")
    return labels
