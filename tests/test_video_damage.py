"""A damaged video never shifts the numbers of the frames after the damage: a Matroska block the demuxer passes over
is refused where the frames after it would be numbered early (exit 2, the frames before kept); a whole video, of a
variable frame rate or with B-frames, is read whole and in order."""

from fractions import Fraction

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.datasets.sources import VideoFrames
from pcreg.errors import InputError
from _runs import one_line_errors
from _videos import mux_all

av = pytest.importorskip("av")


@pytest.fixture(scope="module")
def images():
    return [f.image for f in pcreg.synthetic("syn1a", 12, 0, width=160, height=120)]


def _matroska(path, images, times_ms=None, codec="libx264"):
    """A Matroska file of ``images`` at 10 a second (or at ``times_ms``), H.264 with two B-frames between references."""
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=10, options={"bf": "2", "g": "4"} if codec == "libx264" else {})
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        s.time_base = s.codec_context.time_base = Fraction(1, 1000)
        frames = [av.VideoFrame.from_ndarray(im, format="rgb24") for im in images]
        for f, t in zip(frames, times_ms or [100 * i for i in range(len(images))]):
            f.pts, f.time_base = t, Fraction(1, 1000)
        mux_all(c, s, frames)
    return path


def _block_header_damaged(whole, damaged, k):
    """``whole`` with the 4 bytes before the ``k``-th video packet's data (its block's header) set to 0xff: the
    demuxer passes over what it cannot read, without an error."""
    with av.open(str(whole)) as c:
        pos = [p.pos for p in c.demux(video=0) if p.size][k]
    data = bytearray(whole.read_bytes())
    data[pos - 4:pos] = b"\xff" * 4
    damaged.write_bytes(bytes(data))
    return damaged


def test_a_matroska_block_passed_over_is_refused_where_the_frames_after_it_would_shift(tmp_path, images, capsys):
    whole = _matroska(tmp_path / "whole.mkv", images)
    read = [f.index for f in VideoFrames(whole).frames()]
    assert read == list(range(12))
    for k in (3, 4, 6):  # blocks whose loss takes one frame, a group of pictures, and the frames decoded after it
        damaged = _block_header_damaged(whole, tmp_path / f"d{k}.mkv", k)
        with av.open(str(damaged)) as c:
            assert len(list(c.decode(video=0))) < 12  # frames lost, and FFmpeg says nothing
        with pytest.raises(InputError, match=r"frame\(s\) are missing there and every later frame would be numbered"):
            list(VideoFrames(damaged).frames())
    keys = tmp_path / "keys"  # a key frame late in the video: its labels would be drawn on another frame
    keys.mkdir()
    labels = np.zeros((120, 160), np.uint8)
    labels[:, 80:] = 1
    cv2.imwrite(str(keys / "000000.png"), labels)
    cv2.imwrite(str(keys / "000009.png"), labels)
    damaged = tmp_path / "d4.mkv"
    assert main(["run", str(damaged), "--labels", str(keys), "--out", str(tmp_path / "o"), "--model", "flow"]) == 2
    err = one_line_errors(capsys)
    assert err[0].startswith(f"pcreg: error: {damaged}: frame 4 comes 0.5 s after the frame before, the frames "
                             "before it every 0.1 s: about 4 frame(s) are missing"), err
    written = {p.stem for p in (tmp_path / "o").glob("*.png")}
    assert written <= {"000000", "000001", "000002", "000003", "000009"}, written  # the keys' own, none shifted


def test_matroska_of_a_variable_frame_rate_with_b_frames_is_read_whole(tmp_path, images):
    """Steps of 0.5 s and 1 s at a nominal 10 a second (the frames' durations 0.1 s), and steps of one duration then
    longer ones: a variable frame rate, no frame missing."""
    sparse = _matroska(tmp_path / "sparse.mkv", images[:8], [0, 500, 1000, 1500, 2000, 3000, 4000, 5000])
    assert [f.index for f in VideoFrames(sparse).frames()] == list(range(8))
    slowing = _matroska(tmp_path / "slowing.mkv", images[:8], [0, 100, 200, 300, 450, 650, 900, 1200])
    assert [f.index for f in VideoFrames(slowing).frames()] == list(range(8))
