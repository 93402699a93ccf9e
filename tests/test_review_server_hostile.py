"""The review page's server (``pcreg view RUN_OUT --web``) under requests a browser would not make, and the review
of runs at their edges: a client that resets its connection, frames named in bytes that are not UTF-8, a run
that holds no labelled frame yet.

A real ``pcreg run`` of five small synthetic frames, served in-process (:class:`pcreg.recording.review.ReviewServer`).
"""

from __future__ import annotations

import contextlib
import http.client
import io
import json
import os
import socket
import struct
import threading
import urllib.error
import urllib.request

import cv2
import pytest

import pcreg
from pcreg.cli import main
from _events import until

N = 5


def _frames(folder, names) -> None:
    for name, f in zip(names, pcreg.synthetic("syn1a", len(names), 0, width=96, height=72)):
        ok, buf = cv2.imencode(".png", f.image[:, :, ::-1])
        (folder / name).write_bytes(buf.tobytes())


def _run(root, frames, *more) -> object:
    key = pcreg.synthetic("syn1a", 1, 0, width=96, height=72)[0].labels
    cv2.imwrite(str(root / "key.png"), key)
    out = root / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(frames), "--labels", str(root / "key.png"), "--out", str(out), *more]) == 0
    return out


@pytest.fixture(scope="module")
def run_out(tmp_path_factory):
    root = tmp_path_factory.mktemp("review-hostile")
    (root / "frames").mkdir()
    _frames(root / "frames", [f"frame_{i}.png" for i in range(N)])
    return _run(root, root / "frames", "--confidence")


def _stopped_at_commit(monkeypatch, n: int) -> None:
    """Make the next ``pcreg run`` stop (as at Ctrl-C) at its ``n``-th commit of run.json."""
    from pcreg.runs.run import Run

    real, commits = Run.commit, []

    def stop(self):
        commits.append(1)
        if len(commits) == n:
            raise KeyboardInterrupt
        real(self)

    monkeypatch.setattr(Run, "commit", stop)


def _handlers() -> list[threading.Thread]:
    """The server's threads answering a connection (socketserver's ``process_request_thread``)."""
    return [t for t in threading.enumerate() if "process_request_thread" in t.name]


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def _reset(sock: socket.socket) -> None:
    """Close ``sock`` with a reset (RST), as a browser that goes away with data unread."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


def test_a_client_that_resets_its_connection_mid_request_is_passed_over_quietly(run_out, capfd):
    """A browser that sends half a request and resets the connection: the server printed a traceback
    (ConnectionResetError) on the terminal of ``pcreg view``; it passes it over and serves on."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    with ReviewServer(read_review(run_out), web_port=0) as server:
        half = socket.create_connection(("127.0.0.1", server.port))
        half.sendall(b"GET /review.json HTTP/1.1\r\nHo")
        # a whole request answered after it: the half one was accepted first, its thread waits on the rest
        assert _get(server.url + "review.json")[0] == 200
        _reset(half)
        until(lambda: not _handlers(), what="the server's answering threads done", bound=60)
        assert _get(server.url + "overlay/1.jpg")[0] == 200
    err = capfd.readouterr().err
    assert "Traceback" not in err and "ConnectionResetError" not in err, err


def _undecodable_name(folder) -> str | None:
    """A frame's name made of bytes that are not UTF-8 (as Python names it: surrogate escapes), or None where the
    file system refuses such a name."""
    name = os.fsdecode(b"1_fr\xff\xe9.png")
    try:
        (folder / name).write_bytes(b"")
    except (OSError, UnicodeError):
        return None
    (folder / name).unlink()
    return name


def test_a_damaged_label_image_of_a_frame_named_in_bytes_not_utf8_is_named_on_the_page(tmp_path):
    """A frame whose file name is not UTF-8 (a Latin-1 file system), its label image damaged since the run: the
    server's one line naming the file could not be encoded, the connection was dropped with a traceback, and the
    page said only that the frame could not be read; now that line comes, the name's bytes shown as '?'."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    (tmp_path / "frames").mkdir()
    odd = _undecodable_name(tmp_path / "frames")
    if odd is None:
        pytest.skip("this file system takes only UTF-8 file names")
    _frames(tmp_path / "frames", ["0_a.png", odd, "2_c.png"])
    out = _run(tmp_path, tmp_path / "frames")
    review = read_review(out)
    assert review.names[1] == odd
    review.labels_path(1).write_bytes(b"not a picture")
    with ReviewServer(review, web_port=0) as server:
        for what in ("overlay/1.jpg", "classes/1.json"):
            status, body = _get(server.url + what)
            assert status == 500, what
            assert body.decode() == f"{out}/1_fr??.png: not an image pcreg reads (PNG, JPEG, BMP, TIFF, WebP, PNM)\n", what


def test_a_run_that_holds_no_frame_yet_is_refused_not_written_as_an_empty_video(tmp_path, monkeypatch, capsys):
    """A run from two key frames (frames 3 and 8 of 10) stopped before it labelled frame 0: its review holds no
    frame. ``--overlay`` wrote an MP4 of 0 bytes and said it wrote it, and ``--web`` served a page that stuck
    saying "not found"; both are refused in one line, and nothing is written."""
    from pcreg.review import read_review, write_overlay_video
    from _view import one_line_error, pcreg_view

    names = [f"f{i:02d}.png" for i in range(10)]
    (tmp_path / "frames").mkdir()
    (tmp_path / "keys").mkdir()
    _frames(tmp_path / "frames", names)
    for k, f in zip(range(10), pcreg.synthetic("syn1a", 10, 0, width=96, height=72)):
        if k in (3, 8):
            cv2.imwrite(str(tmp_path / "keys" / names[k]), f.labels)
    _stopped_at_commit(monkeypatch, 3)
    out = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "keys"), "--out", str(out)]) == 130
    monkeypatch.undo()
    capsys.readouterr()  # the run's own line: interrupted
    assert read_review(out).names == ()
    video = tmp_path / "o.mp4"
    for args in (["--overlay", str(video)], ["--web", "--web-port", "0"]):
        assert pcreg_view([str(out), *args]) == 2
        assert f"{out}: holds no frame labelled from the run's first frame on: nothing to review yet" in \
            one_line_error(capsys)
    assert not video.exists() and not list(tmp_path.glob(".o.mp4*"))
    with pytest.raises(pcreg.errors.InputError, match="holds no labelled frame"):
        write_overlay_video(read_review(out), video)
    assert not video.exists() and not list(tmp_path.glob(".o.mp4*"))


def test_a_run_being_written_is_reviewed_as_far_as_its_run_json_counted(tmp_path, monkeypatch):
    """``pcreg view RUN --web`` while ``pcreg run`` writes RUN: the run commits frames between the review's reading
    run.json and its reading steps.jsonl (a folder of 20,000 frames takes the review long enough to list for the
    run to label several), and the review refused the run as one whose steps.jsonl pcreg run did not write. The
    frames run.json counted when read are reviewed. Here the run goes on while the review lists the frames."""
    from pcreg.datasets import sources
    from pcreg.review import read_review

    (tmp_path / "frames").mkdir()
    _frames(tmp_path / "frames", [f"frame_{i}.png" for i in range(7)])
    _stopped_at_commit(monkeypatch, 3)
    with pytest.raises(AssertionError, match="130"):  # interrupted
        _run(tmp_path, tmp_path / "frames")
    monkeypatch.undo()
    state = tmp_path / "out" / "run.json"
    then = state.read_bytes()  # run.json as the review reads it, the run going on
    out = _run(tmp_path, tmp_path / "frames")  # the run goes on to its end
    now = state.read_bytes()
    state.write_bytes(then)
    real = sources.open_frames

    def frames_listed_while_the_run_commits(*args, **kwargs):
        state.write_bytes(now)
        return real(*args, **kwargs)

    monkeypatch.setattr(sources, "open_frames", frames_listed_while_the_run_commits)
    review = read_review(out)
    assert review.names == tuple(f"frame_{i}.png" for i in range(json.loads(then)["done"]))
    assert len(review.names) < 7 and review.errors[1] is not None


def test_the_page_of_a_run_of_more_frames_than_a_call_takes_arguments(run_out):
    """A run of 130,000 frames (72 minutes of video at 30 frames a second): the page took the highest predicted
    error of its plot as ``Math.max(...errors)``, which throws past about 120,000 arguments, and stopped before it
    showed a frame. It shows frame 0 and its plot reaches the highest error. (The run's own five frames, its
    review's list of frames and their errors made long: 130,000 frames take two hours to run.)"""
    import dataclasses

    from _browser import Browser, find_chromium
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    review, n = read_review(run_out), 130_000
    names = review.names + tuple(f"more_{t}.png" for t in range(N, n))
    long = dataclasses.replace(review, names=names, stems=review.stems + names[N:], ious=(None,) * n,
                               errors=(None, *((t % 1000) / 40 for t in range(1, n))))
    with ReviewServer(long, web_port=0) as server, Browser(width=1200, height=700) as browser:
        browser.open(server.url)
        until(lambda: browser.value("document.body.dataset.shown || ''") == "/overlay/0.jpg", what="frame 0 shown",
              bound=120)
        ticks = browser.value("Array.from(document.querySelectorAll('#plot text.tick')).map(t => t.textContent)")
        assert "25%" in ticks and "30%" not in ticks  # the highest error, 24.975 %, under the top line


def _get_as(port: int, path: str, host: str) -> tuple[int, bytes]:
    """GET ``path`` from 127.0.0.1:``port`` as a browser does for a page at ``host`` (its ``Host`` header)."""
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        conn.putrequest("GET", path, skip_host=True)
        conn.putheader("Host", host)
        conn.endheaders()
        answer = conn.getresponse()
        return answer.status, answer.read()
    finally:
        conn.close()


def test_a_page_elsewhere_whose_name_points_here_reads_nothing(run_out):
    """DNS rebinding: a page at attacker.example whose name the attacker then points at 127.0.0.1 asks the review's
    server for what it serves, as its own origin (the browser sends ``Host: attacker.example:PORT``). The server
    answered with the run's frames, paths and labels; it answers only requests for localhost or a loopback
    address, the names the printed URL uses."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    with ReviewServer(read_review(run_out), web_port=0) as server:
        port = server.port
        for path in ("/review.json", "/overlay/1.jpg", "/frame/0.jpg", "/"):
            status, body = _get_as(port, path, f"attacker.example:{port}")
            assert status == 403 and str(run_out).encode() not in body and b"JFIF" not in body, path
            for host in (f"127.0.0.1:{port}", f"localhost:{port}", "[::1]"):
                assert _get_as(port, path, host)[0] == 200, (path, host)
        assert _get_as(port, "/review.json", "127.0.0.1.attacker.example")[0] == 403


def test_the_legend_shows_no_figures_of_another_frame_when_a_frames_labels_cannot_be_read(run_out, tmp_path):
    """Frame 2's label image cut short since the run: stepping from frame 1 to it, the legend kept frame 1's share of
    each class (and, with many classes, its predicted IoU) beside frame 2's name; it shows none."""
    import shutil

    from _browser import Browser, find_chromium
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    out = tmp_path / "out"
    shutil.copytree(run_out, out)
    review = read_review(out)
    cut = review.labels_path(2)
    cut.write_bytes(cut.read_bytes()[:100])
    figures = "Array.from(document.querySelectorAll('#legend span[data-class]')).map(s => s.textContent)"
    with ReviewServer(review, web_port=0) as server, Browser(width=1200, height=700) as browser:
        browser.open(server.url + "#1")
        ev = browser.value
        until(lambda: ev("document.body.dataset.shown || ''") == "/overlay/1.jpg", what="frame 1 shown", bound=120)
        until(lambda: all("%" in f for f in ev(figures) or [""]), what="frame 1's figures in the legend", bound=60)
        ev("document.getElementById('next').click()")
        until(lambda: cut.name in (ev("document.getElementById('frame-error').textContent") or ""),
              what="frame 2's label image named", bound=60)
        until(lambda: ev(figures) == ["", ""], what="the legend without figures", bound=60)
        assert ev("document.getElementById('frame-name').textContent").startswith(review.names[2])


def test_a_connection_left_idle_is_closed_by_the_server_and_its_thread_ends(run_out, monkeypatch, capfd):
    """A client that opens connections and sends nothing: each held a thread of the server for good; each is closed
    after ``IDLE_TIMEOUT`` (lowered here: the test waits for the close, not for the time), and the server serves on."""
    from pcreg.recording import report
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    monkeypatch.setattr(report, "IDLE_TIMEOUT", 0.2)
    with ReviewServer(read_review(run_out), web_port=0) as server:
        idle = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(3)]
        for sock in idle:
            sock.settimeout(60)  # a bound for a hung test only: the server's close ends the wait
            with sock:
                assert sock.recv(1) == b""  # closed by the server, nothing sent
        until(lambda: not _handlers(), what="the idle connections' threads done", bound=60)
        assert _get(server.url + "overlay/1.jpg")[0] == 200
    err = capfd.readouterr().err
    assert "Traceback" not in err, err


def test_connections_beyond_those_served_at_once_are_answered_busy_and_the_server_serves_on(run_out, monkeypatch, capfd):
    """5,000 connections opened and left idle made 5,000 threads, each held until its idle time. Past
    ``MAX_CONNECTIONS`` (lowered here) a connection is answered 503 and closed at once; once one of the idle ones is
    closed, the server answers again."""
    from pcreg.recording import report
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    monkeypatch.setattr(report, "MAX_CONNECTIONS", 4)
    with ReviewServer(read_review(run_out), web_port=0) as server:
        idle = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(4)]
        until(lambda: len(_handlers()) == 4, what="a thread for each idle connection", bound=60)
        for _ in range(20):  # 503, or the connection reset where the server closed it before the request came in
            try:
                status, body = _get(server.url + "overlay/1.jpg")
            except (urllib.error.URLError, ConnectionError, http.client.RemoteDisconnected):
                continue
            assert (status, body) == (503, b"the server has too many open connections\n")
        assert len(_handlers()) == 4
        idle.pop().close()
        until(lambda: _get(server.url + "overlay/1.jpg")[0] == 200, what="an answer once a connection closed", bound=60)
        for sock in idle:
            sock.close()
        until(lambda: not _handlers(), what="the idle connections' threads done", bound=60)
    err = capfd.readouterr().err
    assert "Traceback" not in err, err


def _get_headers(url: str, headers: dict) -> tuple[int, bytes, object]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=60) as r:
            return r.status, r.read(), r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers


def test_every_answer_says_its_type_is_not_to_be_guessed_and_a_held_picture_is_matched_as_http_has_it(run_out):
    """``nosniff`` on every answer, an error's too (a browser guessed a file's type from its bytes); ``If-None-Match``
    compared weakly (a ``W/`` tag, as a proxy may give the browser, or ``*``, was drawn and sent again)."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    with ReviewServer(read_review(run_out), web_port=0) as server:
        for path in ("", "review.json", "overlay/1.jpg", "viz/review.js", "nothing", "overlay/99999.jpg"):
            assert _get_headers(server.url + path, {})[2]["X-Content-Type-Options"] == "nosniff", path
        url = server.url + "overlay/1.jpg"
        etag = _get_headers(url, {})[2]["ETag"]
        for held in (f"W/{etag}", f'"other", {etag}', "*"):
            status, body, headers = _get_headers(url, {"If-None-Match": held})
            assert (status, body, headers["ETag"]) == (304, b"", etag), held
        assert _get_headers(url, {"If-None-Match": '"other", W/"other"'})[0] == 200
        assert [_get_headers(server.url + p, {})[0] for p in ("overlay/01.jpg", "frame/00.jpg", "classes/01.json")] == [404] * 3


def test_a_label_image_replaced_while_the_page_is_served_is_drawn_again(run_out, tmp_path):
    """A frame's label PNG replaced while ``pcreg view RUN_OUT --web`` serves: its overlay was kept as first drawn (and
    the browser kept it 60 s); now the server draws it again, and the browser, which asks again each time with the
    ETag it holds, gets the new picture (a 304 while nothing changed)."""
    import shutil

    import numpy as np

    from pcreg.export import read_labels
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review
    from pcreg.runs.files import write_labels

    out = tmp_path / "out"
    shutil.copytree(run_out, out)
    review = read_review(out)
    with ReviewServer(review, web_port=0) as server:
        status, before, first = _get_headers(server.url + "overlay/2.jpg", {})
        path = review.labels_path(2)
        labels = read_labels(path, review.table)
        write_labels(path, np.where(labels == 2, 2, 1 - np.minimum(labels, 1)).astype(np.uint8), review.table)  # 0 <-> 1
        st = path.stat()
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # written a second later, as a file replaced is
        assert _get(server.url + "overlay/2.jpg") != (200, before)
        # the browser asks again with what it holds: the new picture for the old ETag, a 304 for the new one
        status, after, now = _get_headers(server.url + "overlay/2.jpg", {"If-None-Match": first["ETag"]})
        assert status == 200 and now["ETag"] != first["ETag"] and "no-cache" in now["Cache-Control"]
        assert _get_headers(server.url + "overlay/2.jpg", {"If-None-Match": now["ETag"]})[0] == 304
    with ReviewServer(read_review(out), web_port=0) as fresh:  # what a server started now draws
        assert _get(fresh.url + "overlay/2.jpg") == (200, after)


def test_a_request_head_sent_a_byte_at_a_time_is_closed_within_the_idle_time(run_out, monkeypatch, capfd):
    """A client that sends its request a byte at a time, each within the idle time (slowloris): the bound was read by
    read, so it held a thread for good; the head is now read within ``IDLE_TIMEOUT`` as a whole (lowered here), and a
    request sent at once is answered as before."""
    from pcreg.recording import report
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    monkeypatch.setattr(report, "IDLE_TIMEOUT", 1.0)
    with ReviewServer(read_review(run_out), web_port=0) as server:
        head = b"GET /review.json?" + b"a" * 600  # one line that never ends: the bound was checked between lines
        closed = None
        with socket.create_connection(("127.0.0.1", server.port)) as sock:
            sock.settimeout(0.05)  # the pace: a byte each time nothing came back within it
            for sent, byte in enumerate(head):
                sock.sendall(bytes([byte]))
                try:
                    closed = sock.recv(1) == b""
                except TimeoutError:
                    continue
                break
        assert closed, f"the connection was still open after {sent + 1} bytes at a slow pace"
        assert _get(server.url + "review.json")[0] == 200
    err = capfd.readouterr().err
    assert "Traceback" not in err, err
