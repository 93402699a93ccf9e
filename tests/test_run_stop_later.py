"""`pcreg run` again with a later `--stop` (or none) over the same `--out`: the run goes on to the frames added, as a
person labelling hours of video takes them a stretch at a time; it was refused as a run of "other options"."""

from __future__ import annotations

import json

import cv2
import pytest

from pcreg.cli import main
from _runs import drifting_frames, key_frames_of, one_line_errors
from _videos import mux_all


def _labels(out):
    return {p.name: p.read_bytes() for p in sorted(out.glob("*.png"))}


def test_a_later_stop_goes_on_and_labels_what_one_run_labels(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 5))
    for labels, name in ((key, "one"), (keys, "keyed")):
        out, whole = tmp_path / name, tmp_path / f"{name}-whole"
        run = ["run", str(folder), "--labels", str(labels), "--out", str(out)]
        assert main([*run, "--stop", "3"]) == 0
        assert {p.stem for p in out.glob("*.png")} == {"f0", "f1", "f2"}
        assert main([*run, "--stop", "5"]) == 0
        said = capsys.readouterr().out  # the frames labelled now, and with those before (as the predicted error counts them)
        assert name != "one" or "2 frame(s) labelled into" in said and "(4 with the 2 before)" in said
        assert main(run) == 0
        assert json.loads((out / "run.json").read_text())["run"].get("frames") is None
        assert main(["run", str(folder), "--labels", str(labels), "--out", str(whole)]) == 0
        assert _labels(out) == _labels(whole) and len(_labels(out)) == 6
        capsys.readouterr()
        assert main([*run, "--stop", "4"]) == 2  # fewer frames: refused, the labels kept
        assert "holds a run with other options (frames: every frame then, --stop 4 now)" in one_line_errors(capsys)[-1]
        assert main([*run, "--start", "1", "--stop", "9"]) == 2  # other frames, at other positions
        assert "other options (frames: every frame then, --start 1 --stop 9 now)" in one_line_errors(capsys)[-1]
        assert _labels(out) == _labels(whole)


def test_a_key_frames_run_taken_further_says_the_frames_labelled_in_all(tmp_path, capsys):
    """The frames labelled now (the stretch after the last key frame, 6 and 7) and, as the predicted error counts them, in all."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=8)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 5))
    run = ["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out")]
    assert main([*run, "--stop", "7"]) == 0
    assert "5 frame(s) labelled from 2 key frame(s) into" in capsys.readouterr().out
    assert main(run) == 0
    said = capsys.readouterr().out
    assert "2 frame(s) labelled from 2 key frame(s) into" in said and "(6 in all)" in said and "over 6 frame(s)" in said


def test_a_later_stop_beside_another_option_is_not_named_among_what_differs(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    run = ["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out")]
    assert main([*run, "--stop", "3"]) == 0
    capsys.readouterr()
    assert main([*run, "--confidence"]) == 2  # the confidence maps differ; a later --stop alone would be taken
    said = one_line_errors(capsys)[-1]
    assert "holds a run with other options (confidence: not set then, True now)" in said and "frames" not in said
    assert main([*run, "--stop", "2", "--confidence"]) == 2  # fewer frames: named, as before
    assert "frames: --stop 3 then, --stop 2 now" in one_line_errors(capsys)[-1]


def test_a_video_run_to_its_stop_goes_on_past_it(tmp_path):
    """A video run labelled to its --stop keeps that decoding found its end (``video_end``): the run again with a
    later --stop was to say every frame done. It labels the frames added, as a run over the whole video does."""
    av = pytest.importorskip("av")
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=9)
    video = tmp_path / "v.mp4"
    with av.open(str(video), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        mux_all(container, stream, [cv2.imread(str(p))[:, :, ::-1].copy() for p in sorted(folder.glob("*.png"))])
    run = ["run", str(video), "--labels", str(key), "--out", str(tmp_path / "out")]
    assert main([*run, "--stop", "4"]) == 0
    assert json.loads((tmp_path / "out" / "run.json").read_text())["video_end"] == 4
    assert main(run) == 0
    assert main(["run", str(video), "--labels", str(key), "--out", str(tmp_path / "whole")]) == 0
    assert _labels(tmp_path / "out") == _labels(tmp_path / "whole") and len(_labels(tmp_path / "whole")) == 9
    assert json.loads((tmp_path / "out" / "run.json").read_text())["video_end"] == 9
