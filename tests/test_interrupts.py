"""Ctrl-C and SIGTERM stop every long command: exit 130, finished units kept, no process left in the
command's group, the output lock released, and the same command then runs to the end.

Each command runs in a subprocess in its own process group (as a terminal's foreground job). The
signal is sent when an event shows the run is under way (a unit file in OUT/units, a line on stdout,
a frame committed to run.json), never after a pause; the only time limits are generous bounds that
turn a hang into a failure.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Callable

import cv2
import pytest

from _events import HANG, Ended, processes, until

PCREG = [sys.executable, "-m", "pcreg.cli"]

SEQUENCE = ["evaluate", "sequence", "--data", "synthetic:syn1a,syn2b", "--frames", "24", "--size", "160x120",
            "-k", "1,2,3,4,5,6"]  # 12 units of about a second
ROTATION = ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "6", "--size", "160x120",
            "--angles", "0:180:10", "--samples", "6"]  # 6 units of 19 registrations each
STREAM = ["evaluate", "stream", "--data", "synthetic:syn1a,syn2a,syn2b,syn3a", "--frames", "6", "--size", "160x120",
          "--methods", "unregistered,pcreg,flow_key"]  # 4 units (clips) of 5 frames each
CLASSIFICATION = ["evaluate", "classification", "--data", "synthetic:syn1a,syn2b", "--frames", "24",
                  "--size", "160x120", "--trials", "30"]


def start(args: list, **kwargs) -> subprocess.Popen:
    """The command in a new session (its own process group, whose id is its pid)."""
    return subprocess.Popen([*PCREG, *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)


def wait_for(p: subprocess.Popen, event: Callable[[], object], what: str) -> None:
    """Poll ``event`` until it holds; fail with the command's output if it ends first."""
    try:
        until(event, what=what, alive=p)
    except Ended as exc:
        out, err = p.communicate()
        pytest.fail(f"{exc}:\n{out[-2000:]}\n{err[-2000:]}")


def wait_for_line(p: subprocess.Popen, text: str) -> None:
    """Read stdout until a line holds ``text`` (the command flushes it)."""
    seen = []
    for line in p.stdout:
        seen.append(line)
        if text in line:
            return
    p.wait(timeout=HANG)
    pytest.fail(f"the command ended (exit {p.returncode}) without printing {text!r}:\n{''.join(seen)}"
                f"\n{p.stderr.read()[-2000:]}")


def group_members(pgid: int) -> dict[int, str]:
    """pid -> state letter of every process in the group (from /proc)."""
    return {p.pid: p.state for p in processes() if p.pgrp == pgid}


def signal_and_check(p: subprocess.Popen, how: str, out: Path | None) -> str:
    """Send the signal (``group``: SIGINT to the process group, as Ctrl-C; ``parent``: SIGINT to the
    command alone; ``term``: SIGTERM to the command alone), then check the exit and the aftermath: every
    process of the group ends (waited for through pidfds, readable when a process exits), the output
    lock is free. Returns stderr."""
    import select

    members = group_members(p.pid)
    fds = []
    for pid in members:
        try:
            fds.append(os.pidfd_open(pid))
        except ProcessLookupError:
            pass
    try:
        if how == "group":
            os.killpg(p.pid, signal.SIGINT)
        elif how == "parent":
            p.send_signal(signal.SIGINT)
        else:
            p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=HANG)
        pending = list(fds)
        while pending:
            ready, _, _ = select.select(pending, [], [], HANG)
            assert ready, f"processes of the command still running {HANG} s after it exited"
            pending = [fd for fd in pending if fd not in ready]
    finally:
        for fd in fds:
            os.close(fd)
        if p.poll() is None or any(state != "Z" for state in group_members(p.pid).values()):
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130, err
    said = [part.strip() for line in err.splitlines() for part in line.split("\r")]
    said = [line for line in said if line and "%|" not in line]  # progress bars aside: one line
    assert len(said) == 1 and said[0].startswith("pcreg: interrupted"), err
    left = {pid: st for pid, st in group_members(p.pid).items() if st != "Z"}  # zombies: exited, init reaps them
    assert not left, f"processes of the command left behind: {left}"
    if out is not None:
        from pcreg.outputs import OutputLock

        with OutputLock(out):  # released: a new run may take it
            pass
    return err


def units(out: Path) -> list[Path]:
    return sorted(out.glob("units/**/*.json"))


def resumed(args: list, out: Path, kept: list[Path]) -> dict:
    """Run the same command to the end: the units the interrupted run finished are reused, not redone
    (their files are not written again)."""
    assert kept
    before = {u: (u.stat().st_ino, u.stat().st_mtime_ns) for u in kept}
    p = subprocess.run([*PCREG, *map(str, args)], capture_output=True, text=True, timeout=HANG)
    assert p.returncode == 0, p.stderr
    assert {u: (u.stat().st_ino, u.stat().st_mtime_ns) for u in kept} == before
    return json.loads((out / "results.json").read_text())


@pytest.mark.parametrize("how, workers", [("group", 2), ("parent", 2), ("term", 2), ("group", 1)])
def test_evaluate_sequence_stops_keeps_units_and_resumes(tmp_path, how, workers):
    out = tmp_path / "seq"
    args = [*SEQUENCE, "--workers", workers, "--out", out]
    p = start(args)
    wait_for(p, lambda: units(out), "a finished unit")
    signal_and_check(p, how, out)
    kept = units(out)
    assert kept and all(json.loads(u.read_text())["pairs"] for u in kept)  # whole files
    assert not (out / "results.json").exists()
    resumed(args, out, kept)


def test_sigint_stops_a_command_started_with_sigint_ignored(tmp_path):
    """A shell without job control (a script's ``pcreg ... &``) starts its background commands with
    SIGINT ignored; ``kill -INT`` (and Ctrl-C through a wrapper) must still stop them."""
    out = tmp_path / "seq"
    args = [*SEQUENCE, "--workers", 2, "--out", out]
    p = start(args, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    wait_for(p, lambda: units(out), "a finished unit")
    signal_and_check(p, "parent", out)
    resumed(args, out, units(out))


@pytest.mark.parametrize("how, workers", [("group", 2), ("term", 1)])
def test_evaluate_rotation_stops_and_resumes(tmp_path, how, workers):
    out = tmp_path / "rot"
    args = [*ROTATION, "--workers", workers, "--out", out]
    p = start(args)
    wait_for(p, lambda: units(out), "a finished unit")
    signal_and_check(p, how, out)
    resumed(args, out, units(out))


@pytest.mark.parametrize("how, workers", [("group", 2), ("parent", 1)])
def test_evaluate_classification_stops_and_resumes(tmp_path, how, workers):
    out = tmp_path / "cls"
    args = [*CLASSIFICATION, "--workers", workers, "--out", out]
    p = start(args)
    wait_for(p, lambda: units(out), "a finished unit")
    signal_and_check(p, how, out)
    resumed(args, out, units(out))


@pytest.mark.parametrize("how, workers", [("group", 2), ("parent", 1)])
def test_evaluate_stream_stops_and_resumes(tmp_path, how, workers):
    out = tmp_path / "stream"
    args = [*STREAM, "--workers", workers, "--out", out]
    p = start(args)
    wait_for(p, lambda: units(out), "a finished unit")
    signal_and_check(p, how, out)
    kept = units(out)
    results = resumed(args, out, kept)
    assert set(results["datasets"]) == {"syn1a", "syn2a", "syn2b", "syn3a"}


def _done(state: Path) -> int:
    try:
        return json.loads(state.read_text())["done"]
    except (OSError, ValueError, KeyError):
        return 0


@pytest.mark.parametrize("how", ["group", "term"])
def test_run_stops_between_frames_and_resumes(tmp_path, how):
    import pcreg

    frames = pcreg.synthetic("syn1a", 24, 0, width=320, height=240)
    src = tmp_path / "frames"
    src.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(src / f"f{i:03d}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
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


@pytest.mark.parametrize("how, workers, at", [("group", 2, "2/6"), ("term", 1, "4/6")])
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


def test_an_interrupt_inside_exec_of_a_string_still_exits_130():
    """CPython ends ``python -m`` by SIGINT when a KeyboardInterrupt once escaped an ``exec`` of a string,
    even after the program handled it; the command line clears that note."""
    tests = Path(__file__).parent
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tests), os.environ.get("PYTHONPATH", "")])}
    p = subprocess.run([sys.executable, "-m", "_interrupted_in_exec"], capture_output=True, text=True, env=env,
                       cwd=tests, timeout=HANG)
    assert p.returncode == 130, p.stderr
    assert p.stderr.startswith("pcreg: interrupted"), p.stderr
