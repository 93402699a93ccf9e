"""Deprecated: a run from one label image is :class:`pcreg.runs.run.Run`'s (its folder, opening and
resuming, committing a frame). ``StreamRun`` is kept, with a :class:`DeprecationWarning`, until pcreg 0.4."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .._moved import moved
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

    def learned_after(self, t: int):
        """What the classifier had learned from the stream after frame ``t`` (:meth:`carry_after`'s second), as
        the ``StreamRun`` of before 0.2.0 gave it apart."""
        return Run.carry_after(self, t)[1]


def _stream_run(name: str):
    if name == "StreamRun":
        warnings.warn("pcreg.pipeline.stream_run.StreamRun is deprecated; use pcreg.runs.run.Run (open_key, record, "
                      "carry_after)", DeprecationWarning, stacklevel=3)
        return _StreamRun
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__getattr__ = moved(__name__, {n: "pcreg.runs.files" for n in ("STATE", "STEPS", "CARRY", "CONFIDENCE", "confidence_png")},
                    fallback=_stream_run)
