"""numba's compiler for pcreg's kernels, with an on-disk cache that knows which sources a kernel uses.

numba caches a compiled function under a stamp of the file that defines it, alone. A pcreg kernel also
compiles in the kernels it calls from other files (the ICP loop in ``reference.py`` inlines the KD-tree
search of ``_kd_kernels.py``), so after a change to that file alone numba would load the ICP loop compiled with
the old search: the code that runs would not be the code on disk. Here every kernel of pcreg is cached
under a stamp of all of pcreg's kernel sources (its files that mention ``njit``): any change to one of
them compiles every kernel again, once, and ``make setup`` (``python -m pcreg.kernels``) does that
before a command needs it.

A kernel is compiled, or loaded from the cache, on its first call in a process, with a termination signal
shielded (:func:`_shield_first_calls`): Ctrl-C or SIGTERM landing then is raised once the kernel is ready. Before
the first kernel that the cache cannot give, a process says that it compiles them (:data:`COMPILING`); the
processes of one command (it and its workers) say it once among them (:func:`pcreg._runner.one_compiling_note`).

The cache folders are numba's own: ``NUMBA_CACHE_DIR`` when it is set, else the ``__pycache__`` folders
beside the sources, else numba's folder in the user's cache. Kernel modules import ``njit`` and
``prange`` from here, so that the cache is set up before the first kernel is defined.
"""

from __future__ import annotations

import hashlib
import logging
import os
import pickle
import threading
from pathlib import Path

import numba
from numba import prange
from numba.core import caching

__all__ = ["CACHED", "COMPILING", "KERNEL_SOURCES_STAMP", "njit", "prange", "kernel_sources_stamp"]

_PACKAGE = Path(__file__).resolve().parent


def _sources_stamp() -> str:
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        text = path.read_bytes()
        if b"njit" in text:
            digest.update(path.relative_to(_PACKAGE).as_posix().encode() + b"\0" + text + b"\0")
    return digest.hexdigest()


#: A hash of the names and contents of pcreg's source files that mention ``njit``, read once, when the
#: kernels' compiler is imported (2-3 ms): the kernels a process compiles come from the sources it
#: imported, and numba asks for the stamp once per kernel (39 times for a registration).
KERNEL_SOURCES_STAMP: str = _sources_stamp()


def kernel_sources_stamp() -> str:
    """:data:`KERNEL_SOURCES_STAMP`."""
    return KERNEL_SOURCES_STAMP


class _KernelStamp:
    """Mixin for numba's file-backed locators: only for pcreg's files, and the stamp of all of pcreg's
    kernel sources beside the file's own."""

    def get_source_stamp(self):
        return (super().get_source_stamp(), kernel_sources_stamp())

    @classmethod
    def from_function(cls, py_func, py_file):
        if not Path(py_file).resolve().is_relative_to(_PACKAGE):
            return None
        return super().from_function(py_func, py_file)


def _numba(*names: str):
    """The first of ``names`` that numba's caching module has (names lost their underscore in 0.61)."""
    for name in names:
        if hasattr(caching, name):
            return getattr(caching, name)
    raise AttributeError(f"numba.core.caching has none of {names}")


def _install() -> bool:
    """Put pcreg's locators before numba's own (numba picks the first that takes a function). False,
    changing nothing, where this numba lays out its caching otherwise."""
    try:
        bases = (_numba("UserProvidedCacheLocator", "_UserProvidedCacheLocator"),
                 _numba("InTreeCacheLocator", "_InTreeCacheLocator"),
                 _numba("UserWideCacheLocator", "_UserWideCacheLocator"))
        impl = _numba("CacheImpl", "_CacheImpl")
        classes = list(impl._locator_classes)
    except AttributeError:  # pragma: no cover - a numba whose caching has moved
        return False
    if not any(isinstance(c, type) and issubclass(c, _KernelStamp) for c in classes):
        impl._locator_classes = [*(type(f"Pcreg{b.__name__.lstrip('_')}", (_KernelStamp, b), {}) for b in bases),
                                 *classes]
    return True


#: Whether pcreg's kernels are cached on disk: where this numba's caching cannot be keyed to all of the
#: kernel sources, they are compiled anew in each process rather than risk loading one built from
#: older sources.
CACHED = _install()


#: What a process says (once in each process, once among a command's: :func:`pcreg._runner.one_compiling_note`; on the ``pcreg`` logger, as a warning)
#: before a kernel compiles with nothing in the on-disk cache for it, as after ``pip install`` or a change to a
#: kernel source: the first registration would otherwise wait a minute or more without a word, and report that
#: minute as its own time.
COMPILING = ("pcreg: note: compiling the kernels this command uses for this machine, once (up to a minute or two; "
             "they are kept on disk for the next runs; python -m pcreg.kernels compiles all of them ahead)")

_TOLD: list[bool] = []
_TELLING = threading.Lock()
_AMONG = "_PCREG_COMPILING_NOTE"  # pcreg._runner.COMPILING_NOTE, named here so that neither module loads the other


def _first_among() -> bool:
    """Whether this process is the first of its command to say :data:`COMPILING`: the first to create the file the
    environment names (:func:`pcreg._runner.one_compiling_note`); a process outside one is alone."""
    path = os.environ.get(_AMONG)
    if not path:
        return True
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except FileExistsError:
        return False
    except OSError:  # a temporary folder gone or full: said, as by a process alone
        return True
    return True


def _compiles(dispatcher) -> bool:
    """Whether ``dispatcher``'s call is its first in this process and the on-disk cache holds nothing for it
    (numba's index of the kernel missing, or of older sources), while :data:`COMPILING` is not said yet."""
    if _TOLD or dispatcher.overloads:
        return False
    index = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)  # none where not cached
    try:
        return index is not None and not index._load_index()
    except (OSError, EOFError, pickle.UnpicklingError):  # an index numba cannot read: numba's own load says so
        return False


def _shield_first_calls(dispatcher):
    """``dispatcher`` with its compile-on-call (numba's ``_compile_for_args``, which its C entry looks up on the
    instance on a call no compiled version fits) run with SIGINT and SIGTERM noted, not raised
    (:func:`pcreg._signals._shielded`), and the KeyboardInterrupt raised as it returns.

    Loading a cached kernel goes through LLVM, which calls back into Python (llvmlite's object cache, through
    ctypes); a KeyboardInterrupt raised in such a callback is dropped by ctypes (printed as an exception it
    could not raise, which the command line keeps off stderr), and LLVM goes on without the compiled code:
    numba then wrote the kernel's environment through a null pointer, and the process ended by SIGSEGV
    instead of exit 130."""
    from ._signals import _shielded, check_interrupted

    compile_for_args = getattr(dispatcher, "_compile_for_args", None)
    if compile_for_args is None:  # NUMBA_DISABLE_JIT=1: numba's njit gave the Python function back, nothing compiles
        return dispatcher

    def compile_shielded(*args, **kws):
        if _compiles(dispatcher):
            with _TELLING:
                told, _TOLD[:] = bool(_TOLD), [True]
            if not told and _first_among():
                logging.getLogger("pcreg").warning(COMPILING)
        with _shielded():
            entry = compile_for_args(*args, **kws)
        check_interrupted()
        return entry

    dispatcher._compile_for_args = compile_shielded
    return dispatcher


#: numba's refusal for the first kernel that found no writable cache folder (then every kernel is compiled
#: anew in each process, and a warning said so once); empty while the cache works.
_UNCACHED: list[str] = []


def _uncached(fn, options: dict, error: RuntimeError):
    """``fn`` compiled without the on-disk cache, after numba found no cache folder it can write (``error``):
    numba's ``RuntimeError`` there ended every command at import (exit 1), even ``--help``, where pcreg is
    installed in a folder its user cannot write and ``$HOME`` is not writable either (a read-only container,
    a service's user). Warned once, with how to keep the kernels."""
    import warnings

    if "no locator available" not in str(error):
        raise error
    if not _UNCACHED:
        _UNCACHED.append(str(error))
        warnings.warn("pcreg: no folder is writable for the compiled kernels' cache (neither beside pcreg's "
                      "sources nor in the user's cache folder), so each process compiles them again, adding "
                      "up to a minute to its first registration; set NUMBA_CACHE_DIR to a writable folder to keep them",
                      RuntimeWarning, stacklevel=4)
    return numba.njit(**{**options, "cache": False})(fn)


def njit(*args, **options):
    """``numba.njit`` with the options given, its on-disk cache keyed to all of pcreg's kernel sources
    (``cache=False`` where that cannot be done, :data:`CACHED`, or where no cache folder is writable,
    :func:`_uncached`), its first calls shielded from a signal's KeyboardInterrupt
    (:func:`_shield_first_calls`)."""
    if not CACHED:  # pragma: no cover - see CACHED
        options["cache"] = False

    def compiled(fn):
        try:
            made = numba.njit(**options)(fn)
        except RuntimeError as error:
            if not options.get("cache"):
                raise
            made = _uncached(fn, options, error)
        return _shield_first_calls(made)

    if args:  # ``@njit`` bare (pcreg's kernels give no signatures)
        (fn,) = args
        return compiled(fn)
    return compiled
