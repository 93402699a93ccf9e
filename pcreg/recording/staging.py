"""Recordings made ready for a viewer: the blueprint of what each holds, several merged into one comparison.

:func:`stage` copies one recording's chunks into a new .rrd (same application and recording id) with
the blueprint of its kind built from the entities it holds, or merges several recordings into one, each
under ``/{label}/...``, with the comparison blueprint (:func:`pcreg.recording.blueprint.compare_blueprint`):
the same pane of every recording side by side, their series in one plot with the label in each legend.
The inputs are only read, each as it stands when staging starts (a recording still being written is
read up to its last whole message: :func:`pcreg.recording.readback.snapshot`).
"""

from __future__ import annotations

import os
import re
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path

from . import blueprint as B
from .readback import read_entities, read_kind, snapshot, unfinished_files_allowed, whole_stream

__all__ = ["Staged", "stage", "labels_for"]


@dataclass(frozen=True)
class Staged:
    """A staged file: its path, per input recording its label (``""`` for one input) and kind, and whether
    any input logged data (an entity besides the root's; False for files with nothing to draw)."""

    path: Path
    labels: tuple[str, ...]
    kinds: tuple[str, ...]
    logged: bool = True


def labels_for(paths: list[str | os.PathLike]) -> list[str]:
    """Entity-path-safe labels of recordings from their file names (``run.rrd`` -> ``run``), made unique."""
    out: list[str] = []
    for p in paths:
        base = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(p).stem).strip("_.") or "recording"
        label, n = base, 2
        while label in out:
            label, n = f"{base}_{n}", n + 1
        out.append(label)
    return out


def stage(paths: list[str | os.PathLike], out: str | os.PathLike) -> Staged:
    """Write ``out`` (.rrd) holding ``paths``' recordings with the blueprint that shows them (see module)."""
    if not paths:
        raise ValueError("no recording to stage")
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="pcreg-stage-", dir=out.parent) as tmp, unfinished_files_allowed():
        # a recording may still be written (an evaluation's --record): each is read as it stands, up to its
        # last whole message, from one copy, so that every reading below sees the same data
        copies = [snapshot(p, Path(tmp) / f"{i}.rrd") for i, p in enumerate(paths)]
        return _stage(paths, copies, out)


def _reader_error(exc: Exception, copy: Path) -> str:
    """rerun's reading error, its first line, without the name of the copy it read."""
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    prefix = f"Failed to read RRD file at {copy}: "
    return text[len(prefix):] if text.startswith(prefix) else text.replace(str(copy), "the file")


def _stage(paths: list[str | os.PathLike], copies: list[Path], out: Path) -> Staged:
    import rerun as rr
    from rerun.chunk import RrdReader

    readers = [RrdReader(str(c)) for c in copies]
    stores = []
    for p, r in zip(paths, readers):
        recs = r.recordings()
        if not recs:
            raise ValueError(f"{p}: no recording in this file")
        stores.append(recs[0])
    everything = []
    for p, c in zip(paths, copies):
        try:
            everything.append(read_entities(c))
        except RuntimeError as exc:  # rerun's reader: a damaged message, a version it does not read
            raise ValueError(f"{p}: unreadable ({_reader_error(exc, c)})") from None
    kinds = [read_kind(c) or B.infer_kind(e) for c, e in zip(copies, everything)]
    logged = any(entity != "/" for e in everything for entity in e)
    # only what the viewer shows on the timeline the layout opens on (no view without data there)
    timelines = {B.timeline(k, e) for k, e in zip(kinds, everything)}
    shown_on = timelines.pop() if len(timelines) == 1 else B.timeline("sequence")
    entities = [read_entities(c, timeline=shown_on) for c in copies]
    if len(paths) == 1:
        stream = whole_stream(stores[0].application_id, recording_id=stores[0].recording_id)
        has_views = bool(B.panes(kinds[0], entities[0]))  # else (nothing to show) the viewer chooses
        stream.save(out, default_blueprint=B.blueprint(kinds[0], entities[0]) if has_views else None)
        stream.send_chunks(readers[0].stream(store=stores[0]))
        stream.flush()
        stream.disconnect()
        return Staged(out, ("",), (kinds[0],), logged)

    labels = labels_for(paths)
    bp = B.compare_blueprint(list(zip(labels, kinds, entities)))
    stream = whole_stream(stores[0].application_id, recording_id=f"compare-{uuid.uuid4()}")
    stream.save(out, default_blueprint=bp)
    stream.send_recording_name("compare " + ", ".join(labels))
    series_names: list[tuple[str, list[str]]] = []
    for label, reader, store in zip(labels, readers, stores):
        root = "/" + label

        def move(chunk, root=root):
            path = chunk.entity_path
            if path.startswith("/__"):
                return []
            new = root if path == "/" else root + path
            batch = chunk.to_record_batch()
            if "SeriesLines:names" in batch.schema.names:
                names = [n for v in batch.column("SeriesLines:names").to_pylist() if v for n in v]
                series_names.append((new, names))
            return [chunk.with_entity_path(new)]

        stream.send_chunks(reader.stream(store=store).flat_map(move))
    # the legend tells the recordings apart: "run_a fitness", "run_b fitness"
    for path, names in series_names:
        label = path.strip("/").split("/", 1)[0]
        stream.log(path, rr.SeriesLines(names=[f"{label} {n}" for n in names]), static=True)
    stream.flush()
    stream.disconnect()
    return Staged(out, tuple(labels), tuple(kinds), logged)
