"""The frames a review shows (:class:`FrameImages`): a folder's read when asked for, a video's decoded by a thread into
a cache folder of JPEGs, kept for the next review."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError, OutputError
from .outputs import atomic_write_bytes, remove_leftovers

__all__ = ["FrameImages"]


class FrameImages:
    """The frames of a review's source, RGB, by position: a folder's read when asked for; a video's
    decoded by a thread into ``cache`` (JPEG, one file a frame, kept for the next review), each asked for
    waited for until the decoding reaches it (without ``cache``, a video is only read straight through,
    by :meth:`frames`). The thread decodes in order from the first frame not cached; for a frame asked
    for behind it, or far enough ahead (:attr:`JUMP`, :attr:`RATIO`), it starts again from the video's
    start, converting nothing before that frame (FFmpeg's decoding alone); the frames passed over are
    filled in afterwards. The cache folder holds at most half of what its disk has free plus what it holds already
    when the review starts (the other half left to what else writes there: a ``pcreg run`` beside it, which a review
    filling the disk had stopped); once that is reached, or the disk refuses a file, the decoding ahead stops, said
    once on stderr, and only the frames asked for are decoded and written, going on from where the decoding is when
    they lie just ahead of it. A frame the disk refuses is tried again when asked for again. ``close()`` stops the
    thread; a context manager."""

    #: A frame asked for ahead of the decoding is skipped to (decoding again from the start, converting
    #: nothing before it) when that costs less than going on: converting a frame and encoding its JPEG take
    #: about twice as long as decoding it (720p H.264: 4.7 ms to decode, 14.6 ms with both), so when the
    #: frame is more than JUMP frames ahead and ``frame < RATIO * (frame - decoding)``.
    JUMP = 8
    RATIO = 3.0

    def __init__(self, review: Any, cache: Path | None = None) -> None:  # a pcreg.review.RunReview
        from .datasets.sources import FolderFrames, Selection, open_frames

        self.review = review
        sel = review.selection or {}
        self._frames = open_frames(review.source, Selection(sel.get("start", 0), sel.get("stop"), sel.get("every", 1)))
        self.where = self._frames.where if isinstance(self._frames, FolderFrames) else None  # frame t's file (None: a video's)
        self._cond = threading.Condition()
        self._stop = False
        self._failed: str | None = None
        self._thread: threading.Thread | None = None
        self._wanted: dict[int, int] = {}  # the frames asked for, each by how many readers wait for it
        self.cache = cache
        if review.kind == "video" and cache is not None:
            import os
            import shutil

            cache.mkdir(parents=True, exist_ok=True)
            remove_leftovers(cache, lambda name: name.endswith(".jpg"))  # a killed review's half-written frames
            there = set(os.listdir(cache))
            self._have = [f"{s}.jpg" in there for s in review.stems]
            held = sum((cache / name).stat().st_size for name in there if name.endswith(".jpg") and not name.startswith("."))
            self._budget = max(0, (shutil.disk_usage(cache).free + held) // 2 - held)  # what this review may add
            self._written = 0
            self._ahead = True  # decoding ahead of the frames asked for, until the budget is spent
            self._missed: dict[int, str] = {}  # frames asked for that the disk refused, and why
            self._thread = threading.Thread(target=self._decode, name="pcreg-review-decode", daemon=True)
            self._thread.start()

    def _path(self, t: int) -> Path:
        assert self.cache is not None
        return self.cache / f"{self.review.stems[t]}.jpg"

    def _next_start(self) -> int | None:
        """Where the decoding starts next: the first frame asked for that is not cached, else, decoding ahead, the
        first not cached (None: all are, or the review ends); with the budget spent, waits for a frame asked for."""
        with self._cond:
            while True:
                asked = self._asked()
                if asked is not None or self._stop:
                    return asked
                if self._ahead:
                    return next((t for t, have in enumerate(self._have) if not have), None)
                self._cond.wait()

    def _asked(self) -> int | None:
        """The first frame asked for that is neither cached nor refused (under the lock)."""
        return min((w for w in self._wanted if not self._have[w] and w not in self._missed), default=None)

    def _go_on(self, t: int) -> bool:
        """After frame ``t``: whether the decoding goes on from there. A frame asked for behind it, or far enough ahead
        (:attr:`JUMP`, :attr:`RATIO`), is started at again; with the budget spent and nothing asked for, the decoder
        waits where it is for the next frame asked for (the page asks for a frame and its neighbours)."""
        with self._cond:
            while True:
                w = self._asked()
                if w is not None:
                    return not (w < t or (w > t + self.JUMP and w < self.RATIO * (w - t)))
                if self._ahead or self._stop:
                    return not self._stop
                self._cond.wait()

    def _keep(self, t: int, image: np.ndarray) -> None:
        """Frame ``t`` (RGB) written to the cache as JPEG: decoded ahead, within the budget (a frame that would spend
        it stops the decoding ahead); asked for, whatever the budget. A frame the disk refuses stops the decoding
        ahead too, its half-written file removed; asked for, its reason is what :meth:`__getitem__` raises."""
        import cv2

        data = cv2.imencode(".jpg", image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()
        with self._cond:
            wanted = t in self._wanted
        if not wanted and self._written + len(data) > self._budget:
            return self._spent(f"it holds half of what its disk had free ({self._budget / 2**20:.1f} MiB more)")
        path = self._path(t)
        try:
            atomic_write_bytes(path, data)  # a temporary file of its own, removed if the disk refuses it
        except OutputError as exc:
            said = str(exc)
            with self._cond:
                if wanted:
                    self._missed[t] = said
                self._cond.notify_all()
            return self._spent(f"its disk refused a frame ({said})")
        self._written += len(data)
        with self._cond:
            self._have[t] = True
            self._cond.notify_all()

    def _spent(self, why: str) -> None:
        """Stop decoding ahead (:meth:`_keep`), said once on stderr."""
        import sys

        if self._ahead:
            sys.stderr.write(f"pcreg: note: the review's frame cache {self.cache}: {why}; frames are decoded as they "
                             "are asked for from here on\n")
        self._ahead = False

    def _decode(self) -> None:
        n = len(self.review.names)
        try:
            while not self._stop:
                first = self._next_start()
                if first is None:
                    return
                decoded = self._frames.frames(first)
                t = first - 1
                try:
                    for frame in decoded:
                        t = frame.position
                        if self._stop or t >= n:
                            break
                        with self._cond:
                            keep = not self._have[t] and (self._ahead or t in self._wanted)
                        if keep:
                            self._keep(t, frame.image)
                        if not self._go_on(t):
                            break  # start again at the frame asked for
                    else:
                        if t < n - 1:  # the video ended before the run's frames did
                            self._failed = f"{self.review.source}: ends before the run's frame {self.review.names[t + 1]}"
                            return
                finally:
                    getattr(decoded, "close")()  # the generator's: the video file closed now
        except (InputError, OSError) as exc:
            self._failed = str(exc)
        finally:
            with self._cond:
                self._stop = True
                self._cond.notify_all()

    def __getitem__(self, t: int) -> np.ndarray:
        if not 0 <= t < len(self.review.names):
            raise IndexError(t)
        if self._thread is None:
            from .registration.clouds import load_image_and_alpha

            if self.where is None:
                raise ValueError("a video's frames by position need a cache folder (or read them in order: frames())")
            return load_image_and_alpha(self.where(t))[0]  # as load_image converts it, without its warnings
        with self._cond:
            if not self._have[t]:
                self._wanted[t] = self._wanted.get(t, 0) + 1
                self._missed.pop(t, None)  # asked for again: tried again
                self._cond.notify_all()
                try:
                    self._cond.wait_for(lambda: self._have[t] or self._stop or t in self._missed)
                finally:
                    self._wanted[t] -= 1
                    if not self._wanted[t]:
                        del self._wanted[t]
            missed, decoded = self._missed.get(t), self._have[t]
        path = self._path(t)
        if not path.is_file():
            if decoded:  # written, then removed (the cache folder deleted while the page is served)
                raise InputError(f"{path}: frame {self.review.names[t]} decoded, then removed from the review's folder of "
                                 "decoded frames while the page was served; start pcreg view again to decode it again")
            raise InputError(missed or self._failed or f"{self.review.source}: frame {self.review.names[t]} was not decoded")
        from .formats import read_image_file

        return np.ascontiguousarray(read_image_file(path)[:, :, ::-1])

    def frames(self):
        """Every frame in order, (position, RGB image): a video decoded straight through (one that ends before the
        run's last frame, cut since the run, an :class:`~pcreg.errors.InputError`)."""
        if self.review.kind == "folder":
            for t in range(len(self.review.names)):
                yield t, self[t]
            return
        n, last = len(self.review.names), -1
        for frame in self._frames.frames(0):
            if frame.position >= n:
                return
            last = frame.position
            yield last, frame.image
        if last < n - 1:  # the video has lost frames since the run (cut, or replaced)
            raise InputError(f"{self.review.source}: ends before the run's frame {self.review.names[last + 1]}")

    def close(self) -> None:
        """Stop the decoding: at once between frames; one decoding its way to a frame far into a long video
        cannot be stopped midway and is left to end with the process (a daemon thread), after 5 s."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def __enter__(self) -> "FrameImages":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
