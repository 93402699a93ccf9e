"""The report page's server: an evaluation's output folder beside its recording, in a browser.

:class:`ReportServer` serves, on one address and port (127.0.0.1 unless told otherwise):

- ``/``: the page (``viz/index.html`` with its CSS and JavaScript under ``/viz/``; no build step);
- ``/report.json``: what the page shows (:func:`pcreg.experiments.reports.page.page_data`) and where the
  recording is served;
- ``/files/NAME``: the folder's figures and text files (those named in the report, nothing else);
- ``/rerun/``: rerun's web viewer, its files fetched from the ``rerun --serve-web`` process
  (:func:`pcreg.recording.viewer.serve_web`) that also serves the recording over gRPC. Served from the
  page's own origin, the embedded viewer's JavaScript handle is reachable from the page, which moves its
  time cursor through the viewer's control API (``WebHandle.viewer_control``) when a row is chosen.
"""

from __future__ import annotations

import io
import ipaddress
import json
import re
import mimetypes
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from ..errors import InputError, PcregError
from ..formats import file_of
from .entities import FRAME_TIMELINE
from .viewer import REUSE_ADDRESS, ViewerError, check_bind, check_port, free_port, serve_web, stop, url_host

__all__ = ["ReportServer", "viz_dir"]

#: Seconds a connection to a local page is kept while the client sends nothing of its request, or reads nothing of
#: an answer (a MiB of it at a time, :data:`_PIECE`): each open connection holds a thread, and one that a client opens
#: and leaves idle is closed after this. A request's head (its line and headers) is read within it too, as a whole.
IDLE_TIMEOUT = 60.0
_PIECE = 1 << 20  # an answer is written a MiB at a time, each within IDLE_TIMEOUT (a large file over a slow link)


class _HeadWithin(io.RawIOBase):
    """A connection's reads, with the head of each request read within one time as a whole (``by``, a monotonic
    time; None once it is read), each read from the socket given what is left of it: bounded read by read alone, a
    client that sends a byte now and then, each within the idle time, held a thread of the server for good."""

    def __init__(self, connection: socket.socket) -> None:
        self._connection = connection
        self.by: float | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        if self.by is not None:
            left = self.by - time.monotonic()
            if left <= 0:
                raise TimeoutError("the request's head was not sent in time")  # http.server closes the connection
            self._connection.settimeout(left)
        return self._connection.recv_into(buffer)


class QuietHandler(BaseHTTPRequestHandler):
    """What pcreg's local pages share: no line per request on the terminal, one way to answer (``HEAD``
    as ``GET`` without the body), a file served with its type, and on a loopback address only the requests
    that name it (:meth:`parse_request`)."""

    def log_message(self, *args) -> None:  # no line per request on the terminal
        pass

    def setup(self) -> None:
        """The connection's reads and writes bounded by :data:`IDLE_TIMEOUT` (read now, when it is accepted): one
        idle past it is closed (http.server passes the timeout over, and the thread ends)."""
        super().setup()
        self.connection.settimeout(IDLE_TIMEOUT)
        self._head = _HeadWithin(self.connection)
        self.rfile = io.BufferedReader(self._head)  # what socketserver made of the socket, read through _HeadWithin

    def handle_one_request(self) -> None:
        """One request, its head read within :data:`IDLE_TIMEOUT` as a whole (:class:`_HeadWithin`)."""
        self._head.by = time.monotonic() + IDLE_TIMEOUT
        super().handle_one_request()

    def parse_request(self) -> bool:
        """The request's line and headers read; a server on a loopback address refuses (403) a request whose
        ``Host`` is another name than ``localhost`` or a loopback address: a page elsewhere whose name it
        points at 127.0.0.1 (DNS rebinding) would read the frames and files served as its own."""
        if not super().parse_request():
            return False
        self._head.by = None  # read: the answer's writes are bounded each by the idle time
        self.connection.settimeout(IDLE_TIMEOUT)
        if len(self.headers.get_all("Host") or ()) > 1:  # which one names the server is not for it to choose
            self.send_error(400, "more than one Host header")
            return False
        host = self.headers.get("Host")
        listening = self.server.server_address  # (host, port, ...) of an IP server
        if host is None or not isinstance(listening, tuple) or not ipaddress.ip_address(listening[0]).is_loopback:
            return True
        try:
            name = (urllib.parse.urlsplit(f"//{host}").hostname or "").rstrip(".")
            local = name == "localhost" or name.endswith(".localhost") or ipaddress.ip_address(name).is_loopback
        except ValueError:  # not an address, or a port that is not a number
            local = False
        if not local:
            self.send_error(403, "this server answers requests for localhost only")
        return local

    def end_headers(self) -> None:
        """Every answer's headers (an error's too) end with ``nosniff``: a browser takes each file as the type it is
        sent as, never guessing another from its bytes (a label name or a text file read as a script)."""
        self.send_header("X-Content-Type-Options", "nosniff")
        super().end_headers()

    def _send(self, status: int, ctype: str, body: bytes, headers: dict | None = None, etag: str | None = None) -> None:
        """An answer; with ``etag`` (what the body was made from), one the browser keeps and asks again for each time
        (``no-cache``: a ``304`` when its ``If-None-Match`` names the same, :meth:`_unchanged`), else one it keeps not."""
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-cache" if etag else "no-store")
        if etag:
            self.send_header("ETag", etag)
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            view = memoryview(body)  # its pieces written without a copy of each
            for i in range(0, len(body), _PIECE):  # each piece within IDLE_TIMEOUT, not the whole of a large file
                self.wfile.write(view[i:i + _PIECE])

    def _unchanged(self, etag: str) -> bool:
        """Whether the browser holds the answer made as ``etag`` says (its ``If-None-Match``, compared weakly as HTTP
        has it: ``W/"..."`` names the same answer, ``*`` any): then a ``304``, sent."""
        held = {t.strip().removeprefix("W/") for t in self.headers.get("If-None-Match", "").split(",")}
        if etag not in held and "*" not in held:
            return False
        self.send_response(304)
        self.send_header("Cache-Control", "no-cache")
        self.send_header("ETag", etag)
        self.end_headers()
        return True

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_GET(self) -> None:  # each page's own
        self._send(404, "text/plain", b"not found\n")

    def _file(self, p: Path) -> None:
        try:
            body = p.read_bytes()
        except OSError:
            return self._send(404, "text/plain", b"not found\n")
        ctype = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
        if ctype.startswith("text/") or ctype in ("application/javascript", "application/json"):
            ctype += "; charset=utf-8"
        self._send(200, ctype, body)


def viz_dir() -> Path:
    """The report page's static files: ``pcreg/_viz`` in an installed wheel, ``viz/`` in a source checkout."""
    here = Path(__file__).resolve().parent.parent
    for candidate in (here / "_viz", here.parent / "viz"):
        if (candidate / "index.html").is_file():
            return candidate
    raise PcregError("the report page's files (viz/) are missing from this installation of pcreg")


#: Connections answered at once, each on a thread of its own: as many as wait to be accepted (a browser opens at most
#: six to one server). One more is answered 503 and closed at once: 5,000 connections opened and left idle held
#: 5,000 threads until each one's :data:`IDLE_TIMEOUT`.
MAX_CONNECTIONS = 128
_BUSY_BODY = b"the server has too many open connections\n"
_BUSY = (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\nX-Content-Type-Options: nosniff\r\n"
         b"Content-Length: %d\r\nRetry-After: 1\r\nConnection: close\r\n\r\n%s" % (len(_BUSY_BODY), _BUSY_BODY))


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = REUSE_ADDRESS
    request_queue_size = 128  # connections waiting to be accepted (socketserver's 5 left a burst of them retrying for seconds)

    def server_activate(self) -> None:
        super().server_activate()
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)  # read when the server starts listening

    def process_request(self, request, client_address) -> None:
        """A thread for the connection while fewer than :data:`MAX_CONNECTIONS` are open; else 503, closed."""
        if not self._slots.acquire(blocking=False):
            try:
                request.settimeout(1.0)  # a few bytes into a new connection's empty buffer: never waits, but bounded
                request.sendall(_BUSY)
            except OSError:
                pass
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()  # no thread started to release it
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def handle_error(self, request, client_address) -> None:
        """A browser that went away (a connection reset or closed while its request was read or answered) is
        passed over; anything else printed as :class:`ThreadingHTTPServer` prints it."""
        if isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError)):
            return
        super().handle_error(request, client_address)


class _Server6(_Server):
    address_family = socket.AF_INET6


def listen(bind: str, web_port: int, handler, *, name: str) -> tuple[ThreadingHTTPServer, threading.Thread, int, str]:
    """A local page's server on ``bind``:``web_port`` (0: a free port) answering with ``handler``, serving
    on a daemon thread called ``name``: ``(server, thread, port, url)``; :class:`~pcreg.errors.InputError` when it
    cannot listen there."""
    host = "127.0.0.1" if bind == "localhost" else bind
    try:
        httpd = (_Server6 if ":" in host else _Server)((host, web_port), handler)
    except OSError as exc:
        raise InputError(f"--web-port {web_port}: cannot listen on {bind} ({exc.strerror or exc})") from None
    port = int(httpd.server_address[1])
    thread = threading.Thread(target=httpd.serve_forever, name=name, daemon=True)
    thread.start()
    return httpd, thread, port, f"http://{url_host(bind)}:{port}/"


class ReportServer:
    """The report page of ``data`` (files from ``folder``) and, with ``recording``, rerun's web viewer and
    the recording's data server; a context manager. ``url`` is the page to open."""

    def __init__(self, folder: str | Path, data: dict, *, recording: str | Path | None = None,
                 bind: str = "127.0.0.1", web_port: int = 9090, grpc_port: int = 9876, viewer: str | None = None,
                 timeout: float = 60.0) -> None:
        self.folder = Path(folder)
        self.data = data
        self.proc: subprocess.Popen | None = None
        self._static = viz_dir()
        self._cache: dict[str, tuple[int, str, bytes, dict]] = {}
        self._lock = threading.Lock()
        probe = check_bind(bind)
        self._probe = probe
        try:
            web_port = web_port or free_port(probe)
        except OSError as exc:
            raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
        if recording is not None and web_port == grpc_port:
            raise InputError(f"--web-port and --grpc-port must differ (both {web_port})")
        check_port("--web-port", web_port, probe, bind)
        self._viewer_port = None
        if recording is not None:
            try:
                grpc_port = grpc_port or free_port(probe)
            except OSError as exc:
                raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
            # rerun's own web server, on a port of its own; the page's server fetches the viewer's files from it
            self._viewer_port = free_port(probe)
            while self._viewer_port in (web_port, grpc_port):
                self._viewer_port = free_port(probe)
            self.proc, _ = serve_web(recording, bind=bind, web_port=self._viewer_port, grpc_port=grpc_port,
                                     viewer=viewer, timeout=timeout, page_port=web_port)
        self.grpc_port = grpc_port if recording is not None else None
        try:
            self._httpd, self._thread, self.port, self.url = listen(bind, web_port, self._handler(), name="pcreg-report")
        except InputError:
            self.close()
            raise

    # -- what the page asks for -------------------------------------------------------------------

    def report_json(self) -> bytes:
        recording = None
        if self.grpc_port is not None:
            recording = {"grpc_port": self.grpc_port, "timeline": FRAME_TIMELINE, "viewer": "/rerun/"}
        return json.dumps({**self.data, "recording": recording}, allow_nan=False).encode()

    def _viewer_file(self, path: str) -> tuple[int, str, bytes, dict]:
        """A file of rerun's web viewer, fetched once from its server (the viewer's .wasm is large). A path of other
        than printable ASCII is none of its files (and no URL to ask for): not found."""
        if not re.fullmatch(r"/[\x21-\x7e]*", path):
            return 404, "text/plain", b"not found\n", {}
        with self._lock:
            if path in self._cache:
                return self._cache[path]
        try:  # not under the lock: one file slow to come holds up no other
            with urllib.request.urlopen(f"http://{url_host(self._probe)}:{self._viewer_port}{path}",
                                        timeout=60) as r:
                body = r.read()
                answer = (r.status, r.headers.get("Content-Type", "application/octet-stream"), body,
                          {k: v for k, v in r.headers.items() if k.lower() == "rerun-final-length"})
        except urllib.error.HTTPError as exc:
            return exc.code, "text/plain", b"not found\n", {}
        except OSError:
            return 502, "text/plain", b"the web viewer does not answer\n", {}
        if answer[0] == 200:
            with self._lock:
                answer = self._cache.setdefault(path, answer)
        return answer

    def _handler(self):
        server = self
        static = {f.name: f for f in self._static.iterdir() if f.is_file()}
        inside = Path(server.folder).resolve()  # a name the report lists, and a file of its folder when served
        files = {n: server.folder / n for n in (*server.data.get("figures", []), *server.data.get("files", []))
                 if file_of(Path(server.folder) / n, inside)}

        class Handler(QuietHandler):
            def do_GET(self) -> None:
                path = self.path.split("?", 1)[0].split("#", 1)[0]
                try:
                    if path in ("/", "/index.html"):
                        return self._file(static["index.html"])
                    if path.startswith("/viz/") and path[5:] in static:
                        return self._file(static[path[5:]])
                    if path == "/report.json":
                        return self._send(200, "application/json", server.report_json())
                    name = urllib.parse.unquote(path[7:]) if path.startswith("/files/") else None
                    # the page asks for encodeURIComponent(name); a file replaced since by a link out or a pipe: not served
                    if name in files and file_of(files[name], inside):
                        return self._file(files[name])
                    if path.startswith("/rerun/") and server._viewer_port is not None:
                        return self._send(*server._viewer_file("/" + path[7:]))
                    self._send(404, "text/plain", b"not found\n")
                except (BrokenPipeError, ConnectionResetError):  # the browser went away
                    pass

        return Handler

    # -- life -------------------------------------------------------------------------------------

    def wait(self) -> None:
        """Serve until interrupted (KeyboardInterrupt), or until the recording's server stops (ViewerError)."""
        if self.proc is None:
            self._thread.join()
            return
        self.proc.wait()
        if self.proc.returncode not in (0, -15):
            raise ViewerError(f"the web viewer stopped (exit code {self.proc.returncode})")

    def close(self) -> None:
        httpd = getattr(self, "_httpd", None)
        if httpd is not None:
            httpd.shutdown()
            httpd.server_close()
        if self.proc is not None:
            stop(self.proc)

    def __enter__(self) -> "ReportServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
