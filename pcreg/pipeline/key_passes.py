"""A run labelled from key frames anywhere, both ways, resumable: what ``pcreg run --labels FOLDER`` does (its
public name :mod:`pcreg.pipeline.keys_run`).

Every frame is labelled from the key frames around it, as :func:`pcreg.pipeline.keyframes.label_clip`
labels a clip in memory: before the first key frame backwards from it, between two key frames from
both (``F = d + P_earlier + P_later``), after the last forwards from it. Each stretch's naive Bayes is
fitted on its own key frames (one or two, :data:`~pcreg.pipeline.keyframes.KEY_FITS`), so a stretch's
labels depend on nothing outside it.

Outputs in ``out`` (as a run from one label image's, :mod:`pcreg.runs.run`, each written atomically and
committed through its :class:`~pcreg.runs.run.Run`): ``NAME.png`` per frame (a key frame's own labels as given), ``confidence/NAME.png`` with ``--confidence``,
``steps.jsonl`` (one line per labelled frame, in the order they were labelled; ``keys`` names the key
frames it was labelled from) and ``run.json``, the commit point of every step. Each pass reads its
next frame on a thread of its own and writes a frame's outputs and commit on another
(:class:`~pcreg.outputs.WriteBehind`), in order, while the next frame is labelled.

A stretch between two key frames needs its forward pass before its backward pass: the forward pass
keeps each frame's prior term (:meth:`~pcreg.pipeline.trust.TrustMaps.prior_term`, float16) in
``OUT/.keys/STRETCH/`` (and, for a video, the decoded frames of the stretch, which the backward pass
reads in reverse), removed when the stretch is done; memory does not grow with the stretch's length.
They are compressed without loss (:mod:`pcreg.runs.kept`) when :attr:`KeyRun.compress` says so, which the
run decides when it opens from the free space of its disk (:func:`pcreg.runs.disk.compress_kept`).
A run that stops anywhere resumes at its first step not committed, from the carry that step's
propagator left (``carry-{0,1}.npz`` beside the stretch's files), and writes what an uninterrupted
run writes.

``run.json`` keeps each finished stretch's fingerprint (its key frames' names and labels, and the
options) and where it stops (``stop``, the position after its last frame; None to a video's end): a run on
a labels folder that gained, lost or changed a key frame redoes only the stretches whose fingerprint
changed, and a frames folder that gained or lost frames after its last key frame redoes the stretch after it.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import shutil
from contextlib import closing
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ..classes.keys import binary_table, two_class_table
from ..errors import InputError, OutputError
from ..runs.files import HIDDEN, label_digest
from ..runs.kept import read_frame, read_prior, write_frame, write_prior
from ..runs.truth import empty_counts
from ..runs.video_file import decoded_to

from .bars import kept_between
from .engine import PRIOR_STORE_DTYPE, References, Stretch, propagate, stretches, two_sided
from .multiclass import weight_sum

__all__ = ["KeyRun", "HIDDEN"]  # HIDDEN: pcreg.runs.files.HIDDEN


class KeyRun:
    """A run's passes: ``owner`` (the :class:`~pcreg.runs.run.Run` whose folder they label into and which
    commits each frame: its frames, ``out``, truth and ``confidence``), ``keys`` ({position: (H, W) uint8
    labels}) and the propagators' ``config`` (:class:`~pcreg.pipeline.config.PropagatorConfig`). Users name it
    :class:`pcreg.pipeline.keys_run.KeyRun`, which takes 0.2.0's form too."""

    def __init__(self, owner, keys: dict[int, np.ndarray], config, *, reading: tuple | None = None) -> None:
        self.owner, self.keys, self.config = owner, dict(sorted(keys.items())), config
        self.frames, self.truth, self.confidence = owner.frames, owner.truth, owner.confidence
        self.n = len(self.frames) if self.frames.kind == "folder" else None
        self.plan = stretches(self.keys, self.n)
        self.labelled = 0
        self.on_step: Callable[[], None] | None = None
        #: Whether the stretches' kept files are compressed (:mod:`pcreg.runs.kept`), for the whole run.
        self.compress = True
        self._fingerprints: dict[Stretch, str] = {}
        self._decoded = Decoded(self.frames, reading)

    @property
    def state(self) -> dict:
        """The run's run.json, as :attr:`owner` keeps it."""
        return self.owner.state

    @property
    def out(self) -> Path:
        """The run's folder (its :attr:`owner`'s)."""
        return self.owner.out

    @property
    def identity(self) -> dict:
        """What a resumed run must match (its :attr:`owner`'s)."""
        return self.owner.identity

    # -- bookkeeping ---------------------------------------------------------------------------------

    def fingerprint(self, s: Stretch) -> str:
        """What a stretch's labels depend on: its key frames (position, name, labels), its extent, the options."""
        if s not in self._fingerprints:
            self._fingerprints[s] = self._fingerprint(s)
        return self._fingerprints[s]

    def _fingerprint(self, s: Stretch) -> str:
        what = {"keys": [[k, self.frames.name(k), label_digest(self.keys[k])] for k in s.keys],
                "first": s.first, "last": s.last, "options": self.config.options(), "confidence": self.confidence,
                "fit": "stretch"}
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()

    def _commit(self) -> None:
        self.owner.commit()

    def _hidden(self, fp: str) -> Path:
        return self.owner.hidden(fp)

    def start(self, *, force: bool = False) -> None:
        """Open (or resume) the run (:meth:`pcreg.runs.run.Run.open_keys`): the steps of stretches no longer
        in the plan forgotten, the key frames' labels written where they changed. A stretch under way in a phase it
        has not (a run.json edited) is an :class:`~pcreg.errors.OutputError`, as any other field not as pcreg run
        writes it."""
        from ..runs.files import STATE

        plan = {self.fingerprint(s): s for s in self.plan}
        self.owner.open_keys(self.keys, plan, force=force)
        cur = self.state["cursor"]
        if cur is not None and cur["phase"] not in self._phases(plan[cur["fingerprint"]]):
            raise OutputError(f"{self.owner.out / STATE}: its 'cursor' is not as pcreg run writes it; use --force to "
                              "start over")

    @property
    def finished(self) -> bool:
        """Whether every stretch of the plan is labelled (after :meth:`start`)."""
        done = {e["fingerprint"] for e in self.state["stretches"]}
        return all(self.fingerprint(s) in done for s in self.plan)

    def kept_bytes(self, *, compressed: bool = True) -> float:
        """The most bytes a stretch not labelled yet is expected to keep in the hidden folder while it is labelled,
        ``compressed`` or not (:mod:`pcreg.runs.disk`; after :meth:`start`): its frames' size, the working size,
        the classes its key frames show."""
        from ..runs.disk import frame_bytes, prior_bytes, stretch_bytes

        done = {e["fingerprint"] for e in self.state["stretches"]}
        h, w = next(iter(self.keys.values())).shape[:2]
        scale = self.config.scale
        frame = frame_bytes(w, h, compressed=compressed)
        table = getattr(self.owner, "table", None)
        known = list(table.known_ids) if table is not None and not two_class_table(table) else []  # none: two classes
        shown = {k: np.bincount(lab.ravel(), minlength=256) > 0 for k, lab in self.keys.items()} if known else {}
        need = 0.0
        for s in self.plan:
            if self.fingerprint(s) in done:
                continue
            classes = max(2, sum(1 for c in known if any(shown[k][c] for k in s.keys)))
            prior = prior_bytes(max(1, round(w * scale)), max(1, round(h * scale)), classes, compressed=compressed)
            need = max(need, stretch_bytes(s.first, s.last, video=self.frames.kind == "video", frame=frame,
                                           prior=prior))
        return need

    # -- the run ---------------------------------------------------------------------------------------

    def forward_steps_left(self) -> int:
        """How many steps the forward passes of the stretches between two key frames not done yet still take
        (they label no frame: a progress bar counts them beside the frames)."""
        done = {e["fingerprint"] for e in self.state["stretches"]}
        cur, left = self.state["cursor"], 0
        for s in self.plan:
            if s.first is None or s.last is None or self.fingerprint(s) in done:
                continue
            left += s.last - s.first - 1
            if cur is not None and cur["fingerprint"] == self.fingerprint(s) and cur["phase"] != "store":
                left -= s.last - s.first - 1 if cur["phase"] == "backward" else (cur["next"] or s.first + 1) - s.first - 1
        return left

    def run(self, on_frame: Callable | None = None, check: Callable[[], None] = lambda: None,
            on_step: Callable[[], None] | None = None) -> int:
        """Label every stretch not done yet; returns how many frames this call labelled. ``on_frame(t,
        image, labels, report, name, size, reference=IMAGE)`` after each frame (``size``: the propagator's working
        size; ``reference``: the image the frame was registered to, the pass's key frame or the frame before it
        in the pass, None when not at hand); ``on_step()`` after each step of a forward pass between two key
        frames (:meth:`forward_steps_left`), which labels no frame; ``check()`` before each step (an interruption). A
        callback without a ``reference`` parameter (0.2.0's six arguments) is called without it."""
        self.on_frame, self.check, self.on_step = on_frame, check, on_step
        self._told = on_frame is not None and _takes_reference(on_frame)  # 0.2.0's callbacks took no reference
        with closing(self._decoded):
            self._stretches()
        hidden = self.owner.out / HIDDEN
        if hidden.is_dir() and not any(hidden.iterdir()):
            hidden.rmdir()
        return self.labelled

    def _stretches(self) -> None:
        """Every stretch not done yet, in the plan's order."""
        done = {e["fingerprint"] for e in self.state["stretches"]}
        for s in self.plan:
            fp = self.fingerprint(s)
            if fp in done:
                continue
            cur = self.state["cursor"]
            if cur is None or cur["fingerprint"] != fp:
                self.state["cursor"] = cur = {"fingerprint": fp, "phase": self._phases(s)[0], "next": None, "steps": 0,
                                              "fallbacks": 0, "truth": None if self.truth is None else empty_counts()}
                self._commit()
            self._hidden(fp).mkdir(parents=True, exist_ok=True)
            for phase in self._phases(s)[self._phases(s).index(cur["phase"]):]:
                if cur["phase"] != phase:
                    cur.update(phase=phase, next=None, steps=0)
                    self._commit()
                getattr(self, f"_{phase}")(s, cur)
            entry = {"fingerprint": fp, "keys": [self.frames.name(k) for k in s.keys], "stop": s.stop,
                     "fallbacks": cur["fallbacks"], "truth": cur["truth"]}
            self.state["stretches"].append(entry)
            self.state["cursor"] = None
            self.owner.totals()
            self._commit()
            shutil.rmtree(self._hidden(fp), ignore_errors=True)

    def _phases(self, s: Stretch) -> list[str]:
        video = self.frames.kind == "video"
        if s.last is None:
            return ["forward"]
        return (["store"] if video else []) + (["between"] if s.first is not None else []) + ["backward"]

    def _image(self, s: Stretch, t: int) -> np.ndarray:
        """Frame ``t``'s image, its notes said (on the caller's thread: the run loop's) and kept in the run's state,
        which the pass's next commit writes."""
        image, notes = self._image_and_notes(s, t)
        self.owner.gaps.say(notes)
        return image

    def _image_and_notes(self, s: Stretch, t: int) -> tuple[np.ndarray, tuple]:
        """Frame ``t``'s image and what reading it met (:attr:`~pcreg.datasets.sources.SourceFrame.notes`: a folder's
        frame with transparent pixels; a video's were met where the store phase decoded it)."""
        if self.frames.kind == "folder":
            return self.frames.read(t)
        return read_frame(self._hidden(self.fingerprint(s)), t), ()

    def _images(self, s: Stretch, positions: range, writer, priors: dict | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """``(t, image)`` for the frames at ``positions``, in that order, the next one read on a thread of
        its own while the caller labels this one (:func:`~pcreg.datasets.sources.read_ahead`); with ``priors``,
        what the forward pass kept for frame ``t`` (:func:`~pcreg.runs.kept.read_prior`) put in it at ``t``
        on that thread too, before the frame comes out. A frame's notes are said as it comes out, by the caller's
        thread, and kept in run.json by ``writer`` (the pass's :class:`~pcreg.outputs.WriteBehind`), which commits
        them with the frame."""
        from contextlib import closing

        from ..datasets.sources import read_ahead

        folder = self._hidden(self.fingerprint(s))

        def read() -> Iterator[tuple[int, np.ndarray, tuple]]:
            for t in positions:
                if priors is not None:
                    priors[t] = read_prior(folder, t)
                yield t, *self._image_and_notes(s, t)

        with closing(read_ahead(read())) as frames:
            for t, image, notes in frames:
                self.owner.gaps.say(notes, writer)
                yield t, image

    def _classifier(self, s: Stretch, images: dict):
        from ..classification.bayes import fit_classifier
        from ..datasets import Frame

        table = getattr(self.owner, "table", None)  # the run's class table; lagr's ids keep the default, two known
        # classes in other ids are fitted in theirs and run by the two-class step in lagr's (Propagator)
        try:
            return fit_classifier([Frame(images[k], self.keys[k], self.frames.name(k)) for k in s.keys],
                                  classes=None if table is None or binary_table(table) else table)
        except InputError as exc:  # one class in these key frames' labels: say which key frames
            names = [self.frames.name(k) for k in s.keys]
            said = " and ".join(names) if len(names) < 3 else f"{names[0]} ... {names[-1]}"
            raise InputError(f"the labels of {said}: {exc}") from None

    def _propagator(self, clf, k: int, image, learning: bool):
        """A stream of ``clf`` reset to the key frame at position ``k`` (its ``image``), one colour everywhere refused naming it."""
        from ..frame import PreparedFrame

        table = getattr(self.owner, "table", None)
        PreparedFrame.of(image, name=self.frames.where(k)).check_key(self.keys[k], 2 if table is None else table.unknown,
                                                                      str(self.frames.where(k)))
        prop = self.config.propagator(clf, learns=learning)
        prop.reset(image, self.keys[k])
        return prop

    def _resume(self, prop, s: Stretch, cur: dict) -> None:
        if cur["steps"]:
            try:
                prop.resume(cur["steps"], *self._read_carry(s, cur["steps"]))
            except InputError as exc:  # a carry of another stream, as a one-key run says it
                path = self.owner.carry_path(cur["steps"], self.fingerprint(s))
                raise OutputError(f"{path}: {exc}; use --force to start over") from None

    def _read_carry(self, s: Stretch, steps: int):
        return self.owner.read_carry(steps, stretch=self.fingerprint(s))

    def _keep_carry(self, cur: dict, carry, learned: Callable[[], np.ndarray | None], scene=None) -> None:
        """One more step done: the carry it left, what was ``learned`` (computed now) and the cut test's ``scene``
        (:attr:`pcreg.Propagator.scene`), for a resumed run."""
        cur["steps"] += 1
        self.owner.keep_carry(cur["steps"], carry, learned(), scene, stretch=cur["fingerprint"])

    def _store(self, s: Stretch, cur: dict) -> None:
        """A video's frames of the stretch and its key frames, decoded in order into the hidden folder."""
        lo, hi = s.start if s.first is None else s.first, s.last
        assert hi is not None
        first = lo if cur["next"] is None else cur["next"]
        for frame in self._decoded.frames(first):
            if frame.position > hi:
                break
            self.check()
            self.owner.gaps.mark(frame)  # where the video skips frames: said, and committed with the frame
            write_frame(self._hidden(cur["fingerprint"]), frame.position, frame.image, compress=self.compress)
            cur["next"] = frame.position + 1
            self._commit()
        if cur["next"] is None or cur["next"] <= hi:
            raise InputError(f"{self.frames.path}: the video ends before key frame {self.frames.name(hi)}")

    def _between(self, s: Stretch, cur: dict) -> None:
        """The forward pass of a stretch between two key frames: each frame's prior term from the earlier
        key frame, kept (float16) for the backward pass."""
        from ..outputs import WriteBehind

        a, b = s.first, s.last
        assert a is not None and b is not None
        keys = {k: self._image(s, k) for k in (a, b)}
        prop = self._propagator(self._classifier(s, keys), a, keys[a], learning=False)
        self._resume(prop, s, cur)
        start = a + 1 if cur["next"] is None else cur["next"]
        with WriteBehind() as writer:  # a frame's prior term, carry and commit written while the next is labelled
            for t, _, _ in propagate(prop, self._images(s, range(start, b), writer), check=self.check):
                report = prop.last
                prior = report.trust.prior_term(report.log_odds.shape)  # made smaller on the writer's thread
                weight = None if prop.classes is None else weight_sum(report.trust)
                writer.submit(self._keep_prior, cur, t, prior, bool(report.fallback), prop.carry,
                              prop.learned_later(), weight, prop.scene, cut=report.cut)
                if self.on_step is not None:
                    self.on_step()

    def _keep_prior(self, cur: dict, t: int, prior: np.ndarray, fallback: bool, carry, learned,
                    weight: np.ndarray | None = None, scene=None, *, cut: bool = False) -> None:
        """Frame ``t`` of a forward pass between two key frames: its prior term (with many classes also its
        summed trust weight, for the class window) kept for the backward pass as :data:`PRIOR_STORE_DTYPE`, with
        whether its cut test found the frame in another scene, the propagator's carry, and the commit
        (:func:`~pcreg.runs.kept.write_prior`)."""
        write_prior(self._hidden(cur["fingerprint"]), t, prior.astype(PRIOR_STORE_DTYPE), fallback,
                    None if weight is None else weight.astype(PRIOR_STORE_DTYPE), compress=self.compress, cut=cut)
        self._keep_carry(cur, carry, learned, scene)
        cur["next"] = t + 1
        cur["fallbacks"] += int(fallback)
        self._commit()

    def _backward(self, s: Stretch, cur: dict) -> None:
        """From the later key frame back to the stretch's first frame; between two key frames, each frame
        fuses the forward pass's prior term too."""
        from ..outputs import WriteBehind

        b = s.last
        assert b is not None
        both = s.first is not None
        keys = {k: self._image(s, k) for k in s.keys}
        clf = self._classifier(s, keys)
        prop = self._propagator(clf, b, keys[b], learning=not both)
        self._resume(prop, s, cur)
        start = b - 1 if cur["next"] is None else cur["next"]
        references = References(keys[b], prop.carry)
        priors: dict[int, tuple] | None = {} if both else None  # each frame's, read with the frame
        with WriteBehind() as writer:  # a frame's outputs written while the next is labelled
            todo = self._images(s, range(start, s.start - 1, -1), writer, priors)
            for t, image, labels in propagate(prop, todo, check=self.check):
                report = prop.last
                step = report.to_dict()
                conf = report.confidence
                if priors is not None:
                    p_a, fallback, w_a, cut_a = priors.pop(t)
                    d = report.log_odds
                    weights = None if w_a is None else (w_a.astype(np.float32), weight_sum(report.trust))
                    cuts = (cut_a, report.cut)
                    labels, conf, second = two_sided(d, p_a, report.trust.prior_term(d.shape), prop.trust,
                                                     size=prop.working_size, classes=prop.class_read, weights=weights,
                                                     cuts=cuts)
                    labels, conf, at = kept_between(prop.bars, getattr(image, "rgb", image), labels, conf)
                    iou = prop.class_iou(labels[at], conf[at], None if second is None else second[at])
                    step.update(_two_sided_step(step, iou, conf[at], fallback, cuts))
                    labels = prop.table_labels(labels)  # two known classes in other ids than lagr's: the table's
                self._record(writer, s, cur, t, image, labels, conf, step, prop, clf, after=t - 1,
                             reference=references.of(report))
                references.stepped(report, image)

    def _forward(self, s: Stretch, cur: dict) -> None:
        """From the last key frame to the end, as a run from one key frame."""
        from ..outputs import WriteBehind

        a = s.first
        assert a is not None
        frames = self._decoded.frames(a)
        key = next(frames, None)
        if key is None:
            raise InputError(f"{self.frames.path}: the video ends before key frame {self.frames.name(a)}")
        self.owner.gaps.mark(key)
        clf = self._classifier(s, {a: key.image})
        prop = self._propagator(clf, a, key.image, learning=True)
        self._resume(prop, s, cur)
        start = a + 1 if cur["next"] is None else cur["next"]
        references = References(key.image, prop.carry)
        with WriteBehind() as writer:  # a frame's outputs written while the next is labelled
            todo = ((f.position, f.image) for f in self.owner.gaps.marked(frames, writer) if f.position >= start)
            for t, image, labels in propagate(prop, todo, check=self.check, where=self.frames.where):
                self._record(writer, s, cur, t, image, labels, prop.last.confidence, prop.last.to_dict(), prop,
                             clf, after=t + 1, reference=references.of(prop.last))
                references.stepped(prop.last, image)

    def _record(self, writer, s: Stretch, cur: dict, t: int, image, labels, conf, step: dict, prop, clf, *,
                after: int, reference=None) -> None:
        """Frame ``t``'s outputs, its step line and the commit (the next frame to label: ``after``), written by
        ``writer`` (a :class:`~pcreg.outputs.WriteBehind`) while the next frame is labelled; naive Bayes
        alone (for the truth) and the propagator's carry are taken here, as they are now."""
        from ..runs.truth import scored_step

        step = dict(step, frame=t, name=self.frames.name(t), keys=[self.frames.name(k) for k in s.keys])
        if self.owner.gaps.is_damaged(t):  # decoded with errors: labelled from a concealed picture
            step["damaged"] = True
        truth = None if self.truth is None else self.truth[t]
        plain = None
        if truth is not None:
            plain = clf.predict(image)
            table = getattr(self.owner, "table", None)
            step.update(scored_step(labels, truth, plain, table))
        writer.submit(self._write_frame, cur, t, labels, conf, step, (truth, plain), prop.carry, prop.learned_later(),
                      prop.scene, after=after)
        if self.on_frame is not None:
            told = {"reference": reference} if self._told else {}
            self.on_frame(t, image, labels, prop.last, self.frames.name(t), prop.working_size, **told)

    def _write_frame(self, cur: dict, t: int, labels, conf, step: dict, scored: tuple, carry, learned, scene=None, *,
                     after: int) -> None:
        """On the writer's thread: what :meth:`_record` hands on, in the order a resumed run reads it back
        (``scored``: the frame's truth map and naive Bayes' labels alone, or two Nones), committed by the run."""
        self.owner.write_frame(t, labels, conf if self.confidence else None, step, cur["truth"], scored)
        self._keep_carry(cur, carry, learned, scene)
        cur["fallbacks"] += int(step.get("fallback", False)) + int(step.get("forward", {}).get("fallback", False))
        self.state["lines"] += 1
        self.owner.totals()
        self.labelled += 1
        cur["next"] = after
        self._commit()


class Decoded:
    """The chosen frames read once for every pass that reads the source, in the plan's order: a pass that begins at
    or after the last frame the one before took goes on from there (the last two frames taken are kept: a key frame
    two stretches share, and the frame after it that a pass took to see its stretch end), where each pass read its
    frames from position ``first`` anew, which decodes a video from its start (a key frame a minute over an hour of
    video: its first half decoded sixty times). A frame is the same however the reading got there
    (:meth:`~pcreg.datasets.sources.VideoFrames.frames`). ``held``: a frame and the reading it came from, begun before
    the passes (the run's first chosen frame, read for its size: a video decoded to ``--start``), which the first pass
    goes on from if it begins at that frame; a pass that begins later reads anew, passing the frames before its own
    unconverted."""

    def __init__(self, frames, held: tuple | None = None) -> None:
        self.source = frames
        self._reading: Iterator | None = None if held is None else held[1]
        self._kept: list = [] if held is None else [held[0]]  # the last two frames taken, in order
        self._held = held is not None

    def frames(self, first: int) -> Iterator:
        """The chosen frames from position ``first`` on (:meth:`~pcreg.datasets.sources.VideoFrames.frames`)."""
        from dataclasses import replace

        held, self._held = self._held, False
        if (self._reading is None or not self._kept or first < self._kept[0].position
                or (held and first > self._kept[0].position)):
            self.close()
            self._reading = decoded_to(self.source, first)  # a video decoded to ``first`` under a bar
        for frame in list(self._kept):
            if frame.position >= first:
                yield replace(frame, image=frame.image.copy())  # the caller's own, as a frame read anew
        while True:
            try:
                frame = next(self._reading, None)
            except BaseException:
                self.close()  # an error decoding: the next pass reads anew
                raise
            if frame is None:
                return
            self._kept = [*self._kept[-1:], frame]
            if frame.position >= first:
                yield frame

    def close(self) -> None:
        """The source's reading ended (a video's file closed); the next pass reads anew."""
        if self._reading is not None:
            self._reading.close()  # type: ignore[attr-defined]
        self._reading, self._kept = None, []


def _two_sided_step(step: dict, iou: dict, confidence: np.ndarray, fallback: bool, cuts: tuple[bool, bool]) -> dict:
    """What a frame between two key frames changes of its backward pass's ``step`` line: the predicted error and
    each class's predicted IoU (``iou``) of the labels written (``confidence`` of their picture), the forward pass's
    fallback and cut, and ``cut`` true only where both passes found the frame outside their key frame's scene."""
    from .trust import predicted_error

    trust = step.get("trust")
    if trust is not None and "cut" in trust:
        trust = {**trust, "cut": cuts[0] and cuts[1]}
    return {"predicted_error": predicted_error(confidence), "predicted_iou": {str(k): v for k, v in iou.items()},
            "trust": trust, "forward": {"fallback": fallback, "cut": cuts[0]}}


def _takes_reference(on_frame: Callable) -> bool:
    """Whether an ``on_frame`` callback takes ``reference=`` (0.2.0's took six arguments, without it)."""
    try:
        params = inspect.signature(on_frame).parameters.values()
    except (TypeError, ValueError):  # a callable whose signature Python cannot tell: given it, as before
        return True
    return any(p.name == "reference" or p.kind is inspect.Parameter.VAR_KEYWORD for p in params)
