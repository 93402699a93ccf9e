"""Deprecated: a run from one label image is :class:`pcreg.runs.run.Run`'s (its folder, opening and
resuming, committing a frame). ``StreamRun`` is kept, with a :class:`DeprecationWarning`, until pcreg 0.4."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..runs.run import Run

__all__: list[str] = []  # StreamRun: deprecated, see the module


class _StreamRun(Run):
    """``StreamRun(frames, labels, out, config, truth=None, identity=None)`` as before, over :class:`Run`."""

    def __init__(self, frames, labels: np.ndarray, out: Path, config, truth=None, identity: dict | None = None) -> None:
        super().__init__(frames, out, identity, truth=truth)
        self.labels, self.config = labels, config

    def start(self, *, force: bool = False) -> int:
        """As :meth:`pcreg.runs.run.Run.open_key` with the key frame's labels given when made."""
        return self.open_key(self.labels, force=force)

    def carry_after(self, t: int):
        """``(carry, learned)`` frame ``t`` left, as 0.2.0's gave them (:meth:`pcreg.runs.run.Run.carry_after` adds the
        key frame's scene)."""
        return Run.carry_after(self, t)[:2]


def __getattr__(name: str):
    if name == "StreamRun":
        warnings.warn("pcreg.pipeline.stream_run.StreamRun is deprecated; use pcreg.runs.run.Run (open_key, record, "
                      "carry_after)", DeprecationWarning, stacklevel=2)
        return _StreamRun
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
