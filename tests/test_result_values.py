"""A registration's result is a value: two results of the same registration are equal (``==``, ``in``) however long
each took, a copy or an unpickled one (a worker's) equal to it and as read-only, and an installed pcreg is typed
for mypy (its stub beside a ``py.typed`` marker); a cloud cross-check refuses a callback it would not call."""

import copy
import pickle
import shutil
import subprocess
import venv
from pathlib import Path

import numpy as np
import pytest

import pcreg
from pcreg.registration.result import IcpIteration, RegistrationResult


def _pair() -> tuple:
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 10, (100, 3))
    options = pcreg.ICPOptions(max_correspondence_distance=1)
    return pcreg.icp(p, p + 0.1, options), pcreg.icp(p, p + 0.1, options)


def test_two_results_of_one_registration_are_equal_and_others_not():
    a, b = _pair()
    assert a == b and b in [a] and hash(a) == hash(b) and len({a, b}) == 1
    assert copy.deepcopy(a) == a
    moved = RegistrationResult(a.matrix + np.eye(4) * 1e-9, a.fitness, a.inlier_rmse, a.iterations, a.converged,
                               a.backend, frames=a.frames)
    assert moved != a and a != "a result"
    nan = RegistrationResult(a.matrix, float("nan"), float("nan"), -1, None, "py:mine", frames=a.frames)
    assert nan == RegistrationResult(a.matrix, float("nan"), float("nan"), -1, None, "py:mine", frames=a.frames)
    assert nan != RegistrationResult(a.matrix, float("nan"), float("nan"), -1, None, "py:theirs", frames=a.frames)
    from pcreg.registration.result import ImageEvidence

    def evidence(r):  # an image's result with a NaN in its evidence, and float32 scores (a user's backend)
        return RegistrationResult(np.eye(3), np.float32("nan"), np.float32(0.5), 3, True, "py:mine", frames="T_ref_mov",
                                  evidence=ImageEvidence(float("nan"), 0.1, r, "edges"))

    assert evidence(0.9) == evidence(0.9) == pickle.loads(pickle.dumps(evidence(0.9))) != evidence(0.8)
    step = IcpIteration("reference", 0, 1, a.matrix, 0.5, 0.1, np.zeros((3, 3)), None, np.array([0, -1, 2]))
    assert step == copy.deepcopy(step) and hash(step) == hash(copy.deepcopy(step))
    assert step != IcpIteration("reference", 0, 1, a.matrix, 0.5, 0.1, np.ones((3, 3)), None, np.array([0, -1, 2]))


def test_an_unpickled_or_copied_result_is_as_read_only_as_the_original():
    a, _ = _pair()
    for other in (pickle.loads(pickle.dumps(a)), copy.deepcopy(a), copy.copy(a)):
        assert other == a
        with pytest.raises(ValueError, match="read-only"):
            other.matrix[0, 3] = 999.0


def test_a_cloud_cross_check_refuses_a_callback_it_would_not_call():
    rng = np.random.default_rng(0)
    target = rng.uniform(0, 10, (300, 3))
    with pytest.raises(pcreg.errors.InputError, match="callback"):
        pcreg.crosscheck(target, target + 0.05, callback=lambda it: None)


def test_an_installed_pcreg_is_typed_for_mypy(tmp_path, monkeypatch):
    """pcreg copied into a fresh environment's site-packages, as a wheel installs it: mypy reads its stub (a value
    of pcreg's assigned to an int is an error), where without ``py.typed`` it skipped pcreg as untyped (all Any)."""
    api = pytest.importorskip("mypy.api")
    env = tmp_path / "env"
    venv.create(env, with_pip=False)
    python = env / "bin" / "python"
    site = Path(subprocess.check_output([str(python), "-c", "import site; print(site.getsitepackages()[0])"], text=True).strip())
    shutil.copytree(Path(pcreg.__file__).parent, site / "pcreg", ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.chdir(tmp_path)  # mypy looks in the working directory first: not the checkout's pcreg
    user = tmp_path / "user.py"
    user.write_text("import pcreg\n\nx: int = pcreg.icp\n")
    out, err, rc = api.run(["--python-executable", str(python), "--no-incremental", "--cache-dir", str(tmp_path / "cache"),
                            "--no-error-summary", "--follow-imports", "silent", str(user)])
    assert "py.typed" not in out, out
    assert rc == 1 and "Incompatible types in assignment" in out, (out, err)
