"""What a process that runs pcreg's units must share with the command that sends them, for their numbers to be the
command's: pcreg importable, the same pcreg (its version and a digest of its modules' source), the same versions of
the libraries that make its numbers (:data:`LIBRARIES`), and an environment numba starts in.

A local ``--workers`` pool forks the command itself, so only a dask cluster's workers (``--scheduler``) are checked:
each worker there when the command connects (:func:`check_cluster`), and a worker that joins later before each unit it
runs (:func:`run_checked`). A worker that differs ends the command in one line (exit 2) before it runs a unit, so that
no number from other code is kept among the finished units. Light on purpose: the command line reads
:func:`environment_problem` before any of pcreg's modules load, and a worker imports this module to answer."""

from __future__ import annotations

import functools
import os
import pickle
from typing import Any, Callable

__all__ = ["KEPT", "LIBRARIES", "fingerprint", "mismatch", "source_digest", "environment_problem", "numba_threads_problem", "worker_problem", "run_checked",
           "check_cluster", "submit_checked"]

#: The libraries whose versions make pcreg's numbers, by the name they are imported as.
LIBRARIES = ("numpy", "scipy", "open3d", "cv2", "numba", "sklearn")
#: What a command stopped by a worker says of its units.
KEPT = "the finished units are kept: rerun the same command to resume"


def environment_problem() -> str | None:
    """What of this process's environment pcreg cannot run with, in words, or None: :func:`numba_threads_problem`,
    or a ``PCREG_HELPER_THREAD`` that neither turns the helper thread off nor leaves it on (``maybe``, ``false``
    taken for on before)."""
    from ._threads import ENVIRONMENT, OFF, ON, wanted

    given = os.environ.get(ENVIRONMENT)
    if wanted(given) is None:
        return (f"{ENVIRONMENT}={given!r}: {' or '.join(OFF)} turns the helper thread off, "
                f"{' or '.join(v for v in ON if v)} (or unset) leaves it on")
    return numba_threads_problem()


def numba_threads_problem() -> str | None:
    """What is wrong with ``NUMBA_NUM_THREADS`` in this process's environment, in words, or None: numba refuses 0 and
    less on import (its ValueError, 50 lines), and takes a value that is no whole number with a warning of nine
    lines, then one thread a CPU."""
    given = os.environ.get("NUMBA_NUM_THREADS")
    if given is None:
        return None
    try:
        if int(given) >= 1:  # as numba reads it
            return None
    except ValueError:
        pass
    return f"NUMBA_NUM_THREADS={given!r}: numba's number of threads is a whole number, 1 or more (unset it for one a CPU)"


@functools.lru_cache(maxsize=1)
def fingerprint() -> dict[str, str]:
    """This process's pcreg: its version (``"pcreg"``), a digest of its modules' source (``"code"``: SHA-256 of every
    ``.py`` regular file under the package, by relative path, its line endings read as ``\n`` (a checkout with CRLF
    endings is the same code), first 16 hex digits) and the versions of each of :data:`LIBRARIES` as installed
    (``"not installed"`` for none), read from the packages' metadata, not imported: by version, not distribution
    (``open3d`` and ``open3d-cpu`` of one version, pcreg's two extras, are one; an editor's lock file is no module)."""
    from importlib.metadata import packages_distributions, version
    from pathlib import Path

    import pcreg

    found = {"pcreg": pcreg.__version__, "code": source_digest(Path(pcreg.__file__).parent)}
    installed = packages_distributions()
    for module in LIBRARIES:
        found[module] = ", ".join(sorted({version(name) for name in installed.get(module, ())})) or "not installed"
    return found


def source_digest(root) -> str:
    """The first 16 hex digits of the SHA-256 of every ``.py`` regular file under ``root`` (a :class:`~pathlib.Path`),
    by relative path, its line endings read as ``\\n``: :func:`fingerprint`'s ``"code"``."""
    import hashlib

    digest = hashlib.sha256()
    for path in sorted(q for q in root.rglob("*.py") if q.is_file()):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes().replace(b"\r\n", b"\n") + b"\0")
    return digest.hexdigest()[:16]


def mismatch(expected: dict[str, str], found: dict[str, str]) -> str | None:
    """How ``found`` (a worker's :func:`fingerprint`) differs from ``expected`` (the command's), the first difference
    in words, or None."""
    for key in [*expected, *(k for k in found if k not in expected)]:
        here, there = expected.get(key, "not installed"), found.get(key, "not installed")
        if here == there:
            continue
        if key == "code":
            return f"it runs pcreg {found.get('pcreg')} with other code (its modules' digest {there}, here {here})"
        return f"it has {key} {there}, here {here}" if key != "pcreg" else f"it runs pcreg {there}, here {here}"
    return None


def worker_problem(expected: dict[str, str]) -> str | None:
    """Run where a unit would run: what keeps its numbers from being the command's (``expected``, the command's
    :func:`fingerprint`), in words, or None."""
    environment = environment_problem()
    if environment is not None:
        return f"{environment}; {KEPT}"
    differs = mismatch(expected, fingerprint())
    if differs is not None:
        return f"{differs}; install the same pcreg and libraries on every worker as where the command runs; {KEPT}"
    return None


def _address() -> str:
    try:
        from distributed import get_worker

        return f"dask worker {get_worker().address}"
    except (ImportError, ValueError):  # not on a dask worker
        return "a worker"


def run_checked(expected: dict[str, str], call: bytes) -> Any:
    """A unit on a worker: ``call`` (``fn, args, kwargs`` pickled by :func:`submit_checked`) once
    :func:`worker_problem` finds nothing; else a :class:`~pcreg.errors.PcregError` naming the worker, before the
    call is unpickled (unpickling it imports the modules, numba's among them)."""
    problem = worker_problem(expected)
    if problem is not None:
        from .errors import PcregError

        raise PcregError(f"{_address()}: {problem}")
    fn, args, kwargs = pickle.loads(call)
    return fn(*args, **kwargs)


def submit_checked(submit: Callable, fn: Callable, /, *args: Any, **kwargs: Any) -> Any:
    """``submit(fn, *args, **kwargs)`` as :func:`run_checked` on the worker (``submit``: a dask executor's)."""
    return submit(run_checked, fingerprint(), pickle.dumps((fn, args, kwargs), protocol=pickle.HIGHEST_PROTOCOL))


def check_cluster(client: Any, scheduler: str, timeout: float) -> None:
    """Ask each worker of ``client``'s cluster (at ``scheduler``) the :func:`worker_problem`, before any unit is sent:
    a worker that cannot import pcreg, or differs, is a :class:`~pcreg.errors.PcregError` naming it (a worker
    that cannot import pcreg would fail to read each unit sent to it, and dask would end it: the command would then
    wait for workers). The question is sent by value (a lambda), so that a worker without pcreg can read it. Workers
    that have not all answered within ``timeout`` seconds (one stopped, or its event loop held) are said in a note and
    left to each unit's own check (:func:`run_checked`), so that the healthy ones go on."""
    import sys
    import threading

    from ._signals import check_interrupted
    from .errors import PcregError

    expected, got = fingerprint(), []

    def ask() -> None:
        try:
            got.append(client.run(lambda e: __import__("pcreg") and  # pcreg itself first: its ImportError names it
                                  __import__("pcreg._workers", fromlist=["worker_problem"]).worker_problem(e),
                                  expected, on_error="return"))
        except Exception as exc:  # noqa: BLE001 - the client closed meanwhile, the scheduler lost: said by the run
            got.append(exc)

    asker = threading.Thread(target=ask, name="pcreg-worker-check", daemon=True)
    asker.start()
    for _ in range(max(1, round(timeout / 0.25))):
        asker.join(0.25)
        check_interrupted()
        if not asker.is_alive():
            break
    if not got or not isinstance(got[0], dict):
        sys.stderr.write(f"pcreg: note: the dask workers at {scheduler!r} did not all answer within {timeout:g} s (one "
                         "stopped, or busy); each unit checks its worker before it runs\n")
        return
    for address, answer in sorted(got[0].items()):
        if answer is not None and not isinstance(answer, BaseException):
            raise PcregError(f"dask worker {address} at {scheduler!r}: {answer}")
        if isinstance(answer, ImportError) and getattr(answer, "name", None) == __name__:
            raise PcregError(f"dask worker {address} at {scheduler!r}: it runs another pcreg, one without {__name__} "
                             "(an older one); install the same pcreg there as where the command runs")
        if isinstance(answer, ImportError):
            raise PcregError(f"dask worker {address} at {scheduler!r} cannot import pcreg ({_said(answer)}): install "
                             f"pcreg {expected['pcreg']} there, as where the command runs")
        if answer is not None:
            raise PcregError(f"dask worker {address} at {scheduler!r} failed to say which pcreg it runs ({_said(answer)})")


def _said(exc: BaseException) -> str:
    from .errors import _one_line

    return f"{type(exc).__name__}: {_one_line(exc)}"
