"""A ``pcreg run`` output as an archive an annotation tool imports, so a person corrects the labels there.

One format: CVAT's "Segmentation mask 1.1" (``cvat-mask``), the Pascal VOC segmentation layout that CVAT
reads through Datumaro's ``voc`` importer::

    export-cvat-mask.zip
    ├── labelmap.txt                    # label:color_rgb:parts:actions (the class table's, pcreg.classes)
    ├── ImageSets/Segmentation/default.txt   # the frames' names, without extension, in run order
    ├── SegmentationClass/NAME.png      # RGB, each class in its table colour
    └── SegmentationObject/NAME.png     # RGB, VOC instance colours: the known classes 1, 2, ..., unknown 0

Unknown pixels are black whatever the table's colour, the label map's background (its unknown class, under its own name: no extra
``background`` line duplicates a class), and instance 0 in ``SegmentationObject``: the importer makes no
annotation of instance 0, so in the tool they are unlabelled, where a person looks. Each known class becomes
one mask per frame (a class that a frame does not show, none). The task needs the table's known classes as
labels (``ground`` and ``obstacle`` for the default table, ``lagr``); colours are matched through
``labelmap.txt``, names of frames through ``default.txt`` (the frame's file name without its extension).
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from .classes import DEFAULT_TABLE, ClassTable
from .classes.files import cvat_table
from .errors import InputError
from .formats import check_regular_file
from ._moved import moved

__all__ = ["FORMATS", "cvat_table", "RunLabels", "read_run", "read_labels", "labelled_frames", "labels_with_confidence", "instance_colours",
           "cvat_mask_archive", "write_cvat_mask", "write_cvat_mask_archive", "default_name"]

#: The formats ``pcreg export`` writes.
FORMATS: tuple[str, ...] = ("cvat-mask",)


def instance_colours(table: ClassTable) -> dict[int, tuple[int, int, int]]:
    """Class id -> RGB of its instance in ``SegmentationObject``: the k-th known class the VOC instance
    colour map's entry k (1 (128, 0, 0), 2 (0, 128, 0), ...), the unknown 0 (black, no instance)."""
    from .classes import voc_colormap

    cmap = voc_colormap(table.n_known + 1)
    out = {c.id: (int(cmap[k + 1][0]), int(cmap[k + 1][1]), int(cmap[k + 1][2])) for k, c in enumerate(table.known)}
    out[table.unknown] = (0, 0, 0)
    return out


@dataclass(frozen=True)
class RunLabels:
    """The labelled frames of a run: ``names`` (the frames' file names, in frame order: a run from one label image's
    key frame first, a run from a folder of key frames' key frames where they lie) and
    ``paths`` (each frame's label PNG, ``OUT/STEM.png``), ``confidence`` (each frame's confidence PNG,
    or None: a key frame, or a run without ``--confidence``), ``table`` the run's class table
    (:func:`pcreg.classes.keys.run_table`: the one its ``run.json`` names, else ``lagr``), ``keys`` the key
    frames' names (a person's labels, kept as they are by ``--min-confidence``), ``gaps`` what is said of the places
    its video skips frames by its times (:func:`pcreg.runs.gaps.gaps_note`; None without one): the frames are
    numbered by count all the same, as CVAT numbers them; ``damaged`` what is said of its frames that decode with errors
    (:func:`pcreg.runs.gaps.damaged_note`; None without one); ``notes`` what reading its frames met, each kind's line
    (:func:`pcreg.runs.gaps.kept_notes`: transparent pixels, a turn to interlaced)."""

    folder: Path
    names: tuple[str, ...]
    paths: tuple[Path, ...]
    confidence: tuple[Path | None, ...]
    table: ClassTable = DEFAULT_TABLE
    chosen: int | None = None  # the frames the run chose of its folder (None: a video, or the folder gone)
    keys: frozenset[str] = frozenset()
    gaps: str | None = None
    damaged: str | None = None
    notes: tuple[str, ...] = ()

    def said(self) -> tuple[str, ...]:
        """Every line said of the run's frames, in order: ``gaps``, ``damaged`` and the ``notes``."""
        return tuple(filter(None, (self.gaps, self.damaged, *self.notes)))


def default_name(fmt: str) -> str:
    """The archive's file name in the run's folder when no destination is given."""
    return f"export-{fmt}.zip"


def read_run(folder: str | Path) -> RunLabels:
    """The frames a ``pcreg run`` output in ``folder`` has labelled (counted in its ``run.json``), in order.

    Raises :class:`~pcreg.errors.InputError` naming the file: no ``run.json`` (not a run's output), one
    that cannot be read, a ``steps.jsonl`` that lists fewer frames than counted or holds a line pcreg run did not
    write (:func:`pcreg.runs.files.counted_steps`), a label file missing or not a regular file.
    """
    from .classes.keys import run_table
    from .runs.files import CONFIDENCE, STEPS, has_confidence
    from .runs.gaps import damaged_note, gaps_note, kept_notes
    from .runs.state import STATE, frames_chosen, read_state, run_frames

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: {'not a folder' if folder.exists() else 'no such folder'}")
    state = read_state(folder)
    steps_path = folder / STEPS
    try:
        keys, names = run_frames(state, folder)
    except InputError:  # steps.jsonl's, named
        raise
    except (KeyError, TypeError, AttributeError):
        raise InputError(f"{folder / STATE}: unreadable (not a run.json that pcreg run wrote)") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{steps_path}: missing or unreadable ({exc})") from None
    stems = [Path(n).stem for n in names]
    odd = next((n for s, n in zip(stems, names) if not s or "/" in n or "\\" in n), None)
    if odd is not None:  # an annotation tool reads a backslash in a member's name as a folder
        raise InputError(f"{steps_path}: the frame name {odd!r} is not a file name an archive can hold "
                         "(a slash or a backslash); rename the frame")
    paths = [folder / f"{s}.png" for s in stems]
    if not any(p.exists() for p in paths):
        raise InputError(f"{folder}: no label files (none of {', '.join(p.name for p in paths[:3])}"
                         f"{', ...' if len(paths) > 3 else ''})")
    for p, n in zip(paths, names):
        if p.exists():  # a folder, a FIFO or a device named like a label file is said to be one
            check_regular_file(p, what="label image")
        else:
            raise InputError(f"{p}: missing (the label file of a key frame {folder / STATE} names: the file was "
                             f"removed, or run.json edited)" if n in keys else f"{p}: missing (a labelled frame's "
                             "label file)")
    _check_frames(folder, state)  # the run's own files first
    conf_dir = folder / CONFIDENCE
    kept = has_confidence(folder, state["run"])
    confidence = [None if n in keys or not kept else conf_dir / f"{s}.png" for n, s in zip(names, stems)]
    table = run_table(state["run"], str(folder / STATE))  # messages, the export's among them, name the file
    return RunLabels(folder, tuple(names), tuple(paths), tuple(confidence), table, frames_chosen(state["run"]),
                     frozenset(keys), gaps_note(state.get("gaps"), state["run"].get("video")),
                     damaged_note(state.get("damaged"), state["run"].get("video")), kept_notes(state.get("notes")))


def _check_frames(folder: Path, state: dict) -> None:
    """Refuse, as the review does (:class:`~pcreg.runs.edited.FramesAsLabelled`), a run whose frames folder, still
    there, holds frames written again since the run labelled them (re-extracted at another size, edited) or added,
    removed or renamed: the archive is imported over the frames as they are now; so is a run whose video was written
    over since (:func:`~pcreg.runs.video_file.check_labelled_video`). A video or folder that is gone (the labels are all
    an export needs) is not read."""
    from .datasets.sources import open_frames
    from .runs.edited import FramesAsLabelled
    from .runs.files import counted_steps
    from .runs.state import STATE, chosen_selection, steps_counted, steps_counted_now
    from .runs.video_file import check_labelled_video

    run = state["run"]
    if isinstance(run.get("video"), str) and Path(run["video"]).is_file():  # written over since: not its frames
        check_labelled_video(state, Path(run["video"]), folder, "export")
        return
    source = Path(run["folder"]) if isinstance(run.get("folder"), str) and "video" not in run else None
    if source is None or not source.is_dir():
        return
    frames = open_frames(source, chosen_selection(run, str(folder / STATE)))
    seen = FramesAsLabelled(frames, folder, "export", None if "stretches" in state else str(state["key_frame"]),
                            keys=(state.get("keys") or ()) if "stretches" in state else ())
    for step in counted_steps(folder, steps_counted(state), recount=lambda: steps_counted_now(folder)):
        seen.step(step)
    seen.check()


def read_labels(path: Path, table: ClassTable = DEFAULT_TABLE) -> np.ndarray:
    """(H, W) uint8 class ids of a run's label PNG (:func:`pcreg.classes.read_label_png`: class ids or a
    palette PNG in the table's colours); an :class:`InputError` naming it otherwise."""
    from .classes import read_label_png

    return read_label_png(path, table)


def labelled_frames(run: RunLabels, min_confidence: float | None = None):
    """``(name, labels)`` of each frame of the run in order (:func:`labels_with_confidence`, in the run's
    table), each label PNG checked to have the key frame's size (a file of another size is no label of this
    run's frames: an :class:`InputError` naming it)."""
    shape = None
    for t, name in enumerate(run.names):
        lab = read_labels(run.paths[t], run.table)
        if shape is not None and lab.shape != shape:  # before its confidence, which is of the frame's size
            raise InputError(f"{run.paths[t]}: labels of {lab.shape[1]}x{lab.shape[0]}, the key frame's are "
                             f"{shape[1]}x{shape[0]} (not a label image this run wrote)")
        shape = lab.shape
        yield name, _confident(run, t, lab, min_confidence, run.table)


def labels_with_confidence(run: RunLabels, t: int, min_confidence: float | None,
                           table: ClassTable = DEFAULT_TABLE) -> np.ndarray:
    """Frame ``t``'s labels; with ``min_confidence``, the pixels whose confidence is below it set to
    unknown (the table's). The key frames' labels (a person's) are kept as they are, wherever they lie."""
    return _confident(run, t, read_labels(run.paths[t], table), min_confidence, table)


def _confident(run: RunLabels, t: int, lab: np.ndarray, min_confidence: float | None, table: ClassTable) -> np.ndarray:
    """:func:`labels_with_confidence` of frame ``t``'s labels ``lab``, already read."""
    from .runs.files import read_confidence

    if min_confidence is None or run.names[t] in run.keys:
        return lab
    path = run.confidence[t]
    if path is None:
        raise InputError(f"--min-confidence: {run.folder} has no confidence/ (run pcreg run with --confidence)")
    if not path.is_file():
        raise InputError(f"{path}: missing (--min-confidence needs every frame's confidence)")
    conf = read_confidence(path, lab.shape, "--min-confidence reads the confidence maps pcreg run wrote")
    out = lab.copy()
    out[conf.astype(np.float64) < min_confidence * 255.0] = table.unknown  # 255 x the probability that the label is right
    return out


def _png(rgb: np.ndarray, path: str) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]))  # OpenCV writes BGR
    if not ok:
        raise InputError(f"cannot encode {path}")
    return buf.tobytes()


def _paint(labels: np.ndarray, colours: dict[int, tuple[int, int, int]]) -> np.ndarray:
    lut = np.zeros((256, 3), np.uint8)
    for k, c in colours.items():
        lut[k] = c
    return lut[labels]


def _utf8(text: str) -> str:
    """``text`` as a zip stores it (its names are UTF-8): a name that is not UTF-8 (os.fsdecode's escapes) with each
    bad byte replaced (U+FFFD)."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def cvat_mask_archive(frames, table: ClassTable = DEFAULT_TABLE) -> tuple[bytes, dict[str, int]]:
    """The bytes of a "Segmentation mask 1.1" zip of ``frames`` (pairs of a frame's file name and its
    (H, W) uint8 class ids of ``table``), and how many frames show each class (by name, every class of
    the table): :func:`write_cvat_mask` in memory.
    """
    buf = io.BytesIO()
    counts = write_cvat_mask(buf, frames, table)
    return buf.getvalue(), counts


def write_cvat_mask_archive(path: str | Path, frames, table: ClassTable = DEFAULT_TABLE) -> dict[str, int]:
    """Write the "Segmentation mask 1.1" zip of ``frames`` to ``path`` atomically as the frames come
    (:func:`pcreg.outputs.atomic_file`: one frame's masks in memory at a time, however long the run), and
    return how many frames show each class. A frame refused (an :class:`InputError`) or an interruption
    leaves nothing at ``path``; what an export of ``path`` killed mid-archive left beside it (its temporary
    file, as large as the frames it held) is removed first, and another's still being written is not."""
    from .outputs import atomic_file, remove_leftovers

    remove_leftovers(Path(path).parent, [Path(path).name])
    with atomic_file(path) as fh:
        return write_cvat_mask(fh, frames, table)


def write_cvat_mask(out: BinaryIO, frames, table: ClassTable = DEFAULT_TABLE) -> dict[str, int]:
    """Write a "Segmentation mask 1.1" zip of ``frames`` (as :func:`cvat_mask_archive`) to the seekable
    binary file ``out``, each frame's masks as it comes; how many frames show each class.

    Members are stored in a fixed order with a fixed date, so the same labels give the same bytes.
    """
    from .classes import labelmap_text

    table = cvat_table(table)
    counts = {c.name: 0 for c in table.classes}
    stems: list[str] = []  # in the run's order, for default.txt
    written: dict[str, str] = {}  # each name as the archive stores it -> the frame's, to tell one written twice
    class_colours = {c.id: c.colour for c in table.classes}
    instances = instance_colours(table)
    labelmap = labelmap_text(table)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as z:  # PNGs are compressed already
        def add(name: str, data: bytes | str) -> None:
            # a zip's names are UTF-8: a frame name that is not (os.fsdecode's escapes) is refused before
            name = _utf8(name)
            if isinstance(data, str):
                data = _utf8(data)
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16  # rw-r--r-- once unpacked (0 would be no permission at all)
            z.writestr(info, data)

        add("labelmap.txt", labelmap)
        for frame, labels in frames:
            stem = Path(frame).stem
            labels = np.asarray(labels)
            if labels.ndim != 2 or labels.dtype != np.uint8:
                raise InputError(f"{frame}: labels must be (H, W) uint8 class ids")
            labels = table.check_labels(labels, frame)
            stored = _utf8(stem)
            if stored != stem:  # stored with its bad bytes replaced, it would name no frame where it is imported
                raise InputError(f"{frame!r}: a frame name that is not UTF-8: a zip names its members in UTF-8, and as "
                                 f"{stored!r} its masks would match no frame in the tool (nor in pcreg run --labels); "
                                 "rename the frames to UTF-8 (convmv converts a folder's names)")
            if stored in written:
                raise InputError(f"{frame}: two frames named {stem}")
            if stem.splitlines() != [stem]:  # default.txt lists a name a line: a line break would make it two
                raise InputError(f"{frame!r}: a frame name with a line break cannot be listed in the archive's "
                                 "default.txt; rename the frame")
            if stem != stem.strip() or stem.startswith("#"):  # Datumaro strips each line, and skips a '#' line
                raise InputError(f"{frame!r}: a frame name that starts with '#' or has spaces around it is read "
                                 "otherwise from the archive's default.txt by CVAT's import (a comment, or the name "
                                 "without its spaces), and its masks left out; rename the frame")
            stems.append(stem)
            written[stored] = stem
            for k in np.unique(labels):
                counts[table.name_of(int(k))] += 1
            add(f"SegmentationClass/{stem}.png", _png(_paint(labels, class_colours), stem))
            add(f"SegmentationObject/{stem}.png", _png(_paint(labels, instances), stem))
        add("ImageSets/Segmentation/default.txt", "".join(f"{s}\n" for s in stems))
    return counts


if not TYPE_CHECKING:  # a module __getattr__ would be mypy's for every name: a misspelt one would pass
    __getattr__ = moved(__name__, {"LABELMAP": "pcreg._moved:LABELMAP_0_2 the run's class table (pcreg.export.cvat_table)",
                                    "INSTANCE_COLOURS": "pcreg._moved:INSTANCE_COLOURS_0_2 pcreg.export.instance_colours"})
