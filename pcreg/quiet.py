"""What C and C++ libraries print, kept off the terminal (OpenCV's codecs, Open3D's readers)."""

from __future__ import annotations

import contextlib
import io
import os
import sys
import threading
from typing import Iterator

#: Held while file descriptors 1 and 2 point into a capture. They are the process's own, so two threads
#: capturing at once (``pcreg run`` decodes a frame on its reader thread while its writer reads a truth
#: map) would each restore what the other had put there, and leave the terminal writing into a closed
#: temporary file.
_FDS = threading.RLock()


def _flush_c_stdio() -> None:
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


@contextlib.contextmanager
def capture_output_fds() -> Iterator[list[str]]:
    """Capture what C/C++ code writes to file descriptors 1 and 2 for the duration (Open3D reports a
    failed read only as a printed warning, on stdout; RPly prints on stderr). Yields a list that holds
    the captured text after the block; nothing of it reaches the terminal or ``--json`` output. One
    capture at a time in the process; Python's own ``sys.stdout`` and ``sys.stderr`` are taken over only
    on the main thread (Open3D's Python module prints through them), so that a capture on another
    thread does not take the main thread's printing."""
    with _FDS:
        with _captured(threading.current_thread() is threading.main_thread()) as captured:
            yield captured


class _Kept(io.StringIO):
    """The capture of Python's ``sys.stdout`` and ``sys.stderr``: code that closes them (a ``py:`` implementation's
    ``sys.stdout.close()``) closes nothing, and what it printed is kept (closed, the capture's read raised
    ValueError, and a cross-check ended as a bug in pcreg without its report)."""

    def close(self) -> None:
        pass


@contextlib.contextmanager
def _captured(python: bool) -> Iterator[list[str]]:
    import tempfile

    captured: list[str] = []
    for stream in (sys.stdout, sys.stderr) if python else ():  # another thread's buffers are its own
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:
        yield captured
        return

    py_out, py_err = sys.stdout, sys.stderr
    text = _Kept()  # Open3D's Python module prints its log through Python's sys.stdout
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            if python:
                sys.stdout = sys.stderr = text
            yield captured
        finally:
            if python:
                sys.stdout, sys.stderr = py_out, py_err
            _flush_c_stdio()  # C++ code writes through libc's buffers: empty them into the capture
            for stream in (sys.stdout, sys.stderr) if python else ():
                try:
                    stream.flush()
                except (OSError, ValueError, AttributeError):
                    pass
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            tmp.seek(0)
            captured.append(text.getvalue()[: 1 << 16] + tmp.read(1 << 16).decode("utf-8", "replace"))
