"""Rerun recordings (.rrd) of every stage; the only module of pcreg that logs to rerun (writes).

The others that import rerun: :mod:`pcreg.recording.blueprint` builds layouts (``rerun.blueprint``);
:mod:`pcreg.recording.readback` and :mod:`pcreg.recording.viewer` read recordings (``rerun.chunk.RrdReader``)
and drive the viewer; :mod:`pcreg.recording.staging` copies recordings (their chunks, unchanged, or
moved under a label) into the file a viewer opens.

A :class:`Recorder` writes to its file as it goes, so a run that is interrupted leaves a recording
that reads back up to where it stopped. Entity paths and timelines are named in
:mod:`pcreg.recording.entities`. The recording holds its kind (which command made it) as a property, and
when it closes, the blueprint of that kind built from what was logged (:mod:`pcreg.recording.blueprint`),
so that every view it opens with has data.

Usage::

    with Recorder("out/run.rrd", force=True) as rec:
        rec.log_config({"backend": "reference"})
        for i, (reference, moving) in enumerate(pairs):
            rec.set_frame(i)
            result = register(reference, moving, callback=rec.icp_callback("reference"))
            rec.log_images(reference=reference, moving=moving)
            rec.log_transform(result.matrix)

Cost: what is logged is built, encoded (images as JPEG, quality 60 by default) and logged on the
recorder's own thread; the calling thread only checks and copies it. Clouds and label maps are
subsampled for display. 100 recorded 640x480 pairs of ``pcreg evaluate sequence`` take about 11 MB
(CamVid) to 18 MB (synthetic noise textures), and recording adds 7-9% to their time on a 2-CPU machine
(``tools/bench_recording.py`` measures both; the benchmarks page breaks the size down). The file is
written by rerun's own thread as data arrives (within about a second, :data:`BATCH_SECONDS`);
:meth:`Recorder.flush` forces it.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
import json
import math
import os
import threading
import time
import traceback
import uuid
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Literal, Mapping

import cv2
import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..outputs import check_output, to_json
from ..errors import InputError, OutputError
from ..registration.result import IcpIteration

__all__ = ["Recorder", "DEFAULT_JPEG_QUALITY"]

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

_LEVELS = {"TRACE", "DEBUG", "INFO", "WARN", "ERROR", "CRITICAL"}


def _as_image(image: Any, name: str) -> np.ndarray:
    a = np.asarray(image)
    if a.dtype != np.uint8 or not (a.ndim == 3 and a.shape[2] == 3 or a.ndim == 2) or a.size == 0:
        raise InputError(f"{name} must be an (H, W, 3) RGB or (H, W) uint8 image, got {a.dtype} {a.shape}")
    return a


def _as_points(points: Any, name: str) -> np.ndarray:
    a = np.asarray(points, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{name} must be (N, 2) pixel coordinates, got shape {a.shape}")
    return a


def _as_colors(colors: Any, n: int, name: str) -> np.ndarray | None:
    """(N, 3) float in 0..1 or uint8 -> (N, 3) uint8."""
    if colors is None:
        return None
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise InputError(f"{name} must be (N, 3) with N = {n}, got shape {c.shape}")
    if c.dtype == np.uint8:
        return c[:, :3]
    return np.clip(np.rint(c[:, :3].astype(np.float32) * 255.0), 0, 255).astype(np.uint8)


def _display_indices(n: int, limit: int) -> np.ndarray | slice:
    """Evenly spaced indices of at most ``limit`` of ``n`` items (deterministic, order kept)."""
    if n <= limit:
        return slice(None)
    return _spaced(n, limit)


@functools.lru_cache(maxsize=64)
def _spaced(n: int, limit: int) -> np.ndarray:
    """``limit`` evenly spaced indices of ``n``, read-only: an ICP callback asks for the same few twice
    an iteration, and ``np.linspace`` each time cost about a millisecond a recorded pair."""
    idx = np.linspace(0, n - 1, limit).astype(np.intp)
    idx.flags.writeable = False
    return idx


def _apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 2) points by a (3, 3) homogeneous matrix."""
    h = points @ matrix[:2, :2].T + matrix[:2, 2]
    w = points @ matrix[2, :2] + matrix[2, 2]
    return h / w[:, None]


def _plain(obj: Any) -> Any:
    """JSON-ready copy of a report or config: dataclasses and results become dicts."""
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return _plain(obj.to_dict())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _plain(dataclasses.asdict(obj))
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def _numbers(obj: Any, prefix: str = "") -> dict[str, float]:
    """Every int/float leaf of a nested dict, keyed by the path of keys joined with '/'."""
    out: dict[str, float] = {}
    if isinstance(obj, Mapping):
        for k, v in obj.items():
            key = f"{prefix}/{k}" if prefix else str(k)
            out.update(_numbers(v, key))
    elif isinstance(obj, (int, float, np.integer, np.floating)) and not isinstance(obj, (bool, np.bool_)):
        out[prefix] = float(obj)
    return out


@dataclass
class _IcpRows:
    """One backend's ICP iterations, kept until they are sent as columns; each at its (frame, step)."""

    times: list[tuple[int | None, int]] = field(default_factory=list)
    fitness: list[float] = field(default_factory=list)
    rmse: list[float] = field(default_factory=list)
    drawn: list[tuple[int | None, int]] = field(default_factory=list)  # the iterations drawn (2-D)
    moving: list[np.ndarray] = field(default_factory=list)
    strips: list[np.ndarray] = field(default_factory=list)
    targets: list[tuple[tuple[int | None, int], np.ndarray]] = field(default_factory=list)


class Recorder:
    """Writes one rerun recording (.rrd) of a pcreg run; a context manager.

    Parameters
    ----------
    path : str or Path
        The .rrd file, written as the run goes.
    application_id : str
        Rerun application id (groups recordings in the viewer).
    recording_name : str, optional
        Human-readable name shown by the viewer.
    recording_id : str, optional
        Rerun recording id; a fresh UUID4 when omitted.
    raw_images : bool
        Log images (and label maps) losslessly instead of JPEG (and display-subsampled labels).
    force : bool
        Overwrite an existing file.
    kind : str, optional
        Which command records: ``register``, ``crosscheck``, ``sequence``, ``rotation``, ``demo`` or
        ``dense`` (:data:`pcreg.recording.blueprint.KINDS`). Stored in the recording (property
        ``pcreg.kind``) and picks the blueprint; inferred from what was logged when omitted.
    blueprint : bool or str
        Embed, on :meth:`close`, the blueprint of ``kind`` built from the entities logged (a kind name
        here sets ``kind``; ``"default"`` is the same as ``True``)        ; ``False`` lets the viewer choose.
    jpeg_quality : int
        JPEG quality of logged images (1..100).
    max_display_points : int
        At most this many points of each cloud are logged per frame (evenly spaced subsample).
    label_stride : int, optional
        Label maps are logged as ``labels[::s, ::s]`` for display; default 2 (1 with ``raw_images``).

    Raises
    ------
    OutputError
        ``path`` exists and not ``force``, or it cannot be written.
    """

    enabled = True  # as against pcreg.recording.null.NULL_RECORDER

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        application_id: str = "pcreg",
        recording_name: str | None = None,
        recording_id: str | None = None,
        raw_images: bool = False,
        force: bool = False,
        kind: str | None = None,
        blueprint: bool | str = True,
        jpeg_quality: int = DEFAULT_JPEG_QUALITY,
        max_display_points: int = 500,
        label_stride: int | None = None,
    ) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() != ".rrd":
            raise OutputError(f"{self.path}: a recording's name must end in .rrd")
        if self.path.is_dir():
            raise OutputError(f"cannot write {self.path}: it is a folder")
        check_output(self.path, force=force)
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality must be in 1..100, got {jpeg_quality}")
        try:
            str(self.path).encode("utf-8")
        except UnicodeEncodeError:  # rerun takes the path as UTF-8 text
            raise OutputError(f"cannot write {self.path}: a recording's path must be valid UTF-8") from None
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.path, "wb"):  # fail here, with our message, rather than in rerun's sink thread
                pass
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        self.raw_images = bool(raw_images)
        self.jpeg_quality = int(jpeg_quality)
        self.max_display_points = int(max_display_points)
        self.label_stride = int(label_stride if label_stride is not None else (1 if raw_images else 2))
        self.application_id = application_id
        self.recording_id = recording_id or str(uuid.uuid4())
        batching = rr.ChunkBatcherConfig(flush_tick=BATCH_SECONDS, flush_num_bytes=BATCH_BYTES)
        self._rec = rr.RecordingStream(application_id, recording_id=self.recording_id, batcher_config=batching)
        from pcreg.recording.blueprint import KINDS

        if isinstance(blueprint, str) and blueprint != "default":
            if kind is not None and kind != blueprint:
                raise ValueError(f"kind={kind!r} and blueprint={blueprint!r} disagree")
            kind = blueprint
        if kind is not None and kind not in KINDS:
            raise ValueError(f"unknown kind of recording {kind!r} (choose from {', '.join(KINDS)})")
        self.kind = kind
        self._embed_blueprint = bool(blueprint)
        self._entities: dict[str, set[str]] = {}
        self._scalar_counts: dict[str, int] = {}
        self._entities_lock = threading.Lock()
        try:
            self._rec.save(self.path)
        except Exception as exc:  # rerun raises its own types for sink errors
            self.path.unlink(missing_ok=True)  # the empty file made above
            raise OutputError(f"cannot write {self.path}: {exc}") from None
        if recording_name:  # a name from a path that is not UTF-8 (os.fsdecode's escapes) shown escaped
            self._rec.send_recording_name(recording_name.encode("utf-8", "backslashreplace").decode("utf-8"))
        if kind is not None:
            self._rec.send_property(E.PROPERTY, rr.AnyValues(**{E.KIND_FIELD: kind}))
        self._closed = False
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcreg-recorder")
        #: the last images JPEG-encoded and their bytes (a frame's three images and the next one's)
        self._jpegs: deque[tuple[np.ndarray, bytes]] = deque(maxlen=4)
        self._pending: list[Future] = []
        self._frame: int | None = None
        self._icp_step: dict[str, int] = {}
        self._icp_target_key: dict[str, tuple] = {}
        self._moving_display: tuple[np.ndarray, np.ndarray | None] | None = None
        self._matrix: np.ndarray | None = None
        self._moving_shape: tuple[int, int] | None = None
        self._static_once: set[tuple[str, str]] = set()  # (entity, what): series names and styles logged
        self._icp_rows: dict[str, _IcpRows] = {}
        self._icp_since = time.monotonic()  # when the ICP rows kept were last sent
        self._send("/", rr.AnnotationContext(
            [rr.AnnotationInfo(id=k, label=name, color=color) for k, (name, color) in E.CLASSES.items()]
        ), static=True)

    # -- life cycle ---------------------------------------------------------------------------

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        if exc is not None and not self._closed:
            text = "".join(traceback.format_exception_only(exc_type, exc)).strip()
            self.log_failure(text)
        self.close()
        return False

    def close(self) -> None:
        """Flush everything to the file and finish it (idempotent)."""
        if self._closed:
            return
        try:
            self._send_icp_rows(now=True)
        finally:
            self._closed = True
        try:
            self._wait_pending()
        finally:
            self._worker.shutdown(wait=True)
            self._finish_blueprint()
            self._rec.flush()
            self._rec.disconnect()

    def flush(self) -> None:
        """Block until everything logged so far is in the file."""
        self._send_icp_rows(now=True)
        self._wait_pending()
        self._rec.flush()

    def _wait_pending(self) -> None:
        pending, self._pending = self._pending, []
        for f in pending:
            f.result()  # re-raises an encoding error here, on the caller's thread

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        """Refuse to log after :meth:`close`."""
        if self._closed:
            raise OutputError(f"{self.path}: the recording is closed")

    def _log(self, path: str, *archetypes: Any, static: bool = False) -> None:
        self._check_open()
        self._send(path, *archetypes, static=static)

    def _send(self, path: str, *archetypes: Any, static: bool = False) -> None:
        """Log to rerun and note which archetypes each entity has (for the blueprint)."""
        self._rec.log(path, *archetypes, static=static)
        self._note(path, {type(a).__name__ for a in archetypes})

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

    def _finish_blueprint(self) -> None:
        """Store the inferred kind if none was given, and embed the blueprint of what was logged."""
        from pcreg.recording.blueprint import blueprint as make_blueprint, infer_kind, panes

        entities = self.entities()
        kind = self.kind
        if kind is None:
            kind = infer_kind(entities)
            self._rec.send_property(E.PROPERTY, rr.AnyValues(**{E.KIND_FIELD: kind}))
        if self._embed_blueprint and panes(kind, entities):  # nothing logged: the viewer chooses
            self._rec.send_blueprint(make_blueprint(kind, entities), make_active=True, make_default=True)

    # -- time ---------------------------------------------------------------------------------

    def set_frame(self, index: int) -> None:
        """Put what follows on the ``frame`` timeline at ``index``.

        Waits for the previous frame's logging to be done on the recorder's thread (it is by then in
        practice); rerun writes it to the file within about a second (:data:`BATCH_SECONDS`).
        """
        if self._frame is not None:
            self._wait_pending()
        self._send_icp_rows(now=self._frame is None)  # iterations before the first frame have no frame
        self._frame = int(index)
        self._rec.set_time(E.FRAME_TIMELINE, sequence=self._frame)
        # frame-level data sits at the start of the iteration timelines too, so a view on one of them (a
        # registration's or a cross-check's iterations) shows the images, clouds and log with them
        self._rec.set_time(E.ICP_TIMELINE, sequence=0)
        self._rec.set_time(E.CROSSCHECK_TIMELINE, sequence=0)
        self._icp_step.clear()
        self._icp_target_key.clear()
        self._moving_display = None
        self._matrix = None

    # -- text ---------------------------------------------------------------------------------

    def log_config(self, config: Any) -> None:
        """Log the run's configuration (a dict or a dataclass) as text: a TextLog line and the ``config`` document."""
        text = to_json(_plain(config))
        self._log(E.CONFIG, rr.TextDocument(text, media_type=rr.MediaType.TEXT), static=True)
        line = "config: " + json.dumps(_plain(config), default=str)
        self._log_later(E.LOG, lambda: rr.TextLog(line, level="INFO"))

    def log_text(self, text: str, level: str = "INFO") -> None:
        """One line (or more) on the text log; ``level`` is TRACE, DEBUG, INFO, WARN, ERROR or CRITICAL."""
        level = str(level).upper()
        if level == "WARNING":
            level = "WARN"
        if level not in _LEVELS:
            raise ValueError(f"unknown log level {level!r}")
        self._log_later(E.LOG, lambda: rr.TextLog(str(text), level=level))

    def log_failure(self, text: str) -> None:
        """A failure, as an ERROR line on the text log."""
        self._log_later(E.LOG, lambda: rr.TextLog(str(text), level="ERROR"))

    # -- images -------------------------------------------------------------------------------

    def _image(self, a: np.ndarray, **kw: Any) -> Any:
        if self.raw_images:
            return rr.Image(a, color_model="L" if a.ndim == 2 else "RGB", **kw)
        return rr.EncodedImage(contents=self._jpeg(a), media_type="image/jpeg", **kw)

    def _jpeg(self, a: np.ndarray) -> bytes:
        """``a`` JPEG-encoded; the last images' encodings are kept, so an image logged again (a
        sequence's reference is the previous pair's moving image) is not encoded twice. Runs on the
        recorder's thread only."""
        for old, data in self._jpegs:  # a sparse look first: most candidates differ at once
            if old.shape == a.shape and np.array_equal(old.ravel()[::997], a.ravel()[::997]) and np.array_equal(old, a):
                return data
        bgr = a if a.ndim == 2 else cv2.cvtColor(a, cv2.COLOR_RGB2BGR)
        params = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality, cv2.IMWRITE_JPEG_OPTIMIZE, 1]
        ok, buf = cv2.imencode(".jpg", bgr, params)
        if not ok:  # pragma: no cover - OpenCV's JPEG encoder does not fail on uint8 images
            raise OutputError("JPEG encoding failed")
        data = buf.tobytes()
        self._jpegs.append((a, data))
        return data

    def _mask(self, m8: np.ndarray) -> Any:
        if self.raw_images:
            return rr.Image(m8, color_model="L")
        ok, buf = cv2.imencode(".png", m8, [cv2.IMWRITE_PNG_BILEVEL, 1, cv2.IMWRITE_PNG_COMPRESSION, 1])
        return rr.EncodedImage(contents=buf.tobytes(), media_type="image/png")

    def _later(self, log: Callable[[], None]) -> None:
        """Run ``log`` (archetypes built and logged, images encoded) on the recorder's thread, at the
        current frame, in the order asked.

        The calling thread only checks and copies what it is given: building rerun's archetypes costs
        0.05-0.3 ms each in Python, and a recorded sequence pair logs about twenty, which the pipeline's
        thread would otherwise wait for (docs/benchmarks.md#recording). Errors surface on the calling
        thread at the next :meth:`set_frame`, :meth:`flush` or :meth:`close`. Rerun's time cursor is per
        thread, so the job sets the frame on its own thread.
        """
        self._check_open()
        frame = self._frame

        def job() -> None:
            if frame is not None:
                self._rec.set_time(E.FRAME_TIMELINE, sequence=frame)
                self._rec.set_time(E.ICP_TIMELINE, sequence=0)
                self._rec.set_time(E.CROSSCHECK_TIMELINE, sequence=0)
            log()

        self._pending.append(self._worker.submit(job))

    def _log_later(self, path: str, make: Callable[[], Any]) -> None:
        """Build an archetype with ``make`` on the recorder's thread and log it at ``path`` (:meth:`_later`)."""
        self._later(lambda: self._send(path, make()))

    def log_images(
        self,
        *,
        reference: np.ndarray | None = None,
        moving: np.ndarray | None = None,
        warped: np.ndarray | None = None,
        valid_mask: np.ndarray | None = None,
    ) -> None:
        """Log the frame's images.

        reference, moving, warped : (H, W, 3) uint8 RGB (or (H, W) uint8 grey), optional
            JPEG-compressed unless ``raw_images``. ``warped`` is the moving image on the reference's
            pixel grid and is drawn over the reference at half opacity.
        valid_mask : (H, W) bool, optional
            Where ``warped`` has data; logged losslessly (PNG, or raw).
        """
        # validate here, on the caller's thread; copy, since the caller may reuse its buffers
        jobs = []
        if reference is not None:
            a = _as_image(reference, "reference").copy()
            jobs.append((E.REFERENCE_IMAGE, lambda a=a: self._image(a, draw_order=-10.0)))
        if moving is not None:
            m = _as_image(moving, "moving").copy()
            self._moving_shape = (int(m.shape[0]), int(m.shape[1]))
            jobs.append((E.MOVING_IMAGE, lambda m=m: self._image(m, draw_order=-10.0)))
        if warped is not None:
            w = _as_image(warped, "warped").copy()
            jobs.append((E.WARPED_IMAGE, lambda w=w: self._image(w, opacity=0.5, draw_order=-5.0)))
        if valid_mask is not None:
            mask = np.asarray(valid_mask)
            if mask.ndim != 2:
                raise InputError(f"valid_mask must be (H, W), got shape {mask.shape}")
            m8 = np.where(mask.astype(bool), np.uint8(255), np.uint8(0))
            jobs.append((E.VALID_MASK, lambda m8=m8: self._mask(m8)))
        for path, make in jobs:
            self._log_later(path, make)

    # -- clouds -------------------------------------------------------------------------------

    def _points(self, points: np.ndarray, colors: np.ndarray | None, *, radius: float = 1.5) -> Any:
        return rr.Points2D(points, colors=colors, radii=radius)

    def log_clouds(self, *, reference_points: np.ndarray | None = None, reference_colors: np.ndarray | None = None,
                   moving_points: np.ndarray | None = None, moving_colors: np.ndarray | None = None) -> None:
        """Log both clouds as Points2D coloured by their pixels' colour (at most ``max_display_points`` each).

        *_points : (N, 2) float64 pixel coordinates (x right, y down) in their own image.
        *_colors : (N, 3) float32 in 0..1 or uint8, optional.
        The moving cloud is also drawn in the registration view, mapped by the frame's transform.
        """
        if reference_points is not None:
            p = _as_points(reference_points, "reference_points")
            c = _as_colors(reference_colors, len(p), "reference_colors")
            idx = _display_indices(len(p), self.max_display_points)
            shown = (p[idx].copy(), None if c is None else c[idx].copy())  # the caller may reuse its buffers
            self._log_later(E.REFERENCE_CLOUD, lambda: self._points(*shown))
        if moving_points is not None:
            p = _as_points(moving_points, "moving_points")
            c = _as_colors(moving_colors, len(p), "moving_colors")
            idx = _display_indices(len(p), self.max_display_points)
            moving = (p[idx].copy(), None if c is None else c[idx].copy())
            self._log_later(E.MOVING_CLOUD, lambda: self._points(*moving))
            self._moving_display = moving
            if self._matrix is not None:
                self._log_moved_cloud()

    def _log_moved_cloud(self) -> None:
        assert self._moving_display is not None and self._matrix is not None
        (points, colors), matrix = self._moving_display, self._matrix
        if matrix.shape == (3, 3):
            self._log_later(E.MOVED_CLOUD, lambda: self._points(_apply(matrix, points), colors))

    # -- transform ----------------------------------------------------------------------------

    def log_transform(
        self,
        matrix: np.ndarray,
        *,
        name: str = "T_ref_mov",
        moving_shape: tuple[int, int] | None = None,
    ) -> None:
        """Log a transform exactly (Tensor at ``transforms/{name}``) and draw it.

        matrix : (3, 3) float64 homogeneous ``T_ref_mov`` (or (4, 4) for 3-D clouds, logged but not drawn).
        moving_shape : (H, W), optional
            Size of the moving image whose border is drawn mapped into the reference; defaults to the
            last moving image logged.
        """
        m = np.array(matrix, dtype=np.float64)  # a copy: logged on the recorder's thread
        if m.shape not in ((3, 3), (4, 4)) or not np.all(np.isfinite(m)):
            raise InputError(f"matrix must be a finite (3, 3) or (4, 4) array, got shape {m.shape}")
        self._log_later(E.transform_path(name), lambda: rr.Tensor(m, dim_names=["row", "col"]))
        if m.shape != (3, 3):
            return
        if name == "T_ref_mov":
            self._matrix = m
            if self._moving_display is not None:
                self._log_moved_cloud()
        shape = moving_shape or self._moving_shape
        if shape is not None:
            h, w = shape
            corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5], [-0.5, -0.5]])
            self._log_later(E.outline_path(name),
                            lambda: rr.LineStrips2D([_apply(m, corners)], colors=[255, 220, 0], radii=1.0))

    # -- dense fields ---------------------------------------------------------------------------

    def log_dense(
        self,
        field: np.ndarray,
        *,
        matrix: np.ndarray | None = None,
        confidence: np.ndarray | None = None,
        warped_prior: np.ndarray | None = None,
        quiver_step: int = 24,
    ) -> None:
        """Log a dense registration's field under ``dense/``, in the moving image's pixel frame.

        field : (H, W, 2) float reference coordinates of every moving pixel.
        matrix : (3, 3) the global ``T_ref_mov`` the field refines: ``dense/refinement`` shows
            ``|field(p) - T p|``. confidence : (H, W) float in [0, 1]. warped_prior : (H, W) float
            obstacle probability of the reference labels warped into the moving frame.
        Displacements (``|field(p) - p|``) are colour-mapped (TURBO, 0 to their maximum, which is
        logged as ``dense/max_displacement``); ``dense/quiver`` draws ``field(p) - p`` every
        ``quiver_step`` pixels.
        """
        f = np.array(field, dtype=np.float32)  # copies: drawn on the recorder's thread
        if f.ndim != 3 or f.shape[2] != 2 or not np.all(np.isfinite(f)):
            raise InputError(f"field must be a finite (H, W, 2) array, got shape {f.shape}")
        M = None if matrix is None else np.array(matrix, dtype=np.float64)
        if M is not None and (M.shape != (3, 3) or not np.all(np.isfinite(M))):
            raise InputError("matrix must be a finite (3, 3) array")
        maps = {}
        for path, a in ((E.DENSE_CONFIDENCE, confidence), (E.DENSE_WARPED_PRIOR, warped_prior)):
            if a is not None:
                maps[path] = a = np.array(a, dtype=np.float32)
                if a.shape != f.shape[:2]:
                    raise InputError(f"{path.rsplit('/', 1)[-1]} must be (H, W) = {f.shape[:2]}, got {a.shape}")
        self._later(lambda: self._draw_dense(f, M, maps, max(1, int(quiver_step))))

    def _draw_dense(self, f: np.ndarray, M: np.ndarray | None, maps: dict[str, np.ndarray], step: int) -> None:
        """:meth:`log_dense`'s drawing, on the recorder's thread."""
        h, w = f.shape[:2]
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        disp = f - np.dstack([xs, ys])
        mag = np.hypot(disp[..., 0], disp[..., 1])
        top = float(mag.max()) if mag.size else 0.0

        def colour(m: np.ndarray, scale: float) -> np.ndarray:
            u8 = np.clip(255.0 * m / max(scale, 1e-6), 0, 255).astype(np.uint8)
            return cv2.cvtColor(cv2.applyColorMap(u8, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)

        self._send(E.DENSE_DISPLACEMENT, self._image(colour(mag, top)))
        if M is not None:
            den = M[2, 0] * xs + M[2, 1] * ys + M[2, 2]
            gx = (M[0, 0] * xs + M[0, 1] * ys + M[0, 2]) / den
            gy = (M[1, 0] * xs + M[1, 1] * ys + M[1, 2]) / den
            ref = np.hypot(f[..., 0] - gx, f[..., 1] - gy)
            self._send(E.DENSE_REFINEMENT, self._image(colour(ref, float(ref.max()) if ref.size else 0.0)))
        for path, a in maps.items():
            self._send(path, self._image(np.clip(255.0 * np.nan_to_num(a), 0, 255).astype(np.uint8)))
        sy, sx = slice(step // 2, h, step), slice(step // 2, w, step)
        origins = np.column_stack([xs[sy, sx].ravel(), ys[sy, sx].ravel()])
        vectors = disp[sy, sx].reshape(-1, 2)
        self._send(E.DENSE_QUIVER, rr.Arrows2D(origins=origins, vectors=vectors, colors=[255, 220, 0], radii=0.8))
        self._scalar(E.DENSE_MAX_DISPLACEMENT, top)

    # -- labels -------------------------------------------------------------------------------

    def log_labels(
        self,
        *,
        truth: np.ndarray | None = None,
        predicted: np.ndarray | None = None,
        prefix: str = "",
    ) -> None:
        """Log label maps as SegmentationImage (0 ground, 1 obstacle, 2 unknown; the classes are named
        and coloured by the recording's static AnnotationContext).

        truth, predicted : (H, W) integer class ids; logged as ``labels[::s, ::s]`` uint8 with
        ``s = label_stride``. ``prefix`` separates several predictions (``labels/predicted/{prefix}``).
        """
        s = self.label_stride
        for kind, labels in (("truth", truth), ("predicted", predicted)):
            if labels is None:
                continue
            a = np.asarray(labels)
            if a.ndim != 2 or not np.issubdtype(a.dtype, np.integer):
                raise InputError(f"{kind} labels must be (H, W) integers, got {a.dtype} {a.shape}")
            if a.size and (a.min() < 0 or a.max() > 255):
                raise InputError(f"{kind} labels must be class ids in 0..255")
            shown = np.array(a[::s, ::s], dtype=np.uint8, order="C")  # a copy: logged on the recorder's thread
            self._log_later(E.labels_path(kind, prefix), lambda shown=shown: rr.SegmentationImage(shown))

    # -- series -------------------------------------------------------------------------------

    def _once(self, path: str, what: str, make: Callable[[], Any]) -> None:
        """Log ``make()`` statically at ``path`` the first time ``what`` is asked for there (a series' name,
        a style that every row shares)."""
        if (path, what) not in self._static_once:
            self._static_once.add((path, what))
            self._send(path, make(), static=True)

    def _scalar(self, path: str, value: float, name: str | None = None) -> None:
        self._once(path, "series", lambda: rr.SeriesLines(names=name or path.rsplit("/", 1)[-1]))
        self._send(path, rr.Scalars(float(value)))

    def log_errors(self, errors: Mapping[str, float]) -> None:
        """Log error rates in percent (as everywhere in pcreg) per method as Scalars at ``errors/{method}``;
        NaN is skipped."""
        finite = [(str(m), float(v)) for m, v in errors.items() if math.isfinite(float(v))]

        def log() -> None:
            for method, value in finite:
                self._scalar(E.error_path(method), value, method)

        self._later(log)

    # -- ICP ----------------------------------------------------------------------------------

    def icp_callback(
        self, backend: str, *, max_points: int = 300, max_correspondences: int = 200
    ) -> Callable[[IcpIteration], None]:
        """A per-iteration callback for either ICP; logs under ``icp/{backend}/`` on the ``icp_iteration``
        timeline (a counter that restarts at every :meth:`set_frame` and runs on over pyramid levels).

        Per iteration: the moving (source) cloud as it moves (<= ``max_points``), <= ``max_correspondences``
        source -> target pairs as LineStrips2D, fitness and inlier RMSE as Scalars. The target cloud is
        logged once per frame and pyramid level. Only 2-D iterations are drawn; series are logged for any.
        The iterations of a frame are kept and sent as columns (one message per entity) when the next
        frame starts or the recording is flushed: a registration's dozens of iterations cost a few
        messages, not a hundred.
        """
        backend = str(backend)

        def callback(it: IcpIteration) -> None:
            self._check_open()
            rows = self._icp_rows.setdefault(backend, _IcpRows())
            step = self._icp_step.get(backend, 0)
            self._icp_step[backend] = step + 1
            at = (self._frame, step)
            rows.times.append(at)
            rows.fitness.append(float(it.fitness))
            rows.rmse.append(float(it.inlier_rmse))
            src = np.asarray(it.source_points)
            tgt = np.asarray(it.target_points)
            if not (src.ndim == 2 and src.shape[1] == 2 and tgt.ndim == 2 and tgt.shape[1] == 2):
                return
            key = (it.level, len(tgt))
            if self._icp_target_key.get(backend) != key:
                self._icp_target_key[backend] = key
                rows.targets.append((at, tgt[_display_indices(len(tgt), max_points)].copy()))
            rows.drawn.append(at)
            rows.moving.append(src[_display_indices(len(src), max_points)].copy())
            ti = np.asarray(it.target_indices)
            matched = np.flatnonzero(ti >= 0)
            pick = matched[_display_indices(len(matched), max_correspondences)]
            rows.strips.append(np.stack([src[pick], tgt[ti[pick]]], axis=1) if len(pick) else np.zeros((0, 2, 2)))

        return callback

    def _send_icp_rows(self, *, now: bool = False) -> None:
        """Send the ICP iterations kept, one column per entity, on the recorder's thread: when a frame
        starts and they span :data:`BATCH_SECONDS`, or ``now``. Each send is a chunk of its own (rerun does
        not batch columns), so a frame's iterations sent alone made five chunks a frame."""
        if not self._icp_rows or not (now or time.monotonic() - self._icp_since >= BATCH_SECONDS):
            return
        rows_by_backend, self._icp_rows = self._icp_rows, {}
        self._icp_since = time.monotonic()
        self._later(lambda: self._send_icp_columns(rows_by_backend))

    def _send_icp_columns(self, rows_by_backend: dict[str, _IcpRows]) -> None:
        for backend, rows in rows_by_backend.items():
            for what, values, name in (("fitness", rows.fitness, "fitness"), ("inlier_rmse", rows.rmse, "inlier RMSE")):
                path = E.icp_path(backend, what)
                self._once(path, "series", lambda: rr.SeriesLines(names=f"{backend} {name}"))
                self._send_columns(path, rows.times, rr.Scalars.columns(scalars=values))
            if rows.targets:
                times, clouds = zip(*rows.targets)
                self._send_points(E.icp_path(backend, "target"), list(times), list(clouds), [80, 160, 255])
            if rows.drawn:
                self._send_points(E.icp_path(backend, "moving"), rows.drawn, rows.moving, [255, 120, 0])
                # one (N, 2, 2) array of segments: rerun's numpy path (a list of N strips is converted
                # strip by strip, most of the recorder's own time on an ICP-heavy recording)
                strips = np.concatenate(rows.strips) if rows.strips else np.zeros((0, 2, 2))
                column = rr.LineStrips2D.columns(strips=strips)
                path = E.icp_path(backend, "correspondences")
                self._once(path, "style", lambda: rr.LineStrips2D.from_fields(colors=[255, 255, 255], radii=0.5))
                self._send_columns(path, rows.drawn, column.partition([len(r) for r in rows.strips]),
                                   archetype="LineStrips2D")

    def _send_points(self, path: str, times: list[tuple[int | None, int]], clouds: list[np.ndarray],
                     color: list[int]) -> None:
        column = rr.Points2D.columns(positions=np.concatenate(clouds)).partition([len(c) for c in clouds])
        self._once(path, "style", lambda: rr.Points2D.from_fields(colors=color, radii=1.5))
        self._send_columns(path, times, column, archetype="Points2D")

    def _send_columns(self, path: str, times: list[tuple[int | None, int]], columns: Any, *,
                      archetype: str = "Scalars") -> None:
        """``columns`` at their (frame, step): ``step`` on the ICP timeline, in ``frame`` (at the start of
        the cross-check timeline, as everything of the frame). Rows before the first frame are sent
        alone (:meth:`set_frame`) and have no frame."""
        frames, steps = zip(*times)
        indexes = [rr.TimeColumn(E.ICP_TIMELINE, sequence=list(steps))]
        if frames[0] is not None:
            indexes += [rr.TimeColumn(E.FRAME_TIMELINE, sequence=list(frames)),
                        rr.TimeColumn(E.CROSSCHECK_TIMELINE, sequence=[0] * len(steps))]
        self._rec.send_columns(path, indexes=indexes, columns=columns)
        self._note(path, {archetype}, rows=len(steps))

    # -- crosscheck ---------------------------------------------------------------------------

    def log_crosscheck(self, report: Mapping[str, Any]) -> None:
        """Log a crosscheck report: the whole report as JSON text (``crosscheck/report``), a one-line
        summary on the text log, and every number in it as Scalars (``crosscheck/{key}``, nested keys
        joined by '/'). Results (objects with ``to_dict``) and dataclasses are converted."""
        plain = _plain(report)
        self._log(E.CROSSCHECK_REPORT, rr.TextDocument(to_json(plain), media_type=rr.MediaType.TEXT))
        numbers = _numbers(plain)
        for key, value in numbers.items():
            if math.isfinite(value):
                self._scalar(f"{E.CROSSCHECK}/{key}", value, key)
        summary = ", ".join(f"{k}={v:.6g}" for k, v in numbers.items() if "/" not in k)
        line = f"crosscheck: {summary}" if summary else "crosscheck logged"
        self._log_later(E.LOG, lambda: rr.TextLog(line, level="INFO"))

    def _cloud(self, points: np.ndarray, color: list[int]) -> Any:
        p = np.asarray(points, dtype=np.float64)
        p = p[_display_indices(len(p), self.max_display_points)]
        if p.shape[1] == 2:
            return rr.Points2D(p, colors=color, radii=1.5)
        return rr.Points3D(p, colors=color, radii=0.05)

    def log_crosscheck_target(self, points: np.ndarray) -> None:
        """The target cloud of a cloud cross-check, static at ``crosscheck/target`` (<= max_display_points)."""
        self._log(f"{E.CROSSCHECK}/target", self._cloud(points, [80, 160, 255]), static=True)

    def log_crosscheck_iteration(self, implementation: str, iteration: int, points: np.ndarray, *,
                                 error: float | None = None, fitness: float | None = None,
                                 inlier_rmse: float | None = None) -> None:
        """One implementation's iteration of a cloud cross-check on the ``crosscheck_iteration`` timeline:
        its moved source cloud (``crosscheck/{implementation}/cloud``) and its error, fitness and inlier
        RMSE as Scalars. Every implementation shares the timeline, so their iterations line up."""
        self._rec.set_time(E.CROSSCHECK_TIMELINE, sequence=int(iteration))
        try:
            self._log(E.crosscheck_path(implementation, "cloud"), self._cloud(points, [255, 120, 0]))
            for what, value in (("error", error), ("fitness", fitness), ("inlier_rmse", inlier_rmse)):
                if value is not None and math.isfinite(float(value)):
                    self._scalar(E.crosscheck_path(implementation, what), float(value), f"{implementation} {what}")
        finally:
            if self._frame is None:
                self._rec.disable_timeline(E.CROSSCHECK_TIMELINE)
            else:  # back to where frame-level data sits (see set_frame)
                self._rec.set_time(E.CROSSCHECK_TIMELINE, sequence=0)
