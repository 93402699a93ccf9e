"""Interlaced video (a camcorder's AVCHD, broadcast MPEG-2 or H.264 coded as fields) is read deinterlaced: each
frame's two fields are taken half a frame interval apart, and whatever moves showed combing. The videos here are
encoded with PyAV from two fields of a moving picture (even rows at time t, odd rows at t + 1/2, flagged top field
first), so the true picture at each frame's time is known."""

import json
from fractions import Fraction

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets.sources import Selection, VideoFrames, open_frames
from _runs import stopped_and_resumed, timeless
from _videos import mux_all

av = pytest.importorskip("av")

H, W, N, SPEED = 144, 192, 12, 6  # SPEED: pixels the picture moves right in a frame interval


def _picture(t: float) -> np.ndarray:
    """The true picture at time ``t`` (in frame intervals): vertical bars and smooth texture moving right."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.random((H, 2 * W, 3)).astype(np.float32), (0, 0), 3)
    texture = (texture - texture.min()) / (texture.max() - texture.min())
    bars = (np.sin(np.arange(2 * W) / 3.0) * 0.5 + 0.5)[None, :, None]
    scene = 255 * (0.5 * texture + 0.5 * bars)
    shift = SPEED * t
    whole, part = int(np.floor(shift)), shift - np.floor(shift)
    moved = (1 - part) * np.roll(scene, whole, axis=1) + part * np.roll(scene, whole + 1, axis=1)
    return np.round(moved[:, :W]).clip(0, 255).astype(np.uint8)


def _encoder(codec):
    try:
        av.codec.Codec(codec, "w")
    except (av.FFmpegError, ValueError):
        pytest.skip(f"this FFmpeg has no {codec} encoder")


def _write(path, *, interlaced=True, codec="libx264", fmt=None, n=N):
    """An ``n``-frame video at ``path``; interlaced: each frame woven from two fields of the moving picture and
    flagged so (FFmpeg's ``setfield``, as a camcorder's encoder flags them); else the picture at each frame's time."""
    _encoder(codec)
    with av.open(str(path), "w", format=fmt) as c:
        s = c.add_stream(codec, rate=25)
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        if codec == "libx264":
            s.options = {"crf": "12", **({"flags": "+ildct+ilme", "x264-params": "interlaced=1"} if interlaced else {})}
        else:
            s.bit_rate = 8_000_000
            s.options = {"flags": "+ildct+ilme"} if interlaced else {}
        graph = av.filter.Graph()
        source = graph.add_buffer(width=W, height=H, format="yuv420p", time_base=Fraction(1, 25))
        setfield, sink = graph.add("setfield", "mode=tff"), graph.add("buffersink")
        source.link_to(setfield)
        setfield.link_to(sink)
        graph.configure()

        def frame(k: int):
            image = _picture(k)
            if not interlaced:
                return av.VideoFrame.from_ndarray(image, format="rgb24").reformat(format="yuv420p")
            image[1::2] = _picture(k + 0.5)[1::2]
            graph.vpush(av.VideoFrame.from_ndarray(image, format="rgb24").reformat(format="yuv420p"))
            return graph.vpull()

        mux_all(c, s, (frame(k) for k in range(n)))
    return path


def _decoded(path):
    """The frames as decoded (converted to RGB, nothing else), and whether each is flagged interlaced."""
    with av.open(str(path)) as c:
        got = [(f.to_ndarray(format="rgb24"), bool(f.interlaced_frame)) for f in c.decode(video=0)]
    return [g[0] for g in got], [g[1] for g in got]


def _combing(image) -> float:
    """Mean absolute difference between adjacent rows (0-255)."""
    return float(np.abs(np.diff(image.astype(np.float64), axis=0)).mean())


@pytest.mark.parametrize("name, codec, fmt", [("00001.MTS", "libx264", "mpegts"), ("clip.mp4", "libx264", None),
                                              ("broadcast.mkv", "mpeg2video", None)])
def test_interlaced_frames_are_read_without_combing(tmp_path, name, codec, fmt):
    video = _write(tmp_path / name, codec=codec, fmt=fmt)
    raw, flagged = _decoded(video)
    assert len(raw) == N and all(flagged)
    src = open_frames(video)
    assert src.interlaced and "interlaced" in src.note()
    got = list(src.frames())
    assert [f.name for f in got] == [f"{i:06d}" for i in range(N)] and [f.index for f in got] == list(range(N))
    truth = [_picture(k) for k in range(N)]
    for k, f in enumerate(got):  # the first field's time (top field first): the true picture at t = k
        assert _combing(raw[k]) > 30 > 5 > _combing(f.image), k
        assert np.abs(f.image.astype(int) - truth[k]).mean() < 7 < 15 < np.abs(raw[k].astype(int) - truth[k]).mean(), k


def test_a_deinterlaced_frame_is_the_same_however_the_stream_got_there(tmp_path):
    video = _write(tmp_path / "clip.mkv", codec="mpeg2video")
    whole = {f.index: f.image for f in VideoFrames(video).frames()}
    assert sorted(whole) == list(range(N))
    for sel in [Selection(start=3), Selection(every=3), Selection(start=2, stop=7, every=2), Selection(stop=5),
                Selection(start=1, stop=N - 1, every=5)]:
        src = VideoFrames(video, sel)
        got = list(src.frames())
        assert [f.index for f in got] == list(range(N))[sel.start:sel.stop:sel.every], sel
        assert [f.position for f in got] == list(range(len(got)))
        for f in got:
            np.testing.assert_array_equal(f.image, whole[f.index], err_msg=f"{sel} frame {f.index}")
        for first in range(1, len(got)):  # resumed at each position
            again = list(src.frames(first))
            assert [f.index for f in again] == [f.index for f in got[first:]], (sel, first)
            np.testing.assert_array_equal(again[0].image, got[first].image, err_msg=f"{sel} from {first}")


@pytest.mark.parametrize("codec", ["libx264", "mpeg2video"])
def test_progressive_video_is_read_as_decoded_byte_for_byte(tmp_path, codec):
    video = _write(tmp_path / "clip.mkv", interlaced=False, codec=codec)
    raw, flagged = _decoded(video)
    assert not any(flagged)
    src = VideoFrames(video)
    assert not src.interlaced and src.note() is None
    got = list(src.frames())
    assert len(got) == len(raw) == N
    for f, image in zip(got, raw):
        assert f.image.dtype == image.dtype and f.image.tobytes() == image.tobytes(), f.name
    picked = list(VideoFrames(video, Selection(start=1, every=4)).frames(1))
    assert [f.index for f in picked] == [5, 9] and picked[0].image.tobytes() == raw[5].tobytes()


def test_run_on_an_interlaced_video_says_so_and_resumes_exactly(tmp_path, capsys, monkeypatch):
    video = _write(tmp_path / "00001.MTS", fmt="mpegts", n=8)
    key = np.zeros((H, W), np.uint8)
    key[H // 2:] = 1
    cv2.imwrite(str(tmp_path / "key.png"), key)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png")]
    whole, cut = stopped_and_resumed(monkeypatch, args, tmp_path, 4)
    err = capsys.readouterr().err
    assert f"pcreg: note: {video} is interlaced" in err and "deinterlaced" in err
    assert sorted(p.name for p in whole.glob("*.png")) == [f"{i:06d}.png" for i in range(8)]
    for file in ["run.json", *[f"{i:06d}.png" for i in range(8)]]:
        assert (whole / file).read_bytes() == (cut / file).read_bytes(), file
    assert ([timeless(x) for x in (whole / "steps.jsonl").read_text().splitlines()]
            == [timeless(x) for x in (cut / "steps.jsonl").read_text().splitlines()])
    # a run begun on its frames as decoded (its run.json names no deinterlacing, as before it was done) is not
    # continued on deinterlaced ones: the labels would change kind at the frame it resumed from
    state = json.loads((cut / "run.json").read_text())
    assert state["run"]["deinterlaced"] == "bwdif"
    del state["run"]["deinterlaced"]
    (cut / "run.json").write_text(json.dumps({**state, "done": 4}))
    capsys.readouterr()
    assert main([*args, "--out", str(cut)]) == 2
    assert "holds a run with other options" in capsys.readouterr().err


def test_a_stream_that_turns_interlaced_part_way_is_deinterlaced_from_there(tmp_path, capsys):
    """Two MPEG-TS files joined (progressive, then interlaced: a broadcast recording across a programme change):
    the progressive frames are read as decoded, byte for byte; the interlaced ones deinterlaced; every frame
    numbered in order and ``pcreg run`` labels them all."""
    first = _write(tmp_path / "a.ts", interlaced=False, codec="mpeg2video", fmt="mpegts", n=6)
    second = _write(tmp_path / "b.ts", codec="mpeg2video", fmt="mpegts", n=6)
    video = tmp_path / "joined.ts"
    video.write_bytes(first.read_bytes() + second.read_bytes())
    raw, flagged = _decoded(video)  # FFmpeg itself decodes 11: one frame is lost at the seam
    turn = flagged.index(True)
    assert 3 <= turn <= 6 and all(flagged[turn:]) and len(raw) >= 10
    got = list(open_frames(video).frames())
    assert [f.index for f in got] == list(range(len(raw)))
    for k, f in enumerate(got):
        if k < turn:
            np.testing.assert_array_equal(f.image, raw[k], err_msg=f"frame {k}")
        else:
            assert _combing(raw[k]) > 30 > 5 > _combing(f.image), k
    key = tmp_path / "key.png"
    cv2.imwrite(str(key), (np.arange(W)[None, :] >= W // 2).astype(np.uint8).repeat(H, axis=0))
    capsys.readouterr()
    assert main(["run", str(video), "--labels", str(key), "--out", str(tmp_path / "out")]) == 0
    assert sorted(p.name for p in (tmp_path / "out").glob("*.png")) == [f"{i:06d}.png" for i in range(len(raw))]
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "interlaced" in ln]  # the turn said once, where it is
    line = (f"{video}: frames flagged interlaced from frame {turn:06d} on, the frames before it progressive (recordings "
            "joined, a programme change): they are deinterlaced with FFmpeg's bwdif as they are read")
    assert notes == [f"pcreg: note: {line}"], notes
    # kept in run.json, and said again by what reads the run afterwards
    assert json.loads((tmp_path / "out" / "run.json").read_text())["notes"] == {"interlaced": line}
    for command in (["view", str(tmp_path / "out"), "--overlay", str(tmp_path / "overlay.mp4")],
                    ["export", str(tmp_path / "out"), "--to", str(tmp_path / "cvat.zip")]):
        assert main(command) == 0
        assert [ln for ln in capsys.readouterr().err.splitlines() if "interlaced" in ln] == [f"pcreg: note: {line}"]
    keys = tmp_path / "keys"  # a run from key frames on both sides of the turn: kept by the pass that decodes it
    keys.mkdir()
    for k in (0, len(raw) - 1):
        cv2.imwrite(str(keys / f"{k:06d}.png"), cv2.imread(str(key), cv2.IMREAD_UNCHANGED))
    assert main(["run", str(video), "--labels", str(keys), "--out", str(tmp_path / "keys-out")]) == 0
    assert json.loads((tmp_path / "keys-out" / "run.json").read_text())["notes"] == {"interlaced": line}
