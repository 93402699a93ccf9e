"""Ctrl-C and SIGTERM stop ``pcreg evaluate sequence``: exit 130, finished units kept, no process left in
the command's group, the output lock released, and the same command then runs to the end; also when
the command was started with SIGINT ignored. The other commands: ``test_interrupts.py`` and
``test_interrupts_run_demo.py``; the helpers and how the signal is sent: ``_interrupting.py``.
"""

from __future__ import annotations

import json
import signal

import pytest

from _interrupting import resumed, signal_and_check, start_signalled, stopped, units

pytestmark = pytest.mark.slow  # commands stopped by signals and run again: seconds each

SEQUENCE = ["evaluate", "sequence", "--data", "synthetic:syn1a,syn2b", "--frames", "24", "--size", "160x120",
            "-k", "1,2,3,4,5,6"]  # 12 units of about a second


@pytest.mark.parametrize("how, workers", [("group", 2), ("parent", 2), ("term", 2), ("group", 1)])
def test_evaluate_sequence_stops_keeps_units_and_resumes(tmp_path, how, workers):
    out = tmp_path / "seq"
    args = [*SEQUENCE, "--workers", workers, "--out", out]
    kept = stopped(args, out, how)
    assert kept and all(json.loads(u.read_text())["pairs"] for u in kept)  # whole files
    assert not (out / "results.json").exists()
    resumed(args, out, kept)


def test_sigint_stops_a_command_started_with_sigint_ignored(tmp_path):
    """A shell without job control (a script's ``pcreg ... &``) starts its background commands with
    SIGINT ignored; ``kill -INT`` (and Ctrl-C through a wrapper) must still stop them."""
    out = tmp_path / "seq"
    args = [*SEQUENCE, "--workers", 2, "--out", out]
    kept = stopped(args, out, "parent", preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    resumed(args, out, kept)


def test_sigint_landing_while_wait_holds_the_futures_locks_stops_as_anywhere_else(tmp_path):
    """The pool's results reach the futures through a thread of the pool's, which takes each future's lock;
    a KeyboardInterrupt raised while the main thread's wait() held those locks left them held, that thread
    waited on them for ever and so did Python's exit, which joins it: the watchdog ended the command after
    its grace with a second line."""
    out = tmp_path / "seq"
    args = [*SEQUENCE, "--workers", 2, "--out", out]
    p = start_signalled("wait", args, tmp_path, str(out / "units" / "*" / "*.json"))
    signal_and_check(p, "self", out)
    assert (tmp_path / "signalled").exists()
    resumed(args, out, units(out))
