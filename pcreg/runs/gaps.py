"""Where a run's video skips frames by its times (:class:`~pcreg.datasets.damage.Gap`: frames dropped as it was
recorded, a variable frame rate's still stretch, or a damaged block its demuxer passed over): the run goes on,
its frames numbered by count as annotation tools number them, and says so.

Each place is said on stderr by the run loop that reads the frame after it (never by the thread that decodes
ahead), the first :data:`SAID` one by one and then once that more are counted, and counted in run.json's
``gaps``, committed with the frames: ``{"places": N, "missing": K, "last": NAME, "listed": {NAME: k, ...}}``,
``listed`` naming the frame after each of the first :data:`LISTED` places and about how many frames are missing
before it, ``times`` that frame's presentation time in seconds (runs from before it have none), ``last`` the frame
after the last place counted (a pass or a resumed run that decodes the frames again counts none twice). A run
without such a place has no ``gaps``.

What reads a run afterwards (``pcreg view``, ``pcreg export``) says it with :func:`gaps_note`: from the first place
on, the run's frame N is not frame N of the file's timeline.

What else reading met at a frame (:attr:`~pcreg.datasets.sources.SourceFrame.notes`: a frame with transparent
pixels) is said the same way, the first of each kind once a run, and not counted.

A video's frames that decode with errors (:attr:`~pcreg.datasets.sources.SourceFrame.damaged`: flagged by the
decoder, a damaged or cut-short frame whose missing part FFmpeg's error concealment fills in from nearby pictures)
are labelled, counted in run.json's ``damaged``, ``{"frames": N, "last": NAME, "listed": [NAME, ...]}`` (the first
:data:`LISTED` named), their steps marked ``"damaged": true``, and said once at the end of the run and by what reads
it afterwards (:func:`damaged_note`). The frames decoded from a damaged one up to the next key frame may carry its
damage unflagged; a bit flipped where the bitstream still parses is not flagged at all.
"""

from __future__ import annotations

import sys
from typing import Iterable, Iterator

from .state import STATE

__all__ = ["GapMarks", "LISTED", "SAID", "damaged_note", "gaps_note", "kept_notes"]

#: The places run.json's ``gaps`` lists by name (the rest counted): run.json is rewritten at every frame.
LISTED = 100
#: The places a run says on stderr one by one; the rest are counted, and the count is said at the end.
SAID = 3


def _name(index: int) -> str:
    return f"{index:06d}"  # a video's frame's name (:meth:`~pcreg.datasets.sources.VideoFrames.name`)


def _say(line: str) -> None:
    """A note on stderr, above a progress bar when one is drawn there."""
    from tqdm.auto import tqdm

    tqdm.write(f"pcreg: note: {line}", file=sys.stderr)


def _change(writer, change, *args) -> None:
    """``change(*args)``, a change of the run's state: by ``writer`` (a :class:`~pcreg.outputs.WriteBehind`, which
    commits it with the frame) when one is given, else at once (the caller commits)."""
    if writer is None:
        change(*args)
    else:
        writer.submit(change, *args)


class GapMarks:
    """The places a run's video skips frames, for ``run`` (a :class:`~pcreg.runs.run.Run`: its frames' path, its
    ``out`` and its ``state``, run.json's content)."""

    def __init__(self, run) -> None:
        self.run, self.said, self.last = run, 0, -1
        self.noted: set[str] = set()  # the kinds of the frames' notes said
        self.damaged: set[int] = set()  # the positions of the frames met that decode with errors
        self.last_damaged = -1

    def mark(self, frame, writer=None) -> bool:
        """Say and count the gaps ``frame`` (a :class:`~pcreg.datasets.sources.SourceFrame`) comes after, those not
        counted yet; counted in the run's state by ``writer`` (a :class:`~pcreg.outputs.WriteBehind` that commits
        it) when one is given, else at once (the caller commits). Whether there were any. The frame's notes of a
        kind not said yet are said and kept the same way (:meth:`say`)."""
        self.say(getattr(frame, "notes", ()), writer)
        self._mark_damaged(frame, writer)
        counted = self.run.state.get("gaps")
        last = max(self.last, -1 if counted is None else int(counted["last"]))
        gaps = [g for g in getattr(frame, "gaps", ()) if g.index > last]
        if not gaps:
            return False
        self.last = gaps[-1].index
        path = self.run.frames.path
        for g in gaps:
            self.said += 1
            if self.said <= SAID:
                _say(g.note(path))
            elif self.said == SAID + 1:
                _say(f"{path}: frames missing before frame {g.index} too; further places are not said one by one but "
                     f"counted in {self.run.out / STATE} (\"gaps\")")
        _change(writer, self._count, gaps)
        return True

    def _mark_damaged(self, frame, writer) -> None:
        """Count ``frame`` in run.json's ``damaged`` if it decodes with errors and is not counted yet."""
        if not getattr(frame, "damaged", False):
            return
        self.damaged.add(frame.position)
        counted = self.run.state.get("damaged")
        if frame.index <= max(self.last_damaged, -1 if counted is None else int(counted["last"])):
            return
        self.last_damaged = frame.index
        _change(writer, self._count_damaged, frame.index)

    def _count_damaged(self, index: int) -> None:
        old = self.run.state.get("damaged") or {"frames": 0, "last": "", "listed": []}
        listed = old["listed"] + [_name(index)] if len(old["listed"]) < LISTED else old["listed"]
        self.run.state["damaged"] = {"frames": old["frames"] + 1, "last": _name(index), "listed": listed}

    def is_damaged(self, position: int) -> bool:
        """Whether the frame at ``position`` decodes with errors, as met by this run or listed in run.json."""
        damaged = self.run.state.get("damaged")
        return position in self.damaged or (damaged is not None and self.run.frames.name(position) in damaged["listed"])

    def say(self, notes: Iterable[tuple[str, str]], writer=None) -> None:
        """Say each of a frame's ``notes`` (:attr:`~pcreg.datasets.sources.SourceFrame.notes`, ``(kind, line)``) whose
        kind this run has not said yet, and keep it in the run's state (run.json's ``notes``) by ``writer`` when one
        is given, else at once (the caller commits)."""
        for kind, line in notes:
            if kind in self.noted:
                continue
            self.noted.add(kind)
            _say(line)
            _change(writer, self._keep, kind, line)

    def _keep(self, kind: str, line: str) -> None:
        kept = self.run.state.get("notes") or {}
        if kind not in kept:  # the first line of a kind: a resumed run keeps the one it has
            self.run.state["notes"] = {**kept, kind: line}

    def marked(self, frames: Iterable, writer=None) -> Iterator:
        """``frames`` as they come, each one's gaps marked (:meth:`mark`) as it is taken."""
        for frame in frames:
            self.mark(frame, writer)
            yield frame

    def _count(self, gaps: list) -> None:
        state = self.run.state
        old = state.get("gaps") or {"places": 0, "missing": 0, "last": "", "listed": {}}
        listed, times = dict(old["listed"]), dict(old.get("times") or {})
        for g in gaps[:max(0, LISTED - len(listed))]:
            listed[_name(g.index)] = g.missing
            times[_name(g.index)] = round(g.time, 3)
        state["gaps"] = {"places": old["places"] + len(gaps), "missing": old["missing"] + sum(g.missing for g in gaps),
                         "last": _name(gaps[-1].index), "listed": listed, "times": times}

    def summary(self) -> None:
        """At the end of the run: how many frames decode with errors, how many places skip frames, and where they are
        counted; nothing without one."""
        damaged = self.run.state.get("damaged")
        if damaged:
            _say(f"{damaged_note(damaged, self.run.frames.path)}; counted in {self.run.out / STATE} (\"damaged\"), "
                 "their steps marked \"damaged\"")
        gaps = self.run.state.get("gaps")
        if not gaps:
            return
        first = min(gaps["listed"], default=gaps["last"], key=int)  # by number: a seventh digit from frame 1000000
        _say(f"{self.run.frames.path}: about {gaps['missing']} frame(s) missing by its times at {gaps['places']} "
             f"place(s), the first before frame {int(first)}; counted in {self.run.out / STATE} (\"gaps\"), the "
             "frames numbered by count")


def _clock(seconds: float) -> str:
    """A time in a video as a player shows it: ``0.9 s``, ``12.04 s``, ``1:02:05.4``."""
    if seconds < 60:
        return f"{seconds:.3f}".rstrip("0").rstrip(".") + " s"
    minutes, s = divmod(seconds, 60)
    hours, minutes = divmod(int(minutes), 60)
    return (f"{hours}:{minutes:02d}" if hours else f"{minutes}") + f":{s:04.1f}"


def gaps_note(gaps: dict | None, source) -> str | None:
    """What a reader of a run says of the places its video ``source`` skips frames by its times (run.json's ``gaps``,
    as :class:`GapMarks` counts them): how many places, about how many frames missing, the first :data:`SAID` places
    (the run's frame after each, its time in the file, the frames missing before it), and that the run's frame N is
    not frame N of the file's timeline from the first on. None without a place."""
    if not gaps:
        return None
    listed, times = sorted(gaps["listed"].items(), key=lambda item: int(item[0])), gaps.get("times") or {}

    def place(name: str, missing: int) -> str:
        at = f"at {_clock(float(times[name]))}, " if name in times else ""
        return f"{int(name)} ({at}{missing} missing)"

    shown = [place(n, k) for n, k in listed[:SAID]]
    more = gaps["places"] - len(shown)
    if more:
        shown.append(f"{more} more")
    first = int(listed[0][0]) if listed else int(gaps["last"])
    places = shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} and {shown[-1]}"
    return (f"{source} skips frames by its times: about {gaps['missing']} frame(s) missing at {gaps['places']} "
            f"place(s), before frame{'' if len(shown) == 1 else 's'} {places}; the run numbers its frames by count, as "
            f"annotation tools do, so from frame {first} on the run's frame N is not frame N of the file's timeline "
            f"(run.json's \"gaps\")")


def damaged_note(damaged: dict | None, source) -> str | None:
    """What is said of the frames of the video ``source`` that decode with errors (run.json's ``damaged``, as
    :class:`GapMarks` counts them): how many, the first :data:`SAID`, and that their labels come from pictures the
    decoder filled in. None without one."""
    if not damaged:
        return None
    shown = [str(int(n)) for n in damaged["listed"][:SAID]]
    more = damaged["frames"] - len(shown)
    if more:
        shown.append(f"{more} more")
    frames = shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} and {shown[-1]}"
    return (f"{source}: {damaged['frames']} frame(s) decode with errors (damaged or cut short), frame"
            f"{'' if damaged['frames'] == 1 else 's'} {frames}: FFmpeg filled in their missing parts from nearby "
            "pictures, so their labels (and those of the frames decoded from them up to the next key frame) may "
            "come from grey or smeared pictures")


def kept_notes(notes: dict | None) -> tuple[str, ...]:
    """What a reader of a run says again of what reading its frames met (run.json's ``notes``, as :class:`GapMarks`
    keeps them): each kind's line as the run said it, in the order the run met them; none without one."""
    return tuple((notes or {}).values())
