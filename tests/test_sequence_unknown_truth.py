"""``pcreg evaluate sequence`` of a clip whose moving frames' truth is all unknown: its table was NaN under plain and
augmented, its checks "NOT met (nan vs nan)" and "nan%", numpy's warnings on the terminal, exit 0 (``evaluate
classification`` refuses the same clip). Refused as nothing to score; a cell without a score among scored ones is
left out of the checks, not failed."""

import math
import shutil

import cv2
import numpy as np

from pcreg.cli import main


def _clip(shared_data, tmp_path, void_from):
    src = shared_data / "camvid" / "0001TP_b"
    clip = tmp_path / "clip"
    for sub in ("images", "labels"):
        (clip / sub).mkdir(parents=True)
        for p in sorted((src / sub).iterdir())[:6]:
            shutil.copy(p, clip / sub / p.name)
    for i, p in enumerate(sorted((clip / "labels").iterdir())):
        if i >= void_from:
            cv2.imwrite(str(p), np.full(cv2.imread(str(p), cv2.IMREAD_UNCHANGED).shape[:2], 11, np.uint8))
    return clip


def test_a_clip_whose_moving_frames_are_all_unknown_is_refused(shared_data, tmp_path, capsys):
    clip = _clip(shared_data, tmp_path, void_from=2)
    out = tmp_path / "out"
    args = ["evaluate", "sequence", "--data", f"camvid:{clip}", "--frames", "6", "-k", "1,2", "--levels", "2",
            "--iterations", "5", "--out", str(out)]
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["pcreg: error: no pair was scored (clip k=1: the truth of every moving frame is all unknown, moving "
                   "frame(s) 2): nothing to score"], err
    assert not (out / "results.json").exists() and not list((out / "units").rglob("*.json"))


def test_the_checks_leave_out_a_cell_without_a_score():
    from pcreg.experiments.reports.sequence import checks

    nan = math.nan
    scored = {"plain": 10.0, "augmented": 8.0, "augmented_unregistered": 9.0, "thesis_before": 12.0,
              "thesis_after": 11.0, "thesis_after_masked": 11.0}
    unscored = {**scored, "plain": nan, "augmented": nan, "augmented_unregistered": nan}
    results = {"backends": {"reference": {"datasets": {"a": {
        "increments": {"4": scored, "7": unscored}, "pairs": {"4": {"pairs": 3}, "7": {"pairs": 2}}}}}}}
    said = checks(results)
    assert "nan" not in said, said
    assert "- augmented < plain on every sequence and increment (1 cells): met" in said
    assert "- mean relative reduction of augmented vs plain: 20.0% (min 20.0%, max 20.0%)" in said
    assert "- augmented < augmented_unregistered at k >= 4 (1 cells): met" in said


def test_a_row_without_pairs_shows_no_weight():
    """``-k 1,10`` on a clip of six frames: the k=10 row, which has no pair, showed the fusion weight chosen for k=1."""
    from pcreg.experiments.reports.sequence import table

    nan = math.nan
    means = {"plain": 10.0, "augmented": 8.0}
    results = {"datasets": {}, "backends": {"reference": {"datasets": {"a": {
        "increments": {"1": means, "10": {"plain": nan, "augmented": nan}},
        "pairs": {"1": {"pairs": 5, "failed_pairs": 0, "weight": 1.0},
                  "10": {"pairs": 0, "failed_pairs": 0, "weight": 1.0}}}}}}}
    header, rows = table(results, "reference")
    w = header.index("w")
    assert [r[w] for r in rows] == ["1", "n/a"]
