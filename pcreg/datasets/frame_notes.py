"""What reading a frame met that the reader of the frames says, once a run for each kind
(:attr:`~pcreg.datasets.sources.SourceFrame.notes`, said by :class:`~pcreg.runs.gaps.GapMarks`): a frame with
transparent pixels, whose alpha pcreg does not read, an image file decoded around damaged data, and a video whose
frames turn interlaced after its first.

The rule for alpha: a frame is read with its colours as stored and its alpha left out, as it always was, so an
opaque frame with an alpha channel reads as the same frame without one; where a pixel's alpha is below opaque its
colour may not be the scene (a transparent pixel often stores black), and the first such frame is named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["TRANSPARENT", "DAMAGED", "INTERLACED", "read_frame", "transparent_notes", "damaged_notes", "turn_note",
           "has_alpha"]

#: The kind of note of a frame with transparent pixels (alpha below opaque), whose alpha pcreg does not read.
TRANSPARENT = "transparent"


def read_frame(path: Path) -> tuple[np.ndarray, tuple[tuple[str, str], ...]]:
    """A frame's image file as (H, W, 3) uint8 RGB (:func:`pcreg.load_image`'s conversion, its alpha left out) and
    what reading it met: transparent pixels (:func:`transparent_notes`), damaged data its decoder decoded around
    (:func:`damaged_notes`)."""
    from ..formats import read_image_file_and_damage
    from ..registration.clouds import _rgb_and_alpha

    stored, damage = read_image_file_and_damage(path)
    image, alpha = _rgb_and_alpha(stored, str(path), None)
    return image, transparent_notes(str(path), alpha) + damaged_notes(str(path), damage)


#: The kind of note of a frame's image file whose decoder reports damaged data it decoded around (a JPEG cut short).
DAMAGED = "damaged"


def damaged_notes(where: str, damage: str) -> tuple[tuple[str, str], ...]:
    """The note of a frame's image file (``where`` names it) whose decoder said ``damage`` of damaged data it decoded
    around (:func:`pcreg.formats.read_image_file_and_damage`; "" for none): part of the frame is its guess."""
    if not damage:
        return ()
    return ((DAMAGED, f"{where}: its decoder reports damaged data ({damage}): part of the frame is the decoder's "
             "guess, and its labels there may be off (later such frames not said)"),)


def transparent_notes(where: str, alpha: np.ndarray | None) -> tuple[tuple[str, str], ...]:
    """The note of a frame (``where`` names it) whose ``alpha`` (H, W) uint8 (None: the frame has none) is below 255
    (or 65535) somewhere: its colours are read as stored, without alpha; else none."""
    if alpha is None:
        return ()
    opaque = np.iinfo(alpha.dtype).max  # 255, or 65535 in a 16-bit file
    n = np.count_nonzero(alpha < opaque)
    if n == 0:
        return ()
    return ((TRANSPARENT, f"{where} has transparent pixels ({n} of its {alpha.size}, alpha below opaque): pcreg reads "
             "a frame's colours as stored, without alpha, and labels a transparent pixel by the colour it holds; "
             "flatten the frames onto their background first if that colour is not the scene (later such frames "
             "not said)"),)


#: The kind of note of a video whose frames turn interlaced after its first.
INTERLACED = "interlaced"


def turn_note(path: Path, index: int) -> tuple[str, str]:
    """The note of the video at ``path`` whose frames are flagged interlaced from frame ``index`` on."""
    from .deinterlace import FILTER

    return INTERLACED, (f"{path}: frames flagged interlaced from frame {index:06d} on, the frames before it "
                        "progressive (recordings joined, a programme change): they are deinterlaced with FFmpeg's "
                        f"{FILTER[0]} as they are read")


def has_alpha(frame) -> bool:
    """Whether a decoded ``av.VideoFrame``'s pixel format has an alpha channel (``rgba``, ``argb``, ``yuva420p``)."""
    return any(c.is_alpha for c in frame.format.components)
