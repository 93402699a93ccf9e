"""What a run reads before it labels: its frames' source, its class table (``--classes``,
:func:`pcreg.classes.keys.choose_table`), the key frame's labels (one label image, a folder of key frames'
labels, or a CVAT "Segmentation mask 1.1" export, :mod:`pcreg.classes.cvat`), the truth maps to score
against, each read through the table (:func:`pcreg.classes.keys.read_key_labels`), and the checks that
they fit together and that ``--out`` overwrites none of them (:func:`read_inputs`). Every check is one
line naming the file.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from ..formats import only_files, resolved
from .files import CONFIDENCE, HIDDEN
from .video_file import decoded_to

__all__ = ["RunInputs", "read_inputs", "read_labels", "TruthMaps", "open_truth", "check_spares_inputs",
           "check_suggest", "read_key_labels"]


@dataclass
class RunInputs:
    """A run's inputs, read and checked: its ``frames`` (a :class:`~pcreg.datasets.sources.FolderFrames` or
    ``VideoFrames``), the key frames' labels ``keys`` ({position: (H, W) uint8}), whether they came from a
    ``folder`` of key frames (or a CVAT export; else one label image, at position 0), the ``truth`` maps
    (:class:`TruthMaps`, or None), the class ``table`` the labels are ids of (the request's, or a CVAT
    export's ``labelmap.txt``) and, from one label image, the frames ``pending``: the frame after the key
    frame and the decoder it came from, which a fresh run continues (None from a folder); ``notes``, what reading
    them met that the run says before the first frame (:func:`other_labels_note`); from a folder, ``reading``: the
    first chosen frame and the decoder it came from, which a pass that begins there goes on from (a video decoded
    to ``--start`` once, not again by the first pass)."""

    frames: Any
    keys: dict
    folder: bool
    truth: "TruthMaps | None"
    table: Any
    pending: tuple | None = None
    notes: tuple[str, ...] = ()
    reading: tuple | None = None

    def __enter__(self) -> "RunInputs":
        return self

    def __exit__(self, *exc) -> None:
        """The run from a folder ended, however: the reading it began is closed (a video's file), also where a
        refusal is kept in a traceback. (One label image's ``pending`` its run closes as it reads it ahead.)"""
        if self.reading is not None:
            self.reading[-1].close()


@contextmanager
def _closed_on_error(reading: tuple | None) -> Iterator[None]:
    """``reading``'s decoder closed (a video's file) when what runs under it raises: a refusal kept in a traceback
    keeps no file open."""
    try:
        yield
    except BaseException:
        if reading is not None:
            reading[-1].close()
        raise


def read_inputs(request, frames) -> RunInputs:
    """The inputs of ``request`` (a :class:`~pcreg.runs.run.RunRequest`) whose ``frames`` are open, read and
    checked in the order a run meets them: the key frames' labels (through the request's class table, or a
    CVAT export's), the truth, ``--out`` and ``--suggest``."""
    from ..classes.cvat import left_out_note

    table, mapping = request.coding.table, request.coding.mapping
    left: list[str] = []  # key labels of frames outside --start/--stop, left out
    if request.folder_of_keys:
        (table, keys, reading), shape, pending = _key_folder(request, frames, table, mapping, left), None, None
        # the key files sit in the labels folder, which is not --out: only a frame or a truth map could be overwritten
        spared = request.labels / f"{frames.stem(next(iter(keys)))}.png"
    else:
        (keys, pending), reading = _key_image(request, frames, table, mapping), None
        shape, spared = pending[0].image.shape[:2], request.labels
    with _closed_on_error(reading):
        _check_fits(request, frames, keys, table)
        truth = open_truth(request.truth, frames, shape or keys[next(iter(keys))].shape, mapping, table)
        check_spares_inputs(request.out, frames, spared, truth,
                            writes=((CONFIDENCE,) if request.confidence else ()) + ((HIDDEN,) if request.folder_of_keys else ()))
        check_suggest(request.suggest, frames, len(keys))
        notes = (other_labels_note(request.labels, frames) if request.folder_of_keys and request.labels.is_dir() else None,
                 left_out_note(f"--labels {request.labels}", left, frames.selection),
                 _unheld_note(request, frames, keys, table) if request.folder_of_keys else None)
    return RunInputs(frames, keys, pending is None, truth, table, pending, tuple(filter(None, notes)), reading)


def _unheld_note(request, frames, keys: dict, table) -> str | None:
    """The note of a folder of key frames where a class one key frame draws is on neither key frame around a stretch
    (each stretch is labelled from the key frames around it alone): its frames cannot be given the class, and their
    predicted error cannot know it (a road drawn on the first key frame only: 24% wrong, predicted 0.03%)."""
    from ..classes.table import listed_name
    from ..pipeline.engine import stretches

    held = _held_classes(keys, table)
    drawn = set().union(*held.values())
    unheld = [(s, drawn - set().union(*(held[t] for t in s.keys)))
              for s in stretches(keys, len(frames) if frames.kind == "folder" else None)]
    unheld = [(s, classes) for s, classes in unheld if classes]
    if not unheld:
        return None
    s, classes = unheld[0]
    names = ", ".join(listed_name(table.name_of(c)) for c in sorted(classes))
    around = f"on neither of {' and '.join(frames.name(t) for t in s.keys)}" if len(s.keys) > 1 else f"not on {frames.name(s.keys[0])}"
    more = f" ({len(unheld) - 1} more stretch(es) so)" if len(unheld) > 1 else ""
    return (f"--labels {request.labels}: {names}, drawn on other key frames, {around}, which label the frames around "
            f"them{more}: those frames are not given it, and their predicted error does not count it (if they show it, "
            "draw it on those key frames)")


def _held_classes(keys: dict, table) -> dict[int, set[int]]:
    """The known classes each key frame's labels (``keys``, {position: labels}) hold."""
    return {t: set(np.flatnonzero(np.bincount(np.asarray(lab).ravel(), minlength=256)).tolist()) - {table.unknown}
            for t, lab in keys.items()}


def _check_fits(request, frames, keys: dict, table) -> None:
    """An :class:`~pcreg.errors.InputError` naming the label files when the key frames a classifier is fitted on
    hold fewer than two of the table's known classes, before anything is written: one key frame's alone for a
    run from one label image; from a folder of key frames each stretch's (:class:`~pcreg.pipeline.keys_run.
    KeyRun`): the two key frames around it, and the first and the last alone for the frames before and after."""
    from ..classes.table import listed_name
    from ..errors import InputError

    from ..pipeline.engine import stretches

    groups: list[tuple[int, ...]]
    if not request.folder_of_keys:
        groups = [(min(keys),)]
    else:
        groups = [tuple(s.keys) for s in stretches(keys, len(frames) if frames.kind == "folder" else None)]
    held = _held_classes(keys, table)
    for group in groups:
        present = set().union(*(held[t] for t in group))
        if len(present) < 2:
            only = ", ".join(listed_name(table.name_of(c)) for c in sorted(present)) or "none"
            which = " and ".join(frames.name(t) for t in group)
            where = f"{request.labels}: the labels of {which}" if request.folder_of_keys else f"{request.labels}: the labels"
            raise InputError(f"{where} hold one class only ({only}); the classifier of the frames "
                             f"{'they label' if request.folder_of_keys else 'it labels'} needs pixels of at least two classes")


def _key_image(request, frames, table, mapping: str) -> tuple[dict, tuple]:
    """One label image, the key frame's (the first frame chosen), read through ``table`` as ``mapping``
    says, and the frames it leaves pending (the key frame, the next and their decoder); at least one frame
    more."""
    from ..datasets.davis import check_key_mask
    from ..errors import InputError
    from ..frame import PreparedFrame

    key_labels = read_labels(request.labels, mapping, table)
    if mapping == "davis":
        check_key_mask(key_labels, str(request.labels))
    decoded = decoded_to(frames, 0)  # a video's frames before --start decoded under a bar
    key = next(decoded)  # a source with no frame at --start raises, never ends empty
    PreparedFrame.of(key.image, name=frames.where(0)).check_key(key_labels, table.unknown, str(frames.where(0)))
    second = next(decoded, None)
    if second is None:
        raise InputError(f"{request.frames}: needs at least two frames (the key frame and one more), found 1")
    if key_labels.shape != key.image.shape[:2]:
        turned = frames.turned_note(0, key_labels.shape, key.image.shape)
        raise InputError(f"{request.labels}: labels are {key_labels.shape[1]}x{key_labels.shape[0]}, the key frame "
                         f"{key.name} is {key.image.shape[1]}x{key.image.shape[0]}{turned}")
    _check_known(request.labels, key_labels, table)
    return {0: key_labels}, (key, second, decoded)


def _check_known(path, labels: np.ndarray, table) -> None:
    """An :class:`~pcreg.errors.InputError` naming the key label file ``path`` whose ``labels`` are all unknown."""
    from ..classes.keys import all_unknown
    from ..errors import InputError

    if all_unknown(labels, table):
        raise InputError(f"{path}: the labels are all unknown ({table.unknown}): nothing to fit or propagate")


def _key_folder(request, frames, table, mapping: str, left: list[str]) -> tuple:
    """``(table, keys, reading)``: a folder of key frames' labels, ``NAME.png`` for the frame ``NAME``, read through
    ``table``, or a CVAT export read through its ``labelmap.txt`` (:func:`pcreg.classes.cvat.read_cvat_keys`,
    whose table it is); each of the frames' size, which the first chosen frame, read here, gives: ``reading`` is it
    and the rest of its reading (:attr:`RunInputs.reading`). The names of those of frames outside the chosen stretch,
    left out, are added to ``left``."""
    from ..classes.cvat import is_cvat_export, read_cvat_keys
    from ..errors import InputError

    out, folder = request.out, request.labels
    rest = decoded_to(frames, 0)
    first = next(rest)  # a source with no frame at --start raises, never ends empty
    with _closed_on_error((first, rest)):
        if resolved(folder) == resolved(out):
            raise InputError(f"--out {out} would overwrite the key frames' labels in {folder}; choose another folder")
        if is_cvat_export(folder):  # --classes davis (read as --mapping davis): the export's labelmap.txt checked against it
            implied = mapping == "davis" and request.coding.classes == "davis"
            table, keys = read_cvat_keys(folder, frames, first.image.shape[:2], request.coding.classes,
                                         mapping="none" if implied else mapping, left_out=left)
        else:
            keys = read_key_labels(folder, frames, mapping, first.image.shape[:2], table, left_out=left)
    return table, keys, (first, rest)


def read_labels(path: Path, mapping: str, table=None):
    """A key frame's (or a truth map's) labels read through the run's class ``table`` (None: ``lagr``) as
    ``mapping`` says (:func:`pcreg.classes.keys.read_key_labels`)."""
    from ..classes import DEFAULT_TABLE, LABELMAP_FILE, read_table_file
    from ..classes.keys import read_key_labels as read_through
    from ..errors import InputError

    table = DEFAULT_TABLE if table is None else table
    try:
        return read_through(path, table, mapping)
    except InputError as exc:
        beside = Path(path).parent / LABELMAP_FILE  # a CVAT table saved with the labels, not named
        if mapping != "none" or not table.agrees(DEFAULT_TABLE) or not beside.is_file():
            raise
        try:  # said only when that table reads them
            read_through(path, read_table_file(beside), mapping)
        except InputError:
            raise exc from None
        raise InputError(f"{path}: not labels of the table in use ({table.describe()}); {beside} lies "
                         f"beside it: --classes {beside} reads them through its table") from None


class TruthMaps:
    """Each frame's truth labels, ``ROOT/STEM.png``, read when the frame is scored: a long stream's maps are
    not all held in memory (2,000 frames at 640x480 are 600 MB). A folder's are all checked before the
    run starts; a video's length is known only once decoded, so each of its maps is checked when read."""

    def __init__(self, root: Path, frames, mapping: str, shape: tuple[int, int], table=None) -> None:
        self.root, self.frames, self.mapping, self.shape, self.table = root, frames, mapping, shape, table
        self._digests: dict[int, str] = {}

    def path(self, t: int) -> Path:
        return self.root / f"{self.frames.stem(t)}.png"

    def __getitem__(self, t: int):
        from .truth import check_truth

        from ..errors import InputError

        f = self.path(t)
        if not f.is_file():  # the file named, as every other input check names it
            raise InputError(f"{f}: no truth labels for frame {self.frames.name(t)} (--truth {self.root} holds "
                             "NAME.png for each frame NAME)")
        lab = read_labels(f, self.mapping, self.table)
        check_truth([lab], self.shape, [str(f)])
        return lab

    def digest(self, t: int) -> str:
        """The :func:`~pcreg.runs.files.label_digest` of frame ``t``'s map, kept from its first reading (the folder's
        check reads every map once; a resumed run compares them with the digests it scored against)."""
        from .files import label_digest

        if t not in self._digests:
            self._digests[t] = label_digest(self[t])
        return self._digests[t]


def open_truth(folder: str | None, frames, shape, mapping: str, table=None):
    """The frames' truth labels (:class:`TruthMaps`, read through ``table``); a folder's checked first, every
    one, one at a time."""
    from ..errors import InputError

    if folder is None:
        return None
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"--truth {root}: not a folder")
    truth = TruthMaps(root, frames, mapping, shape, table)
    if frames.kind == "folder":
        for t in range(len(frames)):
            truth.digest(t)
    return truth


def check_spares_inputs(out: Path, frames, labels: Path, truth, *, writes: tuple[str, ...] = ()) -> None:
    """Refuse an ``--out`` whose label PNGs (``OUT/NAME.png`` per frame) would overwrite a frame, the key
    frame's labels or a truth map: ``--out`` the frames' own folder, say; or an input in a folder of ``--out`` the
    run ``writes`` in (``confidence``, ``.keys``)."""
    from ..errors import InputError

    resolved(out)  # a loop of symbolic links named as the --out it is
    if truth is not None and resolved(truth.root) == resolved(out):
        raise InputError(f"--out {out} would overwrite the truth maps in {truth.root}; choose another folder")
    if frames.kind == "folder":
        written = set(_resolved_all([os.path.join(out, f"{p.stem}.png") for p in frames.paths]))
        clobbered = [f for f, where in zip([*frames.paths, labels], _resolved_all([*frames.paths, labels])) if where in written]
        # the frames' own folder: NAME.png written beside NAME.jpg would be read as a second frame NAME
        if not clobbered and frames.paths and resolved(out) == resolved(frames.paths[0].parent):
            raise InputError(f"--out {out} is the frames' own folder; its label PNGs would be read as frames "
                             "beside them; choose another folder")
        # a folder read from itself reads its images/ sub-folder once there is one: the label PNGs, next time
        if not clobbered and frames.source == frames.path and resolved(out) == resolved(frames.path / "images"):
            raise InputError(f"--out {out} is the images/ sub-folder of the frames' folder, which pcreg reads frames "
                             "from once it exists: the next run would read the label PNGs as the frames; choose "
                             "another folder")
    else:  # a video's outputs are OUT/{i:06d}.png, as many as it has frames
        clobbered = [labels] if frames.writes(labels.stem) and resolved(out / f"{labels.stem}.png") == resolved(labels) else []
    if clobbered:
        raise InputError(f"--out {out} would overwrite the input {clobbered[0]}; choose another folder")
    for sub in writes:  # confidence maps written among key labels read from there: later runs refused them
        _check_apart(out, sub, [p for p in (frames.path, labels, truth and truth.root) if p is not None])


def _resolved_all(paths: Sequence[str | os.PathLike[str]]) -> list[str]:
    """Each of ``paths`` as :func:`~pcreg.formats.resolved` gives it, as text, each folder resolved once: a path that is
    no link is its resolved folder joined with its name (an hour's frames took seconds resolved one by one, each
    folder of each path's again, and as many Path objects)."""
    folders: dict[str, str] = {}
    out = []
    for p in paths:
        head, name = os.path.split(os.fspath(p))
        if name in ("", ".", "..") or os.path.islink(p):
            out.append(str(resolved(p)))
            continue
        if head not in folders:
            folders[head] = str(resolved(head or "."))
        out.append(os.path.join(folders[head], name))
    return out


def _check_apart(out: Path, sub: str, inputs: list[Path]) -> None:
    """Refuse an input that lies in ``OUT/sub``, a folder the run writes into."""
    from ..errors import InputError

    place = resolved(out / sub)
    for given in inputs:
        where = resolved(given)
        if where == place or place in where.parents:
            raise InputError(f"{given}: lies in {out / sub}, where this run writes its "
                             f"{'confidence maps' if sub == CONFIDENCE else 'passes'}; move it out of --out, "
                             "or choose another --out")


def check_suggest(count: int | None, frames, keys: int) -> None:
    """``--suggest N`` no larger than the frames that are not key frames (a video's count where its
    container gives it; else checked once the run has decoded them all)."""
    from ..errors import InputError

    n = len(frames) if frames.kind == "folder" else frames.count()
    if count is not None and n is not None and count > n - keys:
        raise InputError(f"--suggest {count}: only {n - keys} frame(s) are not key frames")
    if count is not None and frames.kind == "folder":  # suggest.txt lists a name and a tab a line
        odd = next((frames.name(t) for t in range(len(frames))
                    if "\t" in frames.stem(t) or frames.stem(t).splitlines() != [frames.stem(t)]), None)
        if odd is not None:
            raise InputError(f"--suggest {count}: the frame name {odd!r} holds a tab or a line break, which "
                             "suggest.txt (a name and a tab a line) cannot list; rename the frame")


def _frame_stems(frames, files: list[Path]) -> list[str]:
    """The frame each label file names by its stem: ``NAME_L.png``, as CamVid's download names its labels, the
    frame ``NAME`` when ``NAME_L`` names none and ``NAME`` does (a chosen frame, or one of the source that
    ``--start``, ``--stop`` or ``--every`` leaves out, so that its label is told apart as any other); else the stem
    as it is."""
    from ..classes.cvat import frame_positions, source_indices
    from ..datasets.folder import LABEL_SUFFIX

    where, index_of = frame_positions(frames), source_indices(frames)

    def names(stem: str) -> bool:
        return where(stem) is not None or index_of(stem) is not None

    return [f.stem[: -len(LABEL_SUFFIX)] if f.stem.endswith(LABEL_SUFFIX) and not names(f.stem)
            and names(f.stem[: -len(LABEL_SUFFIX)]) else f.stem for f in files]


def other_labels_note(folder: Path, frames) -> str | None:
    """A note naming the image files of ``folder`` (a folder of key frames' labels) in another format than PNG that
    name a frame as a key label does (:func:`_frame_stems`) with no ``NAME.png`` beside them: they are not read, and a
    key frame someone drew and saved as a JPEG (which changes the values at every edge) or a TIFF would otherwise be
    passed over without a word (they may also be copies of the frames, kept beside their labels); None when there are none."""
    said = _other_labels(folder, frames)
    return None if said is None else f"--labels {folder}: {said}"


def _other_labels(folder: Path, frames) -> str | None:
    """What :func:`other_labels_note` says of ``folder``'s files, without naming the folder; None when there are none."""
    from ..classes.cvat import frame_positions
    from ..formats import IMAGE_SUFFIXES
    from ..validation import listed

    shown = [p for p in sorted(folder.iterdir()) if not p.name.startswith(".")]
    pngs = {p.stem for p in shown if p.suffix.lower() == ".png"}
    other = [p for p in shown if p.suffix.lower() in IMAGE_SUFFIXES and p.suffix.lower() != ".png" and p.stem not in pngs]
    where = frame_positions(frames)
    named = [p.name for p, stem in zip(other, _frame_stems(frames, other)) if where(stem) is not None]
    if not named:
        return None
    n = len(named)
    return (f"{n} image{'s' if n > 1 else ''} named as {'frames' if n > 1 else 'a frame'} but not PNG, not read as key "
            f"labels ({listed(named)}); a key label is NAME.png (lossless: a JPEG changes the values at every edge)")


def read_key_labels(folder: Path, frames, mapping: str, shape: tuple[int, int], table=None, *,
                    left_out: list[str] | None = None) -> dict:
    """``{position: labels}`` of the label PNGs in ``folder`` (``NAME.png`` labels the frame ``NAME``, or
    ``NAME_L.png`` as CamVid's download names it (:func:`_frame_stems`), and ``frame_NNNNNN.png`` the source
    frame NNNNNN, as CVAT names them: :func:`~pcreg.classes.cvat.frame_positions`), read through
    ``table`` (None: ``lagr``), each checked: a frame it names, one label a frame, the frames' size, something
    known. Given a ``left_out`` list, a label of a frame outside the chosen stretch
    (:func:`~pcreg.classes.cvat.outside_chosen`) is left out, its name added to the list, not refused."""
    from ..classes import DEFAULT_TABLE
    from ..classes.cvat import chosen_around, export_within, named_frames, outside_chosen, outside_text, placed
    from ..errors import InputError

    table = DEFAULT_TABLE if table is None else table
    files = only_files(sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png" and not p.name.startswith(".")),
                       "key labels")
    if not files:
        other = _other_labels(folder, frames)
        raise InputError(f"--labels {folder}: holds no label PNG (NAME.png for the frame NAME)"
                         + (export_within(folder) if other is None else f"; {other}"))
    stems = _frame_stems(frames, files)
    positions = placed(frames, stems, folder)
    keys: dict = {}
    seen: dict[int, Path] = {}
    outside = outside_chosen(frames)
    for f, stem, t in zip(files, stems, positions):
        if t is None and left_out is not None and outside(stem):
            left_out.append(f.name)
            continue
        if t is None:
            around = chosen_around(frames, stem)  # a frame of the stretch --every steps over: its name is right
            raise InputError(f"{f}: names no frame of {frames.path} ({named_frames(frames)})"
                             + ("" if frames.selection.to_dict() is None else " among those chosen")
                             + (around or "; a key label is named as its frame: NAME.png labels the frame NAME (as do "
                                          "NAME_L.png and CVAT's frame_NNNNNN.png)"))
        if t in seen:
            raise InputError(f"{f}: a second label for the frame {frames.name(t)} (also {seen[t].name})")
        lab = read_labels(f, mapping, table)
        if lab.shape != shape:
            turned = frames.turned_note(t, lab.shape, shape)
            raise InputError(f"{f}: labels are {lab.shape[1]}x{lab.shape[0]}, the frames {shape[1]}x{shape[0]}{turned}")
        _check_known(f, lab, table)
        keys[t], seen[t] = lab, f
    if not keys:  # every label of a frame outside the stretch
        raise InputError(f"--labels {folder}: every key label names a frame outside those chosen "
                         f"{outside_text(left_out or [], frames.selection)}")
    if mapping == "davis":
        from ..classes.keys import check_one_object

        check_one_object(seen[t] for t in sorted(seen))
    return {t: keys[t] for t in sorted(keys)}

