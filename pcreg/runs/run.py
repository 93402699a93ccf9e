"""One run of ``pcreg run``: :class:`RunRequest` says what to label, :class:`Run` owns the folder it is
labelled into and labels it.

The command hands a request (the frames' source, the key frames' labels, ``--out``, how labels are
coded, the truth folder, the propagators' :class:`~pcreg.pipeline.config.PropagatorConfig`, the outputs
asked for) to :meth:`Run.label`, which reads and checks the inputs (:mod:`pcreg.runs.inputs`; the key
frames' labels and the truth read through the run's class table, ``--classes``), opens or resumes the
folder and labels every frame not labelled yet: from one label image, forwards from the key frame
(:func:`pcreg.pipeline.engine.propagate`); from a folder of key frames (or a CVAT export), stretch by
stretch (:class:`pcreg.pipeline.keys_run.KeyRun`, whose passes commit their frames here).

Outputs in ``out``, each written atomically (:mod:`pcreg.runs.files`, :mod:`pcreg.runs.state`):

- ``NAME.png`` per frame (a folder's file name without its suffix; ``{i:06d}`` for a video's frame ``i``):
  its labels, a palette PNG in the class table's colours whose values are the class ids (``lagr``: 0 ground,
  1 obstacle; a key frame's own labels as given);
- ``steps.jsonl``: one line per labelled frame (:meth:`pcreg.Propagator.step`'s report, and the frame's
  error against the truth when there is one), appended;
- ``run.json``: the run's identity, how far it has come, how many registrations fell back, the running
  error against the truth and the places a video skips frames by its times (``gaps``, :mod:`pcreg.runs.gaps`):
  rewritten after every frame, it is the commit point;
- ``carry-0.npz`` and ``carry-1.npz``: what each step handed to the next (:class:`pcreg.pipeline.stream.Carry`,
  the dense field's control grid, and what naive Bayes has learned from the stream), frame t's in
  ``carry-{t % 2}.npz``, so the one of the last frame counted is always there (a folder of key frames
  keeps them beside each stretch's own files, in ``.keys/STRETCH/``);
- with ``--confidence``, ``confidence/NAME.png`` per frame: 255 times the probability that each label is
  right (:attr:`pcreg.pipeline.stream.StepReport.confidence`);
- with ``--suggest N``, ``suggest.txt``: the frames to label next, best first.

A frame counts once run.json counts it. A run that stops anywhere (a kill, Ctrl-C) resumes at the first
frame not counted: ``steps.jsonl`` is cut back to the frames counted, the temporary files of writes it
left half done are removed, and the propagator continues from the last counted frame's carry, so the
resumed run writes exactly what an uninterrupted run writes.
"""

from __future__ import annotations

import itertools
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import numpy as np

from ..classes.keys import LabelCoding, run_table
from ..errors import InputError, OutputError
from ..outputs import atomic_file
from .earlier import Earlier
from .edited import (check_key_files, check_same_frame, check_same_frames, check_same_inputs, check_same_truth,
                     frame_bytes, frame_stamp, key_contents)
from .files import (CARRY, CONFIDENCE, HIDDEN, RUN_FILES, STEPS, SUGGEST, SUMMARY_FIELDS, append_step, check_labelled, drop_suggestions,
                    label_digest, label_file_problem, labels_of_frames_gone, labels_written, parse_steps, read_carry, remove_partial_writes,
                    step_lines, write_carry, write_confidence, write_labels)
from .records import check_record_path, check_recording, name_recording, nothing_to_record, run_recording
from .state import FORMAT, STATE, inputs_placed, named_otherwise, open_state, read_state, run_frames, run_inputs, write_state
from .truth import add_rates, count_frame, empty_counts, scored_step
from .video_file import check_kept, decoded_to, keep_video, labelled_to_end, mark_end

if TYPE_CHECKING:
    from ..datasets.sources import Selection
    from ..pipeline.config import PropagatorConfig

__all__ = ["RunRequest", "Run"]


@dataclass(frozen=True)
class RunRequest:
    """What to label: the ``frames`` (a folder or a video) and which of them (``selection``, a
    :class:`~pcreg.datasets.sources.Selection`), the key frame's ``labels`` (a label image, or a folder of
    key frames' labels, or a CVAT "Segmentation mask 1.1" export), ``out``, the propagators' ``config``,
    how labels are coded (``coding``, a :class:`~pcreg.classes.keys.LabelCoding`: ``--classes``, the class
    table, and ``--mapping``, none, camvid or davis), a ``truth`` folder to score against, and the outputs
    asked for: ``confidence`` PNGs, ``suggest`` (how many frames to label next), ``force`` (start over), a
    recording (``record``, a .rrd path, ``record_raw``: its images lossless). ``--follow object`` with a
    folder of key frames is an :class:`~pcreg.errors.InputError`."""

    frames: Path
    labels: Path
    out: Path
    config: PropagatorConfig
    selection: Selection
    coding: LabelCoding = field(default_factory=LabelCoding)
    truth: Path | None = None
    confidence: bool = False
    suggest: int | None = None
    force: bool = False
    record: Path | str | None = None
    record_raw: bool = False

    def __post_init__(self) -> None:
        if self.config.follow == "object" and self.folder_of_keys:
            raise InputError(f"--labels {self.labels}: --follow object follows one key frame's mask, not a folder of "
                             "key frames; give one label image")
        if self.record is not None:  # refused before any label is written
            check_record_path(self.record)

    @property
    def folder_of_keys(self) -> bool:
        """Whether ``labels`` is a folder of key frames' labels or a CVAT export
        (:func:`pcreg.classes.cvat.is_cvat_export`), not one label image."""
        from ..classes.cvat import is_cvat_export

        return self.labels.is_dir() or is_cvat_export(self.labels)


class Run:
    """A run's folder, its one owner: the run's ``identity`` (what a resumed run must match, in run.json), opening and
    resuming it, committing a frame, its steps, the carry, the truth counts, the suggestions and reading it back.
    ``frames``: the frame source's names (position 0 is the first frame chosen); ``truth``: label maps indexed by
    position (an entry None where there is none; read when asked), or None; ``confidence``: write
    ``confidence/NAME.png``. The label PNGs are written in the class table the identity names (:func:`pcreg.classes.keys.run_table`)."""

    def __init__(self, frames, out: Path, identity: dict | None, *, truth=None, confidence: bool = False, suggest: int | None = None) -> None:
        from .gaps import GapMarks

        self.frames, self.out, self.identity = frames, Path(out), identity
        self.table = run_table(identity)
        self.truth, self.confidence, self.suggesting = truth, confidence, suggest is not None  # suggest.txt written
        self.state: dict = {}
        self.gaps = GapMarks(self)  # where the video skips frames by its times: said, and counted in run.json
        self.resumed = False  # whether ``out`` held a run of these options (:meth:`open_key`, :meth:`open_keys`)
        self.earlier = Earlier(self.out)  # an earlier run a run started over replaces, kept until it is past bad input

    # -- labelling ----------------------------------------------------------------------------------

    @classmethod
    def label(cls, request: RunRequest) -> int:
        """Label what ``request`` asks into its ``out`` (resuming a run of the same identity there); the
        exit code, 0. Bad inputs are :class:`~pcreg.errors.InputError`, an ``out`` that holds another run an
        :class:`~pcreg.errors.OutputError`, each one line."""
        from ..classes.keys import binary_table, with_classes
        from ..datasets.sources import open_frames
        from ..outputs import OutputLock
        from .inputs import read_inputs
        from .state import run_identity

        with read_inputs(request, open_frames(request.frames, request.selection)) as inputs:  # its readings closed at the end
            keys, pending, table = inputs.keys, inputs.pending, inputs.table
            if request.config.follow == "object" and not binary_table(table):
                what = f"{table.n_known} classes" if table.n_known > 2 else f"the ids {table.describe()}"
                raise InputError(f"--classes {table.source or 'table'}: --follow object follows one object (background and "
                                 f"object, ids 0 and 1, 2 unknown), not {what}; use --follow scene (the default) for them")
            _notes_before_the_first_frame(keys, table, request.config, inputs.frames, pending, inputs.notes)
            try:
                prop = None if pending is None else request.config.from_key_frame(
                    pending[0].image, keys[0], classes=None if binary_table(table) else table)
            except InputError as exc:  # what the follower cannot take of the key mask: name the file
                if request.config.follow != "object":
                    raise
                raise InputError(f"{request.labels}: {exc}") from None
            identity = with_classes(run_identity(inputs.frames, request.frames, request.labels, request.config,
                                                 mapping=request.coding.mapping, truth=request.truth,
                                                 confidence=request.confidence), table, request.coding.mapping)
            run = cls(inputs.frames, request.out, identity, truth=inputs.truth, confidence=request.confidence, suggest=request.suggest)
            with OutputLock(request.out), run.earlier.kept(run._written):  # a second run on the same --out is refused
                if request.record is not None and not request.force:
                    check_recording(run.out, run.identity, Path(request.record))
                if pending is None:
                    run._label_from_keys(request, keys, inputs.reading)
                else:
                    run._label_from_key(request, pending, prop, keys[0])
        return 0

    def _label_from_key(self, request: RunRequest, pending: tuple, prop, labels: np.ndarray) -> None:
        """The frames not labelled yet, forwards from the key frame (its ``labels``), in order; ``pending``:
        the key frame, the frame after it and the decoder it came from, which a fresh run continues."""
        from .._runner import check_interrupted, progress, tick
        from ..datasets.sources import read_ahead
        from ..frame import PreparedFrame
        from ..outputs import WriteBehind
        from ..pipeline.engine import References, propagate
        from ..recording.stream_log import log_frame

        frames, out = self.frames, self.out
        _, second, decoded = pending
        with inputs_placed(out, self.identity, force=request.force):
            start = self.open_key(labels, force=request.force)
        if self.gaps.mark(pending[0]):  # frames missing before the key frame
            self.commit()
        # a video's count is what its container declares or its duration suggests: it sizes the progress bar,
        # never where the run stops (decoding finds the end)
        total = len(frames) if frames.kind == "folder" else frames.count()
        if (frames.kind == "folder" and start >= len(frames)) or (frames.kind == "video" and labelled_to_end(self.state)):
            decoded.close()  # a video labelled to its end in this very file: nothing decoded, no carry read
            nothing_to_record(request.record)
            if named_otherwise(out, self.state):  # its inputs found in new places (moved): kept
                self.commit()
            return self._say_done(request, 0, [0], start=start)
        drop_suggestions(self.out, self.resumed)
        if start == 1:
            todo: Iterator = itertools.chain([second], decoded)
        else:
            decoded.close()
            todo = decoded_to(frames, start)  # decodes (a video, under a bar) or skips (a folder) the frames done
        if start > 1:
            try:
                prop.resume(start - 1, *self.carry_after(start - 1))
            except InputError as exc:  # a carry of another stream
                raise OutputError(f"{out}: {exc}; use --force to start over") from None
        done = start
        with run_recording(request, self.table, self.earlier) as rec, \
                progress(total=None if total is None or total <= start else total - start, desc="frames", disable=None) as bar, \
                WriteBehind() as writer:  # a frame's outputs written while the next is labelled
            self.name_recording(request.record, f"{frames.name(start)} on" if start > 1 else None)
            prepared = ((f.position, PreparedFrame.of(f.image, name="frame"))
                        for f in self.gaps.marked(read_ahead(todo), writer))
            # the next frame decoded while this one is labelled; checked once: naive Bayes alone (with --truth)
            # reads the features the step made
            references = References(pending[0].image, prop.carry)
            for t, image, labels in propagate(prop, prepared, check=check_interrupted, where=frames.where):
                plain = prop.classifier.predict(image) if self.truth is not None else None
                writer.submit(self.record, t, labels, prop.last, plain, carry=prop.carry, learned=prop.learned_later(),
                              confidence=prop.last.confidence if request.confidence else None, scene=prop.scene)
                log_frame(rec, t, image.rgb, labels, prop.last, frames.name(t), prop.working_size,
                          reference=references.of(prop.last))
                references.stepped(prop.last, image.rgb)
                done = t + 1
                tick(bar)
        if frames.kind == "video":  # decoding found the end of the run's frames: a rerun need not look again
            mark_end(self.state, frames, self.out)
            self.commit()
        self._say_done(request, done - start, [0], start=start)

    def _label_from_keys(self, request: RunRequest, keys: dict, reading: tuple | None = None) -> None:
        """Every frame labelled from the key frames around it (:class:`pcreg.pipeline.keys_run.KeyRun`), from ``reading`` (:attr:`~pcreg.runs.inputs.RunInputs.reading`)."""
        from .._runner import check_interrupted, progress, tick
        from ..pipeline.key_passes import KeyRun
        from ..recording.stream_log import log_frame
        from .disk import choose_kept

        frames = self.frames
        job = KeyRun(self, keys, request.config, reading=reading)
        with inputs_placed(self.out, self.identity, force=request.force):
            job.start(force=request.force)
        choose_kept(job, self.out)
        if not job.finished:
            drop_suggestions(self.out, self.resumed)
        if job.finished and request.record is not None and not request.force:
            nothing_to_record(request.record)  # an existing recording is this finished run's: nothing to add to it
            self._say_done(request, 0, sorted(keys))
            return
        with run_recording(request, self.table, self.earlier) as rec:
            self.name_recording(request.record, f"steps.jsonl line {self.state['lines'] + 1} on" if self.state["lines"] else None)
            n = len(frames) if frames.kind == "folder" else frames.count()
            left = None if n is None else max(0, n - len(keys) - self.state["lines"])  # what the bar counts, not the run
            forward = job.forward_steps_left()  # the forward passes between two key frames label no frame
            with progress(total=None if left is None else left + forward, desc="steps" if forward else "frames",
                          disable=None) as bar:
                def on_frame(t, image, labels, report, name, size, reference=None) -> None:
                    log_frame(rec, t, image, labels, report, name, size, reference=reference)
                    tick(bar)

                done = job.run(on_frame=on_frame, check=check_interrupted, on_step=lambda: tick(bar))
            if frames.kind == "video":  # written again while decoded: its frames may be of two videos
                check_kept(self.state, frames, self.out)
            self._say_done(request, done, sorted(keys))

    def _say_done(self, request: RunRequest, done: int, keys: list[int], *, start: int | None = None) -> None:
        """Print what the run did (``done`` frames now; ``start``: the first of them, a run from one label image), write the suggestions (``keys``: the key frames' positions)."""
        import sys

        out, s = self.out, self.state
        self.gaps.summary()
        if done == 0:
            suggested = self.suggest(request.suggest, keys)  # written before a line is printed: a closed stdout loses no file
            if start is None and not s.get("lines"):  # no step ever: every frame is a key frame
                print(f"{out}: every frame is a key frame ({len(keys)}): their labels are written as given, none carried")
            else:
                print(f"{out}: all frames already done" if start is None else f"{out}: all {start} frames already done")
            if suggested:
                print(suggested)
            return
        steps = self._predicting_steps()  # read once, for the suggestions and the closing lines
        suggested = self.suggest(request.suggest, keys, steps)
        if start is not None:
            msg = f"{done} frame(s) labelled into {out}" + (f" ({start - 1 + done} with the {start - 1} before)" if start > 1 else "")
            failed = "those frames fuse the key frame's labels unwarped; "
        else:
            msg = f"{done} frame(s) labelled from {len(keys)} key frame(s) into {out}" + (f" ({len(steps)} in all)" if len(steps) > done else "")
            failed = ""
        if s["fallbacks"]:
            msg += f"; {s['fallbacks']} registration(s) failed ({failed}see {out / STEPS})"
        if s.get("truth") and s["truth"].get("error") is not None:
            msg += (f"\nerror against the truth: {s['truth']['error']:.2f}% over {s['truth']['frames']} frames "
                    f"(naive Bayes alone {s['truth']['plain_error']:.2f}%; in {out / STATE})")
        elif s.get("truth"):  # asked for, and no figure: said, not left out
            msg += "\nerror against the truth: none, the truth labels of the frames labelled are all unknown"
        msg += self.predicted_summary(truth=bool(s.get("truth")), steps=steps)
        print(msg, file=sys.stdout)
        if suggested:
            print(suggested)

    # -- opening and resuming -----------------------------------------------------------------------

    def open_key(self, labels: np.ndarray, *, force: bool = False) -> int:
        """Open (or resume) a run from one label image, the key frame's ``labels``; the first frame still to do."""
        state = open_state(self.out, self.identity, force=force, frames=self.frames, also=(SUGGEST,) if self.suggesting else ())
        self.resumed = state is not None  # an earlier run's, whose suggest.txt a run that labels removes
        digest = label_digest(labels)
        if state is not None:
            self.state = state
            check_same_inputs(self.frames, self.out, self.identity, int(state["done"]),
                              state.get("key_labels", digest) != digest)
            if self.frames.kind == "video":
                keep_video(state, self.frames, self.out)
            self._cut_steps(int(state["done"]) - 1)
            check_same_frames(self.frames, self.out, str(state["key_frame"]), state.get("key_bytes"), state.get("key_contents"),
                              self.truth)
            remove_partial_writes(self.out)
            stems = [self.frames.stem(t) for t in range(int(state["done"]))]
            check_labelled(self.out, stems, labels.shape, stems[1:] if self.confidence else ())
            return int(state["done"])
        self._start_over()
        remove_partial_writes(self.out)  # those of a killed run started over (--force) too
        self.state = {"format": FORMAT, "run": self.identity, "key_frame": self.frames.name(0), "done": 1, "fallbacks": 0,
                      "truth": empty_counts() if self.truth else None, "key_labels": digest}
        if self.frames.kind == "folder":
            self.state.update(key_bytes=frame_bytes(self.frames, 0), key_contents=key_contents(self.frames, [0]))
        if self.frames.kind == "video":
            keep_video(self.state, self.frames, self.out)
        (self.out / STEPS).write_bytes(b"")  # first: a folder of no run holds none (:func:`open_state`)
        write_labels(self.out / f"{self.frames.stem(0)}.png", labels, self.table)
        write_state(self.out, self.state)
        return 1

    def name_recording(self, record, resumed: str | None = None) -> None:
        """Name in run.json the recording ``record`` (a path, or None) it writes (:func:`~pcreg.runs.records.name_recording`; ``resumed``: where a resumed run starts)."""
        if name_recording(self.state, record, resumed):
            self.commit()

    def _start_over(self) -> None:
        """Move aside what an earlier run in ``out`` wrote (:class:`~pcreg.runs.earlier.Earlier`, put back if bad input
        stops the new run), which a run started over (``--force``) would otherwise leave for the review and the export to
        read: its label PNGs (:func:`~pcreg.runs.files.labels_written`; a run over fewer frames left the others), its
        carries, a key-frames run's passes, the confidence maps, the suggestions, steps.jsonl and run.json. Only where
        ``out`` holds an earlier run (its run.json): a folder that was not a run's output keeps every file in it. A path
        that holds one of the run's inputs (its frames, labels or truth) is refused, not moved (a label PNG that is one is kept)."""
        from ..formats import resolved

        if not (self.out / STATE).is_file():
            return
        for path in (self.out / n for n in (CARRY.format(0), CARRY.format(1), HIDDEN, CONFIDENCE, SUGGEST)):
            for given in run_inputs(self.identity):
                if resolved(given) == resolved(path) or resolved(path) in resolved(given).parents:
                    raise OutputError(f"{path}: holds {given}, an input of this run, and a run started over in "
                                      f"{self.out} removes it; move the input or choose another --out")
        self.earlier.set_aside(self._written())

    def _written(self) -> list[Path]:
        """The files and folders of the run in ``out`` (:meth:`_start_over`'s), but the run's inputs (the key labels in
        --out, or --out a folder of them)."""
        from ..export import FORMATS, default_name
        from ..formats import resolved

        kept = {resolved(p) for p in run_inputs(self.identity)}
        names = [self.out / n for n in RUN_FILES] + [self.out / default_name(f) for f in FORMATS]  # its exports, of its labels
        return [f for f in sorted(labels_written(self.out)) + names if resolved(f) not in kept and resolved(f).parent not in kept]

    def _cut_steps(self, n: int) -> None:
        """Keep the first ``n`` lines of steps.jsonl (a step appended after the last commit is dropped)."""
        path = self.out / STEPS
        count = end = 0
        for line in itertools.islice(step_lines(self.out), n):
            count, end = count + 1, end + len(line)
        if count < n:
            raise OutputError(f"{path}: {count} steps for {n} finished frames; use --force to start over")
        if path.is_file() and path.stat().st_size != end:
            os.truncate(path, end)

    def _keep_steps(self, live: list, shape: tuple[int, int]) -> int:
        """Keep the lines of steps.jsonl that run.json counts and whose frames are in a stretch still to label
        (``live``), their label files checked (frames of ``shape``); rewritten as it is read, whole or not at all; how many kept."""
        path, counted = self.out / STEPS, int(self.state["lines"])
        with atomic_file(path) as fh:
            count, stems = 0, []
            lines, parsed = itertools.tee(itertools.islice(step_lines(self.out), counted))
            for line, step in zip(lines, parse_steps(path, parsed)):
                count, t = count + 1, step["frame"]
                if any(t in s for s in live):
                    check_same_frame(self.frames, self.out, t, step)
                    check_same_truth(self.truth, self.out, step)
                    fh.write(line)
                    stems.append(self.frames.stem(t))
            if count < counted:
                raise OutputError(f"{path}: {count} steps for {counted} finished frames; use --force to start over")
            check_labelled(self.out, stems, shape, stems if self.confidence else ())
        return len(stems)

    def open_keys(self, keys: dict[int, np.ndarray], plan: dict, *, force: bool = False) -> None:
        """Open (or resume) a run from a folder of key frames (``keys``, {position: labels}) whose stretches
        are ``plan`` ({fingerprint: :class:`~pcreg.pipeline.engine.Stretch`}): the steps of stretches no
        longer in the plan forgotten, the key frames' labels written where they changed."""
        state = open_state(self.out, self.identity, force=force, frames=self.frames, also=(SUGGEST,) if self.suggesting else ())
        self.resumed = state is not None  # an earlier run's, whose suggest.txt a run that labels removes
        if state is not None:
            self.state = state
        else:
            self._start_over()
            self.state = {"format": FORMAT, "run": self.identity, "keys": {}, "stretches": [], "cursor": None, "lines": 0,
                          "fallbacks": 0, "truth": None}
            (self.out / STEPS).write_bytes(b"")
        remove_partial_writes(self.out)  # writes a killed run left half done
        grown = self.frames.kind == "video" and keep_video(self.state, self.frames, self.out)
        # a stretch done, of the same key frames and options, that stops where it did (the frames after the last key
        # frame of a folder that gained frames since are not done, nor of a video appended to; runs from before
        # ``stop`` was kept do not say)
        kept = [e for e in self.state["stretches"] if e["fingerprint"] in plan
                and e.get("stop", plan[e["fingerprint"]].stop) == plan[e["fingerprint"]].stop
                and not (grown and plan[e["fingerprint"]].stop is None)]
        cursor = self.state["cursor"]
        if cursor is not None and cursor["fingerprint"] not in plan:
            cursor = None
        live = [plan[e["fingerprint"]] for e in kept] + ([] if cursor is None else [plan[cursor["fingerprint"]]])
        if self.frames.kind == "folder":  # a key frame that kept steps were labelled from, written again since: refused
            check_key_files(self.frames, self.out, self.state, {k for s in live for k in s.keys})  # before anything is written
        gone = labels_of_frames_gone(self.out, self.frames)  # read while the steps name them, removed once they are kept
        lines = self._keep_steps(live, next(iter(keys.values())).shape)  # a refusal here removes nothing
        for f in gone:
            f.unlink(missing_ok=True)
        keep_hidden = None if cursor is None else self.hidden(cursor["fingerprint"]).name
        if state is not None and (self.out / HIDDEN).is_dir():  # a run's (one started over lost it whole)
            for d in (self.out / HIDDEN).iterdir():
                if d.name != keep_hidden:
                    shutil.rmtree(d, ignore_errors=True)
        names = {self.frames.name(k): label_digest(lab) for k, lab in keys.items()}
        if self.frames.kind == "folder":
            self.state.update(key_bytes={self.frames.name(k): frame_bytes(self.frames, k) for k in keys},
                              key_contents=key_contents(self.frames, keys))
        for k, lab in keys.items():
            f = self.out / f"{self.frames.stem(k)}.png"
            if self.state["keys"].get(self.frames.name(k)) != names[self.frames.name(k)] \
                    or label_file_problem(f, lab.shape) is not None:
                write_labels(f, lab, self.table)
                (self.out / CONFIDENCE / f.name).unlink(missing_ok=True)  # a key frame has none (labelled before)
        self.state.update(keys=names, stretches=kept, cursor=cursor, lines=lines)
        self.totals()
        self.commit()

    def hidden(self, fingerprint: str) -> Path:
        """The folder of what a key-frames stretch's passes hand on (its carry, prior terms, a video's frames)."""
        return self.out / HIDDEN / fingerprint[:16]

    # -- committing a frame -------------------------------------------------------------------------

    def commit(self) -> None:
        """Write run.json: the commit point."""
        write_state(self.out, self.state)

    def write_frame(self, t: int, labels: np.ndarray, confidence: np.ndarray | None, step: dict,
                    counts: dict | None = None, scored: tuple = (None, None)) -> None:
        """Frame ``t``'s label PNG (and ``confidence``, (H, W) in [0, 1], as ``confidence/NAME.png``), its truth
        counted into ``counts`` (``scored``: its truth map and naive Bayes' labels alone, or two Nones) and its ``step`` line; the caller commits."""
        stem = self.frames.stem(t)
        step = dict(step, **frame_stamp(self.frames, t))  # what a resumed run checks a folder's frame file against
        write_labels(self.out / f"{stem}.png", labels, self.table)
        if confidence is not None:
            (self.out / CONFIDENCE).mkdir(exist_ok=True)
            write_confidence(self.out / CONFIDENCE / f"{stem}.png", confidence)
        truth, plain = scored
        if truth is not None and counts is not None:
            count_frame(counts, labels, truth, plain, unknown=self.table.unknown)
        if truth is not None:  # what a resumed run checks the truth map against: its labels, not its file's bytes
            step["truth_digest"] = label_digest(truth)
        append_step(self.out, step)

    def record(self, t: int, labels: np.ndarray, report, plain: np.ndarray | None = None, carry=None,
               learned=None, confidence: np.ndarray | None = None, scene=None) -> None:
        """A run from one label image: write frame ``t``'s labels (and ``confidence``), step (``report``: its
        dict, or a :class:`~pcreg.pipeline.stream.StepReport`), ``carry`` (a
        :class:`~pcreg.pipeline.stream.Carry` or None), what the classifier has ``learned`` (an array,
        None, or :meth:`~pcreg.pipeline.stream.Propagator.learned_later`) and the cut test's ``scene``
        (:attr:`pcreg.Propagator.scene`), then commit it in run.json."""
        report = report if isinstance(report, dict) else report.to_dict()
        learned = learned() if callable(learned) else learned
        step = dict(report, frame=t, name=self.frames.name(t))
        if self.gaps.is_damaged(t):  # decoded with errors: labelled from a concealed picture
            step["damaged"] = True
        truth = None if self.truth is None else self.truth[t]
        if truth is not None:
            step.update(scored_step(labels, truth, plain, self.table))
        self.write_frame(t, labels, confidence, step, self.state.get("truth"), (truth, plain))
        if truth is not None:
            add_rates(self.state["truth"])
        self.keep_carry(t, carry, learned, scene)
        self.state["done"] = t + 1
        self.state["fallbacks"] += int(report.get("fallback", False))
        self.commit()

    # -- the carry ----------------------------------------------------------------------------------

    def keep_carry(self, t: int, carry, learned: np.ndarray | None, scene=None, *, stretch: str | None = None) -> None:
        """What step ``t`` hands to the next (:func:`pcreg.runs.files.write_carry`), in ``carry-{t % 2}.npz``:
        the run's own, or a key-frames ``stretch``'s (its fingerprint)."""
        write_carry(self.carry_path(t, stretch), t, carry, learned, scene)

    def read_carry(self, t: int, *, stretch: str | None = None, unreadable: str = ""):
        """``(carry, learned, scene)`` that step ``t`` left (:meth:`keep_carry`)."""
        return read_carry(self.carry_path(t, stretch), t, unreadable, with_scene=True)

    def carry_after(self, t: int):
        """A run from one label image: ``(carry, learned, scene)`` frame ``t`` left (a counted frame): the
        :class:`~pcreg.pipeline.stream.Carry` (None for the key frame, or where it left none), what the
        classifier had learned from the stream, as :attr:`pcreg.Propagator.learned` saved it (None where
        it had learned nothing), and the cut test's last frame of the key frame's scene
        (:attr:`pcreg.Propagator.scene`; None where none was kept)."""
        if t == 0:
            return None, None, None
        return self.read_carry(t, unreadable=f", so frame {t + 1} cannot continue where frame {t} left off")

    def carry_path(self, t: int, stretch: str | None = None) -> Path:
        """The carry file step ``t`` leaves (``stretch``: the fingerprint of its stretch, in a run from key frames)."""
        return (self.out if stretch is None else self.hidden(stretch)) / CARRY.format(t % 2)

    # -- the truth counts, the suggestions, reading back --------------------------------------------

    def totals(self) -> None:
        """A run from a folder of key frames: its fallbacks and truth counts, the sum of its stretches'."""
        parts = self.state["stretches"] + ([] if self.state["cursor"] is None else [self.state["cursor"]])
        self.state["fallbacks"] = sum(p["fallbacks"] for p in parts)
        if self.truth is None:
            return
        self.state["truth"] = add_rates({k: sum(p["truth"][k] for p in parts) for k in empty_counts()})

    def suggest(self, count: int | None, keys: list[int], steps: dict[int, dict] | None = None) -> str | None:
        """``OUT/suggest.txt``: the ``count`` frames to label next, best first, with their predicted error
        (:func:`pcreg.runs.files.write_suggestions`), from the predicted errors in steps.jsonl (:meth:`predicted` of
        ``steps``; :func:`pcreg.pipeline.keyframes.suggest`); ``keys``: the key frames' positions. The line that says
        where it is, to print once the run's summary is (None without ``count``)."""
        from ..pipeline.keyframes import suggest
        from .files import write_suggestions

        if count is None:
            return None
        predicted = self.predicted(steps)
        try:
            chosen = suggest(predicted, keys, count, max([*predicted, *keys]) + 1)
        except InputError as exc:
            raise InputError(f"--suggest {count}: {exc}") from None
        path = write_suggestions(self.out, [(self.frames.stem(t), predicted[t]) for t in chosen])
        return f"the {count} frame(s) to label next, best first: {path}"

    def predicted(self, steps: dict[int, dict] | None = None) -> dict[int, float]:
        """{frame: its predicted error, % of its pixels} of every step in steps.jsonl that has one (a key frame has
        none; ``steps``: as :meth:`_predicting_steps` read them, when already read). A step of a frame past the run's
        frames is an :class:`~pcreg.errors.OutputError`: not one pcreg run wrote."""
        return {t: float(s["predicted_error"]) for t, s in (self._predicting_steps() if steps is None else steps).items()}

    def _predicting_steps(self) -> dict[int, dict]:
        """{frame: its step} of the steps in steps.jsonl with a predicted error, as :meth:`predicted` checks them."""
        steps = parse_steps(self.out / STEPS, (ln for ln in step_lines(self.out) if ln.strip()))
        predicted = {s["frame"]: {k: s[k] for k in SUMMARY_FIELDS if k in s} for s in steps if s.get("predicted_error") is not None}
        # a run labels the frames it chose, and one from a label image the first run.json counts: a step of another
        # frame is none it wrote (its name would be looked up past the frames)
        bound = min(len(self.frames) if self.frames.kind == "folder" else math.inf, self.state.get("done", math.inf))
        beyond = next((t for t in predicted if t >= bound), None)
        if beyond is not None:
            raise OutputError(f"{self.out / STEPS}: a step of frame {beyond}, of a run of {bound} frames (not a step "
                              "pcreg run wrote); use --force to start over")
        return predicted

    def predicted_summary(self, *, truth: bool = False, steps: dict[int, dict] | None = None) -> str:
        """The run's predicted error as lines of its closing message (:func:`pcreg.runs.summary.predicted_summary`);
        "" when no step predicted one. ``truth``: a run scored against the truth, whose classes' IoU comes first
        (:func:`pcreg.runs.summary.truth_summary`); ``steps``: as :meth:`suggest` takes them."""
        from .summary import key_classes, lost_summary, predicted_summary, truth_summary

        steps = self._predicting_steps() if steps is None else steps
        lost = lost_summary(steps, key_classes(self.out, self.table, self.state.get("key_frame")), self.frames.stem, self.table)
        return (truth_summary(steps, self.table) if truth else "") + predicted_summary(steps, self.frames.stem, self.table,
                                                                                      self.out, lost, (self.identity or {}).get("weight"))

    @staticmethod
    def read(folder: Path) -> tuple[dict, list[str], list[str]]:
        """A finished or stopped run in ``folder``, for a reader: ``(run.json, key frames, every labelled
        frame)``, by name, in frame order (:func:`pcreg.runs.state.read_state`,
        :func:`pcreg.runs.state.run_frames`). No run.json, or one pcreg run did not write, is an
        :class:`~pcreg.errors.InputError`, and so is a steps.jsonl pcreg run did not write; one that does not
        match run.json raises OSError, KeyError, TypeError or ValueError."""
        state = read_state(folder)
        keys, names = run_frames(state, folder)
        return state, keys, names


def _notes_before_the_first_frame(keys: dict, table, config, frames, pending, read: tuple[str, ...] = ()) -> None:
    """Notes on stderr before the first frame: what reading the inputs met (``read``, :attr:`~pcreg.runs.inputs.
    RunInputs.notes`), the ``frames``' own (an interlaced video, read deinterlaced), when the run is expected to need
    more memory than the system has available (:func:`~pcreg.runs.memory.memory_note`), and when the key frame of a
    run from one (``pending``) holds no more detail than a smaller size would (:func:`~pcreg.datasets.detail.scale_note`)."""
    import sys

    from ..datasets.detail import scale_note
    from .memory import available_bytes, run_note

    notes = (*read, frames.note(), getattr(frames, "streams_note", lambda: None)(), run_note(keys.values(), table, config.scale, available_bytes()),  # labels: the frames' size
             None if pending is None else scale_note(pending[0].image, f"{frames.path}: the key frame {pending[0].name}", config))
    for note in filter(None, notes):
        sys.stderr.write(f"pcreg: note: {note}\n")
