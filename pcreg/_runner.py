"""Running many independent evaluation units: executors and progress bars.

Units are pure functions of their config. ``--workers N`` uses a local
``ProcessPoolExecutor``; ``--scheduler ADDRESS`` uses a ``dask.distributed``
client's executor, so the same code scales to a cluster (dask is optional and
imported only then). Results come back to the parent, which merges and writes them.
"""

from __future__ import annotations

import logging
import sys
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager, nullcontext, suppress
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Sequence

from ._signals import (  # re-exported: the command line, the units and tests import them from here
    _RECEIVED as _RECEIVED,
    _SHIELDED as _SHIELDED,
    _UNRAISABLE as _UNRAISABLE,
    _WATCHDOG as _WATCHDOG,
    STOP_GRACE_SECONDS as STOP_GRACE_SECONDS,
    _arm_watchdog as _arm_watchdog,
    _on_signal as _on_signal,
    _put_watchdog_away as _put_watchdog_away,
    _shielded as _shielded,
    _start_watchdog as _start_watchdog,
    _unraisable as _unraisable,
    check_interrupted as check_interrupted,
    forget_stray_interrupt as forget_stray_interrupt,
    handles_signals as handles_signals,
    ignore_signals as ignore_signals,
    interrupt_on_signals as interrupt_on_signals,
    interrupted as interrupted,
    restore_signals as restore_signals,
)

if TYPE_CHECKING:
    from ._progress import Tally


class InlineExecutor(Executor):
    """Runs each call at submit time, in this process (``--workers 1``): easiest to debug and profile."""

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> Future:
        check_interrupted()
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        # KeyboardInterrupt (Ctrl-C, SIGTERM) propagates at once: the units not started are not run
        return fut


def _worker_init(workers: int = 1, parent: int | None = None, steps: Any = None) -> None:
    """In a local worker process of a pool of ``workers``: the parent handles Ctrl-C and a closed terminal (the
    terminal sends SIGINT or SIGHUP to the whole process group) and stops the workers itself; SIGTERM ends a worker at once, and so
    does the end of ``parent`` (its process id), however it ended (:func:`~pcreg._signals.end_with_parent`). The
    helper thread (:mod:`pcreg._threads`) is used only where the CPUs leave two to each worker: the
    pool already gives the others theirs. ``steps``: the pool's pipe of the units' progress
    (:mod:`pcreg._progress`) to the parent."""
    import signal

    from . import _progress, _signals, _threads

    if steps is not None:
        _progress.tell_through(steps.put)

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a closed terminal's, sent to the group too: the parent stops them
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if parent is not None:
        _signals.end_with_parent(_signals.parent_death_signal(), parent, signal.SIGKILL)
    _threads.set_enabled(_threads.usable_cpus() >= 2 * workers)


def _how_workers_ended(pool: ProcessPoolExecutor) -> str:
    """``" (killed by SIGKILL: ...)"``: how the pool's dead worker processes ended, as far as it is known (their
    exit codes, when the pool has not yet reaped them)."""
    import signal

    # A worker's end is seen by its pipe closing, before the system has made it a zombie whose exit code can be
    # read; the pool's manager thread then ends the others and waits for every worker, so once it is done each
    # exit code is known (read earlier, a loaded machine gave the others' SIGTERM alone, without the SIGKILL).
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None and manager.is_alive():
        manager.join(timeout=5)
    codes = sorted({p.exitcode for p in (getattr(pool, "_processes", None) or {}).values()
                    if p.exitcode not in (None, 0)})
    if not codes:  # the pool may have reaped them before this reads them
        return " (by a signal or a crash: the system's out-of-memory killer ends processes so)"
    if -signal.SIGKILL in codes:
        return " (killed by SIGKILL: the system's out-of-memory killer ends processes so)"
    return f" ({', '.join(_ending(c) for c in codes)})"


def _ending(code: int) -> str:
    """A process's exit code as said: ``SIGTERM`` (a signal, negative), ``SIGRTMIN+6`` (a real-time signal, which
    :class:`signal.Signals` does not name), ``exit code 3``."""
    import signal

    if code >= 0:
        return f"exit code {code}"
    try:
        return signal.Signals(-code).name
    except ValueError:
        low = getattr(signal, "SIGRTMIN", None)
        return f"SIGRTMIN+{-code - low}" if low is not None and low <= -code <= signal.SIGRTMAX else f"signal {-code}"


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel pending units and end the worker processes now (``shutdown(wait=True)`` would wait for
    the running units to finish, which can take minutes). A second Ctrl-C meanwhile does not cut it short."""
    with _shielded():
        _terminate_workers(pool)


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets it
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        try:
            proc.terminate()
        except (OSError, ValueError, AttributeError):
            pass
    for proc in processes:
        try:
            proc.join(timeout=3)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=2)
        except (OSError, ValueError, AssertionError, AttributeError):
            pass
    # Let the pool's manager thread see its workers gone and close its wake-up pipe now. CPython 3.11's
    # exit hook (concurrent.futures.process._python_exit) writes to that pipe without the pool's lock; a
    # close racing with it printed "Exception ignored ... Bad file descriptor" after "interrupted".
    if manager is not None and manager.is_alive():
        manager.join(timeout=5)


def _check_scheduler_address(scheduler: str) -> None:
    """Refuse a dask scheduler address that cannot be one (no port, a port outside 1-65535, a scheme dask does not
    speak) before a client is made: a client refused while it is made still waits for its own close at exit
    (60 s), and one given a port past 65535 waited dask's whole connect time (30 s) to say it timed out."""
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import backends

    from .errors import PcregError

    def refuse(why: str) -> PcregError:
        return PcregError(f"--scheduler {scheduler!r} is not a dask scheduler address (tcp://HOST:PORT): {why}")

    try:
        protocol, location = parse_address(scheduler)
        host, port = parse_host_port(location) if protocol in ("tcp", "tls") else ("-", 1)
        port = int(port)
    except (ValueError, TypeError) as exc:
        raise refuse(str(exc)) from None
    if not str(host).strip("[] "):  # tcp://:8786 waited the connect time, then blamed the network
        raise refuse("no host")
    if protocol not in backends:
        raise refuse(f"dask speaks {', '.join(f'{b}://' for b in sorted(backends))}, not {protocol}://")
    if not 1 <= port <= 65535:
        raise refuse(f"its port {port} is not in 1-65535")


def _connect_timeout() -> float:
    """Seconds a connection to the scheduler may take: dask's ``distributed.comm.timeouts.connect`` (30 s)."""
    import dask
    from dask.utils import parse_timedelta

    return float(parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), default="seconds"))


def _probe_scheduler(scheduler: str, timeout: float) -> None:
    """Ask ``scheduler`` who it is, on a connection of its own, within ``timeout`` seconds (and a few more for
    the reply), before a client is made: a client that fails while it is made waits 60 s more for its own
    close at exit, a server that is not a dask scheduler (an HTTP server, a proxy) can leave dask's handshake
    waiting without end or reading its reply as a message gigabytes long, and the client retries a refused
    connection until the timeout. Raises :class:`~pcreg.errors.PcregError` naming the address."""
    import asyncio
    import threading

    from .errors import PcregError

    async def ask() -> Any:
        from distributed.comm import connect
        from distributed.security import Security

        # with dask's TLS settings (distributed.comm.tls), as the client connects: tls:// and wss:// need them
        comm = await connect(scheduler, timeout=timeout, **Security().get_connection_args("client"))
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    answer: list = []

    def run() -> None:
        try:
            answer.append(asyncio.run(asyncio.wait_for(ask(), timeout + 5)))
        except BaseException as exc:  # noqa: BLE001 - whatever the far end made of it, reported below
            answer.append(exc)

    probe = threading.Thread(target=run, name="pcreg-scheduler-probe", daemon=True)
    probe.start()
    deadline = timeout + 10  # asyncio's own deadline, and a margin should the loop not honour it
    while probe.is_alive() and deadline > 0:
        probe.join(0.25)
        deadline -= 0.25
        check_interrupted()
    got = answer[0] if answer else TimeoutError()
    if isinstance(got, dict) and got.get("type") == "Scheduler":
        return
    scheme = scheduler.split("://")[0] if "://" in scheduler else "tcp"
    if isinstance(got, OSError) and "Timed out trying to connect" in str(got):
        listens = _listens(scheduler)
        why = ("connection refused: nothing listens at that port" if listens is False else
               f"something listens at that port but did not answer {scheme}://: a dask scheduler speaks the one "
               "protocol it was started with (tcp:// unless `dask scheduler --protocol`); is the scheme right?"
               if listens and scheme != "tcp" else "the host is unreachable, or a firewall drops the connection")
        raise PcregError(f"cannot connect to the dask scheduler {scheduler!r} within {timeout:g} s: {why} "
                         "(dask's distributed.comm.timeouts.connect sets the wait)")
    if isinstance(got, BaseException) and not isinstance(got, Exception):
        raise got  # KeyboardInterrupt
    if isinstance(got, Exception) and "ssl_context" in str(got):  # dask's words for tls:// or wss:// without its settings
        raise PcregError(f"--scheduler {scheduler!r}: {scheme}:// needs dask's TLS settings (distributed.comm.tls: "
                         "ca-file, and client cert and key), and none are set here")
    what = ("no reply to its greeting" if isinstance(got, (TimeoutError, asyncio.TimeoutError)) else
            type(got).__name__ if isinstance(got, BaseException) else "an answer of another kind")
    raise PcregError(f"{scheduler!r} answered, but not as a dask scheduler ({what}): is it the address a "
                     "`dask scheduler` printed?")


def _listens(scheduler: str) -> bool | None:
    """Whether something listens at ``scheduler``'s host and port: False when a connection is refused at once, True
    when one plain TCP connection is taken (the last of dask's attempts, cut short by its deadline, may say only that
    it timed out), None when neither is known (no answer within 2 s)."""
    import socket

    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        host, port = parse_host_port(parse_address(scheduler)[1])
        socket.create_connection((host, port), timeout=2).close()
    except ConnectionRefusedError:
        return False
    except (OSError, ValueError, TypeError):
        return None
    return True


def _quiet_dask_logs() -> Callable[[], None]:
    """Keep dask.distributed's own log records below CRITICAL off stderr; returns what puts them back."""
    names = ["distributed"] + [n for n in logging.root.manager.loggerDict if n.startswith("distributed.")]
    levels = {n: logging.getLogger(n).level for n in names}  # dask's configuration sets some of its own
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL)

    def restore() -> None:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)

    return restore


#: Seconds a ``--scheduler`` run goes on with no worker on the cluster, or without its scheduler, before it
#: stops (exit 2, finished units kept): dask would keep the units waiting for a worker without end.
NO_WORKER_SECONDS = 60.0


class _ClusterExecutor(Executor):
    """A dask client's executor, and :meth:`check`: whether the cluster can still run the units."""

    #: Its units run in other working folders, on other machines: they are given absolute paths
    #: (:func:`pcreg.experiments.units.for_workers`).
    remote = True

    def __init__(self, client: Any, scheduler: str) -> None:
        self._client, self._scheduler = client, scheduler
        self._executor = client.get_executor()
        self._idle_since: float | None = None

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> Future:
        from ._workers import submit_checked  # each unit checks its worker first: one that joined late is not asked

        return submit_checked(self._executor.submit, fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._executor.shutdown(wait=wait)

    def check(self) -> None:
        """Raise :class:`~pcreg.errors.PcregError` once the scheduler has been out of reach, or without a
        worker, for :data:`NO_WORKER_SECONDS` (from the client's own view, refreshed every 2 s)."""
        import time

        from .errors import PcregError

        if not hasattr(self._client, "_scheduler_identity"):  # the client's view as dask keeps it: unknown here
            return
        connected = getattr(self._client, "status", "running") == "running"
        identity = self._client._scheduler_identity or {}
        workers = identity.get("n_workers", len(identity.get("workers") or {}))
        if connected and workers:
            self._idle_since = None
            return
        now = time.monotonic()
        if self._idle_since is None:
            self._idle_since = now
        elif now - self._idle_since > NO_WORKER_SECONDS:
            what = ("has had no worker" if connected else "has been out of reach")
            raise PcregError(f"the dask scheduler {self._scheduler!r} {what} for {NO_WORKER_SECONDS:g} s: the finished "
                             f"units are kept; start {'workers' if connected else 'it'} and rerun the same command "
                             "to resume")


def check_workers(workers: int) -> None:
    """Refuse ``--workers`` above 4x the CPUs this process may use: each worker holds its own copy of the data
    and libraries (:func:`make_executor` refuses it too; a command that writes before it starts workers calls this
    first)."""
    import os

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if workers > 4 * cpus:
        from .errors import PcregError

        raise PcregError(f"--workers {workers} is more than 4x the {cpus} CPUs here: give {4 * cpus} or fewer "
                         "(each worker holds its own copy of the data and libraries)")


#: The environment variable naming the file through which a command's processes (its own and its workers') say
#: once among them that they compile pcreg's kernels (:data:`pcreg._jit.COMPILING`): the first to say it creates
#: the file. Read by :mod:`pcreg._jit`, which this module does not load (a pool's parent may need no kernel).
COMPILING_NOTE = "_PCREG_COMPILING_NOTE"


@contextmanager
def one_compiling_note() -> Iterator[None]:
    """While it lasts, this process and the processes it starts say :data:`pcreg._jit.COMPILING` once among them
    (:data:`COMPILING_NOTE`; within an enclosing one, that one's); the file, if said, removed at its end."""
    import os
    import tempfile
    import uuid

    try:
        folder = tempfile.gettempdir()
    except OSError:  # no writable temporary folder: each process says it, as alone
        folder = None
    if os.environ.get(COMPILING_NOTE) or folder is None:
        yield
        return
    path = os.path.join(folder, f"pcreg-compiling-{os.getpid()}-{uuid.uuid4().hex}")
    os.environ[COMPILING_NOTE] = path
    try:
        yield
    finally:
        os.environ.pop(COMPILING_NOTE, None)
        with suppress(OSError):
            os.unlink(path)


@contextmanager
def make_executor(workers: int = 1, *, scheduler: str | None = None) -> Iterator[Executor]:
    """An executor for ``workers`` local processes, or for a dask.distributed scheduler address.

    On an exception (Ctrl-C, SIGTERM turned into KeyboardInterrupt by the command line, an error) the
    pending units are cancelled and local worker processes are terminated before it propagates.
    """
    if scheduler:
        try:
            from dask.distributed import Client
        except ImportError:
            from .errors import PcregError

            raise PcregError("--scheduler needs dask.distributed (pip install 'pcreg[distributed]')") from None
        from .errors import PcregError, _one_line

        _check_scheduler_address(scheduler)
        timeout = _connect_timeout()
        _probe_scheduler(scheduler, timeout)
        try:
            client = Client(scheduler, set_as_default=False, timeout=timeout)
        except Exception as exc:  # noqa: BLE001 - it answered the probe a moment ago: gone since
            raise PcregError(f"cannot connect to the dask scheduler {scheduler!r}: {_one_line(exc)}") from None
        from concurrent.futures import CancelledError

        executor = _ClusterExecutor(client, scheduler)
        quiet = _quiet_dask_logs()  # a lost scheduler or worker is reported in one line, not dask's tracebacks
        try:
            from ._workers import check_cluster

            check_cluster(client, scheduler, timeout)  # its workers: pcreg importable, the same code and libraries
            yield executor
            client.close(timeout=5)
            quiet()  # on a failure dask's threads may still log while the process ends: kept quiet
        except CancelledError:  # not by pcreg: the client cancels every unit when it loses the scheduler
            executor.shutdown(wait=False)
            if interrupted():
                raise KeyboardInterrupt from None
            raise PcregError(f"lost the dask scheduler {scheduler!r} mid-run (it ended, or the network failed): the "
                             "finished units are kept; rerun the same command to resume once it is back") from None
        except BaseException:
            executor.shutdown(wait=False)  # cancels the units not finished
            raise
        finally:
            client.close(timeout=5)
    elif workers <= 1:
        yield InlineExecutor()
    else:
        import multiprocessing
        import os

        check_workers(workers)
        from concurrent.futures.process import BrokenProcessPool

        with one_compiling_note():  # the workers say it once among them, and with this process
            steps: Any = multiprocessing.SimpleQueue()  # the units' progress: a put is in the pipe before the unit's result
            pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init,
                                       initargs=(workers, os.getpid(), steps))
            pool.steps = steps  # type: ignore[attr-defined]  # read by run_units
            try:
                yield pool
            except BrokenProcessPool:
                how = _how_workers_ended(pool)
                _stop_pool(pool)
                if interrupted():  # the workers died of the same signal as the parent
                    raise KeyboardInterrupt from None
                from .errors import PcregError

                raise PcregError(f"a worker process ended abruptly{how}; the units that were running are lost, the finished "
                                 "ones are kept: rerun the same command to resume (with fewer --workers if memory is short)"
                                 ) from None
            except BaseException:
                _stop_pool(pool)
                raise
            pool.shutdown(wait=True)


def progress(iterable: Iterable | None = None, *, total: int | None = None, desc: str = "", disable: bool | None = None,
             unit: str = "it"):
    """A tqdm progress bar on stderr (hidden when stderr is not a terminal unless forced), counting ``unit``."""
    from tqdm.auto import tqdm

    if disable is None:
        disable = not sys.stderr.isatty()
    return tqdm(iterable, total=total, desc=desc, disable=disable, dynamic_ncols=True, leave=False, unit=unit)


class _AboveBars(logging.Handler):
    """The ``pcreg`` logger's lines written to stderr above a progress bar being drawn, not into its line."""

    def emit(self, record: logging.LogRecord) -> None:
        from tqdm import tqdm

        try:
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # a stderr closed or full: the line is lost, the command goes on (as logging's own handlers)
            self.handleError(record)


def say_above_bars() -> None:
    """What the library says on its ``pcreg`` logger (:data:`pcreg._jit.COMPILING`), as a command's own notes."""
    logger = logging.getLogger("pcreg")
    if not any(isinstance(h, _AboveBars) for h in logger.handlers):
        logger.addHandler(_AboveBars())  # (propagated too: a caller's own handlers of the root see it as before)


def tick(bar) -> None:
    """One more done on a :func:`progress` bar whose total is an estimate (a video's frame count from its
    duration: streams joined with ``cat``, a variable rate): past it, the bar counts on without a total rather
    than show more than 100%."""
    if bar.total is not None and bar.n >= bar.total:
        bar.total = None
    bar.update(1)


def run_units(fn: Callable[[Any], Any], units: Sequence[Any], *, executor: Executor, desc: "str | Tally" = "",
              on_result: Callable[[Any, Any], None] | None = None, show_progress: bool | None = None) -> list:
    """Submit ``fn(unit)`` for every unit; call ``on_result(unit, result)`` as each finishes (in the parent).
    The bar, named ``desc``, counts the units, or with a :class:`~pcreg._progress.Tally` that estimates it their
    work as each unit tells it (:mod:`pcreg._progress`).

    Returns the results in the order of ``units``.
    """
    from ._progress import Counting, Tally

    futures: dict = {}
    results: list = [None] * len(units)
    inline = isinstance(executor, InlineExecutor)
    health = getattr(executor, "check", None)  # a cluster's: raises once it cannot run the units any more
    tally = desc if isinstance(desc, Tally) else Tally(desc)
    try:
        with progress(total=len(units), desc=tally.desc, unit=tally.counts,
                      disable=None if show_progress is None else not show_progress) as bar, \
                Counting(bar, units, tally, executor, inline=inline) as counted:

            def land(fut: Future) -> None:
                i = futures[fut]
                counted.read()  # the unit's own, in the pipe before its result
                try:
                    results[i] = fut.result()
                except Exception as exc:
                    if type(exc).__name__ != "KilledWorker":  # dask's, after a unit's workers died again and again
                        raise
                    from .errors import PcregError

                    key = getattr(units[i], "key", i)
                    raise PcregError(f"unit {key}: every dask worker that ran it ended abruptly (out of memory?), "
                                     "so dask gave it up; the finished units are kept: rerun the same command to "
                                     "resume") from None
                if on_result is not None:
                    on_result(units[i], results[i])
                counted.land(i)

            # A pool forks its workers inside submit; a KeyboardInterrupt raised in an os.fork hook would be
            # printed and lost, so a signal there is only noted, and raised once the units are submitted.
            # Inline, submit runs the unit: each result lands (and is kept) before the next unit starts.
            with nullcontext() if inline else _shielded():
                for i, u in enumerate(units):
                    fut = counted.submit(executor, fn, i, u)
                    futures[fut] = i
                    if inline:
                        land(fut)
            check_interrupted()
            pending = set() if inline else set(futures)
            while pending:
                # Shielded too: wait() and result() take each future's lock, and a KeyboardInterrupt raised
                # while one is held leaves it held; the pool's thread, which hands the results to the futures,
                # then waits on it for ever, and so does Python's exit, which joins that thread. A signal is
                # raised here instead, within the 0.25 s of a wait, the units that finished meanwhile kept.
                with _shielded():
                    done, pending = wait(pending, timeout=0.25, return_when=FIRST_COMPLETED)
                    counted.read()
                    for fut in done:
                        land(fut)
                check_interrupted()
                if health is not None:
                    health()
    except BaseException:
        with _shielded():  # a second signal here: the same locks
            for fut in futures:  # nothing more starts; what finished was handed to on_result already
                fut.cancel()
        raise
    return results
