"""A SIGINT landing while pcreg is in native code that calls back into Python (numba loading a kernel through
LLVM, OpenCV reading an error of its own): the KeyboardInterrupt is raised once that call returns, not inside it,
where the native code cannot take it. Raised inside, ``pcreg evaluate sequence`` stopped by Ctrl-C ended now and
then by SIGSEGV instead of exit 130 (a null pointer in numba's loading of a cached kernel; a NULL that cv2 does
not check in ``cv2.Canny``). The signal is raised in the process itself, at the moment the native code would
run the handler."""

from __future__ import annotations

import signal

import numpy as np
import pytest

from pcreg import _signals
from pcreg._jit import njit
from pcreg.registration import clouds


@pytest.fixture
def handled():
    """pcreg's handlers for SIGINT and SIGTERM, as the command line installs them, put back afterwards."""
    previous = _signals.interrupt_on_signals()
    try:
        yield
    finally:
        _signals.restore_signals(previous)


def test_a_signal_while_a_kernel_is_compiled_is_raised_once_it_is_ready(handled, monkeypatch):
    @njit(cache=False)
    def twice(x):
        return 2 * x

    compile_whole = twice.compile

    def compile_signalled(sig):
        signal.raise_signal(signal.SIGINT)  # as when it lands in llvmlite's callbacks from LLVM
        return compile_whole(sig)

    monkeypatch.setattr(twice, "compile", compile_signalled)
    with pytest.raises(KeyboardInterrupt):
        twice(3)
    assert len(twice.overloads) == 1  # compiled whole before the interrupt was raised
    _signals._RECEIVED.clear()
    assert twice(3) == 6


def test_a_signal_during_canny_is_raised_after_it(handled, monkeypatch):
    canny = clouds.cv2.Canny
    returned = []

    def canny_signalled(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)  # as when cv2 reads its first form's error (PyObject_Str runs the handler)
        returned.append(canny(*args, **kwargs))
        return returned[-1]

    monkeypatch.setattr(clouds.cv2, "Canny", canny_signalled)
    image = (np.random.default_rng(0).random((64, 64, 3)) * 255).astype(np.uint8)
    with pytest.raises(KeyboardInterrupt):
        clouds.image_cloud(image)
    assert len(returned) == 1  # Canny ran to its end; the interrupt came after it


def test_a_signal_while_a_recording_stream_is_made_is_raised_once_it_is_whole(handled, monkeypatch):
    """``pcreg demo`` stopped by SIGTERM as it began its recording printed, after "pcreg: interrupted", a traceback of
    rerun's finalizer: the KeyboardInterrupt raised inside ``RecordingStream``'s constructor left it without its native
    part (``'RecordingStream' object has no attribute 'inner'``)."""
    import gc
    import sys

    import rerun.recording_stream as rs

    from pcreg.recording.readback import whole_stream

    made = rs.bindings.new_recording
    unraisable = []

    def made_signalled(*args, **kwargs):
        inner = made(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)  # as when it lands while rerun makes its native stream
        return inner

    monkeypatch.setattr(rs.bindings, "new_recording", made_signalled)
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    with pytest.raises(KeyboardInterrupt):
        whole_stream("pcreg-test", recording_id="interrupted")
    gc.collect()
    assert unraisable == []
    _signals._RECEIVED.clear()
    monkeypatch.undo()
    assert whole_stream("pcreg-test", recording_id="again").inner is not None
