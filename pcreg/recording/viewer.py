"""The rerun viewer as a process: found, started and stopped here, for the command line and the tests.

:func:`find_viewer` locates the ``rerun`` program that comes with rerun-sdk; :func:`check_recording`
tells a recording from any other file in one line; :func:`headless` starts the viewer without a display
on 127.0.0.1 (Vulkan; on a machine without a GPU, Mesa's lavapipe from Debian's ``mesa-vulkan-drivers``)
and drives it with ``rerun.experimental.ViewerClient``, which :func:`screenshot` uses to save a picture;
:func:`serve_web` serves rerun's web viewer (its assets are built into the ``rerun`` program; nothing is
downloaded) and a recording over gRPC, on 127.0.0.1 unless told otherwise. Every process started here
runs in a process group of its own and is stopped with :func:`stop`.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from pathlib import Path
from typing import Any, Iterator

from ..errors import InputError, PcregError

__all__ = ["server_memory", "ViewerError", "find_viewer", "check_recording", "vulkan_icds", "headless", "screenshot", "serve_web",
           "web_url", "stop", "free_port", "port_free", "check_bind", "url_host"]


class ViewerError(PcregError):
    """The rerun viewer is missing, or failed to start or to render."""


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
    from .readback import recordings_in

    try:
        stores = recordings_in(p)  # a recording still being written: up to its last whole message
    except Exception as exc:  # rerun's reader raises its own types for a bad file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{p}: not a rerun recording ({first})") from None
    if not stores:
        raise InputError(f"{p}: not a rerun recording (no recording store in it)")
    return stores[0].application_id, stores[0].recording_id


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
    port = free_port("127.0.0.1")
    env = dict(os.environ)
    env.setdefault("WGPU_BACKEND", "vulkan")
    # the viewer's own files (its catalog, rerun-data-PID-*) in a folder of its own, removed when it stops: they were
    # left in TMPDIR, and a TMPDIR that does not exist stopped the viewer (Python's folder is one that does)
    files = tempfile.TemporaryDirectory(prefix="pcreg-viewer-", ignore_cleanup_errors=True)
    env["TMPDIR"] = files.name
    env.setdefault("XDG_RUNTIME_DIR", files.name)
    cmd = [binary, "--headless", "--bind", "127.0.0.1", "--port", str(port), "--hide-welcome-screen",
           "--window-size", size, "--renderer", "vulkan"]
    started = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True, preexec_fn=_ends_with_us())
    deadline = time.monotonic() + timeout
    try:
        client = None
        while client is None:
            if proc.poll() is not None:
                said = _last_said(proc.stderr.read() or b"" if proc.stderr else b"", proc.returncode)
                raise ViewerError(f"the headless viewer stopped: {said}")
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
        files.cleanup()


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
            held = [(t.start, t.end) for r in state.recordings for t in r.timelines
                    if t.name == name and t.start is not None and t.end is not None]
            if held and not any(lo <= value <= hi for lo, hi in held):  # every view would say "No data available"
                lo, hi = min(h[0] for h in held), max(h[1] for h in held)
                raise InputError(f"--time {name}={value}: outside the recording, whose {name} timeline runs from {lo} to {hi}")
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
            _save_screenshot(client, tmp, view_id, timeout)
            if not tmp.is_file() or tmp.stat().st_size == 0:
                raise ViewerError("the viewer saved no screenshot")
            os.replace(tmp, out_path)
        finally:
            if tmp.exists():
                tmp.unlink()
    return out_path


def _save_screenshot(client, path: Path, view_id: str | None, timeout: float) -> None:
    """``client.save_screenshot`` to ``path``, asked again while it runs out of the viewer's own wait for a
    painted frame (15 s: a software renderer on a loaded machine can take longer), until ``timeout`` seconds
    have passed; then a :class:`ViewerError`."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            client.save_screenshot(str(path), view_id=view_id)
            return
        except TimeoutError:
            if time.monotonic() > deadline:
                raise ViewerError(f"the viewer did not paint the screenshot within {timeout:.0f} s; "
                                  "try a longer --timeout or a smaller --size") from None


def _last_said(err: bytes, returncode: int) -> str:
    """What a process of rerun's (or the sender) said last on stderr (``err``), its last line that is not blank, at
    most its last 300 characters; its exit code where it said nothing."""
    lines = [line for line in err.decode(errors="replace").splitlines() if line.strip()]
    return lines[-1].rstrip()[-300:] if lines else f"exit code {returncode}"


def _ends_with_us() -> Any:
    """A ``preexec_fn`` that has the viewer ended (SIGTERM) when this process ends, however it ends.

    The viewer runs in a session of its own, so that a Ctrl-C in the terminal reaches pcreg alone, which
    then stops it (:func:`stop`). A pcreg killed outright (SIGKILL, or SIGHUP when its terminal closes)
    cannot stop it, and the viewer would serve on, holding its ports, with no one to end it. On Linux
    the kernel's parent-death signal ends it instead. That signal follows the thread that started the
    child, so it is asked for only from the main thread, which lives as long as the process. None
    elsewhere (no such signal, or another thread)."""
    import signal

    from .._signals import end_with_parent, parent_death_signal

    prctl = parent_death_signal()
    if prctl is None or threading.current_thread() is not threading.main_thread():
        return None
    parent = os.getpid()
    return lambda: end_with_parent(prctl, parent, signal.SIGTERM)  # in the child, between fork and exec


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


def loopback(bind: str) -> bool:
    """Whether ``bind`` is a loopback address, one this machine alone reaches (127.0.0.0/8, ::1, ::ffff:127.x.y.z,
    localhost)."""
    try:
        ip = ipaddress.ip_address(bind)
    except ValueError:
        return bind == "localhost"
    return ip.is_loopback or (isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None and ip.ipv4_mapped.is_loopback)


def check_bind(bind: str) -> str:
    """The address to probe for a server bound to ``bind`` (an IP address of this machine, or
    ``localhost``); one-line errors otherwise."""
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
    return probe


def free_port(host: str) -> int:
    """A port free on ``host`` now."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


#: Whether a server may listen on a port whose closed connections still wait there (TIME_WAIT, a minute after a
#: page was served), as Python's own HTTP servers and rerun's do. Not on Windows, where the option lets a
#: second server take a port another listens on.
REUSE_ADDRESS = os.name != "nt"


def port_free(host: str, port: int) -> bool:
    """Whether a server can listen on ``host``:``port`` (another one listening there, or a port this user may not
    take: no)."""
    return port_problem(host, port) is None


def port_problem(host: str, port: int, bind: str | None = None) -> str | None:
    """Why a server cannot listen on ``host``:``port`` (``bind`` as the person gave it, for the message), None where
    it can: the port in use, a privileged port, or what the system said."""
    import errno

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        if REUSE_ADDRESS:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return f"the port is in use on {bind or host} (choose another, or 0 for any free port)"
            if exc.errno == errno.EACCES and port < 1024 and sys.platform != "win32":
                return ("a privileged port (below 1024 on most systems), which only root or a program with the "
                        "CAP_NET_BIND_SERVICE capability may listen on (choose one above 1023, or 0 for any free port)")
            return f"cannot listen on it on {bind or host} ({exc.strerror or exc}; choose another, or 0 for any free port)"
    return None


def check_port(flag: str, port: int, host: str, bind: str) -> None:
    """An :class:`InputError` for ``flag`` ``port`` where a server cannot listen on it (:func:`port_problem`)."""
    problem = port_problem(host, port, bind)
    if problem is not None:
        raise InputError(f"{flag} {port}: {problem}")


def url_host(bind: str) -> str:
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
    page_port: int | None = None,
) -> tuple[subprocess.Popen, str]:
    """Start rerun's web viewer and a gRPC server holding ``recording``, both bound to ``bind``.

    Returns the server process (in a process group of its own; stop it with :func:`stop`) and the URL
    to open, once both ports answer. Port 0 picks a free port. The web viewer's files come from the
    installed rerun-sdk (they are built into its ``rerun`` program). ``page_port``: the port of the page
    that embeds the web viewer, when that is not the web viewer's own (the report viewer's), so that on
    an address other than loopback the data server answers it.
    """
    binary = find_viewer(viewer)
    probe = check_bind(bind)
    try:
        web_port = web_port or free_port(probe)
        grpc_port = grpc_port or free_port(probe)
    except OSError as exc:
        raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
    if web_port == grpc_port:
        raise InputError(f"--web-port and --grpc-port must differ (both {web_port})")
    for name, port in (("--web-port", web_port), ("--grpc-port", grpc_port)):
        check_port(name, port, probe, bind)
    # the recording is sent once the server listens (:func:`_send`), not named here: given a file, rerun's server keeps
    # a core busy for as long as it serves
    cmd = [binary, "--serve-web", "--bind", bind, "--port", str(grpc_port), "--web-viewer-port", str(web_port),
           "--server-memory-limit", server_memory(recording)]
    if bind not in ("127.0.0.1", "::1", "localhost"):  # the page's origin, not who reaches it (:func:`loopback`)
        # the data server answers only pages from localhost unless told otherwise: allow our web viewer's
        # page under whatever name the machine is reached by
        cmd += ["--cors-allow-origin", f"http://*:{page_port or web_port}"]
    env = dict(os.environ)
    env.setdefault("RUST_LOG", "warn")
    with tempfile.TemporaryFile() as log:  # a file, not a pipe: a server that runs for hours must never block on it
        proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=log, start_new_session=True, preexec_fn=_ends_with_us())
        try:
            _wait_listening(proc, log, probe, (web_port, grpc_port), timeout)
            _send(Path(recording), probe, grpc_port)
        except BaseException:
            stop(proc)
            raise
    return proc, web_url(url_host(bind), web_port, grpc_port)


def server_memory(recording: str | os.PathLike) -> str:
    """rerun's ``--server-memory-limit`` for serving ``recording``: room for all of it, twice its size and 1 GB at
    least, so that a viewer gets its first frames too (at rerun's 1 GiB, a recording of 1.36 GB was served from its
    63rd frame on, without a word), and at most three quarters of this machine's memory."""
    limit = max(10**9, 2 * os.path.getsize(recording))
    try:
        limit = min(limit, int(0.75 * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")))
    except (AttributeError, ValueError, OSError):  # a system that does not say
        pass
    return f"{max(1, limit // 10**6)}MB"


def _send(recording: Path, host: str, grpc_port: int) -> None:
    """Send ``recording`` (its recording and blueprint, under their own ids) to the gRPC server listening on
    ``host``:``grpc_port``, which keeps it for every viewer that connects; returns once it is sent. A server given the
    file to read itself (``rerun FILE --serve-web``) keeps polling it after its end, a core busy for as long as it
    serves (rerun 0.41: 100% of a core, idle); one that received it over gRPC waits idle.

    Sent from a process of its own (:func:`send_here`), ended with it: the process that sends a recording keeps
    about five times its size for as long as it lives (139 MB for one of 28.6 MB), and a Ctrl-C that landed while
    it sent printed rerun's own error lines around pcreg's."""
    code = ("import sys; sys.path[:] = sys.argv[4:]; from pcreg.recording.viewer import send_here; "
            "send_here(sys.argv[1], sys.argv[2], int(sys.argv[3]))")  # the modules this process imports, not the cwd's
    try:
        proc = subprocess.Popen([sys.executable, "-c", code, str(recording), host, str(grpc_port), *sys.path],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                start_new_session=True, preexec_fn=_ends_with_us())
    except OSError as exc:  # no interpreter to run (an embedded Python's sys.executable is empty)
        raise ViewerError(f"could not start {sys.executable or 'a Python interpreter'} to send the recording to the "
                          f"web viewer's server ({exc.strerror or exc})") from None
    try:
        _, err = proc.communicate()
    except BaseException:  # Ctrl-C: the sender stopped, its words dropped
        _stop(proc)
        raise
    if proc.returncode:
        raise ViewerError(f"the recording was not sent to the web viewer's server ({_last_said(err, proc.returncode)})")


def send_here(recording: str, host: str, grpc_port: int) -> None:
    """:func:`_send`'s work, in this process."""
    import warnings

    from rerun.chunk import RrdReader

    from .readback import whole_stream

    with warnings.catch_warnings():  # a file without rerun's footer (an earlier rerun's) is read whole: said, not a problem
        warnings.simplefilter("ignore")
        store = RrdReader(str(recording)).recordings()[0]
    stream = whole_stream(store.application_id, recording_id=store.recording_id)
    stream.connect_grpc(f"rerun+http://{f'[{host}]' if ':' in host else host}:{grpc_port}/proxy")
    stream.log_file_from_path(recording)  # its stores as they are in the file, the blueprint among them
    stream.flush()
    stream.disconnect()


def _wait_listening(proc: subprocess.Popen, log, host: str, ports: tuple[int, ...], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    for port in ports:
        while True:
            if proc.poll() is not None:
                log.seek(0)
                raise ViewerError(f"the web viewer stopped: {_last_said(log.read(), proc.returncode)}")
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
