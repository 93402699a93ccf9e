"""The on-disk kernel cache (pcreg._jit) follows a change to a kernel that another file's kernel calls:
numba alone stamps a cached kernel with its own file and would load the caller compiled with the old
callee."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

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
