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


def test_icp_keywords_of_before_0_2_still_work_with_a_deprecation_warning():
    """``pcreg.icp(..., backend=...)`` (before 0.2.0) gives what ``pcreg.icp(..., ICPOptions(...))`` gives,
    and warns naming the new spelling; a keyword that never existed is still a TypeError."""
    import numpy as np

    rng = np.random.default_rng(0)
    target = rng.uniform(0, 50, (300, 2))
    c, s = np.cos(0.05), np.sin(0.05)
    source = (target - 25) @ np.array([[c, -s], [s, c]]).T + 25 + [0.7, -0.4]
    new = pcreg.icp(source, target, pcreg.ICPOptions(model="rigid", max_iteration=40, max_correspondence_distance=5.0))
    with pytest.warns(DeprecationWarning, match=r"pcreg\.ICPOptions\(.*max_iteration=.*\)"):
        old = pcreg.icp(source, target, model="rigid", max_iteration=40, max_correspondence_distance=5.0)
    np.testing.assert_array_equal(old.matrix, new.matrix)
    assert old.iterations == new.iterations
    sched = pcreg.icp(source, target, pcreg.ICPOptions(schedule=pcreg.VoxelSchedule((4.0, 1.0))))
    with pytest.warns(DeprecationWarning, match=r"schedule=pcreg\.VoxelSchedule"):
        old_sched = pcreg.icp(source, target, voxel_sizes=(4.0, 1.0))
    np.testing.assert_array_equal(old_sched.matrix, sched.matrix)
    with pytest.raises(TypeError, match="unexpected keyword argument 'backnd'"):
        pcreg.icp(source, target, backnd="open3d")
    with pytest.raises(TypeError, match="not both"):
        pcreg.icp(source, target, pcreg.ICPOptions(), backend="open3d")
