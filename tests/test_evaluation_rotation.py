"""pcreg evaluate rotation: rotated frames before/after registration (small synthetic frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets import synthetic
from pcreg.experiments.rotation import KEYS, rotate_frame, sample_indices
from pcreg.registration.transforms import apply

SMALL = ["--data", "synthetic:syn1a", "--frames", "4", "--size", "160x120", "--samples", "1"]


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    out = tmp_path_factory.mktemp("rotation") / "rot"
    assert main(["evaluate", "rotation", *SMALL, "--angles", "0,30,90,180", "--backend", "both",
                 "--out", str(out)]) == 0
    return out


def test_outputs_and_layout(done):
    for name in ("results.json", "config.json", "rotation_reference.md", "rotation_open3d.csv", "checks.md",
                 "rotation.png"):
        assert (done / name).is_file(), name
    res = json.loads((done / "results.json").read_text())
    angles = res["datasets"]["syn1a"]["angles"]
    assert set(angles) == {"0", "30", "90", "180"}
    for cell in angles.values():
        assert set(KEYS) <= set(cell)
    # no rotation: before and after are the same classification of the same frame
    assert angles["0"]["before"] == pytest.approx(angles["0"]["after"])
    # registering back recovers the classification of the original frame at a quarter and a half turn
    for a in ("90", "180"):
        assert angles[a]["after"] < angles[a]["before"]
        assert abs(angles[a]["after"] - angles["0"]["after"]) <= 2.0
    assert "backend open3d" in (done / "checks.md").read_text()


def test_rerun_resumes(done):
    assert main(["evaluate", "rotation", *SMALL, "--angles", "0,30,90,180", "--backend", "both",
                 "--out", str(done)]) == 0
    assert json.loads((done / "results.json").read_text())["resumed_units"] == 2


def test_rotate_frame_geometry():
    f = synthetic("syn1a", 1, 0, width=160, height=120)[0]
    img, lab, content, T = rotate_frame(f.image, f.labels, 90.0, canvas="loose")
    assert img.shape[:2] == (160, 120) and lab.shape == (160, 120) and content.all()
    # the centre maps to the centre; the corners stay inside the canvas
    assert np.allclose(apply(T, np.array([[79.5, 59.5]])), [[59.5, 79.5]])
    img_c, _, content_c, _ = rotate_frame(f.image, f.labels, 45.0, canvas="crop")
    assert img_c.shape[:2] == (120, 160) and not content_c.all()
    same, lab0, _, T0 = rotate_frame(f.image, f.labels, 0.0)
    assert np.array_equal(same, f.image) and np.array_equal(lab0, f.labels) and np.allclose(T0, np.eye(3))


def test_sample_indices():
    assert sample_indices(100, 3) == [0, 50, 99]
    assert sample_indices(2, 3) == [0, 1]
    assert sample_indices(0, 3) == []


@pytest.mark.parametrize("bad", [["--angles", "x"], ["--angles", "0:90:0"], ["--canvas", "big"]])
def test_bad_options_exit_2(tmp_path, capsys, bad):
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "rotation", *SMALL, "--out", str(tmp_path / "r"), *bad])
    assert exc.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_bad_values_exit_2_with_one_line(tmp_path, capsys):
    assert main(["evaluate", "rotation", *SMALL, "--samples", "0", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--samples" in err[0]


@pytest.mark.parametrize("size, ids, what", [((3, 3), (3, 5), "too small to register"),
                                              ((24, 20), (3, 3), "only one class")])
def test_a_frame_it_cannot_evaluate_is_named(tmp_path, capsys, size, ids, what):
    """A sampled frame too small to register, or whose labels hold one class, stopped the run with
    "reference image: image too small to register (3x3 px)", naming no dataset nor frame among all those run."""
    import cv2

    rng = np.random.default_rng(0)
    clip = tmp_path / "data" / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i in range(2):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), rng.integers(0, 256, (size[1], size[0], 3), np.uint8))
        lab = np.full((size[1], size[0]), ids[0], np.uint8)
        lab[: size[1] // 2 + 1] = ids[1]
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), lab)
    assert main(["evaluate", "rotation", "--data", f"camvid:{tmp_path / 'data'}", "--angles", "0,10",
                 "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pcreg: error: dataset clip, frame f0: ") and what in err and err.count("\n") == 1, err


def test_the_figure_spans_the_angles_run(done, tmp_path):
    """rotation.png's axis had fixed ticks at 0, 30, ..., 180: --angles -30:30:15 drew its curves on an axis from
    -30 to 180 with no tick below 0, and --angles 0:10:5 squeezed them into its first 20th."""
    from pcreg.experiments.reports.rotation import _figure

    ax = _figure(json.loads((done / "results.json").read_text())).axes[0]
    lo, hi = ax.get_xlim()
    assert [t for t in ax.get_xticks() if lo <= t <= hi] == [0, 30, 60, 90, 120, 150, 180]  # the thesis's ticks
    out = tmp_path / "r"
    assert main(["evaluate", "rotation", *SMALL, "--angles=-30:30:15", "--levels", "2", "--out", str(out)]) == 0
    ax = _figure(json.loads((out / "results.json").read_text())).axes[0]
    lo, hi = ax.get_xlim()
    assert -40 < lo < -30 and 30 < hi < 40, (lo, hi)
    assert any(t < 0 for t in ax.get_xticks() if lo <= t <= hi)


def test_recording_holds_the_error_series_of_results_json(tmp_path):
    from pcreg.recording.readback import read_recording

    rrd = tmp_path / "rot.rrd"
    assert main(["evaluate", "rotation", *SMALL, "--angles", "0,90", "--out", str(tmp_path / "r"),
                 "--record", str(rrd)]) == 0
    res = json.loads((tmp_path / "r" / "results.json").read_text())
    rec = read_recording(rrd)
    for key in KEYS:
        series = rec.series(f"errors/syn1a/frame0/reference/{key}")
        assert sorted(series) == [0, 1]
        assert [series[0], series[1]] == pytest.approx(
            [res["datasets"]["syn1a"]["angles"][a][key] for a in ("0", "90")])
    assert len(rec.get("transforms/T_ref_mov")) == 2
    assert res["units"][0]["recording_frames"] == {"0": 0, "90": 1}  # each angle's frame, for the report page



def test_a_rerun_removes_what_a_killed_run_left_half_written(tmp_path):
    """A run killed (kill -9, power lost) while it wrote a unit's file or the report leaves their temporary
    files in OUT/units and OUT: the next run, which writes those files, removes them, and no other file."""
    from _runs import killed_mid_write

    out = tmp_path / "r"
    args = ["evaluate", "rotation", *SMALL, "--angles", "0,90", "--out", str(out)]
    assert main(args) == 0
    unit = out / "units" / "syn1a" / "frame0_reference.json"
    unit.unlink()  # killed as it wrote the unit: not finished
    left = [killed_mid_write(p) for p in (unit, out / "results.json", out / "config.json", out / "rotation.png")]
    theirs = killed_mid_write(out / "notes.txt")  # not a file the evaluation writes
    assert main(args) == 0
    assert unit.is_file() and not any(p.exists() for p in left) and theirs.is_file()
    assert sorted(p.name for p in out.rglob(".*.tmp")) == [theirs.name]

def test_checks_say_when_neither_quarter_nor_half_turn_was_run():
    """Angles without 90 and 180 (`--angles 0,45`) leave the check nothing to compare: checks.md says so
    rather than ending the dataset's line after its 0-degree error."""
    from pcreg.experiments.reports.rotation import checks

    cell = dict.fromkeys(KEYS, 7.9)
    results = {"backends": {"reference": {"datasets": {"0016E5": {"angles": {"0": cell, "45": cell}}}}}}
    assert "- 0016E5: 0 degrees 7.90; neither 90 nor 180 degrees in the angle set\n" in checks(results)


@pytest.mark.parametrize("angles", ["100.0001,100.0002", "5,5", "0,-0"])
def test_angles_that_the_results_would_name_alike_are_refused(tmp_path, capsys, angles):
    """Results name an angle by its 6 significant digits (``100.0001`` and ``100.0002`` are both ``100``): two such
    angles were one row written twice, the second angle's errors under both, and ``-0`` was not the ``0`` the checks
    read. Refused in one line before anything runs."""
    out = tmp_path / "o"
    assert main(["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "2", "--size", "64x48",
                 "--samples", "1", f"--angles={angles}", "--out", str(out)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "--angles" in err[0] and "one angle" in err[0]
    assert not (out / "results.json").exists()


def test_angles_whose_registration_was_refused_are_marked_not_passed_off_as_registered():
    """A refused registration is scored on the unregistered frame. checks.md judged those numbers "met" or "NOT met"
    as if registered, and rotation.png drew them on the registered curves unmarked."""
    from pcreg.experiments.reports.rotation import _figure, checks

    def cell(after, failed, frames=2):
        return {**dict.fromkeys(KEYS, after), "failed": failed, "frames": frames, "corner_error_median": None}

    angles = {"0": cell(8.0, 0), "90": cell(8.5, 2), "180": cell(9.0, 1)}
    results = {"primary_backend": "reference", "datasets": {"clip": {}},
               "backends": {"reference": {"datasets": {"clip": {"angles": angles}}}}}
    said = checks(results)
    assert "90: not measured, registration refused on every frame at 90 degrees" in said
    assert "after 90" not in said and "after 180: 9.00 (+1.00, met)" in said
    assert "(registration refused on 2 of 2 frames at 90 degrees, 1 of 2 frames at 180 degrees: those frames are " \
           "scored unregistered)" in said
    ax = _figure(results).axes[0]
    marked = [line for line in ax.get_lines() if line.get_label() == "registration refused (scored unregistered)"]
    assert len(marked) == 1 and list(marked[0].get_xdata()) == [90.0, 180.0]
    assert list(marked[0].get_ydata()) == [8.5, 9.0]


def test_the_worst_corner_error_is_shown_beside_the_median():
    """A checkerboard frame registered a period off at 180 degrees (619 px, "registered") among two frames registered
    to 0.01 px read "failed 0/3" and a median of 0.01 px: the worst stands beside the median now."""
    from pcreg.experiments.reports.rotation import table
    from pcreg.experiments.rotation import RotationConfig, summarise

    def unit(name, error):
        row = {**dict.fromkeys(KEYS, 5.0), "registered": True, "corner_error": error, "seconds_register": 0.1}
        return {"dataset": "clip", "backend": "reference", "name": name, "angles": {"180": row}}

    results = summarise(RotationConfig(angles=(180.0,)), [unit("a", 0.01), unit("b", 619.37), unit("c", 0.02)])
    cell = results.backends["reference"]["datasets"]["clip"]["angles"]["180"]
    assert cell["corner_error_median"] == pytest.approx(0.02) and cell["corner_error_max"] == pytest.approx(619.37)
    header, rows = table({"datasets": {}, "backends": results.backends}, "reference")
    assert header[-2:] == ["corner error px (median)", "(worst)"] and rows[0][-3:] == ["0/3", "0.02", "619.37"]


def test_a_sampled_frame_it_cannot_train_on_is_left_out_and_said(tmp_path, capsys):
    """One sampled frame whose labels hold one class (or none) stopped the whole run, though the others could be
    scored (the sequence evaluation leaves such a frame out): left out, said on stderr and in results.json's notes;
    with no frame left, refused as before."""
    import cv2

    rng = np.random.default_rng(0)
    clip = tmp_path / "data" / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i in range(3):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), rng.integers(0, 256, (40, 48, 3), np.uint8))
        lab = np.full((40, 48), 3, np.uint8)  # CamVid's road: ground
        if i:
            lab[:20] = 5  # building: obstacle
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), lab)
    out = tmp_path / "r"
    capsys.readouterr()
    assert main(["evaluate", "rotation", "--data", f"camvid:{tmp_path / 'data'}", "--angles", "0,10", "--levels", "2",
                 "--out", str(out)]) == 0
    said = "dataset clip, frame f0: training labels hold only one class (ground)"
    assert f"pcreg: note: {said}" in capsys.readouterr().err
    results = json.loads((out / "results.json").read_text())
    assert len(results["notes"]) == 1 and results["notes"][0].startswith(said)
    assert results["datasets"]["clip"]["frames"] == ["f1", "f2"]
