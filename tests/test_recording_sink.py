"""The recording sink over a long run: the jobs it hands its thread are not all kept until the end, a
job's error surfaces before the recording is closed, and a recorder keeps no Python object per frame."""

from __future__ import annotations

import gc
import threading
from concurrent.futures import Future

import pytest

from pcreg.recording.sink import Sink

JOBS_PER_FRAME = 20  # about what a recorded pair logs
FRAMES = 200


def _frame(sink: Sink, jobs: int, last=lambda: None) -> None:
    """Ask for ``jobs`` jobs, the last one ``last``, and return once the sink's thread has run them all."""
    ran = threading.Event()
    for _ in range(jobs - 1):
        sink.later(lambda: None)

    def final() -> None:
        try:
            last()
        finally:
            ran.set()

    sink.later(final)
    assert ran.wait(timeout=120)


def test_a_long_recording_keeps_a_bounded_number_of_jobs(tmp_path):
    sink = Sink(tmp_path / "long.rrd")
    try:
        for _ in range(FRAMES):  # 4,000 jobs; every one run before the next frame's
            _frame(sink, JOBS_PER_FRAME)
        # by type: isinstance on a weakref proxy another test left dead raises ReferenceError
        kept = sum(issubclass(type(o), Future) for o in gc.get_objects())  # what stays in memory for them
        assert kept <= FRAMES * JOBS_PER_FRAME // 10, kept
    finally:
        sink.close()
    assert sink.pending_jobs == 0 and (tmp_path / "long.rrd").stat().st_size > 0


def test_a_jobs_error_surfaces_while_the_run_goes_on(tmp_path):
    sink = Sink(tmp_path / "failing.rrd")

    def fail() -> None:
        raise ValueError("a job's error")

    try:
        _frame(sink, 1, fail)
        with pytest.raises(ValueError, match="a job's error"):
            for _ in range(FRAMES * JOBS_PER_FRAME):  # a long run's worth of jobs: not only at the end
                sink.later(lambda: None)
    finally:
        sink.close()


def _record_frames(rec, start: int, stop: int) -> None:
    """Frames ``start``..``stop`` as ``pcreg run`` records each: two images, the labels, a dense field."""
    import numpy as np

    h, w = 30, 40
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for t in range(start, stop):
        image = np.dstack([(xs * (1 + t % 3) + ys) % 256] * 3).astype(np.uint8)
        rec.set_frame(t)
        rec.log_images(reference=image[::-1].copy(), moving=image)
        rec.log_labels(predicted=(xs > 10 + t % 7).astype(np.uint8))
        rec.log_dense(np.dstack([xs + 0.5, ys]), matrix=np.eye(3), confidence=np.full((h, w), 0.5, np.float32))


def test_a_long_recording_keeps_no_python_objects_per_frame(tmp_path):
    from pcreg.recording.recorder import Recorder

    with Recorder(tmp_path / "run.rrd") as rec:
        _record_frames(rec, 0, 100)
        rec.sink.wait()
        gc.collect()
        before = len(gc.get_objects())
        _record_frames(rec, 100, 400)  # 300 frames more: one object kept a frame would be 300 more
        rec.sink.wait()
        gc.collect()
        grown = len(gc.get_objects()) - before
    assert grown < 30, grown  # none in practice


def test_a_long_recording_keeps_no_manifest_of_its_chunks(tmp_path):
    """rerun's file sink, asked for a footer, keeps an entry of every chunk in memory until the file is closed
    (1-3 kB each, about ten a second of a recorded run): the recorder writes none, and ends the stream
    itself, so that the file still reads as finished and whole."""
    import struct

    from pcreg.recording.readback import _scan, ended, read_recording
    from pcreg.recording.recorder import Recorder

    path = tmp_path / "run.rrd"
    with Recorder(path) as rec:
        for t in range(0, 60, 3):
            _record_frames(rec, t, t + 3)
            rec.flush()  # what rerun's one-second tick does: each entity's rows so far become a chunk
    data = path.read_bytes()
    assert data[-16:] == struct.pack("<QQ", 0, 0)  # the end of the stream, and nothing after it: no footer
    assert _scan(path) == (len(data), len(data), True) and ended(path)
    frames = {r.times["frame"] for r in read_recording(path).get("labels/predicted")}
    assert frames == set(range(60))
