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
from typing import Callable

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
