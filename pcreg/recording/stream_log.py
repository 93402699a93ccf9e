"""One step of a labelled stream into a recording (``pcreg run --record``): the frame, its labels, its predicted error
(a series of the Errors view) and its motion (a dense field with its confidence, or a transform), or why it could not
be registered."""

from __future__ import annotations

__all__ = ["log_frame", "PREDICTED"]

#: The series of each frame's predicted error in percent (``errors/predicted``).
PREDICTED = "predicted"


def log_frame(rec, t: int, image, labels, report, name: str, size, *, reference=None) -> None:
    """One frame into the recording ``rec``; ``size``: the propagator's working size (its motion is logged
    in the frames' pixels); ``reference``: the image the frame was registered to, when known (the
    Registration view draws the frame over it)."""
    rec.set_frame(t)
    rec.log_images(reference=reference, moving=image)
    rec.log_labels(predicted=labels)
    if report.predicted_error is not None:
        rec.log_errors({PREDICTED: report.predicted_error})
    reg = report.registration
    if reg is None:
        rec.log_failure(f"{name}: {report.reason} (the key frame's labels, unwarped)")
        return
    matrix = size.frame_matrix(reg.matrix)
    if getattr(reg, "field", None) is not None:
        rec.log_dense(size.frame_field(reg.field), matrix=matrix,
                      confidence=None if reg.confidence is None else size.grow(reg.confidence))
    else:
        rec.log_transform(matrix)

