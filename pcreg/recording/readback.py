"""Read a pcreg recording back into arrays (for tests, tools and figures), with ``rerun.chunk.RrdReader``.

Example::

    rec = read_recording("out/run.rrd")
    rec.application_id, rec.recording_id
    T = tensor(rec.latest("transforms/T_ref_mov", frame=0))          # (3, 3) float64, exact
    errors = rec.series("errors/plain")                              # {frame: value}
    labels = segmentation(rec.latest("labels/predicted", frame=3))   # (h, w) uint8
    reference = image(rec.reference(frame=3))                        # the pair's reference image, (h, w, 3)
    moving = image(rec.moving(frame=3))                              # its moving image
"""

from __future__ import annotations

import os
import struct
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Row", "Recording", "read_recording", "read_entities", "read_kind", "BlueprintView", "read_blueprint", "tensor",
           "image", "segmentation", "scalar", "text", "points", "complete_length", "ended", "end_stream", "snapshot", "recordings_in"]

_SKIP_TIMELINES = {"log_time", "log_tick"}

# The framing of an .rrd file (rerun 0.41, "RRF2"): a stream header of 12 bytes (magic, version,
# options), then messages, each a header of two little-endian u64 (kind, payload length) and its
# payload; kind 0 ends the stream. rerun's file sink follows it with a footer (a manifest of every chunk);
# pcreg's recorder writes none (pcreg.recording.sink) and ends the stream with an empty kind-0 message, as
# rerun did before footers, which its readers read by scanning the file.
_RRD_MAGIC = b"RRF2"
_STREAM_HEADER = 12
_MESSAGE_HEADER = struct.Struct("<QQ")
_END = 0
#: Reading a file with no footer (still being written, or written without one): rerun's reader notes it (and
#: scans the file).
_NO_FOOTER = "RRD file has no footer"


@contextmanager
def unfinished_files_allowed():
    """Read recordings that have no footer (still being written, or written without one) without rerun's
    note that such a file has none (its reader then scans the file, which is what is wanted)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_NO_FOOTER)
        yield


def _reader(path: str | os.PathLike) -> Any:
    """``rerun.chunk.RrdReader`` of ``path``, which may have no footer (:func:`unfinished_files_allowed`)."""
    from rerun.chunk import RrdReader

    with unfinished_files_allowed():
        return RrdReader(str(path))


def whole_stream(application_id: str, **options: Any):
    """``rerun.RecordingStream(application_id, **options)``, made whole: a signal's KeyboardInterrupt raised inside
    its constructor left one without its native part, whose finalizer then printed an AttributeError traceback after
    "pcreg: interrupted". A signal while it is made is noted (:func:`pcreg._signals._shielded`), and raised once it is."""
    import rerun as rr

    from .._signals import _shielded, check_interrupted

    with _shielded():
        stream = rr.RecordingStream(application_id, **options)
    check_interrupted()
    return stream


def end_stream(path: str | os.PathLike) -> None:
    """End the recording ``path``, which rerun has finished writing without a footer, with the end-of-stream
    message (an empty one, as rerun wrote before footers): what :func:`ended` tells a finished file by."""
    with open(path, "ab") as fh:
        fh.write(_MESSAGE_HEADER.pack(_END, 0))


def complete_length(path: str | os.PathLike) -> int | None:
    """Bytes of ``path`` that are whole messages: its size when it is finished or ends on a message, less
    when a writer is half-way through one (rerun's writer appends messages as they come). None when it
    does not start as an .rrd file (the reader's own error then says why)."""
    scan = _scan(path)
    return None if scan is None else (scan[1] if scan[2] else scan[0])


def _scan(path: str | os.PathLike) -> tuple[int, int, bool] | None:
    """(bytes of whole messages, size, whether the end-of-stream message was among them) of ``path``; None
    when it does not start as an .rrd file."""
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size  # what is there now; a writer only appends after it
        if fh.read(len(_RRD_MAGIC)) != _RRD_MAGIC or size < _STREAM_HEADER:
            return None
        end = _STREAM_HEADER
        while end + _MESSAGE_HEADER.size <= size:
            fh.seek(end)
            kind, length = _MESSAGE_HEADER.unpack(fh.read(_MESSAGE_HEADER.size))
            if end + _MESSAGE_HEADER.size + length > size:
                break
            end += _MESSAGE_HEADER.size + length
            if kind == _END:
                return end, size, True
        return end, size, False


def ended(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a recording whose writer finished it (its end of stream is there); False for one
    cut short (a writer killed before it closed the file, which may have left it empty) or not a recording."""
    scan = _scan(path)
    return scan is not None and scan[2]


def unfinished_note(path: str | os.PathLike) -> str | None:
    """A one-line note when ``path`` lacks the end of stream a finished recording has (a writer still at
    it, or a file cut short): it is read up to its last whole message. None for a finished file."""
    scan = _scan(path)
    if scan is None or scan[2]:
        return None
    end, size, _ = scan
    cut = f" (the {size - end} bytes of an unfinished one after it left out)" if size > end else ""
    return (f"{path}: the recording does not end (still being written, or cut short): read up to its last "
            f"whole message{cut}")


def snapshot(path: str | os.PathLike, dest: str | os.PathLike) -> Path:
    """Copy ``path`` to ``dest`` as it stands, up to its last whole message (:func:`complete_length`), so
    that a recording still being written reads back up to there; a finished file is copied whole."""
    import shutil

    dest = Path(dest)
    n = complete_length(path)
    with open(path, "rb") as src, open(dest, "wb") as out:
        if n is None:
            shutil.copyfileobj(src, out)
        else:
            remaining = n
            while remaining:
                block = src.read(min(remaining, 1 << 20))
                if not block:
                    break
                out.write(block)
                remaining -= len(block)
    return dest


def recordings_in(path: str | os.PathLike) -> list:
    """``RrdReader(path).recordings()``, also of a file a writer is half-way through a message of: then
    those of its whole messages (read from a :func:`snapshot`). The reader's error otherwise."""
    import tempfile

    from rerun.chunk import RrdReader

    try:
        with unfinished_files_allowed():
            return RrdReader(str(path)).recordings()
    except Exception as exc:  # rerun raises its own types
        if complete_length(path) is None:
            raise
        first = exc
    with tempfile.TemporaryDirectory(prefix="pcreg-rrd-") as tmp:
        try:
            with unfinished_files_allowed():
                return RrdReader(str(snapshot(path, Path(tmp) / "snapshot.rrd"))).recordings()
        except Exception:  # damaged in its whole messages too: the error about the file itself, not the copy
            raise first from None


@dataclass(frozen=True)
class Row:
    """One logged row: its entity, static or not, its times (``frame``, ``icp_iteration``) and components.

    ``components`` maps ``Archetype:field`` (e.g. ``Scalars:scalars``) to the row's pyarrow array.
    """

    entity: str
    static: bool
    times: dict[str, int]
    components: dict[str, Any]

    def __getitem__(self, component: str) -> Any:
        return self.components[component]


@dataclass
class Recording:
    """Everything in the first recording store of an .rrd file, as rows grouped by entity path."""

    path: Path
    application_id: str
    recording_id: str
    blueprints: int
    rows: dict[str, list[Row]] = field(default_factory=dict)

    def entities(self) -> list[str]:
        return sorted(self.rows)

    def get(self, entity: str, component: str | None = None) -> list[Row]:
        """Rows of ``entity`` (leading '/' optional), optionally only those holding ``component``."""
        rows = self.rows.get("/" + entity.lstrip("/"), [])
        if component is not None:
            rows = [r for r in rows if component in r.components]
        return rows

    def latest(self, entity: str, *, frame: int | None = None, component: str | None = None) -> Row:
        """The last temporal row of ``entity`` at ``frame`` (or at any frame when None); static rows otherwise."""
        rows = self.get(entity, component)
        temporal = [r for r in rows if not r.static and (frame is None or r.times.get("frame") == frame)]
        pick = temporal or [r for r in rows if r.static]
        if not pick:
            raise KeyError(f"{entity}: nothing logged" + (f" at frame {frame}" if frame is not None else ""))
        return pick[-1]

    def latest_at(self, entity: str, *, frame: int, component: str | None = None) -> Row:
        """What a viewer shows of ``entity`` at ``frame``: its last row at the latest frame up to ``frame``
        (a ``Clear`` row included), else its last static row."""
        rows = self.get(entity, component)
        temporal = [(r.times["frame"], i) for i, r in enumerate(rows)
                    if not r.static and r.times.get("frame") is not None and r.times["frame"] <= frame]
        if temporal:
            return rows[max(temporal)[1]]
        static = [r for r in rows if r.static]
        if not static:
            raise KeyError(f"{entity}: nothing logged up to frame {frame}")
        return static[-1]

    def reference(self, frame: int) -> Row:
        """The row holding the reference image of the pair at ``frame``, in any layout: logged at that
        frame (every pair's, in recordings made before a reference was logged only when it changed), kept
        from an earlier frame, or, where ``registration/reference`` was cleared, the image slot placed as
        the reference (``images/0``, ``images/1``), or in earlier recordings of raw images the moving
        image of the previous frame (see :mod:`pcreg.recording.pair_log`)."""
        from . import entities as E

        row = self.latest_at(E.REFERENCE_IMAGE, frame=frame)
        if _CLEAR not in row.components:
            return row
        if not self._slotted():
            return self.latest(E.MOVING_IMAGE, frame=frame - 1)
        return self._slot_at(frame, E.SLOT_DEPTH)

    def moving(self, frame: int) -> Row:
        """The row holding the moving image of the pair at ``frame`` (the image a viewer's Moving view
        shows there), in any layout: an image slot at depth 0, or ``moving/image``."""
        from . import entities as E

        if not self._slotted():
            return self.latest_at(E.MOVING_IMAGE, frame=frame)
        return self._slot_at(frame, 0.0)

    def _slotted(self) -> bool:
        from . import entities as E

        return any(self.get(slot) for slot in E.IMAGE_SLOTS)

    def _slot_at(self, frame: int, depth: float) -> Row:
        """The image of the slot placed at ``depth`` at ``frame``."""
        from . import entities as E

        for slot in E.IMAGE_SLOTS:
            if not self.get(slot, _TRANSLATION):
                continue
            at = self.latest_at(slot, frame=frame, component=_TRANSLATION)[_TRANSLATION].to_pylist()[0]
            if at is not None and float(at[2]) == depth:
                return self.latest_at(slot, frame=frame, component=_IMAGE_OF_SLOT[0]) if self.get(
                    slot, _IMAGE_OF_SLOT[0]) else self.latest_at(slot, frame=frame, component=_IMAGE_OF_SLOT[1])
        raise KeyError(f"no image slot at depth {depth:g} at frame {frame}")

    def series(self, entity: str, *, timeline: str = "frame") -> dict[int, float]:
        """``{time: value}`` of a Scalars entity on ``timeline``."""
        return {r.times[timeline]: scalar(r) for r in self.get(entity, "Scalars:scalars")
                if not r.static and timeline in r.times}


#: The component of a ``Clear`` row.
_CLEAR = "Clear:is_recursive"
_TRANSLATION = "Transform3D:translation"
_IMAGE_OF_SLOT = ("EncodedImage:blob", "Image:buffer")

#: The column of a chunk's record batch that holds each row's id.
_ROW_ID = "rerun.controls.RowId"


def read_recording(path: str | os.PathLike) -> Recording:
    """Read every chunk of the first recording in ``path``; raises ``ValueError`` if it is not a recording."""
    reader = _reader(path)
    stores = reader.recordings()
    if not stores:
        raise ValueError(f"{path}: no recording in this file")
    store = stores[0]
    out = Recording(Path(path), store.application_id, store.recording_id, len(reader.blueprints()))
    logged: dict[str, list[tuple[bytes, Row]]] = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if not n.startswith("rerun.")]
        timelines = [n for n in chunk.timeline_names if n not in _SKIP_TIMELINES]
        comps = [n for n in names if n not in chunk.timeline_names]
        row_ids = batch.column(_ROW_ID).to_pylist()
        for i in range(batch.num_rows):
            times = {}
            for t in timelines:
                v = batch.column(t)[i]
                if v.is_valid:
                    times[t] = int(v.value) if hasattr(v, "value") else int(v.as_py())
            values = {c: batch.column(c)[i].values for c in comps if batch.column(c)[i].is_valid}
            row = Row(chunk.entity_path, chunk.is_static, times, values)
            logged.setdefault(chunk.entity_path, []).append((row_ids[i], row))
    # in the order they were logged: rerun batches rows into chunks by their timelines, so the chunks of one
    # entity need not come in that order; a row id is a big-endian (time, counter), which sorts as it was made
    out.rows = {entity: [row for _, row in sorted(rows, key=lambda r: r[0])] for entity, rows in logged.items()}
    return out


def read_entities(path: str | os.PathLike, *, timeline: str | None = None) -> dict[str, frozenset[str]]:
    """``{entity path: archetype names with data there}`` of the first recording in ``path``, read from the
    chunks' columns only (fast: no row is converted). rerun's ``/__properties`` are left out; an entity
    with Scalars at two times or more also has ``"Scalars+"``.

    With ``timeline``, only what a viewer shows on that timeline: static data and rows that have a time
    on it."""
    reader = _reader(path)
    stores = reader.recordings()
    if not stores:
        raise ValueError(f"{path}: no recording in this file")
    out: dict[str, set[str]] = {}
    scalars: dict[str, int] = {}
    for chunk in reader.stream(store=stores[0]):
        if chunk.entity_path.startswith("/__"):
            continue
        batch = chunk.to_record_batch()
        names = set(chunk.timeline_names)
        rows = None
        if timeline is not None and not chunk.is_static:
            if timeline not in names:
                continue
            rows = batch.column(timeline).is_valid()
        arch = set()
        for n in batch.schema.names:
            if ":" not in n or n.startswith("rerun.") or n in names:
                continue
            col = batch.column(n)
            valid = col.is_valid()
            if rows is not None:
                import pyarrow.compute as pc

                valid = pc.and_(valid, rows)
            count = valid.true_count if hasattr(valid, "true_count") else sum(bool(v) for v in valid.to_pylist())
            if count:
                arch.add(n.split(":", 1)[0])
            if n == "Scalars:scalars":
                scalars[chunk.entity_path] = scalars.get(chunk.entity_path, 0) + count
        out.setdefault(chunk.entity_path, set()).update(arch)
    for path, n in scalars.items():
        if n >= 2:  # a line, not a lone dot (see pcreg.recording.blueprint.SERIES)
            out[path].add("Scalars+")
    return {p: frozenset(a) for p, a in out.items()}


@dataclass(frozen=True)
class BlueprintView:
    """One view of a blueprint stored in a recording file: its class (``2D``, ``TimeSeries``,
    ``TextLog``, ``TextDocument``, ...), name, origin and content queries (``+ /path/**``), and the
    visible time ranges of single entities: ``(entity, timeline, start, end)``, the bounds as stored (a
    time relative to the cursor or absolute, or None for unbounded)."""

    view_class: str
    name: str
    origin: str
    query: tuple[str, ...]
    time_ranges: tuple[tuple[str, str, Any, Any], ...] = ()


def read_blueprint(path: str | os.PathLike) -> tuple[list[BlueprintView], str | None]:
    """The views of the last blueprint stored in ``path`` and the timeline its time panel opens on."""
    reader = _reader(path)
    stores = reader.blueprints()
    if not stores:
        return [], None
    fields: dict[str, dict[str, Any]] = {}
    timeline = None
    for chunk in reader.stream(store=stores[-1]):
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if ":" not in name or name.startswith("rerun."):
                continue
            values = [v for v in batch.column(name).to_pylist() if v is not None]
            if not values:
                continue
            if name == "TimePanelBlueprint:timeline":
                timeline = str(values[-1][0] if isinstance(values[-1], list) else values[-1])
            fields.setdefault(chunk.entity_path, {})[name] = values[-1]
    views = []
    for entity, f in fields.items():
        if "ViewBlueprint:class_identifier" not in f:
            continue

        def one(key: str, f=f) -> str:
            v = f.get(key)
            return str(v[0] if isinstance(v, list) else v) if v is not None else ""

        query = fields.get(entity + "/ViewContents", {}).get("ViewContents:query") or []
        overrides = entity + "/ViewContents/overrides/"
        ranges = tuple(("/" + path[len(overrides):].removesuffix("/visualizers"), r["timeline"], r["range"]["start"],
                        r["range"]["end"])
                       for path, f2 in fields.items() if path.startswith(overrides)
                       for r in f2.get("VisibleTimeRanges:ranges") or [])
        views.append(BlueprintView(one("ViewBlueprint:class_identifier"), one("ViewBlueprint:display_name"),
                                   one("ViewBlueprint:space_origin"), tuple(str(q) for q in query), ranges))
    return views, timeline


def read_kind(path: str | os.PathLike) -> str | None:
    """The kind of recording stored by the recorder (property ``pcreg.kind``), or None."""
    from . import entities as E

    reader = _reader(path)
    stores = reader.recordings()
    if not stores:
        raise ValueError(f"{path}: no recording in this file")
    kind = None
    for chunk in reader.stream(store=stores[0]).filter(content=f"/__properties/{E.PROPERTY}"):
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name == E.KIND_FIELD or name.endswith(":" + E.KIND_FIELD):
                values = [v for v in batch.column(name).to_pylist() if v is not None]
                if values:
                    v = values[-1]
                    kind = str(v[0] if isinstance(v, list) else v)
    return kind


def scalar(row: Row) -> float:
    return float(row["Scalars:scalars"].to_pylist()[0])


def text(row: Row) -> str:
    for key in ("TextLog:text", "TextDocument:text"):
        if key in row.components:
            return str(row[key].to_pylist()[0])
    raise KeyError(f"{row.entity}: no text")


def tensor(row: Row) -> np.ndarray:
    """A Tensor row as an array of its logged dtype and shape (exact)."""
    data = row["Tensor:data"].to_pylist()[0]
    return np.asarray(data["buffer"]).reshape([int(s) for s in data["shape"]])


def points(row: Row) -> np.ndarray:
    """(N, 2) float32 positions of a Points2D row."""
    return np.asarray(row["Points2D:positions"].to_pylist(), dtype=np.float32).reshape(-1, 2)


def segmentation(row: Row) -> np.ndarray:
    """A SegmentationImage row as (H, W) uint8 class ids."""
    fmt = row["SegmentationImage:format"].to_pylist()[0]
    buf = row["SegmentationImage:buffer"][0].values.to_numpy(zero_copy_only=False)
    return np.asarray(buf, dtype=np.uint8).reshape(fmt["height"], fmt["width"])


def image(row: Row) -> np.ndarray:
    """An Image or EncodedImage row as (H, W, 3) RGB or (H, W) grey uint8 (JPEG/PNG decoded)."""
    import cv2

    if "EncodedImage:blob" in row.components:
        blob = row["EncodedImage:blob"][0].values.to_numpy(zero_copy_only=False)
        a = cv2.imdecode(np.asarray(blob, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if a is None:
            raise ValueError(f"{row.entity}: cannot decode the encoded image")
        return a if a.ndim == 2 else cv2.cvtColor(a, cv2.COLOR_BGR2RGB)
    fmt = row["Image:format"].to_pylist()[0]
    buf = np.asarray(row["Image:buffer"][0].values.to_numpy(zero_copy_only=False), dtype=np.uint8)
    h, w = fmt["height"], fmt["width"]
    channels = buf.size // (h * w)
    return buf.reshape(h, w) if channels == 1 else buf.reshape(h, w, channels)
