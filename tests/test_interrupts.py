"""Ctrl-C and SIGTERM stop every long evaluation besides ``sequence`` (in
``test_interrupts_sequence.py``): exit 130, finished units kept, no process left in the command's
group, the output lock released, and the same command then runs to the end.

Each command runs in a subprocess in its own process group (as a terminal's foreground job). The
signal is sent when an event shows the run is under way (a unit file in OUT/units), never after a
pause; the only time limits are generous bounds that turn a hang into a failure (``_interrupting.py``).
"""

from __future__ import annotations

import pytest

from _interrupting import resumed, stopped

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
