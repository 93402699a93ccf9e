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

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from ..classes.keys import run_table
from ..errors import OutputError
from ..runs.files import (CARRY, CONFIDENCE, STEPS, append_step, check_labelled, read_carry,
                          write_carry, write_confidence, write_labels)
from ..runs.state import STATE, open_state, write_state
from ..runs.truth import add_rates, count_frame, empty_counts

__all__ = ["StreamRun"]


class FrameNames(Protocol):
    """What a run needs of its frames: the name of the frame at each position (0 is the key frame) and
    the stem its outputs are named after (:class:`pcreg.datasets.sources.FolderFrames`, ``VideoFrames``)."""

    def name(self, position: int) -> str: ...

    def stem(self, position: int) -> str: ...


@dataclass
class StreamRun:
    """One run: ``frames`` (the frame source's names, position 0 is the key frame), the key frame's
    ``labels``, ``out``, the propagator's ``config`` (:class:`~pcreg.pipeline.config.PropagatorConfig`), and optional
    ``truth`` label maps (indexed by position, an entry None where there is none; it may read each when
    asked) to score against."""

    frames: FrameNames
    labels: np.ndarray
    out: Path
    config: object
    truth: Sequence[np.ndarray | None] | None = None
    identity: dict | None = None  # what a resumed run must match (paths and options), written in run.json

    def start(self, *, force: bool = False) -> int:
        """Open (or resume) the run; returns the index of the first frame still to do."""
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
                      "truth": empty_counts() if self.truth else None}
        write_labels(self.out / f"{self.frames.stem(0)}.png", self.labels, run_table(self.identity))
        (self.out / STEPS).write_bytes(b"")
        write_state(self.out, self.state)
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
        """``(carry, learned)`` frame ``t`` left (a counted frame): the
        :class:`~pcreg.pipeline.stream.Carry` (None for the key frame, or where it left none) and what the
        classifier had learned from the stream, as :attr:`pcreg.Propagator.learned` saved it (None where
        it had learned nothing)."""
        if t == 0:
            return None, None
        return read_carry(self.out / CARRY.format(t % 2), t,
                          f", so frame {t + 1} cannot continue where frame {t} left off")

    def record(self, t: int, labels: np.ndarray, report, plain: np.ndarray | None = None, carry=None,
               learned=None, confidence: np.ndarray | None = None) -> None:
        """Write frame ``t``'s labels (and ``confidence``, (H, W) in [0, 1], as ``confidence/NAME.png``),
        step (``report``: its dict, or a :class:`~pcreg.pipeline.stream.StepReport`), ``carry`` (a
        :class:`~pcreg.pipeline.stream.Carry` or None) and what the classifier has ``learned`` (an array,
        None, or :meth:`~pcreg.pipeline.stream.Propagator.learned_later`), then commit it in run.json."""
        from ..classification.metrics import error_rate

        write_labels(self.out / f"{self.frames.stem(t)}.png", labels, run_table(self.identity))
        if confidence is not None:
            (self.out / CONFIDENCE).mkdir(exist_ok=True)
            write_confidence(self.out / CONFIDENCE / f"{self.frames.stem(t)}.png", confidence)
        report = report if isinstance(report, dict) else report.to_dict()
        learned = learned() if callable(learned) else learned
        step = dict(report, frame=t, name=self.frames.name(t))
        truth = None if self.truth is None else self.truth[t]
        if truth is not None:
            step["error"] = error_rate(labels, truth)
            if plain is not None:
                step["plain_error"] = error_rate(plain, truth)
            count_frame(self.state["truth"], labels, truth, plain)
            add_rates(self.state["truth"])
        append_step(self.out, step)
        write_carry(self.out / CARRY.format(t % 2), t, carry, learned)
        self.state["done"] = t + 1
        self.state["fallbacks"] += int(report.get("fallback", False))
        write_state(self.out, self.state)  # the commit point


