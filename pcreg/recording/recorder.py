"""Rerun recordings (.rrd) of every stage: :class:`Recorder`, which implements
:class:`~pcreg.recording.interface.RecorderProtocol` by handing each call to the logger of its kind.

The recording package is the only part of pcreg that imports rerun. Its parts that write:
:mod:`~pcreg.recording.sink` (the file, the thread that writes it, images' encoding) and one logger a kind
of log, each a small class over the sink: :mod:`~pcreg.recording.text_log` (configuration and text log),
:mod:`~pcreg.recording.pair_log` (a registration pair's images, clouds and transforms),
:mod:`~pcreg.recording.icp_log` (ICP iterations), :mod:`~pcreg.recording.dense_log` (dense fields),
:mod:`~pcreg.recording.evaluation_log` (label maps and error rates) and
:mod:`~pcreg.recording.crosscheck_log` (cross-checks). The others that import rerun:
:mod:`pcreg.recording.blueprint` builds layouts (``rerun.blueprint``); :mod:`pcreg.recording.readback`
and :mod:`pcreg.recording.viewer` read recordings (``rerun.chunk.RrdReader``) and drive the viewer;
:mod:`pcreg.recording.staging` copies recordings (their chunks, unchanged, or moved under a label) into the
file a viewer opens.

A :class:`Recorder` writes to its file as it goes, so a run that is interrupted leaves a recording
that reads back up to where it stopped. Entity paths and timelines are named in
:mod:`pcreg.recording.entities`. The recording holds its kind (which command made it) as a property, and
when it closes, the blueprint of that kind built from what was logged (:mod:`pcreg.recording.blueprint`),
so that every view it opens with has data.

Usage::

    with Recorder("out/run.rrd", force=True) as rec:
        rec.log_config({"backend": "reference"})
        for i, (reference, moving) in enumerate(pairs):
            rec.set_frame(i)
            result = register(reference, moving, callback=rec.icp_callback("reference"))
            rec.log_images(reference=reference, moving=moving)
            rec.log_transform(result.matrix)

Cost: what is logged is built, encoded (images as JPEG, quality 60 by default) and logged on the
recorder's own thread; the calling thread only checks and copies it. Clouds and label maps are
subsampled for display, and each frame's image is stored once (:mod:`~pcreg.recording.pair_log`). 100
recorded 640x480 pairs of ``pcreg evaluate sequence`` take about 9 MB (CamVid) to 14 MB (synthetic noise
textures), and recording adds 3-9% to their time on a quiet 2-CPU machine, more when other work holds a
core (``tools/bench_recording.py`` measures both; the benchmarks page breaks the size down). The file is
written by rerun's own thread as data arrives (within about a second,
:data:`~pcreg.recording.sink.BATCH_SECONDS`); :meth:`Recorder.flush` forces it.
"""

from __future__ import annotations

import os
from pathlib import Path
import traceback
from typing import Any, Callable, Literal, Mapping

import numpy as np

from ..registration.result import IcpIteration
from .crosscheck_log import CrosscheckLogger
from .dense_log import DenseLogger
from .evaluation_log import EvaluationLogger
from .icp_log import IcpLogger
from .interface import RecorderProtocol
from .pair_log import PairLogger
from .sink import BATCH_SECONDS, DEFAULT_JPEG_QUALITY, Sink, remove_made_folders
from .text_log import TextLogger

__all__ = ["Recorder", "open_recording", "DEFAULT_JPEG_QUALITY", "BATCH_SECONDS"]


def _kind(kind: str | None, blueprint: bool | str) -> str | None:
    """The kind of recording from ``kind`` and ``blueprint`` (a kind name there sets it); checked."""
    from pcreg.recording.blueprint import KINDS

    if isinstance(blueprint, str) and blueprint != "default":
        if kind is not None and kind != blueprint:
            raise ValueError(f"kind={kind!r} and blueprint={blueprint!r} disagree")
        kind = blueprint
    if kind is not None and kind not in KINDS:
        raise ValueError(f"unknown kind of recording {kind!r} (choose from {', '.join(KINDS)})")
    return kind


def open_recording(path: str | os.PathLike | None, *, name: str, raw: bool = False, force: bool = False,
                   layout: bool | str = True, classes: Any = None, inputs: tuple = ()):
    """A :class:`Recorder` writing ``path`` (``name``: the recording's; ``raw``: images lossless; ``force``:
    overwrite; ``layout``: its ``blueprint``; ``classes``: its class table), or, with no path, the null recorder
    in a null context. A ``path`` that is one of the command's ``inputs`` is refused, ``force`` or not."""
    import contextlib

    from ..outputs import check_not_input
    from .null import NULL_RECORDER

    if not path:
        return contextlib.nullcontext(NULL_RECORDER)
    check_not_input(path, inputs)
    return Recorder(path, recording_name=name, raw_images=raw, force=force, blueprint=layout, classes=classes)


#: How the :class:`Recorder` makes each of its loggers, by attribute name.
_LOGGERS: dict[str, Callable[["Recorder"], Any]] = {
    "text": lambda rec: TextLogger(rec.sink),
    "pairs": lambda rec: PairLogger(rec.sink, max_display_points=rec._max_display_points),
    "icp": lambda rec: IcpLogger(rec.sink),
    "dense": lambda rec: DenseLogger(rec.sink),
    "evaluation": lambda rec: EvaluationLogger(rec.sink, label_stride=rec._label_stride),
    "crosscheck": lambda rec: CrosscheckLogger(rec.sink, max_display_points=rec._max_display_points),
}


class Recorder(RecorderProtocol):
    """Writes one rerun recording (.rrd) of a pcreg run; a context manager.

    Each method of :class:`~pcreg.recording.interface.RecorderProtocol` (documented there) is handed to
    one of the loggers, which are attributes: :attr:`text`, :attr:`pairs`, :attr:`icp`, :attr:`dense`,
    :attr:`evaluation` and :attr:`crosscheck`, all writing to :attr:`sink`, each made when first used.

    Parameters
    ----------
    path : str or Path
        The .rrd file, written as the run goes.
    application_id : str
        Rerun application id (groups recordings in the viewer).
    recording_name : str, optional
        Human-readable name shown by the viewer.
    recording_id : str, optional
        Rerun recording id; a fresh UUID4 when omitted.
    raw_images : bool
        Log images (and label maps) losslessly instead of JPEG (and display-subsampled labels).
    force : bool
        Overwrite an existing file.
    kind : str, optional
        Which command records: ``register``, ``crosscheck``, ``sequence``, ``rotation``, ``demo`` or
        ``dense`` (:data:`pcreg.recording.blueprint.KINDS`). Stored in the recording (property
        ``pcreg.kind``) and picks the blueprint; inferred from what was logged when omitted.
    blueprint : bool or str
        Embed, on :meth:`close`, the blueprint of ``kind`` built from the entities logged (a kind name
        here sets ``kind``; ``"default"`` is the same as ``True``); ``False`` lets the viewer choose.
    jpeg_quality : int
        JPEG quality of logged images (1..100).
    max_display_points : int
        At most this many points of each cloud are logged per frame (evenly spaced subsample).
    label_stride : int, optional
        Label maps are logged as ``labels[::s, ::s]`` for display; default 2 (1 with ``raw_images``).
    classes : ClassTable, optional
        The class table the label maps' ids are of (a run's ``--classes``): each class's name and colour in the
        viewer; default :data:`pcreg.recording.entities.CLASSES` (0 ground, 1 obstacle, 2 unknown).

    Raises
    ------
    OutputError
        ``path`` exists and not ``force``, or it cannot be written.
    ValueError
        An unknown ``kind``, or one that ``blueprint`` contradicts; ``jpeg_quality`` out of range.
    """

    enabled = True  # as against pcreg.recording.null.NULL_RECORDER

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        application_id: str = "pcreg",
        recording_name: str | None = None,
        recording_id: str | None = None,
        raw_images: bool = False,
        force: bool = False,
        kind: str | None = None,
        blueprint: bool | str = True,
        jpeg_quality: int = DEFAULT_JPEG_QUALITY,
        max_display_points: int = 500,
        label_stride: int | None = None,
        classes: Any = None,
    ) -> None:
        kind = _kind(kind, blueprint)
        self.sink: Sink = Sink(path, application_id=application_id, recording_id=recording_id, recording_name=recording_name,
                         kind=kind, embed_blueprint=bool(blueprint), raw_images=raw_images, jpeg_quality=jpeg_quality,
                         force=force)
        self._label_stride: int = label_stride if label_stride is not None else (1 if raw_images else 2)
        self._max_display_points: int = max_display_points
        self.path: Path = self.sink.path
        self.recording_id: str = self.sink.recording_id
        self.kind = kind  # None: inferred from what was logged when the recording closes
        self.evaluation.log_classes(classes)

    # -- the loggers, each made when first used -------------------------------------------------

    text: TextLogger
    pairs: PairLogger
    icp: IcpLogger
    dense: DenseLogger
    evaluation: EvaluationLogger
    crosscheck: CrosscheckLogger

    def __getattr__(self, name: str) -> Any:
        """A logger (:attr:`text`, :attr:`pairs`, :attr:`icp`, :attr:`dense`, :attr:`evaluation`,
        :attr:`crosscheck`) the first time it is asked for: made over :attr:`sink` and kept."""
        if name not in _LOGGERS:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        logger = _LOGGERS[name](self)
        setattr(self, name, logger)
        return logger

    # -- life cycle ---------------------------------------------------------------------------

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        from ..errors import PcregError

        if isinstance(exc, PcregError) and self.sink.frame is None and not self.closed:
            # bad input found before any work (a --data folder that is not there): the recording would hold
            # nothing but the refusal and stand in the way of the corrected command
            self.discard()
            return False
        if exc is not None and not self.closed:
            text = "".join(traceback.format_exception_only(exc_type, exc)).strip()
            self.log_failure(text)
        self.close()
        return False

    def close(self) -> None:
        """Send what is kept, flush everything to the file and finish it (idempotent)."""
        if self.sink.closed:
            return
        try:
            self.icp.send_kept(now=True)
        finally:
            self.sink.close()

    def discard(self) -> None:
        """Close the recording and remove its file and the folders made for it: a run that found nothing to record
        (bad input before any work, or every unit already done) leaves no recording that looks like its own."""
        self.close()
        self.path.unlink(missing_ok=True)
        remove_made_folders(self.sink.made_folders)
        self.discarded = True

    #: Whether :meth:`discard` removed the file.
    discarded = False

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called (logging is then refused)."""
        return self.sink.closed

    def entities(self) -> dict[str, frozenset[str]]:
        """Entity paths logged so far and the archetypes logged at each."""
        return self.sink.entities()

    def flush(self) -> None:
        """Block until everything logged so far is in the file (the ICP's iterations kept sent first)."""
        self.icp.send_kept(now=True)
        self.sink.flush()

    def set_frame(self, index: int) -> None:
        """Put what follows on the ``frame`` timeline at ``index``: a new pair
        (:meth:`PairLogger.new_pair`) and ICP steps from 0.

        Waits for the previous frame's logging to be done on the recorder's thread (it is by then in
        practice); rerun writes it to the file within about a second (:data:`~pcreg.recording.sink.BATCH_SECONDS`)."""
        if self.sink.frame is not None:
            self.sink.wait()
        self.icp.send_kept(now=self.sink.frame is None)  # iterations before the first frame have no frame
        self.sink.set_frame(index)
        self.icp.new_frame()
        self.pairs.new_pair()

    # -- the loggers' methods -----------------------------------------------------------------

    def log_config(self, config: Any) -> None:
        """As :meth:`RecorderProtocol.log_config`, by :meth:`TextLogger.log_config`."""
        self.text.log_config(config)

    def log_text(self, text: str, level: str = "INFO") -> None:
        """As :meth:`RecorderProtocol.log_text`, by :meth:`TextLogger.log_text`."""
        self.text.log_text(text, level)

    def log_failure(self, text: str) -> None:
        """As :meth:`RecorderProtocol.log_failure`, by :meth:`TextLogger.log_failure`."""
        self.text.log_failure(text)

    def log_images(self, *, reference: np.ndarray | None = None, moving: np.ndarray | None = None,
                   warped: np.ndarray | None = None, valid_mask: np.ndarray | None = None) -> None:
        """As :meth:`RecorderProtocol.log_images`, by :meth:`PairLogger.log_images`."""
        self.pairs.log_images(reference=reference, moving=moving, warped=warped, valid_mask=valid_mask)

    def log_clouds(self, *, reference_points: np.ndarray | None = None, reference_colors: np.ndarray | None = None,
                   moving_points: np.ndarray | None = None, moving_colors: np.ndarray | None = None) -> None:
        """As :meth:`RecorderProtocol.log_clouds`, by :meth:`PairLogger.log_clouds`."""
        self.pairs.log_clouds(reference_points=reference_points, reference_colors=reference_colors,
                             moving_points=moving_points, moving_colors=moving_colors)

    def log_transform(self, matrix: np.ndarray, *, name: str = "T_ref_mov",
                      moving_shape: tuple[int, int] | None = None) -> None:
        """As :meth:`RecorderProtocol.log_transform`, by :meth:`PairLogger.log_transform`."""
        self.pairs.log_transform(matrix, name=name, moving_shape=moving_shape)

    def log_dense(self, field: np.ndarray, *, matrix: np.ndarray | None = None, confidence: np.ndarray | None = None,
                  warped_prior: np.ndarray | None = None, quiver_step: int = 24) -> None:
        """As :meth:`RecorderProtocol.log_dense`, by :meth:`DenseLogger.log_dense`."""
        self.dense.log_dense(field, matrix=matrix, confidence=confidence, warped_prior=warped_prior,
                             quiver_step=quiver_step)

    def log_labels(self, *, truth: np.ndarray | None = None, predicted: np.ndarray | None = None,
                   prefix: str = "") -> None:
        """As :meth:`RecorderProtocol.log_labels`, by :meth:`EvaluationLogger.log_labels`."""
        self.evaluation.log_labels(truth=truth, predicted=predicted, prefix=prefix)

    def log_classes(self, table: Any) -> None:
        """As :meth:`RecorderProtocol.log_classes`, by :meth:`EvaluationLogger.log_classes`."""
        self.sink.check_open()
        self.evaluation.log_classes(table)

    def log_errors(self, errors: Mapping[str, float]) -> None:
        """As :meth:`RecorderProtocol.log_errors`, by :meth:`EvaluationLogger.log_errors`."""
        self.evaluation.log_errors(errors)

    def icp_callback(self, backend: str, *, max_points: int = 300,
                     max_correspondences: int = 200) -> Callable[[IcpIteration], None]:
        """As :meth:`RecorderProtocol.icp_callback`, by :meth:`IcpLogger.callback`."""
        return self.icp.callback(backend, max_points=max_points, max_correspondences=max_correspondences)

    def log_crosscheck(self, report: Mapping[str, Any]) -> None:
        """As :meth:`RecorderProtocol.log_crosscheck`, by :meth:`CrosscheckLogger.log_crosscheck`."""
        self.crosscheck.log_crosscheck(report)

    def log_crosscheck_target(self, points: np.ndarray) -> None:
        """As :meth:`RecorderProtocol.log_crosscheck_target`, by :meth:`CrosscheckLogger.log_crosscheck_target`."""
        self.crosscheck.log_crosscheck_target(points)

    def log_crosscheck_iteration(self, implementation: str, iteration: int, points: np.ndarray, *,
                                 error: float | None = None, fitness: float | None = None,
                                 inlier_rmse: float | None = None) -> None:
        """As :meth:`RecorderProtocol.log_crosscheck_iteration`, by :meth:`CrosscheckLogger.log_crosscheck_iteration`."""
        self.crosscheck.log_crosscheck_iteration(implementation, iteration, points, error=error, fitness=fitness,
                                                 inlier_rmse=inlier_rmse)
