"""``--size`` sizes synthetic frames only: beside real ``--data`` it is refused, not ignored."""

from __future__ import annotations

import json

import pytest

from pcreg.cli import main
from _davis import frames_and_masks, write_pcreg_layout
from _runs import one_line_errors


@pytest.mark.parametrize("command", ["stream", "sequence", "rotation", "classification"])
def test_size_beside_real_data_is_refused_in_one_line(tmp_path, capsys, command):
    # it was ignored: the frames ran at their own 64x48 while config.json said 32x24
    seq = write_pcreg_layout(tmp_path / "davis" / "disc", frames_and_masks(4))
    out = tmp_path / "out"
    assert main(["evaluate", command, "--data", f"davis:{seq}", "--size", "32x24", "--out", str(out)]) == 2
    lines = one_line_errors(capsys)
    assert len(lines) == 1 and "--size 32x24 sets synthetic frames' size only" in lines[0] and f"davis:{seq}" in lines[0]
    assert not out.exists()


def test_size_with_synthetic_data_is_still_the_frames_size(tmp_path):
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", " Synthetic:syn1a", "--frames", "2", "--size", "48x36",
                 "--methods", "plain", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["config"]["size"] == [48, 36] and results["units"][0]["width"] == 48
