"""Scale-out on a real dask.distributed cluster (two worker processes on 127.0.0.1): the same results
as a local run, resume, and a worker killed mid-run (its unit is retried; nothing is lost)."""

from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path

import pytest

from _events import HANG, until

pytestmark = pytest.mark.slow  # a local dask cluster per module

distributed = pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")

ARGS = ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "4", "--size", "160x120",
        "--angles", "0,30,60,90,135,180", "--samples", "4"]  # 4 units (one per sampled frame)
# The same 4 units with 37 angles each, about 0.5 s a unit: room to kill a worker while units still run
# (with 6 angles the 3 units left after the first can all finish within one look at the cluster).
LONG_ARGS = [*ARGS[:-4], "--angles", "0:180:5", "--samples", "4"]


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, host="127.0.0.1",
                                  dashboard_address=":0", silence_logs=50) as c:
        yield c


def _errors(out: Path) -> dict:
    res = json.loads((out / "results.json").read_text())
    return {k: v for k, v in res.items() if k not in ("seconds", "resumed_units", "timing")}, res["resumed_units"]


def _units(out: Path) -> list[Path]:
    return sorted(out.glob("units/**/*.json"))


def _diff(a, b, path=""):
    """Leaves where two JSON trees differ (for the assertion message)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in set(a) | set(b) for d in _diff(a.get(k), b.get(k), f"{path}/{k}")]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _diff(x, y, f"{path}/{i}")]
    if "corner_error" in path and isinstance(a, float) and isinstance(b, float) and abs(a - b) < 1e-6:
        # Registration's sub-pixel result differs by ~1e-9 px between any two processes (also between
        # --workers 1 and --workers 2 on one machine); every other number must be identical.
        return []
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def _strip_times(obj):
    if isinstance(obj, dict):
        return {k: _strip_times(v) for k, v in obj.items() if "second" not in k and "time" not in k}
    if isinstance(obj, list):
        return [_strip_times(v) for v in obj]
    return obj


def _local(tmp_path_factory, args: list[str]) -> Path:
    from pcreg.cli import main

    out = tmp_path_factory.mktemp("local") / "rot"
    assert main([*args, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    return _local(tmp_path_factory, ARGS)


@pytest.fixture(scope="module")
def local_long_run(tmp_path_factory):
    return _local(tmp_path_factory, LONG_ARGS)


def test_cluster_gives_the_local_results_and_resumes(cluster, local_run, tmp_path):
    from pcreg.cli import main

    out = tmp_path / "rot"
    assert main([*ARGS, "--scheduler", cluster.scheduler_address, "--out", str(out)]) == 0
    (dist, resumed), (local, _) = _errors(out), _errors(local_run)
    assert resumed == 0
    assert not _diff(_strip_times(dist), _strip_times(local))
    # resume: drop two finished units, rerun on the cluster; the rest come from the first run
    units = _units(out)
    for u in units[:2]:
        u.unlink()
    assert main([*ARGS, "--scheduler", cluster.scheduler_address, "--out", str(out)]) == 0
    again, resumed = _errors(out)
    assert resumed == len(units) - 2
    assert not _diff(_strip_times(again), _strip_times(local))


def test_relative_data_and_class_table_paths_are_read_where_the_command_runs(cluster, tmp_path, monkeypatch):
    """The workers run in another working folder (here the one pytest started in): a relative ``--data`` path
    was read there, refused as "no such folder" (or, where a folder of that name was, scored other frames under
    the right names, exit 0)."""
    from _davis import frames_and_masks, write_pcreg_layout
    from pcreg.cli import main
    from pcreg.experiments.units import for_workers
    from pcreg.experiments.stream import StreamConfig

    for i, name in enumerate(("disc", "dot")):
        write_pcreg_layout(tmp_path / "seqs" / name, frames_and_masks(3, seed=i))
    monkeypatch.chdir(tmp_path)
    args = ["evaluate", "stream", "--data", "davis:seqs", "--methods", "unregistered,plain"]
    assert main([*args, "--out", "local"]) == 0
    assert main([*args, "--scheduler", cluster.scheduler_address, "--out", "dist"]) == 0
    for name in ("stream_reference.csv", "davis_J.csv"):
        assert (tmp_path / "dist" / name).read_text() == (tmp_path / "local" / name).read_text(), name
    assert json.loads((tmp_path / "dist" / "config.json").read_text())["data"] == "davis:seqs"  # as given
    shipped = for_workers(StreamConfig(data="davis:seqs:all", classes="tables/t.json"))
    assert (shipped.data, shipped.classes) == (f"davis:{tmp_path / 'seqs'}:all", str(tmp_path / "tables" / "t.json"))
    assert for_workers(StreamConfig(data="synthetic:syn1a", classes="camvid11")).classes == "camvid11"


def test_a_worker_killed_mid_run_loses_nothing(cluster, local_long_run, tmp_path):
    from pcreg.cli import main

    out = tmp_path / "rot"
    client = distributed.Client(cluster.scheduler_address, set_as_default=False)
    try:
        pids = client.run(os.getpid)  # asked before the run: a busy worker may be slow to answer
        result: list[int] = []
        runner = threading.Thread(target=lambda: result.append(
            main([*LONG_ARGS, "--scheduler", cluster.scheduler_address, "--out", str(out)])))
        runner.start()
        until(lambda: _units(out), what="a finished unit", alive=runner)
        # the worker busy with a unit; between two units none may be, and then either will do
        busy = [w for w, tasks in client.processing().items() if tasks and w in pids] or list(pids)
        n_done = len(_units(out))
        os.kill(pids[busy[0]], signal.SIGKILL)  # the nanny starts a new worker, the scheduler reruns the unit
        runner.join(timeout=HANG)
        assert not runner.is_alive() and result == [0]
    finally:
        client.close()
    n_units = len(_units(local_long_run))
    assert n_units == 4 and n_done < n_units, "the run had ended before the kill"
    res, _ = _errors(out)
    assert len(_units(out)) == n_units
    assert not _diff(_strip_times(res), _strip_times(_errors(local_long_run)[0]))


def test_unreachable_scheduler_is_one_line(capsys, tmp_path):
    import dask

    from pcreg.cli import main

    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):  # gives up after its own timeout
        rc = main([*ARGS, "--scheduler", "tcp://127.0.0.1:9", "--out", str(tmp_path / "never")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "scheduler" in err[0], err


def test_sigterm_cancels_the_cluster_units_and_keeps_the_finished(cluster, tmp_path):
    import subprocess
    import sys

    out = tmp_path / "rot"
    # 91 angles a unit, about 1.2 s: the signal lands while units run; the run is not waited out
    argv = [sys.executable, "-m", "pcreg.cli", *ARGS[:-4], "--angles", "0:180:2", "--samples", "4",
            "--scheduler", cluster.scheduler_address, "--out", str(out)]
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        until(lambda: _units(out), what="a finished unit", alive=p)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=HANG)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130 and "interrupted" in err, err
    kept = _units(out)
    assert 1 <= len(kept) < 4
    _scheduler_drains(cluster)


def _scheduler_drains(cluster) -> None:
    """The units not finished were cancelled on the scheduler: its task list empties."""
    client = distributed.Client(cluster.scheduler_address, set_as_default=False)
    try:
        until(lambda: client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 0,
              what="an empty task list on the scheduler")
    finally:
        client.close()


@pytest.mark.parametrize("phase", ["data", "units", "report"])
def test_a_signal_in_each_phase_of_a_cluster_run_stops_and_resumes(cluster, local_run, monkeypatch, capsys, tmp_path,
                                                                   phase):
    """--scheduler: the signal while the data load, after the first unit came back, while the report is
    written; exit 130, the units not finished are cancelled on the scheduler, the rerun resumes."""
    from test_interrupt_phases import close, interrupt_and_resume

    monkeypatch.setitem(__import__("test_interrupt_phases").COMMANDS, "rotation", ARGS)
    res, kept = interrupt_and_resume(monkeypatch, capsys, tmp_path, "rotation", phase,
                                     ["--scheduler", cluster.scheduler_address])
    n_units = len(_units(local_run))
    # the units that came back before the signal was handled are kept (every one, on a loaded machine); that
    # none was waited for after it, interrupt_and_resume checks
    lo, hi = {"data": (0, 0), "units": (1, n_units), "report": (n_units, n_units)}[phase]
    assert lo <= kept <= hi, f"{kept} of {n_units} units kept"
    local = json.loads((local_run / "results.json").read_text())
    assert not close(_strip_times(res), _strip_times({k: v for k, v in local.items() if k != "resumed_units"}))
    _scheduler_drains(cluster)


def test_a_worker_with_other_pcreg_code_is_refused_before_any_unit(cluster, monkeypatch, capsys, tmp_path):
    """Workers running other pcreg code (another checkout, a hand edit) gave their numbers, kept among the finished
    units without a word (a sweep: every ``before`` 1.00 off, exit 0). Here the command's own code is made to
    differ from the workers' (its digest): exit 2 naming the worker and both digests, no unit run."""
    import pcreg._workers as W
    from pcreg.cli import main

    real = W.fingerprint()
    monkeypatch.setattr(W, "fingerprint", lambda: {**real, "code": "0" * 16})
    out = tmp_path / "rot"
    assert main([*ARGS, "--scheduler", cluster.scheduler_address, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dask worker tcp://127.0.0.1:" in err[0], err
    assert f"other code (its modules' digest {real['code']}, here {'0' * 16})" in err[0] and "rerun" in err[0], err
    assert not _units(out)


@pytest.mark.parametrize("what", ["no pcreg", "an older pcreg", "NUMBA_NUM_THREADS=0"])
def test_a_worker_that_cannot_run_pcreg_is_named_at_once(what, capsys, tmp_path):
    """A worker that cannot import pcreg (not installed there) failed to read each unit and dask ended it: the
    command said after 60 s that the scheduler "has had no worker", and workers started again did the same. One
    with ``NUMBA_NUM_THREADS=0`` was "an internal error, a bug in pcreg". Each is named when the command connects."""
    from pcreg.cli import main

    hide = tmp_path / "hide_pcreg.py"
    module = "pcreg" if what == "no pcreg" else "pcreg._workers"  # a machine without pcreg; with one from before the check
    hide.write_text(f"import sys\nsys.modules[{module!r}] = None\n")
    worker = {"preload": [str(hide)]} if "pcreg" in what else {"env": {"NUMBA_NUM_THREADS": "0"}}
    with distributed.LocalCluster(n_workers=1, processes=True, threads_per_worker=1, host="127.0.0.1",
                                  dashboard_address=":0", silence_logs=50, **worker) as c:
        rc = main([*ARGS, "--scheduler", c.scheduler_address, "--out", str(tmp_path / "rot")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "dask worker tcp://127.0.0.1:" in err[0], err
    said = {"no pcreg": "cannot import pcreg (ModuleNotFoundError", "an older pcreg": "it runs another pcreg, one without "
            "pcreg._workers (an older one); install the same pcreg there", "NUMBA_NUM_THREADS=0": "NUMBA_NUM_THREADS='0': numba's number"}[what]
    assert said in err[0] and "bug" not in err[0], err
    assert not (tmp_path / "rot").exists()


def test_a_stopped_worker_does_not_hold_the_others_at_the_check(tmp_path):
    """A worker stopped (SIGSTOP) held the check of the workers without end, no unit run on the others: they are
    asked within the connect timeout, then each unit checks its own worker."""
    from _interrupting import start, units, wait_for

    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, host="127.0.0.1",
                                  dashboard_address=":0", silence_logs=50) as c, distributed.Client(c) as client:
        pids = client.run(os.getpid)
        stopped = pids[sorted(pids)[0]]
        os.kill(stopped, signal.SIGSTOP)
        out = tmp_path / "rot"
        try:
            p = start([*ARGS, "--scheduler", c.scheduler_address, "--out", out],
                      env={**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"})
            wait_for(p, lambda: units(out), "a unit written by the worker still running")
        finally:
            os.kill(stopped, signal.SIGCONT)
        _, err = p.communicate(timeout=HANG)
    assert p.returncode == 0, err
    assert "did not all answer within 2 s" in err and "each unit checks its worker" in err, err


def test_a_tls_scheduler_is_reached_with_dasks_tls_settings(tmp_path, capsys):
    """pcreg's first question to the scheduler went without dask's TLS settings, so a ``tls://`` scheduler was never
    reached ("answered, but not as a dask scheduler (TypeError)") where dask's own client connected. With the settings
    (``distributed.comm.tls``) the evaluation runs there; without them it says they are needed."""
    import shutil
    import subprocess

    import dask
    from distributed.security import Security

    from pcreg.cli import main

    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: no certificate to start a TLS scheduler with")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert),
                    "-days", "2", "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1"],
                   check=True, capture_output=True)
    security = Security(tls_ca_file=str(cert), tls_client_cert=str(cert), tls_client_key=str(key),
                        tls_scheduler_cert=str(cert), tls_scheduler_key=str(key), tls_worker_cert=str(cert),
                        tls_worker_key=str(key), require_encryption=True)
    settings = {"distributed.comm.tls.ca-file": str(cert), "distributed.comm.tls.client.cert": str(cert),
                "distributed.comm.tls.client.key": str(key)}
    with distributed.LocalCluster(n_workers=1, processes=True, threads_per_worker=1, host="127.0.0.1",
                                  protocol="tls://", security=security, dashboard_address=":0", silence_logs=50) as c:
        assert c.scheduler_address.startswith("tls://")
        with dask.config.set({"distributed.comm.timeouts.connect": "5s"}):
            assert main([*ARGS, "--scheduler", c.scheduler_address, "--out", str(tmp_path / "none")]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and "tls:// needs dask's TLS settings" in err[0], err
            with dask.config.set(settings):
                assert main([*ARGS, "--scheduler", c.scheduler_address, "--out", str(tmp_path / "rot")]) == 0
    assert len(_units(tmp_path / "rot")) == 4
