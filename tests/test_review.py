"""``pcreg view RUN_OUT --web`` and ``--overlay FILE.mp4``: a real ``pcreg run`` reviewed.

A run of five synthetic frames with --confidence (from a folder, and from a video): what the review reads
of its folder (frames, key frames, predicted errors, suggest.txt), the overlay drawn (colours, unknown
clear, unsure labels hatched), the page's server (loopback only, its images, nothing else served), the
page itself in headless Chromium (frame 0 with the key frame marked, the slider and the arrow keys move
the frame and its picture, one plot point per frame that is not a key, suggest.txt's frames listed and
leading there), and the overlay video (as many frames as the run, of the frames' size).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import urllib.error
import urllib.request

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from _browser import listening, stop_view, view_web
from _events import until
from _view import one_line_error, pcreg_view

N = 5


SUGGEST = 3


def _run(root, source, key_labels):
    out = root / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(source), "--labels", str(key_labels), "--out", str(out), "--confidence",
                     "--suggest", str(SUGGEST)]) == 0
    return out


def _suggested(out):
    """The frames pcreg run suggests, worked out here from its steps' predicted errors: (position, error)."""
    from pcreg.pipeline.keyframes import suggest

    predicted = {s["frame"]: s["predicted_error"] for s in _steps(out)}
    return [(t, round(predicted[t], 2)) for t in suggest(predicted, [0], SUGGEST, N)]


@pytest.fixture(scope="module")
def synthetic():
    return pcreg.synthetic("syn1a", N, 0, width=160, height=120)


@pytest.fixture(scope="module")
def run_out(tmp_path_factory, synthetic):
    """A real ``pcreg run`` of five synthetic frames (PNGs in a folder) with --confidence and --suggest 3."""
    root = tmp_path_factory.mktemp("review")
    (root / "frames").mkdir()
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(root / "frames" / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(root / "key.png"), synthetic[0].labels)
    return _run(root, root / "frames", root / "key.png")


@pytest.fixture(scope="module")
def video_out(tmp_path_factory, synthetic):
    """The same frames as an MP4 video (12 frames a second), run the same way."""
    root = tmp_path_factory.mktemp("review-video")
    writer = cv2.VideoWriter(str(root / "clip.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 12, (160, 120))
    for f in synthetic:
        writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    writer.release()
    cv2.imwrite(str(root / "key.png"), synthetic[0].labels)
    return _run(root, root / "clip.mp4", root / "key.png")


@pytest.fixture
def run_copy(run_out, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(run_out, out)
    return out


def _steps(out):
    return [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]


# -- what the review reads ----------------------------------------------------------------------------


def test_the_review_reads_the_runs_frames_keys_and_errors(run_copy):
    from pcreg.review import read_review

    r = read_review(run_copy)
    assert r.kind == "folder" and r.confidence
    assert r.names == tuple(f"frame_{i:03d}.png" for i in range(N))
    assert r.keys == frozenset({0})
    steps = _steps(run_copy)
    assert r.errors == (None, *(s["predicted_error"] for s in steps))
    # the frames pcreg run --suggest wrote to label next, with their predicted errors, in its order
    assert r.suggested == tuple(_suggested(run_copy)) and len(r.suggested) == SUGGEST
    assert r.confidence_path(0) is None and r.confidence_path(1) == run_copy / "confidence" / "frame_001.png"
    # a suggest.txt edited by hand: a name or a stem, an optional error after a tab; names not in the run,
    # comments and blank lines passed over; pcreg 0.1's space-separated lines read too
    (run_copy / "suggest.txt").write_text("frame_003.png\t12.5\nframe_001\n# a comment\nnot_a_frame\t3\n\n"
                                          "frame_002 7.25\n")
    assert read_review(run_copy).suggested == ((3, 12.5), (1, None), (2, 7.25))
    # several key frames: named in run.json, or a frame without a line in steps.jsonl
    state = json.loads((run_copy / "run.json").read_text())
    (run_copy / "run.json").write_text(json.dumps({**state, "key_frames": ["frame_002.png"]}))
    (run_copy / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps if s["name"] != "frame_004.png"))
    r = read_review(run_copy)
    assert r.keys == frozenset({0, 2, 4})
    assert [e is None for e in r.errors] == [True, False, True, False, True]


def test_a_video_runs_frames_are_named_by_index(video_out):
    from pcreg.review import read_review

    r = read_review(video_out)
    assert r.kind == "video" and r.names == tuple(f"{i:06d}" for i in range(N)) and r.keys == frozenset({0})


def test_bad_run_folders_are_one_line(run_copy, tmp_path, capsys):
    state, steps = json.loads((run_copy / "run.json").read_text()), (run_copy / "steps.jsonl").read_text()
    (run_copy / "run.json").write_text(json.dumps({**state, "run": {**state["run"], "folder": str(tmp_path / "gone")}}))
    assert pcreg_view([str(run_copy), "--web"]) == 2
    assert "is gone" in one_line_error(capsys)
    (run_copy / "run.json").write_text(json.dumps(state))
    (run_copy / "steps.jsonl").write_text("{not json\n")
    assert pcreg_view([str(run_copy), "--web"]) == 2
    assert "steps.jsonl: line 1 is not a step pcreg run wrote" in one_line_error(capsys)
    lines = steps.splitlines(keepends=True)
    for bad in ("1" * 400, "-50", "1e308", "NaN"):  # a figure in % no run writes: the 400 digits were exit 1 (a bug)
        step = json.loads(lines[1])
        (run_copy / "steps.jsonl").write_text("".join([lines[0], json.dumps(step).replace(
            f'"predicted_error": {json.dumps(step["predicted_error"])}', f'"predicted_error": {bad}'), *lines[2:]]))
        assert pcreg_view([str(run_copy), "--web"]) == 2, bad
        assert "steps.jsonl: line 2 is not a step pcreg run wrote" in one_line_error(capsys), bad
    (run_copy / "steps.jsonl").write_text(steps)
    gaps = {"places": 1, "missing": 2, "listed": {"000003": 2}, "last": "000003", "times": {"000003": int("9" * 400)}}
    (run_copy / "run.json").write_text(json.dumps({**state, "gaps": gaps}))
    assert pcreg_view([str(run_copy), "--web"]) == 2
    assert f"{run_copy / 'run.json'}: unreadable (" in one_line_error(capsys)  # exit 1 before
    for frames in ({"every": 0}, {"start": -3}, "all"):  # said as options never given (--every must be 1 or more)
        (run_copy / "run.json").write_text(json.dumps({**state, "run": {**state["run"], "frames": frames}}))
        assert pcreg_view([str(run_copy), "--web"]) == 2
        assert f"{run_copy / 'run.json'}: unreadable (its frames chosen, " in one_line_error(capsys), frames
    (run_copy / "run.json").write_text(json.dumps(state))
    assert pcreg_view([str(run_copy)]) == 2
    assert "--web" in one_line_error(capsys)
    assert pcreg_view([str(run_copy), "--web", "--overlay", str(tmp_path / "o.mp4")]) == 2
    assert "choose one" in one_line_error(capsys)
    assert pcreg_view([str(run_copy), "--overlay", str(tmp_path / "o.avi")]) == 2
    assert "name it .mp4" in one_line_error(capsys)
    (run_copy / "steps.jsonl").write_text("".join(steps.splitlines(keepends=True)[:1]))  # a labelled frame with no step
    assert pcreg_view([str(run_copy), "--overlay", str(tmp_path / "o.mp4")]) == 2
    assert "steps.jsonl: missing or unreadable (1 steps for" in one_line_error(capsys)
    (run_copy / "steps.jsonl").write_text(steps)
    label = sorted(p for p in run_copy.glob("*.png"))[2]
    cv2.imwrite(str(label), np.zeros((6, 8), np.uint8))  # a label image of another size than the frames
    assert pcreg_view([str(run_copy), "--overlay", str(tmp_path / "o.mp4")]) == 2
    assert f"{label}: labels of 8x6, the frame is" in one_line_error(capsys)
    assert not (tmp_path / "o.mp4").exists()


# -- the overlay ---------------------------------------------------------------------------------------


def test_the_overlay_colours_labels_and_hatches_unsure_ones():
    from pcreg.review import ALPHA, COLOURS, overlay

    image = np.full((16, 24, 3), 100, np.uint8)
    labels = np.zeros((16, 24), np.uint8)
    labels[:, 8:16] = 1
    labels[:, 16:] = 2
    conf = np.full((16, 24), 255, np.uint8)
    conf[8:] = 100  # 0.39: below 0.7
    drawn = overlay(image, labels, conf)
    assert drawn.shape == image.shape and drawn.dtype == np.uint8 and (image == 100).all()
    for k, cols in ((0, slice(0, 8)), (1, slice(8, 16))):
        want = np.floor((1 - ALPHA) * 100 + ALPHA * np.array(COLOURS[k]) + 0.5)
        assert (drawn[:8, cols] == want).all(), k
    assert (drawn[:, 16:] == 100).all()  # unknown: clear, and never hatched
    low = drawn[8:, :16].astype(int)
    assert (low.sum(axis=2) < drawn[:8, :16].sum(axis=2).min()).any()  # dark hatching where unsure
    assert (low == drawn[:8, :16]).all(axis=2).any()  # between the hatch lines, the colour as where sure
    keyed = overlay(image, labels, key=True)
    assert tuple(keyed[0, 0]) == (59, 130, 246) and (keyed[8, 8] == drawn[0, 8]).all()


# -- the page's server ---------------------------------------------------------------------------------


def _get(url):
    with urllib.request.urlopen(url, timeout=30) as r:
        return r.headers.get("Content-Type"), r.read()


@pytest.mark.parametrize("which", ["run_out", "video_out"])
def test_the_server_renders_each_frame_on_request(which, request):
    from pcreg.recording.review import ReviewServer
    from pcreg.review import CACHE, read_review

    out = request.getfixturevalue(which)
    review = read_review(out)
    with ReviewServer(review, web_port=0) as server:
        assert listening(server.port) == ["0100007F"]
        _, body = _get(server.url + "review.json")
        data = json.loads(body)
        assert [f["name"] for f in data["frames"]] == list(review.names)
        assert [f["key"] for f in data["frames"]] == [True] + [False] * (N - 1)
        assert data["confidence"] is True
        assert [(f["frame"], f["name"], f["error"]) for f in data["suggested"]] == [
            (t, review.names[t], e) for t, e in _suggested(out)]
        shots = {}
        for t in (N - 1, 0, 2):  # out of order: a video's frame waits for the decoding to reach it
            for what in ("overlay", "frame"):
                ctype, jpg = _get(server.url + f"{what}/{t}.jpg")
                img = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR)
                assert ctype == "image/jpeg" and img.shape == (120, 160, 3), (what, t)
                shots[what, t] = img.astype(int)
        assert np.abs(shots["overlay", 2] - shots["frame", 2]).mean() > 10  # the labels are drawn
        assert np.abs(shots["overlay", 2] - shots["overlay", 0]).mean() > 1
        _, page = _get(server.url)
        assert b"review.js" in page
        for bad in (f"overlay/{N}.jpg", "overlay/-1.jpg", "overlay/x.jpg", "frame/../run.json", "run.json",
                    "viz/../pcreg", "files/run.json",
                    f"frame/{'9' * 5000}.jpg", f"classes/{'9' * 5000}.json"):  # past int()'s 4,300 digits
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(server.url + bad, timeout=30)
            assert e.value.code == 404, bad
    if which == "video_out":
        cached = list((out / CACHE).iterdir())
        assert len(cached) == 1 and sorted(p.name for p in cached[0].iterdir()) == [f"{i:06d}.jpg" for i in range(N)]



def test_a_decoded_frame_removed_from_the_cache_while_served_says_so(video_out, tmp_path):
    """The review's folder of a video's decoded frames deleted while the page was served: every frame not drawn yet
    answered "clip.mp4: frame 000003 was not decoded", which it was. It names the file removed and what to do."""
    from _events import until
    from pcreg.recording.review import ReviewServer
    from pcreg.review import CACHE, read_review

    out = tmp_path / "out"
    shutil.copytree(video_out, out, ignore=shutil.ignore_patterns(CACHE))
    with ReviewServer(read_review(out), web_port=0) as server:
        until(lambda: len(list((out / CACHE).rglob("*.jpg"))) == N, what="every frame decoded")
        assert _get(server.url + "frame/0.jpg")[0] == "image/jpeg"
        shutil.rmtree(out / CACHE)
        with pytest.raises(urllib.error.HTTPError) as caught:
            urllib.request.urlopen(server.url + "frame/3.jpg", timeout=30)
        said = caught.value.read().decode()
        assert "000003.jpg: frame 000003 decoded, then removed" in said and "start pcreg view again" in said, said

# -- the page in a browser -----------------------------------------------------------------------------

SHOWN_JS = "document.body.dataset.shown || ''"
FIGURES_JS = "document.body.dataset.figures || ''"
IMG_JS = "(() => { const r = document.getElementById('overlay').getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()"


@contextlib.contextmanager
def _review_page(out, *, width: int, height: int):
    """The review page of the run in ``out`` open in a headless browser, its first frame and its legend shown: ``(the view's
    process, a function giving the value of a JavaScript expression on the page)``; the view stopped after."""
    from _browser import Browser

    proc, url = view_web(str(out))
    try:
        with Browser(width=width, height=height) as browser:
            browser.open(url)
            until(lambda: browser.value(SHOWN_JS) == "/overlay/0.jpg", what="frame 0 shown", alive=proc, bound=120)
            until(lambda: browser.value(FIGURES_JS) == "0", what="frame 0's class figures", alive=proc, bound=60)
            yield proc, browser.value
    finally:
        stop_view(proc)


@pytest.mark.slow
def test_the_review_page_in_a_browser(run_copy, tmp_path):
    from _browser import Browser, find_chromium

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    suggested = _suggested(run_copy)  # what pcreg run --suggest 3 wrote, worked out from its steps
    proc, url = view_web(str(run_copy))
    port = None
    try:
        port = int(url.rsplit(":", 1)[1].strip("/"))
        assert listening(port) == ["0100007F"]
        with Browser(width=1400, height=800) as browser:
            browser.open(url)

            ev = browser.value

            def picture():
                x, y, w, h = (int(v) for v in ev(IMG_JS))
                return browser.screenshot()[y:y + h, x:x + w].astype(int)

            def key(name, code):
                for kind in ("keyDown", "keyUp"):
                    browser.call("Input.dispatchKeyEvent", session=True, type=kind, key=name, code=name,
                                 windowsVirtualKeyCode=code)

            # frame 0, the key frame, marked as one
            until(lambda: ev(SHOWN_JS) == "/overlay/0.jpg", what="frame 0 shown", alive=proc, bound=120)
            # the legend's figures come after the picture and may wrap it anew: the picture is taken after them
            until(lambda: ev(FIGURES_JS) == "0", what="frame 0's class figures", alive=proc, bound=60)
            assert ev("document.body.dataset.loaded") == "1"
            assert ev("document.getElementById('frame-tag').hidden") is False
            assert ev("document.getElementById('frame-tag').textContent") == "key frame"
            assert ev("document.getElementById('frame-name').textContent").startswith("frame_000.png")
            assert ev("Array.from(document.querySelectorAll('#keys li')).map(li => li.textContent)") == ["frame_000.png"]
            first = picture()
            # the slider moves to frame 2: its picture and the plot's cursor follow
            ev("(() => { const s = document.getElementById('slider'); s.value = '2'; s.dispatchEvent(new Event('input')); })()")
            until(lambda: ev(SHOWN_JS) == "/overlay/2.jpg", what="frame 2 shown", alive=proc, bound=60)
            until(lambda: ev(FIGURES_JS) == "2", what="frame 2's class figures", alive=proc, bound=60)
            picked = [t for t, _ in suggested]
            assert ev("document.getElementById('frame-tag').hidden") is (2 not in picked)  # tagged only if suggested
            steps = _steps(run_copy)
            assert ev("document.getElementById('frame-error').textContent") == f"predicted error {steps[1]['predicted_error']:.1f} %"
            assert ev("document.querySelector('circle.point.current').dataset.frame") == "2"
            ok = until(lambda: np.abs(picture() - first).mean() > 1, what="the picture changing", alive=proc, bound=60)
            assert ok
            # the arrow keys step through frames
            key("ArrowRight", 39)
            until(lambda: ev(SHOWN_JS) == "/overlay/3.jpg", what="frame 3 shown", alive=proc, bound=60)
            key("ArrowLeft", 37)
            key("ArrowLeft", 37)
            until(lambda: ev(SHOWN_JS) == "/overlay/1.jpg", what="frame 1 shown", alive=proc, bound=60)
            # one plot point per frame that is not a key frame, at its predicted error; a click goes there
            points = ev("Array.from(document.querySelectorAll('#plot circle.point')).map(c => Number(c.dataset.frame))")
            assert points == [1, 2, 3, 4]
            ev("document.querySelector('#plot circle.point[data-frame=\"4\"]').dispatchEvent(new MouseEvent('click', {bubbles: true}))")
            until(lambda: ev(SHOWN_JS) == "/overlay/4.jpg", what="frame 4 shown", alive=proc, bound=60)
            # the run's suggest.txt: its three frames listed in its order; choosing one goes there
            assert ev("document.getElementById('suggest-card').hidden") is False
            assert ev("Array.from(document.querySelectorAll('#suggested li')).map(li => li.textContent)") == [
                f"frame_{t:03d}.png predicted error {e:.1f} %" for t, e in suggested]
            ev("document.querySelectorAll('#suggested a')[0].click()")
            until(lambda: ev(SHOWN_JS) == f"/overlay/{suggested[0][0]}.jpg", what="the first suggested frame shown",
                  alive=proc, bound=60)
            assert ev("document.getElementById('frame-tag').textContent") == "suggested"
            assert "confidence below 70 %" in ev("document.getElementById('legend').textContent")
            shot = browser.screenshot()
            cv2.imwrite(str(tmp_path / "review.png"), shot)
            print("review page screenshot:", tmp_path / "review.png")
    finally:
        code = stop_view(proc)
    assert code == 130
    assert port is None or not listening(port)


# -- the overlay as a video ----------------------------------------------------------------------------


@pytest.mark.parametrize("which, encoder, fps", [("run_out", None, None), ("video_out", None, None),
                                                 ("run_out", "mpeg4", "5")])
def test_the_overlay_video_has_every_frame(which, encoder, fps, request, tmp_path, capsys, monkeypatch):
    import av

    import pcreg.review

    if encoder is not None:  # FFmpeg's own MPEG-4 encoder, where there is no libx264
        monkeypatch.setattr(pcreg.review, "_encoder", lambda: encoder)
    out = request.getfixturevalue(which)
    video = tmp_path / "sub" / "overlay.mp4"
    assert pcreg_view([str(out), "--overlay", str(video), *(["--fps", fps] if fps else [])]) == 0
    assert f"wrote {video}: {N} frame(s)" in capsys.readouterr().out
    umask = os.umask(0)
    os.umask(umask)
    assert video.stat().st_mode & 0o777 == 0o666 & ~umask  # as every other output, not mkstemp's 0600
    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == (encoder or "h264")
        assert float(stream.average_rate) == float(fps or (12 if which == "video_out" else 10))  # the video's own, or 10
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) == N and all(f.shape == (120, 160, 3) for f in frames)
    # what the page shows, with the frame's legend drawn in, up to the video's compression
    from pcreg.review import FrameImages, read_review, video_frame

    review = read_review(out)
    with FrameImages(review, tmp_path / "cache") as images:
        drawn = video_frame(review, 2, images[2])[0].astype(int)
    assert np.abs(frames[2].astype(int) - drawn).mean() < 8
    assert pcreg_view([str(out), "--overlay", str(video)]) == 2
    assert "exists" in one_line_error(capsys)
    assert not list(video.parent.glob(".*.tmp*"))


def _count_video(tmp_path, n: int):
    """``(video, straight, review)``: an ``n``-frame 160x120 MP4 in ``tmp_path`` whose frame t is grey 6 t, each frame's
    mean decoded in order, and the review of a run over it (frame 0 its key frame)."""
    from pcreg.datasets.sources import VideoFrames
    from pcreg.review import RunReview

    video = tmp_path / "count.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10, (160, 120))
    for t in range(n):
        writer.write(np.full((120, 160, 3), 6 * t, np.uint8))
    writer.release()
    straight = [float(f.image.mean()) for f in VideoFrames(video).frames()]
    names = tuple(f"{t:06d}" for t in range(n))
    return video, straight, RunReview(tmp_path, video, "video", names, names, frozenset({0}), (None,) * n, (), False)


def test_a_videos_frames_are_decoded_where_asked_and_all_kept(tmp_path, monkeypatch):
    """A frame asked for far ahead of the decoding is started at (the frames before it decoded, not
    converted), and those passed over are filled in afterwards: every frame cached is its own frame."""
    import threading

    from pcreg.datasets.sources import VideoFrames
    from pcreg.review import FrameImages

    n = 40
    video, straight, review = _count_video(tmp_path, n)
    gate, starts = threading.Event(), []
    original = VideoFrames.frames

    def frames(self, first=0):  # the decoding's starts recorded; its first held until a frame is asked for
        starts.append(first)
        if len(starts) == 1:
            gate.wait()
        yield from original(self, first)

    monkeypatch.setattr(VideoFrames, "frames", frames)
    with FrameImages(review, tmp_path / "cache") as images:
        got = {}
        asker = threading.Thread(target=lambda: got.setdefault(30, images[30]))
        asker.start()
        until(lambda: 30 in images._wanted, what="frame 30 asked for", alive=asker)
        gate.set()
        asker.join()
        until(lambda: all(images._have), what="every frame cached", alive=images._thread)
    assert starts[:3] == [0, 30, 1], starts
    assert abs(float(got[30].mean()) - straight[30]) < 1.5
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == [f"{t:06d}.jpg" for t in range(n)]
    with FrameImages(review, tmp_path / "cache") as again:  # all cached: nothing decoded
        for t in range(n):
            assert np.argmin([abs(float(again[t].mean()) - m) for m in straight]) == t, t
    assert len(starts) == 3


def test_a_videos_cache_takes_at_most_half_the_free_space_then_decodes_what_is_asked_for(tmp_path, monkeypatch, capsys):
    """The review decoded every frame of a video ahead into OUT/.pcreg-review/, whatever the disk held: on a small
    disk it filled it (a pcreg run writing beside it stopped, "No space left on device"), every frame not cached
    then failed for good, even once space was freed, and half-written files stayed. The cache holds at most half of
    what its disk has free plus what it holds; then the frames asked for are decoded, several at once as the page
    asks for a frame and its neighbours; a frame the disk refuses is said, and tried again when asked again; a second
    review counts what the first cached."""
    import shutil
    import threading

    from pcreg.review import FrameImages

    n = 40
    _, straight, review = _count_video(tmp_path, n)
    names = review.names
    one = len(cv2.imencode(".jpg", np.full((120, 160, 3), 128, np.uint8))[1])
    real_usage = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda p: real_usage(p)._replace(free=8 * one))  # room for about 4
    cache = tmp_path / "cache"

    def ask(images, frames):  # as the page does: a frame and its neighbours, each on a thread of its own
        got: dict = {}
        threads = [threading.Thread(target=lambda t=t: got.setdefault(t, images[t])) for t in frames]
        for th in threads:
            th.start()
        for th in threads:
            th.join(timeout=60)
            assert not th.is_alive(), f"a reader of {frames} still waits"
        for t in frames:
            assert np.argmin([abs(float(got[t].mean()) - m) for m in straight]) == t, t

    with FrameImages(review, cache) as images:
        until(lambda: not images._ahead, what="the decoding ahead stopped", alive=images._thread)
        ahead = len(list(cache.glob("*.jpg")))
        assert 2 <= ahead <= 5
        for frames in ((30, 31, 29, 32), (10, 11, 9, 12), (31, 32, 30, 33), (38, 39, 37)):
            ask(images, frames)
        assert len(list(cache.glob("*.jpg"))) <= ahead + 14  # the frames asked for, no other
        real_fsync = os.fsync

        def full(fd):  # the disk refuses the frame's data as it is synced
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(os, "fsync", full)
        asked = next(t for t in range(n) if not images._have[t])
        with pytest.raises(pcreg.InputError, match=rf"{names[asked]}.jpg: No space left on device"):
            images[asked]
        monkeypatch.setattr(os, "fsync", real_fsync)  # space freed: the same frame again
        ask(images, (asked,))
    assert "pcreg: note: the review's frame cache" in capsys.readouterr().err
    assert not list(cache.glob(".*.tmp"))
    before = {p.name for p in cache.glob("*.jpg")}
    with FrameImages(review, cache) as again:  # it holds more than half of what is free: nothing ahead
        until(lambda: not again._ahead, what="the decoding ahead stopped", alive=again._thread)
        ask(again, (20,))
    assert {p.name for p in cache.glob("*.jpg")} - before == {"000020.jpg"}


def test_two_reviews_in_one_process_write_a_frame_each_without_taking_the_others_file(tmp_path, monkeypatch):
    """Two reviews of one run in one process (the web page's server and an export) named their temporary files by
    the process alone: one's rename took the other's file, and the other's frame failed "No such file" as if the
    disk had refused it."""
    import os

    from pcreg.review import FrameImages

    _, straight, review = _count_video(tmp_path, 6)
    real_usage, real_replace = shutil.disk_usage, os.replace
    monkeypatch.setattr(shutil, "disk_usage", lambda p: real_usage(p)._replace(free=0))  # nothing decoded ahead
    image = np.full((120, 160, 3), 30, np.uint8)
    with FrameImages(review, tmp_path / "cache") as a, FrameImages(review, tmp_path / "cache") as b:
        until(lambda: not a._ahead and not b._ahead, what="both reviews' decoding ahead stopped", alive=a._thread)
        a._wanted[3] = b._wanted[3] = 1  # frame 3 asked for of both: written whatever the budget

        def replace(src, dst):  # b writes the frame between a's write and a's rename
            monkeypatch.setattr(os, "replace", real_replace)
            b._keep(3, image)
            real_replace(src, dst)

        monkeypatch.setattr(os, "replace", replace)
        a._keep(3, image)
        assert a._have[3] and b._have[3] and not a._missed and not b._missed
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == ["000003.jpg"]


def test_a_killed_reviews_half_written_frames_are_removed_by_the_next(tmp_path):
    """A review killed while writing a frame left its temporary file in the cache for good; the next removes one no
    review is writing (its writer's lock gone: a live review's, its lock held, stays), and starts all the same in a
    cache it may not remove them from."""
    import fcntl

    from pcreg.review import FrameImages

    _, _, review = _count_video(tmp_path, 4)
    cache = tmp_path / "cache"
    cache.mkdir()
    stale, live = cache / ".000002.jpg.k1ll3d_a.tmp", cache / ".000003.jpg.wr1t1ng_.tmp"
    stale.write_bytes(b"half a jpeg")
    live.write_bytes(b"half a jpeg")
    fd = os.open(live, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)  # as a review writing it holds it
    try:
        with FrameImages(review, cache) as images:
            assert not stale.exists() and live.exists()
            until(lambda: all(images._have), what="every frame cached", alive=images._thread)
    finally:
        os.close(fd)  # its writer killed
    real_unlink = os.unlink

    def refused(path, *a, **k):  # a cache it may read and not write (a read-only mount, another user's run)
        raise PermissionError(13, "Permission denied", str(path))

    try:
        os.unlink = refused
        with FrameImages(review, cache) as images:  # the review starts all the same, from the frames cached
            assert all(images._have) and live.exists()
    finally:
        os.unlink = real_unlink
    with FrameImages(review, cache):
        assert not live.exists()


# -- a run of another class table ----------------------------------------------------------------------


@pytest.mark.slow
def test_the_review_draws_the_runs_class_table(synthetic, tmp_path):
    """A run whose classes come from a labelmap.txt: the overlay paints each class in its table colour, the
    page's legend lists the table's names (in headless Chromium)."""
    from _browser import find_chromium
    from pcreg.review import ALPHA, read_overlay, read_review

    frames = tmp_path / "frames"
    frames.mkdir()
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(frames / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
    (tmp_path / "labelmap.txt").write_text("background:0,0,0::\nfloor:0,0,255::\nwall:255,255,0::\n")
    colours = np.array([(0, 0, 255), (255, 255, 0), (0, 0, 0)], np.uint8)
    cv2.imwrite(str(tmp_path / "key.png"), colours[synthetic[0].labels][:, :, ::-1])
    out = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(frames), "--labels", str(tmp_path / "key.png"), "--out", str(out), "--model", "flow",
                     "--classes", str(tmp_path / "labelmap.txt")]) == 0
    review = read_review(out)
    assert [c.name for c in review.table.known] == ["floor", "wall"]
    image = np.full_like(synthetic[2].image, 128)
    drawn = read_overlay(review, 2, image).astype(float)
    labels = pcreg.export.read_labels(out / "frame_002.png", review.table)
    for k, colour in enumerate(colours[:2]):
        want = (1 - ALPHA) * 128 + ALPHA * colour.astype(float)
        assert np.abs(drawn[labels == k] - want).max() <= 1, k
    assert (drawn[labels == 2] == 128).all()  # unknown left clear
    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    with _review_page(out, width=1200, height=700) as (proc, ev):
        items = ev("Array.from(document.querySelectorAll('#legend > span')).map(s => [s.childNodes[1].textContent, "
                   "s.querySelector('.swatch').style.background])")
        assert items[:3] == [["floor", "rgb(0, 0, 255)"], ["wall", "rgb(255, 255, 0)"], ["background", ""]], items
        # beside each class its share of the frame shown, as the run's labels have it
        share = "document.querySelector('#legend span[data-class=\"0\"]').textContent"
        until(lambda: "%" in (ev(share) or ""), what="the classes' shares shown", alive=proc, bound=60)
        shown = float(ev(share).strip().split()[0])
        labels0 = pcreg.export.read_labels(out / "frame_000.png", review.table)
        assert shown == pytest.approx(100.0 * np.mean(labels0 == 0), abs=0.06)


HOSTILE_CLASS = '"quotes" &amp; | <b>pipe</b> 😀 مرحبا ' + "L" * 300


def test_hostile_names_and_a_damaged_label_image_on_the_page(synthetic, tmp_path):
    """Frames and classes named with markup, entities, '#', '%', '?', spaces, right-to-left letters and
    emoji, one class name 300 letters long: the page shows each as written, injects nothing, and fits
    its width (the long name ran off the page); a label image cut short shows pcreg's one line naming it
    where the frame would be (it said only that the frame could not be read)."""
    import json as _json

    from _browser import find_chromium

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    frames = tmp_path / "fr ämes #1"
    frames.mkdir()
    names = ['a#b%20c?', "spa ce", "ünï😀", "<script>alert(1)<script>", '&amp;"q"|x']
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(frames / f"{i}_{names[i]}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "key.png"), synthetic[0].labels)
    (tmp_path / "classes.json").write_text(_json.dumps({"classes": [
        {"id": 0, "name": "<script>alert(1)</script>", "colour": [0, 200, 0]},
        {"id": 1, "name": HOSTILE_CLASS, "colour": [200, 0, 0]},
        {"id": 2, "name": "<img src=x onerror=alert(2)>", "colour": [0, 0, 0]}], "unknown": 2}))
    out = tmp_path / "out <b>&amp; #?%20"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(frames), "--labels", str(tmp_path / "key.png"), "--out", str(out),
                     "--classes", str(tmp_path / "classes.json")]) == 0
    cut = out / f"2_{names[2]}.png"
    cut.write_bytes(cut.read_bytes()[:200])
    with _review_page(out, width=1200, height=700) as (proc, ev):
        assert ev("document.querySelectorAll('script').length") == 2  # the page's own
        assert ev("document.querySelectorAll('main img').length") == 1
        legend = ev("Array.from(document.querySelectorAll('#legend > span')).map(s => s.childNodes[1].textContent)")
        assert legend[:3] == ["<script>alert(1)</script>", HOSTILE_CLASS, "<img src=x onerror=alert(2)>"]
        assert ev("Array.from(document.querySelectorAll('#keys a')).map(a => a.textContent)") == [f"0_{names[0]}.png"]
        assert ev("document.getElementById('frame-name').textContent").startswith(f"0_{names[0]}.png")
        assert ev("document.title") == f"pcreg review: {out.name}"
        assert ev("document.documentElement.scrollWidth <= document.documentElement.clientWidth"), "runs off the page"
        for t in (1, 3, 4):
            ev(f"(() => {{ const s = document.getElementById('slider'); s.value = '{t}'; s.dispatchEvent(new Event('input')); }})()")
            until(lambda: ev(SHOWN_JS) == f"/overlay/{t}.jpg", what=f"frame {t} shown", alive=proc, bound=60)
            assert ev("document.getElementById('frame-name').textContent").startswith(f"{t}_{names[t]}.png")
        ev("(() => { const s = document.getElementById('slider'); s.value = '2'; s.dispatchEvent(new Event('input')); })()")
        error = "document.getElementById('frame-error').textContent"
        until(lambda: cut.name in (ev(error) or ""), what="the cut label image named", alive=proc, bound=60)
        assert ev(SHOWN_JS) == "/overlay/4.jpg"


def test_a_legend_of_many_classes_leaves_the_frame_its_place(synthetic, tmp_path):
    """A run of 254 classes (and its unknown): the legend lists them all and scrolls, the frame stays in
    view at a good size (the legend pushed it off the page)."""
    from _browser import find_chromium
    from pcreg.export import read_labels
    from pcreg.review import read_review

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    key = (np.arange(160)[None, :] * 254 // 160).repeat(120, 0).astype(np.uint8)  # 254 stripes
    out = _many_class_run(synthetic, tmp_path, 254, key)
    table = read_review(out).table
    shown = sorted({int(v) for f in out.glob("frame_*.png") for v in np.unique(read_labels(f, table))} - {254})
    assert 100 < len(shown) < 254
    with _review_page(out, width=1400, height=800) as (proc, ev):
        # the classes the frames show, the unknown, the others counted, the key frame
        assert ev("document.querySelectorAll('#legend > span').length") == len(shown) + 3
        x, y, w, h = ev(IMG_JS)
        assert h >= 0.4 * 800 and y + h <= 800, (y, h)


def test_the_legend_lists_the_classes_the_runs_frames_show_in_the_tables_order(synthetic, tmp_path):
    """A table of 150 classes of which the key frame labels three: the legend listed all 150, the three the run
    shows among them. It lists those three in the table's order, then the unknown, then how many others the
    table holds (named on hover)."""
    from _browser import find_chromium
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review, shown_classes

    key = np.full((120, 160), 120, np.uint8)  # stripes of classes 120, 7 and 64, in no order of the table
    key[:, 50:100], key[:, 100:] = 7, 64
    out = _many_class_run(synthetic, tmp_path, 150, key)
    review = read_review(out)
    assert shown_classes(review) == [7, 64, 120]
    with ReviewServer(review, web_port=0) as server:
        listed = json.loads(_get(server.url + "review.json")[1])["classes"]
    assert len(listed) == 150 and [c["id"] for c in listed if c["shown"]] == [7, 64, 120]
    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    with _review_page(out, width=1200, height=700) as (proc, ev):
        legend = ev("Array.from(document.querySelectorAll('#legend > span')).map(s => s.textContent)")
        assert [t.split(" ")[0] + " " + t.split(" ")[1] for t in legend[:3]] == ["class 7", "class 64", "class 120"]
        assert legend[3:5] == ["void", "147 other classes of the table in no frame"], legend


def test_the_legend_reads_the_classes_of_a_step_from_its_predicted_iou_not_its_label_file(synthetic, tmp_path):
    """A run of thousands of frames in many classes is not read whole before its review page shows: a step's
    predicted IoU names the classes its labels hold, and only the key frames' label files are read. Here the
    later frames' label files are overwritten after the run with a class the run never wrote: the legend
    still lists what the steps say (it listed the overwritten class when it read every file)."""
    from pcreg.review import read_review, shown_classes

    key = np.full((120, 160), 12, np.uint8)
    key[:, 80:] = 7
    out = _many_class_run(synthetic, tmp_path, 20, key)
    review = read_review(out)
    assert review.ious[1] is not None and set(review.ious[1]) <= {7, 12}
    for t in (1, 2):
        cv2.imwrite(str(review.labels_path(t)), np.full((120, 160), 5, np.uint8))
    assert shown_classes(review) == [7, 12]


def test_a_frame_without_its_confidence_map_says_so_on_the_page(run_copy):
    """A run with --confidence whose confidence/NAME.png for one frame is gone: the frame was drawn without
    the hatching and nothing said why."""
    from _browser import find_chromium

    (run_copy / "confidence" / "frame_002.png").unlink()
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    with ReviewServer(read_review(run_copy), web_port=0) as server:
        frames = json.loads(_get(server.url + "review.json")[1])["frames"]
    assert [f["no_confidence"] for f in frames] == [None, None, "confidence/frame_002.png", None, None]
    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    error = "document.getElementById('frame-error').textContent"
    with _review_page(run_copy, width=1200, height=700) as (proc, ev):
        for t in (1, 2):
            ev(f"(() => {{ const s = document.getElementById('slider'); s.value = '{t}'; s.dispatchEvent(new Event('input')); }})()")
            until(lambda: ev(SHOWN_JS) == f"/overlay/{t}.jpg", what=f"frame {t} shown", alive=proc, bound=60)
            missing = "no confidence map (confidence/frame_002.png is missing): drawn without the hatching"
            assert (missing in ev(error)) is (t == 2), ev(error)


def test_a_run_whose_confidence_folder_is_gone_marks_every_frame(run_copy, tmp_path, capsys):
    """A run with --confidence whose whole confidence/ folder was removed: the page said the run had no
    confidence (as if run without it) and marked no frame; the export with --min-confidence said to run with
    --confidence. Each frame is marked as one map gone is, and the export names the missing map."""
    from pcreg.export import read_run
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    shutil.rmtree(run_copy / "confidence")
    with ReviewServer(read_review(run_copy), web_port=0) as server:
        data = json.loads(_get(server.url + "review.json")[1])
    assert data["confidence"] is True
    assert [f["no_confidence"] for f in data["frames"]] == [None, *(f"confidence/frame_{t:03d}.png" for t in range(1, N))]
    assert read_run(run_copy).confidence[1] == run_copy / "confidence" / "frame_001.png"
    assert main(["export", str(run_copy), "--to", str(tmp_path / "e.zip"), "--min-confidence", "0.5"]) == 2
    assert f"{run_copy / 'confidence' / 'frame_001.png'}: missing" in one_line_error(capsys)


def _many_class_run(synthetic, tmp_path, n_classes: int, key: np.ndarray):
    """A run (DIS's flow, for speed) of three synthetic frames from the label image ``key``, in a table of
    ``n_classes`` classes named ``class i`` and a void, its unknown: the run's folder."""
    import json as _json

    frames = tmp_path / "frames"
    frames.mkdir()
    for i, f in enumerate(synthetic[:3]):
        cv2.imwrite(str(frames / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
    classes = [{"id": i, "name": f"class {i}", "colour": [i, 255 - i, (37 * i) % 256]} for i in range(n_classes)]
    void = {"id": n_classes, "name": "void", "colour": [0, 0, 1]}
    (tmp_path / "classes.json").write_text(_json.dumps({"classes": [*classes, void], "unknown": n_classes}))
    cv2.imwrite(str(tmp_path / "key.png"), key)
    out = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(frames), "--labels", str(tmp_path / "key.png"), "--out", str(out), "--model", "flow",
                     "--classes", str(tmp_path / "classes.json")]) == 0
    return out


def test_an_overlay_of_a_video_that_has_since_lost_frames_is_refused(synthetic, tmp_path, capsys):
    """The overlay of a run whose video has since been cut shorter ended at the video's last frame, one line
    saying it wrote fewer frames than the run has and nothing saying why. (Written over since, it is not the video
    the run labelled: refused as such before a frame is read.)"""
    def video(n):
        writer = cv2.VideoWriter(str(tmp_path / "clip.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 12, (160, 120))
        for f in synthetic[:n]:
            writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
        writer.release()

    video(N)
    cv2.imwrite(str(tmp_path / "key.png"), synthetic[0].labels)
    out = _run(tmp_path, tmp_path / "clip.mp4", tmp_path / "key.png")
    video(N - 2)
    overlay = tmp_path / "overlay.mp4"
    assert pcreg_view([str(out), "--overlay", str(overlay)]) == 2
    assert f"clip.mp4: not the video the run in {out} labelled (its size or bytes changed since" in one_line_error(capsys)
    assert not overlay.exists() and not list(tmp_path.glob(".*.tmp*"))


def test_a_run_scored_against_the_truth_shows_the_error_against_it_beside_the_predicted(synthetic, tmp_path):
    """pcreg run --truth: each frame's error against the truth (its step's ``error``) is served with the frame, said
    beside the predicted error, drawn dashed in the plot with a key under it, and its mean is among the facts; a run
    without the truth (the other tests' run) draws no such line and hides the key."""
    from _browser import find_chromium
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    root = tmp_path / "run"
    (root / "frames").mkdir(parents=True)
    (root / "truth").mkdir()
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(root / "frames" / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
        cv2.imwrite(str(root / "truth" / f"frame_{i:03d}.png"), f.labels)
    out = root / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(root / "frames"), "--labels", str(root / "truth" / "frame_000.png"), "--out", str(out),
                     "--truth", str(root / "truth"), "--model", "flow"]) == 0
    steps = _steps(out)
    with ReviewServer(read_review(out), web_port=0) as server:
        frames = json.loads(_get(server.url + "review.json")[1])["frames"]
    assert [f["truth_error"] for f in frames] == [None, *(s["error"] for s in steps)]
    for t in (1, 2):  # each class's IoU against the truth beside its predicted one, as the step has them
        with ReviewServer(read_review(out), web_port=0) as server:
            figures = json.loads(_get(server.url + f"classes/{t}.json")[1])
        assert {f["id"]: f["truth_iou"] for f in figures} == {c: steps[t - 1]["iou"].get(str(c)) for c in (0, 1)}
    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    with _review_page(out, width=1200, height=700) as (proc, ev):
        ev("(() => { const s = document.getElementById('slider'); s.value = '2'; s.dispatchEvent(new Event('input')); })()")
        until(lambda: ev(SHOWN_JS) == "/overlay/2.jpg", what="frame 2 shown", alive=proc, bound=60)
        assert ev("document.getElementById('frame-error').textContent") == (
            f"predicted error {steps[1]['predicted_error']:.1f} %, against the truth {steps[1]['error']:.1f} %")
        legend = "document.querySelector('#legend span[data-class=\"1\"]').textContent"
        iou, predicted = steps[1]["iou"]["1"], steps[1]["predicted_iou"]["1"]  # obstacle, in frame 2's truth and labels
        said = f", predicted IoU {predicted:.2f}, IoU {iou:.2f} against the truth"
        assert until(lambda: ev(legend).endswith(said), what="frame 2's class figures", alive=proc, bound=60)
        assert ev("document.querySelectorAll('#plot path.series.truth').length") == 1
        assert ev("document.getElementById('plot-key').hidden") is False
        mean = np.mean([s["error"] for s in steps])
        assert f"mean error against the truth{mean:.1f} %" in ev("document.getElementById('facts').textContent")
    (tmp_path / "other").mkdir()
    with _review_page(_many_class_run(synthetic, tmp_path / "other", 3, synthetic[0].labels), width=1200,
                      height=700) as (proc, ev):
        assert ev("document.querySelectorAll('#plot path.series.truth').length") == 0
        assert ev("document.getElementById('plot-key').hidden") is True


def test_a_label_image_written_over_at_another_size_has_no_figures_as_it_has_no_overlay(run_copy):
    """A frame's label image written over at another size (by hand, another tool) was refused by the overlay and
    still counted by the legend's figures (100 % of one class for a 10 x 10 map): both refuse it, naming it."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    name = read_review(run_copy).stems[2] + ".png"
    cv2.imwrite(str(run_copy / name), np.zeros((10, 10), np.uint8))
    with ReviewServer(read_review(run_copy), web_port=0) as server:
        assert [f["id"] for f in json.loads(_get(server.url + "classes/1.json")[1])] == [0, 1]
        for what in ("classes/2.json", "overlay/2.jpg"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(server.url + what, timeout=30)
            body = e.value.read().decode()
            assert e.value.code == 500 and name in body and "labels of 10x10" in body, (what, body)
