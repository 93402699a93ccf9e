"""Commands at the same time: two evaluations into two folders, and ``pcreg view --web`` serving a
recording that an evaluation is still writing. Each finishes with what it writes alone, nothing
corrupted.

The overlap is made, not hoped for: a command is paused (SIGSTOP) once an event shows it mid-run (a
unit file written, a recording with data), the other runs meanwhile, then it goes on (SIGCONT). No
pause, no time measured; the only time limits are bounds that turn a hang into a failure.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from _events import HANG
from _interrupting import start as start_in_own_group, units, wait_for

# Small, and long enough to be caught mid-run: after the first unit, 3 more of 19 angles each (2.3 s) and the
# report (1.2 s); the stream's 3 more clips of 11 frames (0.8 s) and its report (2.9 s). With 2 units (0.05 s and
# 0.1 s apart) the report alone was left, 1.3 s and 1.4 s, for the pause to land before results.json.
ROTATION = ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "4", "--size", "160x120",
            "--angles", "0:180:10", "--samples", "4"]
STREAM = ["evaluate", "stream", "--data", "synthetic:syn1a,syn2a,syn2b,syn3a", "--frames", "12", "--size", "160x120",
          "--methods", "plain,pcreg"]


def _env() -> dict:
    """This checkout's pcreg first on the children's path (as pytest has it first on ours)."""
    root = str(Path(__file__).resolve().parent.parent)
    return dict(os.environ, PYTHONPATH=os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p]),
                PYTHONUNBUFFERED="1")


def start(args: list, **kwargs) -> subprocess.Popen:
    """The command in its own process group, with this checkout's pcreg first on its path."""
    return start_in_own_group(args, env=_env(), **kwargs)


def pause_mid_run(p: subprocess.Popen, out: Path) -> None:
    """Stop ``p`` once its first unit is written, with more to do (it holds its lock and partial outputs)."""
    wait_for(p, lambda: units(out), "a unit written")
    os.kill(p.pid, signal.SIGSTOP)
    assert p.poll() is None, "the command ended before it could be paused mid-run"
    assert not (out / "results.json").exists()


def finish(p: subprocess.Popen) -> str:
    out, err = p.communicate(timeout=HANG)
    assert p.returncode == 0, err[-3000:]
    return out


@contextlib.contextmanager
def reaped(*procs: subprocess.Popen):
    """On the way out, a command still there (the test failed) is continued and killed with its group."""
    try:
        yield
    finally:
        for p in procs:
            if p.poll() is None:
                for sig in (signal.SIGCONT, signal.SIGKILL):
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(p.pid, sig)
                p.wait(timeout=HANG)
            for fh in (p.stdout, p.stderr):
                if fh is not None:
                    fh.close()


def _timeless(obj):
    """A result without its clocks (seconds, ms per frame): what is the same from run to run."""
    if isinstance(obj, dict):
        return {k: _timeless(v) for k, v in obj.items() if "seconds" not in k and not k.startswith("ms_per")}
    if isinstance(obj, list):
        return [_timeless(v) for v in obj]
    return obj


#: Registration's floating-point sums are not bit-reproducible from run to run, even alone (the same
#: rotation evaluation twice: corner errors apart by up to 1e-9 px); a mixed-up or corrupted result
#: differs in the labels, the counts or the error rates' leading digits.
RTOL, ATOL = 1e-6, 1e-6


def same(x, y) -> bool:
    """Equal JSON values, numbers within RTOL/ATOL."""
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(same(x[k], y[k]) for k in x)
    if isinstance(x, list) and isinstance(y, list):
        return len(x) == len(y) and all(same(u, v) for u, v in zip(x, y))
    if isinstance(x, float) or isinstance(y, float):
        return (isinstance(x, (int, float)) and isinstance(y, (int, float))
                and bool(np.isclose(x, y, rtol=RTOL, atol=ATOL, equal_nan=True)))
    return x == y


def assert_same_results(a: Path, b: Path) -> None:
    """Two evaluation folders hold the same files: JSON the same but for clocks, tables and checks byte
    for byte, figures that decode."""
    def files(d: Path) -> set[str]:
        return {p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file() and p.name != ".pcreg.lock"}

    assert files(a) == files(b)
    assert not [f for f in files(b) if f.endswith(".tmp")]
    for name in sorted(files(a)):
        x, y = a / name, b / name
        if name.endswith(".json"):
            assert same(_timeless(json.loads(x.read_text())), _timeless(json.loads(y.read_text()))), name
        elif name.endswith((".csv", ".md")):
            assert x.read_bytes() == y.read_bytes(), name
        elif name.endswith(".png"):
            assert cv2.imread(str(y), cv2.IMREAD_UNCHANGED) is not None, name


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    """Each evaluation run by itself (in this process), and the stream's recording."""
    from pcreg import cli

    d = tmp_path_factory.mktemp("alone")
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main([*ROTATION, "--out", str(d / "rotation")]) == 0
        assert cli.main([*STREAM, "--out", str(d / "stream"), "--record", str(d / "stream.rrd")]) == 0
    return d


@pytest.mark.slow
def test_two_evaluations_at_once_write_what_each_writes_alone(alone, tmp_path):
    rot, stream = tmp_path / "rotation", tmp_path / "stream"
    a = start([*ROTATION, "--out", rot])
    b = None
    with reaped(a):
        pause_mid_run(a, rot)
        b = start([*STREAM, "--out", stream, "--record", tmp_path / "stream.rrd"])
        with reaped(b):
            pause_mid_run(b, stream)
            os.kill(a.pid, signal.SIGCONT)  # both mid-run; both go on together
            os.kill(b.pid, signal.SIGCONT)
            finish(a)
            finish(b)
    assert_same_results(alone / "rotation", rot)
    assert_same_results(alone / "stream", stream)
    assert_same_recordings(alone / "stream.rrd", tmp_path / "stream.rrd")


def assert_same_recordings(a: Path, b: Path) -> None:
    """The same entities with the same rows, times and (but for log times) values."""
    from pcreg.recording.readback import read_recording

    x, y = read_recording(a), read_recording(b)
    assert x.entities() == y.entities()
    for entity in x.entities():
        rx, ry = x.rows[entity], y.rows[entity]
        assert [(r.static, r.times) for r in rx] == [(r.static, r.times) for r in ry], entity
        if entity.startswith("/__"):
            continue  # rerun's own: the recording's id and start time
        for u, v in zip(rx, ry):
            assert u.components.keys() == v.components.keys(), entity
            for c in u.components:
                assert same(u[c].to_pylist(), v[c].to_pylist()), (entity, c)


def _listening(port: int) -> bool:
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError), open(table) as fh:
            for line in fh.read().splitlines()[1:]:
                fields = line.split()
                if fields[3] == "0A" and int(fields[1].split(":")[1], 16) == port:
                    return True
    return False


@pytest.mark.slow
def test_web_viewer_serves_a_recording_while_an_evaluation_writes_it(alone, tmp_path):
    """``pcreg view R.rrd --web`` started while ``--record R.rrd`` is being written: it serves what is there,
    the evaluation finishes as it would alone, the recording reads back whole."""
    import re

    from _browser import Browser, find_chromium

    from pcreg.recording.readback import complete_length, recordings_in

    rrd, stream = tmp_path / "stream.rrd", tmp_path / "stream"
    evaluation = start([*STREAM, "--out", stream, "--record", rrd])
    with reaped(evaluation):
        pause_mid_run(evaluation, stream)
        assert recordings_in(rrd)  # data in it, and the recording not finished: no end of stream yet
        assert complete_length(rrd) is not None
        view = start(["view", rrd, "--web", "--web-port", "0", "--grpc-port", "0"])
        with reaped(view):
            url = None
            for line in view.stdout:  # the viewer prints its URL once the staged copy is served
                if line.startswith("http://"):
                    url = line.strip()
                    break
            assert url, view.stderr.read()
            ports = [int(p) for p in re.findall(r"(?::|%3A)(\d+)", url)]
            assert len(ports) == 2 and all(_listening(p) for p in ports)
            os.kill(evaluation.pid, signal.SIGCONT)  # the evaluation writes on while the viewer serves
            if find_chromium() is not None:
                with Browser(width=1280, height=720) as browser:
                    browser.open(url)
                    # the viewer's page draws the frames recorded so far: a picture, not a blank page
                    ok, shot = browser.wait_for(lambda s: s.std() > 20 and _saturated(s) > 0.02, timeout=HANG)
                    cv2.imwrite(str(tmp_path / "web.png"), shot)
                    assert ok, (shot.std(), _saturated(shot))
            finish(evaluation)
            assert view.poll() is None, "the viewer stopped while the evaluation wrote on"
            os.killpg(view.pid, signal.SIGINT)
            assert view.wait(timeout=HANG) == 130
            assert not any(_listening(p) for p in ports)
    assert_same_results(alone / "stream", stream)
    assert_same_recordings(alone / "stream.rrd", rrd)


def _saturated(shot: np.ndarray) -> float:
    """Fraction of the picture in clearly coloured pixels (the frames' greens and blues, the labels'
    colours), which the viewer's grey interface has none of."""
    hsv = cv2.cvtColor(shot, cv2.COLOR_BGR2HSV)
    return float(((hsv[..., 1] > 80) & (hsv[..., 2] > 60)).mean())


def _message_starts(data: bytes) -> list[int]:
    """Where each message with a payload starts in an .rrd file's bytes: after the 12-byte stream header,
    each message is a 16-byte header (kind, payload length: little-endian u64) and its payload; kind 0
    ends the stream (the footer follows)."""
    starts, at = [], 12
    while at + 16 <= len(data):
        kind = int.from_bytes(data[at:at + 8], "little")
        length = int.from_bytes(data[at + 8:at + 16], "little")
        if kind == 0:
            break
        if length > 1:
            starts.append(at)
        at += 16 + length
    return starts


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_a_recording_cut_in_the_middle_of_a_message_reads_up_to_it(tmp_path):
    """What a reader finds while the writer is half-way through a message: the whole messages before it."""
    import rerun.chunk

    from pcreg.recording.viewer import check_recording
    from pcreg.errors import InputError
    from pcreg.recording.readback import (
        complete_length,
        read_recording,
        recordings_in,
        snapshot,
        unfinished_note,
    )
    from pcreg.recording.recorder import Recorder
    from pcreg.recording.staging import stage

    path = tmp_path / "whole.rrd"
    img = np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    with Recorder(path, kind="sequence") as rec:
        for f in range(6):
            rec.set_frame(f)
            rec.log_images(reference=img, moving=img)
            rec.log_errors({"plain": float(f)})
            rec.flush()  # each frame's messages in the file before the next frame's
    data = path.read_bytes()
    assert complete_length(path) == len(data)  # finished: all of it
    # cut half-way through the payload of the first message that starts past the middle of the file
    starts = _message_starts(data)
    start = next((s for s in starts if s >= len(data) // 2), starts[-1])
    length = int.from_bytes(data[start + 8:start + 16], "little")
    cut_at = start + 16 + length // 2
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[:cut_at])
    with pytest.raises(Exception, match="exceeds"):  # rerun's reader alone gives up on the half-written message
        rerun.chunk.RrdReader(str(cut)).recordings()
    n = complete_length(cut)
    assert n == start
    assert unfinished_note(path) is None
    assert unfinished_note(cut).endswith(f"last whole message (the {cut_at - start} bytes of an unfinished one after it left out)")
    (tmp_path / "on_a_message.rrd").write_bytes(data[:start])  # ends on a message, but not the last one
    assert unfinished_note(tmp_path / "on_a_message.rrd").endswith("up to its last whole message")
    assert snapshot(cut, tmp_path / "snap.rrd").stat().st_size == n
    assert recordings_in(cut)[0].application_id == "pcreg"
    assert check_recording(cut)[0] == "pcreg"
    staged = stage([cut], tmp_path / "staged.rrd")
    frames = read_recording(staged.path).series("errors/plain")
    assert frames and set(frames) <= set(range(6)) and all(frames[f] == f for f in frames)
    assert frames == read_recording(tmp_path / "snap.rrd").series("errors/plain")  # the whole messages, no more
    assert cut.read_bytes() == data[:cut_at]  # only read
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording" * 10)
    assert complete_length(bad) is None
    with pytest.raises(InputError, match="not a rerun recording"):
        check_recording(bad)


def test_an_unfinished_run_says_whether_a_command_is_writing_it_now(tmp_path):
    """A run viewed or exported half way: while its `pcreg run` holds the folder, the note says so (and which
    process), not that the same command would go on from where it stopped; once it ends, it says that."""
    import os

    from pcreg.outputs import OutputLock, writer_of
    from pcreg.runs.state import unfinished_note

    folder = tmp_path / "run"
    assert writer_of(folder) is None  # no folder, no lock file
    with OutputLock(folder):
        assert writer_of(folder) == str(os.getpid())
        note = unfinished_note(folder, 3, 10)
        assert note is not None and f"a pcreg run (pid {os.getpid()}) is writing it now" in note
    assert writer_of(folder) is None  # released: the lock file left behind is nobody's
    folder.mkdir(exist_ok=True)
    (folder / "x").write_text("")  # the folder is kept when the lock is released with something in it
    note = unfinished_note(folder, 3, 10)
    assert note is not None and "goes on from where it stopped" in note
