"""Where decoding meets a video whose frames may be numbered otherwise than its maker numbered them.

pcreg numbers a video's frames by their count in presentation order (frame ``i`` is the ``i``-th frame shown,
as an annotation tool that decodes the video numbers it). A frame lost without an error numbers every later
frame one early against another copy of the video:

- an AVI's damaged chunk header: its demuxer passes over the chunk; the index tells where every frame lies, so
  a frame passed over is certainly damage and refused (:func:`frame_places`, :func:`check_place`);
- a Matroska file whose frames' times skip a whole number of frame durations (:class:`Timing`, :class:`Gap`):
  a damaged block header its demuxer passed over (it resynchronises at the next element it recognises, losing
  whole blocks without an error), or frames a live capture dropped under load, or a variable frame rate's still
  stretch. The times cannot tell those apart: the frames go on numbered by count, and the gap is told to the
  reader of the frames (:attr:`~pcreg.datasets.sources.SourceFrame.gaps`). An MP4's demuxer reads every frame
  from the index, and its decoder raises on a frame it cannot decode; an MP4's durations are decoding steps,
  which with B-frames are not the presentation steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

__all__ = ["Gap", "Timing", "Start", "START", "frame_places", "check_place", "missing_index", "FIRST_BOXES"]


@dataclass(frozen=True)
class Gap:
    """Frames missing by the times before frame ``index`` (from 0, as decoded): it comes ``step`` seconds after
    the frame before, the frames before that one ``every`` seconds apart, so about ``missing`` frames would fill
    the step; ``time``: its presentation time in seconds, as the file gives it (where a player's timeline shows
    it, the count of frames before it not)."""

    index: int
    step: float
    every: float
    missing: int
    time: float = 0.0

    def note(self, path: Path) -> str:
        """What a reader says of the gap in the video at ``path``."""
        return (f"{path}: frame {self.index} comes {self.step:.3g} s after the frame before, the frames before it "
                f"every {self.every:.3g} s: about {self.missing} frame(s) missing there (dropped as it was recorded, "
                "or a damaged block passed over); frames numbered by count, as annotation tools do; if the key "
                "labels were drawn on another copy of the video, the frames after this one are numbered early")


class Timing:
    """The frames' presentation times held against their durations (a Matroska block's, or the track's default
    duration): in a stream whose frames have so far followed each other one duration apart, a frame that comes a
    whole number of durations (two or more) after the one before is a :class:`Gap`, the frames between missing.
    A stream whose steps differ from the durations (a variable frame rate: the default duration is the nominal
    rate) is not checked from that step on."""

    #: Steps of one duration that must come before a longer step is taken for a gap (a variable frame rate's first
    #: step is often longer; a frame lost between the first two is not told).
    REGULAR = 1

    def __init__(self, *, checked: bool) -> None:
        self.regular = 0 if checked else -1
        self.previous: tuple[int, int, float] | None = None  # pts, duration, time base of the frame before

    def check(self, index: int, frame) -> Gap | None:
        """Frame ``index`` (from 0, as decoded), an ``av.VideoFrame``: the :class:`Gap` before it, if frames are
        missing there."""
        if self.regular < 0:
            return None
        pts, duration, base = frame.pts, getattr(frame, "duration", 0) or 0, frame.time_base
        previous, self.previous = self.previous, (pts, duration, base) if pts is not None and duration > 0 else None
        if previous is None or self.previous is None or base != previous[2]:
            return None
        step, interval = pts - previous[0], previous[1]
        slots = round(step / interval)  # the frame intervals the step spans
        if 4 * abs(step - interval) <= interval:
            self.regular += 1
        elif self.regular >= self.REGULAR and slots >= 2 and 4 * abs(step - slots * interval) <= interval:
            return Gap(index, float(step * base), float(interval * base), slots - 1, float(pts * base))
        else:
            self.regular = -1
        return None


#: The kind of note (run.json's ``"notes"``) of a video whose first frames do not decode.
START = "start"


class Start:
    """The frames at a video's start that its decoder passes over without an error: the packets shown before the first
    frame that comes out (their presentation time earlier than its) never decode. A file cut without re-encoding
    (``ffmpeg -ss T -c copy`` off a key frame, a stream recorded from its middle) begins with frames that refer to a
    key frame it no longer holds; H.264's and HEVC's decoders drop them (HEVC's leading pictures of an open GOP too),
    so frame 0 is the first frame that decodes, as a player and an annotation tool decoding the file show it.
    :meth:`packets` watches the packets go by; :meth:`first` the first frame out: ``lost``, how many were passed over."""

    def __init__(self) -> None:
        self.times: list[int] | None = []  # the shown packets' times up to the first frame out; None after it
        self.lost = 0

    def packets(self, packets):
        """``packets`` as they come, the time of each shown one (not one an edit list hides) kept until the first frame
        is out."""
        for packet in packets:
            if self.times is not None and packet.size and packet.pts is not None and not getattr(packet, "is_discard", False):
                self.times.append(int(packet.pts))
            yield packet

    def first(self, frame, path: Path) -> tuple[str, str] | None:
        """The note of the video at ``path`` whose first frame out, ``frame`` (an ``av.VideoFrame``), comes after
        packets that never decode; None when none was passed over (or the frame has no time)."""
        times, self.times = self.times, None
        if not times or frame.pts is None:
            return None
        self.lost = sum(t < frame.pts for t in times)
        if not self.lost:
            return None
        at = "" if frame.time is None else f", at {frame.time:.3g} s"
        return START, (f"{path}: its first {self.lost} frame(s) do not decode (the video begins without the key frame "
                       "they refer to, as a file cut without re-encoding does): frame 000000 is the first that decodes"
                       f"{at}, and frames are numbered by count from it, as FFmpeg decodes the file (and annotation tools that "
                       "decode with it number them); "
                       "if the key labels were drawn on another copy of the video, re-encode it from that copy")


def frame_places(container, stream) -> list[int] | None:
    """Where an AVI's index (``idx1``, or OpenDML's) puts each video frame, in bytes from the file's start, when it
    places as many as the header declares; else None. The AVI demuxer reads chunk after chunk and passes over one
    whose header is damaged without a word: every later frame would be read one place early, and labelled so."""
    entries = getattr(stream, "index_entries", None)
    if container.format.name != "avi" or entries is None or not stream.frames or len(entries) != stream.frames:
        return None
    return [int(e.pos) for e in entries]


def check_place(places: list[int], read: int, pos: int, path: Path) -> None:
    """An :class:`InputError` when the ``read``-th packet (from 0) lies at or past the index's place of the next frame
    (``pos``: the packet's data, a chunk header after its index entry): the frames between were passed over."""
    if read + 1 >= len(places) or pos < places[read + 1]:
        return
    skipped = sum(1 for p in places[read + 1:] if p <= pos)
    raise InputError(f"{path}: frame {read} does not read (its chunk at byte {places[read]} is damaged; {skipped} "
                     f"frame(s) passed over): the video is truncated or damaged")


#: The top-level boxes an MP4 or QuickTime file starts with: ``ftyp`` (every MP4), or in a QuickTime file
#: written without it, the padding boxes ``wide``, ``free`` and ``skip``, or its frames' ``mdat`` itself.
FIRST_BOXES = (b"ftyp", b"wide", b"free", b"skip", b"mdat")


def missing_index(path: Path) -> str | None:
    """Why FFmpeg cannot open ``path`` when it is an MP4/MOV whose recording stopped before its end, or None.

    Such a file (a camera's battery ran out, a recorder was killed) holds its frames (``mdat``) but not the index
    written last (``moov``), which says where each frame lies; FFmpeg reads it as invalid data. Read from the
    top-level boxes' headers alone, of a file that starts as MP4 or QuickTime files do (:data:`FIRST_BOXES`: an
    old QuickTime file has no ``ftyp``, and may start with ``wide``, ``free`` or its ``mdat``)."""
    import struct

    seen: list[bytes] = []
    try:
        with open(path, "rb") as fh:
            end = fh.seek(0, 2)
            at = 0
            while at + 8 <= end and len(seen) < 1000:
                fh.seek(at)
                size, kind = struct.unpack(">I4s", fh.read(8))
                if size == 1 and at + 16 <= end:
                    size = struct.unpack(">Q", fh.read(8))[0]
                seen.append(kind)
                if size < 8:  # 0: the last box, to the file's end; below 8, a size never written
                    break
                at += size
    except OSError:
        return None
    if not seen or seen[0] not in FIRST_BOXES or b"moov" in seen or b"mdat" not in seen:
        return None
    return (f"{path}: an MP4 or QuickTime file without its index (no moov box): its recording stopped before it was finished "
            "(power lost, the recorder killed), so FFmpeg cannot tell where its frames lie; a repair tool such as "
            "untrunc rebuilds the index from a whole recording of the same camera and settings")
