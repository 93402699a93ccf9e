"""One helper thread per process, for work that splits in two or runs beside the main thread.

The streaming step (:meth:`pcreg.Propagator.step`) is one frame's work on a robot's computer, which
has more than one core; OpenCV's DIS optical flow, what the step competes with, uses them all. On the
helper pcreg runs

- half of each windowed correspondence search (:func:`pcreg.registration.dense.match_window`: every
  other block of samples) and of the fused labels (every other block of rows);
- one of the grid's two conjugate-gradient solves (its x and y columns are independent systems);
- the finer pyramid levels' matching problems, while the main thread works on the coarser ones;
- the full-size field, while the main thread measures the registration's evidence;
- the new frame's classification, while the main thread registers it.

The work is the same and each item is computed by the same code whichever thread runs it, so the
results are the same, to the bit, with or without the helper.

- **Only compiled code that releases the GIL, or numpy and OpenCV, runs on it**, and never a numba
  ``parallel=True`` kernel: numba's ``workqueue`` threading layer, pcreg's where OpenMP cannot be
  loaded (:mod:`pcreg.registration.nn`), is not thread-safe.
- **One per process.** A ``--workers`` pool forks its workers; a forked child has no thread behind
  its parent's executor (work handed to it would wait for ever), so a child makes its own. A pool's
  workers use it only where the CPUs leave two to each worker (:func:`set_enabled`); ``PCREG_HELPER_THREAD=0``
  in the environment turns it off.
- **Nobody waits for a busy helper.** Work offered to it that it has not started when the caller
  wants it is done by the caller (:func:`beside`, :func:`interleave`), so the helper only ever takes
  work off the main thread.
- **It is idle between calls** (a ``ThreadPoolExecutor`` of one thread, joined at the interpreter's
  exit), and an interrupt in the main thread leaves it to finish what it holds, milliseconds.
- **Its state is the process's**, held at module level for that reason: the executor, its lock and
  whether it is enabled (``_STATE``), the machine's last CPU-time reading that :func:`others_busy`
  measures from (``_OTHERS``) and the mark of the helper thread itself. None of it is a cache of data;
  a forked child starts it afresh.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, TypeVar

__all__ = ["MIN_PIXELS", "alongside", "beside", "both", "close", "enabled", "helper", "interleave", "others_busy", "set_enabled",
           "usable_cpus", "wait_quietly"]

S = TypeVar("S")
T = TypeVar("T")

#: Set to 0 in the environment, pcreg uses no helper thread (one CPU a process, as in a pool of workers).
ENVIRONMENT = "PCREG_HELPER_THREAD"
#: The values of :data:`ENVIRONMENT` that turn the helper off, and those that leave it on (unset is on), case aside.
OFF, ON = ("0", "false", "off", "no"), ("1", "true", "on", "yes", "")


def wanted(value: str | None) -> bool | None:
    """Whether :data:`ENVIRONMENT` set to ``value`` (None: unset) leaves the helper thread on; None for a value it does
    not take (the command line refuses it before any work: :func:`pcreg._workers.environment_problem`)."""
    if value is None:
        return True
    word = value.strip().lower()
    return False if word in OFF else True if word in ON else None

#: From this many pixels a per-pixel pass (the full-size field, the stream's fusion) shares its rows with
#: the helper: at a few nanoseconds a pixel, 65,536 pixels are a few hundred microseconds of work, well
#: above the tens of microseconds that handing a share over costs.
MIN_PIXELS = 1 << 16

_LOCK = threading.Lock()
_STATE: dict = {"pool": None, "enabled": wanted(os.environ.get(ENVIRONMENT)) is not False}


def _forget_after_fork() -> None:
    """In a forked child: its parent's executor has no thread here (work handed to it would wait for
    ever) and the lock may have been held by a parent's thread at the fork; start afresh. The parent's
    last reading of the machine's CPU time is not the child's either (:func:`others_busy`)."""
    global _LOCK, _OTHERS_LOCK
    _LOCK = threading.Lock()
    _STATE["pool"] = None
    _OTHERS_LOCK = threading.Lock()
    _OTHERS.update(at=None, value=None)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_after_fork)


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity; ``os.cpu_count`` where there is none)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: :func:`others_busy` reads the machine's CPU time at most this often (seconds), and measures over the
#: time since its last reading.
OTHERS_INTERVAL = 0.25
_CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
_OTHERS_LOCK = threading.Lock()
_OTHERS: dict = {"at": None, "busy": 0.0, "own": 0.0, "value": None}


def _machine_busy_seconds() -> float | None:
    """CPU seconds the whole machine has been busy since it started: every state of ``/proc/stat``'s
    ``cpu`` line but idle and I/O wait (time a hypervisor stole counts as busy); None where there is no
    such file."""
    try:
        with open("/proc/stat", "rb") as f:
            ticks = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    if len(ticks) < 8:
        return None
    return (sum(ticks) - ticks[3] - ticks[4]) / _CLOCK_TICKS


def others_busy() -> float | None:
    """CPUs that the rest of the machine (every process but this one) kept busy, on average since the
    last reading (:data:`OTHERS_INTERVAL` or more ago): the machine's busy CPU time less this process's
    own. None until a second reading, and where the machine's CPU time is not known.

    Unlike the load average, this process's own threads do not count: a process that has just run two
    threads (its own, or a library's such as Open3D's) pushes its own load average towards 2, and a test
    of the load would then keep it on one thread on an otherwise idle machine."""
    now = time.monotonic()
    with _OTHERS_LOCK:
        at = _OTHERS["at"]
        if at is not None and now - at < OTHERS_INTERVAL:
            return _OTHERS["value"]
        busy = _machine_busy_seconds()
        if busy is None:
            return None
        own = time.process_time()
        if at is not None:
            _OTHERS["value"] = max(0.0, ((busy - _OTHERS["busy"]) - (own - _OTHERS["own"])) / (now - at))
        _OTHERS.update(at=now, busy=busy, own=own)
        return _OTHERS["value"]


def set_enabled(on: bool) -> None:
    """Allow (True, the default) or forbid the helper thread in this process."""
    _STATE["enabled"] = bool(on)


def enabled() -> bool:
    """Whether work may go to the helper: allowed, and this process may use two CPUs or more."""
    return bool(_STATE["enabled"]) and usable_cpus() >= 2


#: Marks the helper thread itself (set by its executor's initializer).
_ON_HELPER = threading.local()


def _mark_helper() -> None:
    _ON_HELPER.value = True
    _STATE["thread"] = threading.current_thread()


def helper() -> ThreadPoolExecutor | None:
    """This process's helper (made on first use), or None when :func:`enabled` says no or when called
    on the helper itself: work offered there to itself could only be taken back by it (:func:`beside`,
    :func:`interleave` then run it in place, whole)."""
    if not enabled() or getattr(_ON_HELPER, "value", False):
        return None
    with _LOCK:
        if _STATE["pool"] is None:
            _STATE["pool"] = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcreg-helper",
                                                initializer=_mark_helper)
        return _STATE["pool"]


def close(timeout: float | None = None) -> bool:
    """Let the helper finish what it holds and end it (a later use makes a new one). Commands call it
    before they return, interrupted or not, so that no helper thread is alive when the interpreter
    shuts down, whatever the order of the interpreter's own exit hooks. ``timeout``: wait at most so long
    (an interrupt can land while the main thread holds a lock the helper waits on, numba's while it loads
    a compiled kernel, and the helper would wait for ever); returns whether the helper ended."""
    with _LOCK:
        pool, _STATE["pool"] = _STATE["pool"], None
        thread, _STATE["thread"] = _STATE.get("thread"), None
    if pool is None:
        return True
    if timeout is None:
        pool.shutdown(wait=True, cancel_futures=True)
        return True
    pool.shutdown(wait=False, cancel_futures=True)
    if thread is not None:
        thread.join(timeout)
        return not thread.is_alive()
    return True


def _claim() -> Callable[[], bool]:
    """A one-time claim: the first call returns True, every later one False (from any thread)."""
    lock = threading.Lock()
    taken = [False]

    def take() -> bool:
        with lock:
            free, taken[0] = not taken[0], True
            return free

    return take


def beside(fn: Callable[[], T]) -> Callable[[], T]:
    """Offer ``fn()`` to the helper and return a function that gives its result (or raises its
    exception): it waits for the helper, or runs ``fn`` itself when the helper has not started it
    (busy with earlier work) or is disabled. ``fn`` runs once either way."""
    pool = helper()
    if pool is None:
        return fn
    take = _claim()
    future: Future = pool.submit(lambda: fn() if take() else None)

    def result() -> T:
        return fn() if take() else future.result()

    return result


def both(side: Callable[[], S], here: Callable[[], T]) -> tuple[S, T]:
    """``(side(), here())``, ``side`` offered to the helper (:func:`beside`) while this thread runs
    ``here``. When ``here`` raises, ``side`` ends first (:func:`wait_quietly`), then the error goes on."""
    later = beside(side)
    try:
        mine = here()
    except BaseException:
        wait_quietly(later)
        raise
    return later(), mine


def alongside(here: Callable[[], T], *sides: Callable[[], object]) -> tuple[T, list]:
    """``(here(), [side() for side in sides])``: the ``sides`` offered to the helper in their order
    (:func:`beside`) while this thread runs ``here``; then this thread takes their results from the last
    offered, so that it runs itself those the helper has not reached (the helper takes them in order). When
    anything raises, every side offered ends first (:func:`wait_quietly`), then the error goes on."""
    laters = [beside(side) for side in sides]
    try:
        mine = here()
        results = [later() for later in reversed(laters)]
    except BaseException:
        for later in laters:
            wait_quietly(later)
        raise
    return mine, results[::-1]


def wait_quietly(result: Callable[[], object]) -> None:
    """Wait for work offered with :func:`beside` whose result is no longer wanted, because an error is on
    its way: the helper's work ends before the error goes on, and an error of its own is dropped (the
    one under way is the one to report)."""
    try:
        result()
    except Exception:  # noqa: BLE001 - the error under way is the one to report
        pass


def interleave(n: int, fn: Callable[[int, int], object], *, min_items: int) -> None:
    """``fn(first, stride)`` over ``n`` items in two shares, ``fn(0, 2)`` and ``fn(1, 2)``, the first
    offered to the helper and the second run here, when ``n >= min_items`` and the helper is enabled;
    else ``fn(0, 1)`` here. ``fn`` takes the blocks ``first, first + stride, ...`` of its items and writes
    each item's output in its own row, so who runs a share does not change what it writes. A helper
    still busy with earlier work when this thread has done its share leaves the other share to this
    thread too. An exception of either share is raised here."""
    pool = helper() if n >= min_items else None
    if pool is None:
        fn(0, 1)
        return
    take = _claim()
    future = pool.submit(lambda: fn(0, 2) if take() else None)
    try:
        fn(1, 2)
    except BaseException:
        if not take():
            future.exception()  # the helper's share ends first (it writes into the caller's arrays)
        raise
    if take():
        fn(0, 2)  # the helper has not started it: this thread is free now
    else:
        future.result()
