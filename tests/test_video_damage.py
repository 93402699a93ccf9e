"""A video whose frames' times skip frames (a Matroska block the demuxer passed over, frames a live capture dropped)
is read on, its frames numbered by count as annotation tools number them, and the run says where and counts it in
run.json, once a place; a whole video, of a variable frame rate or with B-frames, is read whole and in order. A frame the
decoder flags as decoded with errors is labelled, said once, counted in run.json and its step marked."""

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
    assert (at, gap) == (4, Gap(4, 0.5, 0.1, 4, 0.8))
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
    record = {"places": 1, "missing": 4, "last": "000004", "listed": {"000004": 4}, "times": {"000004": 0.8}}
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
    assert _state(cut)["gaps"] == {"places": 2, "missing": 2, "last": "000005", "listed": {"000003": 1, "000005": 1},
                                   "times": {"000003": 0.4, "000005": 0.7}}
    assert main([*args, "--out", str(cut)]) == 0
    assert [line.split(" (dropped")[0] for line in said()] == [  # frames 3 and 5 were said and counted before
        f"frame 7 {step}", f"frame 9 {step}", f"frame 11 {step}", count.format(cut / "run.json")]
    record = {"places": 5, "missing": 5, "last": "000011", "listed": {"000003": 1, "000005": 1},
              "times": {"000003": 0.4, "000005": 0.7}}
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


def _gaps_note(video) -> str:
    return (f"pcreg: note: {video} skips frames by its times: about 4 frame(s) missing at 1 place(s), before frame 4 "
            "(at 0.8 s, 4 missing); the run numbers its frames by count, as annotation tools do, so from frame 4 on "
            "the run's frame N is not frame N of the file's timeline (run.json's \"gaps\")")


@pytest.fixture(scope="module")
def gap_runs(tmp_path_factory, images):
    """Runs of a whole Matroska file and of the same with a block passed over before frame 4 (4 frames lost)."""
    tmp = tmp_path_factory.mktemp("gap_runs")
    whole = _matroska(tmp / "whole.mkv", images)
    damaged = _block_header_damaged(whole, tmp / "d4.mkv", 4)
    key = _label(tmp / "key.png")
    runs = {}
    for video in (whole, damaged):
        runs[video.stem] = out = tmp / f"run_{video.stem}"
        assert main(["run", str(video), "--labels", str(key), "--out", str(out), "--model", "flow"]) == 0
    return {"whole": (whole, runs["whole"]), "damaged": (damaged, runs["d4"])}


@pytest.mark.parametrize("which", ["damaged", "whole"])
def test_the_review_and_the_export_say_where_the_runs_video_skips_frames(which, gap_runs, tmp_path, capsys):
    """The overlay video's and the export's notes on stderr (once each), the overlay's comment and the review page's
    data say that frames are numbered by count from the gap on; of a whole video, nothing."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    video, out = gap_runs[which]
    capsys.readouterr()
    said = [_gaps_note(video)] if which == "damaged" else []
    assert main(["view", str(out), "--overlay", str(tmp_path / "overlay.mp4")]) == 0
    assert [line for line in one_line_errors(capsys) if "skips frames" in line] == said
    with av.open(str(tmp_path / "overlay.mp4")) as c:
        assert c.metadata.get("comment") == (said[0].removeprefix("pcreg: note: ") if said else None)
    assert main(["export", str(out), "--to", str(tmp_path / "cvat.zip")]) == 0
    assert [line for line in one_line_errors(capsys) if "skips frames" in line] == said
    with ReviewServer(read_review(out), web_port=0) as server:
        gaps = json.loads(server.review_json())["gaps"]
    assert gaps == ({"note": said[0].removeprefix("pcreg: note: "), "places": 1, "missing": 4} if said else None)


def test_the_review_page_shows_where_the_runs_video_skips_frames(gap_runs):
    from _browser import review_page_values

    for which in ("damaged", "whole"):
        video, out = gap_runs[which]
        shown, facts = review_page_values(str(out), "(() => { const p = document.getElementById('gaps'); return "
                                          "p.hidden ? null : [p.textContent, p.getBoundingClientRect().height > 0]; })()",
                                          "document.getElementById('facts').textContent")
        if which == "damaged":
            assert shown == [_gaps_note(video).removeprefix("pcreg: note: "), True]
            assert "frames missing by the video's timesabout 4 at 1 place(s)" in facts
        else:
            assert shown is None and "missing" not in facts


def test_a_run_json_from_before_the_places_times_is_read_and_said_without_them(tmp_path):
    from pcreg.runs.gaps import gaps_note
    from pcreg.runs.state import state_problem

    old = {"places": 5, "missing": 9, "last": "000011", "listed": {"000003": 1, "000005": 2, "000007": 1,
                                                                   "000009": 5}}
    assert gaps_note(old, "v.mkv") == (
        "v.mkv skips frames by its times: about 9 frame(s) missing at 5 place(s), before frames 3 (1 missing), 5 (2 "
        "missing), 7 (1 missing) and 2 more; the run numbers its frames by count, as annotation tools do, so from "
        "frame 3 on the run's frame N is not frame N of the file's timeline (run.json's \"gaps\")")
    timed = {**old, "times": {"000003": 0.4, "000005": 75.25, "000009": 3725.5}}
    assert "before frames 3 (at 0.4 s, 1 missing), 5 (at 1:15.2, 2 missing), 7 (1 missing) and 2 more" \
        in gaps_note(timed, "v.mkv")
    assert gaps_note(None, "v.mkv") is None
    state = {"run": {}, "key_frame": "000000", "done": 12, "fallbacks": 0}
    for record, problem in ((old, None), (timed, None), ({**old, "times": {"000004": 0.5}}, "gaps"),
                            ({**old, "times": {"000003": "0.4"}}, "gaps"), ({**old, "times": [0.4]}, "gaps")):
        assert state_problem({**state, "gaps": record}) == problem, record


def _mp4(path, images, codec="libx264"):
    """An MP4 file of ``images`` at 10 a second (H.264 with x264's default B-frames, or MPEG-4 Part 2)."""
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=10)
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        mux_all(c, s, images)
    return path


def _payload_flipped(whole, damaged, k, at):
    """``whole`` with 4 bytes at ``at`` within the ``k``-th video packet's payload inverted: the slice data damaged,
    the container whole."""
    with av.open(str(whole)) as c:
        pos = [p.pos for p in c.demux(video=0) if p.size][k]
    data = bytearray(whole.read_bytes())
    data[pos + at:pos + at + 4] = bytes(255 - b for b in data[pos + at:pos + at + 4])
    damaged.write_bytes(bytes(data))
    return damaged


@pytest.mark.parametrize("codec, k, at, frame", [
    ("libx264", 3, 30, 1), ("libx264", 6, 30, 6), ("mpeg4", 3, 30, 3),
    pytest.param("libvpx-vp9", 3, 30, 3, marks=pytest.mark.skipif("libvpx-vp9" not in av.codecs_available,
                                                                  reason="PyAV's FFmpeg has no libvpx-vp9"))])
def test_frames_that_decode_with_errors_are_labelled_said_once_and_counted(tmp_path, images, capsys, codec, k, at,
                                                                           frame):
    """Bytes flipped inside a packet's slice data: FFmpeg conceals the frame (grey or smeared) without an error, and
    with its slice threads did not flag an H.264 frame at all; the run labelled it and said nothing. The frame is
    flagged, labelled, said once at the end, counted in run.json and its step marked; view and export say it."""
    whole = _mp4(tmp_path / "whole.mp4", images, codec)
    damaged = _payload_flipped(whole, tmp_path / "damaged.mp4", k, at)
    clean = list(VideoFrames(whole).frames())
    read = list(VideoFrames(damaged).frames())
    assert not any(f.damaged for f in clean) and [f.index for f in read if f.damaged] == [frame]
    assert not np.array_equal(read[frame].image, clean[frame].image)
    key, out = _label(tmp_path / "key.png"), tmp_path / "run"
    assert main(["run", str(damaged), "--labels", str(key), "--out", str(out), "--model", "flow"]) == 0
    said = (f"{damaged}: 1 frame(s) decode with errors (damaged or cut short), frame {frame}: FFmpeg filled in their "
            "missing parts from nearby pictures, so their labels (and those of the frames decoded from them up to the "
            "next key frame) may come from grey or smeared pictures")
    err = [line for line in one_line_errors(capsys) if "decode with errors" in line]
    assert err == [f"pcreg: note: {said}; counted in {out / 'run.json'} (\"damaged\"), their steps marked \"damaged\""]
    assert _state(out)["damaged"] == {"frames": 1, "last": f"{frame:06d}", "listed": [f"{frame:06d}"]}
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert [s["frame"] for s in steps if s.get("damaged")] == [frame]
    assert main(["view", str(out), "--overlay", str(tmp_path / "overlay.mp4")]) == 0
    assert [line for line in one_line_errors(capsys) if "decode with errors" in line] == [f"pcreg: note: {said}"]
    with av.open(str(tmp_path / "overlay.mp4")) as c:
        assert c.metadata.get("comment") == said
    assert main(["export", str(out), "--to", str(tmp_path / "cvat.zip")]) == 0
    assert [line for line in one_line_errors(capsys) if "decode with errors" in line] == [f"pcreg: note: {said}"]


def test_a_clean_h264_file_says_nothing_and_decodes_as_with_slice_threads(tmp_path, images, capsys):
    """One thread (on which H.264's decoder flags every concealed frame) decodes a whole file to the same pixels as
    the slice threads it was read with; nothing is said or counted."""
    whole = _mp4(tmp_path / "whole.mp4", images)
    with av.open(str(whole)) as c:
        assert c.streams.video[0].codec_context.thread_type.name == "SLICE"  # PyAV's default
        sliced = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    read = list(VideoFrames(whole).frames())
    assert len(read) == len(sliced) and all(np.array_equal(f.image, s) for f, s in zip(read, sliced))
    out = tmp_path / "run"
    assert main(["run", str(whole), "--labels", str(_label(tmp_path / "key.png")), "--out", str(out), "--model",
                 "flow"]) == 0
    assert not any("decode with errors" in line for line in one_line_errors(capsys))
    assert "damaged" not in _state(out)
    assert not any("damaged" in line for line in (out / "steps.jsonl").read_text().splitlines())


def test_a_run_json_with_a_malformed_damaged_record_is_refused(tmp_path):
    from pcreg.runs.gaps import damaged_note
    from pcreg.runs.state import state_problem

    state = {"run": {}, "key_frame": "000000", "done": 12, "fallbacks": 0}
    good = {"frames": 5, "last": "000011", "listed": ["000003", "000005", "000007", "000009"]}
    assert damaged_note(good, "v.mp4").startswith("v.mp4: 5 frame(s) decode with errors (damaged or cut short), "
                                                  "frames 3, 5, 7 and 2 more: ")
    assert damaged_note(None, "v.mp4") is None
    for record, problem in ((None, None), (good, None), ({**good, "frames": 0}, "damaged"),
                            ({**good, "frames": 3}, "damaged"), ({**good, "listed": {"000003": 1}}, "damaged"),
                            ({**good, "listed": [3]}, "damaged"), ({**good, "last": 11}, "damaged"), ([1], "damaged")):
        assert state_problem(state if record is None else {**state, "damaged": record}) == problem, record
