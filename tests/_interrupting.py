"""What the interrupt tests share: a command started in its own process group, waits for the events
that show it under way, and the signal (sent from outside, or landing at a chosen moment: :data:`SIGNALLED`)
with the checks of its aftermath (exit 130, one line on stderr, no process left, the output lock free). The
tests: ``test_interrupts*.py``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest

from _events import HANG, Ended, processes, until

PCREG = [sys.executable, "-m", "pcreg.cli"]


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


#: A module: ``python -m`` it with WHERE, a file pattern, a file's path and a pcreg command: the command, as
#: ``python -m pcreg.cli`` runs it, with SIGINT's handler called at the moment WHERE names, as the interpreter calls
#: it for a signal arriving then (a profile hook calls it: the interpreter runs no handler inside a hook); the file
#: tells it ran. ``wait``: inside concurrent.futures' wait(), once a file matches the pattern, just as wait() has
#: taken the last of the futures' locks (SIGINT sent from outside within half a millisecond of the first unit's
#: file appearing landed there 3 times in 125); ``exec``: as code made from a string (a dataclass's methods)
#: starts, while the commands' modules load; ``import``: as a module starts loading, the KeyboardInterrupt turned
#: into the ImportError numpy makes of one landing in its own imports.
SIGNALLED = """
import glob, os, runpy, signal, sys
from concurrent.futures import _base

ENTER = _base._AcquireFutures.__enter__.__code__
where, pattern, ran = sys.argv.pop(1), sys.argv.pop(1), sys.argv.pop(1)

def lands(frame, event):
    if where == "wait":
        return (event == "c_return" and frame.f_code is ENTER
                and frame.f_locals["future"] is frame.f_locals["self"].futures[-1] and glob.glob(pattern))
    handled = getattr(signal.getsignal(signal.SIGINT), "__module__", "") == "pcreg._signals"
    name = frame.f_code.co_filename if where == "exec" else frame.f_code.co_name
    return event == "call" and handled and name == {"exec": "<string>", "import": "<module>"}[where]

def at(frame, event, arg):  # every call and return of the main thread
    if lands(frame, event):
        sys.setprofile(None)
        open(ran, "w").close()
        try:
            signal.getsignal(signal.SIGINT)(signal.SIGINT, frame)
        except KeyboardInterrupt as exc:
            if where == "import":
                raise ImportError("PyCapsule_Import could not import module") from exc
            raise

os.register_at_fork(after_in_child=lambda: sys.setprofile(None))
sys.setprofile(at)
runpy.run_module("pcreg.cli", run_name="__main__", alter_sys=True)
"""


def wait_until_ended(fds: list[int], said: str) -> None:
    """Wait until every process of ``fds`` (pidfds, readable once their process exits) has ended; ``said``
    (``{HANG}`` in it: the seconds waited) fails the test when one has not after :data:`HANG` seconds."""
    import select

    pending = list(fds)
    while pending:
        ready, _, _ = select.select(pending, [], [], HANG)
        assert ready, said.format(HANG=HANG)
        pending = [fd for fd in pending if fd not in ready]


def start_signalled(where: str, args: list, tmp: Path, pattern: str = "") -> subprocess.Popen:
    """The command as :func:`start` starts it, SIGINT landing as :data:`SIGNALLED` says (the module written
    in ``tmp``, and the file ``tmp/signalled`` once the handler ran)."""
    (tmp / "signalled_at.py").write_text(SIGNALLED)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp), os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, "-m", "signalled_at", where, pattern, str(tmp / "signalled"),
                             *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=env)


def signal_and_check(p: subprocess.Popen, how: str, out: Path | None) -> str:
    """Send the signal (``group``: SIGINT to the process group, as Ctrl-C; ``parent``: SIGINT to the
    command alone; ``term``: SIGTERM to the command alone; ``hangup``: SIGHUP to the process group, as a closed
    terminal or ssh session sends it; ``self``: none, the command signals itself),
    then check the exit and the aftermath: every process of the group ends (waited for through pidfds,
    readable when a process exits), the output lock is free. Returns stderr."""

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
        elif how == "term":
            p.send_signal(signal.SIGTERM)
        elif how == "hangup":
            os.killpg(p.pid, signal.SIGHUP)
        _, err = p.communicate(timeout=HANG)
        wait_until_ended(fds, "processes of the command still running {HANG} s after it exited")
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


def stopped(args: list, out: Path, how: str, **kwargs) -> list[Path]:
    """Start the evaluation ``args`` (writing to ``out``), signal it once a unit is finished
    (:func:`signal_and_check`) and return the unit files it kept."""
    p = start(args, **kwargs)
    wait_for(p, lambda: units(out), "a finished unit")
    signal_and_check(p, how, out)
    return units(out)


def resumed(args: list, out: Path, kept: list[Path]) -> dict:
    """Run the same command to the end: the units the interrupted run finished are reused, not redone
    (their files are not written again)."""
    assert kept
    before = {u: (u.stat().st_ino, u.stat().st_mtime_ns) for u in kept}
    p = subprocess.run([*PCREG, *map(str, args)], capture_output=True, text=True, timeout=HANG)
    assert p.returncode == 0, p.stderr
    assert {u: (u.stat().st_ino, u.stat().st_mtime_ns) for u in kept} == before
    return json.loads((out / "results.json").read_text())
