"""``pcreg view OUT_DIR --web``: an evaluation's report page beside its recording, in headless Chromium.

For a small sequence, rotation and stream evaluation, each recorded into its output folder: the page
loads, its tables hold results.json's numbers, its figures load, the embedded recording draws, choosing a
row moves the recording to that row's frame, and page and data server listen on loopback only. A bad
OUT_DIR is one line and exit 2; the page's files ship in the wheel's package list.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import pytest

from _events import until
from _browser import listening, stop_view, view_web
from _view import one_line_error, pcreg_view

REPO = Path(__file__).resolve().parent.parent


# -- bad input ----------------------------------------------------------------------------------------


def test_bad_out_dir_is_one_line(tmp_path, capsys):
    assert pcreg_view([str(tmp_path / "missing"), "--web"]) == 2
    assert "no such file or folder" in one_line_error(capsys)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert pcreg_view([str(empty), "--web"]) == 2
    assert "no results.json" in one_line_error(capsys)
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "results.json").write_text('{"datasets": {"syn1a": ')
    assert pcreg_view([str(corrupt), "--web"]) == 2
    assert "not valid JSON" in one_line_error(capsys)
    (corrupt / "results.json").write_bytes(b"\xff\xfe\x00garbage")
    assert pcreg_view([str(corrupt), "--web"]) == 2
    assert "not valid JSON" in one_line_error(capsys)
    (corrupt / "results.json").write_text('{"something": "else"}')
    assert pcreg_view([str(corrupt), "--web"]) == 2
    assert "not the results of pcreg evaluate" in one_line_error(capsys)
    # a sequence's shape with the wrong insides
    (corrupt / "results.json").write_text('{"backends": {"reference": {"datasets": {"a": {"increments": {"1": 3}}}}}}')
    assert pcreg_view([str(corrupt), "--web"]) == 2
    assert "not the results of pcreg evaluate sequence" in one_line_error(capsys)


# -- three small recorded evaluations -----------------------------------------------------------------

SMALL = ["--data", "synthetic:syn1a", "--size", "160x120", "--force"]
RUNS = {
    "sequence": ["evaluate", "sequence", "--frames", "4", "-k", "1,2", "--backend", "reference", "--levels", "2",
                 "--iterations", "5", *SMALL],
    "rotation": ["evaluate", "rotation", "--frames", "2", "--angles", "0,20,40", "--samples", "1", "--backend",
                 "reference", "--levels", "2", "--iterations", "5", *SMALL],
    "stream": ["evaluate", "stream", "--frames", "4", "--methods", "plain,unregistered,pcreg,flow_key", *SMALL],
}


@pytest.fixture(scope="module")
def evaluations(tmp_path_factory):
    """Each evaluation's output folder, with its recording in it (``--record OUT_DIR/run.rrd``)."""
    from pcreg import cli

    d = tmp_path_factory.mktemp("reports")
    out = {}
    for kind, argv in RUNS.items():
        folder = d / kind
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli.main([*argv, "--out", str(folder), "--record", str(folder / "run.rrd")]) == 0, kind
        out[kind] = folder
    return out


def _expected(kind: str, results: dict) -> dict:
    """From results.json, independently of the page's code: {(row key): {column: value}}."""
    out = {}
    if kind == "sequence":
        for b, bd in results["backends"].items():
            for name, d in bd["datasets"].items():
                for k, means in d["increments"].items():
                    out[(f"sequence_{b}", name, k)] = {m.replace("_", " "): v for m, v in means.items()}
    elif kind == "rotation":
        for b, bd in results["backends"].items():
            for name, d in bd["datasets"].items():
                for a, c in d["angles"].items():
                    out[(f"rotation_{b}", name, a)] = {k: c[k] for k in ("before", "after", "after_masked", "after_cropped")}
    else:
        for u in results["units"]:
            for r in u["frames"]:
                out[("stream_frames", u["dataset"], str(r["index"]))] = {m.replace("_", " "): v for m, v in r["errors"].items()}
        for name, c in results["datasets"].items():
            out[("stream_reference", name, None)] = {m.replace("_", " "): v for m, v in c["means"].items()}
        out[("stream_reduction", None, None)] = {m.replace("_", " "): v for m, v in results["average_reduction"].items()}
    return out


def _row_key(table: str, cells: dict) -> tuple:
    if table.startswith("sequence"):
        return (table, cells["dataset"].split(" (")[0], cells["k"])
    if table.startswith("rotation"):
        return (table, cells["dataset"].split(" (")[0], cells["angle"])
    if table == "stream_frames":
        return (table, cells["clip"], cells["frame"])
    return (table, cells.get("clip"), None)


TABLES_JS = """Array.from(document.querySelectorAll('table')).map(t => ({
  name: t.dataset.name,
  head: Array.from(t.querySelectorAll('thead th')).map(th => th.textContent),
  rows: Array.from(t.querySelectorAll('tbody tr')).map(tr => ({
    frame: tr.dataset.frame === undefined ? null : Number(tr.dataset.frame),
    cells: Array.from(tr.querySelectorAll('td')).map(td => [td.textContent, td.dataset.value === undefined ? null : td.dataset.value])
  }))
}))"""

FIGURES_JS = "Array.from(document.querySelectorAll('#figures img')).map(i => [i.alt, i.complete && i.naturalWidth])"
IFRAME_JS = "(() => { const r = document.getElementById('viewer').getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()"


def _colourful(img) -> float:
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    return float(((hsv[..., 1] > 90) & (hsv[..., 2] > 70)).mean())


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(RUNS))
def test_report_page_in_a_browser(evaluations, kind, tmp_path):
    from _browser import Browser, find_chromium

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    folder = evaluations[kind]
    results = json.loads((folder / "results.json").read_text())
    recorded = {f for u in results["units"] for f in (u.get("recording_frames") or {}).values()}
    assert recorded, "the recorded run notes no recording frame"
    proc, url = view_web(str(folder), "--grpc-port", "0")
    ports = []
    try:
        page_port = int(url.rsplit(":", 1)[1].strip("/"))
        with urllib.request.urlopen(url + "report.json", timeout=30) as r:
            report = json.loads(r.read())
        grpc_port = report["recording"]["grpc_port"]
        ports = [page_port, grpc_port]
        for port in ports:  # loopback only, not every interface
            assert listening(port) == ["0100007F"], (port, listening(port))
        for bad in ("/files/..%2Fresults.json", "/files/../config.json", "/files/units", "/viz/../pcreg"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(url.rstrip("/") + bad, timeout=30)
            assert e.value.code == 404, bad
        for raw in (b"/rerun/\x01x", b"/rerun/\xe9", b"/rerun/a\x00b", b"/rerun/\x7f"):  # no answer, a traceback, before
            with socket.create_connection(("127.0.0.1", page_port), timeout=30) as s:
                s.sendall(b"GET " + raw + b" HTTP/1.0\r\n\r\n")
                assert s.recv(64).startswith(b"HTTP/1.0 404"), raw

        with Browser(width=1600, height=900) as browser:
            browser.open(url)

            ev = browser.value

            assert until(lambda: ev("document.body && document.body.dataset.loaded"), what="the page loading",
                         alive=proc, bound=120) == "1"
            # the tables hold results.json's numbers
            expected = _expected(kind, results)
            seen = set()
            for t in ev(TABLES_JS):
                head = [h if h != "rec." else "_rec" for h in t["head"]]
                for row in t["rows"]:
                    cells = {h: (v if v is not None else text) for h, (text, v) in zip(head, row["cells"])}
                    texts = {h: text for h, (text, _) in zip(head, row["cells"])}
                    key = _row_key(t["name"], cells)
                    if key not in expected:
                        continue
                    seen.add(key)
                    for col, want in expected[key].items():
                        if col not in cells:
                            continue
                        if want is None:
                            assert texts[col] == "n/a", (key, col)
                        else:
                            assert float(cells[col]) == want, (key, col, cells[col], want)
                            assert texts[col] == f"{want:.2f}", (key, col, texts[col])
                    if row["frame"] is not None:
                        assert row["frame"] in recorded, (key, row["frame"])
            missing = set(expected) - seen
            assert not missing, f"rows of results.json not in the page: {sorted(missing)}"
            # each table's notes under it, as its Markdown file has them (its ** and ` drawn, not shown)
            footers = ev("Object.fromEntries(Array.from(document.querySelectorAll('section.table-card')).map((s) => "
                         "[s.id, Array.from(s.querySelectorAll('p.footer')).map((p) => p.textContent)]))")
            for t in report["tables"]:
                assert footers[f"table-{t['name']}"] == [p.replace("**", "").replace("`", "") for p in t["footer"]]
            if kind == "stream":
                assert footers["table-stream_reference"][0].startswith("(error %, unknown truth left out")
            # the figures load
            figures = until(lambda: (lambda f: f if f and all(w for _, w in f) else None)(ev(FIGURES_JS)),
                            what="the figures loading", alive=proc, bound=60)
            assert {a for a, _ in figures} == {p.name for p in folder.glob("*.png")}
            # the recording draws in its frame of the page
            x, y, w, h = (int(v) for v in until(lambda: ev("document.getElementById('viewer') && " + IFRAME_JS),
                                                  what="the viewer's frame", alive=proc, bound=60))

            def drawn(shot):
                return _colourful(shot[y:y + h, x:x + w]) > 0.03

            ok, shot = browser.wait_for(drawn, timeout=180)
            cv2.imwrite(str(tmp_path / f"{kind}.png"), shot)
            print(f"{kind} report screenshot:", tmp_path / f"{kind}.png")
            assert ok, f"the recording does not draw (colourful {_colourful(shot[y:y + h, x:x + w]):.3f})"
            # choosing a row moves the recording to its frame; the viewer answers with its new time
            rows = ev("Array.from(document.querySelectorAll('tr.seekable')).map(r => Number(r.dataset.frame))")
            assert rows, "no row leads to the recording"
            for i in sorted({len(rows) - 1, len(rows) // 2}):
                ev(f"document.querySelectorAll('tr.seekable')[{i}].click()")
                until(lambda i=i: ev("document.body.dataset.recordingFrame") == str(rows[i]),
                      what=f"the recording at frame {rows[i]}", alive=proc, bound=60)
                assert ev("document.getElementById('rec-status').textContent") == f"frame {rows[i]}"
    finally:
        code = stop_view(proc)
    assert code == 130
    assert not [p for p in ports if listening(p)]



def test_a_recording_an_earlier_run_left_is_not_shown_beside_new_numbers(tmp_path):
    """``--record OUT/x.rrd``, then a run of other angles started over without --record: the page showed x.rrd,
    a recording of the first run's angles, beside the second's numbers. The recording shown is the one the run
    that wrote the report made; the file an earlier run left is kept (the user named it), and given after the
    folder it is still shown."""
    from pcreg import cli
    from pcreg.experiments.reports.page import load_report

    out = tmp_path / "rot"
    argv = [*RUNS["rotation"], "--out", str(out)]
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main([*argv, "--record", str(out / "x.rrd")]) == 0
        assert load_report(out).recordings == (out / "x.rrd",)
        assert cli.main([*argv, "--angles", "0,90"]) == 0
        assert load_report(out).recordings == () and (out / "x.rrd").is_file()
        assert cli.main([*argv, "--angles", "0,90", "--record", str(out / "y.rrd")]) == 0
        assert load_report(out).recordings == (out / "y.rrd",)
        assert cli.main([*argv, "--angles", "0,90", "--record", str(tmp_path / "elsewhere.rrd")]) == 0
        assert load_report(out).recordings == ()

def test_a_reports_recording_cut_short_is_said(evaluations, tmp_path):
    """An evaluation's folder whose recording was cut short (copied while the run wrote it, a disk filled):
    served without a word, where the same recording viewed alone is said to be cut short."""
    import shutil
    import signal

    folder = tmp_path / "rot"
    shutil.copytree(evaluations["rotation"], folder)
    (rrd,) = folder.glob("*.rrd")
    data = rrd.read_bytes()
    rrd.write_bytes(data[:len(data) * 2 // 3])
    proc, _ = view_web(str(folder), "--grpc-port", "0")
    try:
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=60) == 130
        said = proc.stderr.read()
    finally:
        stop_view(proc)
    assert f"pcreg: note: {rrd}: the recording does not end (still being written, or cut short)" in said, said


def test_report_without_a_recording_and_its_files(evaluations, tmp_path):
    """A folder without .rrd: the page's data says so; only the report's own files are served."""
    from pcreg.experiments.reports.page import load_report, page_data
    from pcreg.recording.report import ReportServer

    folder = tmp_path / "rot"
    folder.mkdir()
    for f in evaluations["rotation"].iterdir():
        if f.is_file() and f.suffix != ".rrd":
            (folder / f.name).write_bytes(f.read_bytes())
    (folder / "secret.txt").write_text("not part of the report")
    (tmp_path / "elsewhere.md").write_text("a file outside the report's folder")
    (folder / "notes.md").symlink_to(tmp_path / "elsewhere.md")  # a link out was listed and served
    report = load_report(folder)
    assert "notes.md" not in report.files
    assert report.recordings == () and report.experiment == "rotation"
    with ReportServer(folder, page_data(report), web_port=0) as server:
        assert listening(server.port) == ["0100007F"]
        with urllib.request.urlopen(server.url + "report.json", timeout=30) as r:
            data = json.loads(r.read())
        assert data["recording"] is None and data["experiment"] == "rotation"
        with urllib.request.urlopen(server.url + "files/rotation.png", timeout=30) as r:
            assert r.read()[:4] == b"\x89PNG"
        for bad in ("files/secret.txt", "files/notes.md", "rerun/", "files/", "viz/nope.js"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(server.url + bad, timeout=30)
            assert e.value.code == 404, bad
        with urllib.request.urlopen(server.url, timeout=30) as r:
            assert b"report.js" in r.read()


def test_files_with_any_name_are_served_at_the_pages_links(evaluations, tmp_path):
    """The page links a file as /files/ + encodeURIComponent(name): a name with spaces, '#', '?', '%',
    markup or letters beyond ASCII is served there (it was not found)."""
    import urllib.parse

    from pcreg.experiments.reports.page import load_report, page_data
    from pcreg.recording.report import ReportServer

    folder = tmp_path / "rot"
    folder.mkdir()
    for f in evaluations["rotation"].iterdir():
        if f.is_file() and f.suffix != ".rrd":
            (folder / f.name).write_bytes(f.read_bytes())
    odd = ["a b ü#1%20?.png", "<script>alert(1)<script> & \"q\".md", "مرحبا 😀.csv"]
    for name in odd:
        (folder / name).write_bytes((folder / "rotation.png").read_bytes())
    data = page_data(load_report(folder))
    assert set(odd) <= set(data["figures"]) | set(data["files"])
    with ReportServer(folder, data, web_port=0) as server:
        for name in odd:
            with urllib.request.urlopen(server.url + "files/" + urllib.parse.quote(name, safe=""), timeout=30) as r:
                assert r.read()[:4] == b"\x89PNG", name
        for bad in ("files/%ff", "files/..%2Fsecret.txt", "files/rotation.png%00"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(server.url + bad, timeout=30)
            assert e.value.code == 404, bad


def test_out_dir_needs_web(evaluations, capsys):
    assert pcreg_view([str(evaluations["rotation"])]) == 2
    assert "--web" in one_line_error(capsys)
    assert pcreg_view([str(evaluations["rotation"]), "--web", "--screenshot", "x.png"]) == 2
    assert "--screenshot" in one_line_error(capsys)


def test_the_wheel_lists_every_package_and_the_page():
    """pyproject.toml names its packages (viz/ ships as pcreg._viz): every package under pcreg/ is listed."""
    tomllib = pytest.importorskip("tomllib")
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "pcreg").rglob("__init__.py")}
    assert set(cfg["packages"]) == on_disk | {"pcreg._viz"}
    assert cfg["package-dir"]["pcreg._viz"] == "viz"
    from fnmatch import fnmatch

    shipped = [p.name for p in (REPO / "viz").iterdir() if any(fnmatch(p.name, g) for g in cfg["package-data"]["pcreg._viz"])]
    assert {"index.html", "report.css", "report.js", "review.html", "review.css", "review.js"} <= set(shipped)


def test_a_page_stopped_after_answering_serves_again_on_its_port_at_once(tmp_path):
    """The server closes each answered connection first, which leaves it waiting (TIME_WAIT, a minute) on the
    port: `pcreg view OUT --web` stopped and started again said "the port is in use" for that minute."""
    import functools
    import urllib.request
    from http.server import SimpleHTTPRequestHandler

    from pcreg.recording.report import listen
    from pcreg.recording.viewer import port_free

    (tmp_path / "index.html").write_text("<p>page</p>")
    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    handler = functools.partial(Quiet, directory=str(tmp_path))
    httpd, thread, port, url = listen("127.0.0.1", 0, handler, name="page-once")
    with urllib.request.urlopen(url) as answer:
        assert answer.read() == b"<p>page</p>"
    assert not port_free("127.0.0.1", port)  # a server listening there still holds it
    httpd.shutdown()
    httpd.server_close()
    thread.join()
    assert port_free("127.0.0.1", port)
    httpd, thread, again, url = listen("127.0.0.1", port, handler, name="page-again")
    try:
        assert again == port
        with urllib.request.urlopen(url) as answer:
            assert answer.read() == b"<p>page</p>"
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join()


@pytest.mark.parametrize("other", ["another program's", "pcreg register's"])
def test_another_recording_in_a_reports_folder_is_said(evaluations, tmp_path, other):
    """Another program's recording (or another pcreg command's) in an evaluation's folder in place of its own was
    served beside the report as its recording, without a word (the page's notes empty)."""
    import json
    import shutil
    import signal
    import urllib.request

    import numpy as np
    import rerun as rr

    folder = tmp_path / "rot"
    shutil.copytree(evaluations["rotation"], folder)
    (rrd,) = folder.glob("*.rrd")
    rrd.unlink()
    if other == "another program's":
        rec = rr.RecordingStream("someotherapp")
        rec.save(str(rrd))
        for i in range(3):
            rec.set_time("step", sequence=i)
            rec.log("foo/points", rr.Points3D(np.random.default_rng(i).random((10, 3))))
        rec.flush()
        rec.disconnect()
        said = f"pcreg: note: {rrd}: a recording of 'someotherapp', not of pcreg evaluate rotation"
    else:
        from pcreg.recording.recorder import Recorder

        with Recorder(rrd, kind="register") as r:
            r.set_frame(0)
            r.log_images(reference=np.zeros((40, 60, 3), np.uint8), moving=np.zeros((40, 60, 3), np.uint8))
        said = f"pcreg: note: {rrd}: a pcreg recording of kind 'register', not of pcreg evaluate rotation"
    proc, url = view_web(str(folder), "--grpc-port", "0")
    try:
        with urllib.request.urlopen(url + "report.json", timeout=30) as r:
            notes = json.loads(r.read())["notes"]
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=60) == 130
        err = proc.stderr.read()
    finally:
        stop_view(proc)
    assert said in err, err
    assert notes and notes[0].startswith(said[len("pcreg: note: "):]), notes


def test_files_the_report_shows_are_its_own_when_read_and_when_served(evaluations, tmp_path):
    """config.json and checks.md, which the page shows whole, were read through a link to any file (a secret's
    JSON, /etc/passwd) and sent in report.json; a listed file replaced while the page is served by a link to a file
    elsewhere was served, and by a pipe held a thread for good. Each is now as a file that is not there: 404, or
    no checks. Two Host headers are refused, whichever comes first."""
    import socket

    from pcreg.experiments.reports.page import load_report, page_data
    from pcreg.recording.report import ReportServer

    folder = tmp_path / "rot"
    folder.mkdir()
    for f in evaluations["rotation"].iterdir():
        if f.is_file() and f.suffix != ".rrd" and f.name not in ("config.json", "checks.md"):
            (folder / f.name).write_bytes(f.read_bytes())
    (tmp_path / "secret.json").write_text('{"api_token": "s3cr3t"}')
    (tmp_path / "secret.md").write_text("a secret outside the folder")
    (folder / "config.json").symlink_to(tmp_path / "secret.json")
    (folder / "checks.md").symlink_to(tmp_path / "secret.md")
    data = page_data(load_report(folder))
    assert "s3cr3t" not in json.dumps(data) and "a secret" not in json.dumps(data)
    (folder / "notes.md").write_text("the report's own notes")
    (folder / "table.csv").write_text("a,b\n1,2\n")
    data = page_data(load_report(folder))
    with ReportServer(folder, data, web_port=0) as server:
        with urllib.request.urlopen(server.url + "files/notes.md", timeout=30) as r:
            assert r.read() == b"the report's own notes"
        (folder / "notes.md").unlink()
        (folder / "notes.md").symlink_to(tmp_path / "secret.md")
        os.unlink(folder / "table.csv")
        os.mkfifo(folder / "table.csv")
        for name in ("notes.md", "table.csv"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(server.url + "files/" + name, timeout=30)
            assert e.value.code == 404, name
        with socket.create_connection(("127.0.0.1", server.port), timeout=30) as c:
            c.sendall(b"GET /report.json HTTP/1.1\r\nHost: localhost\r\nHost: evil.example\r\n\r\n")
            assert c.recv(100).split(b"\r\n")[0] == b"HTTP/1.0 400 more than one Host header"
