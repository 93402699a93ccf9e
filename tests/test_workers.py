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
    assert found["numpy"].startswith("numpy ") and found["sklearn"].startswith("scikit-learn ")


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
