"""Waiting for events in tests: a condition polled until it holds, never a fixed pause.

``until(check, what=..., alive=...)`` looks at ``check()`` every :data:`POLL` s; between looks it
waits on the process or thread the event depends on (so that its early end is noticed at once) and
fails when that one ends first. :data:`HANG` bounds every wait: only a hung program reaches it, and
no test asserts on how long anything took.
"""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path
from typing import Callable, NamedTuple

HANG = 300.0  # s
POLL = 0.05  # s


class Ended(AssertionError):
    """What the test waited for did not happen: the program it depends on ended first."""


def until(check: Callable[[], object], *, what: str, alive: subprocess.Popen | threading.Thread | None = None,
          bound: float = HANG):
    """Return ``check()``'s first true value; raise :class:`Ended` if ``alive`` ends first, and
    AssertionError after ``bound`` s."""
    for _ in range(int(bound / POLL) + 1):
        value = check()
        if value:
            return value
        if isinstance(alive, subprocess.Popen):
            try:
                alive.wait(timeout=POLL)
            except subprocess.TimeoutExpired:
                continue
            if check():
                return check()
            raise Ended(f"the program ended (exit {alive.returncode}) before {what}")
        if isinstance(alive, threading.Thread):
            alive.join(timeout=POLL)
            if not alive.is_alive():
                value = check()
                if value:
                    return value
                raise Ended(f"the thread ended before {what}")
            continue
        time.sleep(POLL)  # nothing to wait on: look again shortly
    raise AssertionError(f"no {what} within {bound:g} s (hung?)")


class Process(NamedTuple):
    """A live process as ``/proc/PID/stat`` shows it."""

    pid: int
    state: str  # R, S, Z, ...
    ppid: int
    pgrp: int


def processes() -> list[Process]:
    """Every process of this machine that ``/proc`` lists (those ending meanwhile are passed over)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, pgrp, ...
        found.append(Process(int(entry.name), fields[0], int(fields[1]), int(fields[2])))
    return found
