"""Image folders (CamVid and the like): ``images/*`` (:data:`pcreg.formats.IMAGE_SUFFIXES`) with ``labels/*.png`` raw ids mapped to
{0 ground, 1 obstacle, 2 unknown}."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import DatasetError, InputError
from .frame import Frame
from .sources import _check_numbering

from ..formats import IMAGE_SUFFIXES

from ..classes.mappings import CAMVID_MAPPING, mapping_lut  # noqa: F401 - read here since 0.1


def _read_png(path: Path) -> np.ndarray:
    """A label file as stored (a regular file, its size checked in the header before decoding)."""
    import cv2

    from ..formats import read_image_file

    try:
        return read_image_file(path, flags=cv2.IMREAD_UNCHANGED)
    except InputError as exc:
        raise DatasetError(str(exc)) from None


def _read_frame(path: Path) -> tuple[np.ndarray, str, tuple[str, ...]]:
    """A frame as (H, W, 3) uint8 RGB, converted from the pixels as stored as :func:`pcreg.load_image` converts them
    for ``pcreg run`` and ``register`` (16 bits scaled by 1/257, floats in [0, 1] taken; a side of any size), what
    its decoder said of damaged data it decoded around, or "" (:func:`pcreg.formats.read_image_file_and_damage`), and
    the notes of its pixels as stored (:func:`pcreg.datasets.frame_notes.stored_notes`)."""
    from ..formats import read_image_file_and_damage
    from ..registration.clouds import _rgb_and_alpha
    from .frame_notes import stored_notes

    try:  # regular files only, size checked in the header before decoding
        stored, damage = read_image_file_and_damage(path)
        image = _rgb_and_alpha(stored, str(path), min_side=1)[0]
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    notes = stored_notes(str(path), stored, later="the figures of the frames it is in may be off")
    return image, damage, tuple(line for _, line in notes)


def _read_table_labels(path: Path, image: np.ndarray, table, mapping, image_path: Path) -> np.ndarray:
    """A label file read through ``table`` (``mapping`` None or ``"camvid"``) as key labels are
    (:func:`pcreg.classes.keys.read_key_labels`: CamVid's ids and ``camvid11``'s table also read CamVid's own 32
    classes' colours), of its image's size; a :class:`DatasetError` naming it otherwise."""
    from ..classes.keys import read_key_labels

    try:
        lab = read_key_labels(path, table, "none" if mapping is None else "camvid")
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    if lab.shape != image.shape[:2]:
        from ..formats import turned_note

        raise DatasetError(f"{path}: labels are {lab.shape[1]}x{lab.shape[0]} but the image is "
                           f"{image.shape[1]}x{image.shape[0]}{turned_note(image_path, lab.shape, image.shape)}")
    return lab


#: The suffix of CamVid's own label files: ``NAME_L.png`` is the label image of frame ``NAME.png``.
LABEL_SUFFIX = "_L"


def download_frame(stem: str, images: dict[str, Path]) -> str:
    """The frame a label file ``stem`` labels: ``NAME`` for ``NAME_L`` as CamVid's own download names them
    (``LabeledApproved_full/``) when ``NAME`` is a frame and ``NAME_L`` is not; else ``stem``."""
    if stem.endswith(LABEL_SUFFIX) and stem not in images and stem[: -len(LABEL_SUFFIX)] in images:
        return stem[: -len(LABEL_SUFFIX)]
    return stem


def download_name(frame: str) -> str | None:
    """The other name :func:`download_frame` reads for ``frame``'s label file, as a refusal says it."""
    return f"{frame}{LABEL_SUFFIX}.png, as CamVid names them"


def _label_files(lab_dir: Path, images: dict[str, Path], frame_of) -> dict[str, Path]:
    """``{frame name: label file}`` of ``lab_dir``'s PNGs, each the label file of frame ``frame_of(stem,
    images)``. A frame with two is refused naming them."""
    from ..formats import only_files

    out: dict[str, Path] = {}
    try:
        named = only_files([p for p in sorted(lab_dir.iterdir()) if p.suffix.lower() == ".png" and not p.name.startswith(".")],
                           "a label file")
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    for p in named:
        name = frame_of(p.stem, images)
        if name in out:
            raise DatasetError(f"{p}: a second label file of frame {name} (beside {out[name].name}); keep one")
        out[name] = p
    return out


def load_folder(folder: str | Path, *, mapping: str | Mapping[int, int] | None = "camvid",
                classes=None) -> list[Frame]:
    """Load ``folder/images/NAME.png`` (or another image suffix) with ``folder/labels/NAME.png`` in name order.

    mapping : ``"camvid"`` (CamVid's 12 ids, the default), a dict raw id -> label in {0, 1, 2}, or
        None (label files already hold the class table's ids). A label id outside the mapping is an error.
    classes : with ``mapping=None``, the labels' class table (a :class:`~pcreg.classes.ClassTable` or what
        :func:`pcreg.classes.class_table` reads; default ``lagr``): each label file is read through it
        (class ids, a palette PNG, or the table's colours; :func:`pcreg.classes.keys.read_key_labels`).
        ``"camvid"`` reads CamVid's ids, or ``camvid11``'s palette or colours, before mapping them.

    Without a ``labels/`` folder the frames load unlabelled. With one, every image needs its label
    file and every label file its image, of the same size; frame ``NAME`` is labelled by ``labels/NAME.png``
    or, as CamVid's own download names them, ``labels/NAME_L.png``.
    Returns frames with image (H, W, 3) uint8 RGB and labels (H, W) uint8.
    """
    from ..validation import check_path

    from ..classes import class_table

    folder = check_path(folder, "folder")
    table = class_table(classes)
    if classes is not None and mapping is not None:
        raise InputError("load_folder: classes= reads the labels through a table, mapping= maps raw ids; give one")
    lut = mapping_lut(mapping)
    img_dir, lab_dir = folder / "images", folder / "labels"
    if not img_dir.is_dir():
        raise DatasetError(f"{folder}: no images/ folder")
    images = frame_names(img_dir, image_files(img_dir))
    labels = label_files(lab_dir, images) if lab_dir.is_dir() else None
    return read_frames(images, labels, mapping=mapping, table=table, lut=lut)


def image_files(img_dir: Path) -> list[Path]:
    """The image files of ``img_dir`` in name order; hidden files left out (macOS's ``._NAME``, as pcreg run), and an
    entry named as an image that is no readable file (a link to nothing, a folder, a FIFO) refused naming it
    (:func:`pcreg.formats.only_files`), as pcreg run refuses it: left out, it was said to be a frame without labels."""
    from ..formats import only_files

    try:
        return only_files([p for p in sorted(img_dir.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES
                           and not p.name.startswith(".")], "a frame")
    except InputError as exc:
        raise DatasetError(str(exc)) from None


def frame_names(img_dir: Path, files: list[Path]) -> dict[str, Path]:
    """``{frame name: image file}`` of one clip's ``files`` (of ``img_dir``, which messages name), in name order;
    refused: none, two files of one name (``X.png`` and ``X.jpg``), numbers of different widths."""
    try:  # frames in name order, as pcreg run reads them: f10.png before f9.png is refused, never scored out of order
        _check_numbering(img_dir, [p.name for p in files])
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    images = {p.stem: p for p in files}
    if len(images) != len(files):  # X.png and X.jpg: which one is frame X?
        twice = sorted({p.name for p in files if sum(q.stem == p.stem for q in files) > 1})
        raise DatasetError(f"{img_dir}: two images share a frame name ({', '.join(twice[:4])})")
    if not images:
        raise DatasetError(f"{img_dir}: no image frames ({', '.join(IMAGE_SUFFIXES)})")
    return images


def label_files(lab_dir: Path, images: dict[str, Path], *, frame_of=download_frame,
                other_name=download_name) -> dict[str, Path]:
    """``{frame name: label file}`` of ``lab_dir``: ``NAME.png`` for the frame ``NAME``, or the file
    ``frame_of(stem, images)`` reads as its (default :func:`download_frame`); one for every frame of ``images``
    and a frame for every one. A :class:`DatasetError` names the first file that has none, and the other name
    it could have had (``other_name(frame)``, None for none)."""
    labels = _label_files(lab_dir, images, frame_of)
    no_label = sorted(set(images) - set(labels))
    if no_label:
        other = other_name(no_label[0])
        raise DatasetError(f"{images[no_label[0]]}: no label file {lab_dir / (no_label[0] + '.png')}"
                           + (f" (or {other})" if other else "") + not_png_note(lab_dir, no_label[0]))
    no_image = sorted(set(labels) - set(images))
    if no_image:
        raise DatasetError(f"{labels[no_image[0]]}: label file without an image in {next(iter(images.values())).parent}")
    return labels


def read_frames(images: dict[str, Path], labels: dict[str, Path] | None, *, mapping, table, lut) -> list[Frame]:
    """The frames of ``images`` in name order, each labelled by its file of ``labels`` (None: unlabelled), read
    through ``table`` (``mapping`` None or ``"camvid"``) or mapped by ``lut`` (:func:`load_folder`)."""
    frames = []
    for name in sorted(images):
        image, damage, notes = _read_frame(images[name])
        lab = None
        if labels is not None:
            if mapping is None or mapping == "camvid":
                lab = _read_table_labels(labels[name], image, table, mapping, images[name])
                frames.append(Frame(image=image, labels=lab, name=name, damage=damage, notes=notes))
                continue
            raw = _read_png(labels[name])
            if raw.ndim != 2 or raw.dtype != np.uint8:
                raise DatasetError(f"{labels[name]}: label file must be a single-channel 8-bit PNG, got {raw.shape} {raw.dtype}")
            if raw.shape != image.shape[:2]:
                raise DatasetError(f"{labels[name]}: labels are {raw.shape[1]}x{raw.shape[0]} but the image is "
                                   f"{image.shape[1]}x{image.shape[0]}")
            lab = lut[raw]
            if lab.max() == 255:
                bad = np.unique(raw[lab == 255])[:8].tolist()
                raise DatasetError(f"{labels[name]}: label ids {bad} are outside the mapping")
        frames.append(Frame(image=image, labels=lab, name=name, damage=damage, notes=notes))
    return frames


def refuse_frameless(parent: Path, what: str) -> None:
    """A :class:`DatasetError` naming the first sub-folder of ``parent`` (a folder of clips or sequences) that holds
    ``labels/`` without an ``images/`` folder beside it (its frames missing, renamed, or behind a link to nowhere):
    passed over, the evaluation would score the others alone without a word. ``what``: ``clip`` or ``sequence``."""
    for d in sorted(p for p in parent.iterdir() if p.is_dir() and not p.name.startswith(".")):
        images = d / "images"
        if not (d / "labels").is_dir() or images.is_dir():
            continue
        why = "a link to nowhere" if images.is_symlink() else "not a folder" if images.exists() else "no such folder"
        others = [p.name for p in sorted(d.iterdir())
                  if p.is_dir() and p.name != "labels" and not p.name.startswith(".")]
        hint = f"; if {others[0]}/ holds them, name it images/" if others else ""
        raise DatasetError(f"{images}: {why}, beside {d / 'labels'}: {what} {d.name}'s frames go in images/{hint}")


def no_folder(path: Path) -> DatasetError:
    """What ``--data KIND:PATH`` says of a ``path`` that is no folder: an archive to unpack (a download's zip or
    tar), a file, or nothing there."""
    import tarfile
    import zipfile

    if path.is_file():
        archive = zipfile.is_zipfile(path) or tarfile.is_tarfile(path)
        return DatasetError(f"{path}: an archive, not a folder: unpack it and give the folder" if archive else
                            f"{path}: a file, not a folder of frames")
    return DatasetError(f"{path}: no such folder")


def not_png_note(folder: Path, stem: str) -> str:
    """``; NAME.jpg is there, ...`` when ``folder`` holds an image named ``stem`` in another format than PNG (a
    label or mask saved as a JPEG or TIFF, which is not read), for the refusal of its missing PNG to say; else
    ``""``."""
    import glob

    other = sorted(p.name for p in folder.glob(f"{glob.escape(stem)}.*")
                   if p.suffix.lower() in IMAGE_SUFFIXES and p.suffix.lower() != ".png") if folder.is_dir() else []
    return (f"; {folder.name}/{other[0]} is there, but a label is read from a PNG only (lossless: a JPEG changes the "
            "values at every edge)") if other else ""
