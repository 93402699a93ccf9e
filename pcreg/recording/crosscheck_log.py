"""Cross-checks (``crosscheck/``): the report, and a cloud cross-check's iterations on the
``crosscheck_iteration`` timeline: :class:`CrosscheckLogger`."""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..outputs import to_json
from .sink import Sink
from .values import display_indices, leaves, plain

__all__ = ["CrosscheckLogger"]


class CrosscheckLogger:
    """Logs cross-checks to a :class:`~pcreg.recording.sink.Sink`; clouds are drawn with at most
    ``max_display_points`` points (Points2D or Points3D by their dimension)."""

    def __init__(self, sink: Sink, *, max_display_points: int = 500) -> None:
        self.sink = sink
        self.max_display_points = int(max_display_points)
        self._parts: dict[str, str] = {}  # a name (an implementation's, a report's key) -> its entity path part

    def part(self, name: str) -> str:
        """The entity path part of ``name``: :func:`~pcreg.recording.entities.path_part`, made unique in this
        recording (a second name with the same part, ``cmd:icp --x 1`` after ``cmd:icp --x=1``, gets ``_2``)."""
        name = str(name)
        if name not in self._parts:
            base = E.path_part(name)
            taken = set(self._parts.values())
            part, n = base, 2
            while part in taken:
                part, n = f"{base}_{n}", n + 1
            self._parts[name] = part
        return self._parts[name]

    def log_crosscheck(self, report: Mapping[str, Any]) -> None:
        """The whole report as JSON text (``crosscheck/report``), a one-line summary on the text log, and
        every finite number in it as Scalars (``crosscheck/{key}``, nested keys joined by '/', each a
        :meth:`part`)."""
        converted = plain(report)
        self.sink.log(E.CROSSCHECK_REPORT, rr.TextDocument(to_json(converted), media_type=rr.MediaType.TEXT))
        found = [(keys, v) for keys, v in leaves(converted) if keys]
        for keys, value in found:
            if math.isfinite(value):
                name = "/".join(keys)
                self.sink.scalar("/".join((E.CROSSCHECK, *map(self.part, keys))), value, name)
        summary = ", ".join(f"{keys[0]}={v:.6g}" for keys, v in found if len(keys) == 1)
        line = f"crosscheck: {summary}" if summary else "crosscheck logged"
        self.sink.log_later(E.LOG, lambda: rr.TextLog(line, level="INFO"))

    def _cloud(self, points: np.ndarray, color: list[int]) -> Any:
        p = np.asarray(points, dtype=np.float64)
        p = p[display_indices(len(p), self.max_display_points)]
        if p.shape[1] == 2:
            return rr.Points2D(p, colors=color, radii=1.5)
        return rr.Points3D(p, colors=color, radii=0.05)

    def log_crosscheck_target(self, points: np.ndarray) -> None:
        """Static at ``crosscheck/target``."""
        self.sink.log(E.CROSSCHECK_TARGET, self._cloud(points, [80, 160, 255]), static=True)

    def log_crosscheck_iteration(self, implementation: str, iteration: int, points: np.ndarray, *,
                                 error: float | None = None, fitness: float | None = None,
                                 inlier_rmse: float | None = None) -> None:
        """At ``iteration`` on the ``crosscheck_iteration`` timeline, which every implementation shares (their
        iterations line up): ``crosscheck/{implementation}/cloud`` and the finite numbers given as
        Scalars (``.../error``, ``.../fitness``, ``.../inlier_rmse``)."""
        sink = self.sink
        sink.set_time(E.CROSSCHECK_TIMELINE, int(iteration))
        try:
            part = self.part(implementation)
            sink.log(f"{E.CROSSCHECK}/{part}/cloud", self._cloud(points, [255, 120, 0]))
            for what, value in (("error", error), ("fitness", fitness), ("inlier_rmse", inlier_rmse)):
                if value is not None and math.isfinite(float(value)):
                    sink.scalar(f"{E.CROSSCHECK}/{part}/{what}", float(value), f"{implementation} {what}")
        finally:
            if sink.frame is None:
                sink.disable_timeline(E.CROSSCHECK_TIMELINE)
            else:  # back to where frame-level data sits (see Sink.set_frame)
                sink.set_time(E.CROSSCHECK_TIMELINE, 0)

