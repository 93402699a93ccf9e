"""The review page while a person works on the run's files: a source frame written over while the page is served
is drawn again (its picture was kept as first drawn), and a label image or frame removed is a 404 naming it (it
was a 500, a fault of the server's); a suggest.txt grown past what a line a frame holds is refused, not read whole."""

from __future__ import annotations

import contextlib
import io
import os
import urllib.error
import urllib.request

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main


def _run(root, *options):
    """Four synthetic frames in ``root/frames`` labelled from the first into ``root/out`` with ``options``."""
    frames = pcreg.synthetic("syn1a", 4, 0, width=96, height=72)
    (root / "frames").mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(root / "frames" / f"f{i}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(root / "key.png"), frames[0].labels)
    out = root / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(root / "frames"), "--labels", str(root / "key.png"), "--out", str(out), *options]) == 0
    return root / "frames", out


@pytest.fixture
def run(tmp_path):
    return _run(tmp_path)


def _get(url):
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.headers.get("ETag"), r.read()
    except urllib.error.HTTPError as e:
        return e.code, None, e.read()


def _mean_grey(jpeg: bytes) -> float:
    return float(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE).mean())


def test_a_source_frame_written_over_is_drawn_again(run):
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    frames, out = run
    with ReviewServer(read_review(out), web_port=0) as server:
        before = {what: _get(f"{server.url}{what}/2.jpg") for what in ("frame", "overlay")}
        white = np.full((72, 96, 3), 255, np.uint8)
        cv2.imwrite(str(frames / "f2.png"), white)
        os.utime(frames / "f2.png", ns=(1, 1))  # another time than the first file's, however coarse the clock
        for what, (status, etag, body) in before.items():
            status2, etag2, body2 = _get(f"{server.url}{what}/2.jpg")
            assert status == status2 == 200 and etag != etag2, what
            assert _mean_grey(body2) > _mean_grey(body) + 20, what


@pytest.mark.parametrize("gone", ["labels", "frame"])
def test_a_file_removed_while_served_is_a_404_naming_it(run, gone):
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    frames, out = run
    path = out / "f2.png" if gone == "labels" else frames / "f2.png"
    with ReviewServer(read_review(out), web_port=0) as server:
        path.unlink()
        asked = ("overlay/2.jpg", "classes/2.json") if gone == "labels" else ("overlay/2.jpg", "frame/2.jpg")
        for what in asked:
            status, _, body = _get(server.url + what)
            assert status == 404 and str(path) in body.decode(), (what, status, body)
        assert _get(server.url + "overlay/1.jpg")[0] == 200


def test_a_suggest_txt_larger_than_a_line_a_frame_is_refused_not_read_whole(run, capsys):
    from pcreg.review import read_review

    frames, out = run
    (out / "suggest.txt").write_text("f2.png\t3.5\n")
    assert read_review(out).suggested == ((2, 3.5),)
    with open(out / "suggest.txt", "r+b") as f:  # 2 GB, no byte of it on the disk
        f.truncate(2 << 30)
    assert main(["view", str(out), "--overlay", str(out.parent / "overlay.mp4")]) == 2
    err = capsys.readouterr().err
    assert "suggest.txt: suggestions file of 2048.0 MiB exceeds the limit of 1.0 MiB" in err and len(err.splitlines()) == 1


def test_a_confidence_map_written_over_with_jpeg_bytes_is_refused_naming_it(tmp_path):
    """A confidence map that is no longer the grey PNG pcreg run wrote (JPEG bytes under its name, whose values move
    at every edge) was drawn as the frame's hatching; the page now says what it is, as the export does."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    _, out = _run(tmp_path, "--confidence")
    conf = out / "confidence" / "f2.png"
    conf.write_bytes(cv2.imencode(".jpg", cv2.imread(str(conf), cv2.IMREAD_UNCHANGED))[1].tobytes())
    with ReviewServer(read_review(out), web_port=0) as server:
        assert _get(server.url + "overlay/1.jpg")[0] == 200
        status, _, body = _get(server.url + "overlay/2.jpg")
        assert status == 500 and body.decode().startswith(f"{conf}: not a PNG"), (status, body)
