"""``pcreg view RUN --overlay FILE.mp4 --force`` never writes over the video the run was labelled from, which the
command reads to draw the overlay: ``--force`` overwrites an earlier overlay, not an input."""

from __future__ import annotations

import contextlib
import io

import cv2
import numpy as np

import pcreg
from pcreg.cli import main
from _view import one_line_error, pcreg_view


def test_the_overlay_is_refused_over_the_runs_own_video(tmp_path, capsys):
    frames = pcreg.synthetic("syn1a", 3, 0, width=96, height=72)
    video = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10, (96, 72))
    for f in frames:
        writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    writer.release()
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    out = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(video), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 0
    before = video.read_bytes()
    capsys.readouterr()
    assert pcreg_view([str(out), "--overlay", str(video), "--force"]) == 2
    assert one_line_error(capsys) == (f"pcreg: error: {video} is the input {video}; the output would overwrite it "
                                      "(choose another file)\n")
    assert video.read_bytes() == before
    assert pcreg_view([str(out), "--overlay", str(tmp_path / "overlay.mp4")]) == 0
