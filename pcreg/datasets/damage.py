"""How a damaged video is told where decoding meets it, before a frame after the damage is numbered wrong.

pcreg numbers a video's frames by their count in presentation order (frame ``i`` is the ``i``-th frame shown,
as an annotation tool that decodes the video numbers it). A frame lost without an error would number every
later frame one early, and a key frame's labels would be drawn on the frame before the one they were made on:

- an AVI's damaged chunk header: its demuxer passes over the chunk; the index tells where every frame lies
  (:func:`frame_places`, :func:`check_place`);
- a Matroska file's damaged block header: its demuxer passes over the element and resynchronises at the next
  it recognises, losing whole blocks (a cluster's frames) without an error. Each frame's time and duration tell
  it (:class:`Timing`). An MP4's demuxer reads every frame from the index, and its decoder raises on a frame it
  cannot decode; an MP4's durations are decoding steps, which with B-frames are not the presentation steps.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

__all__ = ["Timing", "frame_places", "check_place"]


class Timing:
    """The frames' presentation times held against their durations (a Matroska block's, or the track's default
    duration): in a stream whose frames have so far followed each other one duration apart, a frame that comes a
    whole number of durations (two or more) after the one before is refused, the frames between missing. A stream
    whose steps differ from the durations (a variable frame rate: the default duration is the nominal rate) is not
    checked from that step on."""

    #: Steps of one duration that must come before a longer step is taken for a loss (a variable frame rate's first
    #: step is often longer; a frame lost between the first two is not told).
    REGULAR = 1

    def __init__(self, path: Path, *, checked: bool) -> None:
        self.path, self.regular = path, 0 if checked else -1
        self.previous: tuple[int, int, float] | None = None  # pts, duration, time base of the frame before

    def check(self, index: int, frame) -> None:
        """Frame ``index`` (from 0, as decoded), an ``av.VideoFrame``: an :class:`InputError` when frames are
        missing before it."""
        if self.regular < 0:
            return
        pts, duration, base = frame.pts, getattr(frame, "duration", 0) or 0, frame.time_base
        previous, self.previous = self.previous, (pts, duration, base) if pts is not None and duration > 0 else None
        if previous is None or self.previous is None or base != previous[2]:
            return
        step, interval = pts - previous[0], previous[1]
        slots = round(step / interval)  # the frame intervals the step spans
        if 4 * abs(step - interval) <= interval:
            self.regular += 1
        elif self.regular >= self.REGULAR and slots >= 2 and 4 * abs(step - slots * interval) <= interval:
            missing, seconds = slots - 1, float(step * base)
            raise InputError(f"{self.path}: frame {index} comes {seconds:.3g} s after the frame before, the frames "
                             f"before it every {float(interval * base):.3g} s: about {missing} frame(s) are missing "
                             f"there and every later frame would be numbered early; the video is damaged (if its frame "
                             f"rate changes there, remux it to MP4 to read it as it is: ffmpeg -i IN -c copy OUT.mp4)")
        else:
            self.regular = -1


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
