"""A user's own ICP: ``py:MODULE:FUNCTION`` (a Python callable) or ``cmd:"PROGRAM {source} ..."``
(an external program of any language).

Python callables are called as::

    FUNCTION(source, target, *, init, max_correspondence_distance, max_iterations, relative_fitness,
             relative_rmse)

with ``source`` (N, d), ``target`` (M, d) float64 arrays, ``init`` the (d+1, d+1) guess, and return the
(d+1, d+1) matrix ``T_target_source`` (an array, nested lists, or what numpy reads: a tensor), or a dict / object with ``matrix`` and optionally ``iterations``,
``fitness``, ``inlier_rmse``, ``converged``. A function attribute ``comparability`` ("step",
"fixed-point", "objective"; default "step") says which tolerance applies.

The file protocol of ``cmd:`` programs (fixed; other tools are written against it):

- ``{source}``, ``{target}``: ``.npy`` files, each an (N, d) float64 array, d = 2 or 3;
- ``{init}``: a text file with the (d+1)x(d+1) initial guess, one row per line, numbers separated by
  whitespace (what ``numpy.savetxt`` writes);
- ``{params}``: a JSON file with ``max_correspondence_distance``, ``max_iterations``, ``relative_fitness``
  and ``relative_rmse``;
- ``{out}``: the program writes the (d+1)x(d+1) matrix mapping source points onto the target there, in
  the format of ``{init}``; it may also write ``{out}.json`` with ``iterations`` (whole, at least 0),
  ``fitness`` (0..1), ``inlier_rmse`` (at least 0), ``converged`` (true or false) and ``comparability``.

Placeholders the template does not use are not written; a literal brace is written ``{{`` or ``}}``. The program runs in the current directory
with a time limit; a non-zero exit, a timeout, an unreadable output, a NaN, a matrix that is not a rigid
transform (:data:`RETURNED_TOLERANCE`) or a figure out of its range is that implementation's failure (a
Python callable's too).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import math
import os
import shlex
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import NoReturn

import numpy as np

from ..formats import load_json_object, read_regular_file
from ..text_files import text_matrix
from ..errors import InputError
from .base import COMPARABILITY, STEP, ImplementationError, Implementation, result

PLACEHOLDERS = ("source", "target", "init", "out", "params")
DEFAULT_TIMEOUT = 60.0


def _comparability(value, where: str) -> str:
    if value is None:
        return STEP
    if value not in COMPARABILITY:
        raise ImplementationError(f"{where}: comparability must be one of {', '.join(COMPARABILITY)}, got {value!r}")
    return value


#: The most iterations an implementation may report: the cross-check's own bound on ``max_iterations``.
MAX_ITERATIONS = 100_000


def _number(value, key: str, kind=float, lo: float = 0.0, hi: float = math.inf):
    """A reported number, None when not reported; an :class:`ImplementationError` for one of another type or
    outside ``lo`` .. ``hi`` (iterations and errors are not negative, a fitness is a share)."""
    if value is None:
        return None
    if isinstance(value, (np.integer, np.floating)):  # numpy's scalars, as a Python function returns them
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (isinstance(value, float)
                                                                          and not math.isfinite(value)):
        raise ImplementationError(f"{key} must be a finite number, got {_shown(value)}")
    if kind is int and value != int(value):
        raise ImplementationError(f"{key} must be a whole number, got {_shown(value)}")
    if not lo <= value <= hi:  # a whole number of 400 digits is compared as it is: float() would overflow
        raise ImplementationError(f"{key} must be in {lo:g}..{hi:g}, got {_shown(value)}")
    return kind(value)


def _shown(value) -> str:
    """``value``'s repr, at most 40 characters (a 400-digit number, a long string)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _converged(value):
    if isinstance(value, np.bool_):
        value = bool(value)
    if value is not None and not isinstance(value, bool):
        raise ImplementationError(f"converged must be true or false, got {value!r}")
    return value


#: How far a returned matrix may be from a rigid transform (its rotation block's R^T R from the identity,
#: its last row from (0, ..., 0, 1)): text written with six significant digits is well within it.
RETURNED_TOLERANCE = 1e-4


def _checked_matrix(m: np.ndarray, d: int, what: str) -> np.ndarray:
    """``m`` when it is a finite rigid (d+1)x(d+1) transform (the cross-check pins the rigid ICP); else an
    :class:`ImplementationError` naming ``what`` and how it is not (its shape, a NaN, a scale or a shear, a
    reflection, a last row of a projection)."""
    from ..registration.transforms import rigid_problem

    if m.shape != (d + 1, d + 1):
        raise ImplementationError(f"{what} is {'x'.join(map(str, m.shape))}, expected {d + 1}x{d + 1}")
    if not np.all(np.isfinite(m)):
        raise ImplementationError(f"{what} holds NaN or inf")
    problem = rigid_problem(m, tolerance=RETURNED_TOLERANCE, row_tolerance=RETURNED_TOLERANCE)
    if problem is not None:
        raise ImplementationError(f"{what}: {problem}")
    return m


class _ProcessExit(BaseException):
    """``os._exit`` called by a ``py:`` implementation's own code, on the thread that runs it (:func:`_user_code`)."""


@contextlib.contextmanager
def _user_code(what: str):
    """Run a ``py:`` implementation's own code (its import, its call, the reading of what it returned): what
    it raises, ``sys.exit`` and a KeyboardInterrupt no signal sent included, becomes an
    :class:`ImplementationError` (its row's one line), and the working directory, numpy's error handling
    (``np.seterr``) and the warning filters it changed are put back
    (the next implementation's relative paths, and the command's outputs, are the caller's); threads it
    left running are marked ``pcreg_user_code`` (:mod:`pcreg.cli` ends the process without them)."""
    try:
        cwd: int | None = os.open(".", getattr(os, "O_PATH", os.O_RDONLY))
    except OSError:  # a working directory gone or unreadable: none to put back
        cwd = None
    before = set(threading.enumerate())
    # os._exit in the function ended pcreg at once, with its status (0: a cross-check that printed nothing and
    # exited as if it had succeeded); on the thread that runs it, it is the row's error (another thread's, pcreg's
    # own stop watchdog's included, exits)
    real_exit, caller = os._exit, threading.get_ident()

    def exit_refused(status: int) -> NoReturn:
        if threading.get_ident() == caller:
            raise _ProcessExit(status)
        real_exit(status)

    os._exit = exit_refused
    try:
        # numpy's error handling and the warning filters it set are put back too: np.seterr(all="raise") in a
        # function made the next implementation's row fail ("pycpd: underflow encountered in exp")
        with np.errstate(), warnings.catch_warnings():
            yield
    except ImplementationError:
        raise
    except Exception as exc:  # noqa: BLE001 - a user function's failure is its row's error
        said = {"import": "", "call": "raised ", "result": "its result raised "}[what]
        raise ImplementationError(f"{said}{type(exc).__name__}: {exc}") from None
    except SystemExit as exc:  # sys.exit in a function would end the cross-check with its status
        raise ImplementationError(f"called sys.exit({exc.code!r}){'' if what == 'import' else '; a function returns its matrix'}") from None
    except KeyboardInterrupt:  # raised by the code itself, not by Ctrl-C or SIGTERM
        from .._runner import handles_signals, interrupted

        if interrupted() or not handles_signals():  # a real interrupt, or one nothing can tell apart
            raise
        raise ImplementationError("raised KeyboardInterrupt (no interrupt came)") from None
    except GeneratorExit:  # the one other BaseException code can raise by itself
        raise ImplementationError("raised GeneratorExit") from None
    except _ProcessExit as exc:
        raise ImplementationError(f"called os._exit({exc.args[0]!r}){'' if what == 'import' else '; a function returns its matrix'}") from None
    finally:
        os._exit = real_exit
        for t in set(threading.enumerate()) - before:  # marked for pcreg.cli, whose exit would wait for them
            if not t.daemon:
                t.pcreg_user_code = True  # type: ignore[attr-defined]
        if cwd is not None:
            try:
                os.fchdir(cwd)
            finally:
                os.close(cwd)


def _check_program_exists(spec: str, program: str) -> None:
    """An :class:`InputError` when ``program`` is neither a path to an executable file nor a command on
    ``PATH``: a misspelt name, found before any implementation runs."""
    import shutil

    if os.sep in program or (os.altsep and os.altsep in program):
        if not os.path.isfile(program):
            raise InputError(f"{spec}: no program {program!r} (the path is read from the current directory)")
        if not os.access(program, os.X_OK):
            raise InputError(f"{spec}: {program!r} is not executable (chmod +x it, or name its interpreter first)")
    elif shutil.which(program) is None:
        raise InputError(f"{spec}: no program {program!r} on PATH")


class PythonCallable(Implementation):
    """``py:MODULE:FUNCTION``."""

    def __init__(self, spec: str):
        self.name = spec
        body = spec[3:]
        module, sep, func = body.rpartition(":")
        if not sep or not module or not func:
            raise InputError(f"{spec}: expected py:MODULE:FUNCTION")
        self.module, self.function = module, func
        self.description = f"Python callable {module}.{func}"
        self._func = None

    def load(self):
        """The function, imported at the first call: what its import raises is an
        :class:`ImplementationError` (its row's one line); no such module, or a module without the
        function, is an :class:`InputError`, as a misspelt name is."""
        if self._func is None:
            added = False
            if os.getcwd() not in sys.path:
                sys.path.insert(0, os.getcwd())
                added = True
            missing = None
            try:
                with _user_code("import"):
                    try:
                        mod = importlib.import_module(self.module)
                    except ModuleNotFoundError as exc:  # the named module itself, not one it imports
                        if exc.name is None or not (self.module + ".").startswith(exc.name + "."):
                            raise
                        missing = exc.name
            except ImplementationError as exc:
                raise ImplementationError(f"cannot import {self.module}: {exc}") from None
            finally:
                if added:
                    sys.path.remove(os.getcwd())
            if missing is not None:
                where = "" if "." in missing else (" in the current directory or on Python's path (run pcreg from "
                                                   "the folder that holds it, or install it)")
                raise InputError(f"{self.name}: no module named {missing!r}{where}")
            func = getattr(mod, self.function, None)
            if not callable(func):
                raise InputError(f"{self.name}: {self.module} has no callable {self.function!r}")
            self._func = func
        return self._func

    @property
    def comparability(self) -> str:  # type: ignore[override]
        try:
            return _comparability(getattr(self.load(), "comparability", None), self.name)
        except ImplementationError:
            return STEP

    def settings(self, pinned):
        return pinned.params()

    def _run(self, pinned, *, trace):
        func = self.load()
        _comparability(getattr(func, "comparability", None), self.name)  # a typo is the row's error, as a cmd:'s
        start = time.perf_counter()
        with _user_code("call"):
            r = func(pinned.source.copy(), pinned.target.copy(), init=pinned.init.copy(), **pinned.params())
        seconds = time.perf_counter() - start
        with _user_code("result"):  # its properties and __array__ are the function's code too
            return self._result(r, pinned.source.shape[1], seconds)

    def _result(self, r, d: int, seconds: float):
        get = (lambda k: r.get(k)) if isinstance(r, dict) else (lambda k: getattr(r, k, None))
        # a matrix itself: an array, nested lists, or what numpy reads as one (a torch or jax tensor)
        isarr = isinstance(r, (np.ndarray, list, tuple)) or (hasattr(r, "__array__") and not hasattr(r, "matrix"))
        matrix = r if isarr else get("matrix")
        if matrix is None:
            raise ImplementationError("returned neither a matrix nor an object with 'matrix'")
        try:
            if np.iscomplexobj(matrix):  # numpy would drop the imaginary parts with a warning
                raise TypeError
            matrix = np.array(matrix, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise ImplementationError("returned a matrix that is not numeric") from None
        return result(self.name, _checked_matrix(matrix, d, "the returned matrix"),
                      iterations=None if isarr else _number(get("iterations"), "iterations", int, hi=MAX_ITERATIONS),
                      fitness=None if isarr else _number(get("fitness"), "fitness", hi=1.0),
                      inlier_rmse=None if isarr else _number(get("inlier_rmse"), "inlier_rmse"),
                      converged=None if isarr else _converged(get("converged")), seconds=seconds)


def _run_in_own_group(argv: list[str], timeout: float | None) -> tuple[int, str]:
    """``(exit status, the last line it printed on stderr)`` of ``argv`` run to its end in a process group of
    its own: its stdout dropped, and of its stderr only the last 4 kB kept (what it prints costs neither memory
    nor disk); past ``timeout`` the whole group is killed, and at its end what it left running (a program's own
    children outlive a kill of the program alone, and would hold the run)."""
    import signal

    def kill_group(pid: int) -> None:
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:  # the group is gone already
            pass

    try:
        p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             start_new_session=True)
    except OSError as exc:
        raise ImplementationError(f"cannot run {argv[0]}: {exc.strerror or exc}") from None
    tail = bytearray()
    assert p.stderr is not None  # stderr=PIPE
    stderr = p.stderr

    def keep_tail() -> None:  # the pipe is the reader's: a process left outside the group may hold it open
        try:
            while chunk := os.read(stderr.fileno(), 1 << 16):
                tail.extend(chunk)
                del tail[:-4096]
        finally:
            stderr.close()

    reader = threading.Thread(target=keep_tail, name="pcreg-cmd-stderr", daemon=True)
    reader.start()
    try:
        status = p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ImplementationError(f"timed out after {timeout:g} s") from None
    finally:  # at its end, past the timeout or on an interrupt: the program and what it left running end here
        kill_group(p.pid)
        p.wait()
        # The group's end closes its stderr, and the reader ends with it; a process that left the group (setsid)
        # and holds it keeps the reader until it ends, not the run.
        reader.join(5.0)
    lines = bytes(tail).decode("utf-8", "replace").strip().splitlines()
    last = lines[-1] if lines else ""
    return status, last if len(last) <= 200 else last[:197] + "..."  # shortened, and marked so


class Command(Implementation):
    """``cmd:"PROGRAM {source} {target} {init} {out} {params}"``."""

    def __init__(self, spec: str, *, timeout: float = DEFAULT_TIMEOUT):
        self.name = spec
        template = spec[4:].strip()
        if len(template) >= 2 and template[0] == template[-1] and template[0] in "\"'":
            template = template[1:-1]
        try:
            self.argv = shlex.split(template)
        except ValueError as exc:
            raise InputError(f"{spec}: cannot parse the command: {exc}") from None
        if not self.argv:
            raise InputError(f"{spec}: empty command")
        import string

        used = set()
        braces = "; a literal brace is written {{ or }}"
        for tok in self.argv:
            try:
                parsed = list(string.Formatter().parse(tok))
            except ValueError as exc:  # a lone brace: "expected '}' before end of string"
                raise InputError(f"{spec}: cannot read the placeholders of {tok!r}: {exc}{braces}") from None
            for _, field, format_spec, conversion in parsed:
                if field is None:
                    continue
                if field not in PLACEHOLDERS or format_spec or conversion:
                    shown = field + (f"!{conversion}" if conversion else "") + (f":{format_spec}" if format_spec else "")
                    raise InputError(f"{spec}: unknown placeholder {{{shown}}} (use "
                                     f"{', '.join('{'+p+'}' for p in PLACEHOLDERS)}){braces}")
                used.add(field)
        if "out" not in used:
            raise InputError(f"{spec}: the command has no {{out}}: it cannot return a matrix")
        _check_program_exists(spec, self.argv[0])
        self.used = used
        from ..validation import check_float

        self.timeout = check_float(timeout, "timeout", lo=0, lo_open=True)
        self.description = f"external program {self.argv[0]}"
        self._declared = STEP

    @property
    def comparability(self) -> str:  # type: ignore[override]
        return self._declared

    def settings(self, pinned):
        return {**pinned.params(), "timeout_s": self.timeout}

    def _run(self, pinned, *, trace):
        d = pinned.dim
        with tempfile.TemporaryDirectory(prefix="pcreg-cmd-") as tmp:
            paths = {"source": Path(tmp) / "source.npy", "target": Path(tmp) / "target.npy",
                     "init": Path(tmp) / "init.txt", "out": Path(tmp) / "out.txt", "params": Path(tmp) / "params.json"}
            if "source" in self.used:
                np.save(paths["source"], np.ascontiguousarray(pinned.source, dtype=np.float64))
            if "target" in self.used:
                np.save(paths["target"], np.ascontiguousarray(pinned.target, dtype=np.float64))
            if "init" in self.used:
                np.savetxt(paths["init"], pinned.init)
            if "params" in self.used:
                paths["params"].write_text(json.dumps(pinned.params(), indent=2))
            argv = [tok.format(**{k: str(v) for k, v in paths.items()}) for tok in self.argv]
            start = time.perf_counter()
            status, last = _run_in_own_group(argv, self.timeout)
            seconds = time.perf_counter() - start
            if status != 0:
                raise ImplementationError(f"exit status {status}{f': {last}' if last else ''}")
            out = paths["out"]
            if not out.exists():
                raise ImplementationError("wrote no output matrix")
            try:  # a regular file of at most 64 kB: a FIFO left at {out} would block the read forever
                text = read_regular_file(out, max_bytes=1 << 16, what="output matrix")
                with warnings.catch_warnings():  # "input contained no data": said below, in the row
                    warnings.simplefilter("ignore")
                    m = text_matrix(text)
            except InputError as exc:
                raise ImplementationError(str(exc).removeprefix(f"{out}: ")) from None
            except ValueError as exc:
                raise ImplementationError(f"unreadable output matrix ({str(exc).splitlines()[0][:120]})") from None
            if m.size == 0:
                raise ImplementationError("wrote an empty output matrix")
            m = _checked_matrix(m, d, "output matrix")
            extra = {}
            side = Path(str(out) + ".json")
            if side.exists():
                try:
                    extra = load_json_object(side)
                except ValueError as exc:
                    raise ImplementationError(f"{side.name}: {exc}") from None
            self._declared = _comparability(extra.get("comparability"), self.name)
            return result(self.name, m, iterations=_number(extra.get("iterations"), "iterations", int, hi=MAX_ITERATIONS),
                          fitness=_number(extra.get("fitness"), "fitness", hi=1.0),
                          inlier_rmse=_number(extra.get("inlier_rmse"), "inlier_rmse"),
                          converged=_converged(extra.get("converged")), seconds=seconds)
