"""pcreg evaluate sequence: outputs, resume, recording, bad input (small synthetic frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcreg.cli import main
from pcreg.pipeline import METHODS

SMALL = ["--data", "synthetic:syn1a,syn2b", "--frames", "8", "--size", "160x120"]


def _run(tmp_path, *extra, out="seq"):
    return main(["evaluate", "sequence", *SMALL, "--out", str(tmp_path / out), *extra])


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sequence")
    assert main(["evaluate", "sequence", *SMALL, "--increments", "1,3", "--backend", "both", "--workers", "2",
                 "--out", str(tmp / "seq")]) == 0
    return tmp / "seq"


def test_outputs_and_layout(done):
    for name in ("results.json", "config.json", "sequence_reference.md", "sequence_reference.csv",
                 "sequence_open3d.md", "checks.md", "sequence_syn1a.png", "sequence_summary.png"):
        assert (done / name).is_file(), name
    res = json.loads((done / "results.json").read_text())
    assert set(res["datasets"]) == {"syn1a", "syn2b"}
    for name, d in res["datasets"].items():
        assert set(d["increments"]) == {"1", "3"}
        for k, means in d["increments"].items():
            assert set(means) == set(METHODS)
            assert means["augmented"] < means["plain"]
            # the top-level means are the first backend's, recomputed from its per-pair errors
            unit = next(u for u in res["units"] if u["dataset"] == name and str(u["k"]) == k
                        and u["backend"] == "reference")
            for m in METHODS:
                assert means[m] == pytest.approx(np.mean([p["errors"][m] for p in unit["pairs"]]))
    assert set(res["backends"]) == {"reference", "open3d"}
    cfg = json.loads((done / "config.json").read_text())
    assert cfg["increments"] == [1, 3] and cfg["backends"] == ["reference", "open3d"]
    assert "augmented < plain" in (done / "checks.md").read_text()


def test_rerun_with_the_same_config_resumes(done, tmp_path):
    before = json.loads((done / "results.json").read_text())
    # an interrupted run: one unit's file is lost
    (done / "units" / "syn2b" / "k3_open3d.json").unlink()
    assert main(["evaluate", "sequence", *SMALL, "--increments", "1,3", "--backend", "both",
                 "--out", str(done)]) == 0
    after = json.loads((done / "results.json").read_text())
    assert after["resumed_units"] == 7
    assert after["datasets"] == before["datasets"]


def test_a_different_config_needs_force(done, capsys):
    assert main(["evaluate", "sequence", *SMALL, "--increments", "2", "--out", str(done)]) == 2
    err = capsys.readouterr().err.strip().splitlines()  # the setting that differs named (it said none)
    assert len(err) == 1 and "different configuration (" in err[0] and "[1, 3] then, [2] now" in err[0], err


def test_a_config_that_finished_nothing_is_replaced_without_force(tmp_path, capsys):
    """A bad option found once config.json was written left a folder that refused the corrected command
    ("a different configuration"): with no unit finished and no report, it is replaced."""
    from pcreg.errors import OutputError
    from pcreg.experiments.units import UnitStore

    out = tmp_path / "e"
    UnitStore(out, {"keys": [5]}, force=False)  # what a run stopped by a bad --keys left
    UnitStore(out, {"keys": [0]}, force=False)
    assert json.loads((out / "config.json").read_text()) == {"keys": [0]}
    (out / "units").mkdir()
    (out / "units" / "a.json").write_text("{}")  # a finished unit: kept, and the other configuration refused
    with pytest.raises(OutputError, match="different configuration"):
        UnitStore(out, {"keys": [1]}, force=False)


def test_units_of_another_config_are_not_reused_before_the_report(tmp_path, capsys):
    """A run stopped after a unit finished and before its report keeps the unit in units/NAME/: the same --out
    with other options was taken as holding nothing (only units/*.json was looked at), and the unit of the
    first options was read back as one of the second."""
    args = ["evaluate", "sequence", "--data", "synthetic:syn1a", "--size", "160x120", "--increments", "1",
            "--levels", "2", "--out", str(tmp_path / "s")]
    assert main([*args, "--frames", "4"]) == 0
    (tmp_path / "s" / "results.json").unlink()  # stopped before the report: the finished unit is kept
    capsys.readouterr()
    assert main([*args, "--frames", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different configuration" in err[0], err
    assert main([*args, "--frames", "5", "--force"]) == 0
    res = json.loads((tmp_path / "s" / "results.json").read_text())
    assert res["resumed_units"] == 0 and res["datasets"]["syn1a"]["pairs"]["1"]["pairs"] > 2


def test_units_without_a_config_are_refused(tmp_path):
    """Finished units whose config.json is gone are of a configuration unknown: refused, not taken as this one's."""
    from pcreg.errors import OutputError
    from pcreg.experiments.units import UnitStore

    out = tmp_path / "e"
    UnitStore(out, {"frames": 4}, force=False)
    (out / "units" / "syn1a").mkdir(parents=True)
    (out / "units" / "syn1a" / "k1_reference.json").write_text("{}")
    (out / "config.json").unlink()
    with pytest.raises(OutputError, match="without a readable config.json"):
        UnitStore(out, {"frames": 5}, force=False)
    UnitStore(out, {"frames": 5}, force=True)
    assert not (out / "units" / "syn1a").exists()


def test_starting_over_removes_the_earlier_report(tmp_path):
    """--force over a folder whose report had a clip no longer run kept that clip's figure, which the report page
    showed beside the new tables; and --force stopped before its report left the earlier results.json beside the
    new config.json, the page showing the earlier numbers under the new options."""
    from pcreg.experiments.reports.page import load_report
    from pcreg.experiments.units import UnitStore

    out = tmp_path / "s"
    args = ["evaluate", "sequence", "--size", "160x120", "--frames", "4", "--increments", "1", "--levels", "2",
            "--out", str(out)]
    assert main([*args, "--data", "synthetic:syn1a,syn2b"]) == 0
    assert (out / "sequence_syn2b.png").is_file()
    (out / "notes.md").write_text("mine")  # not the report's: kept
    assert main([*args, "--data", "synthetic:syn1a", "--force"]) == 0
    assert not (out / "sequence_syn2b.png").exists() and (out / "sequence_syn1a.png").is_file()
    assert "sequence_syn2b.png" not in load_report(out).figures and (out / "notes.md").read_text() == "mine"
    config = json.loads((out / "config.json").read_text())
    UnitStore(out, {**config, "frames": 5}, force=True)  # where a --force run stopped before its report
    assert not (out / "results.json").exists() and not (out / "sequence_syn1a.png").exists()
    assert (out / "notes.md").is_file() and not (out / "units").exists()


def test_a_kept_unit_without_a_methods_mean_is_run_again(tmp_path):
    """A unit kept without one method's mean (an earlier pcreg's, or edited) was read back, the method nan in its
    row of the table without a word."""
    out = tmp_path / "s"
    args = ["evaluate", "sequence", "--data", "synthetic:syn1a", "--size", "96x72", "--frames", "4", "--increments",
            "1,2", "--levels", "2", "--out", str(out)]
    assert main(args) == 0
    first = json.loads((out / "results.json").read_text())["datasets"]["syn1a"]["increments"]
    kept = out / "units" / "syn1a" / "k1_reference.json"
    doc = json.loads(kept.read_text())
    del doc["means"]["augmented_flow"]
    kept.write_text(json.dumps(doc))
    (out / "results.json").unlink()
    assert main(args) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["resumed_units"] == 1 and res["datasets"]["syn1a"]["increments"] == first


def test_increment_longer_than_the_sequence_is_a_note(tmp_path):
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "3", "--size", "160x120",
                 "--increments", "1,5", "--out", str(tmp_path / "s")]) == 0
    res = json.loads((tmp_path / "s" / "results.json").read_text())
    assert res["datasets"]["syn1a"]["pairs"]["5"]["pairs"] == 0
    assert any("not shorter" in n for n in res["notes"])
    assert res["datasets"]["syn1a"]["increments"]["5"]["plain"] is None  # NaN written as null


def test_a_run_that_scores_no_pair_is_bad_input(tmp_path, capsys):
    """A one-frame sequence (or an increment no shorter than the sequence) scores nothing: exit 2 and the
    reason, not a report of NaNs whose checks read "met"."""
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "1", "--size", "160x120",
                 "--increments", "1", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no pair was scored" in err[0] and "no pairs" in err[0], err
    assert not (tmp_path / "s" / "results.json").exists()
    # two frames, both choosing the fusion weight: said so, not the weight's own note
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "2", "--size", "160x120",
                 "--increments", "1", "--levels", "2", "--out", str(tmp_path / "s")]) == 2
    assert "no pair was scored (syn1a k=1: no pair with its moving frame after the 2 fusion frames)" \
        in capsys.readouterr().err
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "4", "--size", "160x120",
                 "--increments", "1,10", "--levels", "2", "--out", str(tmp_path / "t")]) == 0
    res = json.loads((tmp_path / "t" / "results.json").read_text())
    assert res["datasets"]["syn1a"]["pairs"]["10"]["pairs"] == 0 and res["datasets"]["syn1a"]["pairs"]["1"]["pairs"]


def test_the_corrected_command_runs_where_a_run_scored_no_pair(tmp_path, capsys):
    """A run refused for scoring no pair (--train first:9 of 5 frames) kept its unit in units/, so the corrected
    command on the same --out was refused as "a different configuration" though nothing had been scored."""
    args = ["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "5", "--size", "160x120",
            "--increments", "1", "--levels", "2", "--out", str(tmp_path / "s")]
    assert main([*args, "--train", "first:9"]) == 2
    assert "no pair was scored" in capsys.readouterr().err
    assert main([*args, "--train", "first:2"]) == 0, capsys.readouterr().err
    res = json.loads((tmp_path / "s" / "results.json").read_text())
    assert res["config"]["train"] == "first:2" and res["datasets"]["syn1a"]["pairs"]["1"]["pairs"] == 3


def test_recording_holds_the_error_series_of_results_json(tmp_path):
    from pcreg.recording.readback import read_recording

    rrd = tmp_path / "seq.rrd"
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "6", "--size", "160x120",
                 "--increments", "2", "--out", str(tmp_path / "s"), "--record", str(rrd)]) == 0
    res = json.loads((tmp_path / "s" / "results.json").read_text())
    rec = read_recording(rrd)
    unit = res["units"][0]
    for m in ("plain", "augmented", "thesis_after"):
        series = rec.series(f"errors/syn1a/k2/reference/{m}")
        assert [series[f] for f in sorted(series)] == pytest.approx([p["errors"][m] for p in unit["pairs"]])
    assert rec.get("transforms/T_ref_mov") and rec.get("warped/valid_mask")
    assert rec.get("labels/predicted/augmented") and rec.get("labels/truth")
    # each pair's frame on the recording, for the report page; a resumed run's units carry none
    series = rec.series("errors/syn1a/k2/reference/plain")
    assert unit["recording_frames"] == {str(p["moving"]): f for p, f in zip(unit["pairs"], sorted(series))}
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "6", "--size", "160x120",
                 "--increments", "2", "--out", str(tmp_path / "s")]) == 0
    again = json.loads((tmp_path / "s" / "results.json").read_text())
    assert again["resumed_units"] == 1 and "recording_frames" not in again["units"][0]


@pytest.mark.parametrize("bad", [["--increments", "0"], ["--increments", "a"], ["--backend", "x"],
                                 ["--train", "first:0"], ["--size", "10x10"], ["--frames", "0"],
                                 ["--fusion-weight", "-1"], ["--model", "warp"], ["--workers", "0"],
                                 ["--data", "nothing:here"]])
def test_bad_options_exit_2_with_one_line(tmp_path, capsys, bad):
    if bad[0] in ("--increments", "--backend", "--train", "--size", "--workers", "--frames",
                  "--fusion-weight"):  # refused by the parser
        with pytest.raises(SystemExit) as exc:
            _run(tmp_path, *bad)
        code = exc.value.code
    else:
        code = _run(tmp_path, *bad)
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error" in err[0]


def test_augmented_above_plain_reads_higher_not_a_negative_lower(tmp_path, shared_data):
    """On CamVid 0006R0_b's first frames augmented is worse than plain: the column read "-175.9% lower"."""
    clip = shared_data / "camvid" / "0006R0_b"
    if not clip.is_dir():
        pytest.skip(f"{clip} not found")
    out = tmp_path / "seq"
    assert main(["evaluate", "sequence", "--data", f"camvid:{clip}", "--frames", "3", "--increments", "1",
                 "--out", str(out)]) == 0
    means = json.loads((out / "results.json").read_text())["datasets"]["0006R0_b"]["increments"]["1"]
    assert means["augmented"] > means["plain"]
    row = next(line for line in (out / "sequence_reference.md").read_text().splitlines() if "| 0006R0_b |" in line)
    rel = 100.0 * (means["augmented"] - means["plain"]) / means["plain"]
    assert row.endswith(f"| {rel:.1f}% higher |"), row
    assert "-" not in row.split("|")[-2]


def test_a_recorded_run_says_it_leaves_the_scheduler_aside(tmp_path, capsys):
    """--record runs every unit in this process: it said so of --workers, and dropped --scheduler without a word."""
    args = ["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "4", "--size", "160x120", "--increments", "2",
            "--out", str(tmp_path / "s"), "--record", str(tmp_path / "s.rrd"), "--force"]
    for given in (["--scheduler", "tcp://127.0.0.1:1"], ["--workers", "2"]):
        assert main([*args, *given]) == 0
        assert f"pcreg: note: --record runs every unit in this process ({given[0]} ignored)" in capsys.readouterr().err
    # both: the scheduler's workers would run the units, --workers was dropped without a word
    assert main([*args, "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"]) == 2
    assert capsys.readouterr().err.splitlines() == ["pcreg: error: --workers 2 with --scheduler: the scheduler's workers run "
                                                    "the units; choose one"]


def test_record_raw_without_a_recording_is_refused(tmp_path, capsys):
    """``--record-raw`` without ``--record``: nothing recorded, the option dropped without a word."""
    assert main(["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "4", "--size", "160x120",
                 "--out", str(tmp_path / "s"), "--record-raw"]) == 2
    assert capsys.readouterr().err.splitlines() == ["pcreg: error: --record-raw logs a recording's images losslessly: give "
                                                    "--record FILE.rrd with it"]
    assert not (tmp_path / "s").exists()


def test_a_mean_over_fewer_pairs_than_the_row_counts_says_so(tmp_path):
    """A pair whose moving frame's labels are all unknown has no score against them: each such method's mean is
    taken over the other pairs, while the row's `pairs` counted them all, without a word."""
    import cv2

    from pcreg.datasets import load_dataset

    clip = tmp_path / "data" / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i, f in enumerate(load_dataset("synthetic:syn1a", n_frames=6, size=(160, 120))["syn1a"]):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), f.image[:, :, ::-1])
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), f.labels if i < 5 else np.full_like(f.labels, 2))
    out = tmp_path / "s"
    assert main(["evaluate", "sequence", "--data", f"folder:{tmp_path / 'data'}", "--increments", "1,4",
                 "--out", str(out)]) == 0
    pairs = json.loads((out / "results.json").read_text())["datasets"]["clip"]["pairs"]
    assert pairs["4"]["pairs"] == 2 and pairs["4"]["scored_pairs"]["plain"] == 1  # (1, 5) has no score
    assert pairs["4"]["scored_pairs"]["thesis_before"] == 2  # scored against the reference frame's labels
    table = (out / "sequence_reference.md").read_text()
    assert "Means over fewer pairs than `pairs`" in table and "clip k=4: plain 1," in table
    assert "augmented_flow 1 of 2" in table and "thesis_before" not in table.split("Means over")[1]


def test_a_temporal_weight_that_no_frame_could_choose_is_said_so(tmp_path, shared_data):
    """0001TP at one frame a second: on the first 2 frames the chain carries no label into a frame (its gate ends
    it), so every weight scores the same (10.33% measured) and the smallest, 0, was taken without a word, which
    makes augmented_temporal naive Bayes alone. The run now says so in results.json and checks.md."""
    out = tmp_path / "s"
    assert main(["evaluate", "sequence", "--data", f"camvid:{shared_data / 'camvid' / '0001TP'}", "--frames", "5",
                 "--fusion-frames", "2", "--increments", "1", "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    said = "temporal fusion weight not determined: every weight scored the same on the first 2 frames"
    assert any(said in n for n in res["notes"]), res["notes"]
    assert res["units"][0]["temporal_weight"]["weight"] == 0.0
    checks = (out / "checks.md").read_text()
    assert "### Notes" in checks and said in checks and "augmented_temporal is naive Bayes alone" in checks


def test_a_reference_frame_that_cannot_train_fails_its_own_pairs_only(tmp_path):
    """Each pair trains naive Bayes on its reference frame: one frame labelled all unknown failed the whole
    increment (`pairs` 0 at k = 1, and only a note in results.json), where it is the reference of one pair."""
    import cv2

    from pcreg.datasets import load_dataset

    clip = tmp_path / "data" / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i, f in enumerate(load_dataset("synthetic:syn1a", n_frames=6, size=(160, 120))["syn1a"]):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), f.image[:, :, ::-1])
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), f.labels if i != 2 else np.full_like(f.labels, 2))
    out = tmp_path / "s"
    assert main(["evaluate", "sequence", "--data", f"folder:{tmp_path / 'data'}", "--increments", "1",
                 "--fusion-frames", "2", "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    stats = res["datasets"]["clip"]["pairs"]["1"]
    assert stats["pairs"] == 3 and stats["failed_pairs"] == 1  # (1, 2), (3, 4), (4, 5) scored; (2, 3) failed
    (failure,) = res["units"][0]["failures"]
    assert (failure["reference"], failure["moving"]) == (2, 3)
    assert failure["reason"].startswith("reference frame f2 cannot train naive Bayes: training labels hold no class")
    assert np.isfinite(res["datasets"]["clip"]["increments"]["1"]["augmented"])
