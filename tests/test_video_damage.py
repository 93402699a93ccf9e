"""A video whose frames' times skip frames (a Matroska block the demuxer passed over, frames a live capture dropped)
is read on, its frames numbered by count as annotation tools number them, and the run says where and counts it in
run.json, once a place; a whole video, of a variable frame rate or with B-frames, is read whole and in order."""

import json
from fractions import Fraction

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.datasets.damage import Gap
from pcreg.datasets.sources import Selection, VideoFrames
from pcreg.runs import gaps
from _runs import kill_before_commit, one_line_errors
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


def _gaps(frames) -> list[tuple[int, Gap]]:
    return [(f.index, g) for f in frames for g in f.gaps]


def _label(path, shape=(120, 160)):
    labels = np.zeros(shape, np.uint8)
    labels[:, shape[1] // 2:] = 1
    cv2.imwrite(str(path), labels)
    return path


def _state(out) -> dict:
    return json.loads((out / "run.json").read_text())


SAID = "frames numbered by count, as annotation tools do; if the key labels were drawn on another copy of the video, " \
       "the frames after this one are numbered early"


def test_a_matroska_block_passed_over_is_told_with_the_frame_after_it(tmp_path, images):
    whole = _matroska(tmp_path / "whole.mkv", images)
    read = list(VideoFrames(whole).frames())
    assert [f.index for f in read] == list(range(12)) and _gaps(read) == []
    for k in (3, 4, 6):  # blocks whose loss takes one frame, a group of pictures, and the frames decoded after it
        damaged = _block_header_damaged(whole, tmp_path / f"d{k}.mkv", k)
        with av.open(str(damaged)) as c:
            n = len(list(c.decode(video=0)))
        assert n < 12  # frames lost, and FFmpeg says nothing
        read = list(VideoFrames(damaged).frames())
        assert [f.index for f in read] == list(range(n))  # numbered by count
        (at, gap), = _gaps(read)
        assert gap.index == at and gap.missing == 12 - n, (k, gap)
    damaged = tmp_path / "d4.mkv"
    (at, gap), = _gaps(VideoFrames(damaged).frames())
    assert (at, gap) == (4, Gap(4, 0.5, 0.1, 4))
    assert gap.note(damaged) == (f"{damaged}: frame 4 comes 0.5 s after the frame before, the frames before it every "
                                 "0.1 s: about 4 frame(s) missing there (dropped as it was recorded, or a damaged "
                                 f"block passed over); {SAID}")
    # with the chosen frame after it when frame 4 is not chosen; not again from a later frame on (a resumed run)
    assert _gaps(VideoFrames(damaged, Selection(every=3)).frames()) == [(6, gap)]
    assert _gaps(VideoFrames(damaged).frames(4)) == [(4, gap)]
    assert _gaps(VideoFrames(damaged).frames(5)) == []


def test_a_run_on_a_video_that_skips_frames_goes_on_says_so_once_and_counts_it(tmp_path, images, capsys):
    damaged = _block_header_damaged(_matroska(tmp_path / "whole.mkv", images), tmp_path / "d4.mkv", 4)
    out = tmp_path / "one"
    assert main(["run", str(damaged), "--labels", str(_label(tmp_path / "key.png")), "--out", str(out),
                 "--model", "flow"]) == 0
    err = one_line_errors(capsys)
    notes = [line for line in err if "frame 4 comes 0.5 s after the frame before" in line]
    assert notes == [f"pcreg: note: {damaged}: frame 4 comes 0.5 s after the frame before, the frames before it every "
                     "0.1 s: about 4 frame(s) missing there (dropped as it was recorded, or a damaged block passed "
                     f"over); {SAID}"], err
    assert err[-1] == (f"pcreg: note: {damaged}: about 4 frame(s) missing by its times at 1 place(s), the first before "
                       f"frame 4; counted in {out / 'run.json'} (\"gaps\"), the frames numbered by count"), err
    record = {"places": 1, "missing": 4, "last": "000004", "listed": {"000004": 4}}
    assert _state(out)["gaps"] == record
    assert sorted(p.stem for p in out.glob("*.png")) == [f"{i:06d}" for i in range(8)]
    keys = tmp_path / "keys"
    keys.mkdir()
    for at in ((0, 4), (0, 2)):  # the key frame after the gap, read by two passes; the gap in the last pass
        for k in at:
            _label(keys / f"{k:06d}.png")
        out = tmp_path / f"keys{at[1]}"
        assert main(["run", str(damaged), "--labels", str(keys), "--out", str(out), "--model", "flow"]) == 0
        err = one_line_errors(capsys)
        assert sum("frame 4 comes 0.5 s after" in line for line in err) == 1, err
        assert _state(out)["gaps"] == record
        assert sorted(p.stem for p in out.glob("*.png")) == [f"{i:06d}" for i in range(8)]
        for p in keys.iterdir():
            p.unlink()


def test_a_live_capture_that_dropped_frames_is_said_in_few_lines_and_counted_once_when_resumed(tmp_path, images,
                                                                                                  capsys, monkeypatch):
    """Five frames dropped one at a time (the frames' times 0.1 s apart but at five places 0.2 s): the first three
    said, then that more are counted, then the count; run.json lists at most :data:`~pcreg.runs.gaps.LISTED`."""
    times = [0, 100, 200, 400, 500, 700, 800, 1000, 1100, 1300, 1400, 1600]
    dropped = _matroska(tmp_path / "dropped.mkv", images, times)
    assert [(t, g.missing) for t, g in _gaps(VideoFrames(dropped).frames())] == [(i, 1) for i in (3, 5, 7, 9, 11)]
    monkeypatch.setattr(gaps, "LISTED", 2)
    args = ["run", str(dropped), "--labels", str(_label(tmp_path / "key.png")), "--model", "flow"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main([*args, "--out", str(whole)]) == 0

    def said():
        return [line.split(": ", 3)[3] for line in one_line_errors(capsys) if "missing" in line]

    step = "comes 0.2 s after the frame before, the frames before it every 0.1 s: about 1 frame(s) missing there"
    count = ("about 5 frame(s) missing by its times at 5 place(s), the first before frame 3; counted in {} "
             '("gaps"), the frames numbered by count')
    assert [line.split(" (dropped")[0] for line in said()] == [
        f"frame 3 {step}", f"frame 5 {step}", f"frame 7 {step}", "frames missing before frame 9 too; further places "
        f'are not said one by one but counted in {whole / "run.json"} ("gaps")', count.format(whole / "run.json")]
    kill_before_commit(monkeypatch, 6)  # stopped after frame 6's files, before run.json counted it, and resumed
    assert main([*args, "--out", str(cut)]) == 130
    monkeypatch.undo()
    monkeypatch.setattr(gaps, "LISTED", 2)
    one_line_errors(capsys)  # what it said depends on how far it had read ahead when it stopped
    assert _state(cut)["gaps"] == {"places": 2, "missing": 2, "last": "000005", "listed": {"000003": 1, "000005": 1}}
    assert main([*args, "--out", str(cut)]) == 0
    assert [line.split(" (dropped")[0] for line in said()] == [  # frames 3 and 5 were said and counted before
        f"frame 7 {step}", f"frame 9 {step}", f"frame 11 {step}", count.format(cut / "run.json")]
    record = {"places": 5, "missing": 5, "last": "000011", "listed": {"000003": 1, "000005": 1}}
    assert _state(whole)["gaps"] == _state(cut)["gaps"] == record
    for i in range(12):
        assert (whole / f"{i:06d}.png").read_bytes() == (cut / f"{i:06d}.png").read_bytes()


def test_matroska_of_a_variable_frame_rate_with_b_frames_is_read_whole(tmp_path, images):
    """Steps of 0.5 s and 1 s at a nominal 10 a second (the frames' durations 0.1 s), and steps of one duration then
    longer ones: a variable frame rate, no frame missing."""
    sparse = _matroska(tmp_path / "sparse.mkv", images[:8], [0, 500, 1000, 1500, 2000, 3000, 4000, 5000])
    assert [f.index for f in VideoFrames(sparse).frames()] == list(range(8))
    slowing = _matroska(tmp_path / "slowing.mkv", images[:8], [0, 100, 200, 300, 450, 650, 900, 1200])
    assert [f.index for f in VideoFrames(slowing).frames()] == list(range(8))
