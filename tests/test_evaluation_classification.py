"""`pcreg evaluate classification` end to end on tiny synthetic data, and every bad input."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io

from pcreg.classification.bayes import NaiveBayesPixelClassifier
from pcreg.classification.weight_search import thesis_weight_search
from pcreg.cli import main
from pcreg.datasets import synthetic
from pcreg.experiments import classification
from pcreg.classification.metrics import confusion_matrix, error_from_confusion

SMALL = ["--frames", "6", "--size", "48x36", "--trials", "4"]


def run_cli(argv: list[str]) -> int:
    """``pcreg evaluate classification ARGV`` through the real command line."""
    from pcreg import cli

    return cli.main(["evaluate", "classification", *argv])


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cls")
    rc = run_cli(["--data", "synthetic:syn1a,syn2b", *SMALL, "--out", str(out)])
    assert rc == 0
    return out


def test_outputs_are_complete(small_run):
    for name in classification.OUTPUT_FILES:
        assert (small_run / name).is_file(), name
    results = json.loads((small_run / "results.json").read_text())
    config = json.loads((small_run / "config.json").read_text())
    assert config == results["config"] and config["data"] == "synthetic:syn1a,syn2b"
    assert results["k"]["I"] == {"syn1a": [1, 2, 3, 4, 5], "syn2b": [1, 2, 3, 4, 5]}
    assert results["k"]["III"] == {"syn1a": [1], "syn2b": [1]}  # 10% and 20% of 6 frames both round to 1
    n_units = 2 * (2 * 5 + 2 + 1)  # features x (case I + case II + case III)
    assert len(results["units"]) == n_units
    assert all(0.0 <= u["error"] <= 100.0 for u in results["units"])
    rows = list(csv.reader((small_run / "case1.csv").open()))
    assert rows[0][:3] == ["dataset", "features", "k=1"] and len(rows) == 1 + 2 * 2
    md = (small_run / "case2.md").read_text()
    assert md.startswith("### Table 4.3") and "| syn1a (DS1A) | thesis |" in md
    assert "10%..90%" in (small_run / "case1.md").read_text()
    assert (small_run / "case1.png").read_bytes()[:4] == b"\x89PNG"


def test_table_4_1_says_how_many_trials_found_its_weights(small_run):
    """Its title said "30 random trials" whatever --trials was (4 here)."""
    from pcreg.experiments.reports.page import load_report, page_data

    assert (small_run / "table41_weights.md").read_text().startswith(
        "### Table 4.1: thesis feature weights, 4 random trials (lowest training error)")
    tables = {t["name"]: t for t in page_data(load_report(small_run))["tables"]}
    assert tables["table41_weights"]["title"].startswith("Table 4.1: thesis feature weights, 4 random trials")
    # Case I's note under its table on the page, as case1.md has it under the table
    [note] = tables["case1"]["footer"]
    assert note.startswith("Note: Case I: k is 10%..90%") and note in (small_run / "case1.md").read_text()
    assert tables["table41_weights"]["footer"] == []


def test_case_i_numbers_are_recomputed_exactly(small_run):
    """One Case I unit redone by hand: weight search on the training frames, fit, pooled error."""
    results = json.loads((small_run / "results.json").read_text())
    frames = synthetic("syn2b", 6, 0, width=48, height=36)
    train, test = frames[:3], frames[3:]
    search = thesis_weight_search([f.image for f in train], [f.labels for f in train], n_trials=4, seed=0)
    clf = NaiveBayesPixelClassifier("thesis", weights=search.weights).fit([f.image for f in train],
                                                                          [f.labels for f in train])
    conf = sum(confusion_matrix(clf.predict(f.image), f.labels) for f in test)
    unit = next(u for u in results["units"] if u["case"] == "I" and u["key"] == ["thesis", "syn2b", 3])
    assert unit["error"] == pytest.approx(error_from_confusion(conf), abs=1e-9)
    assert unit["weights"] == pytest.approx(list(search.weights))
    case2 = next(u for u in results["units"] if u["case"] == "II" and u["key"] == ["rgb+hsv+row", "syn1a"])
    assert [t["dataset"] for t in case2["tests"]] == ["syn1a", "syn2b"]
    total = np.sum([t["confusion"] for t in case2["tests"]], axis=0)
    assert case2["error"] == pytest.approx(error_from_confusion(total))


@pytest.mark.slow
def test_workers_give_the_same_numbers(small_run, tmp_path):
    rc = run_cli(["--data", "synthetic:syn1a,syn2b", *SMALL, "--cases", "II", "--workers", "2",
                  "--out", str(tmp_path)])
    assert rc == 0
    par = json.loads((tmp_path / "results.json").read_text())["units"]
    ser = {tuple(u["key"]): u["error"] for u in json.loads((small_run / "results.json").read_text())["units"]
           if u["case"] == "II"}
    assert {tuple(u["key"]): u["error"] for u in par} == ser


def test_a_rerun_resumes_from_the_finished_units(small_run, capsys):
    before = json.loads((small_run / "results.json").read_text())
    rc = run_cli(["--data", "synthetic:syn1a,syn2b", *SMALL, "--out", str(small_run)])
    assert rc == 0
    after = json.loads((small_run / "results.json").read_text())
    assert after["resumed_units"] == len(after["units"]) == len(before["units"])
    assert [u["error"] for u in after["units"]] == [u["error"] for u in before["units"]]


def test_results_json_is_strict_json(small_run):
    text = (small_run / "results.json").read_text()
    json.loads(text, parse_constant=lambda c: pytest.fail(f"results.json holds {c}"))


def test_refuses_to_overwrite_without_force(small_run, capsys):
    rc = run_cli(["--data", "synthetic:syn1a", *SMALL, "--out", str(small_run)])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pcreg: error:") and "--force" in err and "\n" not in err


def _clip(folder: Path, n: int = 3, *, rng=None, ids=(0, 3, 5), size=(12, 10)) -> None:
    rng = rng or np.random.default_rng(0)
    (folder / "images").mkdir(parents=True)
    (folder / "labels").mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / "images" / f"f{i}.png"), rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8))
        cv2.imwrite(str(folder / "labels" / f"f{i}.png"), rng.choice(np.array(ids, np.uint8), (size[1], size[0])))


def _damage(root: Path, case: str) -> str:
    """Make a bad dataset under root; return the --data value."""
    clip = root / "camvid" / "clip"
    if case == "lagr_without_variables":
        (root / "lagr" / "labeled_lagr_data_640x480_DS1A").mkdir(parents=True)
        scipy.io.savemat(root / "lagr" / "labeled_lagr_data_640x480_DS1A" / "frame001.mat", {"x": np.zeros(2)})
        return f"lagr:{root / 'lagr'}"
    if case == "no_frames":
        (clip / "images").mkdir(parents=True)
        return f"camvid:{root / 'camvid'}"
    _clip(clip)
    if case == "image_without_label":
        (clip / "labels" / "f1.png").unlink()
    elif case == "label_without_image":
        (clip / "images" / "f2.png").unlink()
    elif case == "size_mismatch":
        cv2.imwrite(str(clip / "labels" / "f0.png"), np.zeros((3, 3), np.uint8))
    elif case == "ids_outside_mapping":
        cv2.imwrite(str(clip / "labels" / "f0.png"), np.full((10, 12), 77, np.uint8))
    elif case == "corrupt_png":
        (clip / "images" / "f0.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    elif case == "one_class_only":
        for i in range(3):
            cv2.imwrite(str(clip / "labels" / f"f{i}.png"), np.full((10, 12), 3, np.uint8))
    elif case == "k_larger_than_dataset":
        return f"camvid:{root / 'camvid'} --k 5"
    return f"camvid:{root / 'camvid'}"


BAD = {
    "no_frames": "no image frames",
    "image_without_label": "no label file",
    "label_without_image": "label file without an image",
    "size_mismatch": "but the image is",
    "ids_outside_mapping": "label value 77 is not a class id",
    "lagr_without_variables": "im_rgb",
    "corrupt_png": "cannot decode",
    "one_class_only": "one class only",
    "k_larger_than_dataset": "larger than dataset",
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_exit_2_and_no_results(tmp_path, capsys, case):
    spec = _damage(tmp_path, case).split()
    out = tmp_path / "out"
    rc = run_cli(["--data", spec[0], *spec[1:], "--trials", "2", "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("pcreg: error:") and err.count("\n") == 1, err
    assert BAD[case] in err
    assert not (out / "results.json").exists()


def test_k_larger_than_a_synthetic_sequence(tmp_path, capsys):
    rc = run_cli(["--data", "synthetic:syn1a", *SMALL, "--cases", "III", "--k3", "7", "--out", str(tmp_path)])
    assert rc == 2 and "k=7 is larger than dataset syn1a" in capsys.readouterr().err
    assert not (tmp_path / "results.json").exists()


def test_case_i_on_a_one_frame_sequence_names_it_before_any_unit_runs(tmp_path, capsys):
    """A sequence of one frame gave Case I k = 0: a unit trained on no frame and the run stopped with "no training
    images", naming neither the sequence nor the case, after writing config.json and units/. It is refused
    before anything is written, naming both; Cases II and III still run on it."""
    _clip(tmp_path / "data" / "clip", 1)
    out = tmp_path / "out"
    assert run_cli(["--data", f"camvid:{tmp_path / 'data'}", "--features", "rgb", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "dataset clip has 1 frame(s): Case I" in err and "--cases" in err and err.count("\n") == 1, err
    assert not out.exists()
    assert run_cli(["--data", f"camvid:{tmp_path / 'data'}", "--features", "rgb", "--cases", "II,III",
                    "--out", str(out)]) == 0


def test_case_iii_keeps_each_fraction_of_a_long_sequence_beside_a_short_one(tmp_path):
    """Case III's levels are 10% and 20% of each sequence. Beside a sequence of 3 frames, where both round to
    k = 1, a sequence of 10 lost its 20% level (k = 2) without a word: each sequence's levels were deduplicated on
    their own and cut to the shortest list. A level is dropped only when it is the same in every sequence."""
    _clip(tmp_path / "data" / "long", 10)
    _clip(tmp_path / "data" / "short", 3, rng=np.random.default_rng(1))
    out = tmp_path / "out"
    assert run_cli(["--data", f"camvid:{tmp_path / 'data'}", "--cases", "III", "--features", "rgb",
                    "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["k"]["III"] == {"long": [1, 2], "short": [1, 1]}
    assert [u["train_frames"] for u in res["units"]] == [2, 3]
    with open(out / "case3.csv", newline="") as fh:
        assert [r[:3] for r in list(csv.reader(fh))[1:]] == [["1", "rgb", "2"], ["1,2", "rgb", "3"]]


def test_unknown_feature_and_case_are_rejected(tmp_path, capsys):
    assert run_cli(["--features", "rgb+nope", "--out", str(tmp_path)]) == 2
    assert "unknown feature" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        run_cli(["--cases", "IV", "--out", str(tmp_path)])
    assert exc.value.code == 2


@pytest.mark.parametrize("sets, said", [
    (["rgb+hsv", "hsv+rgb"], "lists one feature set twice (rgb+hsv and hsv+rgb: the order of a set's features"),
    (["rgb", "RGB"], "lists rgb twice"),
])
def test_one_feature_set_given_twice_is_refused_in_any_order(tmp_path, capsys, sets, said):
    """rgb+hsv and hsv+rgb are one naive Bayes (it multiplies its features' likelihoods): both ran, as two rows of
    the same numbers."""
    assert run_cli(["--features", *sets, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and said in err, err
    assert not (tmp_path / "out").exists()


def test_data_help_names_davis_which_it_reads(capsys):
    """Every evaluation reads --data davis:PATH (classification's Case I-III on DAVIS's frames and masks), and
    classification's --help says so as the others' do."""
    with pytest.raises(SystemExit):
        main(["evaluate", "classification", "--help"])
    assert "davis:PATH[:val|train|all]" in " ".join(capsys.readouterr().out.split())


def test_case_i_columns_of_sequences_of_different_lengths_name_the_k_of_their_cells(tmp_path):
    """With sequences of different lengths, Case I's columns were named by the fractions (k=10% ... k=90%) while a
    short sequence's cells, fewer after rounding (6 frames: k = 1..5), filled the first columns: its k=5 (83%) sat
    under k=50%. Each cell now lies under the fraction that gave its k, and the other cells of its row are empty."""
    _clip(tmp_path / "data" / "long", 10)
    _clip(tmp_path / "data" / "short", 6, rng=np.random.default_rng(1))
    out = tmp_path / "out"
    assert run_cli(["--data", f"camvid:{tmp_path / 'data'}", "--cases", "I", "--features", "rgb", "--out", str(out)]) == 0
    with open(out / "case1.csv", newline="") as fh:
        header, *rows = list(csv.reader(fh))
    assert header[2:] == [f"k={p}%" for p in range(10, 100, 10)]
    frames = {"long": 10, "short": 6}
    for row in rows:
        for col, cell in zip(header[2:], row[2:]):
            if cell:
                k = int(cell.split("(k=")[1].rstrip(")"))
                assert k == min(max(1, round(int(col[2:-1]) / 100 * frames[row[0]])), frames[row[0]] - 1), (row, col)
    short = next(r for r in rows if r[0] == "short")
    assert [c.split("(k=")[1] if c else "" for c in short[2:]] == ["1)", "", "2)", "", "3)", "4)", "", "5)", ""]


def test_test_frames_whose_truth_is_all_unknown_are_refused_not_scored_nan(shared_data, tmp_path, capsys):
    """A clip whose frames after the first hold only void truth: `evaluate classification` wrote a report of NaN
    (Case I's every cell) and exited 0, with numpy's "Mean of empty slice" on stderr. Refused, exit 2."""
    import cv2
    import numpy as np

    from pcreg.cli import main

    src = shared_data / "camvid" / "0001TP"
    clip = tmp_path / "data" / "c1"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    names = sorted(p.name for p in (src / "images").iterdir())[:5]
    for i, name in enumerate(names):
        (clip / "images" / name).write_bytes((src / "images" / name).read_bytes())
        labels = cv2.imread(str(src / "labels" / name), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(clip / "labels" / name), labels if i == 0 else np.full_like(labels, 11))
    out = tmp_path / "out"
    assert main(["evaluate", "classification", "--data", f"camvid:{tmp_path / 'data'}", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "nothing to score" in err and "RuntimeWarning" not in err and not (out / "results.json").exists()
