"""The review page's server: a ``pcreg run`` output's frames with their labels drawn over them, in a browser.

:class:`ReviewServer` serves, on one address and port (127.0.0.1 unless told otherwise):

- ``/``: the page (``viz/review.html`` with its CSS and JavaScript under ``/viz/``; no build step);
- ``/review.json``: the frames (name, key frame or not, predicted error, error against the truth), the suggested frames, whether
  there is a confidence, whether any step predicts its classes' IoU (``ious``), where the video skips frames by its times (``gaps``: the note, the places and frames
  missing; None without one), the notes of what reading the frames met (``notes``: run.json's lines, transparent
  pixels or a turn to interlaced; ``[]`` without one), the class table (each known class's name, colour and whether the run's frames show it,
  for the legend) and the frames' size; read again when the run's run.json or steps.jsonl changed since (a run still
  being written: the page reloaded shows the frames labelled since, :meth:`ReviewServer.current`);
- ``/overlay/T.jpg``: frame ``T`` (its position in the run) with its labels drawn over it
  (:func:`pcreg.review.overlay`), rendered when asked for and kept for the next time (a few hundred), drawn again
  when its label image or confidence map changes (by their time and size; the browser asks again each time with the
  picture's ETag, answered 304 while they are the same);
- ``/frame/T.jpg``: frame ``T`` as it is.

Nothing is rendered ahead: the page asks for the frame shown and its neighbours, so a long run opens at
once. A video's frames come from :class:`pcreg.review.FrameImages` (decoded once into the run's
``.pcreg-review/`` folder, under a name of the video's path, size and time; the folders of the video's earlier
versions removed).
"""

from __future__ import annotations

import hashlib
import json
import re
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, PcregError
from .report import QuietHandler, listen, viz_dir
from .viewer import check_bind, check_port, free_port

__all__ = ["ReviewServer"]

_KEEP = 256  # rendered JPEGs kept in memory


def _video_key(path: Path) -> str:
    """The cache folder's name for a video: its file's path, size and time of change, so that a run
    made again on another video never shows the frames decoded from the first."""
    st = path.stat()
    return "frames-" + hashlib.sha1(f"{path.resolve()}\0{st.st_size}\0{st.st_mtime_ns}".encode()).hexdigest()[:12]


_KEYED = re.compile(r"frames-[0-9a-f]{12}")  # a folder _video_key names
_DECODED = re.compile(r"[0-9]+\.jpg|\.[0-9]+\.jpg\.[0-9]+\.tmp")  # a frame FrameImages wrote there, or was writing


def _remove_others(cache: Path) -> None:
    """Remove the folders beside ``cache`` that the review decoded earlier versions of the run's video into: named as
    :func:`_video_key` names them and holding nothing but the frames :class:`pcreg.review.FrameImages` writes (a
    folder holding anything else, or that cannot be removed, is left as it is). Never read again, each would
    keep a whole video's frames as JPEG."""
    try:
        others = list(cache.parent.iterdir())
    except OSError:
        return
    for other in others:
        if other.name == cache.name or not _KEYED.fullmatch(other.name) or other.is_symlink() or not other.is_dir():
            continue
        try:
            files = list(other.iterdir())
            if all(_DECODED.fullmatch(f.name) and not f.is_symlink() and f.is_file() for f in files):
                for f in files:
                    f.unlink()
                other.rmdir()
        except OSError:  # gone meanwhile, or not ours to remove: left
            continue


def _stat(path: Path | None) -> tuple[int, int] | None:
    """``path``'s (mtime_ns, size); None when there is no such file."""
    try:
        st = path.stat() if path is not None else None
    except OSError:
        return None
    return None if st is None else (st.st_mtime_ns, st.st_size)


def _run_stamp(folder: Path) -> tuple:
    """The (mtime_ns, size) of a run's run.json and steps.jsonl (:func:`_stat`)."""
    from ..runs.files import STATE, STEPS

    return _stat(folder / STATE), _stat(folder / STEPS)


def _number(name: str, suffix: str, n: int) -> int | None:
    """The frame number of a request's file name (``NUMBER`` then ``suffix``, ASCII digits only) when it is one of
    ``n`` frames, else None: a name of thousands of digits is no frame (not ``int()``'s limit raised in the server),
    nor one with a leading zero (``01.jpg`` is not a second name of ``1.jpg``)."""
    digits = name[:-len(suffix)]
    if not name.endswith(suffix) or not digits.isascii() or not digits.isdigit() or len(digits) > len(str(n)) \
            or (digits.startswith("0") and digits != "0"):
        return None
    t = int(digits)
    return t if t < n else None


class ReviewServer:
    """The review page of the run output ``review`` (:func:`pcreg.review.read_review`); a context
    manager. ``url`` is the page to open."""

    def __init__(self, review, *, bind: str = "127.0.0.1", web_port: int = 9090, cache: Path | None = None) -> None:
        self.review = review
        probe = check_bind(bind)
        try:
            web_port = web_port or free_port(probe)
        except OSError as exc:
            raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
        check_port("--web-port", web_port, probe, bind)
        self._tmp: Any = None  # a tempfile.TemporaryDirectory, made when the run's folder is not writable
        self._cache = cache  # None: a video's decoded frames in the run's folder, by the video's path
        self.images = self._frame_images(review)
        self._read = _run_stamp(review.folder)  # the run's files as the review was read
        self._static = viz_dir()
        self._rendered: OrderedDict[tuple[str, int, tuple], bytes] = OrderedDict()
        self._lock = threading.Lock()
        self._shown: frozenset[int] | None = None
        self._shape: tuple[int, ...] | None = None  # the run's labels' size, once read (): none can be read
        try:
            self._httpd, self._thread, self.port, self.url = listen(bind, web_port, self._handler(), name="pcreg-review")
        except InputError:
            self.images.close()
            raise

    def _frame_images(self, review) -> Any:
        """The frames of ``review``'s source (:class:`pcreg.review.FrameImages`): a video's decoded into the run's
        ``.pcreg-review/`` folder under a name of the video's path, size and time (the folders of its other versions
        removed), or into a folder that lasts as long as the server where the run's folder is not writable."""
        from ..review import CACHE, FrameImages

        cache = self._cache
        if review.kind == "video" and cache is None:
            cache = review.folder / CACHE / _video_key(review.source)
            try:
                cache.mkdir(parents=True, exist_ok=True)
            except OSError:  # a run's folder that is not writable: the decoded frames last as long as the server
                import tempfile

                if self._tmp is None:
                    self._tmp = tempfile.TemporaryDirectory(prefix="pcreg-review-")
                cache = Path(self._tmp.name) / _video_key(review.source)
                cache.mkdir(exist_ok=True)
            else:
                _remove_others(cache)
        return FrameImages(review, cache)

    # -- what the page asks for -------------------------------------------------------------------

    def current(self) -> Any:
        """The run's review as its files are now (a :class:`pcreg.review.RunReview`): read again when its run.json or
        steps.jsonl changed since it was read, a run that ``pcreg run`` goes on writing while the page is served (a
        reload of the page shows the frames labelled since; a run started over, on its source or another, shows as
        it is now); the review as it was when the new one cannot be read."""
        from ..review import read_review

        with self._lock:
            stamp = _run_stamp(self.review.folder)
            if stamp == self._read:
                return self.review
            self._read = stamp
            try:
                new = read_review(self.review.folder)
            except InputError:
                return self.review
            self.images.close()  # its decoding stopped before the next one writes the cache folder
            self.images = self._frame_images(new)
            self.review, self._shown = new, None
            return new

    def _frame(self, t: int):
        """Frame ``t`` (RGB), from the frames as they are now: one asked for while a reload swapped them
        (:meth:`current`, which stops the earlier ones' decoding) is asked of the new ones."""
        images = self.images
        try:
            return images[t]
        except InputError:
            with self._lock:  # held by a reload until the new frames are in place
                now = self.images
            if now is images:
                raise
            return now[t]

    def review_json(self) -> bytes:
        from ..review import LOW_CONFIDENCE, shown_classes

        r = self.current()
        with self._lock:
            if self._shown is None:  # the label files read once, when the page first asks
                self._shown = frozenset(shown_classes(r))
            shown = self._shown
        frames = [{"name": n, "key": t in r.keys, "error": r.errors[t], "no_confidence": self._no_confidence(r, t),
                   "truth_error": None if (truth := r.truth_at(t)) is None else truth.error} for t, n in enumerate(r.names)]
        suggested = [{"frame": t, "name": r.names[t], "error": e} for t, e in r.suggested]
        return json.dumps({
            "folder": str(r.folder), "source": str(r.source), "kind": r.kind, "frames": frames,
            "suggested": suggested, "confidence": r.confidence, "low_confidence": LOW_CONFIDENCE,
            "ious": any(i is not None for i in r.ious),
            "classes": [{"id": c.id, "name": c.name, "colour": list(c.colour), "shown": c.id in shown}
                        for c in r.table.known],
            "unknown": {"id": r.table.unknown, "name": r.table.unknown_class.name},
            "gaps": None if r.gaps is None else {"note": r.gaps_note(), "places": r.gaps["places"],
                                                 "missing": r.gaps["missing"]},
            "notes": list(r.kept_notes()),
        }, allow_nan=False).encode()

    def _no_confidence(self, r, t: int) -> str | None:
        """The confidence map that frame ``t`` lacks in a run with ``--confidence`` (``confidence/STEM.png``,
        drawn without the hatching), None when it has one or needs none."""
        from ..runs.files import CONFIDENCE

        if not r.confidence or t in r.keys or r.confidence_path(t) is not None:
            return None
        return f"{CONFIDENCE}/{r.stems[t]}.png"

    def class_json(self, t: int) -> bytes:
        """Frame ``t``'s classes: each one's share of the frame and predicted IoU
        (:func:`pcreg.review.class_figures`)."""
        from ..review import class_figures

        return json.dumps(class_figures(self.review, t, self._labels_shape()), allow_nan=False).encode()

    def _labels_shape(self) -> tuple[int, ...] | None:
        """The size of the run's labels, its first key frame's (read once; None where they cannot be read): a frame's
        label image of another size (written over by hand) has no figures, as its overlay has no picture."""
        from ..export import read_labels

        r = self.review
        with self._lock:
            if self._shape is None:
                try:
                    self._shape = read_labels(r.labels_path(min(r.keys)), r.table).shape if r.keys else ()
                except InputError:
                    self._shape = ()
            return self._shape or None

    def stamp(self, what: str, t: int) -> tuple:
        """What frame ``t``'s picture ``what`` is drawn from, as it is now: for an overlay its label image's and
        confidence map's (mtime_ns, size) (None: no such file), so that one replaced while the page is served is
        drawn again; the frame's own file (a folder's) for both."""
        r, where = self.review, self.images.where
        frame = () if where is None else (_stat(where(t)),)
        return (_stat(r.labels_path(t)), _stat(r.confidence_path(t)), *frame) if what == "overlay" else frame

    def gone(self, t: int, what: str = "overlay") -> bool:
        """Whether a file frame ``t``'s picture ``what`` (or its class figures: ``overlay``) is drawn from is not
        there: its label image, or the frame's own file (a folder's)."""
        where = self.images.where
        return (what == "overlay" and not self.review.labels_path(t).is_file()) or (where is not None and not where(t).is_file())

    def image(self, what: str, t: int, stamp: tuple | None = None) -> bytes:
        """Frame ``t`` as JPEG: ``what`` is ``overlay`` (its labels drawn over it) or ``frame``; kept, and drawn
        again when its files change (``stamp``: :meth:`stamp`, taken before they are read)."""
        import cv2

        from ..review import read_overlay

        key = (what, t, self.stamp(what, t) if stamp is None else stamp)
        with self._lock:
            if key in self._rendered:
                self._rendered.move_to_end(key)
                return self._rendered[key]
        image = self._frame(t)
        drawn = read_overlay(self.review, t, image) if what == "overlay" else image
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(drawn[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise PcregError(f"frame {self.review.names[t]} does not encode as JPEG")
        body = buf.tobytes()
        with self._lock:
            self._rendered[key] = body
            while len(self._rendered) > _KEEP:
                self._rendered.popitem(last=False)
        return body

    def _handler(self):
        server = self
        static = {f.name: f for f in self._static.iterdir() if f.is_file()}

        class Handler(QuietHandler):
            def do_GET(self) -> None:
                path = self.path.split("?", 1)[0].split("#", 1)[0]
                try:
                    if path in ("/", "/index.html", "/review.html"):
                        return self._file(static["review.html"])
                    if path.startswith("/viz/") and path[5:] in static:
                        return self._file(static[path[5:]])
                    if path == "/review.json":
                        return self._send(200, "application/json", server.review_json())
                    what, _, name = path.strip("/").partition("/")
                    n = len(server.review.names)
                    if what == "classes" and (t := _number(name, ".json", n)) is not None:
                        try:
                            body = server.class_json(t)
                        except (InputError, OSError) as exc:
                            return self._unreadable(exc, server.gone(t))
                        return self._send(200, "application/json", body)
                    if what in ("overlay", "frame") and (t := _number(name, ".jpg", n)) is not None:
                        stamp = server.stamp(what, t)
                        etag = '"' + hashlib.sha1(repr((what, t, stamp)).encode()).hexdigest()[:16] + '"'
                        if self._unchanged(etag):
                            return None
                        try:
                            body = server.image(what, t, stamp)
                        except (InputError, OSError) as exc:
                            return self._unreadable(exc, server.gone(t, what))
                        return self._send(200, "image/jpeg", body, etag=etag)
                    self._send(404, "text/plain", b"not found\n")
                except IndexError:  # a frame past the run's end, the run read again shorter (--force) while asked for
                    self._send(404, "text/plain", b"not found: the run holds fewer frames now (reload the page)\n")
                except (BrokenPipeError, ConnectionResetError):  # the browser went away
                    pass

            def _unreadable(self, exc: Exception, gone: bool) -> None:
                """Why a frame cannot be shown, its one line (a file name that is not UTF-8 shown with '?'): a 404
                where a file it is drawn from is ``gone``, else a 500."""
                self._send(404 if gone else 500, "text/plain; charset=utf-8", f"{exc}\n".encode(errors="replace"))

        return Handler

    # -- life -------------------------------------------------------------------------------------

    def wait(self) -> None:
        """Serve until interrupted (KeyboardInterrupt)."""
        self._thread.join()

    def close(self) -> None:
        httpd = getattr(self, "_httpd", None)
        if httpd is not None:
            httpd.shutdown()
            httpd.server_close()
        self.images.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> "ReviewServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
