"""pcreg demo: the whole story in small form writes a report, figures and a recording."""

from __future__ import annotations

import json

import pytest

from pcreg.cli import main
from pcreg.experiments.demo import DemoConfig, run_demo


@pytest.mark.slow
def test_demo_writes_report_figures_and_recording(tmp_path):
    from pcreg.recording.readback import read_recording

    out = tmp_path / "demo"
    config = DemoConfig(presets=("syn1a",), frames=8, size=(160, 120), increments=(1, 4), angles=(0.0, 90.0))
    report = run_demo(config, out=out, workers=1, record=out / "demo.rrd")
    text = report.read_text()
    for heading in ("Naive Bayes alone", "Rotated frames", "ICP backends", "Sequences", "labelled from its key frame",
                    "stage times"):
        assert heading in text
    stream = json.loads((out / "stream" / "results.json").read_text())
    assert stream["methods"] == ["plain", "unregistered", "pcreg", "flow_key"]
    assert stream["datasets"]["syn1a"]["means"]["pcreg"] < stream["datasets"]["syn1a"]["means"]["plain"]
    for png in ("stream/stream.png", "pair.png", "rotation/rotation.png", "sequence/sequence_syn1a.png", "classification/case1.png"):
        assert (out / png).is_file(), png
        assert f"({png})" in text
    seq = json.loads((out / "sequence" / "results.json").read_text())
    assert set(seq["backends"]) == {"reference", "open3d"}
    cc = json.loads((out / "crosscheck.json").read_text())
    assert {"reference", "open3d", "max_corner_disagreement_px"} <= set(cc)
    rec = read_recording(out / "demo.rrd")
    series = rec.series("errors/syn1a/k1/reference/augmented")
    unit = next(u for u in seq["units"] if u["k"] == 1 and u["backend"] == "reference")
    assert len(series) == len(unit["pairs"])


def test_demo_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "report.md").write_text("old")
    assert main(["demo", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["demo", "--out", str(out), "--frames", "3", "--force"]) == 2


@pytest.mark.parametrize("extra", [["--record", "x.rrd"], ["--record-raw"]])
def test_demo_refuses_no_record_with_a_recording(tmp_path, capsys, extra):
    """``--no-record`` beside ``--record FILE`` wrote no recording without a word."""
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--no-record", *extra]) == 2
    assert "choose one" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("held", ["an evaluation's stage folder", "an evaluation's --out"])
def test_demo_refuses_a_folder_holding_another_commands_results(tmp_path, capsys, held):
    """``pcreg demo --out out`` ran its evaluations into ``out/classification`` (the default ``--out`` of ``pcreg
    evaluate classification``) with ``force``, and into an evaluation's own folder wrote its config.json, so that
    the evaluation no longer resumed."""
    out = tmp_path / "out"
    config = out / "classification" / "config.json" if held == "an evaluation's stage folder" else out / "config.json"
    config.parent.mkdir(parents=True)
    config.write_text('{"data": "synthetic", "frames": 6}')
    assert main(["demo", "--out", str(out), "--frames", "8", "--no-record"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and str(config.parent if "stage" in held else config) in err[0] and "--force" in err[0], err
    assert [p for p in out.rglob("*") if not p.is_dir()] == [config]  # nothing written beside it
    assert config.read_text() == '{"data": "synthetic", "frames": 6}'


@pytest.mark.parametrize("args, said", [
    (["--workers", "1000"], "--workers 1000 is more than 4x"),
    (["--record", "pair.png"], "a recording's name must end in .rrd"),
    (["--out", "dm\udcff x"], "a recording's path must be valid UTF-8"),
])
def test_demo_checks_its_options_before_writing(tmp_path, capsys, monkeypatch, args, said):
    """These were refused after the demo's first stages had written their folders (a recording at stage 4)."""
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--frames", "8", *(args if "--out" in args else ["--out", "d", *args])]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and said in err[0], err
    assert list(tmp_path.iterdir()) == []
