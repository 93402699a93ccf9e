"""The run's configuration and its text log (``config``, ``log``): :class:`TextLogger`."""

from __future__ import annotations

import json
from typing import Any

import rerun as rr

from pcreg.recording import entities as E

from ..outputs import to_json
from .sink import Sink
from .values import plain

__all__ = ["TextLogger", "LEVELS"]

#: The text log's levels (``WARNING`` is read as ``WARN``).
LEVELS = frozenset({"TRACE", "DEBUG", "INFO", "WARN", "ERROR", "CRITICAL"})


class TextLogger:
    """Logs text to a :class:`~pcreg.recording.sink.Sink`: the ``config`` document and lines on ``log``."""

    def __init__(self, sink: Sink) -> None:
        self.sink = sink

    def log_config(self, config: Any) -> None:
        """The ``config`` document (static, JSON) now, and a ``config: ...`` line on the log."""
        text = to_json(plain(config))
        self.sink.log(E.CONFIG, rr.TextDocument(text, media_type=rr.MediaType.TEXT), static=True)
        line = "config: " + json.dumps(plain(config), default=str)
        self.sink.log_later(E.LOG, lambda: rr.TextLog(line, level="INFO"))

    def log_text(self, text: str, level: str = "INFO") -> None:
        """A line at ``level`` (checked here: a ValueError names an unknown one)."""
        level = str(level).upper()
        if level == "WARNING":
            level = "WARN"
        if level not in LEVELS:
            raise ValueError(f"unknown log level {level!r}")
        self.sink.log_later(E.LOG, lambda: rr.TextLog(str(text), level=level))

    def log_failure(self, text: str) -> None:
        """An ERROR line."""
        self.sink.log_later(E.LOG, lambda: rr.TextLog(str(text), level="ERROR"))
