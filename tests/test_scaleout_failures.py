"""What goes wrong when an evaluation scales out, as a user meets it: a ``--workers`` process killed as the
out-of-memory killer kills (exit 2, one line, the finished units kept, the rerun resumes), and a
``--scheduler`` address where something else answers (an HTTP server, a proxy) or nothing does: exit 2 with
one line naming the address, within the connect timeout, never a hang or a dask traceback."""

from __future__ import annotations

import json
import os
import signal
import socket
import threading

import pytest

from _events import HANG
from _interrupting import group_members, start, units, wait_for, wait_until_ended

ROTATION = ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "8", "--size", "160x120",
            "--angles", "0:180:10", "--samples", "8"]  # 8 units: the first lands with more to run


def _one_line_after(args: list, out, act) -> list[str]:
    """Run ``pcreg ARGS`` in a process, ``act(process)`` once a unit is written in ``out``; its stderr's lines,
    checked to be one, after exit 2."""
    p = start(args)
    try:
        wait_for(p, lambda: units(out), "a unit written")
        act(p)
        _, err = p.communicate(timeout=HANG)
    finally:
        if p.poll() is None:
            p.kill()
    lines = err.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, err
    return lines


def test_a_pool_worker_killed_is_one_line_and_the_rerun_resumes(tmp_path):
    out = tmp_path / "rot"
    def kill_a_worker(p) -> None:
        os.killpg(p.pid, signal.SIGSTOP)  # the command and its workers held mid-run
        workers = [pid for pid in group_members(p.pid) if pid != p.pid]
        assert workers, "no worker process in the command's group"
        os.kill(workers[0], signal.SIGKILL)
        os.killpg(p.pid, signal.SIGCONT)

    lines = _one_line_after([*ROTATION, "--workers", "2", "--out", out], out, kill_a_worker)
    # how it ended is said as far as the pool still knows its workers' exit codes (SIGKILL), else in general words
    assert "out-of-memory killer" in lines[0] and "rerun" in lines[0] and "bug" not in lines[0], lines[0]
    kept = len(units(out))
    assert kept >= 1 and not (out / "results.json").exists()
    again = start([*ROTATION, "--workers", "1", "--out", out])
    _, err = again.communicate(timeout=HANG)
    assert again.returncode == 0, err
    assert json.loads((out / "results.json").read_text())["resumed_units"] == kept


def test_a_pool_command_killed_takes_its_workers_with_it(tmp_path):
    """The command itself killed (SIGKILL: the out-of-memory killer's choice, ``kill -9``, a job scheduler's
    hard stop): its ``--workers`` processes end too, instead of idling without end and holding the output
    folder's lock, and the rerun resumes. Waited for through pidfds, readable when a process exits."""
    out = tmp_path / "rot"
    p = start([*ROTATION, "--workers", "2", "--out", out])
    wait_for(p, lambda: units(out), "a unit written")
    workers = [pid for pid in group_members(p.pid) if pid != p.pid]
    assert workers, "no worker process in the command's group"
    fds = [os.pidfd_open(pid) for pid in workers]
    try:
        p.kill()
        p.wait(timeout=HANG)  # not communicate(): workers left behind would hold its pipes open
        wait_until_ended(fds, "worker processes still running {HANG} s after the command was killed")
    finally:
        for fd in fds:
            os.close(fd)
        for pid, state in group_members(p.pid).items():
            if state != "Z":
                os.kill(pid, signal.SIGKILL)
    kept = len(units(out))
    again = start([*ROTATION, "--workers", "1", "--out", out])
    _, err = again.communicate(timeout=HANG)
    assert again.returncode == 0, err
    assert json.loads((out / "results.json").read_text())["resumed_units"] == kept >= 1


class _Server:
    """A TCP server on 127.0.0.1 that is not a dask scheduler: ``reply`` is sent to each connection as soon as it
    has read something (``b""``: it reads and never answers)."""

    def __init__(self, reply: bytes) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.reply = reply
        self.conns: list[socket.socket] = []
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            try:
                conn.recv(65536)
                if self.reply:
                    conn.sendall(self.reply)
            except OSError:
                pass

    def close(self) -> None:
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.mark.parametrize("reply", [b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n", b""],
                         ids=["http-reply", "silent"])
def test_a_scheduler_address_where_something_else_answers_is_one_line(reply, capsys, tmp_path):
    pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")
    import dask

    from pcreg.cli import main

    server = _Server(reply)
    try:
        with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
            rc = main([*ROTATION, "--scheduler", server.address, "--out", str(tmp_path / "never")])
    finally:
        server.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert server.address in err[0] and "not as a dask scheduler" in err[0], err[0]
    assert "memory" not in err[0].lower().split("(")[0], err[0]


def test_a_closed_port_says_refused(capsys, tmp_path):
    pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")
    import dask

    from pcreg.cli import main

    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]  # closed when the block ends: nothing listens there afterwards
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        rc = main([*ROTATION, "--scheduler", f"tcp://127.0.0.1:{port}", "--out", str(tmp_path / "never")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and f"127.0.0.1:{port}" in err[0] and "refused" in err[0], err



def test_a_cluster_without_workers_stops_with_one_line(monkeypatch, capsys, tmp_path):
    """dask keeps units waiting for a worker without end: the command stops once there has been none for
    NO_WORKER_SECONDS (here shortened), exit 2."""
    distributed = pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")
    from pcreg import _runner
    from pcreg.cli import main

    monkeypatch.setattr(_runner, "NO_WORKER_SECONDS", 1.0)
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0", silence_logs=50) as cluster:
        rc: list[int] = []
        runner = threading.Thread(target=lambda: rc.append(
            main([*ROTATION, "--scheduler", cluster.scheduler_address, "--out", str(tmp_path / "rot")])), daemon=True)
        runner.start()
        runner.join(timeout=HANG)  # without the stop, the units wait for a worker without end
        assert not runner.is_alive(), f"still waiting for a worker after {HANG} s"
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == [2] and len(err) == 1 and "no worker" in err[0] and cluster.scheduler_address in err[0], err


@pytest.mark.slow
def test_the_scheduler_lost_mid_run_is_one_line_and_the_rerun_resumes(tmp_path):
    distributed = pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")
    out = tmp_path / "rot"
    with distributed.LocalCluster(n_workers=1, processes=True, threads_per_worker=1, host="127.0.0.1",
                                  dashboard_address=":0", silence_logs=50) as cluster:
        lines = _one_line_after([*ROTATION, "--scheduler", cluster.scheduler_address, "--out", out], out,
                                lambda p: cluster.sync(cluster.scheduler.close))
    assert "lost the dask scheduler" in lines[0] and "rerun" in lines[0], lines[0]
    kept = len(units(out))
    again = start([*ROTATION, "--workers", "2", "--out", out])
    _, err = again.communicate(timeout=HANG)
    assert again.returncode == 0, err
    assert json.loads((out / "results.json").read_text())["resumed_units"] == kept >= 1


@pytest.mark.slow
def test_a_unit_dask_gives_up_on_is_named():
    """A unit whose worker dies each time (here: it ends its process) is given up by dask (KilledWorker): a
    PcregError naming the unit, not a bug."""
    distributed = pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")
    import dask

    from pcreg._runner import make_executor, run_units
    from pcreg.errors import PcregError

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with distributed.LocalCluster(n_workers=1, processes=True, threads_per_worker=1, host="127.0.0.1",
                                      dashboard_address=":0", silence_logs=50) as cluster:
            with pytest.raises(PcregError, match="unit 0: every dask worker that ran it ended abruptly"):
                with make_executor(scheduler=cluster.scheduler_address) as ex:
                    run_units(os._exit, [3], executor=ex)  # os._exit(3) in the worker


@pytest.mark.parametrize("scheme, said", [
    ("ws", "something listens at that port but did not answer ws://: a dask scheduler speaks the one protocol it was "
           "started with (tcp:// unless `dask scheduler --protocol`); is the scheme right?"),
    ("tls", "tls:// needs dask's TLS settings (distributed.comm.tls: ca-file, and client cert and key), and none are set here"),
])
def test_a_scheduler_given_with_another_scheme_says_so(scheme, said, capsys, tmp_path):
    """A scheduler listening on tcp:// given as ws:// was "the host is unreachable, or a firewall drops the
    connection" after the connect timeout; as tls:// (no TLS settings) "answered, but not as a dask scheduler
    (TypeError)"."""
    pytest.importorskip("distributed", reason="pcreg[distributed] (dask.distributed) is not installed")
    import dask

    from pcreg.cli import main

    server = _Server(b"")  # takes the connection and says nothing, as a tcp:// scheduler does to a ws:// greeting
    address = server.address.replace("tcp://", f"{scheme}://")
    try:
        with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
            rc = main([*ROTATION, "--scheduler", address, "--out", str(tmp_path / "never")])
    finally:
        server.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and address in err[0] and said in err[0], err
