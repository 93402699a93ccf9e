"""``pcreg run --truth`` on clips unlike the shared ones: a truth map all void, a truth map missing."""

from __future__ import annotations

import json

import cv2
import numpy as np

from pcreg.cli import main


def _clip(folder, n: int, *, void: tuple[int, ...] = ()):
    """``n`` synthetic frames (96x72) in ``folder/images`` with their CamVid ids in ``folder/labels``, the
    frames in ``void`` labelled void (11) all over."""
    import pcreg

    (folder / "images").mkdir(parents=True)
    (folder / "labels").mkdir()
    ids = np.array([3, 1, 11], np.uint8)  # road, building, void
    for i, f in enumerate(pcreg.synthetic("syn1a", n, 0, width=96, height=72)):
        cv2.imwrite(str(folder / "images" / f"f{i:02d}.png"), f.image[:, :, ::-1])
        cv2.imwrite(str(folder / "labels" / f"f{i:02d}.png"), np.full((72, 96), 11, np.uint8) if i in void else ids[f.labels])
    return folder


def test_a_truth_map_all_void_is_not_counted_as_a_scored_frame(tmp_path, capsys):
    """The run said 'over 3 frames' where one of the three had no pixel of known truth."""
    clip = _clip(tmp_path / "clip", 4, void=(2,))
    out = tmp_path / "out"
    assert main(["run", str(clip), "--labels", str(clip / "labels" / "f00.png"), "--classes", "camvid11",
                 "--truth", str(clip / "labels"), "--out", str(out)]) == 0
    assert "over 2 frames" in capsys.readouterr().out
    truth = json.loads((out / "run.json").read_text())["truth"]
    assert truth["frames"] == 2
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    known = sum(int((cv2.imread(str(clip / "labels" / f"f{i:02d}.png"), cv2.IMREAD_UNCHANGED) != 11).sum()) for i in (1, 3))
    assert truth["known"] == known and len(steps) == 3
