"""What an evaluation scores, per frame: label maps (``labels/``) and error rates (``errors/``): :class:`EvaluationLogger`."""

from __future__ import annotations

import functools
import math
from typing import Mapping

import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..errors import InputError
from .sink import Sink

__all__ = ["EvaluationLogger"]


class EvaluationLogger:
    """Logs label maps and error rates to a :class:`~pcreg.recording.sink.Sink`.

    Label maps are logged as ``labels[::s, ::s]`` uint8 with ``s = label_stride`` (for display).
    """

    def __init__(self, sink: Sink, *, label_stride: int = 2) -> None:
        self.sink = sink
        self.label_stride = int(label_stride)

    def log_classes(self, table=None) -> None:
        """The classes the label maps' ids name, with their colours: a static AnnotationContext at ``/``;
        ``table`` a :class:`~pcreg.classes.ClassTable` (a run's), its classes; None, :data:`~pcreg.recording.entities.CLASSES`."""
        classes = E.CLASSES.items() if table is None else ((c.id, (c.name, c.colour)) for c in table.classes)
        self.sink.send("/", rr.AnnotationContext(
            [rr.AnnotationInfo(id=k, label=name, color=color) for k, (name, color) in classes]
        ), static=True)

    def log_labels(self, *, truth: np.ndarray | None = None, predicted: np.ndarray | None = None,
                   prefix: str = "") -> None:
        """SegmentationImage at ``labels/truth`` or ``labels/predicted`` (``/{prefix}`` appended when given)."""
        s = self.label_stride
        for kind, labels in (("truth", truth), ("predicted", predicted)):
            if labels is None:
                continue
            a = np.asarray(labels)
            if a.ndim != 2 or not np.issubdtype(a.dtype, np.integer):
                raise InputError(f"{kind} labels must be (H, W) integers, got {a.dtype} {a.shape}")
            if a.size and (a.min() < 0 or a.max() > 255):
                raise InputError(f"{kind} labels must be class ids in 0..255")
            shown = np.array(a[::s, ::s], dtype=np.uint8, order="C")  # a copy: logged on the sink's thread
            self.sink.log_later(E.labels_path(kind, prefix), functools.partial(rr.SegmentationImage, shown))

    def log_errors(self, errors: Mapping[str, float]) -> None:
        """Scalars at ``errors/{method}`` on the frame timeline, each series named by its method."""
        finite = [(str(m), float(v)) for m, v in errors.items() if math.isfinite(float(v))]

        def log() -> None:
            for method, value in finite:
                self.sink.scalar(E.error_path(method), value, method)

        self.sink.later(log)
