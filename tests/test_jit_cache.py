"""The on-disk kernel cache (pcreg._jit) follows a change to a kernel that another file's kernel calls:
numba alone stamps a cached kernel with its own file and would load the caller compiled with the old
callee."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

import pcreg

CALLER = """
from ._jit import njit
from ._cache_probe_callee import inner


@njit(cache=True)
def outer():
    return inner() + 1
"""

CALLEE = """
from ._jit import njit


@njit(cache=True)
def inner():
    return {value}
"""


def _outer(root: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(root)}
    env.pop("NUMBA_CACHE_DIR", None)
    code = "import pcreg._cache_probe_caller as m; print(m.outer())"
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=root, capture_output=True, text=True, check=True,
                          timeout=300).stdout.strip()


def test_a_kernel_is_compiled_again_when_a_kernel_it_calls_changes(tmp_path):
    package = tmp_path / "pcreg"
    shutil.copytree(Path(pcreg.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    (package / "_cache_probe_caller.py").write_text(CALLER)
    callee = package / "_cache_probe_callee.py"
    callee.write_text(CALLEE.format(value=1))
    assert _outer(tmp_path) == "2"
    assert any(p.suffix == ".nbi" for p in (package / "__pycache__").iterdir())  # cached on disk
    assert _outer(tmp_path) == "2"  # loaded back
    callee.write_text(CALLEE.format(value=10))
    assert _outer(tmp_path) == "11"  # numba alone would load the caller's old code and print 2


UNWRITABLE = """
import os, tempfile, warnings
from numba.core import caching

def unwritable(self):  # what a folder the user cannot write gives numba's check: PermissionError
    raise PermissionError(13, "Permission denied", self.get_cache_path())

caching._CacheLocator.ensure_cache_path = unwritable
warnings.simplefilter("always")
with warnings.catch_warnings(record=True) as caught:
    import numpy as np
    from pcreg.registration.motion import field_from_matrix
    from pcreg.pipeline import prior  # more kernels, no second warning
    field = field_from_matrix(np.eye(3), (4, 5))
print(field[3, 4].tolist())
print(len(caught), caught[0].category.__name__, caught[0].message)
"""


def test_kernels_compile_uncached_with_one_warning_where_no_cache_folder_is_writable(tmp_path):
    """pcreg installed in a folder its user cannot write, ``$HOME`` not writable either: numba refused every
    cached kernel as it was defined, and every command ended at import (exit 1), ``--help`` included."""
    package = tmp_path / "pcreg"
    shutil.copytree(Path(pcreg.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    env.pop("NUMBA_CACHE_DIR", None)
    run = subprocess.run([sys.executable, "-c", UNWRITABLE], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    value, warned = run.stdout.strip().splitlines()
    assert value == "[4.0, 3.0]"
    assert warned.startswith("1 RuntimeWarning pcreg: no folder is writable for the compiled kernels' cache")
    assert "NUMBA_CACHE_DIR" in warned
    assert not (package / "__pycache__").exists() or not any((package / "__pycache__").glob("*.nbi"))


FIRST_CALL = """
import numpy as np
from pcreg.registration.motion import field_from_matrix
from pcreg.registration.kdtree import warm_up

field_from_matrix(np.eye(3), (4, 5))
warm_up()  # more kernels: no second note
"""


def test_a_process_says_once_that_it_compiles_the_kernels_the_cache_lacks(tmp_path):
    """After ``pip install``, the first registration compiled the kernels for a minute or more without a word and
    reported that minute as its own time: the first kernel the on-disk cache cannot give is announced, once, on the
    ``pcreg`` logger; a process that loads them from the cache says nothing."""
    from pcreg._jit import COMPILING

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    said = [subprocess.run([sys.executable, "-c", FIRST_CALL], env=env, capture_output=True, text=True, check=True,
                           timeout=300).stderr for _ in range(2)]
    assert said[0].splitlines() == [COMPILING]
    assert said[1] == ""


def test_the_command_line_writes_the_librarys_notes_above_a_progress_bar(capsys):
    import logging

    from pcreg._jit import COMPILING
    from pcreg._runner import progress, say_above_bars

    logger = logging.getLogger("pcreg")
    handlers, propagate = list(logger.handlers), logger.propagate
    try:
        say_above_bars()
        say_above_bars()  # once, however often asked
        with progress(total=3, desc="frames", disable=False) as bar:
            bar.update(1)
            logger.warning(COMPILING)
        err, propagated = capsys.readouterr().err, logger.propagate
    finally:
        logger.handlers[:], logger.propagate = handlers, propagate
    assert err.count(COMPILING) == 1 and propagated == propagate  # a caller's root handlers still see it
    assert f"\r{COMPILING}\n" in err  # on a line of its own, the bar's cleared first (not written after its text)


def test_a_note_that_cannot_be_written_is_lost_and_the_command_goes_on(monkeypatch):
    """The note written to a stderr whose reader is gone (``2> >(exec true)``) raised BrokenPipeError from the
    kernel's first call, and the command ended without its result."""
    import logging
    import os

    from pcreg._jit import COMPILING
    from pcreg._runner import _AboveBars

    read, write = os.pipe()
    os.close(read)
    with os.fdopen(write, "w", buffering=1) as gone:  # line-buffered, as a terminal's stderr: the write reaches the pipe
        monkeypatch.setattr(sys, "stderr", gone)
        _AboveBars().handle(logging.LogRecord("pcreg", logging.WARNING, __file__, 1, COMPILING, None, None))
        monkeypatch.undo()
        try:
            gone.close()
        except BrokenPipeError:  # what the failed write left in its buffer
            pass


WORKERS_FIRST_CALL = """
import multiprocessing
import numpy as np

from pcreg._runner import make_executor


def compile_here(barrier):
    from pcreg.registration.motion import field_from_matrix

    barrier.wait(timeout=120)  # both workers hold a task: each compiles the kernel itself
    field_from_matrix(np.eye(3), (4, 5))
    import os
    return os.getpid()


def compile_another():
    from pcreg.registration.kdtree import warm_up

    warm_up()


if __name__ == "__main__":
    import os

    from pcreg._runner import COMPILING_NOTE, one_compiling_note

    with one_compiling_note(), multiprocessing.Manager() as manager:  # one command, two pools (as pcreg demo's)
        barrier = manager.Barrier(2)
        with make_executor(2) as pool:
            pids = {f.result() for f in [pool.submit(compile_here, barrier) for _ in range(2)]}
        assert len(pids) == 2, pids
        with make_executor(2) as pool:  # new workers, other kernels not cached yet: nothing said again
            pool.submit(compile_another).result()
    assert COMPILING_NOTE not in os.environ
"""


def test_the_workers_of_one_command_say_it_once_among_them(tmp_path):
    """With ``--workers 2`` on an empty cache each worker said that it compiles the kernels: two lines alike (and a
    command of two pools, as ``pcreg demo``, would say it in each). The parent does not load numba for it."""
    from pcreg._jit import _AMONG, COMPILING
    from pcreg._runner import COMPILING_NOTE

    assert _AMONG == COMPILING_NOTE

    script = tmp_path / "two_workers.py"
    script.write_text(WORKERS_FIRST_CALL)
    # a temporary folder of its own, of a short path: the manager's socket lives there (108 bytes at most)
    temporary = Path(tempfile.mkdtemp(prefix="note"))
    try:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "TMPDIR": str(temporary)}
        ran = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=600)
        assert ran.returncode == 0, ran.stderr[-3000:]  # the script's own traceback, where it failed
        said = ran.stderr
        assert said.splitlines() == [COMPILING]
        assert not [p for p in temporary.iterdir() if p.name.startswith("pcreg-")]  # what the note was told by: gone
    finally:
        shutil.rmtree(temporary, ignore_errors=True)


def test_a_machine_without_a_writable_temporary_folder_still_runs_commands(monkeypatch, capsys):
    """The note's file lives in the temporary folder: where there is none to write (a read-only container),
    ``tempfile.gettempdir`` raises, and every command would have ended as a bug before it began."""
    import tempfile

    from pcreg.cli import main

    def none_usable():
        raise FileNotFoundError(2, "No usable temporary directory found in ['/tmp']")

    monkeypatch.setattr(tempfile, "gettempdir", none_usable)
    with pytest.raises(SystemExit) as ended:  # argparse's own exit after printing the version
        main(["--version"])
    assert ended.value.code == 0 and "pcreg" in capsys.readouterr().out


@pytest.mark.slow
def test_the_kernels_compile_stopped_by_ctrl_c_ends_in_one_line_and_130(tmp_path):
    """``python -m pcreg.kernels`` (what ``make`` runs after installing) stopped while it compiled printed some 100
    lines of numba's traceback and ended in exit 1, or swallowed the Ctrl-C in LLVM's callback and went on: it takes
    pcreg's signals, as a command does, and ends with one line and exit 130 once the kernel under way is compiled."""
    import signal

    from pcreg._jit import COMPILING

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.Popen([sys.executable, "-m", "pcreg.kernels"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stderr.readline().rstrip("\n") == COMPILING  # compiling now: the event to stop it at
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=600)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert err.splitlines() == ["pcreg: interrupted while compiling the kernels (those compiled are kept; python -m "
                                "pcreg.kernels, or make, goes on)"], err
    assert out == ""


def test_numba_disable_jit_runs_the_kernels_as_python(tmp_path):
    """``NUMBA_DISABLE_JIT=1`` (numba's switch for debugging a kernel in Python): pcreg's first-call shield looked up
    numba's compile-on-call on what njit gave back, the Python function itself, and every command, ``--version``
    included, ended in a 44-line traceback."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    code = ("import numpy as np; from pcreg.registration.motion import field_from_matrix; "
            "print(field_from_matrix(np.eye(3), (4, 5))[3, 4].tolist())")
    run = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "[4.0, 3.0]", run.stderr
    version = subprocess.run([sys.executable, "-m", "pcreg", "--version"], env=env, cwd=tmp_path, capture_output=True,
                             text=True, timeout=300)
    assert version.returncode == 0 and version.stdout.startswith("pcreg "), version.stderr
