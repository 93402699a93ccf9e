"""``pcreg view``: bad input gives one line and exit 2; a headless screenshot shows the recording's images."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.recording import viewer as view
from pcreg.errors import PcregError
from pcreg.recording.recorder import Recorder
from pcreg.recording.readback import unfinished_note

from _events import until
from _browser import listening, stop_view, view_web
from _view import one_line_error, pcreg_view


def test_missing_file(tmp_path, capsys):
    assert pcreg_view([str(tmp_path / "nope.rrd")]) == 2
    assert "no such file" in one_line_error(capsys)


def test_file_that_is_not_a_recording(tmp_path, capsys):
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"this is not a rerun recording\n" * 10)
    assert pcreg_view([str(bad), "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "not a rerun recording" in one_line_error(capsys)
    assert not (tmp_path / "x.png").exists()


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory):
    """Two frames whose reference image is half saturated red, half saturated green."""
    path = tmp_path_factory.mktemp("view") / "small.rrd"
    img = np.zeros((120, 160, 3), np.uint8)
    img[:, :80] = (230, 20, 20)
    img[:, 80:] = (20, 210, 20)
    with Recorder(path, recording_id="view-test") as rec:
        for f in range(2):
            rec.set_frame(f)
            rec.log_images(reference=img, moving=img, warped=np.roll(img, 5 * f, axis=1))
            rec.log_transform(np.array([[1.0, 0.0, 5.0 * f], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
            rec.log_labels(truth=np.zeros((120, 160), np.uint8), predicted=np.ones((120, 160), np.uint8))
            rec.log_errors({"plain": 0.1 + f})
    return path


def test_missing_viewer_binary(small_recording, tmp_path, capsys):
    code = pcreg_view([str(small_recording), "--viewer", str(tmp_path / "no-rerun")])
    assert code == 2
    assert "rerun viewer not found" in one_line_error(capsys)


def test_existing_screenshot_refused(small_recording, tmp_path, capsys):
    out = tmp_path / "shot.png"
    out.write_bytes(b"old")
    assert pcreg_view([str(small_recording), "--screenshot", str(out)]) == 2
    assert "exists" in one_line_error(capsys)
    assert out.read_bytes() == b"old"


def test_bad_time_argument(small_recording, tmp_path, capsys):
    assert pcreg_view([str(small_recording), "--screenshot", str(tmp_path / "s.png"), "--time", "frame"]) == 2
    assert "TIMELINE=N" in one_line_error(capsys)


@pytest.mark.slow
def test_headless_screenshot_shows_the_images(small_recording, tmp_path, capsys):
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    out = tmp_path / "shot.png"
    code = pcreg_view([str(small_recording), "--screenshot", str(out), "--time", "frame=1",
                       "--view", "Registration", "--size", "1280x720"])
    assert code == 0, capsys.readouterr().err
    # a time outside the recording drew "No data available" in every view, exit 0: refused, the picture kept
    before = out.read_bytes()
    for time in ("frame=-5", "frame=1000"):
        assert pcreg_view([str(small_recording), "--screenshot", str(out), "--time", time, "--force"]) == 2
        assert f"--time {time}: outside the recording, whose frame timeline runs from 0 to " in one_line_error(capsys)
    assert out.read_bytes() == before
    shot = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert shot is not None and shot.shape[0] > 100 and shot.shape[1] > 100
    b, g, r = (shot[..., i].astype(int) for i in range(3))
    red = (r > 150) & (g < 90) & (b < 90)
    green = (g > 140) & (r < 90) & (b < 90)
    # the reference image fills a good part of the view: both halves visible, not a blank canvas
    assert red.mean() > 0.05 and green.mean() > 0.05, (red.mean(), green.mean())
    assert shot.std() > 20


@pytest.mark.parametrize("raw_images", [False, True], ids=["jpeg", "raw"])
def test_headless_screenshot_shows_the_reference_stored_once(tmp_path, capsys, raw_images):
    """Frame 1's reference is frame 0's moving image, stored once (in an image slot): the Registration view
    at frame 1 draws it (red and green), not frame 1's own moving image (blue) nor frame 0's reference
    (grey), and the Moving view draws the blue image alone; at frame 0 they draw the grey reference and
    the red and green moving image."""
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    halves = np.zeros((120, 160, 3), np.uint8)
    halves[:, :80] = (230, 20, 20)
    halves[:, 80:] = (20, 210, 20)
    grey = np.full((120, 160, 3), 128, np.uint8)
    blue = np.zeros((120, 160, 3), np.uint8)
    blue[:] = (20, 20, 230)
    path = tmp_path / "once.rrd"
    with Recorder(path, kind="sequence", raw_images=raw_images) as rec:
        for f, (reference, moving) in enumerate([(grey, halves), (halves, blue)]):
            rec.set_frame(f)
            rec.log_images(reference=reference, moving=moving)
            rec.log_errors({"plain": 0.1 + f})
    shots = {}
    for name in ("Registration", "Moving"):
        for f in (0, 1):
            shots[name, f] = tmp_path / f"{name}{f}.png"
            code = pcreg_view([str(path), "--screenshot", str(shots[name, f]), "--time", f"frame={f}", "--view", name,
                               "--size", "1280x720"])
            assert code == 0, capsys.readouterr().err
    seen = {key: _colours(cv2.imread(str(shot), cv2.IMREAD_COLOR)) for key, shot in shots.items()}
    red, green, blue_, grey_ = seen["Registration", 1]
    assert red > 0.05 and green > 0.05 and blue_ < 0.01 and grey_ < 0.01, seen
    red, green, blue_, grey_ = seen["Moving", 1]
    assert blue_ > 0.05 and max(red, green, grey_) < 0.01, seen
    red, green, blue_, grey_ = seen["Registration", 0]
    assert grey_ > 0.05 and max(red, green, blue_) < 0.01, seen
    red, green, blue_, grey_ = seen["Moving", 0]
    assert red > 0.05 and green > 0.05 and max(blue_, grey_) < 0.01, seen


def _colours(shot: np.ndarray) -> tuple[float, float, float, float]:
    """Fractions of the picture that are the recording's saturated red, green and blue, and its grey (BGR input)."""
    b, g, r = (shot[..., i].astype(int) for i in range(3))
    red = (r > 150) & (g < 90) & (b < 90)
    green = (g > 140) & (r < 90) & (b < 90)
    blue = (b > 150) & (r < 90) & (g < 90)
    grey = (np.abs(r - 128) < 12) & (np.abs(g - 128) < 12) & (np.abs(b - 128) < 12)
    return float(red.mean()), float(green.mean()), float(blue.mean()), float(grey.mean())


@pytest.mark.slow
def test_web_viewer_shows_the_recording_in_a_browser(small_recording, tmp_path):
    """``pcreg view --web`` in a real browser: headless Chromium, software GL, no display, no GPU."""
    import re

    from _browser import Browser, find_chromium

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    second = tmp_path / "again.rrd"  # two recordings, shown side by side
    second.write_bytes(small_recording.read_bytes())
    proc, url = view_web(str(small_recording), str(second), "--grpc-port", "0")
    try:
        m = re.match(r"http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1%3A(\d+)%2Fproxy$", url)
        assert m, url
        for port in map(int, m.groups()):  # bound to the loopback address only, not to every interface
            assert listening(port) == ["0100007F"], (port, listening(port))
        with Browser(width=1280, height=720) as browser:
            browser.open(url)
            # both recordings drawn: their red and green in the left and in the right half of the page
            def both(s):
                half = s.shape[1] // 2
                return min(*_colours(s[:, :half])[:2], *_colours(s[:, half:])[:2]) > 0.02

            ok, shot = browser.wait_for(both, timeout=120)
            cv2.imwrite(str(tmp_path / "web.png"), shot)
            print("web viewer screenshot:", tmp_path / "web.png")
        red, green = _colours(shot)[:2]
        assert ok, f"the recordings' colours are not on both halves of the page: red {red:.3f}, green {green:.3f}"
        assert shot.std() > 20
    finally:
        code = stop_view(proc)
    assert code == 130
    assert not listening(int(m.group(1))) and not listening(int(m.group(2)))


def _children(pid: int) -> list[tuple[int, str]]:
    """The processes whose parent is ``pid``: (pid, command line)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # ended meanwhile
            continue
        if int(fields[1]) == pid:
            found.append((int(stat.parent.name), cmdline))
    return found


def test_a_recording_is_sent_to_the_server_by_a_process_that_a_ctrl_c_stops_without_a_word(small_recording, tmp_path):
    """The web viewer's server is given the recording by a process of its own, which ends once it is sent (the
    process that sends one keeps about five times its size for as long as it lives): a Ctrl-C while it sends ends
    the sender and the server, and says pcreg's one line (rerun's own error lines were printed around it)."""
    import os
    import signal
    import subprocess

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "pcreg.cli", "view", str(small_recording), "--web", "--web-port", "0",
                             "--grpc-port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    try:
        sender = until(lambda: [c for c in _children(proc.pid) if "send_here" in c[1]], what="the recording being sent",
                       alive=proc, bound=120)
        server = [c for c in _children(proc.pid) if "--serve-web" in c[1]]
        os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C in the terminal: pcreg's group, not the sender's own
        assert proc.wait(timeout=60) == 130
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()
        proc.stderr.close()
    assert err.strip().splitlines() == ["pcreg: interrupted (nothing was written)"], err
    for pid, _ in sender + server:  # none left running
        until(lambda: not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2],
              what=f"process {pid} ended", bound=60)


def test_the_recording_is_sent_with_pcregs_modules_not_those_of_the_folder_it_runs_in(small_recording, tmp_path):
    """pcreg run as its installed command from a folder holding a ``rerun.py`` (or another pcreg checkout): the
    process that sends the recording imported from that folder first (``python -c`` puts it on its path) and the
    page was refused ("not sent ... 'rerun' is not a package"); it imports what pcreg's own process does."""
    import os
    import signal
    import subprocess

    work, entry = tmp_path / "work", tmp_path / "bin" / "pcreg_entry.py"
    work.mkdir()
    entry.parent.mkdir()
    (work / "rerun.py").write_text("raise ImportError('the rerun.py of the folder pcreg runs in')\n")
    entry.write_text("import sys\nfrom pcreg.cli import main\nsys.exit(main())\n")  # as the console script: no cwd
    proc = subprocess.Popen([sys.executable, str(entry), "view", str(small_recording), "--web", "--web-port", "0",
                             "--grpc-port", "0"], cwd=work, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"), start_new_session=True)
    try:
        url = next((line for line in proc.stdout if line.startswith("http://")), None)
        assert url, proc.stderr.read()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=60)
        proc.stdout.close()
        proc.stderr.close()
    assert code == 130


def test_no_interpreter_to_send_the_recording_is_one_line(small_recording, monkeypatch):
    """An embedded Python whose ``sys.executable`` is empty: ``Permission denied`` and nothing more."""
    monkeypatch.setattr(sys, "executable", "")
    with pytest.raises(view.ViewerError, match="could not start a Python interpreter to send the recording"):
        view._send(small_recording, "127.0.0.1", 9)


# -- one blueprint per kind of recording ------------------------------------------------------------

KIND_NAMES = ("register", "crosscheck", "sequence", "rotation", "demo", "dense", "crosscheck-implementations")


@pytest.fixture(scope="module")
def kind_recordings(tmp_path_factory):
    """A small recording of every kind, each made the way its command makes it."""
    import contextlib
    import io


    from _images import moved, rigid_about_centre, shapes_image
    from pcreg import cli
    from pcreg.commands import evaluate_sequence
    from pcreg.experiments import sequence

    d = tmp_path_factory.mktemp("kinds")
    ref = shapes_image(120, 160, 0)
    mov = moved(ref, rigid_about_centre(ref.shape, 0.15, 3.0, -2.0))
    cv2.imwrite(str(d / "ref.png"), ref[..., ::-1])
    cv2.imwrite(str(d / "mov.png"), mov[..., ::-1])
    small = ["--data", "synthetic:syn1a", "--size", "160x120", "--backend", "reference", "--levels", "2",
             "--iterations", "5", "--force"]
    runs = {
        "register": ["register", str(d / "ref.png"), str(d / "mov.png")],
        "crosscheck": ["crosscheck", str(d / "ref.png"), str(d / "mov.png")],
        "sequence": ["evaluate", "sequence", "--frames", "5", "-k", "1", "--out", str(d / "seq"), *small],
        "rotation": ["evaluate", "rotation", "--frames", "2", "--angles", "0,20", "--samples", "1",
                     "--out", str(d / "rot"), *small],
    }
    paths = {}
    for kind, argv in runs.items():
        paths[kind] = d / f"{kind}.rrd"
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli.main([*argv, "--record", str(paths[kind])]) == 0, kind
    # the demo records its sequence evaluation with kind "demo"
    parser = cli._Parser(prog="pcreg evaluate sequence")
    evaluate_sequence.add_arguments(parser)
    args = parser.parse_args(["--frames", "5", "-k", "1", *small])
    paths["demo"] = d / "demo.rrd"
    with Recorder(paths["demo"], recording_name="pcreg demo", kind="demo") as rec:
        sequence.evaluate(evaluate_sequence.config_from_args(args), out=d / "demo", force=True, recorder=rec,
                          show_progress=False)
    # a dense registration of the pair, logged by the recorder
    from pcreg import register_dense

    paths["dense"] = d / "dense.rrd"
    dense = register_dense(ref, mov)
    with Recorder(paths["dense"], kind="dense") as rec:
        rec.set_frame(0)
        rec.log_images(reference=ref, moving=mov, warped=mov)
        rec.log_dense(dense.field, matrix=dense.matrix, confidence=dense.confidence,
                      warped_prior=dense.confidence)
    # a cloud cross-check: every implementation on the crosscheck_iteration timeline
    rng = np.random.default_rng(0)
    target = rng.uniform(0, 10, (300, 3)) * [1.0, 1.0, 0.3]
    a = 0.1
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    np.save(d / "target.npy", target)
    np.save(d / "source.npy", (target - [0.2, -0.1, 0.05]) @ R)
    paths["crosscheck-implementations"] = d / "clouds.rrd"
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(["crosscheck", str(d / "target.npy"), str(d / "source.npy"), "--with", "reference,open3d",
                         "--json", "--record", str(paths["crosscheck-implementations"])]) == 0
    return paths


def _data_kinds(view_class: str) -> frozenset[str]:
    from pcreg.recording import blueprint as B

    return B.VIEW_DATA[view_class]


def _query_matches(query: str, path: str) -> bool:
    pattern = query.removeprefix("+ ").strip()
    if pattern.endswith("/**"):
        base = pattern[:-3]
        return path == base or path.startswith(base + "/")
    return path == pattern


@pytest.mark.parametrize("kind", KIND_NAMES)
def test_every_view_of_the_embedded_blueprint_has_data(kind_recordings, kind):
    """The blueprint the recorder embeds, read back from the file, against the entities logged: every
    view's contents hold data of its class on the timeline the blueprint opens on."""
    from pcreg.recording.readback import read_blueprint, read_entities, read_kind

    path = kind_recordings[kind]
    assert read_kind(path) == kind.split("-")[0]
    views, timeline = read_blueprint(path)
    assert views and timeline
    shown = read_entities(path, timeline=timeline)
    for v in views:
        wanted = _data_kinds(v.view_class)
        with_data = [p for p, arch in shown.items() if wanted & arch and any(_query_matches(q, p) for q in v.query)]
        assert with_data, f"{kind}: view {v.name!r} ({v.view_class}, {v.query}) has no data on {timeline}"
    names = {v.name for v in views}
    expected = {
        "register": {"Registration", "Moving", "ICP reference", "ICP fitness", "Log"},
        "crosscheck": {"ICP reference", "ICP open3d", "ICP fitness", "Crosscheck report"},
        "sequence": {"Registration", "Truth", "Predicted plain", "Predicted augmented", "Errors"},
        "rotation": {"Registration", "Truth", "Predicted before", "Predicted after", "Errors"},
        "demo": {"Registration", "Truth", "Predicted plain", "Errors"},
        "dense": {"Displacement", "Confidence", "Warped prior", "Registration"},
        "crosscheck-implementations": {"reference", "open3d", "error", "fitness", "Crosscheck report"},
    }[kind]
    assert expected <= names, (kind, sorted(names))
    if kind == "dense":  # one value is a dot, not a plot
        assert "Max displacement" not in names
    if kind in ("register", "crosscheck"):  # a sequence's views do not belong to a registration
        assert not [n for n in names if n.startswith(("Truth", "Predicted", "Errors"))], sorted(names)


def _colourful(img: np.ndarray) -> float:
    """Fraction of saturated, not dark pixels (recorded images, label maps, clouds and plot lines; the
    viewer's own chrome and its "no data" text are grey)."""
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    return float(((hsv[..., 1] > 90) & (hsv[..., 2] > 70)).mean())


@pytest.mark.slow
@pytest.mark.parametrize("kind", KIND_NAMES)
def test_headless_viewer_draws_every_view_of_each_kind(kind_recordings, kind, tmp_path):
    """``pcreg view`` of each kind in the headless viewer: the views it lays out are the blueprint's,
    none reports a problem, and every image, cloud and plot view draws something in colour."""
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    from pcreg.recording import blueprint as B
    from pcreg.recording.staging import stage

    staged = stage([kind_recordings[kind]], tmp_path / "staged.rrd")
    with view.headless(staged.path, size="1200x700") as (client, state, _):
        names = sorted(v.name for v in state.views)
        from pcreg.recording.readback import read_entities

        tl = B.timeline(staged.kinds[0], read_entities(staged.path))
        expected = B.panes(staged.kinds[0], read_entities(staged.path, timeline=tl))
        assert names == sorted(p.name for p in expected)
        drawn, hidden = [], []
        for v in state.views:
            assert not [r for r in v.reports if r.severity == "error"], (v.name, v.reports)
            if v.view_class not in ("2D", "3D", "TimeSeries"):
                continue
            out = tmp_path / f"{v.view_id}.png"
            seen = {}

            def look(v=v, out=out, seen=seen):
                """"hidden", "drawn", or None (looked again: images are decoded a few frames after the
                recording loads)."""
                try:
                    client.save_screenshot(str(out), view_id=v.view_id)
                except ConnectionError as exc:  # a view in a tab that is not in front is not drawn
                    assert "not found" in str(exc), exc
                    return "hidden"
                shot = cv2.imread(str(out), cv2.IMREAD_COLOR)
                assert shot is not None
                # colour (images, label maps, clouds, plot lines), or a large bright area (a valid
                # mask); an empty view is dark grey with one line of grey "no data" text
                seen.update(colour=_colourful(shot), bright=float((shot.max(axis=2) > 150).mean()))
                return "drawn" if seen["colour"] > 0.002 or seen["bright"] > 0.05 else None

            try:
                found = until(look, what=f"{kind}: view {v.name!r} drawing", bound=120)
            except AssertionError:
                pytest.fail(f"{kind}: view {v.name!r} draws nothing ({seen})")
            if found == "hidden":
                hidden.append(v.name)
                continue
            drawn.append(v.name)
        print(kind, "drawn:", drawn, "in tabs behind:", hidden)
        assert len(drawn) >= 2 and len(drawn) > len(hidden), (drawn, hidden)


# -- several recordings together ------------------------------------------------------------------


@pytest.mark.slow
def test_two_backends_side_by_side(kind_recordings, tmp_path, capsys):
    """``pcreg view A.rrd B.rrd``: one recording per backend of the same registration, merged under
    their file names; each 2-D view has one pane per recording, each series plot both recordings."""
    import contextlib
    import io

    from pcreg import cli
    from pcreg.recording import blueprint as B
    from pcreg.recording.readback import read_blueprint, read_entities
    from pcreg.recording.staging import stage

    d = kind_recordings["register"].parent
    runs = {}
    for backend in ("reference", "open3d"):
        runs[backend] = tmp_path / f"{backend}.rrd"
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli.main(["register", str(d / "ref.png"), str(d / "mov.png"), "--backend", backend,
                             "--record", str(runs[backend])]) == 0
    staged = stage([runs["reference"], runs["open3d"]], tmp_path / "both.rrd")
    assert staged.labels == ("reference", "open3d") and staged.kinds == ("register", "register")
    views, timeline = read_blueprint(staged.path)
    shown = read_entities(staged.path, timeline=timeline)
    names = {v.name for v in views}
    assert {"reference: Registration", "open3d: Registration", "reference: ICP reference", "open3d: ICP open3d",
            "ICP fitness"} <= names, sorted(names)
    for v in views:
        hits = [p for p, a in shown.items() if B.VIEW_DATA[v.view_class] & a and any(_query_matches(q, p) for q in v.query)]
        assert hits, (v.name, v.query)
        if v.name == "ICP fitness":  # one plot, both recordings
            assert {h.split("/")[1] for h in hits} == {"reference", "open3d"}, hits
    # the legends tell the recordings apart
    from pcreg.recording.readback import read_recording

    rec = read_recording(staged.path)
    legend = rec.latest("/open3d/icp/open3d/fitness", component="SeriesLines:names")["SeriesLines:names"].to_pylist()
    assert legend == ["open3d open3d fitness"]
    # and natively, headless
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    out = tmp_path / "both.png"
    assert pcreg_view([str(runs["reference"]), str(runs["open3d"]), "--screenshot", str(out),
                       "--size", "1200x700"]) == 0, capsys.readouterr().err
    shot = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert shot is not None and _colourful(shot) > 0.05


def test_staging_an_empty_recording_and_bad_files(tmp_path, capsys):
    """A recording with nothing logged stages without a layout (the viewer chooses); a bad second file
    is one line and exit 2."""
    from pcreg.recording.readback import read_blueprint
    from pcreg.recording.staging import labels_for, stage

    empty = tmp_path / "empty.rrd"
    with Recorder(empty):
        pass
    staged = stage([empty], tmp_path / "staged.rrd")
    assert read_blueprint(staged.path)[0] == []
    assert labels_for(["a/run.rrd", "b/run.rrd", "x y.rrd"]) == ["run", "run_2", "x_y"]
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording")
    assert pcreg_view([str(empty), str(bad), "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "not a rerun recording" in one_line_error(capsys)
    assert pcreg_view([str(empty), "--web", "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "choose one" in one_line_error(capsys)


def test_a_screenshot_of_nothing_is_refused_at_once(tmp_path, capsys):
    """A recording with nothing logged, or cut short before its first data, has nothing to draw: the
    screenshot is refused in one line (exit 2) instead of the headless viewer waiting its whole timeout."""
    empty = tmp_path / "empty.rrd"
    with Recorder(empty):
        pass
    whole = tmp_path / "whole.rrd"
    with Recorder(whole) as rec:
        rec.set_frame(0)
        rec.log_text("something to draw")
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(whole.read_bytes()[:300])  # the file's header and first messages, no data
    for path in (empty, cut):
        assert pcreg_view([str(path), "--screenshot", str(tmp_path / "x.png"), "--timeout", "600"]) == 2
        assert one_line_error(capsys).rstrip().endswith("nothing to draw (nothing logged, or the file ends before its first data)")
    assert not (tmp_path / "x.png").exists()


def test_a_damaged_recording_is_one_line(small_recording, tmp_path, capsys):
    """A recording whose header names a rerun version this one does not read, or whose messages are
    damaged half way, is one line naming the file and exit 2 (it was an internal error, exit 1), for
    --screenshot, --web and the report page alike; no screenshot is left."""
    whole = small_recording.read_bytes()
    old = tmp_path / "old version.rrd"
    old.write_bytes(whole[:4] + bytes([0, 9, 0, 0]) + whole[8:])  # RRF2, then the writer's version 0.9.0
    damaged = tmp_path / "damaged.rrd"
    middle = bytearray(whole)
    for i in range(len(whole) // 2, len(whole) // 2 + 2000):
        middle[i] ^= 0x5A
    damaged.write_bytes(bytes(middle))
    for bad in (old, damaged):
        assert pcreg_view([str(bad), "--screenshot", str(tmp_path / "x.png")]) == 2
        assert str(bad) in one_line_error(capsys)
        assert pcreg_view([str(small_recording), str(bad), "--web", "--web-port", "0", "--grpc-port", "0"]) == 2
        assert str(bad) in one_line_error(capsys)
    assert not (tmp_path / "x.png").exists()
    assert "version" in (pcreg_view([str(old), "--web"]), one_line_error(capsys))[1]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc, a folder nothing can be made in")
def test_a_screenshot_where_no_file_can_be_made_is_refused_at_once(small_recording, capsys):
    """A screenshot into a folder that takes no file (even for root, whom os.access lets write anywhere)
    is refused before the viewer starts, naming the screenshot (not a temporary file of the viewer's)."""
    for out in ("/proc/shot.png", "/proc/no/such/folder/shot.png"):
        assert pcreg_view([str(small_recording), "--screenshot", out]) == 2
        assert one_line_error(capsys).startswith(f"pcreg: error: cannot write {out}: no file can be made in /proc")


def test_native_viewer_without_a_display_points_to_web(small_recording, monkeypatch, capsys):
    if not sys.platform.startswith("linux"):
        pytest.skip("DISPLAY/WAYLAND_DISPLAY decide only on Linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert pcreg_view([str(small_recording)]) == 2
    assert "--web" in one_line_error(capsys)


def test_web_arguments(small_recording, capsys):
    with pytest.raises(SystemExit):
        pcreg_view([str(small_recording), "--web", "--web-port", "70000"])
    assert "0..65535" in capsys.readouterr().err
    assert view.web_url("127.0.0.1", 9090, 9876) == \
        "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy"
    assert pcreg_view([str(small_recording), "--web", "--web-port", "9999", "--grpc-port", "9999"]) == 2
    assert "must differ" in one_line_error(capsys)
    assert pcreg_view([str(small_recording), "--web", "--bind", "not-an-address"]) == 2
    assert "IP address" in one_line_error(capsys)
    assert pcreg_view([str(small_recording), "--web", "--bind", "192.0.2.1"]) == 2  # not this machine's
    assert "cannot listen there" in one_line_error(capsys)


@pytest.mark.slow
def test_web_viewer_on_another_address(small_recording):
    """``--bind`` opts in to another address; the page, reached by that address, still gets the data
    (127.0.0.2: another address on this machine's loopback, so nothing is exposed by the test)."""
    from _browser import Browser, find_chromium

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    try:
        proc, url = view.serve_web(small_recording, bind="127.0.0.2", web_port=0, grpc_port=0)
    except PcregError as exc:
        pytest.skip(f"127.0.0.2 is not usable here: {exc}")
    try:
        # the recording sent to the server over gRPC, not named to it: a server given the file polls it, a core busy
        assert not any(str(a).endswith(".rrd") for a in proc.args), proc.args
        assert url.startswith("http://127.0.0.2:") and "127.0.0.2%3A" in url
        ports = [int(p) for p in __import__("re").findall(r"127\.0\.0\.2(?::|%3A)(\d+)", url)]
        assert all(listening(p) == ["0200007F"] for p in ports), ports
        with Browser(width=1280, height=720) as browser:
            browser.open(url)
            ok, shot = browser.wait_for(lambda s: min(_colours(s)[:2]) > 0.03, timeout=120)
        assert ok, _colours(shot)[:2]
    finally:
        view.stop(proc)


@pytest.mark.slow
def test_web_viewer_ends_with_a_pcreg_killed_outright(small_recording):
    """A ``pcreg view --web`` killed outright (SIGKILL: it cannot stop its viewer) leaves no viewer
    serving on: the viewer, in a session of its own, is ended with it."""
    import os
    import re
    import subprocess

    proc = subprocess.Popen([sys.executable, "-m", "pcreg.cli", "view", str(small_recording), "--web",
                             "--web-port", "0", "--grpc-port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        url = next((line.strip() for line in proc.stdout if line.startswith("http://")), None)
        assert url, proc.stderr.read()
        ports = [int(p) for p in re.findall(r"(?::|%3A)(\d+)", url)]
        assert len(ports) == 2 and all(listening(p) for p in ports)
        children = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and _parent(p) == proc.pid]
        assert children, "the viewer is not a child of pcreg view"
        proc.kill()
        proc.wait(timeout=30)
        # (its ports are then closed with it; another test's viewer may take them at once, so they are
        # not checked here)
        for pid in children:
            until(lambda pid=pid: not _alive(pid), what=f"viewer {pid} ending after pcreg view was killed")
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)
        proc.stdout.close()
        proc.stderr.close()


def _parent(proc_dir: Path) -> int | None:
    try:
        return int((proc_dir / "stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None


def _alive(pid: int) -> bool:
    """Running (not gone, nor a zombie waiting to be reaped)."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def test_a_cut_recording_is_drawn_with_a_note(small_recording, tmp_path, capsys):
    """A recording cut short (or still being written) is drawn up to its last whole message, and says so:
    a screenshot of it exited 0 without a word that part of it was missing."""
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    data = small_recording.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) * 3 // 4])
    assert unfinished_note(small_recording) is None
    assert pcreg_view([str(cut), "--screenshot", str(tmp_path / "shot.png")]) == 0
    err = capsys.readouterr().err
    assert f"pcreg: note: {cut}: the recording does not end (still being written, or cut short)" in err, err
    assert (tmp_path / "shot.png").exists()


def test_default_ports_held_by_another_server_give_way_to_free_ones(monkeypatch, capsys):
    """Two users of one machine, or a second `pcreg view --web`: the default port 9090 was refused as in use,
    and the user had to find --web-port 0. Ports the user gives are kept (and refused later when in use)."""
    import argparse
    import socket

    from pcreg.commands import view as command

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        busy, free = held.getsockname()[1], view.free_port("127.0.0.1")
        monkeypatch.setattr(command, "WEB_PORT", busy)
        monkeypatch.setattr(command, "GRPC_PORT", free)
        args = argparse.Namespace(bind="127.0.0.1", web=True, web_port=None, grpc_port=None)
        command._choose_ports(args)
        assert (args.web_port, args.grpc_port) == (0, free)
        assert capsys.readouterr().err == ""  # said once it serves: bad input found before is said alone, in one line
        command._note_serving(args)
        assert capsys.readouterr().err == (f"pcreg: note: port {busy} is in use on 127.0.0.1; serving on a free "
                                           "port instead (--web-port chooses one)\n")
        args = argparse.Namespace(bind="127.0.0.1", web=True, web_port=busy, grpc_port=None)
        command._choose_ports(args, grpc=False)
        assert (args.web_port, args.grpc_port) == (busy, None) and capsys.readouterr().err == ""
        with pytest.raises(PcregError, match=rf"--web-port {busy}: the port is in use on 127.0.0.1"):
            view.serve_web(Path("unused.rrd"), web_port=busy, grpc_port=free)


@pytest.mark.parametrize("damage", ["old_version", "reserved_options", "unknown_message"])
def test_a_damaged_recording_is_refused_naming_it_and_no_temporary_copy(small_recording, tmp_path, capsys, damage):
    """A recording of an older rerun, or with a damaged header or message, was refused with rerun's error about
    the temporary copy it was read from a second time ("Failed to read RRD file at /tmp/pcreg-rrd-.../snapshot.rrd"),
    a file the person never named and that no longer exists. The error is now about the file given."""
    data = small_recording.read_bytes()
    bad = tmp_path / "bad.rrd"
    bad.write_bytes({"old_version": data[:4] + bytes([0, 20, 0, 0]) + data[8:],
                     "reserved_options": data[:8] + bytes([9, 9, 9, 9]) + data[12:],
                     "unknown_message": data[:12] + (77).to_bytes(8, "little") + data[20:]}[damage])
    assert pcreg_view([str(bad), "--screenshot", str(tmp_path / "x.png")]) == 2
    said = one_line_error(capsys)
    assert "not a rerun recording" in said and "snapshot" not in said and "pcreg-rrd-" not in said, said
    assert said.count(str(bad)) == 2, said  # pcreg's and rerun's words both name it


def test_the_recording_server_keeps_room_for_the_whole_recording(tmp_path):
    """rerun's server keeps 1 GiB by default and drops the oldest data past it: a recording of 1.36 GB was served from
    its 63rd frame on. Its limit is twice the recording (1 GB at least), at most three quarters of the memory."""
    import os

    from pcreg.recording.viewer import server_memory

    small, large = tmp_path / "small.rrd", tmp_path / "large.rrd"
    small.write_bytes(b"x")
    with open(large, "wb") as f:
        f.truncate(3 * 10**9)  # sparse: no disk taken
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert server_memory(small) == f"{min(10**9, int(0.75 * total)) // 10**6}MB"
    assert server_memory(large) == f"{min(6 * 10**9, int(0.75 * total)) // 10**6}MB"


@pytest.mark.slow
def test_a_screenshot_with_tmpdir_missing_is_taken_and_leaves_nothing_there(small_recording, tmp_path):
    """``TMPDIR`` naming a folder that does not exist stopped the headless viewer ("the headless viewer stopped: Report
    bugs: ..." the cause, rerun's catalog folder, lost); and each screenshot left an empty ``rerun-data-PID-*`` folder in
    ``TMPDIR``. The viewer's files go to a folder of its own, removed when it stops."""
    import os
    import subprocess

    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    there = tmp_path / "tmp"
    there.mkdir()
    for tmpdir in (tmp_path / "missing", there):
        out = tmp_path / f"{tmpdir.name}.png"
        env = {**os.environ, "TMPDIR": str(tmpdir)}
        run = subprocess.run([sys.executable, "-m", "pcreg", "view", str(small_recording), "--screenshot", str(out)],
                             env=env, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0 and out.is_file(), run.stderr
    assert list(there.iterdir()) == [] and not (tmp_path / "missing").exists()
