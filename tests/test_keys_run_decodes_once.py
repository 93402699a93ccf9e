"""A run from a folder of key frames reads a video once through its passes: each stretch's pass went on from where the
one before stopped, where it decoded the video from its first frame again (60 frames with a key frame every 10:
221 frames decoded), and every label and confidence map is what reading anew gave, on an interlaced video too."""

import contextlib
import io
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets import sources
from pcreg.pipeline import key_passes
from _runs import video_and_keys


def _counting(monkeypatch) -> list[int]:
    """How many frames the video's decoder hands on, counted as the run goes."""
    count, decoded = [0], sources.VideoFrames._decoded

    def counted(self, reading):
        for item in decoded(self, reading):
            count[0] += 1
            yield item

    monkeypatch.setattr(sources.VideoFrames, "_decoded", counted)
    return count


def _run(video, keys, out) -> bytes:
    """``pcreg run VIDEO --labels KEYS --confidence``: every label and confidence map it wrote, in name order."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(video), "--labels", str(keys), "--confidence", "--out", str(out)]) == 0
    maps = sorted(out.glob("*.png")) + sorted((out / "confidence").glob("*.png"))
    assert len(maps) > 1
    return b"".join(p.name.encode() + p.read_bytes() for p in maps)


def _anew(monkeypatch) -> None:
    """Each pass reading its frames anew, as before."""
    monkeypatch.setattr(key_passes.Decoded, "frames", lambda self, first: self.source.frames(first))


def test_a_video_with_a_key_frame_every_ten_is_decoded_once(tmp_path, monkeypatch):
    n = 60
    _, video, keys = video_and_keys(tmp_path, n, range(0, n, 10))
    count = _counting(monkeypatch)
    once = _run(video, keys, tmp_path / "once")
    assert count[0] <= n + 1  # the passes' one reading, and the key frame's check at the start
    _anew(monkeypatch)
    count[0] = 0
    assert _run(video, keys, tmp_path / "anew") == once
    assert count[0] > 3 * n  # as it was: each pass decoded the video from its first frame


def test_an_interlaced_video_s_frames_are_the_same_however_the_passes_read_them(tmp_path, monkeypatch):
    pytest.importorskip("av")
    from test_video_interlaced import _write

    video = _write(tmp_path / "fields.mp4", n=14)
    keys = tmp_path / "keys"
    keys.mkdir()
    with contextlib.closing(sources.VideoFrames(video).frames()) as shown:
        images = [f.image for f in shown]
    for i in (2, 6, 7, 11):  # two key frames side by side: a stretch of no frame between
        grey = cv2.cvtColor(images[i], cv2.COLOR_RGB2GRAY)
        cv2.imwrite(str(keys / f"{i:06d}.png"), (grey > np.median(grey)).astype(np.uint8))
    count = _counting(monkeypatch)
    once = _run(video, keys, tmp_path / "once")
    assert count[0] <= 14 + 2  # the check at the start decodes two: a frame is handed on once the next is decoded
    _anew(monkeypatch)
    assert _run(video, keys, tmp_path / "anew") == once


def test_a_run_from_a_later_start_decodes_the_frames_before_it_once(tmp_path, monkeypatch):
    n, start = 40, 20
    _, video, keys = video_and_keys(tmp_path, n, (25, 32))  # the first pass begins at frame 20, before the first key
    count = _counting(monkeypatch)
    args = ["run", str(video), "--labels", str(keys), "--start", str(start), "--confidence"]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*args, "--out", str(tmp_path / "once")]) == 0
    assert count[0] <= n + 1  # the key frames' size read from frame 20, where the first pass went on
    _anew(monkeypatch)
    count[0] = 0
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*args, "--out", str(tmp_path / "anew")]) == 0
    assert count[0] >= n + start  # as it was: decoded to frame 20 for the size, then again by the first pass
    for name in ("once", "anew"):
        assert len(list((tmp_path / name).glob("0*.png"))) == n - start
    for p in sorted((tmp_path / "anew").rglob("*.png")):
        assert (tmp_path / "once" / p.relative_to(tmp_path / "anew")).read_bytes() == p.read_bytes(), p.name


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="reads the open files from /proc/self/fd (Linux)")
def test_a_refused_run_keeps_no_video_open_while_its_error_is_held(tmp_path):
    """The reading a folder run begins at --start is closed however the run ends: a refusal kept (a notebook's last
    error, ``pytest.raises``) held the video's file and its decoder."""
    from pcreg.datasets.sources import Selection
    from pcreg.errors import OutputError
    from pcreg.pipeline.config import PropagatorConfig
    from pcreg.runs.run import Run, RunRequest

    _, video, keys = video_and_keys(tmp_path, 12, (6, 9))
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(video), "--labels", str(keys), "--start", "4", "--confidence", "--out", str(tmp_path / "o")]) == 0

    def held() -> list[str]:
        fds = Path("/proc/self/fd")
        return [t for t in (os.readlink(fd) for fd in fds.iterdir() if fd.exists()) if t.endswith("clip.avi")]

    request = RunRequest(video, keys, tmp_path / "o", PropagatorConfig(), Selection(start=4), confidence=False)
    with pytest.raises(OutputError, match="other options") as refused:
        Run.label(request)
    assert refused.value is not None and held() == []
