"""Headless Chromium driven over the DevTools protocol on a pipe (no debugging port, no extra package).

``Browser`` starts ``chromium --headless --remote-debugging-pipe`` with software rendering (SwiftShader:
no GPU, no display), opens a page and takes screenshots of it, so a test can wait until a web page has
drawn what it should.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-dev-shm-usage", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
]


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class Browser:
    """One headless Chromium with one page; a context manager."""

    def __init__(self, *, width: int = 1280, height: int = 720, binary: str | None = None) -> None:
        binary = binary or find_chromium()
        if binary is None:
            raise FileNotFoundError("chromium not found")
        self._profile = tempfile.TemporaryDirectory(prefix="pcreg-chromium-")
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()

        def pipes_on_3_and_4() -> None:  # the DevTools pipe is fd 3 (commands in) and fd 4 (answers out)
            a, b = os.dup(to_child_r), os.dup(from_child_w)
            os.dup2(a, 3)
            os.dup2(b, 4)
            os.set_inheritable(3, True)
            os.set_inheritable(4, True)

        self._log = open(Path(self._profile.name) / "chromium.log", "wb")
        self.proc = subprocess.Popen(
            [binary, *FLAGS, f"--user-data-dir={self._profile.name}", f"--window-size={width},{height}",
             "--remote-debugging-pipe", "about:blank"],
            preexec_fn=pipes_on_3_and_4, close_fds=False, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=self._log, start_new_session=True)
        os.close(to_child_r)
        os.close(from_child_w)
        self._out = os.fdopen(to_child_w, "wb", buffering=0)
        self._in = os.fdopen(from_child_r, "rb", buffering=0)
        self._buf = b""
        self._id = 0
        self.console: list[str] = []
        targets = self.call("Target.getTargets")["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        self._session = self.call("Target.attachToTarget", targetId=page["targetId"], flatten=True)["sessionId"]
        self.call("Page.enable", session=True)
        self.call("Emulation.setDeviceMetricsOverride", session=True, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)

    def call(self, method: str, *, session: bool = False, **params) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self._session
        self._out.write(json.dumps(msg).encode() + b"\0")
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                answer = json.loads(raw)
                if answer.get("id") == self._id:
                    if "error" in answer:
                        raise RuntimeError(f"{method}: {answer['error']}")
                    return answer.get("result", {})
            chunk = self._in.read(1 << 16)
            if not chunk:
                raise RuntimeError("chromium closed its DevTools pipe")
            self._buf += chunk

    def value(self, expr: str):
        """The value of the JavaScript expression ``expr`` on the open page (returned by value)."""
        return self.call("Runtime.evaluate", session=True, expression=expr, returnByValue=True)["result"].get("value")

    def open(self, url: str) -> None:
        self.call("Page.navigate", session=True, url=url)

    def screenshot(self) -> np.ndarray:
        """The page as a (H, W, 3) BGR image."""
        data = self.call("Page.captureScreenshot", session=True, format="png")["data"]
        img = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise RuntimeError("chromium's screenshot does not decode")
        return img

    def wait_for(self, check, *, timeout: float, every: float = 1.0) -> tuple[bool, np.ndarray]:
        """Screenshot until ``check(image)`` is true (looking every ``every`` s), or ``timeout`` s have
        passed (a bound for a page that never draws, not a measurement)."""
        deadline = time.monotonic() + timeout
        shot = np.zeros((1, 1, 3), np.uint8)
        while True:
            try:
                shot = self.screenshot()
            except RuntimeError:  # the page is still being replaced by the one navigated to
                if time.monotonic() > deadline:
                    raise
            else:
                if check(shot):
                    return True, shot
                if time.monotonic() > deadline:
                    return False, shot
            time.sleep(every)  # then look again

    def close(self) -> None:
        try:
            self._out.write(json.dumps({"id": self._id + 1, "method": "Browser.close"}).encode() + b"\0")
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, 9)
            self.proc.wait(timeout=5)
        for f in (self._out, self._in, self._log):
            f.close()
        self._profile.cleanup()

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def listening(port: int) -> list[str]:
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


def view_web(*args: str):
    """``pcreg view ARGS --web --web-port 0`` in a session of its own: ``(process, url)``, the URL the
    first line it printed (the process's stderr in the assertion where it printed none)."""
    import subprocess
    import sys

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "pcreg.cli", "view", *args, "--web", "--web-port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    url = next((line.strip() for line in proc.stdout if line.startswith("http://")), None)
    assert url and url.startswith("http://127.0.0.1:"), (url, proc.stderr.read() if proc.poll() is not None else "")
    return proc, url


def stop_view(proc) -> int:
    """Interrupt a :func:`view_web` process as Ctrl-C does (if it still runs) and its exit code."""
    import signal

    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
    code = proc.wait(timeout=30)
    proc.stdout.close()
    proc.stderr.close()
    return code


def review_page_values(run: str, *scripts: str) -> list:
    """What each JavaScript expression of ``scripts`` gives on ``pcreg view RUN --web``'s page once it has loaded,
    in a headless Chromium (skipped when there is none)."""
    import pytest
    from _events import until

    if find_chromium() is None:
        pytest.skip("chromium is not installed (Debian's `chromium`, installed by `make setup`)")
    proc, url = view_web(run)
    try:
        with Browser(width=1400, height=800) as browser:
            browser.open(url)
            ev = browser.value
            until(lambda: ev("document.body.dataset.loaded") == "1", what="the page loaded", alive=proc, bound=120)
            return [ev(script) for script in scripts]
    finally:
        stop_view(proc)
