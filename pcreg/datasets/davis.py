"""DAVIS sequences (``--data davis:PATH``): video frames with the objects' masks on every frame.

The benchmark (Perazzi et al., "A Benchmark Dataset and Evaluation Methodology for Video Object
Segmentation", CVPR 2016) gives the first frame's mask and asks for the object in every later frame. A
DAVIS 2016 mask's value 0 is the background, anything else the object: pcreg's labels 0 and 1
(:data:`DAVIS_MAPPING`, ``pcreg run --mapping davis``). DAVIS 2017 stores several objects in one palette
PNG, indices 1..N the objects, 0 the background, 255 void: each object of the first frame is a clip of its
own, ``SEQ_K``, scored on its own as the DAVIS 2017 evaluation does (:func:`load_objects`); so is a grey mask
of those ids, or an RGB mask in the palette's colours. Two layouts are
read (:func:`find_sequences`), PATH naming one sequence or a folder of them:

- pcreg's (as in ``../shared/data/davis``): ``SEQ/images/NNNNN.jpg`` with ``SEQ/labels/NNNNN.png``;
- the official one: ``ROOT/JPEGImages/480p/SEQ/NNNNN.jpg`` with ``ROOT/Annotations/480p/SEQ/NNNNN.png``,
  PATH being ``ROOT``, ``ROOT/JPEGImages/480p`` or ``ROOT/JPEGImages/480p/SEQ`` (another resolution
  folder, ``1080p`` or ``Full-Resolution``, where ``480p`` is absent).

At an official root only the split its ``ImageSets`` names is read, DAVIS 2016 val by default
(``davis:ROOT:train`` or ``davis:ROOT:all`` for others; :mod:`pcreg.datasets.davis_splits`).

The benchmark's published per-sequence results (:func:`published`) come from a ``published_*.csv``
beside the sequences when there is one, else from the figures pcreg ships
(:data:`PUBLISHED_CSV`: the twenty sequences of DAVIS 2016 val, for users of the official layout, whose
copy has none).
"""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import DatasetError, InputError
from ..classes.mappings import DAVIS_MAPPING, mask_hint
from .davis_splits import DavisSplit, choose_split
from .frame import Frame
from .folder import no_folder, not_png_note, refuse_frameless
from .sources import _check_numbering

__all__ = ["DAVIS_MAPPING", "RESOLUTIONS", "PUBLISHED_CSV", "PUBLISHED_SOURCE", "find_sequences", "select_sequences",
           "check_key_mask", "mask_hint", "object_name", "load_objects", "load_sequence", "load_davis", "objects_of",
           "published"]

#: The official layout's resolution folders, the one read first first.
RESOLUTIONS: tuple[str, ...] = ("480p", "1080p", "Full-Resolution")
#: The figures pcreg ships: per method and sequence of DAVIS 2016 val, J and F averaged over frames 1..n-2.
PUBLISHED_CSV = Path(__file__).with_name("published_davis2016_val.csv")
#: Where :data:`PUBLISHED_CSV`'s figures come from.
PUBLISHED_SOURCE = ("the DAVIS website's data, davisvideochallenge/davisvideochallenge.github.io, "
                    "json_data/raw_eval/2016/METHOD_davis.json (the per-frame J and F whose means "
                    "json_data/global_eval_val_2016.js lists)")

_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


def _dirs(path: Path) -> list[Path]:
    """The sub-folders of ``path`` in name order; hidden ones left out (``.ipynb_checkpoints``, as hidden files)."""
    return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))


def _official_root(path: Path) -> tuple[Path, str] | None:
    """(ROOT, resolution) when ``path`` is ``ROOT`` of the official layout, else None."""
    for res in RESOLUTIONS:
        if (path / "JPEGImages" / res).is_dir():
            return path, res
    return None


def _locate(p: Path) -> tuple[dict[str, tuple[Path, Path]], Path, Path | None, str | None]:
    """Every sequence at ``p`` (as :func:`find_sequences`), the folder beside them, and the official root and
    resolution when ``p`` is ``ROOT`` or ``ROOT/JPEGImages/RES`` (else None, None)."""
    root = _official_root(p)
    if (p / "images").is_dir():  # pcreg's layout, one sequence
        if root is not None:  # read as one sequence, the official layout beside it was left out without a word
            raise DatasetError(f"{p}: a sequence in pcreg's layout (images/) and DAVIS's official layout "
                               f"(JPEGImages/{root[1]}/) in one folder: give davis:{p / 'JPEGImages' / root[1]} for the "
                               "official sequences, and move images/ and labels/ to a folder of their own")
        return {p.name: (p / "images", p / "labels")}, p.parent, None, None
    if root is not None:  # ROOT
        img_root, ann_root, beside = p / "JPEGImages" / root[1], p / "Annotations" / root[1], p
        ours = [d.name for d in _dirs(p) if (d / "images").is_dir()]
        if ours:  # read as the official layout alone, they were left out without a word
            raise DatasetError(f"{p}: holds DAVIS's official layout (JPEGImages/{root[1]}/) and sequences in pcreg's "
                               f"({', '.join(ours[:3])}{', ...' if len(ours) > 3 else ''}: SEQ/images/): give "
                               f"davis:{p / 'JPEGImages' / root[1]} for the official ones, and move the others to a "
                               "folder of their own")
    elif p.name in RESOLUTIONS and p.parent.name == "JPEGImages":  # ROOT/JPEGImages/480p
        img_root, ann_root, beside = p, p.parent.parent / "Annotations" / p.name, p.parent.parent
        root = (p.parent.parent, p.name)
    elif p.parent.name in RESOLUTIONS and p.parent.parent.name == "JPEGImages":  # ROOT/JPEGImages/480p/SEQ
        ann = p.parent.parent.parent / "Annotations" / p.parent.name / p.name
        return {p.name: (p, ann)}, p.parent.parent.parent, None, None
    else:  # pcreg's layout, a folder of sequences
        refuse_frameless(p, "sequence")
        seqs = [d for d in _dirs(p) if (d / "images").is_dir()]
        if not seqs:
            _refuse_youtube_vos(p)
            raise DatasetError(f"{p}: no DAVIS sequence (no SEQ/images/ folder, and no JPEGImages/480p/ of the "
                               "official layout)")
        return {d.name: (d / "images", d / "labels") for d in seqs}, p, None, None
    seqs = _dirs(img_root)
    if not seqs:
        raise DatasetError(f"{img_root}: no sequence folder")
    return {d.name: (d, ann_root / d.name) for d in seqs}, beside, root[0], root[1]


def _refuse_youtube_vos(p: Path) -> None:
    """A :class:`DatasetError` when ``p`` is laid out as YouTube-VOS is (``ROOT/JPEGImages/SEQ/`` beside
    ``ROOT/Annotations/SEQ/``, no resolution folder; ``p`` the root or a folder of it): its masks are not DAVIS's
    (every fifth frame, objects that enter after the first frame, ``meta.json`` naming them), so it is not read
    as DAVIS's official layout. The line says how to give its sequences."""
    for root in (p, p.parent, p.parent.parent):
        if root.name in ("JPEGImages", "Annotations") or not (root / "JPEGImages").is_dir() \
                or not (root / "Annotations").is_dir() or _official_root(root) is not None:
            continue
        raise DatasetError(f"{p}: YouTube-VOS's layout (JPEGImages/SEQ/ beside Annotations/SEQ/, no 480p/ folder) is "
                           "not read as DAVIS's, whose masks cover every frame and the first frame's objects: give "
                           "each sequence as SEQ/images/ and SEQ/labels/, a mask for every frame (0 the background, "
                           "1..N the objects of the first frame)")


def select_sequences(path: str | Path, *, split: str | None = None
                     ) -> tuple[dict[str, tuple[Path, Path]], Path, DavisSplit]:
    """:func:`find_sequences`, and which split they are (:class:`~pcreg.datasets.davis_splits.DavisSplit`):
    at an official root (``ROOT`` or ``ROOT/JPEGImages/480p``) the ``split`` named (``val``, ``train`` or
    ``all``; None: ``val`` when ``ImageSets`` has its list, else all), elsewhere all of them."""
    p = Path(path).expanduser()
    if not p.is_dir():
        raise no_folder(p)
    seqs, beside, root, res = _locate(p)
    chosen = choose_split(list(seqs), root=root, resolution=res, split=split, where=p)
    frames = next(iter(seqs.values()))[0]  # the official layout's ROOT/JPEGImages/RES/SEQ, whichever PATH named
    if frames.parent.name in RESOLUTIONS and frames.parent.parent.name == "JPEGImages":
        chosen = replace(chosen, resolution=frames.parent.name)
    return {n: seqs[n] for n in chosen.sequences}, beside, chosen


def find_sequences(path: str | Path, *, split: str | None = None) -> tuple[dict[str, tuple[Path, Path]], Path]:
    """The sequences at ``path`` (the module's layouts): ``{name: (frames folder, masks folder)}`` in name
    order, and the folder they lie in (where :func:`published` looks for a ``published_*.csv``). At an
    official root, those of ``split`` (:func:`select_sequences`: DAVIS 2016 val by default when the download's
    ``ImageSets`` names it)."""
    seqs, beside, _ = select_sequences(path, split=split)
    return seqs, beside


def _read_frame(path: Path) -> tuple[np.ndarray, str]:
    """A frame (H, W, 3) uint8 RGB (a regular file, its size checked in the header before decoding), and what its
    decoder said of damaged data it decoded around, or "" (:func:`pcreg.formats.read_image_file_and_damage`)."""
    import cv2

    from ..formats import read_image_file_and_damage

    try:
        img, damage = read_image_file_and_damage(path, flags=cv2.IMREAD_COLOR)
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB), damage


def _mask(path: Path, frame: Path, shape: tuple[int, int]) -> tuple[np.ndarray, bool]:
    """The mask's values (H, W) uint8 and whether they are object ids (DAVIS 2017's: a palette PNG's indices, as
    VOC stores masks, or those ids as grey values or as the palette's colours), else a grey value or a colour,
    nonzero the object (:func:`pcreg.classes.keys.read_object_mask`)."""
    from ..classes.keys import read_object_mask

    try:
        values, palette = read_object_mask(path)
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    if values.shape[:2] != shape:
        raise DatasetError(f"{path}: the mask is {values.shape[1]}x{values.shape[0]}, its frame {frame.name} "
                           f"{shape[1]}x{shape[0]}")
    return values, palette


def check_key_mask(labels: np.ndarray, path: str | Path) -> None:
    """Refuse a key frame's mask (pcreg's labels) with no object pixel, or no background pixel, naming its file
    ``path``."""
    labels = np.asarray(labels)
    if not (labels == 1).any():
        raise DatasetError(f"{path}: the object's mask on the key frame is empty: there is no object to follow")
    if not (labels == 0).any():
        raise DatasetError(f"{path}: the object's mask on the key frame covers the whole frame: no background pixel, "
                           "which the classifier needs beside the object's")


def _frame_files(frames: Path, name: str, n_frames: int | None) -> list[Path]:
    from ..formats import only_files

    try:  # hidden: macOS's ._NAME, as pcreg run; a link to nothing named as a frame refused, as pcreg run refuses it
        files = only_files(sorted(f for f in frames.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES
                                  and not f.name.startswith(".")), "a frame") if frames.is_dir() else []
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    try:  # frames in name order, as pcreg run reads them: 10.jpg before 9.jpg is refused
        _check_numbering(frames, [f.name for f in files])
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    if not files:
        raise DatasetError(f"{frames}: no frames (.jpg, .png) in sequence {name}")
    twice = [(f, g) for f, g in zip(files, files[1:]) if f.stem == g.stem]  # 00000.jpg and 00000.png: which one?
    if twice:
        raise DatasetError(f"{twice[0][0]}: a second frame of this name beside it, {twice[0][1].name}; keep one")
    return files[:n_frames] if n_frames is not None else files


def _numbering_gaps(files: list[Path]) -> dict[str, tuple[str, ...]]:
    """``{stem: (note,)}`` of each frame of ``files`` (numbered names, in order) whose number is more than one after
    the frame before it: a frame and its mask both missing (a copy cut short), which no mask without its frame tells.
    DAVIS numbers every frame, so the motion to that frame spans two or more, and the frames scored are not all the
    benchmark's."""
    if not all(f.stem.isdigit() for f in files):
        return {}
    notes: dict[str, tuple[str, ...]] = {}
    for a, b in zip(files, files[1:]):
        missing = int(b.stem) - int(a.stem) - 1
        if missing > 0:
            notes[b.stem] = (f"{missing} frame(s) missing from the numbering before it ({a.stem}, then {b.stem}), "
                             "frame and mask (a copy cut short?): DAVIS numbers every frame, so the motion to it spans "
                             f"{missing + 1} and the frames scored are not all the benchmark's",)
    return notes


def _check_masks_have_frames(masks: Path, files: list[Path]) -> None:
    """Refuse a mask of ``masks`` (a PNG, hidden files left out) whose frame is not among ``files``: a frame
    missing from the sequence (a copy cut short) would move every later frame up one, and other frames than
    the benchmark's would be scored."""
    if not masks.is_dir():
        return
    stems = {f.stem for f in files}
    for m in sorted(masks.iterdir()):
        if m.suffix.lower() == ".png" and m.is_file() and not m.name.startswith(".") and m.stem not in stems:
            raise DatasetError(f"{m}: a mask without its frame (no {m.stem}.jpg or .png in {files[0].parent}): "
                               "DAVIS masks every frame, and a frame missing would shift the frames scored")


def _mask_file(masks: Path, stem: str) -> Path:
    """``masks/STEM.png``, or ``STEM.PNG`` where only that is (masks saved on Windows), as frames' suffixes are read
    in any case."""
    m = masks / f"{stem}.png"
    upper = m.with_suffix(".PNG")
    return upper if not m.is_file() and upper.is_file() else m


def object_name(sequence: str, obj: int) -> str:
    """The clip name of object ``obj`` of a multi-object sequence: ``SEQ_K``, as davis2017-evaluation names
    its per-object rows."""
    return f"{sequence}_{obj}"


def load_objects(frames: str | Path, masks: str | Path, *, n_frames: int | None = None,
                 name: str | None = None) -> dict[str, list[Frame]]:
    """One sequence, one clip per object: every image of ``frames`` (.jpg, .jpeg or .png, in name order; the
    first ``n_frames``) with its mask ``masks/STEM.png`` as labels (0 background, 1 the object, 2 void).

    A mask of one object (DAVIS 2016's 0/255, a grey or colour mask: nonzero the object; a palette of one
    index) gives ``{name: frames}``. A mask whose first frame holds several object ids (DAVIS 2017: a palette
    PNG's indices 1..254, 0 the background, 255 void; or those ids saved as grey values or as the palette's
    colours, :func:`pcreg.classes.keys.object_values`) gives one clip per id, ``{name_K: frames}``
    (:func:`object_name`), each with object K as 1 and every other object as background, as the DAVIS 2017
    evaluation scores each object on its own (davis2017-evaluation ``davis2017/davis.py``
    ``get_all_masks``: the objects are those of the first frame). A void index is label 2 (unknown), on every
    frame of such a sequence, whether its first frame shows void or not.

    Refused with a :class:`~pcreg.errors.DatasetError` naming the file: no frame, no mask for the first
    frame, an empty object on it, a missing mask of a later frame, a mask without its frame, a mask of
    another size than its frame, a frame or mask that does not decode.
    """
    from ..classes.mappings import VOID_INDEX, object_labels, palette_objects

    frames, masks = Path(frames), Path(masks)
    name = name or frames.name
    every = _frame_files(frames, name, None)
    _check_masks_have_frames(masks, every)
    files = every[:n_frames] if n_frames is not None else every
    gaps = _numbering_gaps(files)
    objects: tuple[int | None, ...] = (None,)
    void = None
    out: dict[int | None, list[Frame]] = {}
    for t, f in enumerate(files):
        m = _mask_file(masks, f.stem)
        if not m.is_file():
            what = "no mask of the first frame: DAVIS gives the object on frame 0" if t == 0 else \
                f"no mask of frame {f.name}: every frame is scored"
            raise DatasetError(f"{m}: {what}{not_png_note(masks, f.stem)}")
        image, damage = _read_frame(f)
        values, by_id = _mask(m, f, image.shape[:2])
        if t == 0 and by_id:  # the objects are the first frame's (its palette's indices)
            ids = palette_objects(values)[0]
            objects = ids if ids else (None,)
            # 255 is void on every frame, whether or not the first shows any (DAVIS 2016's 0/255: the object)
            void = VOID_INDEX if ids and VOID_INDEX not in ids else None
        # DAVIS 2016's 0/255 after a first mask of one object by its id (saved again as a palette): 255 the object
        grey_object = t > 0 and not by_id and void is not None and len(objects) == 1 \
            and set(np.unique(values).tolist()) == {0, VOID_INDEX}
        if t > 0 and not by_id and len(objects) > 1 and set(np.unique(values).tolist()) == {0, VOID_INDEX}:
            # 255 would be void on every frame, its objects never scored (J 0 for every method, and no word)
            raise DatasetError(f"{m}: a grey mask of one object (0 and 255, DAVIS 2016's) after a first mask of "
                               f"{len(objects)} objects by palette index ({_mask_file(masks, files[0].stem).name}): "
                               "the sequence's masks read two ways; save every mask one way")
        later = palette_objects(values)[0] if t > 0 and by_id and objects == (None,) else ()
        if len(later) > 1:  # their union would be scored as the first frame's one object, and no word
            raise DatasetError(f"{m}: a mask of {len(later)} objects by palette index ({', '.join(map(str, later))}) after "
                               f"a first mask of one object ({_mask_file(masks, files[0].stem).name}): the sequence's "
                               "masks read two ways; save every mask one way")
        for k in objects:
            labels = object_labels(values) if grey_object else object_labels(values, k, void)
            if t == 0:
                check_key_mask(labels, m if len(objects) == 1 else f"{m} (object {k})")
            out.setdefault(k, []).append(Frame(image=image, labels=labels, name=f.stem, damage=damage,
                                               notes=gaps.get(f.stem, ())))
    if len(objects) == 1:
        return {name: out[objects[0]]}
    return {object_name(name, int(k)): out[k] for k in objects if k is not None}


def load_sequence(frames: str | Path, masks: str | Path, *, n_frames: int | None = None,
                  name: str | None = None) -> list[Frame]:
    """One sequence of one object (:func:`load_objects`): its frames with labels 0 background, 1 the object.
    A sequence of several objects (DAVIS 2017's palette masks) is refused naming the first frame's mask and
    its object ids: :func:`load_objects` (and ``--data davis:PATH``) reads each object on its own."""
    clips = load_objects(frames, masks, n_frames=n_frames, name=name)
    if len(clips) > 1:
        first = _mask_file(Path(masks), next(iter(clips.values()))[0].name)  # the file read, .png or .PNG
        ids = ", ".join(c.rpartition("_")[2] for c in clips)
        raise DatasetError(f"{first}: a mask of {len(clips)} objects (palette indices {ids}); load_objects "
                           "reads each object as a sequence of its own")
    return next(iter(clips.values()))


def load_davis(path: str | Path, *, n_frames: int | None = None, split: str | None = None) -> dict[str, list[Frame]]:
    """Every sequence at ``path`` (:func:`find_sequences`; at an official root those of ``split``, DAVIS 2016
    val by default when ``ImageSets`` names it), ``{name: frames}``; ``n_frames`` keeps each sequence's first
    frames. A sequence of several objects (DAVIS 2017) is one clip per object, ``SEQ_K``
    (:func:`load_objects`); a clip name that another sequence's name takes is refused."""
    seqs, _ = find_sequences(path, split=split)
    out: dict[str, list[Frame]] = {}
    for n, (f, m) in seqs.items():
        for clip, frames in load_objects(f, m, n_frames=n_frames, name=n).items():
            if clip in out or (clip != n and clip in seqs):
                raise DatasetError(f"{f}: object clip {clip} of sequence {n} has the name of another sequence; "
                                   "rename one of them")
            out[clip] = frames
    return out


def objects_of(clips, sequences) -> dict[str, list[str]]:
    """``{sequence: [clip per object]}`` of the multi-object sequences among ``clips`` (names :func:`load_davis`
    gave), ``sequences`` being the sequence names they came from (:func:`find_sequences`)."""
    out: dict[str, list[str]] = {}
    for c in clips:
        base, _, k = str(c).rpartition("_")
        if c not in sequences and base in sequences and k.isdigit():
            out.setdefault(base, []).append(c)
    return out


def _read_published(path: Path) -> list[dict]:
    rows = []
    try:
        # utf-8-sig: a byte-order mark (Excel's "CSV UTF-8") is no part of the first column's name
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = [ln for ln in fh if not ln.startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read the published results ({exc})") from None
    reader = csv.DictReader(lines)
    need = {"method", "sequence", "J_mean", "F_mean"}
    if not need <= set(reader.fieldnames or ()):
        raise DatasetError(f"{path}: published results need the columns {', '.join(sorted(need))}")
    for i, r in enumerate(reader, start=2):
        try:
            frames = (r.get("n_frames_evaluated") or "").strip()  # optional: how many frames the figures are over
            rows.append({"method": r["method"].strip(), "sequence": r["sequence"].strip(),
                         "J": float(r["J_mean"]), "F": float(r["F_mean"]), "frames": int(frames) if frames else None,
                         "at": f"{path}: line {i}"})
        except (TypeError, ValueError, AttributeError):
            raise DatasetError(f"{path}: line {i} is not method, sequence, J_mean, F_mean") from None
    if not rows:  # the published columns would vanish from the tables without a word
        raise DatasetError(f"{path}: no published figure, its header alone (remove it, and pcreg's own copy of the "
                           "benchmark's figures stands beside the sequences)")
    return rows


def _refuse_two_figures(rows: list[dict]) -> None:
    """A :class:`DatasetError` naming both lines where one method has two figures of one sequence (the same figures
    twice are one): the table would show whichever came last."""
    def same(a, b) -> bool:
        return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))

    def said(r: dict) -> str:
        return f"J {r['J']!r}, F {r['F']!r}" + (f", {r['frames']} frames" if r["frames"] is not None else "")

    first: dict = {}
    for r in rows:
        seen = first.setdefault((r["method"], r["sequence"]), r)
        if seen is not r and not all(same(seen[k], r[k]) for k in ("J", "F", "frames")):
            raise DatasetError(f"{r['at']}: {r['method']} on {r['sequence']} has {said(r)} here and {said(seen)} at "
                               f"{seen['at']}: one figure each, or the tables would show whichever comes last")


def published(path: str | Path) -> dict:
    """The benchmark's published results for the sequences at ``path``: ``{"file": str, "source": str,
    "methods": [names in the file's order], "J": {method: {sequence: value}}, "F": {...}, "frames": {sequence:
    frames scored}}``, read from the ``published_*.csv`` files beside the sequences (columns method, sequence,
    J_mean, F_mean and, optional, n_frames_evaluated; lines
    starting with ``#`` skipped), else from :data:`PUBLISHED_CSV`.

    ``source`` cites where the figures come from: :data:`PUBLISHED_SOURCE` for pcreg's own, or for a file
    beside the sequences whose figures are those (within 0.0005) on every method and sequence both hold (the
    file named for the figures of methods or sequences pcreg does not ship); else the file itself, saying
    that it names no source.
    """
    _, beside, _ = select_sequences(path, split="all")  # where they lie, whichever split is evaluated
    files = sorted(beside.glob("published_*.csv"))
    rows = [r for f in files for r in _read_published(f)] if files else _read_published(PUBLISHED_CSV)
    source = PUBLISHED_SOURCE
    if files:
        ours = {(r["method"], r["sequence"]): r for r in _read_published(PUBLISHED_CSV)}
        shared = [(r, ours[(r["method"], r["sequence"])]) for r in rows if (r["method"], r["sequence"]) in ours]
        names = f"{', '.join(f.name for f in files)} (which names no source)"
        if not shared or any(abs(a[k] - b[k]) > 5e-4 for a, b in shared for k in ("J", "F")):
            source = names
        elif len(shared) < len(rows):  # the website's figures beside others: those others are the file's own
            own = dict.fromkeys(r["method"] for r in rows if (r["method"], r["sequence"]) not in ours)
            source = f"{PUBLISHED_SOURCE}, except the figures of {', '.join(own)} that pcreg does not ship: {names}"
    _refuse_two_figures(rows)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    doc: dict = {"file": ", ".join(str(f) for f in files) if files else str(PUBLISHED_CSV), "source": source,
                 "methods": methods, "J": {m: {} for m in methods}, "F": {m: {} for m in methods}, "frames": {}}
    for r in rows:
        doc["J"][r["method"]][r["sequence"]] = r["J"]
        doc["F"][r["method"]][r["sequence"]] = r["F"]
        if r["frames"] is not None:
            doc["frames"].setdefault(r["sequence"], r["frames"])
    return doc
