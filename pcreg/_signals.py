"""Ctrl-C, SIGTERM and SIGHUP in a pcreg command: the handler that turns them into KeyboardInterrupt, the checks that
raise it again where it was swallowed, and the watchdog that ends a stop that does not end by itself.

Signal handlers are the process's: what they note is held at module level, one per process. Used by the
command line (:mod:`pcreg.cli`) and by the runner of evaluation units (:mod:`pcreg._runner`).
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Any, Iterator

#: Termination signals received since :func:`interrupt_on_signals` (cleared by each call).
_RECEIVED: list[int] = []
#: > 0 while workers are being stopped: a signal then is noted, not raised, so the clean-up completes.
_SHIELDED = [0]


#: Seconds a stopping command has, from its first SIGINT or SIGTERM, to end by itself (finished units
#: kept, exit 130); past them the process is ended with exit 130 all the same, so that a stop never waits
#: without end, wherever the signal landed (a lock or a thread left waiting for work that will not come).
STOP_GRACE_SECONDS = 60.0
#: The running watchdog's ``(process id, pipe's write end)`` (:func:`_start_watchdog`; put away by
#: :func:`restore_signals`).
_WATCHDOG: list = []


def _start_watchdog() -> None:
    """A daemon thread that, once armed by the first signal (:func:`_arm_watchdog`), ends the process with
    exit 130 if :data:`STOP_GRACE_SECONDS` pass without :func:`restore_signals` or the process's own exit.

    It is started here, before any signal, and armed through a pipe: a signal handler runs wherever the main
    thread was, possibly inside ``threading``'s own bookkeeping of a thread being started, so the handler
    itself starts no thread and takes no lock; it writes one byte."""
    import os
    import select
    import threading

    read_end, write_end = os.pipe()

    def watch() -> None:
        try:
            if os.read(read_end, 1) != b"a":  # put away (or the write end closed) before any signal
                return
            ready, _, _ = select.select([read_end], [], [], STOP_GRACE_SECONDS)
            if not ready:
                # any command's last word: a run keeps its frames, an evaluation its units, a one-shot nothing
                sys.stderr.write(f"pcreg: interrupted; still stopping after {STOP_GRACE_SECONDS:g} s, so ended now "
                                 "(what was finished is kept)\n")
                sys.stderr.flush()
                os._exit(130)
        finally:
            os.close(read_end)

    threading.Thread(target=watch, name="pcreg-stop-watchdog", daemon=True).start()
    _WATCHDOG.append((os.getpid(), write_end))


def _arm_watchdog() -> None:
    """After the first signal: start the watchdog's grace (a byte down its pipe; in a forked child, which
    inherited the pipe but not the thread, nothing)."""
    import os

    for pid, write_end in list(_WATCHDOG):
        if pid == os.getpid():
            try:
                os.write(write_end, b"a")
            except OSError:  # put away meanwhile
                pass


def _put_watchdog_away() -> None:
    """Stand the watchdog down (a byte it reads as the end; then the pipe's write end closed)."""
    import os

    while _WATCHDOG:
        pid, write_end = _WATCHDOG.pop()
        if pid == os.getpid():
            try:
                os.write(write_end, b"c")
            except OSError:
                pass
        os.close(write_end)


def _on_signal(signum, frame) -> None:
    _RECEIVED.append(signum)
    if len(_RECEIVED) == 1:
        _arm_watchdog()
    if not _SHIELDED[0]:
        raise KeyboardInterrupt


#: The ``sys.unraisablehook`` :func:`interrupt_on_signals` replaced (put back by :func:`restore_signals`).
_UNRAISABLE: list = []


def _unraisable(unraisable) -> None:
    """Python prints an exception it cannot raise (in a finalizer, a weakref callback of the garbage collector,
    an ``os.fork`` hook); a signal's KeyboardInterrupt raised there is noted, and raised again later, not printed."""
    if not (_RECEIVED and issubclass(unraisable.exc_type, KeyboardInterrupt)):
        (_UNRAISABLE[-1] if _UNRAISABLE else sys.__unraisablehook__)(unraisable)


def interrupt_on_signals() -> dict:
    """SIGINT (Ctrl-C), SIGTERM and SIGHUP (the terminal or ssh session closed; not where the process started with
    it ignored, as ``nohup`` starts it) raise KeyboardInterrupt in the main thread; returns the handlers they
    replace (for :func:`restore_signals`). Call it from the main thread.

    SIGINT is handled even when this process started with it ignored: a shell without job control (a
    script's ``pcreg ... &``) starts its background commands so, and Python then leaves it ignored.
    The KeyboardInterrupt is raised wherever the main thread is, and a few places swallow it (an
    ``os.fork`` hook, run while the pool starts a worker, a finalizer: Python can only print it, and
    :func:`_unraisable` keeps that off stderr): :func:`check_interrupted`, called between units and while
    waiting for them, raises it again.
    """
    import signal

    _RECEIVED.clear()
    _put_watchdog_away()  # one started by an earlier command in this process, and never put back
    _SHIELDED[0] = 0
    previous: dict = {}
    hangup = [] if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN else [signal.SIGHUP]  # nohup's ignore kept
    for signum in (signal.SIGINT, signal.SIGTERM, *hangup):
        try:
            previous[signum] = signal.signal(signum, _on_signal)
        except (ValueError, OSError):  # not the main thread
            pass
    if previous:
        _start_watchdog()
        if sys.unraisablehook is not _unraisable:
            _UNRAISABLE.append(sys.unraisablehook)
            sys.unraisablehook = _unraisable
    return previous


def restore_signals(previous: dict) -> None:
    """Put back the handlers :func:`interrupt_on_signals` replaced, and forget the signals received."""
    import signal

    _RECEIVED.clear()
    _put_watchdog_away()
    hook = _UNRAISABLE.pop() if _UNRAISABLE else None
    if hook is not None and sys.unraisablehook is _unraisable:
        sys.unraisablehook = hook
    for signum, handler in previous.items():
        try:
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
        except (ValueError, OSError, TypeError):
            pass


def ignore_signals() -> None:
    """Ignore SIGINT, SIGTERM and SIGHUP from now on: a program that is already stopping on one (exit 130) must
    not be killed by a second one (a terminal's Ctrl-C pressed twice, a signal sent to the whole process
    group) while Python shuts down, which would end it with the signal instead of its exit code; nor one whose
    command has ended, or has committed its one output and only says so (``pcreg export``, ``view --overlay``):
    interrupted there, it would say that nothing was written, or (its handlers put back to the default once Python
    has flushed its output at exit) be killed without a word. Python's shutdown keeps an ignored signal ignored."""
    import signal

    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        try:
            signal.signal(signum, signal.SIG_IGN)
        except (ValueError, OSError):  # not the main thread
            pass


def forget_stray_interrupt() -> None:
    """Clear CPython's note of a KeyboardInterrupt that escaped an ``exec``/``eval`` of a string.

    When Ctrl-C lands while such code runs (a dataclass or namedtuple being made during a lazy import,
    generated code), CPython notes it, and ``python -m pcreg.cli`` then ends by SIGINT at exit even
    though the command handled the interrupt and exits 130. Evaluating a string resets that note.
    """
    exec("None")  # noqa: S102 - a constant: its only effect is the reset


def handles_signals() -> bool:
    """Whether SIGINT raises through :func:`interrupt_on_signals`' handler (the command line), so that
    :func:`interrupted` tells a real interrupt from a KeyboardInterrupt raised by other code."""
    import signal

    return signal.getsignal(signal.SIGINT) is _on_signal


def interrupted() -> bool:
    """Whether a SIGINT, SIGTERM or SIGHUP arrived since :func:`interrupt_on_signals`."""
    return bool(_RECEIVED)


def check_interrupted() -> None:
    """Raise KeyboardInterrupt if a termination signal arrived (its first KeyboardInterrupt may have been
    swallowed); a no-op outside the command line, where no handler is installed."""
    if _RECEIVED and not _SHIELDED[0]:
        raise KeyboardInterrupt


@contextmanager
def _shielded() -> Iterator[None]:
    _SHIELDED[0] += 1
    try:
        yield
    finally:
        _SHIELDED[0] -= 1


def parent_death_signal() -> Any:
    """The C library's ``prctl`` where Linux can send a process a signal when its parent ends
    (``PR_SET_PDEATHSIG``), None elsewhere: looked up before a fork, so that :func:`end_with_parent` in the child
    needs no lookup (between fork and exec nothing may take a lock)."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # pragma: no cover - every Linux C library has prctl
        return None


def end_with_parent(prctl: Any, parent: int, signum: int) -> None:
    """In a child process: have the system send it ``signum`` when its parent ends, however the parent ends (a
    SIGKILL or the out-of-memory killer lets it stop nothing itself), and exit at once if ``parent`` (the
    parent's process id, taken before the fork) ended before the request was made. ``prctl``:
    :func:`parent_death_signal`'s (None: nothing is done). The system ties the request to the thread that
    forked the child, so the parent's side forks from a thread that lives as long as it needs the child."""
    pr_set_pdeathsig = 1
    if prctl is None or prctl(pr_set_pdeathsig, int(signum), 0, 0, 0) != 0:
        return
    if os.getppid() != parent:
        os._exit(1)
