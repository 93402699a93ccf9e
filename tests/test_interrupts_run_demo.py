"""Ctrl-C, SIGTERM and SIGHUP (a closed terminal; it ended a run with 129, silent, its temporary files left) stop
``pcreg run`` between frames and ``pcreg demo`` in its worker and recording phases, and the same command then finishes the work; an interrupt that once escaped an ``exec`` still
exits 130. The helpers and how the signal is sent: ``_interrupting.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from _events import HANG
from _interrupting import PCREG, signal_and_check, start, wait_for, wait_for_line

pytestmark = pytest.mark.slow  # commands stopped by signals and run again: seconds each


def _done(state: Path) -> int:
    try:
        return json.loads(state.read_text())["done"]
    except (OSError, ValueError, KeyError):
        return 0


def _frames(tmp_path: Path, n: int, width: int, height: int):
    """``n`` synthetic frames written to ``tmp_path/frames`` as ``f000.png``, ..., and the first one's labels to
    ``tmp_path/key.png``: (the frames, the folder)."""
    import pcreg

    frames = pcreg.synthetic("syn1a", n, 0, width=width, height=height)
    src = tmp_path / "frames"
    src.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(src / f"f{i:03d}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    return frames, src


@pytest.mark.parametrize("how", ["group", "term", "hangup"])
def test_run_stops_between_frames_and_resumes(tmp_path, how):
    frames, src = _frames(tmp_path, 60, 320, 240)  # about 1.5 s left when it is stopped
    out = tmp_path / "out"
    args = ["run", src, "--labels", tmp_path / "key.png", "--out", out]
    p = start(args)
    wait_for(p, lambda: _done(out / "run.json") >= 3, "three frames committed")
    signal_and_check(p, how, out)
    done = _done(out / "run.json")
    assert 3 <= done < len(frames)
    assert all((out / f"f{i:03d}.png").is_file() for i in range(done))
    again = subprocess.run([*PCREG, *map(str, args)], capture_output=True, text=True, timeout=HANG)
    assert again.returncode == 0, again.stderr
    assert f"{len(frames) - done} frame(s) labelled" in again.stdout
    assert _done(out / "run.json") == len(frames)


@pytest.mark.parametrize("how, workers, at", [("group", 2, "2/6"), ("term", 1, "4/6"), ("hangup", 2, "2/6")])
def test_demo_stops_and_runs_again(tmp_path, how, workers, at):
    """Stopped in Ch. 5 (units in worker processes) or in Ch. 6-7 (recording in this process); the same
    command then runs to the end, replacing the recording the interrupted run left."""
    out = tmp_path / "demo"
    args = ["demo", "--frames", 8, "--workers", workers, "--out", out]
    p = start(args)
    wait_for_line(p, at)
    signal_and_check(p, how, out)
    assert not (out / "report.md").exists()
    again = subprocess.run([*PCREG, *map(str, args)], capture_output=True, text=True, timeout=HANG)
    assert again.returncode == 0, again.stderr
    assert (out / "report.md").is_file() and (out / "demo.rrd").is_file()


def test_a_run_started_under_nohup_goes_on_when_its_terminal_closes(tmp_path):
    """``nohup`` starts a command with SIGHUP ignored so that it outlives its terminal: pcreg keeps it so."""
    import signal

    frames, src = _frames(tmp_path, 12, 160, 120)
    out = tmp_path / "out"
    p = start(["run", src, "--labels", tmp_path / "key.png", "--out", out],
              preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    wait_for(p, lambda: _done(out / "run.json") >= 2, "two frames committed")
    os.killpg(p.pid, signal.SIGHUP)
    _, err = p.communicate(timeout=HANG)
    assert p.returncode == 0, err
    assert _done(out / "run.json") == len(frames)


def test_an_interrupt_inside_exec_of_a_string_still_exits_130():
    """CPython ends ``python -m`` by SIGINT when a KeyboardInterrupt once escaped an ``exec`` of a string,
    even after the program handled it; the command line clears that note."""
    tests = Path(__file__).parent
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tests), os.environ.get("PYTHONPATH", "")])}
    p = subprocess.run([sys.executable, "-m", "_interrupted_in_exec"], capture_output=True, text=True, env=env,
                       cwd=tests, timeout=HANG)
    assert p.returncode == 130, p.stderr
    assert p.stderr.startswith("pcreg: interrupted"), p.stderr
