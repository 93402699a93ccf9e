"""`pcreg evaluate stream`: every method on the same frames, outputs, resume and bad input."""

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest

from pcreg.cli import main
from pcreg.experiments.stream import METHODS, run_clip

CAMVID = Path(__file__).resolve().parents[2] / "shared" / "data" / "camvid"


def test_evaluate_stream_writes_every_table_and_resumes(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--frames", "4", "--size", "160x120", "--data", "synthetic:syn1a,syn2b",
            "--methods", "unregistered,pcreg,flow_key", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "mean error % per clip" in printed and "### Checks" in printed
    res = json.loads((out / "results.json").read_text())
    assert set(res["datasets"]) == {"syn1a", "syn2b"} and res["methods"] == ["plain", "unregistered", "pcreg", "flow_key"]
    for name, c in res["datasets"].items():
        assert c["scored"] == 3
        assert c["reduction"]["plain"] == 0
        assert c["means"]["pcreg"] < c["means"]["plain"]  # the key frame's labels carried by the dense field
    with open(out / "stream_frames.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 6 and {r["since_key"] for r in rows} == {"1", "2", "3"}
    for f in ("stream_reference.md", "checks.md", "stream.png", "config.json"):
        assert (out / f).stat().st_size > 0
    before = {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()}
    assert main(args) == 0  # resumed: no unit is run again
    assert {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()} == before
    assert json.loads((out / "results.json").read_text())["resumed_units"] == 2


def test_pcreg_is_exactly_the_propagator_and_key_frames_restart(tmp_path):
    import pcreg

    frames = pcreg.synthetic("syn1a", 5, 0, width=160, height=120)
    r = run_clip(frames, methods=("plain", "pcreg", "dense_key"), key_every=3)
    assert [f["key"] for f in r["frames"]] == [0, 0, 3] and r["key_frames"] == [0, 3]
    for f in r["frames"]:
        assert f["errors"]["pcreg"] == f["errors"]["dense_key"]


def test_evaluate_stream_bad_input(tmp_path, capsys):
    assert main(["evaluate", "stream", "--frames", "1", "--size", "160x120", "--data", "synthetic:syn1a",
                 "--out", str(tmp_path / "o")]) == 2
    assert "needs a key frame and one more" in capsys.readouterr().err
    assert main(["evaluate", "stream", "--methods", "warp", "--out", str(tmp_path / "o")]) == 2
    assert "--methods: unknown warp" in capsys.readouterr().err
    clip = tmp_path / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    import cv2

    for i in range(2):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), np.full((40, 60, 3), 60 * i, np.uint8))
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), np.full((40, 60), 2, np.uint8))
    assert main(["evaluate", "stream", "--data", f"folder:{clip}", "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no known label" in err


@pytest.mark.skipif(not CAMVID.is_dir(), reason="needs ../shared/data/camvid (real CamVid clips)")
def test_pcreg_beats_plain_and_unregistered_on_a_real_clip():
    from pcreg.datasets.folder import load_folder

    frames = load_folder(CAMVID / "0016E5")[:12]
    r = run_clip(frames, methods=("plain", "unregistered", "pcreg"))
    assert r["means"]["pcreg"] < r["means"]["unregistered"] < r["means"]["plain"]
