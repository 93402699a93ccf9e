"""numba's compiler for pcreg's kernels, with an on-disk cache that knows which sources a kernel uses.

numba caches a compiled function under a stamp of the file that defines it, alone. A pcreg kernel also
compiles in the kernels it calls from other files (the ICP loop in ``reference.py`` inlines the grid
search of ``nn.py``), so after a change to ``nn.py`` alone numba would load the ICP loop compiled with
the old search: the code that runs would not be the code on disk. Here every kernel of pcreg is cached
under a stamp of all of pcreg's kernel sources (its files that mention ``njit``): any change to one of
them compiles every kernel again, once, and ``make setup`` (``python -m pcreg.kernels``) does that
before a command needs it.

The cache folders are numba's own: ``NUMBA_CACHE_DIR`` when it is set, else the ``__pycache__`` folders
beside the sources, else numba's folder in the user's cache. Kernel modules import ``njit`` and
``prange`` from here, so that the cache is set up before the first kernel is defined.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

from numba import njit, prange
from numba.core import caching

__all__ = ["njit", "prange", "kernel_sources_stamp"]

_PACKAGE = Path(__file__).resolve().parent


@functools.lru_cache(maxsize=None)
def _stamp(files: tuple[tuple[str, int, int], ...]) -> str:
    digest = hashlib.sha256()
    for name, _, _ in files:
        text = (_PACKAGE / name).read_bytes()
        if b"njit" in text:
            digest.update(name.encode() + b"\0" + text + b"\0")
    return digest.hexdigest()


def kernel_sources_stamp() -> str:
    """A hash of the names and contents of pcreg's source files that mention ``njit`` (read again
    whenever a file's size or modification time changes)."""
    files = []
    for path in sorted(_PACKAGE.rglob("*.py")):
        st = path.stat()
        files.append((path.relative_to(_PACKAGE).as_posix(), st.st_mtime_ns, st.st_size))
    return _stamp(tuple(files))


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
    raise ImportError(f"numba.core.caching has none of {names}")  # pragma: no cover - numba>=0.60


_LOCATORS = tuple(type(f"Pcreg{base.__name__.lstrip('_')}", (_KernelStamp, base), {})
                  for base in (_numba("UserProvidedCacheLocator", "_UserProvidedCacheLocator"),
                               _numba("InTreeCacheLocator", "_InTreeCacheLocator"),
                               _numba("UserWideCacheLocator", "_UserWideCacheLocator")))


def _install() -> None:
    """Put pcreg's locators before numba's own (numba picks the first that takes a function)."""
    impl = _numba("CacheImpl", "_CacheImpl")
    if not any(isinstance(c, type) and issubclass(c, _KernelStamp) for c in impl._locator_classes):
        impl._locator_classes = [*_LOCATORS, *impl._locator_classes]


_install()
