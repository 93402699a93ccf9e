"""What a dask worker must share with the command for its units' numbers to be the command's (``pcreg._workers``):
the checks a unit makes on its worker before it runs, in this process (the cluster's own in test_distributed.py)."""

from __future__ import annotations

import pickle

import pytest

import pcreg._workers as W
from pcreg.errors import PcregError


def test_the_fingerprint_names_pcreg_its_code_and_the_libraries():
    found = W.fingerprint()
    assert list(found) == ["pcreg", "code", *W.LIBRARIES]
    assert len(found["code"]) == 16 and int(found["code"], 16) >= 0
    from importlib.metadata import version

    assert found["numpy"] == version("numpy") and found["sklearn"] == version("scikit-learn")  # by version alone


def test_the_code_digest_reads_modules_alone_and_line_endings_as_one(tmp_path):
    """An editor's lock file (a dangling link named ``.#run.py``) ended the command in a traceback; a checkout with
    CRLF line endings is the same code; a module changed is not."""
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "a.py").write_bytes(b"x = 1\ny = 2\n")
    (tmp_path / "pkg" / "sub" / "b.py").write_bytes(b"z = 3\n")
    before = W.source_digest(tmp_path / "pkg")
    (tmp_path / "pkg" / "sub" / ".#b.py").symlink_to("root@host.1234:1700000000")  # as Emacs leaves it
    (tmp_path / "pkg" / "__pycache__").mkdir()
    (tmp_path / "pkg" / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"compiled")
    (tmp_path / "pkg" / "a.py").write_bytes(b"x = 1\r\ny = 2\r\n")
    assert W.source_digest(tmp_path / "pkg") == before
    (tmp_path / "pkg" / "a.py").write_bytes(b"x = 1\ny = 3\n")
    assert W.source_digest(tmp_path / "pkg") != before


@pytest.mark.parametrize("change, said", [
    ({"code": "0" * 16}, "it runs pcreg {pcreg} with other code (its modules' digest {code}, here 0000000000000000)"),
    ({"pcreg": "0.1.0"}, "it runs pcreg {pcreg}, here 0.1.0"),
    ({"open3d": "open3d 0.1"}, "it has open3d {open3d}, here open3d 0.1"),
])
def test_a_difference_is_named_first_of_all(change, said):
    found = W.fingerprint()
    assert W.mismatch({**found, **change}, found) == said.format(**found)
    assert W.mismatch(found, dict(found)) is None


def test_a_unit_runs_on_a_worker_that_matches():
    call = pickle.dumps((divmod, (17, 5), {}))
    assert W.run_checked(W.fingerprint(), call) == (3, 2)


def test_a_unit_on_a_worker_that_differs_is_refused_before_it_is_read(monkeypatch):
    """Refused before the call is unpickled (unpickling imports the unit's modules, numba among them): a call that
    cannot be unpickled at all is never reached."""
    with pytest.raises(PcregError, match=r"^a worker: it runs pcreg .* with other code .* rerun the same command"):
        W.run_checked({**W.fingerprint(), "code": "0" * 16}, b"not a pickle")
    monkeypatch.setenv("NUMBA_NUM_THREADS", "0")
    with pytest.raises(PcregError, match=r"^a worker: NUMBA_NUM_THREADS='0': numba's number of threads"):
        W.run_checked(W.fingerprint(), b"not a pickle")
