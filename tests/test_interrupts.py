"""Ctrl-C and SIGTERM stop every long evaluation besides ``sequence`` (in
``test_interrupts_sequence.py``): exit 130, finished units kept, no process left in the command's
group, the output lock released, and the same command then runs to the end.

Each command runs in a subprocess in its own process group (as a terminal's foreground job). The
signal is sent when an event shows the run is under way (a unit file in OUT/units), never after a
pause; the only time limits are generous bounds that turn a hang into a failure (``_interrupting.py``).
"""

from __future__ import annotations

import pytest

from _interrupting import resumed, signal_and_check, start_signalled, stopped

pytestmark = pytest.mark.slow  # commands stopped by signals and run again: seconds each

ROTATION = ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "6", "--size", "160x120",
            "--angles", "0:180:10", "--samples", "6"]  # 6 units of 19 registrations each
STREAM = ["evaluate", "stream", "--data", "synthetic:syn1a,syn2a,syn2b,syn3a", "--frames", "6", "--size", "160x120",
          "--methods", "unregistered,pcreg,flow_key"]  # 4 units (clips) of 5 frames each
CLASSIFICATION = ["evaluate", "classification", "--data", "synthetic:syn1a,syn2b", "--frames", "24",
                  "--size", "160x120", "--trials", "30"]


@pytest.mark.parametrize("how, workers", [("group", 2), ("term", 1)])
def test_evaluate_rotation_stops_and_resumes(tmp_path, how, workers):
    out = tmp_path / "rot"
    args = [*ROTATION, "--workers", workers, "--out", out]
    resumed(args, out, stopped(args, out, how))


@pytest.mark.parametrize("how, workers", [("group", 2), ("parent", 1)])
def test_evaluate_classification_stops_and_resumes(tmp_path, how, workers):
    out = tmp_path / "cls"
    args = [*CLASSIFICATION, "--workers", workers, "--out", out]
    resumed(args, out, stopped(args, out, how))


@pytest.mark.parametrize("how, workers", [("group", 2), ("parent", 1)])
def test_evaluate_stream_stops_and_resumes(tmp_path, how, workers):
    out = tmp_path / "stream"
    args = [*STREAM, "--workers", workers, "--out", out]
    results = resumed(args, out, stopped(args, out, how))
    assert set(results["datasets"]) == {"syn1a", "syn2a", "syn2b", "syn3a"}


@pytest.mark.parametrize("where", ["exec", "import"])
def test_a_signal_while_the_commands_modules_load_exits_130(tmp_path, where):
    """Ctrl-C before the command starts: exit 130 and one line, also when it escaped code made from a string
    (Python then ended the program by SIGINT at exit) or a module made an ImportError of it (a traceback)."""
    p = start_signalled(where, [*ROTATION, "--out", tmp_path / "rot"], tmp_path)
    assert signal_and_check(p, "self", None).strip() == "pcreg: interrupted before the command started"
    assert (tmp_path / "signalled").exists()


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT"])
def test_a_signal_after_the_command_ended_leaves_its_exit_status(tmp_path, signame):
    """A signal after the command's report (while Python shuts down: joining threads, a few tenths of a second after
    an evaluation; once Python has flushed its output, its handlers are the default again) killed the process by the
    signal, without a word (status 143 for SIGTERM). The command is over: the signal is ignored and the process
    exits with the command's status. Sent by the process to itself right after ``main()`` returned, and again
    after its output was flushed (where Python's shutdown puts a handler back to the default)."""
    import subprocess
    import sys

    code = (f"import atexit, os, signal, sys; sys.argv = ['pcreg', 'export', {str(tmp_path / 'none')!r}]\n"
            "from pcreg.cli import main\n"
            "code = main()\n"
            f"os.kill(os.getpid(), signal.{signame})\n"
            f"atexit.register(lambda: (sys.stdout.flush(), os.kill(os.getpid(), signal.{signame})))\n"
            "raise SystemExit(code)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert len(p.stderr.splitlines()) == 1 and p.stderr.startswith("pcreg: error: "), p.stderr
