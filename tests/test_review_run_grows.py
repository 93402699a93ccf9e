"""``pcreg view RUN --web`` while ``pcreg run`` goes on writing the run: the page reloaded shows the frames labelled
since it was served (the review was read once, when the command started, and a reload showed the same frames for as
long as the server ran). A run.json that cannot be read leaves the page showing what it showed; a run started over,
on another source too, shows as it is now."""

from __future__ import annotations

import contextlib
import io
import json
import urllib.error
import urllib.request

import cv2
import pytest
from _runs import write_video

import pcreg
from pcreg.cli import main


def _get(url):
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def _frames(server) -> list[str]:
    status, body = _get(server.url + "review.json")
    assert status == 200
    return [f["name"] for f in json.loads(body)["frames"]]


def _source(root, kind: str):
    """Six synthetic frames as a folder of PNGs or an MP4 in ``root``, and the first frame's labels: (source, labels)."""
    frames = pcreg.synthetic("syn1a", 6, 0, width=96, height=72)
    cv2.imwrite(str(root / "key.png"), frames[0].labels)
    if kind == "video":
        return write_video(root / "clip.mp4", frames), root / "key.png"
    (root / "frames").mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(root / "frames" / f"f{i}.png"), f.image[:, :, ::-1])
    return root / "frames", root / "key.png"


def _run(source, labels, out, *options) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(source), "--labels", str(labels), "--out", str(out), *options]) == 0


@pytest.mark.parametrize("kind", ["folder", "video"])
def test_the_page_reloaded_shows_the_frames_labelled_since_it_was_served(tmp_path, kind):
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    source, labels = _source(tmp_path, kind)
    out = tmp_path / "out"
    _run(source, labels, out, "--stop", "3")
    with ReviewServer(read_review(out), web_port=0) as server:
        assert len(_frames(server)) == 3
        assert _get(server.url + "overlay/2.jpg")[0] == 200
        assert _get(server.url + "overlay/4.jpg")[0] == 404  # no frame 4 yet
        _run(source, labels, out)  # the same run taken to the end, as pcreg run goes on beside the page
        assert len(_frames(server)) == 6
        for t in (0, 4, 5):
            status, body = _get(f"{server.url}overlay/{t}.jpg")
            assert status == 200 and body[:2] == b"\xff\xd8", (t, status, body[:80])
        assert _get(server.url + "classes/5.json")[0] == 200


def test_a_run_json_that_cannot_be_read_leaves_the_page_as_it_was(tmp_path):
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    source, labels = _source(tmp_path, "folder")
    out = tmp_path / "out"
    _run(source, labels, out, "--stop", "3")
    with ReviewServer(read_review(out), web_port=0) as server:
        names = _frames(server)
        (out / "run.json").write_text("{ not json")
        assert _frames(server) == names
        assert _get(server.url + "overlay/2.jpg")[0] == 200


def test_a_run_started_over_on_another_source_shows_as_it_is_now(tmp_path):
    """The run --force'd onto another source while served: the page showed the first source's frames with the new
    run's labels drawn over them (the names alike), and said nothing."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    source, labels = _source(tmp_path, "folder")
    out = tmp_path / "out"
    _run(source, labels, out, "--stop", "3")
    other = tmp_path / "other"
    other.mkdir()
    for f in sorted(source.iterdir())[:5]:
        (other / f.name).write_bytes(f.read_bytes())
    with ReviewServer(read_review(out), web_port=0) as server:
        assert len(_frames(server)) == 3
        _run(other, labels, out, "--force")
        assert len(_frames(server)) == 5 and server.review.source == other
        assert _get(server.url + "frame/4.jpg")[0] == 200


def test_frames_asked_for_while_the_page_reloads_are_drawn(tmp_path):
    """A video run read again (a reload) while frames were being decoded for other requests: those were answered
    500 ("frame N was not decoded"), the decoding they waited for stopped under them."""
    import os
    import shutil
    import threading

    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    frames = pcreg.synthetic("syn1a", 24, 0, width=96, height=72)
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    video = write_video(tmp_path / "clip.mp4", frames)
    out = tmp_path / "out"
    _run(video, tmp_path / "key.png", out)
    failed = []
    for i in range(4):
        shutil.rmtree(out / ".pcreg-review", ignore_errors=True)
        with ReviewServer(read_review(out), web_port=0) as server:
            asked = {}
            threads = [threading.Thread(target=lambda t=t: asked.__setitem__(t, _get(f"{server.url}overlay/{t}.jpg")))
                       for t in (5, 15, 23)]
            for thread in threads:
                thread.start()
            os.utime(out / "run.json", ns=(i + 1, i + 1))  # as pcreg run writes it again after a step
            assert len(_frames(server)) == 24
            for thread in threads:
                thread.join()
            failed += [(t, status, body[:120]) for t, (status, body) in asked.items() if status != 200]
    assert not failed, failed
