"""How a video's frames are shown: the frames its demuxer hands on (an edit list's hidden frames counted), whether
the first is interlaced, the video stream's own duration, and the quarter turns and mirrors of a frame's display
matrix, as FFmpeg's players apply them. :class:`~pcreg.datasets.sources.VideoFrames` reads a video through these."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError

__all__ = ["shown_frames", "first_interlaced", "video_duration", "Turn", "display_turn", "as_shown", "shown_note"]


def shown_frames(container, stream, hidden: list[int], path: Path, through=iter) -> Iterator:
    """The video stream's frames as ``container.decode(stream)`` gives them, its packets passed ``through`` a function
    (a :class:`~pcreg.datasets.vp9_check.Vp9Check`'s), counting in ``hidden[0]`` the packets the demuxer marks to discard:
    an MP4's edit list starting after its first frames (``ffmpeg -ss T -c copy``, a phone's trim) keeps them as references,
    decoded, never shown, though the container counts them. An AVI's indexed frame the demuxer passes over is refused where missed."""
    from .damage import check_place, frame_places

    places = frame_places(container, stream)
    read = 0
    for packet in through(resynced(container, stream)):
        hidden[0] += bool(getattr(packet, "is_discard", False))
        if places is not None and packet.pos is not None:
            check_place(places, read, int(packet.pos), path)
            read += 1
        yield from packet.decode()


#: Times in a row FFmpeg's demuxer may give up resynchronising before the video counts as unreadable.
RESYNC_TRIES = 100_000


def resynced(container, stream) -> Iterator:
    """``container.demux(stream)``, taken up again where the demuxer gives up resynchronising (EAGAIN): an MPEG-TS
    demuxer scans a bounded stretch for its next packet, so a whole file with a run of other bytes (a recorder's
    padding, 200 kB of zeros) was refused as truncated at the frame after them, though FFmpeg plays it through."""
    import av

    tries = 0
    while True:
        try:
            for packet in container.demux(stream):
                tries = 0
                yield packet
            return
        except av.BlockingIOError:
            tries += 1
            if tries > RESYNC_TRIES:
                raise


def first_interlaced(container, stream) -> bool:
    """Whether the video's first frame is flagged interlaced; False when it does not decode (refused where
    :meth:`~pcreg.datasets.sources.VideoFrames.frames` meets it)."""
    import av

    try:
        frame = next(iter(container.decode(stream)), None)
    except av.FFmpegError:
        return False
    return frame is not None and bool(frame.interlaced_frame)


def video_duration(container, stream) -> float | None:
    """The video stream's own duration in seconds: its ``duration`` in its time base, or Matroska's ``DURATION``
    tag (left out where it is no positive finite time: ``float`` reads ``nan`` and ``inf``); the container's only
    when the video is its one stream (an audio track may run longer); else None."""
    import math

    if stream.duration and stream.time_base:
        return float(stream.duration * stream.time_base)
    tag = str(stream.metadata.get("DURATION", ""))
    hours, _, rest = tag.partition(":")
    minutes, _, seconds = rest.partition(":")
    try:
        tagged = int(hours) * 3600 + int(minutes) * 60 + float(seconds)
        if math.isfinite(tagged) and tagged > 0:
            return tagged
    except ValueError:
        pass
    if container.duration and len(container.streams) == 1:
        return container.duration / 1e6
    return None


#: How a frame is turned to be shown: (transposed, rows reversed, columns reversed), in that order.
Turn = tuple[bool, bool, bool]


def display_turn(frame, path: Path) -> Turn:
    """How the frame's display matrix (FFmpeg's ``DISPLAYMATRIX`` side data, as a phone writes it) shows it: a
    pixel ``(p, q)`` is shown at ``(a p + c q, b p + d q)``, with ``a, b, c, d`` the matrix's entries 0, 1, 3 and 4,
    so a matrix of quarter turns and mirrors moves the pixel grid by a transpose and reversals, as FFmpeg's
    autorotation does. PyAV's ``VideoFrame.rotation`` gives the angle alone: a mirrored matrix (a selfie camera's)
    read as a rotation is shown upside down. A matrix that is not quarter turns is refused; one of zeros (no angle) turns
    nothing, as in FFmpeg's players."""
    from av.sidedata.sidedata import SideDataContainer, Type

    # Read through a container of its own, not ``frame.side_data``: that property keeps its container on the frame,
    # which refers back to the frame, so the frame (and its picture, FFmpeg's memory) would be freed only by
    # Python's cycle collector, and one that outlived a collection only by a full one, rare in a long run: decoding's
    # memory grew with them, about 2.5 kB a frame at 320x240 (docs/benchmarks.md).
    side = SideDataContainer(frame)  # type: ignore[call-arg]  # PyAV's stub leaves out its constructor
    try:  # looked up by its type: iterating the container gives the side data up to PyAV 18.1.0, their types since
        matrix: bytes | None = bytes(side[Type.DISPLAYMATRIX])
    except KeyError:
        matrix = None
    if matrix is None or len(matrix) != 36:
        return False, False, False
    a, b, _, c, d = np.frombuffer(matrix, dtype=np.int32)[:5].astype(float)
    big = max(abs(a), abs(b), abs(c), abs(d))
    if big == 0:  # no angle at all (FFmpeg's is NaN): its players show the frames as stored, and so does pcreg
        return False, False, False
    small = 0.0087 * big  # sin(0.5 degrees): the tolerance a rotation has of a quarter turn
    if max(abs(b), abs(c)) <= small < min(abs(a), abs(d)):
        return False, d < 0, a < 0
    if max(abs(a), abs(d)) <= small < min(abs(b), abs(c)):
        return True, b < 0, c < 0
    rotation = float(getattr(frame, "rotation", 0) or 0)
    raise InputError(f"{path}: a display rotation of {rotation:g} degrees; pcreg turns frames by quarter turns only")


def shown_note(turn: Turn, path: Path, size: tuple[int, int]) -> tuple[str, str] | None:
    """The note of a video at ``path`` whose display matrix turns its frames (``turn``, :func:`display_turn`) at the
    size they are stored (``size``, (W, H) as shown): a half turn, a mirror, or a quarter turn of a square frame. Key
    labels drawn on the frames as stored fit the frames as shown as well, and nothing would tell them apart: they are
    wrong where the picture is not symmetric. None for frames shown as stored, or at another size (labels drawn on
    the frames as stored are then refused for their size)."""
    from .folder_view import ORIENTATION

    transposed, rows, columns = turn
    if not (transposed or rows or columns) or (transposed and size[0] != size[1]):
        return None
    said = {(False, True, True): "turned by a half turn", (False, True, False): "mirrored top to bottom",
            (False, False, True): "mirrored left to right", (True, False, False): "mirrored about a diagonal",
            (True, True, True): "mirrored about a diagonal"}.get(turn, "turned by a quarter turn")
    return ORIENTATION, (f"{path}: its display matrix has players show its frames {said}, at the size they are stored: "
                         "pcreg reads the frames as shown and takes --labels as drawn on them so; if the labels were drawn "
                         "on the frames as stored, turn them the same way, and run again with --force")


def as_shown(image: np.ndarray, turn: Turn) -> np.ndarray:
    """``image`` (H, W, C) turned as :func:`display_turn` says the frame is shown."""
    transposed, rows, columns = turn
    if not (transposed or rows or columns):
        return image
    shown = image.transpose(1, 0, 2) if transposed else image
    return np.ascontiguousarray(shown[::-1 if rows else 1, ::-1 if columns else 1])
