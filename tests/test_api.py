"""The public API: every name in ``pcreg.__all__`` resolves, and the type stub lists exactly those names."""

import importlib.util
import sys
from pathlib import Path

import pytest

import pcreg

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("name", pcreg.__all__)
def test_public_name_resolves(name):
    """Each name is its module's own object (a module for ``transforms``), not a wrapper around it."""
    module = importlib.import_module(pcreg._EXPORTS[name])
    expected = module if name in pcreg._MODULES else getattr(module, name)
    assert getattr(pcreg, name) is expected
    assert not hasattr(expected, "__wrapped__")


def test_stub_is_current():
    spec = importlib.util.spec_from_file_location("make_stub", ROOT / "tools" / "make_stub.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert (ROOT / "pcreg" / "__init__.pyi").read_text() == mod.stub_text(), "run python tools/make_stub.py"


def test_import_is_cheap():
    """``import pcreg`` loads neither Open3D nor rerun nor scikit-learn (they load on first use)."""
    import subprocess

    code = "import sys, pcreg; print(','.join(m for m in ('open3d', 'rerun', 'sklearn', 'cv2') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
