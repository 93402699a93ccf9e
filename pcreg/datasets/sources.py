"""Frame sources for a stream: a folder of images or a video file, each frame decoded when it is read.

A source yields :class:`SourceFrame` (position in the stream, index in the folder or video, name,
image) lazily, one frame at a time: memory does not grow with the length of the video, and a resumed
stream starts at its first frame not done. :class:`Selection` chooses the frames (``start``, ``stop``,
``every``); the first chosen frame is the key frame.

Videos are decoded with PyAV (FFmpeg's libraries, called directly), not with OpenCV's
``cv2.VideoCapture``. Both run FFmpeg underneath; PyAV says what OpenCV hides:

- a frame of another size: OpenCV scales every frame silently to the first frame's size, PyAV gives each
  frame as decoded (a size change is refused, never resampled into the labels);
- a decoding error: OpenCV's ``read()`` returns False at an error as at the end of the stream, PyAV
  raises, so a damaged or truncated file is told from its end;
- the container: PyAV names the demuxer FFmpeg chose (an image renamed ``.mp4`` opens as a one-frame
  ``png_pipe`` in both) and the frame count the container's index declares.

A frame's display matrix (a phone's portrait video, a mirrored selfie camera) is applied by quarter turns and
mirrors, as FFmpeg's players show the frame: the key frame's labels are drawn on what the annotator saw.

An MPEG transport stream (``.ts``; a camcorder's AVCHD ``.mts``/``.m2ts``) has no index: its count is
estimated from its duration and frame rate (the progress bar's size, never where a run stops), and a file cut
short at a frame's end reads as a shorter recording. A frame the decoder had to conceal (cut short in the
middle, or damaged) is refused in any container, where decoding meets it.

Frames are read in decoding order and never by seeking: a seek lands on a key frame near the target and
is exact only where the container's timestamps are, so a resumed run decodes (without converting) the
frames before its first and gets every frame bit for bit as an uninterrupted run does.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Generator, Iterator, TypeVar

import numpy as np

from ..errors import InputError
from ..outputs import shell_word
from .video_shown import Turn, as_shown, display_turn, first_interlaced, shown_frames, shown_note, video_duration

if TYPE_CHECKING:
    from .folder_view import FolderView

__all__ = ["Selection", "SourceFrame", "FolderFrames", "VideoFrames", "open_frames", "read_ahead", "VIDEO_SUFFIXES",
           "OTHER_VIDEO_SUFFIXES", "convert_hint"]

#: The video files pcreg reads (by suffix, any case); what the file holds is checked by FFmpeg's demuxer.
VIDEO_SUFFIXES: tuple[str, ...] = (".mp4", ".m4v", ".mov", ".3gp", ".avi", ".mkv", ".webm", ".ts", ".mts", ".m2ts")
#: Image files pcreg does not read as frames (OpenCV's reader takes none of them, or not as a frame).
OTHER_IMAGE_SUFFIXES: tuple[str, ...] = (".gif", ".heic", ".heif", ".avif", ".jxl", ".jp2", ".j2k", ".psd", ".dng",
                                         ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".exr", ".hdr",
                                         ".ico", ".svg")
#: Video files pcreg does not read (their demuxers untested here): refused with the command that converts them.
OTHER_VIDEO_SUFFIXES: tuple[str, ...] = (".mpg", ".mpeg", ".vob", ".m2v", ".flv", ".f4v", ".wmv", ".asf", ".ogv",
                                         ".dv", ".mxf", ".rm", ".rmvb", ".3g2", ".divx", ".y4m")
# FFmpeg's demuxers for those containers, by the name PyAV reports (MPEG-TS also for a camcorder's AVCHD .mts/.m2ts).
_CONTAINERS = {"mov,mp4,m4a,3gp,3g2,mj2": "MP4/QuickTime", "avi": "AVI", "matroska,webm": "Matroska",
               "mpegts": "MPEG-TS"}


@dataclass(frozen=True)
class Selection:
    """Which frames of a source a stream reads: indices ``start``, ``start + every``, ... below ``stop``
    (None: to the end). Indices count from 0 in name order (a folder) or decoding order (a video)."""

    start: int = 0
    stop: int | None = None
    every: int = 1

    def __post_init__(self) -> None:
        for name, v in (("start", self.start), ("every", self.every), ("stop", self.stop)):
            if v is not None and (not isinstance(v, (int, np.integer)) or isinstance(v, bool)):
                raise InputError(f"--{name} must be an integer, got {v!r}")
        if self.start < 0:
            raise InputError(f"--start must be 0 or more, got {self.start}")
        if self.every < 1:
            raise InputError(f"--every must be 1 or more, got {self.every}")
        if self.stop is not None and self.stop <= self.start:
            raise InputError(f"--stop {self.stop} must be greater than --start {self.start}")

    def index(self, position: int) -> int:
        """The source index of the stream's ``position``-th frame."""
        return self.start + position * self.every

    def chosen(self, index: int) -> bool:
        """Whether the source's frame ``index`` is one of the stream's."""
        return (index >= self.start and (self.stop is None or index < self.stop)
                and (index - self.start) % self.every == 0)

    def to_dict(self) -> dict | None:
        """The selection as a run's identity names it: None for every frame (a run from before the options resumes as it was)."""
        return None if self == Selection() else {"start": self.start, "stop": self.stop, "every": self.every}


@dataclass(frozen=True, eq=False)
class SourceFrame:
    """One frame of a stream: its ``position`` (0 is the key frame), its ``index`` in the source, its
    ``name`` (a folder's file name; ``{index:06d}`` in a video), the ``stem`` its outputs are named
    after, and the ``image`` (H, W, 3) uint8 RGB. ``gaps``: a video's places where frames are missing by its
    times (:class:`~pcreg.datasets.damage.Gap`), after the stream's frame before this one and up to this one,
    told with the frame to whoever reads it (the frames are still numbered by count). ``notes``: what reading met
    at this frame, as ``(kind, line)`` pairs, for the reader to say once a run for each kind (a frame with
    transparent pixels, :mod:`~pcreg.datasets.frame_notes`; a video's frames turning interlaced after the first).
    ``damaged``: the decoder flags the frame as decoded with errors, its missing part concealed (:mod:`pcreg.runs.gaps`)."""

    position: int
    index: int
    name: str
    stem: str
    image: np.ndarray
    gaps: tuple = ()
    notes: tuple[tuple[str, str], ...] = ()
    damaged: bool = False  # a video's frame that decodes with errors, the decoder's concealment filling it in


def _out_of_count(a: str, b: str) -> bool:
    """Whether name order puts ``a`` before ``b`` where counting does not: where the two names first differ, both
    hold a run of ASCII digits, of different widths, and ``a``'s number is the larger (``f10`` before ``f8``).
    A run after ``<digits>.`` is a decimal fraction (a time stamp ``1612345678.15``), compared as name order does."""
    pa, pb = _DIGITS.split(a), _DIGITS.split(b)  # text, digits, text, digits, ...
    for i, (x, y) in enumerate(zip(pa, pb)):
        if x == y:
            continue
        fraction = i >= 3 and pa[i - 1].endswith(".")  # the text before is the same: "." after a digit run
        return i % 2 == 1 and not fraction and len(x) != len(y) and int(x) > int(y)
    return False


#: A run of ASCII digits (``str.isdigit`` takes ``²`` and other digits ``int`` does not read).
_DIGITS = re.compile(r"([0-9]+)")


def _check_numbering(folder: Path, names: list[str]) -> None:
    """An :class:`InputError` when name order (pcreg's, and an annotation tool's) is not counting order, because
    numbered names have numbers of different widths (``f10.png`` sorts before ``f8.png``): the frames would be
    labelled out of order, and key labels drawn on one frame carried from another."""
    for a, b in zip(names, names[1:]):
        if _out_of_count(a, b):
            raise InputError(f"{folder}: frames numbered with different widths ({a} sorts before {b} by name, "
                             "the order frames are read in); rename them with zero-padded numbers (f08.png, f10.png)")


class FolderFrames:
    """The image files of a folder (or of its ``images/`` sub-folder) in name order, each read when the stream reaches it."""

    kind = "folder"

    def __init__(self, folder: str | Path, selection: Selection = Selection()) -> None:
        from ..formats import IMAGE_SUFFIXES, only_files

        self.path, self.selection = Path(folder), selection
        if not self.path.is_dir():
            raise InputError(f"{self.path}: not a folder or a video file ({', '.join(VIDEO_SUFFIXES)})")
        src = self.path / "images" if (self.path / "images").is_dir() else self.path
        shown = sorted(p for p in src.iterdir() if not p.name.startswith("."))  # hidden: a thumbnail, macOS's ._NAME
        files = only_files([p for p in shown if p.suffix.lower() in IMAGE_SUFFIXES], "a frame")
        #: Images among the frames in a format pcreg does not read (a GIF, a phone's HEIC): not frames, said in a note.
        self.unread = [p.name for p in shown if p.suffix.lower() in OTHER_IMAGE_SUFFIXES]
        self.source = src
        _check_numbering(src, [p.name for p in files])
        names = [p.stem for p in files]
        if len(set(names)) != len(names):  # X.png beside X.jpg: which one is frame X (its labels OUT/X.png)?
            stem = next(a for a, b in zip(sorted(names), sorted(names)[1:]) if a == b)
            first, *others = [p for p in files if p.stem == stem]
            raise InputError(f"{first}: another frame of this name beside it, {', '.join(p.name for p in others)}; keep one")
        if files and selection.start >= len(files):
            raise InputError(f"--start {selection.start} is past the end of {src} ({len(files)} frames)")
        self.paths = files[selection.start:selection.stop:selection.every]
        #: Every frame file of the folder, those --start/--every/--stop leave out too (a key label may name one).
        self.files = files
        self._view: FolderView | None = None  # the key frame's orientation and size, read with the first frame read (:meth:`read`)
        if len(self.paths) < 2:
            raise InputError(f"{src}: needs at least two frames (the key frame and one more), found {len(self.paths)}"
                             + ("" if selection == Selection() else " of those chosen")
                             + ("" if files else f" (frames are image files: {', '.join(IMAGE_SUFFIXES)})"))

    def __len__(self) -> int:
        return len(self.paths)

    def name(self, position: int) -> str:
        return self.paths[position].name

    def stem(self, position: int) -> str:
        return self.paths[position].stem

    def note(self) -> str | None:
        """A line for the user before the first frame, when the folder holds images pcreg does not read: the run
        passes over them, one frame fewer each."""
        if not self.unread:
            return None
        from ..validation import listed

        n = len(self.unread)
        return (f"{self.source}: {n} image{'s' if n > 1 else ''} in a format pcreg does not read, not labelled "
                f"({listed(self.unread)}); "
                f"convert {'them' if n > 1 else 'it'} to PNG to label {'them' if n > 1 else 'it'} with the others")

    def where(self, position: int) -> Path:
        """The file of the frame at ``position``, as a message names it."""
        return self.paths[position]

    def turned_note(self, position: int, labels_shape: tuple, frame_shape: tuple) -> str:
        """What a refusal of labels of ``labels_shape`` for the frame at ``position`` adds when its EXIF
        orientation turns it (:func:`pcreg.formats.turned_note`)."""
        from ..formats import turned_note

        return turned_note(self.where(position), labels_shape, frame_shape)

    def writes(self, stem: str) -> bool:
        """Whether a stream over this source writes an output named ``stem`` (``OUT/STEM.png``)."""
        return stem in {p.stem for p in self.paths}

    def frames(self, first: int = 0) -> Iterator[SourceFrame]:
        """The chosen frames from position ``first`` on, each read as it is asked for (:meth:`read`)."""
        for t in range(first, len(self.paths)):
            p = self.paths[t]
            image, notes = self.read(t)
            yield SourceFrame(t, self.selection.index(t), p.name, p.stem, image, notes=notes)

    def read(self, position: int) -> tuple[np.ndarray, tuple[tuple[str, str], ...]]:
        """The image at ``position`` (H, W, 3) uint8 RGB and what reading it met (:attr:`SourceFrame.notes`: those of
        :func:`~pcreg.datasets.frame_notes.read_frame`, the key frame's EXIF orientation where the labels' size cannot
        tell it); a frame of another orientation or size than the key frame is refused (:class:`~pcreg.datasets.folder_view.FolderView`)."""
        from .folder_view import FolderView
        from .frame_notes import read_frame

        if self._view is None:
            self._view = FolderView(self.paths[0])
        p = self.paths[position]
        image, notes = read_frame(p)
        self._view.check(p, image.shape[:2])
        return image, (self._view.notes() if position == 0 else ()) + notes


class VideoFrames:
    """The frames of a video file, decoded one at a time with PyAV; frame ``i`` (from 0) is named ``{i:06d}``. Opening
    reads the container's header: a file FFmpeg cannot open, that is not an MP4, QuickTime (3GP), AVI, Matroska or
    MPEG-TS file, or that holds no video stream (cover art is none) is refused here; a truncated or damaged file, a
    frame of another size, or a ``start`` past the end is refused where decoding meets it."""

    kind = "video"

    def __init__(self, path: str | Path, selection: Selection = Selection()) -> None:
        from ..formats import check_regular_file
        from ..validation import max_pixels

        self.path, self.selection = check_regular_file(path, what="video"), selection
        with self._open() as container:
            stream = container.streams.video[0]
            w, h = stream.codec_context.width, stream.codec_context.height
            #: The video streams (index, width, height) a player may show, cover art left out: pcreg reads the first.
            self.streams = [(int(v.index), int(v.codec_context.width), int(v.codec_context.height))
                            for v in container.streams.video if not _attached(v) and v.codec_context is not None]
            if w * h > max_pixels():  # the limit images have, checked before a frame is decoded
                raise InputError(f"{self.path}: {w}x{h} px frames exceed the limit of {max_pixels()} pixels "
                                 "(raise --max-pixels or PCREG_MAX_PIXELS)")
            declared = int(stream.frames or 0)
            #: The frame count the container's index declares (MP4, QuickTime, AVI): exact; else None.
            self.declared: int | None = declared if declared > 0 else None
            #: Without one (Matroska, MPEG-TS), the count its duration and frame rate give: an estimate.
            self.estimated: int | None = None
            #: The video stream's duration in seconds (None when it gives none), and its mean frame rate.
            self.duration = video_duration(container, stream)
            self.rate = float(stream.average_rate) if stream.average_rate else None
            #: A transport stream's time stamps may restart (recordings joined with ``cat``, as a camcorder's
            #: files are): its duration is no measure of where its frames end.
            self.timed = container.format.name != "mpegts"
            if self.declared is None and self.duration and self.rate:
                self.estimated = int(round(self.duration * self.rate))
            #: Whether the first frame is flagged interlaced (its two fields taken apart in time): every frame so
            #: flagged is deinterlaced as it is read (:meth:`frames`); this only says so (:meth:`note`).
            self.interlaced = first_interlaced(container, stream)
        if self.declared is not None and selection.start >= self.declared:
            raise InputError(f"--start {selection.start} is past the end of {self.path} ({self.declared} frames)")

    def _open(self):
        import av

        try:
            container = av.open(str(self.path), metadata_errors="ignore")
        except (av.FFmpegError, UnicodeDecodeError) as exc:
            from .damage import missing_index

            if (unfinished := missing_index(self.path)) is not None:
                raise InputError(unfinished) from None
            reason = getattr(exc, "strerror", None) or str(exc)
            raise InputError(f"{self.path}: not a video FFmpeg can read ({reason}): not a video, or truncated or "
                             "damaged") from None
        fmt = container.format.name
        moving = [v for v in container.streams.video if not _attached(v)]  # cover art is no video
        if fmt not in _CONTAINERS:
            container.close()
            if moving and not fmt.endswith("_pipe"):  # an image renamed, a song's cover: no video
                raise InputError(f"{self.path}: a video in a container pcreg does not read (FFmpeg reads it as {fmt}, "
                                 f"not as {', '.join(_CONTAINERS.values())}); {convert_hint(self.path)}")
            raise InputError(f"{self.path}: not a video (FFmpeg reads it as {fmt}, not as {', '.join(_CONTAINERS.values())})")
        if not moving:
            kinds, art = sorted({s.type for s in container.streams if s.type != "video"}), bool(container.streams.video)
            container.close()
            if art:  # a recording's cover
                raise InputError(f"{self.path}: holds no video stream, only a still picture attached to it (cover art"
                                 f"{' of a recording of sound' if kinds == ['audio'] else ''}), not frames")
            held = f"only {' and '.join(kinds)} streams{': a recording of sound alone' if kinds == ['audio'] else ''}, or" if kinds else "no stream at all:"
            raise InputError(f"{self.path}: holds no video stream ({held} an empty or damaged {_CONTAINERS[fmt]} file)")
        if container.streams.video[0].codec_context is None:  # PyAV opens no decoder for a codec FFmpeg does not know
            container.close()
            raise InputError(f"{self.path}: its video stream is in a codec FFmpeg does not know (a damaged header, or "
                             f"a codec PyAV's FFmpeg lacks); if another FFmpeg plays it, {convert_hint(self.path)}")
        return container

    def note(self) -> str | None:
        """A line for the user before the first frame, when the video is interlaced."""
        if not self.interlaced:
            return None
        from .deinterlace import FILTER

        return (f"{self.path} is interlaced (two fields a frame, taken apart in time): its frames are deinterlaced "
                f"with FFmpeg's {FILTER[0]} as they are read")

    def streams_note(self) -> str | None:
        """A line for the user when the file holds more than one video stream (pcreg reads the first); else None."""
        if len(self.streams) < 2:
            return None
        (index, w, h), others = self.streams[0], self.streams[1:]
        listed = ", ".join(f"#{i} {ow}x{oh}" for i, ow, oh in others)
        out = self.path.with_name(f"{self.path.stem}-stream1{self.path.suffix}")
        return (f"{self.path} holds {len(self.streams)} video streams: pcreg reads the first (#{index}, {w}x{h}), not "
                f"{listed}; to label another, extract it first: ffmpeg -i {shell_word(self.path)} -map 0:v:1 "
                f"-c copy {shell_word(out)}")

    def count(self) -> int | None:
        """How many frames the stream chooses, from the container's count (None if it gives none)."""
        n, s = self.declared or self.estimated, self.selection
        if n is None:
            return None
        end = n if s.stop is None else min(n, s.stop)
        return max(0, -(-(end - s.start) // s.every))

    def name(self, position: int) -> str:
        return f"{self.selection.index(position):06d}"

    stem = name

    def where(self, position: int) -> str:
        """The video and the frame at ``position``, as a message names it."""
        return f"{self.path} frame {self.name(position)}"

    def turned_note(self, position: int, labels_shape: tuple, frame_shape: tuple) -> str:
        """What a refusal of labels of ``labels_shape`` (H, W) for frames of ``frame_shape`` adds when the labels
        are the frames turned by a quarter and the video's display matrix turns them so (as a phone's portrait
        video): pcreg reads the frames as players show them, the labels were drawn on them as stored; else the
        note on the video's other streams (:meth:`streams_note`), or ``""``."""
        import av

        streams = self.streams_note()
        other = f" ({streams})" if streams is not None else ""
        if tuple(labels_shape[:2]) != tuple(frame_shape[:2])[::-1] or labels_shape[0] == labels_shape[1]:
            return other
        with self._open() as container:
            try:
                frame = next(container.decode(container.streams.video[0]), None)
                turned = frame is not None and display_turn(frame, self.path)[0]
            except (av.FFmpegError, InputError):
                turned = False
        if not turned:
            return other
        return (f" ({self.path.name}'s display matrix has players show its frames turned by a quarter, "
                f"{frame_shape[1]}x{frame_shape[0]}, and pcreg reads them so: the labels were drawn on the frames as "
                "stored; draw them on the frames as shown, or turn them the same way)")

    def writes(self, stem: str) -> bool:
        """Whether a stream over this video writes an output named ``stem`` (``OUT/{i:06d}.png``; within the container's count where it gives one)."""
        n, chosen = self.count(), len(stem) >= 6 and stem.isdigit() and stem.isascii() and self.selection.chosen(int(stem))
        return chosen and (n is None or (int(stem) - self.selection.start) // self.selection.every < n)

    def frames(self, first: int = 0, *, passing: Callable[[int], None] | None = None) -> Iterator[SourceFrame]:
        """The chosen frames from position ``first`` on, decoded in order: every frame before is decoded too (never converted;
        ``passing(i)`` told of each), so frame ``i`` is the same however the stream got there. From the first frame flagged
        interlaced on, the frames beside a chosen one pass through a :class:`~pcreg.datasets.deinterlace.Deinterlacer` (a
        frame not so flagged comes out as it went in), and a chosen frame is handed on once the frame after it is decoded.
        Frames missing by the times (a Matroska file's) are handed on with the chosen frame after them, in its ``gaps``."""
        from av.video.reformatter import VideoReformatter

        from .deinterlace import Deinterlacer
        from .frame_notes import has_alpha, transparent_notes, turn_note, video_dark_notes

        s, reading = self.selection, _Reading()
        target = s.index(first)
        # One converter to RGB for the stream: ``frame.to_ndarray(format=...)`` makes a new one (an FFmpeg scaler context) for every
        # frame, which costs more than decoding the frame, and a long run's memory grew with them (10 kB a frame at 160x120).
        rgb, rgba, grey16 = VideoReformatter(), VideoReformatter(), VideoReformatter()  # rgba: the alpha of a format with one; grey16: 16-bit values as stored
        fields: Deinterlacer | None = None
        previous, stopped = None, False

        def wanted(i: int) -> bool:
            return i >= target and s.chosen(i)

        before = target - s.every if first > 0 else -1  # the gaps up to the frame before were the earlier frames'

        def made(i: int, frame, turn: Turn) -> SourceFrame:
            nonlocal before
            reading.yielded = True
            name = f"{i:06d}"
            image = as_shown(rgb.reformat(frame, format="rgb24").to_ndarray(), turn)
            notes, reading.notes = tuple(reading.notes), []
            alpha = rgba.reformat(frame, format="rgba").to_ndarray()[:, :, 3] if has_alpha(frame) else None
            gaps = tuple(g for g in reading.gaps if before < g.index <= i)
            reading.gaps, before = [g for g in reading.gaps if g.index > i], i
            dark = video_dark_notes(f"{self.path} frame {name}", frame, grey16)
            return SourceFrame((i - s.start) // s.every, i, name, name, image, gaps,
                               notes + transparent_notes(f"{self.path} frame {name}", alpha) + dark, i in reading.damaged)

        for i, frame, turn in self._decoded(reading):
            if passing is not None and i < target:
                passing(i)
            stopped = s.stop is not None and i >= s.stop  # the frame after the last: only the next of the one before
            if fields is None and frame.interlaced_frame and not stopped:
                fields = Deinterlacer()
                if i > 0:  # the turn, told with the next frame handed on (the first flagged: :meth:`note` says it)
                    reading.notes.append(turn_note(self.path, i))
                if previous is not None and wanted(i):  # the frame before it, as this frame's neighbour
                    fields.push(previous, None)
            if fields is None:
                if wanted(i):
                    yield made(i, frame, turn)
            elif (wanted(i - 1) or wanted(i) or wanted(i + 1)) and not (stopped and frame.is_corrupt):
                yield from [made(j, f, t) for (j, t), f in fields.push(frame, (i, turn) if wanted(i) else None)]
            previous = frame
        if fields is not None:  # the last frame pushed, its next field taken from itself
            yield from [made(j, f, t) for (j, t), f in fields.flush()]
        if stopped:
            return
        if reading.decoded == 0:
            raise InputError(f"{self.path}: no frame decodes (an empty, truncated or damaged video)")
        self._check_length(reading.decoded, reading.last_time, reading.hidden[0] + reading.start.lost)
        if first == 0 and not reading.yielded:
            raise InputError(f"--start {s.start} is past the end of {self.path} ({reading.decoded} frames)")

    def _decoded(self, reading: _Reading) -> Iterator[tuple[int, Any, Turn]]:
        """Every frame of the video in decoding order, as (index, ``av.VideoFrame``, how it is shown), up to the
        first past the selection's ``stop``; ``reading`` counts them and keeps the gaps in their times and the frames
        that decode with errors (flagged by the decoder, concealed). A frame of another size is refused where met."""
        import av

        from .damage import Start, Timing
        from .vp9_check import Vp9Check

        s, size = self.selection, None
        with self._open() as container:
            stream = container.streams.video[0]
            if stream.codec_context.name == "h264":  # on one thread, so that it flags every concealed frame
                stream.codec_context.thread_count = 1  # (slice threads flag none; frame threads lose some: usage.md)
            timing = Timing(checked=container.format.name == "matroska,webm")
            check = Vp9Check(stream)  # FFmpeg's VP9 decoder flags no damaged frame: libvpx tells them
            start = reading.start = Start()

            def through(packets):
                return start.packets(check.packets(packets))

            try:
                for frame in shown_frames(container, stream, reading.hidden, self.path, through):
                    i, turn = reading.decoded, display_turn(frame, self.path)
                    shown = (frame.height, frame.width) if turn[0] else (frame.width, frame.height)
                    if i == 0:  # a start passed over, a turn the frames' size cannot tell
                        reading.notes += filter(None, (start.first(frame, self.path), shown_note(turn, self.path, shown)))
                    reading.decoded += 1
                    reading.last_time = frame.time if frame.time is not None else reading.last_time
                    if size is None:
                        size = shown
                    elif shown != size:
                        raise InputError(f"{self.path}: frame {i} is {shown[0]}x{shown[1]}, the frames before it "
                                         f"{size[0]}x{size[1]}; pcreg needs one frame size")
                    if s.stop is not None and i >= s.stop:
                        yield i, frame, turn
                        return
                    gap = timing.check(i, frame)
                    if gap is not None:
                        reading.gaps.append(gap)
                    if frame.is_corrupt or check.damaged(frame):  # concealed: a frame cut short or damaged, drawn in part
                        reading.damaged.add(i)
                    yield i, frame, turn
            except av.FFmpegError as exc:
                reason = getattr(exc, "strerror", None) or str(exc)
                raise InputError(f"{self.path}: frame {reading.decoded} does not decode ({reason}): the video is "
                                 "truncated or damaged") from None

    def _check_length(self, decoded: int, last_time: float | None, hidden: int = 0) -> None:
        """At the end of the stream: fewer frames than the container declares is a truncated file, the ``hidden``
        ones (before an edit list's start, as a trim without re-encoding leaves them) counted. Without a
        count (Matroska) the last frame's time is held against the duration: a stream that stops more than two
        mean frame intervals and 2% of the duration before it is refused (a count estimated from the duration is
        wrong for a variable frame rate, 8 frames over 5 s at a nominal 30 per second); without times, a
        shortfall against that estimate of more than 2 frames and 2%. A transport stream is not checked so: its
        duration is estimated from its own last packets, and its time stamps restart where two were joined."""
        if self.declared is not None and decoded + hidden < self.declared:
            raise InputError(f"{self.path}: ends after {decoded} of the {self.declared} frames its container declares: "
                             "the video is truncated or damaged")
        if self.estimated is None or self.duration is None or self.rate is None or not self.timed:
            return
        if last_time is not None:
            if last_time < self.duration - max(2.0 / self.rate, 0.02 * self.duration):
                raise InputError(f"{self.path}: ends at {last_time:.2f} s after {decoded} frames, its duration is "
                                 f"{self.duration:.2f} s: the video is truncated or damaged")
            return
        if decoded < self.estimated - max(2, 0.02 * self.estimated):
            raise InputError(f"{self.path}: ends after {decoded} frames, its duration holds about {self.estimated}: "
                             "the video is truncated or damaged")


@dataclass
class _Reading:
    """What reading a video met: frames ``decoded``, the last one's time, the ``hidden`` ones (a one-item list, as
    :func:`~pcreg.datasets.video_shown.shown_frames` counts them), whether a frame was handed on, the gaps in the
    times and the notes (:attr:`SourceFrame.notes`) not handed on yet, and the frames that decode with errors."""

    decoded: int = 0
    last_time: float | None = None
    hidden: list[int] = field(default_factory=lambda: [0])
    yielded: bool = False
    gaps: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    damaged: set[int] = field(default_factory=set)
    start: Any = None  # the frames at the start that do not decode (:class:`~pcreg.datasets.damage.Start`)


def _attached(stream) -> bool:
    """Whether a video stream is a still picture attached to the file (cover art), not frames."""
    return bool(int(getattr(stream, "disposition", 0) or 0) & 0x400)  # FFmpeg's AV_DISPOSITION_ATTACHED_PIC


def convert_hint(path: Path) -> str:
    """How to convert the video at ``path`` to one pcreg reads: FFmpeg's command, its first video stream to H.264
    in MP4 (at a quality where labels drawn on it stay where they were)."""
    out = path.with_name(path.stem + ("-converted" if path.suffix.lower() == ".mp4" else "") + ".mp4")
    return f"convert it with: ffmpeg -i {shell_word(path)} -map 0:v:0 -c:v libx264 -crf 18 {shell_word(out)}"


def open_frames(path: str | Path, selection: Selection = Selection()) -> FolderFrames | VideoFrames:
    """The frame source at ``path``: a video file (:data:`VIDEO_SUFFIXES`) or a folder of images; a video in
    another container (:data:`OTHER_VIDEO_SUFFIXES`) is refused with the command that converts it."""
    p = Path(path)
    if p.suffix.lower() in VIDEO_SUFFIXES and not p.is_dir():
        return VideoFrames(p, selection)
    if p.suffix.lower() in OTHER_VIDEO_SUFFIXES and p.is_file():
        raise InputError(f"{p}: pcreg does not read {p.suffix} videos (it reads {', '.join(VIDEO_SUFFIXES)}); "
                         f"{convert_hint(p)}")
    if p.exists() and not p.is_dir():
        raise InputError(f"{p}: not a folder or a video file ({', '.join(VIDEO_SUFFIXES)})")
    return FolderFrames(p, selection)


#: What :func:`read_ahead` hands on: a decoded frame, or anything an iterator yields.
_Item = TypeVar("_Item")


def read_ahead(frames: Iterator[_Item]) -> Generator[_Item, None, None]:
    """``frames`` as they come, the next one read and decoded on a thread of its own while the caller
    works on this one (a 640x480 PNG takes about 14 ms to decode; PyAV and OpenCV release the GIL while
    they decode). An error reading a frame comes out where that frame would have; closing this
    iterator (the caller stops, or is interrupted) stops the thread after the frame it holds."""
    import contextlib
    import queue
    import threading

    box: queue.Queue = queue.Queue(maxsize=1)
    stop = threading.Event()

    def work() -> None:
        try:
            for frame in frames:
                box.put(("frame", frame))
                if stop.is_set():
                    return
            box.put(("end", None))
        except BaseException as exc:  # handed to the caller, who raises it in its own thread
            box.put(("error", exc))
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()

    reader = threading.Thread(target=work, name="pcreg-read-ahead", daemon=True)
    reader.start()
    try:
        while True:
            kind, item = box.get()
            if kind == "frame":
                yield item
            elif kind == "error":
                raise item
            else:
                return
    finally:
        stop.set()
        with contextlib.suppress(queue.Empty):  # a slot for the frame the reader may be putting, so that it sees the stop
            box.get_nowait()
        reader.join()
