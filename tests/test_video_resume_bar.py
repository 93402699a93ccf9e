"""A resumed video run decodes its way to its first frame not done under a bar of its own, counting the frames on the
way (an hour into a video: minutes), where the run's bar of frames stood at 0 all that time."""

import contextlib
import io

import cv2

import pcreg
from pcreg import _runner
from pcreg.cli import main
from _runs import video_and_keys, write_video


def _ways(monkeypatch, args) -> list[tuple]:
    """``pcreg ARGS`` with every bar drawn (to stderr, which pytest holds) and kept: each ``decoding to frame`` bar's
    name, count and total."""
    bars, progress = [], _runner.progress

    def shown(*a, **kw):
        kw["disable"] = False
        bars.append(progress(*a, **kw))
        return bars[-1]

    monkeypatch.setattr(_runner, "progress", shown)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(args) == 0
    monkeypatch.undo()
    return [(b.desc, b.n, b.total) for b in bars if b.desc.startswith("decoding to frame")]


def test_a_video_run_taken_further_shows_the_frames_decoded_on_the_way(tmp_path, monkeypatch):
    frames = pcreg.synthetic("syn1a", 12, 0, width=96, height=72)
    video = write_video(tmp_path / "clip.mp4", frames)
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "out")]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*args, "--stop", "7"]) == 0
    assert _ways(monkeypatch, args) == [("decoding to frame 000007", 7, 7)]
    assert sorted(p.name for p in (tmp_path / "out").glob("0*.png")) == [f"{i:06d}.png" for i in range(12)]


def test_a_key_frames_run_that_redoes_a_later_stretch_shows_the_way_to_it(tmp_path, monkeypatch):
    frames, video, keys = video_and_keys(tmp_path, 12, (0, 4))
    args = ["run", str(video), "--labels", str(keys), "--out", str(tmp_path / "out")]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(args) == 0
    cv2.imwrite(str(keys / "000008.png"), frames[8].labels)  # the stretch after 4 is redone, and one after 8 added
    assert _ways(monkeypatch, args) == [("decoding to frame 000004", 4, 4)]


def test_a_run_from_a_later_start_shows_the_frames_decoded_before_it(tmp_path, monkeypatch):
    frames = pcreg.synthetic("syn1a", 12, 0, width=96, height=72)
    video = write_video(tmp_path / "clip.mp4", frames)
    cv2.imwrite(str(tmp_path / "key.png"), frames[5].labels)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--start", "5", "--out", str(tmp_path / "out")]
    assert _ways(monkeypatch, args) == [("decoding to frame 000005", 5, 5)]
