"""pcreg's exceptions. Every one is a ``ValueError`` so callers can catch bad input in one place.

The command line turns a :class:`PcregError` into a one-line message and exit code 2 (3 for a
:class:`RegistrationError`); any other exception is a bug in pcreg (exit code 1).
"""

from __future__ import annotations

from types import FrameType


class PcregError(ValueError):
    """Base class of every error pcreg raises on purpose."""


class InputError(PcregError):
    """A file or array that pcreg cannot use: missing, unreadable, empty, wrong shape or dtype."""


class RegistrationError(PcregError):
    """Registration impossible with the given inputs (too few points, degenerate geometry, no overlap)."""


class DatasetError(PcregError):
    """A dataset folder or file that does not follow its format."""


class OutputError(PcregError):
    """An output path that cannot be written, or that exists and would be overwritten."""


class StuckOutput(OutputError):
    """An output whose writer, outside Python, stopped and cannot be finished (a recording on a full disk):
    the process cannot end normally either (the writer's library waits for it at exit), so the command
    line reports it and ends the process at once."""


class ImageWarning(UserWarning):
    """What :func:`pcreg.load_image` warns of an image file whose array is not what a viewer shows: transparent
    pixels kept as pixels, an EXIF orientation, damaged data the decoder guessed around (``pcreg register`` says
    the same as notes)."""



class UncalibratedWarning(UserWarning):
    """A confidence asked of options it was not calibrated at: a :class:`pcreg.Propagator` whose prior's ``weight`` is
    not the stream's (its confidence's coefficients were fitted at that weight), whose confidence and predicted error
    then read surer, or less sure, than its labels are."""

def outside_pcreg() -> int:
    """The ``stacklevel`` that points a warning the calling function warns at the first line outside pcreg: the
    user's call, however deep in pcreg it was made (``pcreg.crosscheck(path, path)`` reads its images)."""
    import os
    import sys

    package = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame: FrameType | None = sys._getframe(1)
    level = 1
    while frame is not None and frame.f_code.co_filename.startswith(package):
        frame, level = frame.f_back, level + 1
    return level


def _one_line(exc: BaseException) -> str:
    """An exception's words on one line, at most 300 characters (its type's name when it says nothing), as a message
    quotes another's: a scheduler's or worker's refusal, an implementation's failure."""
    return " ".join(str(exc).split())[:300] or type(exc).__name__
