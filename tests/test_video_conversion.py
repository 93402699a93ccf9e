"""A video's frames converted to RGB by one converter for the whole stream are, byte for byte, what PyAV's
conversion of each frame on its own gives, for the pixel formats cameras and encoders write (limited and full
range, 4:2:0 and 4:4:4, 10 bits, grey, RGB already) and for a frame turned by its display matrix."""

import numpy as np
import pytest

import pcreg
from pcreg.datasets.sources import VideoFrames
from _videos import mux_all

av = pytest.importorskip("av")


@pytest.fixture(scope="module")
def images():
    return [f.image for f in pcreg.synthetic("syn1a", 6, 0, width=160, height=120)]


def _write(path, images, codec, pix_fmt, degrees=None):
    """``images`` (RGB) encoded with ``codec`` in ``pix_fmt``; ``degrees``: a display rotation."""
    try:
        av.codec.Codec(codec, "w")
    except (av.FFmpegError, ValueError):
        pytest.skip(f"this FFmpeg has no {codec} encoder")
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=10)
        stream.width, stream.height, stream.pix_fmt = images[0].shape[1], images[0].shape[0], pix_fmt
        if degrees is not None:
            if not hasattr(stream, "set_display_rotation"):
                pytest.skip("this PyAV cannot write a display rotation")
            stream.set_display_rotation(degrees)
        mux_all(container, stream, images)
    return path


def _each_converted(path):
    """Every frame of ``path`` as PyAV converts a frame to RGB alone (a converter made for it)."""
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]


@pytest.mark.parametrize("name, codec, pix_fmt", [
    ("v.mp4", "libx264", "yuv420p"),
    ("v.mp4", "libx264", "yuvj420p"),
    ("v.mp4", "libx264", "yuv444p"),
    ("v.mkv", "ffv1", "yuv420p10le"),
    ("v.mkv", "ffv1", "gray"),
    ("v.mkv", "ffv1", "bgr0"),
    ("v.mov", "png", "rgb24"),
    ("v.avi", "mjpeg", "yuvj422p"),
])
def test_frames_are_converted_as_each_frame_alone_would_be(tmp_path, images, name, codec, pix_fmt):
    path = _write(tmp_path / name, images, codec, pix_fmt)
    with av.open(str(path)) as container:
        assert container.streams.video[0].codec_context.pix_fmt == pix_fmt
    expected = _each_converted(path)
    got = [f.image for f in VideoFrames(path).frames()]
    assert len(got) == len(expected) == len(images)
    for i, (g, e) in enumerate(zip(got, expected)):
        assert g.dtype == np.uint8 and g.shape == e.shape == (120, 160, 3), i
        assert np.array_equal(g, e), i
    assert not np.array_equal(got[0], got[-1])  # frames that differ: nothing of one frame is kept for the next


@pytest.mark.parametrize("degrees", [90, 180])
def test_turned_frames_are_converted_as_each_frame_alone_would_be(tmp_path, images, degrees):
    path = _write(tmp_path / f"r{degrees}.mp4", images, "mpeg4", "yuv420p", degrees)
    expected = [np.rot90(e, degrees // 90) for e in _each_converted(path)]
    got = [f.image for f in VideoFrames(path).frames()]
    assert len(got) == len(expected) == len(images)
    for i, (g, e) in enumerate(zip(got, expected)):
        assert g.shape == e.shape and np.array_equal(g, e), i


def test_a_stream_read_twice_and_from_a_later_frame_gives_the_same_frames(tmp_path, images):
    path = _write(tmp_path / "v.mp4", images, "libx264", "yuv420p")
    source = VideoFrames(path)
    first = [f.image for f in source.frames()]
    again = [f.image for f in source.frames()]
    later = [f.image for f in source.frames(3)]
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert len(later) == len(images) - 3 and all(np.array_equal(a, b) for a, b in zip(first[3:], later))
