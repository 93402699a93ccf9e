"""The recorder that records nothing, so that the experiments have one code path with or without ``--record``.

Like pycpd's ``callback=lambda **kw: None``: an experiment takes a recorder and calls it; without a
recording it is :data:`NULL_RECORDER`, whose every ``log_*`` call, ``set_frame`` and ``flush`` does
nothing and whose :meth:`NullRecorder.icp_callback` is ``None`` (the ICP then runs with no callback at
all). ``enabled`` tells the two apart where a caller must plan differently (a recording is written by one
process, in frame order). This module imports nothing: making one costs nothing.
"""

from __future__ import annotations

from typing import Any, Callable

__all__ = ["NULL_RECORDER", "NullRecorder"]


def _nothing(*args: Any, **kwargs: Any) -> None:
    return None


class NullRecorder:
    """Stands for a :class:`pcreg.recording.recorder.Recorder` when nothing is recorded."""

    enabled = False

    def icp_callback(self, backend: str, **kwargs: Any) -> Callable | None:
        """No callback: the ICP is not slowed by one that would drop every iteration."""
        return None

    def __getattr__(self, name: str) -> Callable[..., None]:
        if name.startswith("log_") or name in ("set_frame", "flush"):
            return _nothing
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    def __repr__(self) -> str:
        return "NULL_RECORDER"


NULL_RECORDER = NullRecorder()
