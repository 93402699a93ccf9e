"""``--size`` and ``--seed`` make synthetic frames only: beside real ``--data`` they are refused, not ignored."""

from __future__ import annotations

import json

import pytest

from pcreg.cli import main
from _davis import frames_and_masks, write_pcreg_layout
from _runs import one_line_errors


def _camvid(root):
    """A CamVid-layout clip of three 12x10 frames (ids 3 and 5) in ``root``; ``root``."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    (root / "clip" / "images").mkdir(parents=True)
    (root / "clip" / "labels").mkdir()
    for i in range(3):
        cv2.imwrite(str(root / "clip" / "images" / f"f{i}.png"), rng.integers(0, 256, (10, 12, 3), np.uint8))
        cv2.imwrite(str(root / "clip" / "labels" / f"f{i}.png"), rng.choice(np.uint8([3, 5]), (10, 12)))
    return root


SYNTHETIC_ONLY = {"--size": ("32x24", "--size 32x24 sets synthetic frames' size only"),
                  "--seed": ("7", "--seed 7 seeds synthetic frames only")}


@pytest.mark.parametrize("kind", ["davis", "camvid"])
@pytest.mark.parametrize("command, option", [(c, o) for o in SYNTHETIC_ONLY for c in ("stream", "sequence", "rotation",
                                                                                       "classification")
                                             if (c, o) != ("classification", "--seed")])
def test_an_option_of_synthetic_data_beside_real_data_is_refused_in_one_line(tmp_path, capsys, command, option, kind):
    """--size was ignored: the frames ran at their own 64x48 (12x10) while config.json said the --size, and a rerun
    with another --size was refused as a different configuration. --seed was ignored but written in config.json
    too. (``evaluate classification``'s --seed seeds its weight search as well, and stays.)"""
    data = (f"davis:{write_pcreg_layout(tmp_path / 'davis' / 'disc', frames_and_masks(4))}" if kind == "davis"
            else f"camvid:{_camvid(tmp_path / 'data')}")
    out = tmp_path / "out"
    value, said = SYNTHETIC_ONLY[option]
    assert main(["evaluate", command, "--data", data, option, value, "--out", str(out)]) == 2
    lines = one_line_errors(capsys)
    assert len(lines) == 1 and lines[0].startswith(f"pcreg: error: {said}")
    assert data in lines[0]
    assert not out.exists()


def test_size_with_synthetic_data_is_still_the_frames_size(tmp_path):
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", " Synthetic:syn1a", "--frames", "2", "--size", "48x36",
                 "--methods", "plain", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["config"]["size"] == [48, 36] and results["units"][0]["width"] == 48


def test_seed_with_synthetic_data_is_the_frames_seed_and_real_data_keeps_0_in_its_configuration(tmp_path):
    """Runs from before keep resuming: a real --data's config.json still holds seed 0."""
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", "synthetic:syn1a", "--frames", "2", "--size", "48x36", "--seed", "7",
                 "--methods", "plain", "--out", str(out)]) == 0
    assert json.loads((out / "results.json").read_text())["config"]["seed"] == 7
    real = tmp_path / "real"
    assert main(["evaluate", "stream", "--data", f"camvid:{_camvid(tmp_path / 'data')}", "--methods", "plain",
                 "--out", str(real)]) == 0
    assert json.loads((real / "results.json").read_text())["config"]["seed"] == 0
