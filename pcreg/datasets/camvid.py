"""CamVid as its own download lays it out, and its 32 classes read as ``camvid11``'s eleven.

The download (Brostow et al. 2008) holds every labelled frame of its four sequences (0001TP, 0006R0, 0016E5,
Seq05VD) in one folder, ``701_StillsRaw_full/SEQ_NNNNNN.png``, and their labels in another,
``LabeledApproved_full/SEQ_NNNNNN_L.png``, in the colours of 32 classes (its ``label_colors.txt``).
:func:`find_official` finds those two folders in a root, :func:`load_official` reads one clip per sequence.

The 32 classes become ``camvid11``'s (:data:`pcreg.classes.table.CAMVID11`) by the grouping SegNet's eleven
classes were made with (Sturgess et al. 2009; Badrinarayanan et al., SegNet; written out class by class in
MATLAB's CamVid example, ``camvidPixelLabelIDs``): road markings are road, a sidewalk, parking block or road
shoulder pavement, a bus or truck a car, a traffic light or a text sign symbol, and so on (:data:`CAMVID32`).
SegNet's labels of the shared clips (``../shared/data/camvid``) agree with it where one can see it: lane
markings are road, buses and vans car, traffic lights sign symbol, grass verges tree. CamVid's ``Void`` is
void; a colour of none of the 32 is refused naming the file and the colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DatasetError, InputError

__all__ = ["CAMVID32", "FRAMES_FOLDER", "LABELS_FOLDER", "camvid32_ids", "read_camvid_labels", "find_official",
           "load_official"]

#: The folders of CamVid's download: the frames, and their labels in the 32 classes' colours.
FRAMES_FOLDER, LABELS_FOLDER = "701_StillsRaw_full", "LabeledApproved_full"

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


def find_official(root: Path) -> tuple[Path, Path] | None:
    """``(frames folder, labels folder)`` of CamVid's download in ``root``: ``701_StillsRaw_full/`` and
    ``LabeledApproved_full/``, or, named otherwise, the one sub-folder of frames named ``SEQ_...`` and the one of
    label files all named ``NAME_L.png`` beside it. None when ``root`` holds no such pair; several candidates
    of one are refused naming them."""
    from .folder import LABEL_SUFFIX, image_files

    subs = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    named = {p.name: p for p in subs}
    if FRAMES_FOLDER in named and LABELS_FOLDER in named:
        return named[FRAMES_FOLDER], named[LABELS_FOLDER]
    frames: list[Path] = []
    labels: list[Path] = []
    for sub in subs:
        stems = [p.stem for p in image_files(sub)]
        if not stems or not all("_" in s.strip("_") for s in stems):
            continue
        (labels if all(s.endswith(LABEL_SUFFIX) for s in stems) else frames).append(sub)
    if not frames or not labels:
        return None
    for what, found in (("frames", frames), ("label files (NAME_L.png)", labels)):
        if len(found) > 1:
            raise DatasetError(f"{root}: {len(found)} folders of CamVid's {what} ({', '.join(p.name for p in found)}); "
                               f"keep one, or name them {FRAMES_FOLDER}/ and {LABELS_FOLDER}/")
    return frames[0], labels[0]


def sequence_of(name: str) -> str:
    """The sequence a CamVid frame ``SEQ_NNNNNN`` belongs to: ``SEQ``."""
    return name.split("_", 1)[0]


def load_official(frames_dir: Path, labels_dir: Path, *, mapping, classes, n_frames: int | None = None) -> dict:
    """``{sequence: frames}`` of CamVid's download (:func:`find_official`): one clip per sequence (the ``SEQ`` of
    ``SEQ_NNNNNN.png``), frames in name order, each labelled by ``labels_dir/SEQ_NNNNNN_L.png`` (every frame its
    label file, every label file its frame); the first ``n_frames`` of each clip read. ``mapping`` and
    ``classes`` as :func:`pcreg.datasets.load_folder` takes them."""
    from ..classes import class_table
    from ..classes.mappings import mapping_lut
    from .folder import frame_names, image_files, label_files, read_frames

    table, lut = class_table(classes), mapping_lut(mapping)
    files = image_files(frames_dir)
    if not files:
        raise DatasetError(f"{frames_dir}: no image frames")
    odd = [p for p in files if "_" not in p.stem.strip("_")]
    if odd:
        raise DatasetError(f"{odd[0]}: not named SEQ_NNNNNN.png as CamVid's frames are (the sequence, an "
                           "underscore, the frame's number)")
    clips = {seq: frame_names(frames_dir, [p for p in files if sequence_of(p.stem) == seq])  # numbered alike
             for seq in sorted({sequence_of(p.stem) for p in files})}
    labels = label_files(labels_dir, {n: p for clip in clips.values() for n, p in clip.items()})
    out: dict = {}
    for seq, clip in clips.items():
        keep = sorted(clip)[:n_frames]
        out[seq] = read_frames({n: clip[n] for n in keep}, {n: labels[n] for n in keep}, mapping=mapping,
                               table=table, lut=lut)
    return out
