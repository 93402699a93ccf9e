"""DAVIS through the command line: ``pcreg evaluate stream --data davis:PATH`` scores J and F beside the
published methods, ``pcreg run --mapping davis`` follows the object, and bad input ends in one line and
exit 2 with nothing already written lost."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pcreg.classification.davis_measures import jaccard
from pcreg.cli import main
from _davis import frames_and_masks, shared_sequence, write_official_layout, write_pcreg_layout
from _runs import one_line_errors
from test_davis_dataset import BROKEN, _broken
from pcreg.export import read_labels
from pcreg.classes import DAVIS


def test_evaluate_stream_on_davis_scores_j_and_f_beside_the_published_methods(tmp_path, capsys):
    root = write_official_layout(tmp_path / "DAVIS", "blackswan", frames_and_masks(5))
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{root}", "--methods", "unregistered,flow_key",
                 "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    d = res["davis"]
    assert d["methods"] == ["plain", "unregistered", "flow_key"]
    unit = res["units"][0]["davis"]
    assert unit["frames"] == [1, 2, 3]  # frames 1 to n-2
    for k in ("J", "F"):
        for m in d["methods"]:
            assert d["sequences"]["blackswan"][k][m] == pytest.approx(np.mean(unit[k][m]))
            assert d["mean"][k][m] == pytest.approx(d["sequences"]["blackswan"][k][m])
            assert 0 <= d["mean"][k][m] <= 1
    assert d["mean"]["J"]["flow_key"] > 0.8  # the disc moves 2 px a frame: DIS carries its mask
    # the published figures of the same sequence (pcreg's own copy: no csv beside the official layout)
    assert d["published"]["J"]["osvos"] == {"blackswan": 0.9423}
    assert "davisvideochallenge.github.io" in d["published"]["source"]
    table = (out / "davis_J.md").read_text()
    assert "| blackswan | 3 |" in table and "OSVOS" in table and "davisvideochallenge.github.io" in table
    row = next(line for line in table.splitlines() if line.startswith("| blackswan |"))
    assert " 0.942 |" in row  # J with three decimals, as the figures are compared (OSVOS's 0.9423 read 0.94)
    # a sequence of 5 frames where the benchmark's has 50: its figures beside the published ones were said nothing of
    assert d["published"]["frames"] == {"blackswan": 48}
    assert ("Scored over other frames than the published figures are (blackswan 3 against 48 frames): the sequence "
            "does not hold the benchmark's frames, and its figures and the published ones do not compare.") in table
    said = capsys.readouterr().out  # the benchmark's J and F printed after the error table, before the checks
    at = [said.find(t) for t in ("### Labelling a stream", table.splitlines()[0], "### DAVIS: F", "### Checks")]
    assert -1 not in at and at == sorted(at), said
    header = (out / "davis_F.csv").read_text().splitlines()[0]
    assert header.startswith("sequence,frames scored,plain,unregistered,flow_key,OSVOS,MSK")
    from pcreg.experiments.reports.page import load_report, page_data  # the report page shows them too

    shown = {t["name"]: t for t in page_data(load_report(out))["tables"]}
    assert shown["davis_J"]["better"] == "higher" and shown["davis_J"]["columns"] == header.split(",")
    assert shown["davis_J"]["digits"] == shown["davis_F"]["digits"] == 3


def test_a_kept_davis_unit_without_its_j_and_f_is_run_again_not_left_out(tmp_path):
    """A sequence's kept unit without its ``davis`` section (as a pcreg from before J and F kept it) was read back
    and silently left out of the DAVIS tables: the mean over sequences was one sequence's."""
    root = write_official_layout(tmp_path / "DAVIS", "blackswan", frames_and_masks(5))
    write_official_layout(root, "goat", frames_and_masks(5, seed=1))
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--data", f"davis:{root}", "--methods", "unregistered", "--out", str(out)]
    assert main(args) == 0
    first = json.loads((out / "results.json").read_text())["davis"]
    kept = out / "units" / "goat_reference.json"
    kept.write_text(json.dumps({k: v for k, v in json.loads(kept.read_text()).items() if k != "davis"}))
    (out / "results.json").unlink()  # stopped before its report
    assert main(args) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["resumed_units"] == 1 and set(res["davis"]["sequences"]) == {"blackswan", "goat"}
    assert res["davis"]["mean"] == first["mean"]
    assert "| goat | 3 |" in (out / "davis_J.md").read_text()


def test_evaluate_stream_on_davis_refuses_other_key_frames(tmp_path, capsys):
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(4))
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--keys", "first,last", "--out",
                 str(tmp_path / "o")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "DAVIS's benchmark keys the first frame's mask alone, as the default does: leave --keys out" in err[0]


@pytest.mark.parametrize("how", BROKEN)
def test_a_broken_davis_sequence_is_one_line_and_exit_2_and_the_earlier_results_stay(tmp_path, capsys, how):
    seq, path, what = _broken(tmp_path, how)
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text("{}")  # an earlier evaluation's
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "unregistered", "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and str(path) in err[0] and what in err[0]
    assert (out / "results.json").read_text() == "{}"


def _run_case(tmp_path, how: str):
    """Frames in a folder and a key mask broken one way: (extra args, the file named, what is said)."""
    pairs = frames_and_masks(4)
    seq = write_pcreg_layout(tmp_path / "seq", pairs)
    key = seq / "labels" / "00000.png"
    if how == "a 0/255 mask without --mapping davis":
        return [], key, "--mapping davis reads it"
    if how == "a mask of another size":
        cv2.imwrite(str(key), np.repeat(np.array([[0, 255]], np.uint8), 16, axis=1).repeat(24, axis=0))
        return ["--mapping", "davis"], key, "labels are 32x24, the key frame 00000.jpg is 64x48"
    if how == "no first mask":
        key.unlink()
        return ["--mapping", "davis"], key, "no such file"
    if how == "a JPEG mask":  # its edge is values 1, 2, ...: read as object, around the object
        key = key.with_suffix(".jpg")
        cv2.imwrite(str(key), pairs[0][1])
        return ["--mapping", "davis"], key, "a JPEG, which changes the values at every edge"
    cv2.imwrite(str(key), np.zeros((48, 64), np.uint8))
    return ["--mapping", "davis"], key, "the object's mask on the key frame is empty"


RUN_CASES = ("a 0/255 mask without --mapping davis", "a mask of another size", "no first mask", "an empty key mask",
             "a JPEG mask")


@pytest.mark.parametrize("how", RUN_CASES)
def test_pcreg_run_refuses_a_bad_davis_key_mask_in_one_line(tmp_path, capsys, how):
    extra, key, what = _run_case(tmp_path, how)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "seq"), "--labels", str(key), "--out", str(out), *extra]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and str(key) in err[0] and what in err[0]
    assert not out.exists()


def test_pcreg_run_stops_at_an_unreadable_jpeg_keeps_what_it_wrote_and_resumes(tmp_path, capsys):
    pairs = frames_and_masks(4)
    seq = write_pcreg_layout(tmp_path / "seq", pairs)
    bad = seq / "images" / "00002.jpg"
    good = bad.read_bytes()
    bad.write_bytes(good[:200])
    out = tmp_path / "out"
    args = ["run", str(seq), "--labels", str(seq / "labels" / "00000.png"), "--mapping", "davis", "--out", str(out)]
    assert main(args) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and str(bad) in err[0] and "cannot decode image" in err[0]
    first = (out / "00001.png").read_bytes()
    assert json.loads((out / "run.json").read_text())["done"] == 2
    bad.write_bytes(good)
    assert main(args) == 0
    assert (out / "00001.png").read_bytes() == first  # kept, not labelled again
    assert json.loads((out / "run.json").read_text())["done"] == 4


@pytest.mark.data
def test_pcreg_run_with_the_davis_mapping_follows_a_shared_sequence(shared_data, tmp_path):
    goat = shared_sequence(shared_data, "goat")
    out = tmp_path / "out"
    assert main(["run", str(goat / "images"), "--labels", str(goat / "labels" / "00000.png"), "--mapping", "davis",
                 "--truth", str(goat / "labels"), "--stop", "6", "--out", str(out)]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["run"]["mapping"] == "davis" and run["done"] == 6
    for i in range(1, 6):
        labels = read_labels(out / f"{i:05d}.png", DAVIS)
        truth = cv2.imread(str(goat / "labels" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE)
        assert labels.shape == truth.shape and set(np.unique(labels)) <= {0, 1}
        assert jaccard(labels, truth) > 0.6  # the goat, five frames after its mask
    assert 0 <= run["truth"]["error"] < 5  # percent of pixels


@pytest.mark.data
def test_evaluate_stream_on_a_shared_davis_sequence(shared_data, tmp_path, capsys):
    goat = shared_sequence(shared_data, "goat")
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{goat}", "--frames", "4", "--methods", "pcreg",
                 "--out", str(out)]) == 0
    d = json.loads((out / "results.json").read_text())["davis"]
    assert d["sequences"]["goat"]["frames"] == 2
    assert d["mean"]["J"]["pcreg"] > 0.6 and d["mean"]["J"]["pcreg"] > d["mean"]["J"]["plain"]
    # the published figures beside the shared sequences: the benchmark's, over the whole sequence
    assert d["published"]["J"]["bvs"] == {"goat": 0.6612} and d["published"]["F"]["bvs"] == {"goat": 0.5839}


def test_a_sequence_too_short_to_score_keeps_every_method_in_the_davis_tables(tmp_path):
    """A sequence of two frames (none of frames 1 to n-2 scored) beside a longer one dropped every pcreg method
    from davis_J and davis_F: their columns were gone, the longer sequence's J and F with them. The short one is
    now a row of nan, left out of the means as the benchmark's nanmean leaves it."""
    write_pcreg_layout(tmp_path / "d" / "long", frames_and_masks(5))
    write_pcreg_layout(tmp_path / "d" / "short", frames_and_masks(2, seed=1))
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{tmp_path / 'd'}", "--methods", "unregistered",
                 "--out", str(out)]) == 0
    d = json.loads((out / "results.json").read_text())["davis"]
    assert d["methods"] == ["plain", "unregistered"]
    for k in ("J", "F"):
        for m in d["methods"]:
            assert d["sequences"]["short"][k][m] is None  # NaN, written as null
            assert d["mean"][k][m] == pytest.approx(d["sequences"]["long"][k][m])
    header, *rows = (out / "davis_J.csv").read_text().splitlines()
    assert header.startswith("sequence,frames scored,plain,unregistered,OSVOS")
    assert rows[1].startswith("short,0,nan,nan,")
    assert "short: fewer than 3 frames, none scored" in (out / "davis_J.md").read_text()
    from pcreg.experiments.reports.page import load_report, page_data  # the report page reads it back

    shown = {t["name"]: t for t in page_data(load_report(out))["tables"]}
    assert shown["davis_F"]["rows"][1]["cells"][:4] == ["short", 0, None, None]


def test_the_means_that_compare_leave_out_a_sequence_pcreg_could_not_score(tmp_path):
    """A sequence of two frames (none scored) beside a longer one, both with published figures: pcreg's means were
    over the longer one and the published means over both, side by side with no row that compares, the note "left
    out of the means" true of pcreg's columns alone; and the report page showed none of the tables' notes."""
    write_pcreg_layout(tmp_path / "d" / "blackswan", frames_and_masks(2, seed=1))
    write_pcreg_layout(tmp_path / "d" / "goat", frames_and_masks(5))
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{tmp_path / 'd'}", "--methods", "unregistered",
                 "--out", str(out)]) == 0
    d = json.loads((out / "results.json").read_text())["davis"]
    assert d["published"]["covered"] == ["goat"]
    for k in ("J", "F"):
        assert d["mean_covered"][k]["osvos"] == pytest.approx(d["published"][k]["osvos"]["goat"])
        assert d["mean_covered"][k]["plain"] == pytest.approx(d["sequences"]["goat"][k]["plain"])
        assert d["published"]["mean"][k]["osvos"] == pytest.approx(np.mean(list(d["published"][k]["osvos"].values())))
    table = (out / "davis_J.md").read_text()
    assert "| mean over the 1 scored with published figures | 3 |" in table
    said = ("blackswan: fewer than 3 frames, none scored (frames 1 to n-2): nan, left out of the means of pcreg's "
            "methods; the published means count blackswan, so the means over sequences do not compare: the row of the "
            "1 scored with published figures does.")
    assert said in table
    from pcreg.experiments.reports.page import load_report, page_data  # the page shows each table's notes under it

    shown = {t["name"]: t for t in page_data(load_report(out))["tables"]}
    assert said in shown["davis_J"]["footer"] and said in shown["davis_F"]["footer"]
    assert any(p.startswith("Scored over other frames than the published figures") for p in shown["davis_J"]["footer"])
    assert shown["stream_reference"]["footer"][0].startswith("(error %, unknown truth left out; reduction vs plain:")
    assert shown["stream_frames"]["footer"] == []


def test_evaluate_stream_on_davis_refuses_a_class_table(tmp_path, capsys):
    """``--classes camvid11`` on DAVIS scored the object and its background as camvid11's building and pole (an mIoU
    of the object's mask read as a street scene) and left no method in the J and F tables: refused in one line."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(4))
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--classes", "camvid11", "--out",
                 str(tmp_path / "o")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "--classes with --data davis:PATH" in err[0]
    assert not (tmp_path / "o" / "results.json").exists()


def test_key_every_keeps_the_current_key_frame_where_the_object_is_out_of_view(tmp_path, capsys):
    # a later key frame whose mask has no object pixel: naive Bayes cannot be fitted on one class, and the whole
    # evaluation was refused ("training labels hold only one class"); it is now scored as any other frame
    pairs = frames_and_masks(7, shape=(96, 128))
    pairs = [(img, mask if i < 3 else np.zeros_like(mask)) for i, (img, mask) in enumerate(pairs)]
    seq = write_pcreg_layout(tmp_path / "gone", pairs)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "plain,pcreg_object", "--key-every", "3",
                 "--out", str(out)]) == 0
    unit = json.loads((out / "results.json").read_text())["units"][0]
    assert unit["key_frames"] == [0] and unit["davis"]["frames"] == [1, 2, 3, 4, 5]
    assert all(0 <= v <= 1 for m in ("plain", "pcreg_object") for v in unit["davis"]["J"][m])


def test_key_every_keeps_the_current_key_frame_where_the_object_is_too_small_to_follow(tmp_path, capsys):
    # one object pixel on a later key frame: the follower's reset refused it and the whole evaluation with it
    pairs = frames_and_masks(7, shape=(96, 128))
    speck = np.zeros_like(pairs[3][1])
    speck[41, 41] = 255
    pairs[3] = (pairs[3][0], speck)
    seq = write_pcreg_layout(tmp_path / "hidden", pairs)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "plain,pcreg_object", "--key-every", "3",
                 "--out", str(out)]) == 0
    unit = json.loads((out / "results.json").read_text())["units"][0]
    assert unit["key_frames"] == [0, 6] and unit["davis"]["frames"] == [1, 2, 3, 4, 5]
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "plain", "--key-every", "3",
                 "--out", str(tmp_path / "plain")]) == 0  # naive Bayes alone can start there
    assert json.loads((tmp_path / "plain" / "results.json").read_text())["units"][0]["key_frames"] == [0, 3, 6]


def test_a_damaged_jpeg_frame_is_said_when_evaluated(tmp_path, capsys):
    """A frame whose JPEG decodes around damaged data (cut short, its end marker put back): scored without a word,
    where ``pcreg register`` of the same image says so."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(5))
    path = seq / "images" / "00002.jpg"
    data = path.read_bytes()
    path.write_bytes(data[:len(data) * 2 // 3] + b"\xff\xd9")
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "unregistered", "--out",
                 str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "pcreg: note: clip seq, frame 00002: its decoder reports damaged data (Corrupt JPEG data" in err, err
    assert err.count("damaged data") == 1


def test_the_calibration_table_is_of_the_follower_when_it_runs_without_pcreg(tmp_path):
    """``--methods pcreg_object``: the calibration table and checks were of ``pcreg``, not run (a row of nan a
    sequence); they are of the follower's confidence, and a run of no method with a confidence has none."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(6, shape=(96, 128)))
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "plain,pcreg_object", "--out", str(out)]) == 0
    table = (out / "stream_calibration.md").read_text()
    assert "pcreg_object's confidence" in table and "nan" not in table and "`pcreg run --follow object` writes" in table, table
    assert json.loads((out / "results.json").read_text())["calibration"]["pixels"] > 0
    assert "pcreg_object's confidence is calibrated" in (out / "checks.md").read_text()
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "plain", "--out", str(tmp_path / "plain")]) == 0
    assert not (tmp_path / "plain" / "stream_calibration.md").exists()
    assert "confidence" not in (tmp_path / "plain" / "checks.md").read_text()


@pytest.mark.parametrize("stamp", [None, ["pcreg_object", 1.084, 0.132]], ids=["no stamp", "the magnitude alone"])
def test_a_resumed_evaluation_runs_again_a_clip_whose_follower_counts_an_earlier_version_kept(tmp_path, stamp):
    """A clip kept by a version that counted no confidence of the follower (no stamp) was read back as it was: the
    resumed run's calibration table held 0 pixels under the follower's name. One counted by other coefficients (the
    confidence ``sigmoid(1.084 |L| + 0.132)`` of |L| alone, its stamp ``["pcreg_object", 1.084, 0.132]``) is counted
    again with the confidence of now, not read back."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(6, shape=(96, 128)))
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "plain,pcreg_object", "--out", str(out)]
    assert main(args) == 0
    unit = out / "units" / "seq_reference.json"
    kept = json.loads(unit.read_text())
    assert kept["calibrated"][0] == "pcreg_object"
    counted = kept["calibration"]
    del kept["calibrated"]
    if stamp is not None:
        kept["calibrated"] = stamp
    kept["calibration"] = np.zeros_like(np.array(counted)).tolist()
    unit.write_text(json.dumps(kept))
    assert main(args) == 0
    assert json.loads((out / "results.json").read_text())["calibration"]["pixels"] > 0
    assert json.loads(unit.read_text())["calibration"] == counted
