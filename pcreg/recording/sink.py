"""The file a :class:`~pcreg.recording.recorder.Recorder` writes, the thread that writes it, and its images' encoding.

A :class:`Sink` opens the .rrd file (refusing what cannot be written, with pcreg's own message), sends
what the loggers build to rerun, notes the archetypes each entity has (the blueprint embedded when it
closes is built from them), holds the ``frame`` the rows go to (rerun's time cursor), and runs jobs on its
own thread in the order they are asked for (:meth:`Sink.later`). Images are encoded there: JPEG, with the
last few encodings kept (:class:`JpegCache`), bi-level PNG masks, or raw. The loggers
(``pcreg.recording.*_log``) are what decide what is logged where; the sink knows no entity path.
"""

from __future__ import annotations

import os
import threading
import uuid
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..errors import OutputError, StuckOutput
from ..outputs import check_output
from .readback import end_stream, whole_stream

__all__ = ["Sink", "JpegCache", "check_path", "DEFAULT_JPEG_QUALITY", "BATCH_SECONDS", "BATCH_BYTES"]

#: JPEG quality of logged images (with optimised Huffman tables): the highest that kept a 100-frame
#: 640x480 sequence recording of an earlier layout under 15 MB (design notes, docs/algorithms.md).
#: ``raw_images=True`` logs losslessly.
DEFAULT_JPEG_QUALITY = 60

#: How rerun batches rows into chunks before writing them: a chunk holds up to a second of rows (or
#: 16 MiB, which bounds the memory held). rerun's own default, a fifth of a second, and a flush at every
#: frame made chunks of one frame's rows each (a sequence recording of 100 pairs had about 2,800), and
#: every chunk carries its own schema and is compressed on its own: a second's chunks make the same
#: recording 14% (synthetic) to 23% (CamVid) smaller (docs/benchmarks.md). A reader of the file as it grows, and a run killed
#: without closing its recorder, are at most about a second behind; the ICP's iterations, kept until
#: they span a second and sent when the next frame starts, about a second and a frame.
BATCH_SECONDS = 1.0
BATCH_BYTES = 16 << 20
#: Seconds of each wait for rerun's writer when a recording is finished; a file that has not grown over
#: :data:`FLUSH_STALLS` waits in a row while rerun still holds data is a writer that stopped (a full disk,
#: where rerun's flush and its exit otherwise wait without end).
FLUSH_SECONDS = 5.0
FLUSH_STALLS = 3


class JpegCache:
    """JPEG encoding at one quality that keeps the last ``size`` images and their bytes, so that an image
    logged again (a sequence's reference is the previous pair's moving image) is not encoded twice and is
    stored with the same bytes. Used from one thread."""

    def __init__(self, quality: int, size: int = 4) -> None:
        if not 1 <= int(quality) <= 100:
            raise ValueError(f"jpeg_quality must be in 1..100, got {quality}")
        self.quality = int(quality)
        self._kept: deque[tuple[np.ndarray, bytes]] = deque(maxlen=size)  # a frame's three images and the next one's

    def encode(self, a: np.ndarray) -> bytes:
        """``a`` ((H, W, 3) RGB or (H, W) grey uint8) as JPEG bytes."""
        for old, data in self._kept:  # a sparse look first: most candidates differ at once
            if old.shape == a.shape and np.array_equal(old.ravel()[::997], a.ravel()[::997]) and np.array_equal(old, a):
                return data
        bgr = a if a.ndim == 2 else cv2.cvtColor(a, cv2.COLOR_RGB2BGR)
        params = [cv2.IMWRITE_JPEG_QUALITY, self.quality, cv2.IMWRITE_JPEG_OPTIMIZE, 1]
        ok, buf = cv2.imencode(".jpg", bgr, params)
        if not ok:  # pragma: no cover - OpenCV's JPEG encoder does not fail on uint8 images
            raise OutputError("JPEG encoding failed")
        data = buf.tobytes()
        self._kept.append((a, data))
        return data


def check_path(path: str | os.PathLike, force: bool) -> None:
    """Refuse a recording's path that is not a .rrd file's, not UTF-8 text (rerun takes the path as text), a
    folder, or a file that exists (unless ``force``): what :class:`Sink` refuses, for a command that opens its
    recording after other outputs to refuse it before them."""
    path = Path(path)
    if path.suffix.lower() != ".rrd":
        raise OutputError(f"{path}: a recording's name must end in .rrd")
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        raise OutputError(f"cannot write {path}: a recording's path must be valid UTF-8") from None
    if path.is_dir():
        raise OutputError(f"cannot write {path}: it is a folder")
    check_output(path, force=force)


def _create_empty(path: Path) -> list[Path]:
    """Create ``path`` empty, or refuse it with the reason (rerun's own error would come from its thread); the
    folders made for it, deepest first (:func:`remove_made_folders`)."""
    made = [p for p in path.absolute().parents if not p.exists()]
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb"):  # fail here, with our message, rather than in rerun's sink thread
            pass
    except OSError as exc:
        remove_made_folders(made)
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return made


def remove_made_folders(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first) that a recording's path made and that are still empty: a run refused
    before its recording held anything leaves no trace of it."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:  # not empty (something else was written there), or gone: kept as it is
            return


def _save_without_footer(rec: Any, path: Path) -> None:
    """``rec.save(path)`` without rerun's footer: its file sink otherwise keeps a manifest entry of every chunk
    in memory until the file is closed (every index column padded for every chunk: 1-3 kB a chunk, and
    about ten chunks a second of a recorded run), which grew a long ``pcreg run --record`` by 2-16 kB a
    frame, more the slower the run (docs/benchmarks.md). rerun's note that the file will have no manifest is
    kept off the terminal; anything else it prints is passed on."""
    import sys

    from ..quiet import capture_output_fds

    with capture_output_fds() as captured:
        rec.save(path, write_footer=False)
    other = [line for line in "".join(captured).splitlines() if line.strip() and "write_footer" not in line]
    if other:
        sys.stderr.write("\n".join(other) + "\n")


#: How many pending jobs :meth:`Sink.later` keeps before it forgets the ones done.
REAP_AT = 256


class Sink:
    """One rerun recording file being written: see the module.

    Parameters
    ----------
    path : str or Path
        The .rrd file.
    application_id, recording_id, recording_name : str
        Rerun's (a fresh UUID4 recording id when None; no name when None).
    kind : str, optional
        Stored as the recording property ``pcreg.kind``; inferred from what was logged at :meth:`close`
        when None.
    embed_blueprint : bool
        Embed the blueprint of the kind, built from the entities logged, at :meth:`close`.
    raw_images : bool
        :meth:`image` and :meth:`mask` log raw pixels instead of JPEG and PNG.
    jpeg_quality : int
        1..100 (:class:`JpegCache`).
    force : bool
        Overwrite an existing file.

    Raises
    ------
    OutputError
        ``path`` exists and not ``force``, or it cannot be written.
    """

    def __init__(self, path: str | os.PathLike, *, application_id: str = "pcreg", recording_id: str | None = None,
                 recording_name: str | None = None, kind: str | None = None, embed_blueprint: bool = True,
                 raw_images: bool = False, jpeg_quality: int = DEFAULT_JPEG_QUALITY, force: bool = False) -> None:
        self.path = Path(path)
        check_path(self.path, force)
        self._jpegs = JpegCache(jpeg_quality)
        self.made_folders = _create_empty(self.path)
        self.raw_images = bool(raw_images)
        self.application_id = application_id
        self.recording_id = recording_id or str(uuid.uuid4())
        batching = rr.ChunkBatcherConfig(flush_tick=BATCH_SECONDS, flush_num_bytes=BATCH_BYTES)
        self._rec = whole_stream(application_id, recording_id=self.recording_id, batcher_config=batching)
        self.kind = kind
        self._embed_blueprint = embed_blueprint
        self._entities: dict[str, set[str]] = {}
        self._scalar_counts: dict[str, int] = {}
        self._entities_lock = threading.Lock()
        try:
            _save_without_footer(self._rec, self.path)
        except Exception as exc:  # rerun raises its own types for sink errors
            self.path.unlink(missing_ok=True)  # the empty file made above
            remove_made_folders(self.made_folders)
            raise OutputError(f"cannot write {self.path}: {exc}") from None
        if recording_name:  # a name from a path that is not UTF-8 (os.fsdecode's escapes) shown escaped
            self._rec.send_recording_name(recording_name.encode("utf-8", "backslashreplace").decode("utf-8"))
        if kind is not None:
            self._send_kind(kind)
        self._closed = False
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcreg-recorder")
        self._pending: list[Future] = []
        self._frame: int | None = None
        self._static_once: set[tuple[str, str]] = set()  # (entity, what): series names and styles logged

    @property
    def jpeg_quality(self) -> int:
        """The JPEG quality of logged images."""
        return self._jpegs.quality

    # -- life cycle ---------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called (logging is then refused)."""
        return self._closed

    def check_open(self) -> None:
        """Refuse to log after :meth:`close`."""
        if self._closed:
            raise OutputError(f"{self.path}: the recording is closed")

    def wait(self) -> None:
        """Wait for the jobs asked for so far (:meth:`later`); re-raises a job's error here, on the caller's thread."""
        pending, self._pending = self._pending, []
        for f in pending:
            f.result()

    def flush(self) -> None:
        """Block until everything logged so far is in the file (:class:`StuckOutput` when it cannot be)."""
        self.wait()
        self._flush_to_file()

    def close(self) -> None:
        """Finish the jobs, store the kind and the blueprint, and finish the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.wait()
        finally:
            self._worker.shutdown(wait=True)
            self._finish_blueprint()
            self._flush_to_file()
            self._rec.disconnect()
            end_stream(self.path)

    def _flush_to_file(self) -> None:
        """rerun's flush, in waits of :data:`FLUSH_SECONDS`, until the file holds everything; a writer that
        has stopped (an error, or no growth over :data:`FLUSH_STALLS` waits) is a :class:`StuckOutput`, and
        the unfinished file is removed."""
        size, stalls = -1, 0
        while True:
            try:
                self._rec.flush(timeout_sec=FLUSH_SECONDS)
                return
            except RuntimeError as exc:  # rerun's: a wait that ran out, or its writer gone
                now = self.path.stat().st_size if self.path.exists() else -1
                stalls = stalls + 1 if now == size else 0
                size = now
                if "timed out" not in str(exc) or stalls >= FLUSH_STALLS:
                    import shutil

                    free = shutil.disk_usage(self.path.parent).free if self.path.parent.exists() else 0
                    self.path.unlink(missing_ok=True)
                    raise StuckOutput(f"{self.path}: the recording could not be written ({free} bytes free on its "
                                      f"disk; rerun: {str(exc).splitlines()[0]}); it was removed") from None

    def _send_kind(self, kind: str) -> None:
        """The recording property that names the kind of recording."""
        fields: dict[str, Any] = {E.KIND_FIELD: kind}
        self._rec.send_property(E.PROPERTY, rr.AnyValues(**fields))

    def _finish_blueprint(self) -> None:
        """Store the inferred kind if none was given, and embed the blueprint of what was logged."""
        from pcreg.recording.blueprint import blueprint as make_blueprint, infer_kind, panes

        entities = self.entities()
        kind = self.kind
        if kind is None:
            kind = infer_kind(entities)
            self._send_kind(kind)
        if self._embed_blueprint and panes(kind, entities):  # nothing logged: the viewer chooses
            self._rec.send_blueprint(make_blueprint(kind, entities), make_active=True, make_default=True)

    # -- time ---------------------------------------------------------------------------------

    @property
    def frame(self) -> int | None:
        """The frame what is logged now goes to (None before the first :meth:`set_frame`)."""
        return self._frame

    def set_frame(self, index: int) -> None:
        """Put what follows at ``index`` on the ``frame`` timeline, and at 0 on both iteration timelines (so
        that a view on one of them, a registration's or a cross-check's iterations, shows the frame's
        images, clouds and log with them)."""
        self._frame = int(index)
        self._at_frame(self._frame)

    def _at_frame(self, frame: int) -> None:
        self._rec.set_time(E.FRAME_TIMELINE, sequence=frame)
        self._rec.set_time(E.ICP_TIMELINE, sequence=0)
        self._rec.set_time(E.CROSSCHECK_TIMELINE, sequence=0)

    def set_time(self, timeline: str, sequence: int) -> None:
        """Set ``timeline`` on the calling thread's time cursor."""
        self._rec.set_time(timeline, sequence=int(sequence))

    def disable_timeline(self, timeline: str) -> None:
        """Take ``timeline`` off the calling thread's time cursor."""
        self._rec.disable_timeline(timeline)

    # -- sending ------------------------------------------------------------------------------

    def log(self, path: str, *archetypes: Any, static: bool = False) -> None:
        """Log now, on the calling thread (refused after :meth:`close`)."""
        self.check_open()
        self.send(path, *archetypes, static=static)

    def send(self, path: str, *archetypes: Any, static: bool = False) -> None:
        """Log to rerun and note which archetypes each entity has (for the blueprint)."""
        self._rec.log(path, *archetypes, static=static)
        self._note(path, {type(a).__name__ for a in archetypes})

    def send_columns(self, path: str, indexes: list, columns: Any, *, archetype: str, rows: int) -> None:
        """``rows`` rows of ``archetype`` at once (rerun's ``send_columns``)."""
        self._rec.send_columns(path, indexes=indexes, columns=columns)
        self._note(path, {archetype}, rows=rows)

    def once(self, path: str, what: str, make: Callable[[], Any]) -> None:
        """Log ``make()`` statically at ``path`` the first time ``what`` is asked for there (a series' name,
        a style that every row shares)."""
        if (path, what) not in self._static_once:
            self._static_once.add((path, what))
            self.send(path, make(), static=True)

    def scalar(self, path: str, value: float, name: str | None = None) -> None:
        """A value of the series at ``path`` (named ``name``, else by the path's last part)."""
        self.once(path, "series", lambda: rr.SeriesLines(names=name or path.rsplit("/", 1)[-1]))
        self.send(path, rr.Scalars(float(value)))

    def _note(self, path: str, names: set[str], rows: int = 1) -> None:
        """Note the archetypes an entity has (``rows`` values logged at once), for the blueprint."""
        key = "/" + path.strip("/")
        with self._entities_lock:
            if "Scalars" in names:  # two values make a line (pcreg.recording.blueprint.SERIES)
                self._scalar_counts[key] = self._scalar_counts.get(key, 0) + rows
                if self._scalar_counts[key] >= 2:
                    names.add("Scalars+")
            self._entities.setdefault(key, set()).update(names)

    def entities(self) -> dict[str, frozenset[str]]:
        """Entity paths logged so far and the archetypes logged at each."""
        with self._entities_lock:
            return {p: frozenset(a) for p, a in self._entities.items()}

    # -- the sink's thread --------------------------------------------------------------------

    def later(self, log: Callable[[], None]) -> None:
        """Run ``log`` (archetypes built and logged, images encoded) on the sink's thread, at the current
        frame, in the order asked.

        The calling thread only checks and copies what it is given: building rerun's archetypes costs
        0.05-0.3 ms each in Python, and a recorded sequence pair logs about twenty, which the pipeline's
        thread would otherwise wait for (docs/benchmarks.md#recording). Errors surface on the calling
        thread at the next :meth:`wait`, :meth:`flush` or :meth:`close`, or once :data:`REAP_AT` jobs are
        pending, when the jobs done are forgotten (a run of thousands of frames that never waits keeps no
        record of every job it asked for). Rerun's time cursor is per
        thread, so the job sets the frame on its own thread.
        """
        self.check_open()
        frame = self._frame

        def job() -> None:
            if frame is not None:
                self._at_frame(frame)
            log()

        if len(self._pending) >= REAP_AT:
            self._reap()
        self._pending.append(self._worker.submit(job))

    def _reap(self) -> None:
        """Forget the jobs that are done, raising the first one's error here, on the caller's thread."""
        keep: list[Future] = []
        done: list[Future] = []
        for f in self._pending:
            (done if f.done() else keep).append(f)
        self._pending = keep
        for f in done:
            f.result()

    @property
    def pending_jobs(self) -> int:
        """How many jobs asked for (:meth:`later`) are still kept: those not known to be done."""
        return len(self._pending)

    def log_later(self, path: str, make: Callable[[], Any]) -> None:
        """Build an archetype with ``make`` on the sink's thread and log it at ``path`` (:meth:`later`)."""
        self.later(lambda: self.send(path, make()))

    # -- images (on the sink's thread) --------------------------------------------------------

    def image(self, a: np.ndarray, **kw: Any) -> Any:
        """An image archetype of ``a``: JPEG (:class:`JpegCache`), or raw with ``raw_images``."""
        if self.raw_images:
            return rr.Image(a, color_model="L" if a.ndim == 2 else "RGB", **kw)
        return rr.EncodedImage(contents=self._jpegs.encode(a), media_type="image/jpeg", **kw)

    def mask(self, m8: np.ndarray) -> Any:
        """A 0/255 mask, lossless: bi-level PNG, or raw with ``raw_images``."""
        if self.raw_images:
            return rr.Image(m8, color_model="L")
        ok, buf = cv2.imencode(".png", m8, [cv2.IMWRITE_PNG_BILEVEL, 1, cv2.IMWRITE_PNG_COMPRESSION, 1])
        return rr.EncodedImage(contents=buf.tobytes(), media_type="image/png")
