"""The ``pcreg`` command line: parse, build a config, call the library.

Exit codes: 0 ok; 1 a bug in pcreg (any exception pcreg did not raise on purpose: one line on stderr
that says so, or the whole traceback with ``PCREG_TRACEBACK=1``); 2 bad input (a
:class:`pcreg.errors.PcregError` other than a refused registration, bad options, or an ``OSError``: the file
system refused, a full disk or a folder where a file goes; one line on stderr);
3 a refused registration (:class:`pcreg.errors.RegistrationError`; with ``--json``, the object
``{"ok": false, "reason": ...}`` is printed on stdout as well); 130 interrupted (Ctrl-C, SIGTERM, or SIGHUP: its terminal closed).
Each command lives in its own module under ``pcreg.commands`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports happen inside ``run``.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from typing import NoReturn

# name -> (module, one-line help). "evaluate" has sub-commands of its own.
COMMANDS: dict[str, tuple[str, str]] = {
    "register": ("pcreg.commands.register", "register a moving image to a reference image"),
    "crosscheck": ("pcreg.commands.crosscheck", "run ICP implementations (up to ten) on the same input and compare them"),
    "demo": ("pcreg.commands.demo", "the whole story on the built-in synthetic data (what `make demo` runs)"),
    "run": ("pcreg.commands.run", "label a folder of frames or a video from labelled key frames, in two classes or a table's"),
    "export": ("pcreg.commands.export", "write a pcreg run's labels as an archive an annotation tool imports (CVAT)"),
    "view": ("pcreg.commands.view", "open a rerun recording or render a screenshot of it, serve an evaluation's report, review a run's labels"),
}
EVALUATIONS: dict[str, tuple[str, str]] = {
    "classification": ("pcreg.commands.evaluate_classification", "thesis Ch. 4: naive Bayes cases I-III"),
    "rotation": ("pcreg.commands.evaluate_rotation", "thesis Ch. 5: classify rotated frames before/after registration"),
    "sequence": ("pcreg.commands.evaluate_sequence", "thesis Ch. 6-7: register frame i+k to i, classify, fuse labels"),
    "stream": ("pcreg.commands.evaluate_stream", "label every frame of a clip from its key frame, methods side by side"),
}


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # a value that begins with a minus and a digit is a value (``--angles -30,0,30``, ``--init -1,0,...``), not an
        # option: Python 3.11's argparse takes only a lone negative number so, and refused these as "expected one
        # argument"; no option of pcreg's is spelled so
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message: str) -> NoReturn:  # one line, exit 2 (argparse's default prints usage too)
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


#: Words whose full stop ends no sentence ("thesis Ch. 4").
_ABBREVIATIONS = ("ch", "sec", "fig", "eq", "e.g", "i.e", "cf", "vs", "al")


def _first_sentence(doc: str) -> str:
    """The first sentence of a docstring's first paragraph, on one line, without reST's code marks (a
    command's description)."""
    para = " ".join(doc.strip().split("\n\n")[0].split()).replace("``", "")
    for stop in re.finditer(r"\. ", para):
        if para[:stop.start()].rsplit(" ", 1)[-1].lstrip("(").lower() not in _ABBREVIATIONS:
            return para[:stop.start() + 1]
    return para


def _add(sub, name: str, module: str, help_: str) -> None:
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name != module:  # a missing dependency inside the module is a real error
            raise
        return
    p = sub.add_parser(name, help=help_, description=_first_sentence(mod.__doc__ or help_))
    mod.add_arguments(p)
    _add_limits(p)
    _refuse_empty_values(p)
    p.set_defaults(_module=module)


def _add_limits(p: argparse.ArgumentParser) -> None:
    """--max-pixels on every command (images and clouds larger than this are refused before decoding)."""
    from .commands._common import arg_int
    from .validation import DEFAULT_MAX_PIXELS

    if not any("--max-pixels" in a.option_strings for a in p._actions):
        p.add_argument("--max-pixels", type=arg_int(1), default=None, metavar="N",
                       help=f"largest image (pixels) or cloud (points) accepted (default {DEFAULT_MAX_PIXELS}, "
                            "or $PCREG_MAX_PIXELS)")


def _not_empty(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a value, got {text!r}")
    return text


def _refuse_empty_values(p: argparse.ArgumentParser) -> None:
    """Every option and argument given as text (no ``type=`` of its own) refuses an empty value: a path ``''`` is
    the current folder (``--out ''`` wrote a run's files there), and other options took it for not given."""
    for action in p._actions:
        if action.type is None and action.nargs != 0 and not isinstance(action, argparse._SubParsersAction):
            action.type = _not_empty


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pcreg", description="Register images as point clouds; label video per pixel from a few labelled frames.")
    from . import __version__

    parser.add_argument("--version", action="version", version=f"pcreg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (module, help_) in COMMANDS.items():
        _add(sub, name, module, help_)
    ev = sub.add_parser("evaluate", help="score pcreg beside baselines: the thesis's experiments, a labelled stream, DAVIS")
    ev_sub = ev.add_subparsers(dest="evaluation", metavar="EXPERIMENT", parser_class=_Parser)
    for name, (module, help_) in EVALUATIONS.items():
        _add(ev_sub, name, module, help_)
    return parser


#: Whether the program's caller closed its stdout (:func:`_usable_streams`): ``--json`` is then refused, since
#: what it prints would be lost.
_STDOUT_CLOSED = False


def _usable_streams() -> None:
    """The program's stdout and stderr as the command writes them: a stream its caller closed
    (``exec 1>&-``) goes to the null device, and what the terminal's encoding cannot show (a path's
    letters under ``PYTHONIOENCODING=ascii``) is written escaped instead of failing the command."""
    import os

    global _STDOUT_CLOSED
    _STDOUT_CLOSED = sys.stdout is None
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is None:
            setattr(sys, name, open(os.devnull, "w"))
        elif hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    if not _STDOUT_CLOSED:
        sys.stdout = _NamedStdout(sys.stdout)
    sys.stderr = _SpokenStderr(sys.stderr)


class _SpokenStderr:
    """The program's stderr, whose refused write (``2>/dev/full``) is dropped: nothing is left to say it on, and the
    command's exit status still says how it ended (a bad input's 2 became 1, a bug, as Python reported the failed
    write of its line)."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def __getattr__(self, name: str):
        return getattr(self._stream, name)

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError:
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError:
            pass


class _NamedStdout:
    """The program's stdout, whose refused write (``> /dev/full``) names standard output: the failure
    said "No space left on device" naming nothing, as if a file of the command's had failed. A closed pipe
    stays a BrokenPipeError (the command ends quietly, as other tools)."""

    def __init__(self, stream) -> None:
        self._stream = stream
        #: the last refused write, kept for a caller that drops the error (argparse's ``--help``)
        self.refused: OSError | None = None

    def __getattr__(self, name: str):
        return getattr(self._stream, name)

    def write(self, text: str) -> int:
        return self._named(self._stream.write, text)

    def flush(self) -> None:
        self._named(self._stream.flush)

    def _named(self, call, *args):
        try:
            return call(*args)
        except BrokenPipeError:
            raise
        except OSError as exc:
            self.refused = OSError(exc.errno, exc.strerror, "standard output")
            raise self.refused from None


def _help_written() -> int:
    """``--help`` or ``--version`` printed: exit 0 once it is out, 2 naming standard output where it was
    refused (``> /dev/full``): argparse drops a failed write of its own, and the help was lost with exit 0."""
    try:
        sys.stdout.flush()
    except OSError:
        pass
    refused = getattr(sys.stdout, "refused", None)
    if isinstance(refused, OSError):
        sys.stderr.write(f"pcreg: error: {refused.strerror}: {refused.filename}\n")
        return 2
    return 0


def _no_command(args: argparse.Namespace) -> int:
    """`pcreg` or `pcreg evaluate` alone: one line naming the choices, as any bad input."""
    group = EVALUATIONS if getattr(args, "command", None) == "evaluate" else [*COMMANDS, "evaluate"]
    what = "pcreg evaluate" if group is EVALUATIONS else "pcreg"
    sys.stderr.write(f"{what}: error: choose one of {', '.join(group)} ({what} --help says what each does)\n")
    return 2


def _run_command(args: argparse.Namespace) -> int:
    """The command's own run (its module's ``run``), after what the environment asks is checked."""
    import os

    from ._runner import interrupted, say_above_bars

    say_above_bars()
    if "NUMBA_THREADING_LAYER" in os.environ:  # the environment is input too
        from .registration.nn import check_threading_layer

        check_threading_layer()
    module = importlib.import_module(args._module)
    _check_together(args)
    if getattr(args, "max_pixels", None):
        from .validation import set_max_pixels

        set_max_pixels(args.max_pixels)  # also seen by worker processes
    code = int(module.run(args) or 0)
    if code == 0 and interrupted():  # the signal's KeyboardInterrupt was swallowed (an ignored callback)
        raise KeyboardInterrupt
    return code


def _check_together(args: argparse.Namespace) -> None:
    """Refuse options given together where one would be dropped without a word: ``--record-raw`` without a
    recording (the demo records by default), ``--workers N`` beside ``--scheduler`` (the cluster's workers run the
    units)."""
    from .errors import InputError

    if getattr(args, "record_raw", False) and not getattr(args, "record", None) and not args._module.endswith(".demo"):
        raise InputError("--record-raw logs a recording's images losslessly: give --record FILE.rrd with it")
    if getattr(args, "scheduler", None) and (getattr(args, "workers", None) or 1) > 1:
        raise InputError(f"--workers {args.workers} with --scheduler: the scheduler's workers run the units; choose one")


def _memory_advice(args) -> str:
    """What a command that ran out of memory can be given instead: its own options, not another command's."""
    command = getattr(args, "command", None)
    if command == "run":
        return ("a run's steps grow with the frames' size and the classes the key frames show: --scale 0.5 takes a "
                "quarter; a lower --max-pixels refuses such frames before they are read")
    if command in ("register", "crosscheck"):
        return ("a registration's memory grows with the images' pixels or the clouds' points: smaller inputs, or a lower "
                "--max-pixels to refuse such inputs before they are read")
    return "use smaller inputs, or a lower --max-pixels to refuse such inputs before they are read"


def _bug(exc: Exception, args) -> int:
    """An exception pcreg did not raise on purpose: exit 1 with one line (the traceback with
    ``PCREG_TRACEBACK=1``), or 130 when the process was being stopped by a signal anyway."""
    import os

    from ._runner import interrupted

    # e.g. the workers died of the same SIGTERM before the parent's handler ran, or the signal landed inside
    # a compiled kernel, which returns it as a SystemError: the same words as a KeyboardInterrupt's
    if interrupted():
        return _interrupted(args)
    if os.environ.get("PCREG_TRACEBACK", "") not in ("", "0"):
        import traceback

        traceback.print_exc(file=sys.stderr)
    else:
        sys.stderr.write(f"pcreg: internal error, a bug in pcreg: {type(exc).__name__}: {_one_line(exc)} "
                         "(PCREG_TRACEBACK=1 shows the traceback)\n")
    return 1


#: The commands that write one file, atomically, and have nothing to resume: interrupted, they wrote nothing.
ONE_SHOT = (".export", ".view")

#: How long a command stopping on a signal waits for the helper thread to end (seconds; it ends in milliseconds
#: unless it waits on a lock the interrupt left held).
HELPER_GRACE = 5.0


def main(argv: list[str] | None = None) -> int:
    from ._runner import one_compiling_note

    with one_compiling_note():  # said once in the command, by it or a worker
        code = _main(argv)
    if argv is None:  # the program itself
        _leave_without_user_threads(code)
    return code


def _leave_without_user_threads(code: int) -> None:
    """End the process with ``code`` now when threads a ``py:`` implementation started are still running:
    Python's exit would wait for them, for ever if they never end, with the report already printed."""
    import os
    import threading

    held = [t.name for t in threading.enumerate() if getattr(t, "pcreg_user_code", False) and t.is_alive()]
    if not held:
        return
    sys.stderr.write(f"pcreg: {len(held)} thread{'s' if len(held) > 1 else ''} a py: implementation started "
                     f"{'are' if len(held) > 1 else 'is'} still running ({', '.join(held[:3])}): ended with the process\n")
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _main(argv: list[str] | None) -> int:
    import os

    from .errors import PcregError

    from ._runner import interrupt_on_signals, interrupted, restore_signals

    if argv is None:  # the program itself, not a caller's own streams
        _usable_streams()
    if _environment_refused():  # before the commands' modules load
        return 2
    saved_limit = os.environ.get("PCREG_MAX_PIXELS")
    # Ctrl-C and SIGTERM: exit 130, finished units kept; from the start, while the commands' modules load
    previous = interrupt_on_signals()
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # the parser's own exit (a bad option: 2; --help: 0)
        restore_signals(previous)
        if exc.code == 0 and argv is None:
            return _help_written()
        raise
    except BaseException as exc:
        if not (isinstance(exc, KeyboardInterrupt) or interrupted()):
            restore_signals(previous)
            if _said_out_of_memory(exc):  # under a memory limit, a module could not load
                return 2
            raise
        # the KeyboardInterrupt, or what a module being loaded made of it (an ImportError of numpy's)
        _end(argv is None, saved_limit, previous)
        sys.stderr.write("pcreg: interrupted before the command started\n")
        return 130
    if not getattr(args, "_module", None):
        restore_signals(previous)
        return _no_command(args)
    if getattr(args, "json", False) and _STDOUT_CLOSED:
        restore_signals(previous)
        sys.stderr.write("pcreg: error: --json prints to standard output, which is closed: the result would be "
                         "lost (redirect it to a file: > result.json)\n")
        return 2
    from .errors import RegistrationError, StuckOutput

    try:
        return _run_command(args)
    except RegistrationError as exc:  # a refused registration: exit 3 (the JSON form goes to stdout)
        return _refused(exc, args)
    except PcregError as exc:
        sys.stderr.write(f"pcreg: error: {_one_line(exc)}{_full_disk_resumes(str(exc), args)}\n")
        if isinstance(exc, StuckOutput) and argv is None:  # a writer outside Python would hold the process at exit
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(2)
        return 2
    except KeyboardInterrupt:
        return _interrupted(args)
    except BrokenPipeError:  # stdout closed early (`pcreg ... | head`): no message, as other tools
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # Python's flush at exit must not fail again
        except (OSError, ValueError):
            pass
        return 141
    except OSError as exc:  # the file system refused (a full disk, a folder where a file goes, permissions)
        sys.stderr.write(f"pcreg: error: {_os_error(exc)}{_full_disk_resumes(str(exc), args)}\n")
        return 2
    except Exception as exc:  # noqa: BLE001 - memory run out or an extra not installed (exit 2), else a bug (exit 1)
        return 2 if _said_out_of_memory(exc, args) or _said_not_installed(exc) else _bug(exc, args)
    finally:
        _end(argv is None and interrupted(), saved_limit, previous, program=argv is None)


#: The libraries of pcreg's extras that a command may need, each with how to install it.
EXTRAS = {"open3d": "pip install 'pcreg[cpu]' (or 'pcreg[cuda]' for Open3D's CUDA build)",
          "dask": "pip install 'pcreg[distributed]'", "distributed": "pip install 'pcreg[distributed]'"}


def _said_not_installed(exc: BaseException) -> bool:
    """Say, in one line, that the command needs a library of one of pcreg's extras that is not installed (Open3D, of
    ``pcreg[cpu]``: pcreg installed without it), and whether it did: any other missing module is a bug."""
    name = getattr(exc, "name", None) if isinstance(exc, ModuleNotFoundError) else None
    install = EXTRAS.get((name or "").split(".")[0])
    if install is None:
        return False
    sys.stderr.write(f"pcreg: error: this command needs {name}, which is not installed: {install}\n")
    return True


def _os_error(exc: OSError) -> str:
    """An OSError in one line: the file it names; for too many open files, the limit (``ulimit -n``), which is no
    file's fault (the file named is whichever was opened last, perhaps one of pcreg's own modules)."""
    import errno

    if exc.errno in (errno.EMFILE, errno.ENFILE):
        try:  # a compiled module: with every file descriptor taken, it may not load
            import resource

            may = f"this process may open {resource.getrlimit(resource.RLIMIT_NOFILE)[0]}; "
        except (ImportError, OSError, ValueError):
            may = ""
        return f"too many open files ({may}pcreg needs a few dozen): raise the limit (ulimit -n)"
    where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
    return f"{exc.strerror or _one_line(exc)}{where}"


def _environment_refused() -> bool:
    """Say, in one line, what of the environment pcreg cannot run with before its modules load, and whether it did:
    a ``NUMBA_NUM_THREADS`` numba does not take, a ``PCREG_HELPER_THREAD`` pcreg does not (:func:`pcreg._workers.environment_problem`)."""
    from ._workers import environment_problem

    problem = environment_problem()
    if problem is None:
        return False
    sys.stderr.write(f"pcreg: error: {problem}\n")
    return True


def _said_out_of_memory(exc: BaseException, args: argparse.Namespace | None = None) -> bool:
    """Say, in one line, that memory ran out where ``exc`` says so (a :class:`MemoryError`, or a library's words:
    :func:`_out_of_memory`), with what the command can be given instead; ``args`` None: while pcreg loaded its
    modules, before any command. Whether it did."""
    if not (isinstance(exc, MemoryError) or _out_of_memory(exc)):
        return False
    if args is None:
        sys.stderr.write("pcreg: error: out of memory while pcreg loaded its modules (a memory limit such as "
                         "ulimit -v below about 2 GB?)\n")
    else:
        sys.stderr.write(f"pcreg: error: out of memory ({_memory_advice(args)})\n")
    return True


def _refused(exc: BaseException, args) -> int:
    """Exit 3 for a refused registration: its reason on stderr, then what the command notes of its inputs (an EXIF
    orientation: the exception's notes), and with ``--json`` both on stdout."""
    reason = _one_line(exc, limit=1000)  # its advice whole, where an error is cut at 500
    sys.stderr.write(f"pcreg: registration refused: {reason.removeprefix('registration refused: ')}\n")
    notes = list(getattr(exc, "__notes__", ()))
    for note in notes:
        sys.stderr.write(f"pcreg: note: {note}\n")
    if getattr(args, "json", False):
        from .commands._common import print_json

        try:
            print_json({"ok": False, "reason": _one_line(exc, limit=None), "notes": notes})
        except BrokenPipeError:
            return 3
        except OSError as err:  # stdout on a full disk: said, the refusal's status kept
            sys.stderr.write(f"pcreg: error: {err.strerror}: {err.filename}\n")
    return 3


def _out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is the memory running out as a library says it: OpenCV's "Insufficient memory" (its
    ``cv2.error``), or a compiled module that could not be mapped into memory when it loaded (``ImportError``:
    "failed to map segment", under a ``ulimit -v``)."""
    said = str(exc)
    if type(exc).__name__ == "error" and type(exc).__module__ == "cv2":
        return "Insufficient memory" in said or "Failed to allocate" in said
    # the same words for a library on a file system mounted noexec, with its reason: no memory's fault
    return (isinstance(exc, ImportError) and "failed to map segment" in said
            and not any(w in said for w in ("Operation not permitted", "Permission denied")))


def _interrupted(args) -> int:
    """Exit 130 with one line that says what the interrupted command kept and how it resumes."""
    module = getattr(args, "_module", "")
    if module.endswith(ONE_SHOT):
        sys.stderr.write("pcreg: interrupted (nothing was written)\n")
        return 130
    resumes = _resumes(args)
    sys.stderr.write("pcreg: interrupted\n" if resumes is None else f"pcreg: interrupted ({resumes[0]}; rerun {resumes[1]} "
                     "to resume)\n")  # (without it: nothing it could resume, or not yet parsed)
    return 130


def _resumes(args) -> tuple[str, str] | None:
    """``(what is kept, the command that resumes)`` of a command that resumes (``pcreg run``, the evaluations), stopped;
    None for one that does not."""
    module = getattr(args, "_module", "")
    if not (module.endswith(".run") or ".evaluate_" in module):
        return None
    again = ("the same command with another --record file (the recording holds what was done)"
             if getattr(args, "record", None) else "the same command")
    if getattr(args, "force", False):  # which starts over
        again = again.replace("the same command", "the same command without --force", 1)
    return "the frames labelled are kept" if module.endswith(".run") else "finished units are kept", again


def _full_disk_resumes(said: str, args) -> str:
    """What a command that resumes says after a refusal of a full disk: what it kept, and that it goes on once there is
    room (the refusal named the file alone, and a user short of space may remove the run's own files)."""
    resumes = _resumes(args)
    if resumes is None or "No space left on device" not in said:
        return ""
    return f" ({resumes[0]}; free space there, then rerun {resumes[1]} to resume)"


def _end(stopping: bool, saved_limit: str | None, previous, *, program: bool = False) -> None:
    """What every command does last: the pixel limit as it was, the helper thread ended, and the signal
    handlers as they were; ``stopping``: the program itself is stopping on a signal, and exits 130; ``program``:
    the program itself (not a caller of :func:`main`), whose command is over: a signal from here to its exit is
    ignored (:func:`~pcreg._signals.ignore_signals`), and it exits with the command's status."""
    import os

    from ._runner import forget_stray_interrupt, ignore_signals, restore_signals

    if stopping:
        ignore_signals()
        forget_stray_interrupt()
    if saved_limit is None:
        os.environ.pop("PCREG_MAX_PIXELS", None)
    else:
        os.environ["PCREG_MAX_PIXELS"] = saved_limit
    from . import _threads

    # the helper thread ends here (milliseconds), not in the interpreter's shutdown; stopping on a signal, a
    # helper still busy after the grace waits on a lock the interrupt left held: the outputs are whole (written
    # atomically, the writers closed), so the process ends without it
    if not _threads.close(HELPER_GRACE if stopping else None):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    if not stopping and program:  # the handlers put back now would be the default, which kills without a word
        ignore_signals()
        restore_signals({})
    elif not stopping:
        restore_signals(previous)


def _one_line(exc: BaseException, limit: int | None = 500) -> str:
    """``exc``'s words on one line, cut to ``limit`` characters (None: whole, as ``--json`` gives a refusal)."""
    # a path that is not UTF-8 holds the file system's escapes (os.fsdecode): shown as \udcXX on any stream
    text = " ".join(str(exc).split()).encode("utf-8", "backslashreplace").decode("utf-8")
    return (text if limit is None or len(text) <= limit else text[:limit - 3] + "...") if text else type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
