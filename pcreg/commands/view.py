"""Open rerun recordings (.rrd) in the viewer, in a browser, or render a screenshot without a display.

Every recording is shown with the blueprint of its kind built from what it holds (no empty view);
several recordings (``pcreg view A.rrd B.rrd``) are merged into one comparison, each under its file
name, the same view of each side by side and their series in one plot (:mod:`pcreg.recording.staging`).

``pcreg view FILE.rrd`` starts the native viewer (the ``rerun`` program that comes with rerun-sdk).
``pcreg view FILE.rrd --web`` serves rerun's web viewer (its assets are inside rerun-sdk; nothing is
downloaded) and the recording over gRPC, both on 127.0.0.1 unless ``--bind`` says otherwise, prints the
URL to open and serves until Ctrl-C: no display and no GPU needed on the machine (over SSH, forward
both ports, e.g. ``ssh -L 9090:localhost:9090 -L 9876:localhost:9876 HOST``).
``pcreg view FILE.rrd --screenshot OUT.png [--time frame=N] [--view NAME]`` starts the viewer headless
on 127.0.0.1 (Vulkan; on a machine without a GPU, Mesa's lavapipe from Debian's
``mesa-vulkan-drivers``), drives it with ``rerun.experimental.ViewerClient`` and saves the picture.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from pathlib import Path
from typing import Any, Iterator

from ..errors import InputError, OutputError, PcregError


class ViewerError(PcregError):
    """The rerun viewer is missing, or failed to start or to render."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recordings", metavar="FILE.rrd", nargs="+",
                        help="the recording to show; several are shown side by side (a comparison)")
    parser.add_argument("--web", action="store_true", help="serve the web viewer and print its URL instead of opening a window")
    parser.add_argument("--bind", metavar="ADDRESS", default="127.0.0.1",
                        help="address the web viewer and its data server listen on (default 127.0.0.1: this machine only)")
    parser.add_argument("--web-port", type=_port, default=9090, help="web viewer's HTTP port (default 9090; 0: any free port)")
    parser.add_argument("--grpc-port", type=_port, default=9876, help="recording server's port (default 9876; 0: any free port)")
    parser.add_argument("--screenshot", metavar="OUT.png", help="render to this PNG headless instead of opening a window")
    parser.add_argument("--time", metavar="TIMELINE=N", help="put the time cursor here before the screenshot, e.g. frame=3")
    parser.add_argument("--view", metavar="NAME", help="screenshot only the view with this name (e.g. Registration)")
    from ..validation import arg_float, arg_window_size

    parser.add_argument("--size", type=arg_window_size, metavar="WxH", default="1600x900", help="headless window size in points (default 1600x900)")
    parser.add_argument("--viewer", metavar="PATH", help="the rerun program (default: the one installed with rerun-sdk)")
    parser.add_argument("--timeout", type=arg_float(0, 86400, lo_open=True), default=60.0, help="seconds to wait for the viewer (default 60)")
    parser.add_argument("--force", action="store_true", help="overwrite OUT.png")


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 0..65535, got {value}")
    return value


def find_viewer(explicit: str | None = None) -> str:
    """Path of the ``rerun`` program: ``explicit``, else rerun-sdk's own binary, else ``rerun`` on PATH."""
    if explicit:
        p = Path(explicit)
        if not (p.is_file() and os.access(p, os.X_OK)):
            raise ViewerError(f"rerun viewer not found at {explicit}")
        return str(p)
    try:
        import importlib.util

        spec = importlib.util.find_spec("rerun_cli")
        if spec and spec.origin:
            binary = Path(spec.origin).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
            if binary.is_file() and os.access(binary, os.X_OK):
                return str(binary)
    except (ImportError, ValueError):
        pass
    for candidate in (Path(sys.executable).parent / "rerun", shutil.which("rerun")):
        if candidate and Path(candidate).is_file():
            return str(candidate)
    raise ViewerError("rerun viewer not found: install rerun-sdk (it ships the `rerun` program)")


def check_recording(path: str | os.PathLike) -> tuple[str, str]:
    """(application id, recording id) of the first recording in ``path``; one-line errors otherwise."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if not p.is_file():
        raise InputError(f"{p}: not a file")
    from rerun.chunk import RrdReader

    try:
        stores = RrdReader(str(p)).recordings()
    except Exception as exc:  # rerun's reader raises its own types for a bad file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{p}: not a rerun recording ({first})") from None
    if not stores:
        raise InputError(f"{p}: not a rerun recording (no recording store in it)")
    return stores[0].application_id, stores[0].recording_id


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _parse_time(text: str | None) -> tuple[str, int] | None:
    if not text:
        return None
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name.strip(), int(value)
    except ValueError:
        raise InputError(f"--time must look like TIMELINE=N (e.g. frame=3), got {text!r}") from None


def vulkan_icds() -> list[Path]:
    """The Vulkan drivers (ICD files) the loader would find."""
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        names = (os.environ.get("VK_DRIVER_FILES") or os.environ["VK_ICD_FILENAMES"]).split(os.pathsep)
        return [Path(n) for n in names if Path(n).is_file()]
    found: list[Path] = []
    for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d"):
        if Path(d).is_dir():
            found += sorted(Path(d).glob("*.json"))
    return found


#: Seconds after the headless viewer starts before a picture of the whole window is taken: its start-up
#: notices (server address, renderer) fade out by then.
NOTICES_FADE_S = 7.0


@contextlib.contextmanager
def headless(recording: str | os.PathLike, *, size: str = "1600x900", viewer: str | None = None,
             timeout: float = 60.0) -> Iterator[tuple[Any, Any, float]]:
    """The headless viewer with ``recording`` loaded: yields ``(ViewerClient, ViewerState, started)``.

    Starts ``rerun --headless`` bound to 127.0.0.1 on a free port in a process group of its own, opens
    the file, waits for it to load (its views laid out), and stops the viewer on exit. ``started`` is
    the ``time.monotonic()`` at which the viewer started.
    """
    from rerun.experimental import ViewerClient

    binary = find_viewer(viewer)
    if sys.platform.startswith("linux") and not vulkan_icds():
        raise ViewerError("no Vulkan driver for a headless screenshot: install Debian's mesa-vulkan-drivers (lavapipe)")
    rec_path = Path(recording).resolve()
    port = _free_port()
    env = dict(os.environ)
    env.setdefault("WGPU_BACKEND", "vulkan")
    env.setdefault("XDG_RUNTIME_DIR", str(Path(os.environ.get("TMPDIR", "/tmp"))))
    cmd = [binary, "--headless", "--bind", "127.0.0.1", "--port", str(port), "--hide-welcome-screen",
           "--window-size", size, "--renderer", "vulkan"]
    started = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + timeout
    try:
        client = None
        while client is None:
            if proc.poll() is not None:
                err = (proc.stderr.read() or b"").decode(errors="replace").strip().splitlines() if proc.stderr else []
                last = next((line for line in reversed(err) if line.strip()), f"exit code {proc.returncode}")
                raise ViewerError(f"the headless viewer stopped: {last[-300:]}")
            try:
                c = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                c.get_state()
                client = c
            except Exception:
                if time.monotonic() > deadline:
                    raise ViewerError(f"the headless viewer did not answer within {timeout:.0f} s") from None
                time.sleep(0.2)
        client.open(str(rec_path))
        while True:
            state = client.get_state()
            if not state.loading and state.recordings and state.views:
                break
            if time.monotonic() > deadline:
                raise ViewerError(f"the viewer did not finish loading {rec_path} within {timeout:.0f} s")
            time.sleep(0.2)
        yield client, state, started
    except RuntimeError as exc:  # ViewerClient's errors
        raise ViewerError(f"the viewer failed: {str(exc).strip().splitlines()[0] if str(exc).strip() else exc}") from None
    finally:
        _stop(proc)


def screenshot(
    recording: str | os.PathLike,
    out: str | os.PathLike,
    *,
    time_cursor: tuple[str, int] | None = None,
    view: str | None = None,
    size: str = "1600x900",
    viewer: str | None = None,
    timeout: float = 60.0,
) -> Path:
    """Render ``recording`` headless to the PNG ``out`` and return its path.

    Loads it in the :func:`headless` viewer, sets the time cursor, saves the screenshot (of the whole
    viewer, once its start-up notices have faded, or of the view named ``view``) and stops the viewer.
    """
    out_path = Path(out).resolve()
    with headless(recording, size=size, viewer=viewer, timeout=timeout) as (client, state, started):
        if time_cursor is not None:
            name, value = time_cursor
            timelines = {t.name for r in state.recordings for t in r.timelines}
            if name not in timelines:
                raise InputError(f"--time: the recording has no timeline {name!r} (it has {', '.join(sorted(timelines))})")
            client.set_time(name, sequence=value, play_state="paused")
        view_id = None
        if view is not None:
            names = {v.name: v.view_id for v in state.views}
            if view not in names:
                raise InputError(f"--view: no view named {view!r} (views: {', '.join(sorted(names))})")
            view_id = names[view]
        time.sleep(0.5)  # let a few frames paint after the cursor moved
        if view_id is None:
            time.sleep(max(0.0, started + NOTICES_FADE_S - time.monotonic()))
        out_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.png")
        try:
            client.save_screenshot(str(tmp), view_id=view_id)
            if not tmp.is_file() or tmp.stat().st_size == 0:
                raise ViewerError("the viewer saved no screenshot")
            os.replace(tmp, out_path)
        finally:
            if tmp.exists():
                tmp.unlink()
    return out_path


def _stop(proc: subprocess.Popen) -> None:
    """Stop the viewer we started (its own process group), then reap it."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, 15)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(proc.pid, 9)
            except ProcessLookupError:
                pass
            proc.wait(timeout=5)
    if proc.stderr:
        proc.stderr.close()


def _free_port_on(host: str) -> int:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _port_free(host: str, port: int) -> bool:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _url_host(bind: str) -> str:
    """The host name a browser uses for a server bound to ``bind``."""
    if bind == "::1":
        return "[::1]"
    if bind in ("0.0.0.0", "::"):
        return socket.gethostname()
    return f"[{bind}]" if ":" in bind else bind


def web_url(host: str, web_port: int, grpc_port: int) -> str:
    """The web viewer's URL, with the recording server to connect to."""
    data = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={urllib.parse.quote(data, safe='')}"


def serve_web(
    recording: str | os.PathLike,
    *,
    bind: str = "127.0.0.1",
    web_port: int = 9090,
    grpc_port: int = 9876,
    viewer: str | None = None,
    timeout: float = 60.0,
) -> tuple[subprocess.Popen, str]:
    """Start rerun's web viewer and a gRPC server holding ``recording``, both bound to ``bind``.

    Returns the server process (in a process group of its own; stop it with :func:`stop`) and the URL
    to open, once both ports answer. Port 0 picks a free port. The web viewer's files come from the
    installed rerun-sdk (they are built into its ``rerun`` program).
    """
    binary = find_viewer(viewer)
    if bind != "localhost":
        try:
            ipaddress.ip_address(bind)
        except ValueError:
            raise InputError(f"--bind must be an IP address of this machine (e.g. 127.0.0.1, 0.0.0.0), got {bind!r}") from None
    probe = "127.0.0.1" if bind in ("0.0.0.0", "localhost") else ("::1" if bind == "::" else bind)
    try:
        with socket.socket(socket.AF_INET6 if ":" in probe else socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind((probe, 0))
    except OSError as exc:
        raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
    try:
        web_port = web_port or _free_port_on(probe)
        grpc_port = grpc_port or _free_port_on(probe)
    except OSError as exc:
        raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
    if web_port == grpc_port:
        raise InputError(f"--web-port and --grpc-port must differ (both {web_port})")
    for name, port in (("--web-port", web_port), ("--grpc-port", grpc_port)):
        if not _port_free(probe, port):
            raise InputError(f"{name} {port}: the port is in use on {bind} (choose another, or 0 for any free port)")
    cmd = [binary, str(Path(recording).resolve()), "--serve-web", "--bind", bind, "--port", str(grpc_port),
           "--web-viewer-port", str(web_port)]
    if bind not in ("127.0.0.1", "::1", "localhost"):
        # the data server answers only pages from localhost unless told otherwise: allow our web viewer's
        # page under whatever name the machine is reached by
        cmd += ["--cors-allow-origin", f"http://*:{web_port}"]
    env = dict(os.environ)
    env.setdefault("RUST_LOG", "warn")
    with tempfile.TemporaryFile() as log:  # a file, not a pipe: a server that runs for hours must never block on it
        proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=log, start_new_session=True)
        try:
            _wait_listening(proc, log, probe, (web_port, grpc_port), timeout)
        except BaseException:
            stop(proc)
            raise
    return proc, web_url(_url_host(bind), web_port, grpc_port)


def _wait_listening(proc: subprocess.Popen, log, host: str, ports: tuple[int, ...], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    for port in ports:
        while True:
            if proc.poll() is not None:
                log.seek(0)
                err = log.read().decode(errors="replace").strip().splitlines()
                last = next((line for line in reversed(err) if line.strip()), f"exit code {proc.returncode}")
                raise ViewerError(f"the web viewer stopped: {last[-300:]}")
            try:
                with socket.create_connection((host, port), timeout=1.0):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    raise ViewerError(f"the web viewer did not listen on port {port} within {timeout:.0f} s") from None
                time.sleep(0.1)


def stop(proc: subprocess.Popen) -> None:
    """Stop a viewer or server started here (its own process group), then reap it."""
    _stop(proc)


def run(args: argparse.Namespace) -> int:
    from ..outputs import check_output
    from ..recording.staging import stage

    for r in args.recordings:
        check_recording(r)
    if args.web and args.screenshot:
        raise InputError("--web serves the viewer to a browser; --screenshot renders without one: choose one")
    if args.screenshot is None and (args.time or args.view):
        raise InputError("--time and --view go with --screenshot")
    binary = find_viewer(args.viewer)
    native = args.screenshot is None and not args.web
    if native and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerError("no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset): "
                          "use --web to view it in a browser, or --screenshot OUT.png")
    out = None
    time_cursor = _parse_time(args.time)
    if args.screenshot is not None:
        out = check_output(args.screenshot, force=args.force)
        if out.suffix.lower() != ".png":
            raise OutputError(f"{out}: the screenshot is written as PNG; name it .png")
    with tempfile.TemporaryDirectory(prefix="pcreg-view-") as tmp:
        try:
            staged = stage(args.recordings, Path(tmp) / "view.rrd")
        except ValueError as exc:
            raise InputError(str(exc)) from None
        if out is not None:
            path = screenshot(staged.path, out, time_cursor=time_cursor, view=args.view, size=args.size,
                              viewer=binary, timeout=args.timeout)
            print(path)
            return 0
        if args.web:
            proc, url = serve_web(staged.path, bind=args.bind, web_port=args.web_port, grpc_port=args.grpc_port,
                                  viewer=binary, timeout=args.timeout)
            if args.bind not in ("127.0.0.1", "::1", "localhost"):
                sys.stderr.write(f"pcreg: note: serving on {args.bind}: whoever can reach this machine there can "
                                 "read the recording\n")
            try:
                print(f"serving {', '.join(map(str, args.recordings))} on {args.bind} (Ctrl-C stops)")
                print(url, flush=True)
                proc.wait()
            except KeyboardInterrupt:
                return 130
            finally:
                stop(proc)
            if proc.returncode not in (0, -15):
                raise ViewerError(f"the web viewer stopped (exit code {proc.returncode})")
            return 0
        return subprocess.call([binary, str(staged.path)])
