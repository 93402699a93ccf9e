"""The closing lines of ``pcreg run``: the run's predicted error over the frames it labelled, the frame predicted
worst, the class predicted worst, the classes the labels lost, and the command that shows the labels on the frames."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from ..classes.table import listed_name
from ..outputs import shell_word
from ..pipeline.stream import STREAM_WEIGHT

__all__ = ["predicted_summary", "truth_summary", "lost_summary", "key_classes", "LISTED"]

#: The closing message lists each class's IoU against the truth up to this many classes (CamVid's eleven and a
#: void fit); beyond, the lowest this many: a line a person reads, not a table.
LISTED = 12


def predicted_summary(steps: dict[int, dict], stem: Callable[[int], str], table, out: Path, lost: str = "",
                      weight: float | None = None) -> str:
    """The run's predicted error as lines of its closing message ("" when no step predicted one): the mean over the
    frames labelled, the frame predicted worst (``stem``: a frame's name by its position), the class of ``table`` of
    the lowest mean predicted IoU, ``lost`` (:func:`lost_summary`'s line) and the command that shows the labels in
    ``out`` on the frames; a run of another ``weight`` (``--weight``) than the one the confidence is calibrated at
    says so after the predicted error. ``steps``:
    {frame: its step} of the steps with a predicted error (:meth:`pcreg.runs.run.Run.predicted`)."""
    if not steps:
        return ""
    predicted = {t: float(s["predicted_error"]) for t, s in steps.items()}
    worst = max(predicted, key=lambda t: predicted[t])
    line = (f"\npredicted error: {sum(predicted.values()) / len(predicted):.2f}% of a frame's pixels on average "
            f"over {len(predicted)} frame(s), {predicted[worst]:.2f}% at most ({stem(worst)})")
    if weight is not None and weight != STREAM_WEIGHT:
        line += (f" (the confidence is calibrated at the default --weight {STREAM_WEIGHT:g}: at {weight:g} it and the "
                 "predicted error read surer, or less sure, than the labels are)")
    ious = _mean_ious(steps, "predicted_iou", table)
    if ious:  # a small class can be half wrong while the frame's error reads a few %
        c = min(ious, key=lambda c: ious[c][0])
        line += (f"; the class predicted worst: {listed_name(table.name_of(c))}, IoU {ious[c][0]:.2f} on average "
                 f"over the {ious[c][1]} frame(s) that show it")
    return line + lost + f"\nto review the labels on the frames: pcreg view {shell_word(out)} --web"


def truth_summary(steps: dict[int, dict], table) -> str:
    """The line of the closing message on each class's IoU against the truth (``pcreg run --truth``; "" when no step
    has one): its mean over the frames whose truth or labels show it (``steps.jsonl``'s ``iou``), beside its mean
    predicted IoU (in brackets, over the frames whose labels show it), and the mean over the classes. Every class in
    the table's order, up to :data:`LISTED`; more (a large table's), the :data:`LISTED` lowest, lowest first, and how
    many more steps.jsonl holds."""
    truth = _mean_ious(steps, "iou", table)
    if not truth:
        return ""
    predicted = _mean_ious(steps, "predicted_iou", table)
    shown = sorted(truth) if len(truth) <= LISTED else sorted(truth, key=lambda c: (truth[c][0], c))[:LISTED]
    each = ", ".join(f"{listed_name(table.name_of(c))} {truth[c][0]:.2f}" + (f" ({predicted[c][0]:.2f})" if c in predicted else "")
                     for c in shown)
    more = "" if len(shown) == len(truth) else f", and {len(truth) - len(shown)} more classes in steps.jsonl"
    lowest = "" if len(shown) == len(truth) else f" (the {LISTED} lowest)"
    scored = sum(isinstance(step.get("iou"), dict) for step in steps.values())  # a step of an earlier pcreg kept none
    among = "" if scored == len(steps) else f", among the {scored} of the {len(steps)} frames whose step holds one"
    return (f"\nIoU against the truth, each class's mean over the frames that show it{among} (predicted from the "
            f"confidence in brackets){lowest}: {each}{more}; the mean over all {len(truth)} classes "
            f"{np.mean([v for v, _ in truth.values()]):.2f}")


def _mean_ious(steps: dict[int, dict], field: str, table) -> dict[int, tuple[float, int]]:
    """{class id: (mean IoU, frames)} of the steps' ``field`` (``predicted_iou`` or ``iou``), each class's over the
    steps that give it one (a class a frame does not show has no IoU there)."""
    ious: dict[int, list[float]] = {}
    for step in steps.values():
        for c, v in _class_ious(step.get(field), table):
            ious.setdefault(c, []).append(v)
    return {c: (float(np.mean(v)), len(v)) for c, v in ious.items()}


def _class_ious(iou, table) -> list[tuple[int, float]]:
    """``(class id, IoU)`` of a step's ``predicted_iou`` or ``iou`` for the classes of
    ``table``; an entry pcreg run did not write (not a class of the table, not an IoU in [0, 1]) is left out: a
    summary's figure, not a reader's."""
    if not isinstance(iou, dict):
        return []
    ids = {c.id for c in table.classes}
    read = []
    for k, v in iou.items():
        c = int(k) if isinstance(k, str) and k.isdigit() else None
        if c is not None and c in ids and type(v) in (int, float) and 0.0 <= v <= 1.0:
            read.append((c, float(v)))
    return read


def lost_summary(steps: dict[int, dict], keys_of: Callable[[dict], set[int] | None], stem: Callable[[int], str],
                 table) -> str:
    """The line of the closing message naming the classes that a step's key frame(s) hold and its labels do not
    (``keys_of``: a step's key frames' known classes, None where they cannot be read; a step's labels' classes are
    its ``predicted_iou``'s), in how many frames and from which (``stem``: a frame's name by its position); "" when
    none. The confidence cannot see such a class (it has no pixel to be unsure of), and on the shared clips the
    truth still held it in most such frames (docs/results.md)."""
    lost: dict[int, list[int]] = {}
    for t, step in sorted(steps.items()):
        held, keys = step.get("predicted_iou"), keys_of(step)
        if not isinstance(held, dict) or not keys:
            continue
        for c in keys - {c for c, _ in _class_ious(held, table)}:
            lost.setdefault(c, []).append(t)
    if not lost:
        return ""
    shown = sorted(lost, key=lambda c: (-len(lost[c]), c))[:LISTED]
    each = ", ".join(f"{listed_name(table.name_of(c))} in {len(lost[c])} frame(s) from {stem(lost[c][0])}" for c in shown)
    more = "" if len(shown) == len(lost) else f", and {len(lost) - len(shown)} more"
    return (f"\nclasses the key frame(s) hold that the labels lost: {each}{more} (a class that left the view, or one the "
            "labels missed: the predicted error cannot tell)")


def key_classes(out: Path, table, key_frame: str | None) -> Callable[[dict], set[int] | None]:
    """A step's key frames' known classes, read from their label files in the run's ``out`` (each once): the step's
    ``keys`` (a key-frames run's), else ``key_frame`` (a run from one label image); None where a file cannot be
    read (the line is then not said of that step)."""
    from ..errors import InputError
    from ..export import read_labels

    known = set(table.known_ids)
    read: dict[str, set[int] | None] = {}

    def classes(name: str) -> set[int] | None:
        if name not in read:
            try:
                read[name] = set(np.unique(read_labels(out / f"{Path(name).stem}.png", table)).tolist()) & known
            except (InputError, OSError):
                read[name] = None
        return read[name]

    def of(step: dict) -> set[int] | None:
        names = step.get("keys") or ([] if key_frame is None else [key_frame])
        found = [classes(str(n)) for n in names]
        if not found or any(f is None for f in found):
            return None
        return {c for f in found if f is not None for c in f}

    return of
