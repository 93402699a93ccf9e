"""What C and C++ libraries print, kept off the terminal (OpenCV's codecs, Open3D's readers)."""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Iterator


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
    the captured text after the block; nothing of it reaches the terminal or ``--json`` output."""
    import tempfile

    captured: list[str] = []
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:
        yield captured
        return
    import io

    py_out, py_err = sys.stdout, sys.stderr
    text = io.StringIO()  # Open3D's Python module prints its log through Python's sys.stdout
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            sys.stdout = sys.stderr = text
            yield captured
        finally:
            sys.stdout, sys.stderr = py_out, py_err
            _flush_c_stdio()  # C++ code writes through libc's buffers: empty them into the capture
            for stream in (sys.stdout, sys.stderr):
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
