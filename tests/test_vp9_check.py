"""A VP9 frame that decodes with errors: FFmpeg's VP9 decoder flags none (it conceals the frame without a word);
libvpx, fed the same packets, refuses it, and the frame is marked damaged. A clean file decodes to FFmpeg's pixels,
nothing marked."""

import numpy as np
import pytest

import pcreg
from pcreg.datasets.sources import VideoFrames
from pcreg.datasets.vp9_check import Vp9Check
from _videos import mux_all

av = pytest.importorskip("av")
pytestmark = pytest.mark.skipif(not {"libvpx-vp9", "vp9"} <= av.codecs_available,
                                reason="PyAV's FFmpeg has no libvpx-vp9 (VP9's encoder and reference decoder)")


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """A WebM file of 12 synthetic frames at 10 a second, VP9 with a key frame every 6."""
    path = tmp_path_factory.mktemp("vp9") / "whole.webm"
    with av.open(str(path), "w") as c:
        s = c.add_stream("libvpx-vp9", rate=10, options={"g": "6"})
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        mux_all(c, s, [f.image for f in pcreg.synthetic("syn1a", 12, 0, width=160, height=120)])
    return path


def _flipped(whole, damaged, packets, at=30):
    """``whole`` with 4 bytes at ``at`` inverted within each of its video ``packets`` (numbered from 0)."""
    with av.open(str(whole)) as c:
        pos = [p.pos for p in c.demux(video=0) if p.size]
    data = bytearray(whole.read_bytes())
    for k in packets:
        data[pos[k] + at:pos[k] + at + 4] = bytes(255 - b for b in data[pos[k] + at:pos[k] + at + 4])
    damaged.write_bytes(bytes(data))
    return damaged


def _ffmpeg(path):
    with av.open(str(path)) as c:
        frames = list(c.decode(video=0))
    return frames


def test_a_clean_vp9_file_decodes_to_ffmpegs_pixels_nothing_marked(whole):
    plain = _ffmpeg(whole)
    read = list(VideoFrames(whole).frames())
    assert len(read) == len(plain) == 12
    assert all(np.array_equal(f.image, p.to_ndarray(format="rgb24")) for f, p in zip(read, plain))
    assert not any(f.damaged for f in read)


@pytest.mark.parametrize("packets, marked, changed", [
    ((2,), [2], [2, 3, 4, 5]),  # the frames after it up to the key frame carry its damage, unmarked
    ((0,), [0], [0, 1, 2, 3, 4, 5]),  # the first key frame
    ((1, 8), [1, 8], [1, 2, 3, 4, 5, 8, 9, 10, 11]),  # one after the other key frame: told again
    ((1, 3), [1], [1, 2, 3, 4, 5]),  # a second one before the key frame: libvpx refuses all until then
])
def test_a_damaged_vp9_frame_is_marked_where_ffmpeg_flags_nothing(tmp_path, whole, packets, marked, changed):
    damaged = _flipped(whole, tmp_path / "damaged.webm", packets)
    assert not any(f.is_corrupt for f in _ffmpeg(damaged))  # FFmpeg's decoder says nothing
    clean, read = list(VideoFrames(whole).frames()), list(VideoFrames(damaged).frames())
    assert [f.index for f in read] == list(range(12))
    assert [f.index for f in read if f.damaged] == marked
    assert [f.index for f, c in zip(read, clean) if not np.array_equal(f.image, c.image)] == changed


def test_only_8_bit_vp9_is_checked(tmp_path, whole):
    with av.open(str(whole)) as c:
        assert Vp9Check(c.streams.video[0]).decoder is not None
    path = tmp_path / "h264.mp4"
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=10)
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        mux_all(c, s, [np.zeros((120, 160, 3), np.uint8)] * 2)
    with av.open(str(path)) as c:
        assert Vp9Check(c.streams.video[0]).decoder is None
