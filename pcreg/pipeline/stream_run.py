"""A stream over a folder of frames or a video, resumable: what ``pcreg run`` does.

Outputs in ``out``, each written atomically:

- ``NAME.png`` per frame (a folder's file name without its suffix; ``{i:06d}`` for a video's frame ``i``): its labels (0 ground, 1 obstacle; the key frame's own labels as given);
- ``steps.jsonl``: one line per step (:meth:`pcreg.Propagator.step`'s report, and the frame's error
  against the truth when there is one), appended;
- ``run.json``: the options, how many frames are done, how many fell back, and the running error
  against the truth: rewritten after every frame, and always the same small size;
- ``carry-0.npz`` and ``carry-1.npz``: what each step handed to the next (:class:`pcreg.pipeline.stream.Carry`,
  the dense field's control grid, and what naive Bayes has learned from the stream), frame t's in
  ``carry-{t % 2}.npz``, so the one of the last frame counted is always there;
- with ``--confidence``, ``confidence/NAME.png`` per frame: 255 times the probability that each label is
  right (:attr:`pcreg.pipeline.stream.StepReport.confidence`).

``run.json`` is the commit point: a frame counts once it is written. A run that stops anywhere (a
kill, Ctrl-C) resumes at the first frame not counted: ``steps.jsonl`` is cut back to the frames
counted, the temporary files of writes it left half done are removed, and the propagator continues
from the last counted frame's carry. Every frame is registered to the key frame and its registration
starts from that carry, so the resumed run writes exactly what an uninterrupted run writes.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import InputError, OutputError
from ..formats import NPY_HEADER_ERRORS

__all__ = ["StreamRun", "STATE", "STEPS", "CARRY", "CONFIDENCE", "confidence_png", "run_frames"]

STATE = "run.json"
STEPS = "steps.jsonl"
CARRY = "carry-{}.npz"
CONFIDENCE = "confidence"
#: What reading a damaged carry file raises (a zip archive of .npy members).
_UNREADABLE_CARRY: tuple[type[BaseException], ...] = (*NPY_HEADER_ERRORS, KeyError, EOFError, zipfile.BadZipFile,
                                                      zlib.error)


class FrameNames(Protocol):
    """What a run needs of its frames: the name of the frame at each position (0 is the key frame) and
    the stem its outputs are named after (:class:`pcreg.datasets.sources.FolderFrames`, ``VideoFrames``)."""

    def name(self, position: int) -> str: ...

    def stem(self, position: int) -> str: ...


@dataclass
class StreamRun:
    """One run: ``frames`` (the frame source's names, position 0 is the key frame), the key frame's
    ``labels``, ``out``, the propagator's ``options`` (:class:`pcreg.Propagator` keywords), and optional
    ``truth`` label maps (indexed by position, an entry None where there is none; it may read each when
    asked) to score against."""

    frames: FrameNames
    labels: np.ndarray
    out: Path
    options: dict
    truth: Sequence[np.ndarray | None] | None = None
    identity: dict | None = None  # what a resumed run must match (paths and options), written in run.json

    def start(self, *, force: bool = False) -> int:
        """Open (or resume) the run; returns the index of the first frame still to do."""
        from ..outputs import atomic_write_json

        state = open_state(self.out, self.identity, force=force)
        if state is not None:
            self.state = state
            self._cut_steps(int(state["done"]) - 1)
            self._remove_partial_writes()
            check_labelled(self.out, [self.frames.stem(t) for t in range(int(state["done"]))])
            return int(state["done"])
        for slot in (0, 1):
            (self.out / CARRY.format(slot)).unlink(missing_ok=True)
        self.state = {"run": self.identity, "key_frame": self.frames.name(0), "done": 1, "fallbacks": 0,
                      "truth": {"frames": 0, "wrong": 0, "known": 0, "plain_wrong": 0} if self.truth else None}
        _write_png(self.out / f"{self.frames.stem(0)}.png", self.labels)
        (self.out / STEPS).write_bytes(b"")
        atomic_write_json(self.out / STATE, self.state)
        return 1

    def _remove_partial_writes(self) -> None:
        """Delete the temporary files of writes a killed run left half done (``.NAME.*.tmp`` of a label
        PNG or run.json, :func:`pcreg.outputs.atomic_write_bytes`); the caller holds the folder's lock."""
        for f in self.out.glob(".*.tmp"):
            if f.name.startswith((f".{STATE}.", ".carry-")) or ".png." in f.name:
                f.unlink(missing_ok=True)

    def _cut_steps(self, n: int) -> None:
        """Keep the first ``n`` lines of steps.jsonl (a step appended after the last commit is dropped)."""
        path = self.out / STEPS
        lines = path.read_bytes().splitlines(keepends=True) if path.is_file() else []
        if len(lines) < n:
            raise OutputError(f"{path}: {len(lines)} steps for {n} finished frames; use --force to start over")
        if len(lines) != n:
            path.write_bytes(b"".join(lines[:n]))

    def carry_after(self, t: int):
        """The carry frame ``t`` left (a counted frame; None for the key frame, or where it left none)."""
        from ..pipeline.stream import Carry

        if t == 0:
            return None
        path = self.out / CARRY.format(t % 2)
        unreadable = OutputError(f"{path}: missing or unreadable, so frame {t + 1} cannot continue where frame "
                                 f"{t} left off; use --force to start over")
        try:
            with np.load(path, allow_pickle=False) as z:
                frame, grid, evidence = np.array(z["frame"]), np.array(z["grid"]), np.array(z["evidence"])
        except _UNREADABLE_CARRY:
            raise unreadable from None
        if frame.shape != () or frame.dtype.kind not in "iu" or evidence.shape != () or evidence.dtype.kind != "f":
            raise unreadable
        if int(frame) != t:
            raise OutputError(f"{path} holds frame {int(frame)}'s carry, not frame {t}'s; use --force to start over")
        if grid.shape == (0, 0, 2) and np.isnan(evidence):  # that frame left none (_write_carry)
            return None
        try:
            return Carry(grid, float(evidence))
        except InputError as exc:
            raise OutputError(f"{path}: {exc}; use --force to start over") from None

    def learned_after(self, t: int) -> np.ndarray | None:
        """What the classifier had learned from the stream after frame ``t`` (a counted frame), as
        :attr:`pcreg.Propagator.learned` saved it; None where it had learned nothing."""
        if t == 0:
            return None
        path = self.out / CARRY.format(t % 2)
        try:
            with np.load(path, allow_pickle=False) as z:
                learned = np.array(z["learned"]) if "learned" in z.files else None
        except _UNREADABLE_CARRY:
            raise OutputError(f"{path}: missing or unreadable; use --force to start over") from None
        return None if learned is None or learned.size == 0 else learned

    def record(self, t: int, labels: np.ndarray, report, plain: np.ndarray | None = None, carry=None,
               learned=None, confidence: np.ndarray | None = None) -> None:
        """Write frame ``t``'s labels (and ``confidence``, (H, W) in [0, 1], as ``confidence/NAME.png``),
        step (``report``: its dict, or a :class:`~pcreg.pipeline.stream.StepReport`), ``carry`` (a
        :class:`~pcreg.pipeline.stream.Carry` or None) and what the classifier has ``learned`` (an array,
        None, or :meth:`~pcreg.pipeline.stream.Propagator.learned_later`), then commit it in run.json."""
        from ..classification.metrics import error_rate
        from ..outputs import atomic_write_json, to_json

        _write_png(self.out / f"{self.frames.stem(t)}.png", labels)
        if confidence is not None:
            (self.out / CONFIDENCE).mkdir(exist_ok=True)
            _write_png(self.out / CONFIDENCE / f"{self.frames.stem(t)}.png", confidence_png(confidence))
        report = report if isinstance(report, dict) else report.to_dict()
        learned = learned() if callable(learned) else learned
        step = dict(report, frame=t, name=self.frames.name(t))
        truth = None if self.truth is None else self.truth[t]
        if truth is not None:
            known = truth < 2
            wrong = int(np.count_nonzero((labels[known] == 1) != (truth[known] == 1)))
            step["error"] = error_rate(labels, truth)
            s = self.state["truth"]
            s["frames"] += 1
            s["wrong"] += wrong
            s["known"] += int(known.sum())
            if plain is not None:
                s["plain_wrong"] += int(np.count_nonzero((plain[known] == 1) != (truth[known] == 1)))
                step["plain_error"] = error_rate(plain, truth)
            s["error"] = 100.0 * s["wrong"] / s["known"] if s["known"] else None
            s["plain_error"] = 100.0 * s["plain_wrong"] / s["known"] if s["known"] else None
        with open(self.out / STEPS, "ab") as fh:
            fh.write((json.dumps(json.loads(to_json(step, strict=True))) + "\n").encode())
        _write_carry(self.out / CARRY.format(t % 2), t, carry, learned)
        self.state["done"] = t + 1
        self.state["fallbacks"] += int(report.get("fallback", False))
        atomic_write_json(self.out / STATE, self.state)  # the commit point


def confidence_png(confidence: np.ndarray) -> np.ndarray:
    """(H, W) uint8: 255 times the probability that the label is right, rounded. A confidence that is
    NaN or outside [0, 1] is a bug, never written."""
    c = np.asarray(confidence, dtype=np.float32)
    if not (np.all(np.isfinite(c)) and c.min(initial=0.0) >= 0.0 and c.max(initial=0.0) <= 1.0):
        raise AssertionError("a confidence outside [0, 1] reached the writer")
    return np.rint(c * 255.0).astype(np.uint8)


def run_frames(state: dict, steps: list[bytes]) -> tuple[list[str], list[str]]:
    """``(key frames, every labelled frame)`` of a run, by name, in frame order, from its run.json
    (``state``) and the lines of its steps.jsonl: a run from one label image (its key frame, then the
    frames it counted done) or from a folder of key frames (:mod:`pcreg.pipeline.keys_run`: its key
    frames and the steps it counted, in name order, which is a folder's and a video's frame order).
    Raises KeyError, TypeError or ValueError for a state or a line pcreg run did not write."""
    field = state_problem(state)
    if field is not None:
        raise ValueError(f"run.json's {field!r} is not as pcreg run writes it")
    if "stretches" in state:
        keys = sorted(str(k) for k in state["keys"])
        done = [str(json.loads(line)["name"]) for line in steps[:int(state["lines"])]]
        return keys, sorted(set(keys) | set(done))
    key, count = str(state["key_frame"]), int(state["done"])
    names = [key] + [str(json.loads(line)["name"]) for line in steps[:count - 1]]
    if len(names) != count:
        raise ValueError(f"{len(names) - 1} steps for {count - 1} labelled frames")
    return [key], names


def is_count(value, lo: int = 0) -> bool:
    """Whether ``value`` is an int (not a bool, not a float) of at least ``lo``, as run.json's counts are."""
    return type(value) is int and value >= lo


def has_counts(d, names: tuple[str, ...]) -> bool:
    """Whether ``d`` is a dict whose ``names`` are all counts (:func:`is_count`)."""
    return isinstance(d, dict) and all(is_count(d.get(k)) for k in names)


#: The counters of a run's running error (run.json's ``truth``, and each key-frame stretch's).
TRUTH_COUNTS = ("frames", "wrong", "known", "plain_wrong")


def stream_state_problem(state: dict) -> str | None:
    """What in a one-key run's run.json is not as pcreg run writes it (the first field), or None."""
    if not is_count(state.get("done"), 1):
        return "done"
    if not is_count(state.get("fallbacks")):
        return "fallbacks"
    if not isinstance(state.get("key_frame"), str):
        return "key_frame"
    if state.get("truth") is not None and not has_counts(state["truth"], TRUTH_COUNTS):
        return "truth"
    return None


def state_problem(state) -> str | None:
    """What in a run.json (one key frame's, or a folder of key frames') is not as pcreg run writes it."""
    from .keys_run import keys_state_problem

    if not isinstance(state, dict):
        return "its top level"
    return (keys_state_problem if "stretches" in state else stream_state_problem)(state)


def parse_steps(path: Path, lines: Sequence[bytes]) -> list[dict]:
    """The steps of ``lines`` of a run's steps.jsonl (``path``), each a dict whose ``frame`` is an int and
    whose ``predicted_error`` is a finite number or None; a line that is not one pcreg run wrote is an
    :class:`~pcreg.errors.OutputError` naming it."""
    import math

    steps = []
    for i, line in enumerate(lines):
        try:
            step = json.loads(line)
            ok = (isinstance(step, dict) and type(step.get("frame")) is int and step["frame"] >= 0
                  and (step.get("predicted_error") is None
                       or (type(step["predicted_error"]) in (int, float) and math.isfinite(step["predicted_error"]))))
        except ValueError:  # not JSON, or not UTF-8
            ok = False
        if not ok:
            raise OutputError(f"{path}: line {i + 1} is not a step pcreg run wrote; use --force to start over")
        steps.append(step)
    return steps


def open_state(out: Path, identity: dict | None, *, force: bool) -> dict | None:
    """Make ``out`` (a folder) and read the run it holds: its run.json when it is a run of ``identity``
    (the same options and inputs), None when there is none or ``force`` starts over; a run of other
    options, an unreadable run.json, or one whose fields are not as pcreg run writes them
    (:func:`state_problem`) is an :class:`~pcreg.errors.OutputError`."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    if force or not state_path.is_file():
        return None
    try:
        state = json.loads(state_path.read_text())
    except (OSError, ValueError):
        raise OutputError(f"{state_path}: unreadable; use --force to start over") from None
    if not isinstance(state, dict):
        raise OutputError(f"{state_path}: not a run's state (a JSON {type(state).__name__}); use --force to start over")
    if state.get("run") != identity:
        raise OutputError(f"{out} holds a run with other options{_differences(state.get('run'), identity or {})}; "
                          "use --force to start over or another --out")
    field = state_problem(state)
    if field is not None:
        raise OutputError(f"{state_path}: its {field!r} is not as pcreg run writes it; use --force to start over")
    return state


def _differences(before: object, now: dict) -> str:
    """`` (NAME: A then, B now, ...)``: what differs between a kept run's identity and this one's."""
    from ..validation import short_repr

    if not isinstance(before, dict):
        return ""

    def shown(d: dict, k: str) -> str:
        return short_repr(d[k]) if k in d else "not set"

    names = sorted(k for k in set(before) | set(now) if shown(before, k) != shown(now, k))
    said = [f"{k}: {shown(before, k)} then, {shown(now, k)} now" for k in names[:3]]
    return f" ({'; '.join(said)}{'; ...' if len(names) > 3 else ''})" if said else ""


def check_labelled(out: Path, stems: list[str]) -> None:
    """The label PNG of every frame run.json counts labelled (``stems``) is in ``out``; one gone (deleted
    or moved since) is an :class:`~pcreg.errors.OutputError`: the run cannot make it again where it
    stands, and "all frames done" would not be true."""
    for stem in stems:
        if not (out / f"{stem}.png").is_file():
            raise OutputError(f"{out / stem}.png is missing, though {out / STATE} counts that frame labelled; "
                              "use --force to start over")


def _write_carry(path: Path, t: int, carry, learned: np.ndarray | None = None) -> None:
    import io

    from ..outputs import atomic_write_bytes

    buf = io.BytesIO()
    grid = np.zeros((0, 0, 2), np.float32) if carry is None else carry.grid
    evidence = float("nan") if carry is None else carry.reference_evidence
    learned = np.zeros((0,), np.float64) if learned is None else np.asarray(learned, np.float64)
    np.savez(buf, frame=np.int64(t), grid=grid, evidence=np.float64(evidence), learned=learned)
    atomic_write_bytes(path, buf.getvalue())


def _write_png(path: Path, labels: np.ndarray) -> None:
    import cv2

    from ..outputs import atomic_write_bytes

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(labels, dtype=np.uint8))
    if not ok:
        raise OutputError(f"cannot encode {path}")
    atomic_write_bytes(path, buf.tobytes())


def check_truth(truth: list[np.ndarray | None], shape: tuple[int, int], names: list[str]) -> None:
    """Every truth map present and of the frames' size, or one line naming the first that is not."""
    for t, (lab, name) in enumerate(zip(truth, names)):
        if lab is None:
            raise InputError(f"no truth labels for frame {name}")
        if lab.shape != shape:
            raise InputError(f"truth labels of {name} are {lab.shape[1]}x{lab.shape[0]}, the frames "
                             f"{shape[1]}x{shape[0]}")
