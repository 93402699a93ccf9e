"""A Matroska file whose video track's ``DURATION`` tag holds no finite time (``nan``, ``inf``, a negative one:
a damaged or hand-edited tag; FFmpeg hands the text on as it is) is read as one without the tag: its duration is the container's. The text went
through ``float``, which takes ``nan`` and ``inf``, and the frame count estimated from it raised Python's
ValueError or OverflowError: ``pcreg run`` ended as a bug in pcreg."""

from __future__ import annotations

import re

import numpy as np
import pytest

from _videos import mux_all


def _matroska(path, n: int = 5) -> bytes:
    import av

    rng = np.random.default_rng(0)
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        mux_all(container, stream, [rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(n)])
    return path.read_bytes()


@pytest.mark.parametrize("value", ["nan", "inf", "-5"])
def test_a_duration_tag_of_no_finite_time_is_left_out(tmp_path, value):
    from pcreg.datasets.sources import open_frames

    data = _matroska(tmp_path / "whole.mkv")
    tag = re.search(rb"DURATION.{1,8}?(\d\d:\d\d:\d\d\.\d+)", data, re.S).group(1)  # 00:00:00.200000000
    said = b"00:00:" + value.encode().rjust(len(tag) - 6)  # float() takes the spaces before it
    (tmp_path / "tagged.mkv").write_bytes(data.replace(tag, said))
    video = open_frames(tmp_path / "tagged.mkv")
    assert video.duration == pytest.approx(0.2) and video.count() == 5  # the container's: 5 frames at 25 a second
    assert [f.name for f in video.frames()] == [f"{i:06d}" for i in range(5)]
