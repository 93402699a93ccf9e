"""A run's ``run.json`` names its format: a run.json of a later format is refused by name (exit 2, one line)
by the run that would resume it and by every reader, rather than read as if this pcreg had written it; one from
before the format was named still resumes, and is named from then on."""

from __future__ import annotations

import json

import pytest

from pcreg import __version__
from pcreg.cli import main
from pcreg.runs.state import FORMAT
from _runs import drifting_frames, key_frames_of, one_line_errors


@pytest.mark.parametrize("kind", ["one key frame", "key frames"])
def test_a_run_json_names_its_format_and_a_later_one_is_refused_by_every_command(tmp_path, capsys, kind):
    if kind == "key frames":
        folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
        labels = key_frames_of(key, tmp_path / "keys")
    else:
        folder, labels = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(labels), "--out", str(out)]
    assert main(run) == 0
    state = json.loads((out / "run.json").read_text())
    assert state["format"] == FORMAT == 1
    later = {**state, "format": FORMAT + 1, "done": "fields of a layout this pcreg does not know"}
    (out / "run.json").write_text(json.dumps(later))
    capsys.readouterr()
    for args in (run, ["export", str(out), "--to", str(tmp_path / "x.zip")], ["view", str(out), "--overlay", str(tmp_path / "o.mp4")]):
        assert main(args) == 2, args
        err = one_line_errors(capsys)
        assert len(err) == 1, err
        assert "run.json: written by a later pcreg (run.json format 2" in err[0], err
        assert f"pcreg {__version__} reads format 1" in err[0], err
    assert json.loads((out / "run.json").read_text()) == later  # nothing rewritten
    assert main([*run, "--force"]) == 0
    assert json.loads((out / "run.json").read_text())["format"] == FORMAT


def test_a_run_json_from_before_the_format_was_named_resumes_and_gains_it(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=7)
    later = tmp_path / "later"
    later.mkdir()
    for name in ("f5.png", "f6.png"):  # frames that arrive after the first run
        (folder / name).rename(later / name)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    state = json.loads((out / "run.json").read_text())
    del state["format"]
    (out / "run.json").write_text(json.dumps(state))
    assert main(["export", str(out), "--to", str(tmp_path / "x.zip")]) == 0
    for name in ("f5.png", "f6.png"):
        (later / name).rename(folder / name)
    assert main(run) == 0  # resumed: the two new frames labelled, the file named from its next commit on
    state = json.loads((out / "run.json").read_text())
    assert state["done"] == 7 and state["format"] == FORMAT


@pytest.mark.parametrize("bad", [0, -1, "1", 1.0, True, None])
def test_a_format_that_is_not_a_count_is_refused(tmp_path, capsys, bad):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    state = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**state, "format": bad}))
    capsys.readouterr()
    assert main(run) == 2
    assert "its 'format' is not as pcreg run writes it" in one_line_errors(capsys)[-1]
    assert main(["export", str(out), "--to", str(tmp_path / "x.zip")]) == 2
    assert "run.json: unreadable" in one_line_errors(capsys)[-1]
