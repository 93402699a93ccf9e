"""Open a rerun recording (.rrd) in the viewer, or render a screenshot of it without a display.

``pcreg view FILE.rrd`` starts the native viewer (the ``rerun`` program that comes with rerun-sdk).
``pcreg view FILE.rrd --screenshot OUT.png [--time frame=N] [--view NAME]`` starts the viewer headless
on 127.0.0.1 (Vulkan; on a machine without a GPU, Mesa's lavapipe from Debian's
``mesa-vulkan-drivers``), drives it with ``rerun.experimental.ViewerClient`` and saves the picture.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

from ..errors import InputError, OutputError, PcregError


class ViewerError(PcregError):
    """The rerun viewer is missing, or failed to start or to render."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="FILE.rrd", help="the recording to show")
    parser.add_argument("--screenshot", metavar="OUT.png", help="render to this PNG headless instead of opening a window")
    parser.add_argument("--time", metavar="TIMELINE=N", help="put the time cursor here before the screenshot, e.g. frame=3")
    parser.add_argument("--view", metavar="NAME", help="screenshot only the view with this name (e.g. Registration)")
    from ..validation import arg_float, arg_window_size

    parser.add_argument("--size", type=arg_window_size, metavar="WxH", default="1600x900", help="headless window size in points (default 1600x900)")
    parser.add_argument("--viewer", metavar="PATH", help="the rerun program (default: the one installed with rerun-sdk)")
    parser.add_argument("--timeout", type=arg_float(0, 86400, lo_open=True), default=60.0, help="seconds to wait for the viewer (default 60)")
    parser.add_argument("--force", action="store_true", help="overwrite OUT.png")


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

    Starts ``rerun --headless`` bound to 127.0.0.1 on a free port in a process group of its own, opens
    the file, waits for it to load, sets the time cursor, saves the screenshot (of the whole viewer or
    of the view named ``view``) and stops the viewer.
    """
    from rerun.experimental import ViewerClient

    binary = find_viewer(viewer)
    if sys.platform.startswith("linux") and not vulkan_icds():
        raise ViewerError("no Vulkan driver for a headless screenshot: install Debian's mesa-vulkan-drivers (lavapipe)")
    rec_path = Path(recording).resolve()
    out_path = Path(out).resolve()
    port = _free_port()
    env = dict(os.environ)
    env.setdefault("WGPU_BACKEND", "vulkan")
    env.setdefault("XDG_RUNTIME_DIR", str(Path(os.environ.get("TMPDIR", "/tmp"))))
    cmd = [binary, "--headless", "--bind", "127.0.0.1", "--port", str(port), "--hide-welcome-screen",
           "--window-size", size, "--renderer", "vulkan"]
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
    except RuntimeError as exc:  # ViewerClient's errors
        raise ViewerError(f"the viewer failed: {str(exc).strip().splitlines()[0] if str(exc).strip() else exc}") from None
    finally:
        _stop(proc)


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


def run(args: argparse.Namespace) -> int:
    from ..outputs import check_output

    check_recording(args.recording)
    if args.screenshot is None:
        if args.time or args.view:
            raise InputError("--time and --view go with --screenshot")
        binary = find_viewer(args.viewer)
        return subprocess.call([binary, str(args.recording)])
    out = check_output(args.screenshot, force=args.force)
    if out.suffix.lower() != ".png":
        raise OutputError(f"{out}: the screenshot is written as PNG; name it .png")
    path = screenshot(args.recording, out, time_cursor=_parse_time(args.time), view=args.view, size=args.size,
                      viewer=args.viewer, timeout=args.timeout)
    print(path)
    return 0
