"""Interrupting a command in a chosen phase, in this process, without waiting on time.

The command runs through ``pcreg.cli.main`` in the test's own (main) thread, so its signal handlers are
the real ones. A phase is entered by calling a function of pcreg; :func:`signal_at` wraps that function
so that its first call, in whichever process runs it, sends SIGINT to the command (the process itself,
or its parent when a worker of ``--workers N`` runs the phase) and then goes on as usual: the command
gets the signal while it is in the phase, exactly as from a Ctrl-C at that moment. A file created with
``O_EXCL`` makes the signal go once across processes.
"""

from __future__ import annotations

import functools
import json
import multiprocessing
import os
import signal
from pathlib import Path

import pytest


def signal_at(monkeypatch: pytest.MonkeyPatch, owner: object, name: str, flag: Path, *, after: bool = False) -> None:
    """Replace ``owner.name`` by a wrapper that sends SIGINT to the command once, before the real call
    (``after``: once the real call has returned, e.g. when a unit has been saved)."""
    real = getattr(owner, name)

    def fire() -> None:
        try:
            os.close(os.open(flag, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return
        target = os.getpid() if multiprocessing.parent_process() is None else os.getppid()
        os.kill(target, signal.SIGINT)

    @functools.wraps(real)
    def wrapper(*args, **kwargs):
        if not after:
            fire()
        result = real(*args, **kwargs)
        if after:
            fire()
        return result

    monkeypatch.setattr(owner, name, wrapper)


def live_children() -> dict[int, str]:
    """pid -> state of this process's children that have not exited (zombies aside)."""
    from _events import processes

    me = os.getpid()
    return {p.pid: p.state for p in processes() if p.ppid == me and p.state != "Z"}


def interrupted_line(err: str) -> None:
    """The command said one line, that it was interrupted (progress bars aside)."""
    said = [part.strip() for line in err.splitlines() for part in line.split("\r")]
    said = [line for line in said if line and "%|" not in line]
    assert len(said) == 1 and said[0].startswith("pcreg: interrupted"), err


def results_without_times(out: Path) -> dict:
    """``results.json`` without run times, resume counts and the units' own timings."""

    def strip(obj):
        if isinstance(obj, dict):
            return {k: strip(v) for k, v in obj.items()
                    if not any(w in k for w in ("second", "time", "ms_per")) and k != "resumed_units"}
        if isinstance(obj, list):
            return [strip(v) for v in obj]
        return obj

    return strip(json.loads((out / "results.json").read_text()))


def unit_files(out: Path) -> dict[Path, tuple[int, int]]:
    """Each finished unit's file -> (inode, mtime): a resumed run reuses them without writing them again."""
    return {u: (u.stat().st_ino, u.stat().st_mtime_ns) for u in sorted(out.glob("units/**/*.json"))}
