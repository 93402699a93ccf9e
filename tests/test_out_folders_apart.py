"""An evaluation's --out and a run's --out are folders of their own: one given the other's folder mixed their files
(both still worked, an export of the run then holding an evaluation's report beside it, exit 0)."""

import json

import pytest

from pcreg.cli import main
from _runs import drifting_frames, one_line_errors


def test_an_evaluation_into_a_runs_folder_and_a_run_into_an_evaluations_are_refused(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames")
    run = tmp_path / "run"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(run)]) == 0
    before = sorted(p.name for p in run.iterdir())
    capsys.readouterr()
    for force in ([], ["--force"]):
        assert main(["evaluate", "sequence", "--frames", "6", "--out", str(run), *force]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{run}: a pcreg run's folder (its run.json)" in err[0], err
    assert sorted(p.name for p in run.iterdir()) == before

    evaluation = tmp_path / "evaluation"
    assert main(["evaluate", "sequence", "--frames", "6", "--out", str(evaluation)]) == 0
    report = sorted(p.name for p in evaluation.iterdir())
    assert "config.json" in report and json.loads((evaluation / "config.json").read_text())
    capsys.readouterr()
    for force in ([], ["--force"]):
        assert main(["run", str(folder), "--labels", str(key), "--out", str(evaluation), *force]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{evaluation}: an evaluation's folder" in err[0], err
    assert sorted(p.name for p in evaluation.iterdir()) == report


@pytest.mark.parametrize("experiment, held, extra", [("sequence", "checks.md", ["--frames", "6"]),
                                                     ("classification", "case1.csv", ["--frames", "6", "--cases", "I", "--k", "3"])])
def test_an_evaluation_into_a_folder_of_no_evaluation_holding_a_file_its_report_writes_is_refused(tmp_path, capsys,
                                                                                                  experiment, held, extra):
    """A person's own checks.md in a folder given as an evaluation's --out was written over by the report without a
    word. Refused in one line naming it, before anything is written; a file of another name is no obstacle; --force
    writes over it."""
    out = tmp_path / "out"
    out.mkdir()
    (out / held).write_text("a person's own")
    (out / "notes.md").write_text("another of theirs")
    (out / "config.json").write_text('{"project": "theirs"}')  # a config.json alone is anyone's, no evaluation's
    command = ["evaluate", experiment, *extra, "--out", str(out)]
    assert main(command) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{out / held}: the report would write over it" in err[0] and "--force" in err[0], err
    assert sorted(p.name for p in out.iterdir() if p.name != ".pcreg.lock") == sorted([held, "notes.md", "config.json"])
    assert (out / "config.json").read_text() == '{"project": "theirs"}'
    assert main([*command, "--force"]) == 0
    assert (out / held).read_text() != "a person's own" and (out / "notes.md").read_text() == "another of theirs"
