"""The files of a run's folder other than run.json (:mod:`pcreg.runs.state`), each written and read by
one pair of functions here, and nowhere else:

- labels, ``NAME.png``: :func:`write_labels`, a palette PNG in the class table's colours (and a run's
  readers read them back through :func:`pcreg.export.read_labels`);
- confidence, ``confidence/NAME.png``: :func:`write_confidence` (:func:`confidence_png`, a grey PNG);
- steps, ``steps.jsonl``: :func:`append_step`, :func:`step_lines`, :func:`parse_steps` and :func:`counted_steps`;
- the carry, ``carry-{0,1}.npz`` (and a key-frames stretch's own, under :data:`HIDDEN`): :func:`write_carry`,
  :func:`read_carry`;
- the frames to label next, ``suggest.txt``: :func:`write_suggestions`, :func:`read_suggestions`.

What a key-frames stretch's forward pass keeps for its backward pass (its prior terms, a video's frames) is
:mod:`pcreg.runs.kept`'s.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import stat
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import InputError, OutputError
from ..cloud_files import NPY_HEADER_ERRORS
from ..formats import loads_json

__all__ = ["check_steps_file", "StepTruth", "finite_figure", "step_class_iou", "STATE", "STEPS", "CARRY", "CONFIDENCE", "SUGGEST", "HIDDEN", "RUN_FILES", "EARLIER",
           "label_digest", "UNREADABLE_CARRY", "write_labels",
           "labels_written", "labels_of_frames_gone", "write_confidence", "write_grey", "confidence_png",
           "append_step", "step_lines", "parse_steps", "counted_steps", "write_carry", "read_carry", "label_file_problem", "read_confidence", "check_labelled",
           "write_suggestions", "read_suggestions", "drop_suggestions", "remove_partial_writes", "has_confidence", "SUMMARY_FIELDS"]

#: What the suggestions and a run's closing lines read of each step (:mod:`pcreg.runs.summary`), all that is kept of
#: it there: an hour's steps (108,000 at 30 frames a second) kept whole took about half a GB.
SUMMARY_FIELDS = ("frame", "predicted_error", "predicted_iou", "iou", "keys")

STATE = "run.json"  #: the run's record (pcreg.runs.state reads and writes it), the commit point of its steps
STEPS = "steps.jsonl"
CARRY = "carry-{}.npz"
CONFIDENCE = "confidence"
#: The frames suggested to label next: ``NAME<TAB>PREDICTED_ERROR`` a line, best first.
SUGGEST = "suggest.txt"
#: The hidden folder of a run from a folder of key frames that holds what a stretch's passes hand on.
HIDDEN = ".keys"
#: The run's own files and folders in ``OUT`` beside its label PNGs (what a run started over moves aside).
RUN_FILES: tuple[str, ...] = (CARRY.format(0), CARRY.format(1), HIDDEN, CONFIDENCE, SUGGEST, STEPS, STATE)
#: The folder in ``OUT`` that holds the earlier run's files while a run started over has not finished
#: (:mod:`pcreg.runs.earlier`).
EARLIER = ".earlier-run"
#: What reading a damaged carry file raises (a zip archive of .npy members).
UNREADABLE_CARRY: tuple[type[BaseException], ...] = (*NPY_HEADER_ERRORS, KeyError, EOFError, zipfile.BadZipFile,
                                                     zlib.error)


def label_digest(labels: np.ndarray) -> str:
    """A key frame's labels as run.json names them, to tell when they changed: the SHA-256 of their shape
    and bytes."""
    import hashlib

    lab = np.ascontiguousarray(labels, dtype=np.uint8)
    return hashlib.sha256(f"{lab.shape}".encode() + lab.tobytes()).hexdigest()


def write_labels(path: Path, labels: np.ndarray, table=None) -> None:
    """(H, W) uint8 class ids of ``table`` (a :class:`~pcreg.classes.ClassTable`; None: ``lagr``) as a
    palette PNG at ``path``, atomically: the values the ids, the palette the table's colours
    (:func:`pcreg.classes.write_label_png`), so that any viewer shows the classes."""
    from ..classes import DEFAULT_TABLE, write_label_png

    write_label_png(path, np.asarray(labels), DEFAULT_TABLE if table is None else table)


def write_confidence(path: Path, confidence: np.ndarray) -> None:
    """A confidence map ((H, W) in [0, 1]) as a grey PNG at ``path``, atomically (:func:`confidence_png`)."""
    write_grey(path, confidence_png(confidence))


def write_grey(path: Path, values: np.ndarray) -> None:
    """An (H, W) uint8 map as a grey PNG at ``path``, atomically."""
    import cv2

    from ..outputs import atomic_write_bytes

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(values, dtype=np.uint8))
    if not ok:
        raise OutputError(f"cannot encode {path}")
    atomic_write_bytes(path, buf.tobytes())


def confidence_png(confidence: np.ndarray) -> np.ndarray:
    """(H, W) uint8: 255 times the probability that the label is right, rounded. A confidence that is
    NaN or outside [0, 1] is a bug, never written."""
    c = np.asarray(confidence, dtype=np.float32)
    if not (np.all(np.isfinite(c)) and c.min(initial=0.0) >= 0.0 and c.max(initial=0.0) <= 1.0):
        raise AssertionError("a confidence outside [0, 1] reached the writer")
    return np.rint(c * 255.0).astype(np.uint8)


def check_steps_file(steps: Path, *, force: bool) -> None:
    """In a folder of no run, a ``steps`` (steps.jsonl) that is no file of its own, which a run's appends would go
    through (a link's target, a hard link's other names, a pipe's reader): an OutputError; ``force`` removes it."""
    try:
        st = steps.lstat()
    except FileNotFoundError:
        return
    kind = stat.S_IFMT(st.st_mode)
    if kind == stat.S_IFREG and st.st_nlink == 1:
        return
    if force and kind != stat.S_IFDIR:
        return steps.unlink()  # the link or name itself, not the file it names
    what = {stat.S_IFREG: f"a file of {st.st_nlink} names (a hard link)", stat.S_IFLNK: "a link", stat.S_IFDIR: "a folder",
            stat.S_IFIFO: "a named pipe"}.get(kind, "a device or socket")
    raise OutputError(f"{steps}: {what}, not a file of its own, where a run appends its steps; give another --out"
                      + ("" if kind == stat.S_IFDIR else ", or --force to remove it (not what it names)"))


def append_step(out: Path, step: dict) -> None:
    """One line of ``out``'s steps.jsonl: ``step`` as strict JSON (NaN and infinities as null). A write the
    file system refuses (a full disk) is an :class:`~pcreg.errors.OutputError` naming the file, and the
    part of the line written is cut off again where the file system lets it be."""
    from ..outputs import to_json

    path = out / STEPS
    line = (json.dumps(json.loads(to_json(step, strict=True))) + "\n").encode()
    try:
        with open(path, "ab", buffering=0) as fh:
            size = fh.seek(0, os.SEEK_END)
            try:
                written = 0
                while written < len(line):
                    written += fh.write(line[written:])
            except OSError:
                with contextlib.suppress(OSError):
                    fh.truncate(size)
                raise
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None


def step_lines(out: Path) -> Iterator[bytes]:
    """The lines of ``out``'s steps.jsonl one at a time, as written (none when there is no such file): an
    hour's run at 30 frames a second holds about a hundred thousand (some 190 MB), which no reader holds at
    once."""
    path = out / STEPS
    if not path.is_file():
        return
    with open(path, "rb") as fh:
        yield from fh


def parse_steps(path: Path, lines: Iterable[bytes]) -> Iterator[dict]:
    """The steps of ``lines`` of a run's steps.jsonl (``path``), one at a time, each a dict whose ``frame`` is
    an int and whose ``predicted_error`` is a finite number or None; a line that is not one pcreg run wrote is
    an :class:`~pcreg.errors.OutputError` naming it."""
    for i, line in enumerate(lines):
        step = _step(line)
        if step is None:
            raise OutputError(f"{path}: line {i + 1} is not a step pcreg run wrote; use --force to start over")
        yield step


def counted_steps(out: Path, count: int, *, recount: Callable[[], int] | None = None) -> Iterator[dict]:
    """For a reader of a finished or stopped run (the export, the review): the ``count`` steps of ``out``'s
    steps.jsonl that its run.json counts, one at a time, as :func:`parse_steps` reads them (blank lines
    skipped; fewer when the file holds fewer). After them the file may hold only the step of a run stopped
    between writing it and committing it (:func:`append_step`), whole or cut off before its line break; a
    line among them that is not a step, or anything else after them, is an :class:`~pcreg.errors.InputError`
    naming the line, raised when the last step has been read. ``recount``: the count run.json gives now
    (:func:`pcreg.runs.state.steps_counted_now`), asked when more lines follow: a run being written, which
    counted more steps since ``count`` was read, has appended them (they are not read)."""
    path = out / STEPS
    numbered = ((i + 1, line) for i, line in enumerate(step_lines(out)) if line.strip())
    for n, line in itertools.islice(numbered, max(count, 0)):
        step = _step(line)
        if step is None:
            raise InputError(f"{path}: line {n} is not a step pcreg run wrote")
        yield step
    after = list(itertools.islice(numbered, 2))
    if len(after) > 1 and recount is not None and recount() > count:  # the run went on since
        return
    if len(after) > 1:
        raise InputError(f"{path}: line {after[1][0]} follows the {count} step(s) run.json counts and the one a "
                         "stopped run may leave after them (not a steps.jsonl pcreg run wrote)")
    if after and after[0][1].endswith(b"\n") and _step(after[0][1]) is None:  # whole, so not cut off by a kill
        raise InputError(f"{path}: line {after[0][0]} is not a step pcreg run wrote")


#: The figures of a step in % (each a number from 0 to 100, or none): pcreg writes a NaN as null.
PERCENT_FIGURES = ("predicted_error", "error", "plain_error")


def _step(line: bytes) -> dict | None:
    """A line of steps.jsonl as a step (a dict whose ``frame`` is an int and whose :data:`PERCENT_FIGURES` are each
    a number from 0 to 100 or None), or None: not one pcreg run wrote."""
    try:
        step = loads_json(line)
    except ValueError:  # not JSON, or not UTF-8
        return None
    ok = (isinstance(step, dict) and type(step.get("frame")) is int and step["frame"] >= 0
          and all(step.get(k) is None or (type(step[k]) in (int, float) and 0 <= step[k] <= 100) for k in PERCENT_FIGURES))
    return step if ok else None


def labels_written(out: Path) -> set[Path]:
    """The label PNGs the run in ``out`` wrote, as its run.json and steps.jsonl name their frames (its key frames' and
    each step's, ``OUT/STEM.png``): what a run started over removes, or a run over fewer frames (``--every``,
    ``--stop``) would leave the others beside its own. Only what can be read: a damaged run.json names no key frame,
    a line that is not a step no frame, a name with a folder in it nothing."""
    try:
        state = loads_json((out / STATE).read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        state = None
    names: list = []
    if isinstance(state, dict):
        keys = state.get("keys")
        names += [state.get("key_frame"), *(keys if isinstance(keys, dict) else ())]
    names += [step.get("name") for step in map(_step, step_lines(out)) if step is not None]
    return {out / f"{Path(n).stem}.png" for n in names if isinstance(n, str) and Path(n).name == n and Path(n).stem.strip(".")}


def write_carry(path: Path, t: int, carry, learned: np.ndarray | None = None, scene=None) -> None:
    """What step ``t`` hands to the next (a :class:`~pcreg.pipeline.stream.Carry`, a chained stream's
    :class:`~pcreg.pipeline.estimators.ChainCarry`, an object follower's
    :class:`~pcreg.pipeline.follow.FollowCarry`, or None, what the classifier has ``learned``, or
    None, and the cut test's last frame of the key frame's scene, a :class:`~pcreg.pipeline.cuts.Scene` or None:
    the ``scene_grey`` and ``scene_colours`` members), atomically at ``path``. A follower's carry is the ``follow`` member: its labels and grey
    levels, (2, h, w) uint8, ``follow_colours``, its colour histogram, and while a cut has lost the object
    ``follow_held`` and ``follow_held_colours``, the same of the last frame that held it; a chained stream's the ``chain_*`` members (:func:`_chain_members`)."""
    import io

    from ..outputs import atomic_write_bytes
    from ..pipeline.estimators import ChainCarry
    from ..pipeline.follow import FollowCarry

    buf = io.BytesIO()
    chain = _chain_members(carry) if isinstance(carry, ChainCarry) else {}
    carry = None if chain else carry
    follow = isinstance(carry, FollowCarry)
    grid = np.zeros((0, 0, 2), np.float32) if carry is None or follow else carry.grid
    evidence = float("nan") if carry is None or follow else carry.reference_evidence
    learned = np.zeros((0,), np.float64) if learned is None else np.asarray(learned, np.float64)
    members: dict = {"frame": np.int64(t), "grid": grid, "evidence": np.float64(evidence),
                                      "learned": learned}
    if follow:
        members["follow"] = np.stack([carry.labels, carry.grey])
        if carry.colours is not None:
            members["follow_colours"] = carry.colours
        if carry.held is not None:
            members["follow_held"] = np.stack([carry.held.labels, carry.held.grey])
            members["follow_held_colours"] = carry.held.colours
    if scene is not None:
        members.update(scene_grey=scene.grey, scene_colours=scene.colours)
    np.savez(buf, **members, **chain)
    atomic_write_bytes(path, buf.getvalue())


def read_carry(path: Path, t: int, unreadable: str, *, with_scene: bool = False):
    """``(carry, learned)`` that step ``t`` left at ``path`` (:func:`write_carry`): a
    :class:`~pcreg.pipeline.stream.Carry`, a :class:`~pcreg.pipeline.follow.FollowCarry` or None, and an
    array or None; ``with_scene``: ``(carry, learned, scene)``, the :class:`~pcreg.pipeline.cuts.Scene` or None
    (none kept: a carry written before it was, or a stream without the cut test). A missing or damaged file, or
    one of another step, is an :class:`~pcreg.errors.OutputError`: ``unreadable`` says what it stops."""
    from ..pipeline.stream import Carry

    bad = OutputError(f"{path}: missing or unreadable{unreadable}; use --force to start over")
    try:
        with np.load(path, allow_pickle=False) as z:
            frame, grid, evidence = np.array(z["frame"]), np.array(z["grid"]), np.array(z["evidence"])
            learned = np.array(z["learned"]) if "learned" in z.files else None
            follow = np.array(z["follow"]) if "follow" in z.files else None
            colours = np.array(z["follow_colours"]) if "follow_colours" in z.files else None
            held = [np.array(z[k]) for k in ("follow_held", "follow_held_colours") if k in z.files]
            chain = {k: np.array(z[k]) for k in z.files if k.startswith("chain_")}
            scene = [np.array(z[k]) for k in ("scene_grey", "scene_colours") if k in z.files]
    except UNREADABLE_CARRY:
        raise bad from None
    if frame.shape != () or frame.dtype.kind not in "iu" or evidence.shape != () or evidence.dtype.kind != "f":
        raise bad
    if int(frame) != t:
        raise OutputError(f"{path} holds frame {int(frame)}'s carry, not frame {t}'s; use --force to start over")
    if learned is not None and learned.dtype.kind not in "fiu":
        raise bad
    learned = None if learned is None or learned.size == 0 else learned
    kept = _scene(scene, bad)
    if chain:
        carry = _chain_carry(chain, bad)
    elif follow is not None:
        carry = _follow_carry(follow, colours, held, bad)
    elif grid.shape == (0, 0, 2) and np.isnan(evidence):  # that step left none
        carry = None
    else:
        try:
            carry = Carry(grid, float(evidence))
        except InputError as exc:
            raise OutputError(f"{path}: {exc}; use --force to start over") from None
    return (carry, learned, kept) if with_scene else (carry, learned)


def _scene(members: list, bad: OutputError):
    """The :class:`~pcreg.pipeline.cuts.Scene` of a carry's ``scene_grey`` and ``scene_colours`` members
    (:func:`write_carry`), None without them; one member alone, or a malformed one, is ``bad``."""
    from ..pipeline.cuts import Scene

    if not members:
        return None
    if len(members) != 2:
        raise bad
    try:
        return Scene(*members)
    except InputError:
        raise bad from None


def _follow_carry(follow: np.ndarray, colours: np.ndarray | None, held: list, bad: OutputError):
    """A follower's :class:`~pcreg.pipeline.follow.FollowCarry` from its members (:func:`write_carry`):
    ``follow`` (2, h, w) uint8, ``colours`` or None, ``held`` [] or the frame before a cut's two members."""
    from ..pipeline.follow import FollowCarry

    for pair in [follow] + held[:1]:
        if pair.ndim != 3 or pair.shape[0] != 2 or pair.dtype != np.uint8:
            raise bad
    if len(held) == 1:
        raise bad
    try:
        before = FollowCarry(held[0][0], held[0][1], held[1]) if held else None
        return FollowCarry(follow[0], follow[1], colours, before)
    except InputError:
        raise bad from None


def _chain_members(carry) -> dict:
    """A :class:`~pcreg.pipeline.estimators.ChainCarry` as arrays: the frame (``chain_rgb``), its step
    (``chain_frame``) and its motion to the key frame, a matrix (``chain_matrix``, (3, 3)) or a field and
    its confidence (``chain_field``, ``chain_confidence``); an absent one is empty."""
    m = carry.motion
    empty = np.zeros((0,), np.float32)

    def part(a, dtype):
        return empty if a is None else np.asarray(a, dtype)

    return {"chain_rgb": np.asarray(carry.rgb, np.uint8), "chain_frame": np.int64(carry.frame),
            "chain_matrix": part(None if m is None else m.matrix, np.float64),
            "chain_field": part(None if m is None else m.field, np.float32),
            "chain_confidence": part(None if m is None else m.confidence, np.float32)}


def _chain_carry(members: dict, bad: OutputError):
    """The :class:`~pcreg.pipeline.estimators.ChainCarry` of :func:`_chain_members`' arrays; anything
    malformed is ``bad``."""
    from ..pipeline.estimators import ChainCarry
    from ..registration.motion import Motion

    try:
        rgb, frame = members["chain_rgb"], members["chain_frame"]
        matrix, fld, conf = members["chain_matrix"], members["chain_field"], members["chain_confidence"]
    except KeyError:
        raise bad from None
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or frame.shape != () or frame.dtype.kind not in "iu":
        raise bad
    try:
        if matrix.size:
            motion = Motion(matrix=matrix)
        elif fld.size:
            motion = Motion(field=fld, confidence=conf if conf.size else None)
        else:
            motion = None
    except InputError:
        raise bad from None
    return ChainCarry(rgb, motion, int(frame))


def read_confidence(path: Path, shape: tuple[int, int], why: str) -> np.ndarray:
    """The (H, W) uint8 confidence map at ``path`` (:func:`write_confidence`'s) of frames of ``shape``; a file that is
    not one pcreg run writes (:func:`label_file_problem`: JPEG bytes under its name, say, whose values move at every
    edge) an :class:`~pcreg.errors.InputError` naming it, ``why`` in brackets after."""
    import cv2

    from ..formats import read_image_file

    problem = label_file_problem(path, shape, confidence=True)
    if problem is not None:
        raise InputError(f"{path}: {problem} ({why})")
    conf = read_image_file(path, flags=cv2.IMREAD_UNCHANGED)
    if conf.ndim != 2 or conf.dtype != np.uint8 or conf.shape != tuple(shape):
        raise InputError(f"{path}: not a confidence map of frames of {shape[1]}x{shape[0]} (8-bit, one channel; {why})")
    return conf


def label_file_problem(path: Path, shape: tuple[int, int], *, confidence: bool = False) -> str | None:
    """What keeps the file at ``path`` from being a label PNG a run wrote (:func:`write_labels`; ``confidence``: a
    confidence PNG, :func:`write_confidence`) of frames of ``shape`` (H, W), told from its header and its chunks' CRCs
    without decoding its pixels: ``"missing"``, why it is damaged, of another size, or not a palette PNG (nor the
    8-bit grey one pcreg 0.2 wrote; a confidence PNG: not an 8-bit grey one); None when it is one."""
    from ..classes.png import PNG_SIGNATURE, check_png_chunks, is_palette_png
    from ..formats import max_file_bytes, read_regular_file
    from ..validation import max_pixels

    if not path.is_file():
        return "missing"
    try:
        data = read_regular_file(path, max_bytes=max_file_bytes(max_pixels()), what="label image")
        if data.startswith(PNG_SIGNATURE):
            check_png_chunks(data, str(path))
    except InputError as exc:
        return str(exc).removeprefix(f"{path}: ")
    if not data.startswith(PNG_SIGNATURE):
        return "not a PNG"
    if confidence and (data[24], data[25]) != (8, 0):  # IHDR's bit depth and colour type: 8-bit grey
        return "not a confidence PNG pcreg run writes (an 8-bit grey PNG)"
    if not confidence and not is_palette_png(data) and (data[24], data[25]) != (8, 0):  # or grey, as pcreg 0.2 wrote
        return "not a label PNG pcreg run writes (a palette PNG, or 8-bit grey ids)"
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if (h, w) != tuple(shape):
        return f"{'a confidence map' if confidence else 'labels'} of {w}x{h}, the frames {shape[1]}x{shape[0]}"
    return None


def labels_of_frames_gone(out: Path, frames) -> list[Path]:
    """The label PNGs, and confidence maps, that the run in ``out`` wrote (:func:`labels_written`) of frames its folder
    ``frames`` no longer has (removed since), read while the steps still name them: a key-frames run that goes on
    without them removes them once its kept steps are written, so that ``out`` holds no labels of a frame that is not
    the run's (and a run started over, which removes what the steps name, would not find them any more). None of a video's: where its container declares no
    count, how many frames it has is known only once decoded."""
    if frames.kind != "folder":
        return []
    there = {frames.stem(t) for t in range(len(frames))}
    gone = sorted(f for f in labels_written(out) if f.stem not in there)
    return gone + [out / CONFIDENCE / f.name for f in gone if (out / CONFIDENCE / f.name).is_file()]


def check_labelled(out: Path, stems: list[str], shape: tuple[int, int], confidence: Iterable[str] = ()) -> None:
    """The label PNG of every frame run.json counts labelled (``stems``) is in ``out``, whole, of the frames' ``shape``
    (:func:`label_file_problem`), and so is the confidence PNG of each of the frames ``confidence`` (those carried, in
    a run with ``--confidence``); one gone (deleted or moved since) or damaged (cut short, overwritten) is an
    :class:`~pcreg.errors.OutputError`: the run cannot make it again where it stands, and "all frames done" would
    not be true."""
    named = [(out / f"{stem}.png", False) for stem in stems] + [(out / CONFIDENCE / f"{stem}.png", True) for stem in confidence]
    for path, is_confidence in named:
        problem = label_file_problem(path, shape, confidence=is_confidence)
        if problem == "missing":
            aside = out / EARLIER / path.relative_to(out)
            where = (f" (it is in {out / EARLIER}, where a run started over there and killed while it moved this run "
                     "aside left it)") if aside.is_file() else ""
            raise OutputError(f"{path} is missing{where}, though {out / STATE} counts that frame labelled; "
                              "use --force to start over")
        if problem is not None:
            raise OutputError(f"{path}: {problem}, though {out / STATE} counts that frame labelled; "
                              "use --force to start over")


def drop_suggestions(out: Path, resumed: bool) -> None:
    """Remove the suggest.txt of the run before in ``out`` (``resumed``: one was there) before frames are labelled
    again: chosen from the predicted errors they replace, it may name a frame that is a key frame now (written anew at
    the end with ``--suggest``). A first run keeps a person's own file of that name, as it keeps every file it did
    not write."""
    if resumed:
        (out / SUGGEST).unlink(missing_ok=True)


def remove_partial_writes(out: Path) -> None:
    """Delete the temporary files of writes a killed run left half done in ``out`` (``.NAME.*.tmp`` of a label
    PNG, a carry, run.json, steps.jsonl (rewritten by a key-frames run as it resumes) or suggest.txt, and of a
    ``confidence/NAME.png``, :func:`pcreg.outputs.atomic_write_bytes`), and no other file; the caller holds the folder's lock."""
    for f in out.glob(".*.tmp"):
        if f.name.startswith((f".{STATE}.", ".carry-", f".{SUGGEST}.", f".{STEPS}.")) or ".png." in f.name:
            f.unlink(missing_ok=True)
    for f in (out / CONFIDENCE).glob(".*.png.*.tmp"):
        f.unlink(missing_ok=True)


def write_suggestions(out: Path, chosen: Sequence[tuple[str, float]]) -> Path:
    """``out``'s suggest.txt: the frames to label next, best first, as ``(stem, predicted error %)``,
    ``STEM<TAB>ERROR`` a line (a tab, since a file name may hold spaces); names as the files have them."""
    from ..outputs import atomic_write_bytes

    text = "".join(f"{stem}\t{error:.2f}\n" for stem, error in chosen)
    return atomic_write_bytes(out / SUGGEST, text.encode("utf-8", "surrogateescape"))


def read_suggestions(out: Path, known: set[str]) -> list[tuple[str, float | None]]:
    """suggest.txt's frames that are among ``known`` (names or stems), in its order, with the predicted
    error given there (None where none is, or it is not a number). A line of the space-separated form of
    pcreg 0.1 (``STEM ERROR``) is read too; lines naming no known frame, blank or ``#`` lines are skipped. A file
    larger than a line a frame holds (at least 1 MiB) is an :class:`~pcreg.errors.InputError`, not read whole."""
    from ..formats import read_regular_file

    path = out / SUGGEST
    if not path.is_file():
        return []
    how = "one frame name a line, a tab and its predicted error"
    try:  # a line a frame at most, each name at most a file name's 255 bytes
        read = read_regular_file(path, max_bytes=max(1 << 20, 320 * len(known)), what="suggestions file", hint=f" ({how})")
    except OSError:
        raise InputError(f"{path}: unreadable ({how})") from None
    lines = read.decode("utf-8", "surrogateescape").splitlines()
    found: list[tuple[str, float | None]] = []
    for line in lines:
        name, tab, rest = line.partition("\t")
        if not tab and line.strip() not in known:  # pcreg 0.1's NAME ERROR
            name, _, rest = line.rpartition(" ")
        name = name.strip()
        if not name or name.startswith("#") or name not in known:
            continue
        try:
            error: float | None = float(rest.strip()) if rest.strip() else None
        except ValueError:
            error = None
        found.append((name, error if error is None or math.isfinite(error) else None))
    return found


class StepTruth(NamedTuple):
    """A frame's figures against the truth (``pcreg run --truth``): its ``error`` in % and each class's ``iou`` by
    class id (``steps.jsonl``'s ``error`` and ``iou``; None where the step has none)."""

    error: float | None
    iou: dict[int, float] | None


def finite_figure(value) -> float | None:
    """A figure of a step as a float, None where it is none or not a finite number."""
    return float(value) if isinstance(value, (int, float)) and np.isfinite(value) else None


def step_class_iou(iou, steps_path: Path, name: str, field: str = "predicted_iou") -> dict[int, float] | None:
    """A step's ``predicted_iou`` (or ``field``) as read from ``steps_path`` (class id: IoU in [0, 1]; None when it
    has none); an :class:`InputError` naming the frame ``name`` for one pcreg run did not write (a NaN among them)."""
    try:
        read = {int(k): float(v) for k, v in iou.items()} if isinstance(iou, dict) else None
        if read is not None and not all(0.0 <= v <= 1.0 for v in read.values()):  # NaN too
            raise ValueError
    except (ValueError, TypeError):
        raise InputError(f"{steps_path}: the step of {name} has a{'n' if field == 'iou' else ''} {field} pcreg run did "
                         "not write") from None
    return read


def has_confidence(folder: Path, run: dict) -> bool:
    """Whether the run in ``folder`` (``run``: run.json's identity) has confidence maps: it was asked for them
    (``--confidence``), or its ``confidence/`` folder is there. A map missing, or the folder removed, is then a map
    missing, which the review and the export say, not a run without confidence."""
    return run.get("confidence") is True or (folder / CONFIDENCE).is_dir()
