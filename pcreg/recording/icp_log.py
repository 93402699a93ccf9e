"""ICP iterations (``icp/{backend}/``, on the ``icp_iteration`` timeline): :class:`IcpLogger`."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..registration.result import IcpIteration
from .sink import BATCH_SECONDS, Sink
from .values import display_indices

__all__ = ["IcpLogger"]

#: (frame, step): where an iteration is logged; the frame is None before the first frame.
_At = tuple[int | None, int]


@dataclass
class _IcpRows:
    """One backend's ICP iterations, kept until they are sent as columns; each at its (frame, step)."""

    times: list[_At] = field(default_factory=list)
    fitness: list[float] = field(default_factory=list)
    rmse: list[float] = field(default_factory=list)
    drawn: list[_At] = field(default_factory=list)  # the iterations drawn (2-D)
    moving: list[np.ndarray] = field(default_factory=list)
    strips: list[np.ndarray] = field(default_factory=list)
    targets: list[tuple[_At, np.ndarray]] = field(default_factory=list)


class IcpLogger:
    """Logs the iterations of either ICP to a :class:`~pcreg.recording.sink.Sink`.

    The ``icp_iteration`` timeline is a counter per backend that restarts at every frame
    (:meth:`new_frame`) and runs on over pyramid levels. Per iteration: the moving (source) cloud as it
    moves, a subsample of source -> target pairs as LineStrips2D, fitness and inlier RMSE as Scalars; the
    target cloud once per frame and pyramid level. Only 2-D iterations are drawn; series are logged for
    any. The iterations are kept and sent as columns (one message per entity) when a frame starts and
    they span :data:`~pcreg.recording.sink.BATCH_SECONDS`, or at :meth:`send_kept` with ``now``: a
    registration's dozens of iterations cost a few messages, not a hundred.

    ``steps`` (the next step per backend) and ``target_keys`` (the pyramid level and size of the target
    cloud last kept per backend) are the frame's so far.
    """

    def __init__(self, sink: Sink) -> None:
        self.sink = sink
        self.steps: dict[str, int] = {}
        self.target_keys: dict[str, tuple[int, int]] = {}
        self._rows: dict[str, _IcpRows] = {}
        self._since = time.monotonic()  # when the rows kept were last sent

    def new_frame(self) -> None:
        """Restart the steps and the target clouds (a new frame)."""
        self.steps.clear()
        self.target_keys.clear()

    def callback(self, backend: str, *, max_points: int = 300,
                 max_correspondences: int = 200) -> Callable[[IcpIteration], None]:
        """A per-iteration callback for ``backend``; at most ``max_points`` of each cloud and
        ``max_correspondences`` pairs are drawn."""
        backend = str(backend)

        def callback(it: IcpIteration) -> None:
            self.sink.check_open()
            rows = self._rows.setdefault(backend, _IcpRows())
            step = self.steps.get(backend, 0)
            self.steps[backend] = step + 1
            at = (self.sink.frame, step)
            rows.times.append(at)
            rows.fitness.append(float(it.fitness))
            rows.rmse.append(float(it.inlier_rmse))
            src = np.asarray(it.source_points)
            tgt = np.asarray(it.target_points)
            if not (src.ndim == 2 and src.shape[1] == 2 and tgt.ndim == 2 and tgt.shape[1] == 2):
                return
            key = (it.level, len(tgt))
            if self.target_keys.get(backend) != key:
                self.target_keys[backend] = key
                rows.targets.append((at, tgt[display_indices(len(tgt), max_points)].copy()))
            rows.drawn.append(at)
            rows.moving.append(src[display_indices(len(src), max_points)].copy())
            ti = np.asarray(it.target_indices)
            matched = np.flatnonzero(ti >= 0)
            pick = matched[display_indices(len(matched), max_correspondences)]
            rows.strips.append(np.stack([src[pick], tgt[ti[pick]]], axis=1) if len(pick) else np.zeros((0, 2, 2)))

        return callback

    def send_kept(self, *, now: bool = False) -> None:
        """Send the iterations kept, one column per entity, on the sink's thread: when they span
        :data:`~pcreg.recording.sink.BATCH_SECONDS`, or ``now``. Each send is a chunk of its own (rerun does
        not batch columns), so a frame's iterations sent alone made five chunks a frame."""
        if not self._rows or not (now or time.monotonic() - self._since >= BATCH_SECONDS):
            return
        rows_by_backend, self._rows = self._rows, {}
        self._since = time.monotonic()
        self.sink.later(lambda: self._send_columns(rows_by_backend))

    def _send_columns(self, rows_by_backend: dict[str, _IcpRows]) -> None:
        for backend, rows in rows_by_backend.items():
            for what, values, name in (("fitness", rows.fitness, "fitness"), ("inlier_rmse", rows.rmse, "inlier RMSE")):
                path = E.icp_path(backend, what)
                self.sink.once(path, "series", lambda: rr.SeriesLines(names=f"{backend} {name}"))
                self._send(path, rows.times, rr.Scalars.columns(scalars=values), "Scalars")
            if rows.targets:
                times, clouds = zip(*rows.targets)
                self._send_points(E.icp_path(backend, "target"), list(times), list(clouds), [80, 160, 255])
            if rows.drawn:
                self._send_points(E.icp_path(backend, "moving"), rows.drawn, rows.moving, [255, 120, 0])
                # one (N, 2, 2) array of segments: rerun's numpy path (a list of N strips is converted
                # strip by strip, most of the recorder's own time on an ICP-heavy recording); float64, which
                # rerun's stubs do not list at the top level but take
                strips: Any = np.concatenate(rows.strips) if rows.strips else np.zeros((0, 2, 2))
                column = rr.LineStrips2D.columns(strips=strips)
                path = E.icp_path(backend, "correspondences")
                self.sink.once(path, "style", lambda: rr.LineStrips2D.from_fields(colors=[255, 255, 255], radii=0.5))
                self._send(path, rows.drawn, column.partition([len(r) for r in rows.strips]), "LineStrips2D")

    def _send_points(self, path: str, times: list[_At], clouds: list[np.ndarray], color: list[int]) -> None:
        column = rr.Points2D.columns(positions=np.concatenate(clouds)).partition([len(c) for c in clouds])
        self.sink.once(path, "style", lambda: rr.Points2D.from_fields(colors=color, radii=1.5))
        self._send(path, times, column, "Points2D")

    def _send(self, path: str, times: list[_At], columns: Any, archetype: str) -> None:
        """``columns`` at their (frame, step): ``step`` on the ICP timeline, in ``frame`` (at the start of
        the cross-check timeline, as everything of the frame). Rows before the first frame are sent
        alone (see :meth:`send_kept`) and have no frame."""
        frames, steps = zip(*times)
        indexes = [rr.TimeColumn(E.ICP_TIMELINE, sequence=list(steps))]
        if frames[0] is not None:
            indexes += [rr.TimeColumn(E.FRAME_TIMELINE, sequence=list(frames)),
                        rr.TimeColumn(E.CROSSCHECK_TIMELINE, sequence=[0] * len(steps))]
        self.sink.send_columns(path, indexes, columns, archetype=archetype, rows=len(steps))
