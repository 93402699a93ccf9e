"""Ctrl-C in every phase of a long command: loading the data, calibrating the fusion weight, running the
units, writing the report. Each ends with exit 130 and one line, no worker left, the output folder
unlocked, the finished units kept; the same command then resumes (the kept units are not redone) and
gives the results of a run that was never interrupted.

The signal comes from the phase itself (:func:`_phases.signal_at`), so no test waits on time; the
subprocess tests in ``test_interrupts*.py`` cover the process group and SIGTERM.
"""

from __future__ import annotations

import math

import pytest

from _phases import interrupted_line, live_children, results_without_times, signal_at, unit_files

pytestmark = pytest.mark.slow  # commands stopped by signals and run again: seconds each

SMALL = ["--size", "160x120"]
COMMANDS = {
    "sequence": ["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "12", *SMALL, "-k", "1,2,3"],
    "rotation": ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "3", *SMALL, "--angles", "0,90",
                 "--samples", "3"],
    "stream": ["evaluate", "stream", "--data", "synthetic:syn1a,syn2a", "--frames", "4", *SMALL,
               "--methods", "unregistered,pcreg"],
    "classification": ["evaluate", "classification", "--data", "synthetic:syn1a,syn2b", "--frames", "8", *SMALL,
                       "--trials", "4"],
}
REPORTS = {name: f"pcreg.experiments.reports.{name}" for name in COMMANDS}


def close(a, b, path: str = "", tol: float = 1e-9) -> list[str]:
    """Leaves where two results differ; floats agree to ``tol`` relative (a worker process's registration
    differs from this process's in the last bits)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in set(a) | set(b) for d in close(a.get(k), b.get(k), f"{path}/{k}", tol)]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in close(x, y, f"{path}/{i}", tol)]
    if isinstance(a, float) and isinstance(b, float) and math.isclose(a, b, rel_tol=tol, abs_tol=tol):
        return []
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """Each command's results from a run that nobody stops (made on first use)."""
    from pcreg.cli import main

    made: dict[str, tuple[dict, int]] = {}

    def get(name: str) -> tuple[dict, int]:
        """(results, number of units)"""
        if name not in made:
            out = tmp_path_factory.mktemp(f"whole-{name}")
            assert main([*COMMANDS[name], "--out", str(out)]) == 0
            made[name] = results_without_times(out), len(unit_files(out))
        return made[name]

    return get


def _hook(monkeypatch, name: str, phase: str, flag) -> None:
    import importlib

    import pcreg.datasets
    import pcreg.experiments.units as units
    import pcreg.pipeline.sequence as sequence

    if phase == "data":
        monkeypatch.setattr(units, "_DATA_CACHE", {})  # this process loaded the data before: load it again
        signal_at(monkeypatch, pcreg.datasets, "load_dataset", flag)
    elif phase == "calibration":
        signal_at(monkeypatch, sequence, "_choose_weights", flag)
    elif phase == "units":  # after the first unit is saved, with more to come
        signal_at(monkeypatch, units.UnitStore, "save", flag, after=True)
    elif phase == "report":
        signal_at(monkeypatch, importlib.import_module(REPORTS[name]), "write_outputs", flag)


def _waits_after_the_signal(monkeypatch) -> list[int]:
    """The runner's waits for units that began once the signal had arrived (the pending units' count of
    each). A stop lands the units that finished while it waited, and waits for no more: a signal sent by the
    parent itself (a unit's save) is followed by no wait, one sent by a worker (calibrating) by at most the
    one that began as it came. How many units that last batch holds is the machine's timing (two workers, or
    a cluster's, finishing together; on a loaded machine every one), not the stop's."""
    from pcreg import _runner

    real, late = _runner.wait, []

    def wait(pending, **kwargs):
        if _runner.interrupted():
            late.append(len(pending))
        return real(pending, **kwargs)

    monkeypatch.setattr(_runner, "wait", wait)
    return late


def interrupt_and_resume(monkeypatch, capsys, tmp_path, name: str, phase: str, extra: list[str]) -> tuple[dict, int]:
    """Run ``name`` with the signal in ``phase``; check the stop, then resume. Returns the resumed results
    and how many units the stopped run had finished."""
    from pcreg.cli import main
    from pcreg.outputs import OutputLock

    out = tmp_path / "out"
    args = [*COMMANDS[name], *extra, "--out", str(out)]
    flag = tmp_path / "signalled"
    before = set(live_children())  # a local cluster's processes, for one
    with monkeypatch.context() as m:
        _hook(m, name, phase, flag)
        late = _waits_after_the_signal(m)
        rc = main(args)
    err = capsys.readouterr().err
    assert flag.exists(), f"the {phase} phase never ran"
    assert rc == 130, err
    assert len(late) <= (phase == "calibration"), f"{len(late)} wait(s) for more units after the signal"
    interrupted_line(err)
    assert not set(live_children()) - before, "a worker outlived the command"
    with OutputLock(out):  # unlocked: a new run may take it
        pass
    assert not (out / "results.json").exists(), "the stopped run wrote its report"
    kept = unit_files(out)
    assert main(args) == 0
    capsys.readouterr()
    assert {u: s for u, s in unit_files(out).items() if u in kept} == kept, "a kept unit was redone"
    return results_without_times(out), len(kept)


CASES = [(name, phase, 1) for name in COMMANDS for phase in ("data", "units", "report")]
CASES += [("sequence", "calibration", 1), ("sequence", "calibration", 2), ("sequence", "units", 2),
          ("stream", "units", 2), ("rotation", "data", 2)]


@pytest.mark.parametrize("name, phase, workers", CASES)
def test_a_signal_in_each_phase_stops_and_the_run_resumes(monkeypatch, capsys, tmp_path, uninterrupted, name, phase,
                                                          workers):
    whole, n_units = uninterrupted(name)
    res, kept = interrupt_and_resume(monkeypatch, capsys, tmp_path, name, phase, ["--workers", str(workers)])
    assert n_units >= 2
    # with two workers, the units that finished before the signal was handled are kept too (every one, on a
    # loaded machine); that none was waited for after it, interrupt_and_resume checks
    last = n_units - (workers == 1)
    expected = {"data": (0, 0), "calibration": (0, last), "units": (1, last),
                "report": (n_units, n_units)}[phase]
    assert expected[0] <= kept <= expected[1], f"{kept} of {n_units} units kept"
    assert not close(res, whole)


SUITE = ["crosscheck", "--with", "reference,open3d"]


@pytest.mark.parametrize("phase, owner, function, after", [
    ("building the cases", "pcreg.implementations.suite", "builtin_cases", False),
    ("the cases", "pcreg.implementations.crosscheck", "crosscheck_implementations", True),
    ("writing the results", "pcreg.implementations.suite", "write_results", False),
])
def test_crosscheck_suite_stops_in_each_phase_and_runs_again(monkeypatch, capsys, tmp_path, phase, owner, function,
                                                             after):
    """``crosscheck --suite``: the stopped run leaves no half-written table; the same command then writes
    the tables of a run never stopped."""
    import importlib

    from pcreg.cli import main

    whole, out = tmp_path / "whole", tmp_path / "out"
    assert main([*SUITE, "--suite", str(whole)]) == 0
    capsys.readouterr()
    flag = tmp_path / "signalled"
    before = set(live_children())
    with monkeypatch.context() as m:
        signal_at(m, importlib.import_module(owner), function, flag, after=after)
        rc = main([*SUITE, "--suite", str(out)])
    err = capsys.readouterr().err
    assert flag.exists() and rc == 130, err
    interrupted_line(err)
    assert not set(live_children()) - before
    assert not [p.name for p in out.glob("*") if p.name.startswith(".") or p.suffix in (".tmp", ".part")]
    assert main([*SUITE, "--suite", str(out)]) == 0
    # the 2d-edges case (sub-pixel edges of an image and its warped copy) differs between two runs in one
    # process by ~1e-8 relative in its errors against the truth; every other number is identical
    assert not close(results_without_times(out), results_without_times(whole), tol=1e-6)


def test_a_signal_whose_interrupt_was_swallowed_still_stops_the_command(monkeypatch, capsys, tmp_path):
    """Python only prints a KeyboardInterrupt raised in a weakref callback or a ``__del__`` (an import
    lock's clean-up, say) and goes on. A Ctrl-C landing there must still end the command with 130."""
    import os
    import signal

    from pcreg.cli import main
    from pcreg.experiments.reports import sequence as report

    real = report.write_outputs
    swallowed = []

    def write_outputs(*args, **kwargs):
        try:
            os.kill(os.getpid(), signal.SIGINT)  # the handler runs before os.kill returns
        except KeyboardInterrupt:
            swallowed.append(True)
        return real(*args, **kwargs)

    monkeypatch.setattr(report, "write_outputs", write_outputs)
    out = tmp_path / "out"
    rc = main([*COMMANDS["sequence"], "--out", str(out)])
    err = capsys.readouterr().err
    assert swallowed and rc == 130, err
    interrupted_line(err)
    assert len(unit_files(out)) == 3  # every unit kept: the same command has nothing left to run


def test_in_one_process_each_unit_is_kept_before_the_next_starts(monkeypatch, capsys, tmp_path):
    """``--workers 1``: a unit's file is written as soon as it finishes, so a stop (or a crash) in the
    next unit loses none of the work done."""
    import pcreg.experiments.sequence as sequence
    import pcreg.experiments.units as units
    from pcreg.cli import main

    events: list[str] = []
    real_run, real_save = sequence.run_unit, units.UnitStore.save

    def run_unit(unit, **kwargs):
        events.append("run")
        return real_run(unit, **kwargs)

    def save(self, key, result):
        events.append("save")
        return real_save(self, key, result)

    monkeypatch.setattr(sequence, "run_unit", run_unit)
    monkeypatch.setattr(units.UnitStore, "save", save)
    assert main([*COMMANDS["sequence"], "--workers", "1", "--out", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    assert events == ["run", "save"] * 3
