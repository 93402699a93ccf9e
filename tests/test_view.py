"""``pcreg view``: bad input gives one line and exit 2; a headless screenshot shows the recording's images."""

from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np
import pytest

from pcreg.commands import view
from pcreg.errors import PcregError
from pcreg.recording.recorder import Recorder


def pcreg_view(argv: list[str]) -> int:
    """``pcreg view ARGV`` in-process: the command line's own entry point where every command is importable,
    else the same parse / run / one-line-error path for ``view`` alone."""
    from pcreg import cli

    try:
        cli.build_parser()
    except ModuleNotFoundError:
        parser = cli._Parser(prog="pcreg view")
        view.add_arguments(parser)
        args = parser.parse_args(argv)
        try:
            return int(view.run(args) or 0)
        except PcregError as exc:
            sys.stderr.write(f"pcreg: error: {exc}\n")
            return 2
    return cli.main(["view", *argv])


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pcreg: error: "), err
    return err


def test_missing_file(tmp_path, capsys):
    assert pcreg_view([str(tmp_path / "nope.rrd")]) == 2
    assert "no such file" in _one_line_error(capsys)


def test_file_that_is_not_a_recording(tmp_path, capsys):
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"this is not a rerun recording\n" * 10)
    assert pcreg_view([str(bad), "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "not a rerun recording" in _one_line_error(capsys)
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
    assert "rerun viewer not found" in _one_line_error(capsys)


def test_existing_screenshot_refused(small_recording, tmp_path, capsys):
    out = tmp_path / "shot.png"
    out.write_bytes(b"old")
    assert pcreg_view([str(small_recording), "--screenshot", str(out)]) == 2
    assert "exists" in _one_line_error(capsys)
    assert out.read_bytes() == b"old"


def test_bad_time_argument(small_recording, tmp_path, capsys):
    assert pcreg_view([str(small_recording), "--screenshot", str(tmp_path / "s.png"), "--time", "frame"]) == 2
    assert "TIMELINE=N" in _one_line_error(capsys)


def test_headless_screenshot_shows_the_images(small_recording, tmp_path, capsys):
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    out = tmp_path / "shot.png"
    code = pcreg_view([str(small_recording), "--screenshot", str(out), "--time", "frame=1",
                       "--view", "Registration", "--size", "1280x720"])
    assert code == 0, capsys.readouterr().err
    shot = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert shot is not None and shot.shape[0] > 100 and shot.shape[1] > 100
    b, g, r = (shot[..., i].astype(int) for i in range(3))
    red = (r > 150) & (g < 90) & (b < 90)
    green = (g > 140) & (r < 90) & (b < 90)
    # the reference image fills a good part of the view: both halves visible, not a blank canvas
    assert red.mean() > 0.05 and green.mean() > 0.05, (red.mean(), green.mean())
    assert shot.std() > 20


def _colours(shot: np.ndarray) -> tuple[float, float]:
    """Fractions of the picture that are the recording's saturated red and green (BGR input)."""
    b, g, r = (shot[..., i].astype(int) for i in range(3))
    red = (r > 150) & (g < 90) & (b < 90)
    green = (g > 140) & (r < 90) & (b < 90)
    return float(red.mean()), float(green.mean())


def _listening(port: int) -> list[str]:
    """Local addresses (hex, as /proc/net/tcp writes them) listening on ``port``."""
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = open(table).read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            addr, hexport = fields[1].split(":")
            if fields[3] == "0A" and int(hexport, 16) == port:
                out.append(addr)
    return out


def test_web_viewer_shows_the_recording_in_a_browser(small_recording, tmp_path):
    """``pcreg view --web`` in a real browser: headless Chromium, software GL, no display, no GPU."""
    import os
    import re
    import signal
    import subprocess

    from _browser import Browser, find_chromium

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "pcreg.cli", "view", str(small_recording), "--web",
                             "--web-port", "0", "--grpc-port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    try:
        url = None
        for line in proc.stdout:
            if line.startswith("http://"):
                url = line.strip()
                break
        assert url, proc.stderr.read()
        m = re.match(r"http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1%3A(\d+)%2Fproxy$", url)
        assert m, url
        for port in map(int, m.groups()):  # bound to the loopback address only, not to every interface
            assert _listening(port) == ["0100007F"], (port, _listening(port))
        with Browser(width=1280, height=720) as browser:
            browser.open(url)
            ok, shot = browser.wait_for(lambda s: min(_colours(s)) > 0.03, timeout=120)
            cv2.imwrite(str(tmp_path / "web.png"), shot)
        red, green = _colours(shot)
        assert ok, f"the recording's colours are not on the page: red {red:.3f}, green {green:.3f}"
        assert shot.std() > 20
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=30)
        proc.stdout.close()
        proc.stderr.close()
    assert code == 130
    assert not _listening(int(m.group(1))) and not _listening(int(m.group(2)))
