"""`pcreg run VIDEO`: a video file's frames decoded one at a time, named by index, chosen with --start,
--stop and --every, resumed exactly; bad videos and options refused in one line (exit 2), nothing
already written lost. Every video is written here with OpenCV's writer (or by hand, for an AVI whose
frame size changes)."""

import gc
import json
import struct

import av
import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.datasets.sources import Selection, VideoFrames, open_frames
from pcreg.errors import InputError
from _runs import kill_before_commit, one_line_errors, stopped_and_resumed, timeless
from _videos import mux_all


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 8, 0, width=160, height=120)


def _write_video(path, images, fourcc="mp4v"):
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (w, h))
    assert writer.isOpened(), path
    for rgb in images:
        writer.write(np.ascontiguousarray(rgb[:, :, ::-1]))
    writer.release()
    return path


def _mjpeg_avi(path, images):
    """An AVI of JPEG frames written by hand, each frame at its own size (OpenCV's writer keeps one)."""
    def chunk(fourcc, data):
        return fourcc + struct.pack("<I", len(data)) + data + b"\0" * (len(data) % 2)

    def listed(kind, body):
        return b"LIST" + struct.pack("<I", len(body) + 4) + kind + body

    h, w = images[0].shape[:2]
    n = len(images)
    avih = struct.pack("<14I", 100_000, 0, 0, 0x10, n, 0, 1, 0, w, h, 0, 0, 0, 0)
    strh = b"vidsMJPG" + struct.pack("<IHHIIIIIIIIhhhh", 0, 0, 0, 0, 1, 10, 0, n, 0, 0xFFFFFFFF, 0, 0, 0, w, h)
    strf = struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, int.from_bytes(b"MJPG", "little"), w * h * 3, 0, 0, 0, 0)
    hdrl = listed(b"hdrl", chunk(b"avih", avih) + listed(b"strl", chunk(b"strh", strh) + chunk(b"strf", strf)))
    movi = listed(b"movi", b"".join(chunk(b"00dc", cv2.imencode(".jpg", f[:, :, ::-1])[1].tobytes()) for f in images))
    body = b"AVI " + hdrl + movi
    path.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    return path


_err, _timeless = one_line_errors, timeless


def test_video_frames_are_decoded_in_order_and_chosen(tmp_path, frames):
    video = _write_video(tmp_path / "v.mp4", [f.image for f in frames])
    src = open_frames(video)
    assert isinstance(src, VideoFrames) and src.declared == 8 and src.count() == 8
    got = list(src.frames())
    assert [(f.position, f.index, f.name) for f in got] == [(i, i, f"{i:06d}") for i in range(8)]
    for f, truth in zip(got, frames):  # mp4v is lossy: close, not equal
        assert f.image.shape == truth.image.shape and f.image.dtype == np.uint8
        assert np.abs(f.image.astype(int) - truth.image).mean() < 8
    chosen = VideoFrames(video, Selection(1, 7, 2))
    assert chosen.count() == 3 and [f.name for f in chosen.frames()] == ["000001", "000003", "000005"]
    later = list(chosen.frames(1))  # a resumed stream: the frames before decoded, not returned
    assert [(f.position, f.name) for f in later] == [(1, "000003"), (2, "000005")]
    np.testing.assert_array_equal(later[0].image, got[3].image)
    assert chosen.writes("000003") and not chosen.writes("000002") and not chosen.writes("000007")
    # a file named as a frame past the video's end is no output of it (an --out holding it was refused)
    assert src.writes("000007") and not src.writes("000008") and not src.writes("000100") and not src.writes("20240101")
    assert VideoFrames(video, Selection(1, None, 2)).writes("000007") and not VideoFrames(video, Selection(1, None, 2)).writes("000009")
    for bad, said in (({"every": 0}, "--every"), ({"start": 3, "stop": 3}, "--stop 3 must be greater"),
                      ({"start": -1}, "--start")):
        with pytest.raises(InputError, match=said):
            Selection(**bad)


def test_run_on_a_video_names_frames_by_index_and_resumes_exactly(tmp_path, frames, capsys, monkeypatch):

    video = _write_video(tmp_path / "clip.avi", [f.image for f in frames[:6]], "MJPG")
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--confidence"]
    assert main(args + ["--out", str(tmp_path / "whole")]) == 0
    whole = tmp_path / "whole"
    assert sorted(p.name for p in whole.glob("*.png")) == [f"{i:06d}.png" for i in range(6)]
    assert sorted(p.name for p in (whole / "confidence").glob("*.png")) == [f"{i:06d}.png" for i in range(1, 6)]
    steps = [json.loads(line) for line in (whole / "steps.jsonl").read_text().splitlines()]
    assert [s["name"] for s in steps] == [f"{i:06d}" for i in range(1, 6)]
    state = json.loads((whole / "run.json").read_text())
    assert state["key_frame"] == "000000" and state["done"] == 6 and state["run"]["video"] == str(video)
    assert "frames" not in state["run"]  # every frame: the identity names no selection

    # killed after frame 3's PNG and step line were written, before run.json counted it; then resumed
    kill_before_commit(monkeypatch, 3)
    assert main(args + ["--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    cut = tmp_path / "cut"
    assert json.loads((cut / "run.json").read_text())["done"] == 3
    assert main(args + ["--out", str(cut)]) == 0
    names = [f"{i:06d}.png" for i in range(6)] + [f"confidence/{i:06d}.png" for i in range(1, 6)]
    for name in ["run.json", "carry-0.npz", "carry-1.npz", *names]:
        assert (whole / name).read_bytes() == (cut / name).read_bytes(), name
    assert ([_timeless(x) for x in (whole / "steps.jsonl").read_text().splitlines()]
            == [_timeless(x) for x in (cut / "steps.jsonl").read_text().splitlines()])
    assert main(args + ["--out", str(cut)]) == 0 and "already done" in capsys.readouterr().out

    # another choice of frames over the same --out is refused; in its own folder it names frames by index
    for other in (["--every", "2"], ["--start", "1"], ["--stop", "5"]):
        assert main(args + ["--out", str(cut), *other]) == 2
        assert "other options" in _err(capsys)[0]
    picked = tmp_path / "picked"
    assert main(args + ["--out", str(picked), "--start", "1", "--every", "2"]) == 0
    assert sorted(p.name for p in picked.glob("*.png")) == ["000001.png", "000003.png", "000005.png"]
    state = json.loads((picked / "run.json").read_text())
    assert state["key_frame"] == "000001" and state["run"]["frames"] == {"start": 1, "stop": None, "every": 2}
    # the labels of a chosen frame are the same however the stream got there (frame 3 from frame 1's key)
    half = tmp_path / "half"
    assert main(args + ["--out", str(half), "--start", "1", "--every", "2", "--stop", "4"]) == 0
    assert sorted(p.name for p in half.glob("*.png")) == ["000001.png", "000003.png"]
    assert (half / "000003.png").read_bytes() == (picked / "000003.png").read_bytes()


def test_a_folder_takes_start_stop_and_every_too(tmp_path, frames, capsys):
    src = tmp_path / "frames"
    src.mkdir()
    for i, f in enumerate(frames[:6]):
        cv2.imwrite(str(src / f"f{i:03d}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "key.png"), frames[1].labels)
    base = ["run", str(src), "--labels", str(tmp_path / "key.png")]
    assert main(base + ["--out", str(tmp_path / "o"), "--start", "1", "--stop", "5", "--every", "2"]) == 0
    out = tmp_path / "o"
    assert sorted(p.name for p in out.glob("*.png")) == ["f001.png", "f003.png"]
    assert [json.loads(x)["name"] for x in (out / "steps.jsonl").read_text().splitlines()] == ["f003.png"]
    assert json.loads((out / "run.json").read_text())["key_frame"] == "f001.png"
    assert main(base + ["--out", str(tmp_path / "p"), "--start", "6"]) == 2
    assert _err(capsys) == [f"pcreg: error: --start 6 is past the end of {src} (6 frames)"]
    assert main(base + ["--out", str(tmp_path / "p"), "--start", "5"]) == 2
    assert "needs at least two frames" in _err(capsys)[0]
    assert not (tmp_path / "p").exists()


def test_bad_videos_and_options_are_refused_in_one_line(tmp_path, frames, capsys):
    images = [f.image for f in frames]
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    good = _write_video(tmp_path / "good.mp4", images)
    text = tmp_path / "text.mp4"
    text.write_text("not a video\n" * 50)
    png = tmp_path / "image.mp4"
    png.write_bytes(cv2.imencode(".png", images[0])[1].tobytes())
    other = tmp_path / "notes.txt"
    other.write_text("x")
    data = good.read_bytes()
    cut_mp4 = tmp_path / "cut.mp4"
    cut_mp4.write_bytes(data[:len(data) // 2])  # OpenCV writes the index (moov) last: it is gone
    empty_avi = tmp_path / "empty.avi"
    cv2.VideoWriter(str(empty_avi), cv2.VideoWriter_fourcc(*"MJPG"), 10, (160, 120)).release()  # no frame
    empty_mp4 = tmp_path / "empty.mp4"
    cv2.VideoWriter(str(empty_mp4), cv2.VideoWriter_fourcc(*"mp4v"), 10, (160, 120)).release()
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), frames[0].labels[:60])
    sound = tmp_path / "sound.mp4"  # a recording of sound alone
    with av.open(str(sound), "w") as container:
        stream = container.add_stream("aac", rate=8000)
        tone = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        tone.sample_rate = 8000
        for packet in [*stream.encode(tone), *stream.encode(None)]:
            container.mux(packet)

    def refused(source, *extra, labels=tmp_path / "key.png"):
        out = tmp_path / "o"
        try:
            rc = main(["run", str(source), "--labels", str(labels), "--out", str(out), *map(str, extra)])
        except SystemExit as exc:  # an option argparse refuses
            rc = exc.code
        err = _err(capsys)
        assert rc == 2 and len(err) == 1, (rc, err)
        assert not out.exists()  # refused before anything was written
        return err[0]

    assert f"{text}: not a video FFmpeg can read" in refused(text)
    assert f"{png}: not a video (FFmpeg reads it as png_pipe" in refused(png)
    assert f"{other}: not a folder or a video file" in refused(other)
    assert f"{cut_mp4}: an MP4 or QuickTime file without its index (no moov box)" in refused(cut_mp4)
    assert f"{empty_avi}: no frame decodes" in refused(empty_avi)
    assert f"{empty_mp4}: holds no video stream (no stream at all" in refused(empty_mp4)
    assert f"{sound}: holds no video stream (only audio streams: a recording of sound alone" in refused(sound)
    m4a, mp3 = _songs_with_cover_art(tmp_path, frames[0].image)
    assert f"{m4a}: holds no video stream, only a still picture attached to it (cover art of a recording of sound)" \
        in refused(m4a)
    assert f"{mp3}: not a video (FFmpeg reads it as mp3, not as" in refused(mp3)
    assert "--every: expected an integer" in refused(good, "--every", 0)
    assert f"--start 8 is past the end of {good} (8 frames)" in refused(good, "--start", 8)
    assert "--stop 3 must be greater than --start 3" in refused(good, "--start", 3, "--stop", 3)
    assert "--stop 2 must be greater than --start 5" in refused(good, "--start", 5, "--stop", 2)
    assert f"{small}: labels are 160x60, the key frame 000000 is 160x120" in refused(good, labels=small)
    assert f"{good}: needs at least two frames" in refused(good, "--start", 7)
    assert f"{good}: 160x120 px frames exceed the limit of 1000 pixels" in refused(good, "--max-pixels", 1000)
    keep = tmp_path / "keep"  # key labels named as a frame's output, in --out: refused, never overwritten
    keep.mkdir()
    cv2.imwrite(str(keep / "000000.png"), frames[0].labels)
    assert main(["run", str(good), "--labels", str(keep / "000000.png"), "--out", str(keep)]) == 2
    assert "would overwrite the input" in _err(capsys)[0] and sorted(p.name for p in keep.iterdir()) == ["000000.png"]


def test_a_video_is_scored_against_truth_maps_named_by_index(tmp_path, frames, capsys):
    video = _write_video(tmp_path / "v.avi", [f.image for f in frames[:5]], "MJPG")
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    truth = tmp_path / "truth"
    truth.mkdir()
    for i, f in enumerate(frames[:3]):
        cv2.imwrite(str(truth / f"{i:06d}.png"), f.labels)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--truth", str(truth), "--out", str(tmp_path / "o")]
    assert main(args + ["--stop", "3"]) == 0
    state = json.loads((tmp_path / "o" / "run.json").read_text())
    assert state["truth"]["frames"] == 2 and state["truth"]["error"] < state["truth"]["plain_error"]
    # a video's length is known once decoded: a missing map stops the run at its frame, the frames before kept
    assert main(args[:-1] + [str(tmp_path / "p")]) == 2
    assert _err(capsys) == [f"pcreg: error: {truth / '000003.png'}: no truth labels for frame 000003 (--truth {truth} "
                            "holds NAME.png for each frame NAME)"]
    assert json.loads((tmp_path / "p" / "run.json").read_text())["done"] == 3


def test_a_video_that_breaks_midway_keeps_the_frames_already_labelled(tmp_path, frames, capsys):
    images = [frames[i % 8].image for i in range(12)]
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    # the frame size changes at frame 3: refused there, never resampled; frames 0-2 stay labelled
    mixed = _mjpeg_avi(tmp_path / "mixed.avi", images[:3] + [cv2.resize(im, (80, 60)) for im in images[3:5]])
    args = ["run", str(mixed), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "m")]
    assert main(args) == 2
    assert _err(capsys) == [f"pcreg: error: {mixed}: frame 3 is 80x60, the frames before it 160x120; "
                            "pcreg needs one frame size"]
    assert json.loads((tmp_path / "m" / "run.json").read_text())["done"] == 3
    assert sorted(p.name for p in (tmp_path / "m").glob("*.png")) == ["000000.png", "000001.png", "000002.png"]
    # a video cut in half: the frames before the cut are labelled and kept, the cut is named
    whole = _write_video(tmp_path / "whole.avi", images, "MJPG")
    data = whole.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[:len(data) // 2])
    args = ["run", str(cut), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "c")]
    assert main(args) == 2
    err = _err(capsys)
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {cut}: ") and "truncated or damaged" in err[0], err
    done = json.loads((tmp_path / "c" / "run.json").read_text())["done"]
    assert done >= 3 and len(list((tmp_path / "c").glob("0*.png"))) == done
    assert main(args) == 2 and "truncated or damaged" in _err(capsys)[0]  # resumed: the same frames, kept
    assert json.loads((tmp_path / "c" / "run.json").read_text())["done"] == done


def test_a_rotated_video_is_read_as_it_is_shown(tmp_path, frames):
    """A display rotation (a phone held upright) is applied, as players and OpenCV's capture apply it."""
    av = pytest.importorskip("av")
    image = frames[0].image
    for degrees in (90, -90, 180):
        path = tmp_path / f"r{degrees}.mp4"
        with av.open(str(path), "w") as container:
            stream = container.add_stream("mpeg4", rate=10)
            stream.width, stream.height, stream.pix_fmt = 160, 120, "yuv420p"
            if not hasattr(stream, "set_display_rotation"):
                pytest.skip("this PyAV cannot write a display rotation")
            stream.set_display_rotation(degrees)
            mux_all(container, stream, [image, image])
        got = next(VideoFrames(path).frames()).image
        shown = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG).read()[1][:, :, ::-1]
        assert got.shape == shown.shape == np.rot90(image, degrees // 90).shape
        assert np.abs(got.astype(int) - shown).mean() < 2
        assert np.abs(got.astype(int) - np.rot90(image, degrees // 90)).mean() < 8


def _turned_mp4(path, images):
    """An MPEG-4 file of ``images`` (160x120) whose display matrix turns them by a quarter, as a phone's portrait
    video; skipped where this PyAV cannot write one."""
    av = pytest.importorskip("av")
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 160, 120, "yuv420p"
        if not hasattr(stream, "set_display_rotation"):
            pytest.skip("this PyAV cannot write a display rotation")
        stream.set_display_rotation(90)
        mux_all(container, stream, images)
    return path


def test_key_labels_drawn_on_a_rotated_videos_frames_as_stored_are_refused_naming_the_turn(tmp_path, frames, capsys):
    """Key labels of a portrait phone video drawn on its frames as stored (extracted by a tool that does not turn
    them): the refusal named the two sizes alone; it says the display matrix turns the frames, as players do."""
    path = _turned_mp4(tmp_path / "phone.mp4", [f.image for f in frames[:3]])
    key = tmp_path / "key.png"
    cv2.imwrite(str(key), frames[0].labels)  # 160x120: the frame as stored
    assert main(["run", str(path), "--labels", str(key), "--out", str(tmp_path / "out")]) == 2
    assert one_line_errors(capsys) == [
        f"pcreg: error: {key}: labels are 160x120, the key frame 000000 is 120x160 (phone.mp4's display matrix has "
        "players show its frames turned by a quarter, 120x160, and pcreg reads them so: the labels were drawn on the "
        "frames as stored; draw them on the frames as shown, or turn them the same way)"]
    cv2.imwrite(str(key), np.rot90(frames[0].labels).copy())  # drawn on the frame as shown: labelled
    assert main(["run", str(path), "--labels", str(key), "--out", str(tmp_path / "out")]) == 0


@pytest.mark.parametrize("suffix, fourcc", [(".avi", "MJPG"), (".mp4", "mp4v"), (".mkv", "MJPG")])
def test_damaged_videos_decode_or_are_refused_never_crash(tmp_path, frames, suffix, fourcc):
    """Seeded damage (bytes changed, the file cut anywhere): every frame decodes, or InputError says why."""
    data = np.frombuffer(_write_video(tmp_path / f"v{suffix}", [f.image for f in frames[:4]], fourcc).read_bytes(), np.uint8)
    rng = np.random.default_rng(0)
    for k in range(20):
        damaged = data[:rng.integers(1, len(data))].copy() if k % 3 == 0 else data.copy()
        where = rng.integers(0, len(damaged), size=rng.integers(1, 12))
        damaged[where] = rng.integers(0, 256, size=len(where))
        path = tmp_path / f"d{suffix}"
        path.write_bytes(damaged.tobytes())
        try:
            for f in VideoFrames(path).frames():
                assert f.image.shape == (120, 160, 3) and f.image.dtype == np.uint8
        except InputError as exc:
            assert str(exc).startswith(f"{path}: ") or str(exc).startswith("--start"), exc


def test_a_matroska_file_of_a_variable_frame_rate_is_whole_and_one_cut_short_is_not(tmp_path, frames, capsys):
    """Eight frames over 5 s at a nominal 30 a second: the count its duration gives (151) called the file
    truncated after every frame was labelled, on every run. The last frame's time against the duration tells
    a whole file from one cut short."""
    av = pytest.importorskip("av")
    from fractions import Fraction

    def matroska(path, times_ms):
        with av.open(str(path), "w") as c:
            s = c.add_stream("ffv1", rate=30)
            s.width, s.height, s.pix_fmt = 160, 120, "yuv444p"
            s.time_base = s.codec_context.time_base = Fraction(1, 1000)
            timed = [av.VideoFrame.from_ndarray(frames[i % len(frames)].image, format="rgb24") for i in range(len(times_ms))]
            for f, t in zip(timed, times_ms):
                f.pts, f.time_base = t, Fraction(1, 1000)
            mux_all(c, s, timed)
        return path

    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    sparse = matroska(tmp_path / "sparse.mkv", [0, 500, 1000, 1500, 2000, 3000, 4000, 5000])
    assert main(["run", str(sparse), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "s")]) == 0
    assert json.loads((tmp_path / "s" / "run.json").read_text())["done"] == 8
    whole = matroska(tmp_path / "whole.mkv", [100 * i for i in range(40)]).read_bytes()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(whole[:len(whole) // 2])
    assert main(["run", str(cut), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "c")]) == 2
    assert "the video is truncated or damaged" in _err(capsys)[0]


def test_an_mp4_trimmed_by_an_edit_list_is_whole(tmp_path, frames, capsys):
    """A trim without re-encoding (``ffmpeg -ss T -c copy``, a phone's trim) keeps the frames before the cut as
    references and an edit list that hides them: the container counts 8 frames, 6 are shown. It was called
    truncated after every frame was labelled, on every run."""
    av = pytest.importorskip("av")
    whole = tmp_path / "whole.mp4"
    with av.open(str(whole), "w") as c:
        s = c.add_stream("mpeg4", rate=10)
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        mux_all(c, s, [f.image for f in frames])
    trimmed = tmp_path / "trimmed.mp4"
    with av.open(str(whole)) as inp, av.open(str(trimmed), "w") as out:
        src = inp.streams.video[0]
        dst = out.add_stream_from_template(src)
        step = int(round(1 / (src.average_rate * src.time_base)))
        for p in inp.demux(src):
            if p.dts is not None:  # the first two frames before the edit list's start
                p.pts, p.dts, p.stream = p.pts - 2 * step, p.dts - 2 * step, dst
                out.mux(p)
    video = VideoFrames(trimmed)
    assert video.declared == 8
    got = list(video.frames())
    shown = cv2.VideoCapture(str(trimmed), cv2.CAP_FFMPEG)
    assert [f.name for f in got] == [f"{i:06d}" for i in range(6)]
    for f, truth in zip(got, frames[2:]):  # frame 000000 is the third frame written, as players show it
        ok, bgr = shown.read()
        assert ok and np.abs(f.image.astype(int) - bgr[:, :, ::-1]).mean() < 1
        assert np.abs(f.image.astype(int) - truth.image).mean() < 8
    cv2.imwrite(str(tmp_path / "key.png"), frames[2].labels)
    assert main(["run", str(trimmed), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "o")]) == 0, \
        _err(capsys)
    assert json.loads((tmp_path / "o" / "run.json").read_text())["done"] == 6


def _oriented(path, image, degrees, hflip=False, vflip=False):
    """A one-frame MP4 of ``image`` whose display matrix turns it ``degrees`` counter-clockwise, then mirrors it."""
    av = pytest.importorskip("av")
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = image.shape[1], image.shape[0], "yuv420p"
        if not hasattr(stream, "set_display_rotation"):
            pytest.skip("this PyAV cannot write a display matrix")
        stream.set_display_rotation(degrees, hflip=hflip, vflip=vflip)
        mux_all(container, stream, [image])
    return path



def test_decoded_frames_are_freed_without_the_cycle_collector(tmp_path, frames):
    """Reading a frame's display matrix leaves no reference cycle: every decoded frame is freed once let go. A frame
    in a cycle waits for Python's cycle collector, one that outlived a collection for a full one (rare in a long
    run), its picture (FFmpeg's memory) with it: a long run's memory grew about 2.5 kB a frame so."""
    av = pytest.importorskip("av")
    path = _turned_mp4(tmp_path / "r.mp4", [f.image for f in frames])
    enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    gc.set_debug(gc.DEBUG_SAVEALL)  # what a collection finds unreachable is kept in gc.garbage, to be looked at
    try:
        shapes = [f.image.shape for f in VideoFrames(path).frames()]
        gc.collect()
        in_cycles = sum(isinstance(o, av.VideoFrame) for o in gc.garbage)
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        if enabled:
            gc.enable()
    assert shapes == [(160, 120, 3)] * len(frames)  # turned: the display matrix was read
    assert in_cycles == 0

@pytest.mark.parametrize("degrees", [0, 90, 180, -90])
def test_a_mirrored_display_matrix_is_shown_mirrored(tmp_path, frames, degrees):
    """A display matrix that mirrors (a selfie camera's; FFmpeg's players apply it) was read by its angle alone:
    a frame mirrored left-right came out upside down, and the key frame's labels were drawn on another image."""
    image = frames[0].image
    for hflip, vflip in ((True, False), (False, True), (True, True)):
        path = _oriented(tmp_path / f"m{degrees}{hflip:d}{vflip:d}.mp4", image, degrees, hflip, vflip)
        shown = np.rot90(image, degrees // 90)[::-1 if vflip else 1, ::-1 if hflip else 1].astype(int)
        got = next(VideoFrames(path).frames()).image
        assert got.shape == shown.shape, (hflip, vflip)
        wrong = np.rot90(image, degrees // 90 + 2 * (hflip != vflip)).astype(int)  # the angle alone
        assert np.abs(got - shown).mean() < 8 < np.abs(got - wrong).mean(), (hflip, vflip)


def test_a_display_matrix_that_keeps_the_frames_size_is_noted_with_the_first_frame(tmp_path, frames):
    """A half turn or a mirror (a quarter turn of a square frame too) keeps the frames' size: key labels drawn on the
    frames as stored fit the frames as shown, and a run took them without a word, 38-42% of pixels wrong on a
    street. The first frame carries a note naming the turn; frames shown as stored, or turned to another size
    (labels drawn on them as stored are refused for their size), carry none."""
    image = frames[0].image
    for degrees, hflip, said in ((180, False, "turned by a half turn"), (0, True, "mirrored left to right"),
                                 (180, True, "mirrored top to bottom"), (0, False, None), (90, False, None)):
        path = _oriented(tmp_path / f"n{degrees}{hflip:d}.mp4", image, degrees, hflip)
        notes = dict(next(VideoFrames(path).frames()).notes)
        if said is None:
            assert "orientation" not in notes, notes
        else:
            assert notes["orientation"].startswith(f"{path}: its display matrix has players show its frames {said}, "
                                                   "at the size they are stored"), notes
    square = _oriented(tmp_path / "square.mp4", np.ascontiguousarray(image[:, :120]), 90)
    assert "turned by a quarter turn" in dict(next(VideoFrames(square).frames()).notes)["orientation"]


def test_a_display_matrix_of_zeros_turns_nothing(tmp_path, frames):
    """A display matrix of zeros (damaged; FFmpeg's angle for it is NaN, and its players show the frames as stored)
    was refused as "a display rotation of -2.14748e+09 degrees"."""
    image = frames[0].image
    path = _oriented(tmp_path / "h.mp4", image, 180)
    half_turn = bytes.fromhex("FFFF0000" + "00000000" * 3 + "FFFF0000")  # tkhd's matrix: -1 0 0 / 0 -1 0
    data = path.read_bytes()
    assert data.count(half_turn) == 1
    path.write_bytes(data.replace(half_turn, bytes(len(half_turn))))
    frame = next(VideoFrames(path).frames())
    assert frame.notes == () and np.abs(frame.image.astype(int) - image).mean() < 8


def test_a_display_matrix_of_no_quarter_turn_is_refused(tmp_path, frames):
    path = _oriented(tmp_path / "tilted.mp4", frames[0].image, 45)
    with pytest.raises(InputError, match=f"{path}: a display rotation of 45 degrees; pcreg turns frames by quarter turns only"):
        next(VideoFrames(path).frames())


def test_webm_and_m4v_videos_are_read(tmp_path, frames, capsys):
    """A browser's or a screen recorder's WebM (VP9) and an iPhone's export (.m4v) were refused as 'not a folder or a
    video file' by their suffix, though FFmpeg reads them with the Matroska and MP4 demuxers pcreg takes."""
    av = pytest.importorskip("av")
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    for name, codec, fmt in (("clip.webm", "libvpx-vp9", "webm"), ("clip.M4V", "mpeg4", "mp4")):
        try:
            av.codec.Codec(codec, "w")
        except (av.FFmpegError, ValueError):
            pytest.skip(f"this FFmpeg has no {codec} encoder")
        with av.open(str(tmp_path / name), "w", format=fmt) as c:
            s = c.add_stream(codec, rate=10)
            s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
            mux_all(c, s, [f.image for f in frames[:4]])
        out = tmp_path / name.replace(".", "_")
        assert main(["run", str(tmp_path / name), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 0, \
            _err(capsys)
        assert sorted(p.name for p in out.glob("*.png")) == [f"{i:06d}.png" for i in range(4)]


def test_an_avi_frame_whose_chunk_is_damaged_is_refused_where_it_is_missed(tmp_path, frames, capsys):
    """The AVI demuxer passes over a chunk whose header is damaged without a word: frame 7 was read as frame 6 and
    every later frame one place early, all labelled and kept, and the run refused only at the end (one frame short)."""
    av = pytest.importorskip("av")
    images = [frames[i % 8].image for i in range(12)]
    video = _write_video(tmp_path / "v.avi", images, "MJPG")
    with av.open(str(video)) as c:
        entries = getattr(c.streams.video[0], "index_entries", None)
        if entries is None:
            pytest.skip("this PyAV does not give a stream's index")
        at = int(entries[6].pos)  # frame 6's chunk header
    data = bytearray(video.read_bytes())
    data[at:at + 12] = b"\xff" * 12
    damaged = tmp_path / "damaged.avi"
    damaged.write_bytes(bytes(data))
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    out = tmp_path / "o"
    assert main(["run", str(damaged), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 2
    assert _err(capsys) == [f"pcreg: error: {damaged}: frame 6 does not read (its chunk at byte {at} is damaged; "
                            "1 frame(s) passed over): the video is truncated or damaged"]
    assert json.loads((out / "run.json").read_text())["done"] == 6
    assert sorted(p.name for p in out.glob("*.png")) == [f"{i:06d}.png" for i in range(6)]


def _pyav_video(path, images, fmt, options=None, codec="h264"):
    """``images`` encoded with PyAV into the container ``fmt`` (H.264 with B-frames: decoding order is not display
    order); skipped where this FFmpeg has no such encoder."""
    av = pytest.importorskip("av")
    try:
        av.codec.Codec(codec, "w")
    except (av.FFmpegError, ValueError):
        pytest.skip(f"this FFmpeg has no {codec} encoder")
    h, w = images[0].shape[:2]
    with av.open(str(path), "w", format=fmt, options=options or {}) as c:
        s = c.add_stream(codec, rate=10)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.options = {"crf": "12", "bf": "2", "g": "5"} if codec == "h264" else {}
        mux_all(c, s, images)
    return path


@pytest.mark.parametrize("name, fmt, options", [("clip.ts", "mpegts", None),
                                                ("00001.MTS", "mpegts", {"mpegts_m2ts_mode": "1"}),
                                                ("clip.m2ts", "mpegts", {"mpegts_m2ts_mode": "1"}),
                                                ("phone.3gp", "3gp", None)])
def test_transport_streams_and_3gp_are_read_in_order_and_resume_exactly(tmp_path, frames, capsys, monkeypatch,
                                                                        name, fmt, options):
    """A broadcast or camcorder recording (MPEG-TS, AVCHD's .mts/.m2ts) and a phone's 3GP were refused by their
    suffix. A transport stream has no index: its count is estimated from its duration (the progress bar's size),
    its frames are read from the start in order, and a resumed run gives what an uninterrupted one does."""
    images = [frames[i % 8].image for i in range(10)]
    video = _pyav_video(tmp_path / name, images, fmt, options)
    src = open_frames(video)
    assert isinstance(src, VideoFrames) and src.count() == 10
    got = list(src.frames())
    assert [f.name for f in got] == [f"{i:06d}" for i in range(10)]
    for i, f in enumerate(got):  # in display order, each frame its own and no other (H.264 is lossy: close)
        errors = [np.abs(f.image.astype(int) - other.image).mean() for other in frames]
        assert errors[i % 8] < 6 and int(np.argmin(errors)) == i % 8, (i, errors)
    np.testing.assert_array_equal(list(VideoFrames(video).frames(6))[0].image, got[6].image)

    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--confidence"]
    whole, cut = stopped_and_resumed(monkeypatch, args, tmp_path, 6)
    assert sorted(p.name for p in whole.glob("*.png")) == [f"{i:06d}.png" for i in range(10)]
    names = [f"{i:06d}.png" for i in range(10)] + [f"confidence/{i:06d}.png" for i in range(1, 10)]
    for file in ["run.json", *names]:
        assert (whole / file).read_bytes() == (cut / file).read_bytes(), file
    assert ([_timeless(x) for x in (whole / "steps.jsonl").read_text().splitlines()]
            == [_timeless(x) for x in (cut / "steps.jsonl").read_text().splitlines()])


def _cut_in_its_last_frame(tmp_path):
    """(whole, cut): an H.264 transport stream of 6 frames, and a copy of it that ends in its last frame's packet."""
    av = pytest.importorskip("av")
    rng = np.random.default_rng(0)
    images = [np.roll(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), 3 * i, axis=1) for i in range(6)]
    whole = _pyav_video(tmp_path / "whole.ts", images, "mpegts")
    with av.open(str(whole)) as c:
        last = [(p.pos, p.size) for p in c.demux(video=0) if p.size][-1]
    cut = tmp_path / "cut.ts"
    cut.write_bytes(whole.read_bytes()[:last[0] + last[1] // 2])  # its payload goes on over later TS packets
    return whole, cut


def test_a_frame_cut_short_is_flagged_each_time_it_is_decoded(tmp_path):
    """H.264 was decoded with frame threads, which lost the flag of a concealed frame now and then (this cut frame in
    12 of 200 decodes; a run labelled it saying nothing); on one thread the decoder flags it every time."""
    _, cut = _cut_in_its_last_frame(tmp_path)
    for _ in range(60):
        assert [f.damaged for f in VideoFrames(cut).frames()] == [False] * 5 + [True]


def test_a_frame_cut_in_the_middle_is_labelled_and_marked_not_concealed_silently(tmp_path, frames, capsys):
    """A transport stream copied in part ends in the middle of a frame: FFmpeg decodes what arrived and conceals the
    rest, without an error, and the run labelled that half-grey frame saying nothing. The decoder marks it: labelled,
    said and counted in run.json as a frame that decodes with errors; a stream cut at a frame's end is a shorter
    recording."""
    whole, cut = _cut_in_its_last_frame(tmp_path)
    labels = np.zeros((120, 160), np.uint8)
    labels[:, 80:] = 1
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    args = ["run", str(cut), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "c")]
    assert main(args) == 0
    err = [line for line in _err(capsys) if "decode with errors" in line]
    assert len(err) == 1 and err[0].startswith(f"pcreg: note: {cut}: 1 frame(s) decode with errors (damaged or cut "
                                               "short), frame 5: "), err
    state = json.loads((tmp_path / "c" / "run.json").read_text())
    assert state["done"] == 6 and state["damaged"] == {"frames": 1, "last": "000005", "listed": ["000005"]}
    assert main(["run", str(whole), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "w")]) == 0
    assert not any("decode with errors" in line for line in _err(capsys))
    assert "damaged" not in json.loads((tmp_path / "w" / "run.json").read_text())


def test_transport_streams_joined_with_cat_are_read_whole(tmp_path, frames, capsys):
    """A camcorder's recordings joined with ``cat`` (its split .MTS files, or two clips): the second one's time stamps
    start again, and the run refused the whole as truncated ('ends at 0.50 s after 20 frames, its duration is
    1.60 s'). Its frames are read in order, every one of both."""
    images = [frames[i % 8].image for i in range(16)]
    first = _pyav_video(tmp_path / "a.ts", images, "mpegts").read_bytes()
    second = _pyav_video(tmp_path / "b.ts", images[:4], "mpegts").read_bytes()
    joined = tmp_path / "joined.MTS"
    joined.write_bytes(first + second)
    got = list(VideoFrames(joined).frames())
    assert len(got) == 20
    for i, f in enumerate(got):
        errors = [np.abs(f.image.astype(int) - other.image).mean() for other in frames]
        assert int(np.argmin(errors)) == (i if i < 16 else i - 16) % 8, i
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    assert main(["run", str(joined), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "j")]) == 0, \
        _err(capsys)
    assert json.loads((tmp_path / "j" / "run.json").read_text())["done"] == 20


def test_a_video_in_another_container_is_refused_with_the_command_that_converts_it(tmp_path, frames, capsys):
    """An MPEG program stream (a DVD's .vob, a camera's .mpg) was refused as 'not a folder or a video file', or, named
    .mp4, as 'not a video': neither said that it is a video, nor how to make one pcreg reads."""
    images = [f.image for f in frames[:3]]
    mpg = _pyav_video(tmp_path / "old camera.mpg", images, "mpeg", codec="mpeg2video")
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    args = ["--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "o")]
    assert main(["run", str(mpg), *args]) == 2
    assert _err(capsys) == [f"pcreg: error: {mpg}: pcreg does not read .mpg videos (it reads .mp4, .m4v, .mov, .3gp, "
                            ".avi, .mkv, .webm, .ts, .mts, .m2ts); convert it with: ffmpeg -i "
                            f"'{mpg}' -map 0:v:0 -c:v libx264 -crf 18 '{tmp_path / 'old camera.mp4'}'"]
    named = tmp_path / "named.mp4"
    named.write_bytes(mpg.read_bytes())
    assert main(["run", str(named), *args]) == 2
    assert _err(capsys) == [f"pcreg: error: {named}: a video in a container pcreg does not read (FFmpeg reads it as "
                            "mpeg, not as MP4/QuickTime, AVI, Matroska, MPEG-TS); convert it with: ffmpeg -i "
                            f"{named} -map 0:v:0 -c:v libx264 -crf 18 {tmp_path / 'named-converted.mp4'}"]
    assert not (tmp_path / "o").exists()


def test_a_video_of_frames_too_small_to_register_is_refused_naming_the_file(tmp_path, capsys):
    """A video of 3x5 frames was refused as "key frame: image too small to register (3x5 px)", naming no file."""
    av = pytest.importorskip("av")
    path = tmp_path / "tiny.mkv"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("ffv1", rate=10)
        stream.width, stream.height, stream.pix_fmt = 3, 5, "yuv444p"
        mux_all(container, stream, [np.full((5, 3, 3), 40 * i, np.uint8) for i in range(3)])
    labels = np.zeros((5, 3), np.uint8)
    labels[3:] = 1
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    assert main(["run", str(path), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "out")]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {path} frame 000000: image too small to register (3x5 px)"]


def _songs_with_cover_art(folder, picture) -> list:
    """A recording of sound with a picture attached as its cover, in MP4 (an .m4a named .mp4) and in MP3 (named
    .mp4): FFmpeg lists the picture as a video stream, which was read as a video of one frame ("needs at least two
    frames") or, the MP3, as a video in a container pcreg does not read, to convert."""
    import av
    from av.stream import Disposition

    songs = []
    for fmt, codec in (("mp4", "aac"), ("mp3", "libmp3lame")):
        path = folder / f"song-{fmt}.mp4"
        with av.open(str(path), "w", format=fmt) as container:
            sound = container.add_stream(codec, rate=44100)
            cover = container.add_stream("mjpeg", rate=1)
            cover.width, cover.height, cover.pix_fmt = picture.shape[1], picture.shape[0], "yuvj420p"
            cover.disposition = Disposition.attached_pic
            for packet in cover.encode(av.VideoFrame.from_ndarray(picture, format="rgb24").reformat(format="yuvj420p")):
                container.mux(packet)
            for i in range(30):  # under a second: FFmpeg reads a shorter MP3 as no MP3
                tone = av.AudioFrame.from_ndarray(np.zeros((1, 1152), np.float32), format="fltp", layout="mono")
                tone.sample_rate, tone.pts = 44100, 1152 * i
                for packet in sound.encode(tone):
                    container.mux(packet)
            for packet in sound.encode(None):
                container.mux(packet)
        songs.append(path)
    return songs
