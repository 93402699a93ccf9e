"""What reading a frame met that the reader of the frames says, once a run for each kind
(:attr:`~pcreg.datasets.sources.SourceFrame.notes`, said by :class:`~pcreg.runs.gaps.GapMarks`): a frame with
transparent pixels, whose alpha pcreg does not read, a 16-bit frame whose values use only the lowest bits (read as
nearly black), an image file decoded around damaged data, and a video whose frames turn interlaced after its first.

The rule for alpha: a frame is read with its colours as stored and its alpha left out, as it always was, so an
opaque frame with an alpha channel reads as the same frame without one; where a pixel's alpha is below opaque its
colour may not be the scene (a transparent pixel often stores black), and the first such frame is named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["TRANSPARENT", "DARK", "DAMAGED", "INTERLACED", "read_frame", "stored_notes", "transparent_notes",
           "dark_notes", "damaged_notes", "turn_note", "has_alpha"]

#: The kind of note of a frame with transparent pixels (alpha below opaque), whose alpha pcreg does not read.
TRANSPARENT = "transparent"

#: How a run's note ends: it names the first such frame only.
LATER = "later such frames not said"


def read_frame(path: Path) -> tuple[np.ndarray, tuple[tuple[str, str], ...]]:
    """A frame's image file as (H, W, 3) uint8 RGB (:func:`pcreg.load_image`'s conversion, its alpha left out) and
    what reading it met (:func:`stored_notes`, :func:`damaged_notes`)."""
    from ..formats import read_image_file_and_damage
    from ..registration.clouds import _rgb_and_alpha

    stored, damage = read_image_file_and_damage(path)
    image, _ = _rgb_and_alpha(stored, str(path), None)
    return image, stored_notes(str(path), stored) + damaged_notes(str(path), damage)


def stored_notes(where: str, stored: np.ndarray, *, later: str = LATER) -> tuple[tuple[str, str], ...]:
    """The notes of a frame's pixels as its file stores them (``where`` names it; ``stored`` as decoded, its alpha
    last): transparent pixels (:func:`transparent_notes`), 16-bit values in the lowest bits (:func:`dark_notes`).
    ``later`` ends each note (what is said of later such frames)."""
    alpha = stored[:, :, 3] if stored.ndim == 3 and stored.shape[2] == 4 else None
    colours = stored[:, :, :3] if alpha is not None else stored
    return transparent_notes(where, alpha, later=later) + dark_notes(where, colours, later=later)


#: The kind of note of a 16-bit frame whose values use only the lowest bits, read as nearly black.
DARK = "dark"


def dark_notes(where: str, colours: np.ndarray, *, later: str = LATER) -> tuple[tuple[str, str], ...]:
    """The note of a frame (``where`` names it) whose ``colours`` as stored are 16-bit values in at most the lowest 12
    bits (8-bit values stored in 16 bits, a 10- or 12-bit camera's): pcreg scales 16 bits by 1/257, so the frame
    reads as nearly black and its classes by little more than noise (:func:`pcreg.frame.low_bits_note`)."""
    from ..frame import low_bits_note

    said = low_bits_note(colours)
    return ((DARK, f"{where}: {said} ({later})"),) if said else ()


def video_dark_notes(where: str, frame, reformatter) -> tuple[tuple[str, str], ...]:
    """:func:`dark_notes` of a decoded ``av.VideoFrame`` of a 16-bit pixel format (``gray16le``, ``rgb48le``, ...; a
    10- or 12-bit camera's frames stored in 16 bits), from its brightness as stored (``reformatter`` makes it
    ``gray16le``, one for the stream); () for other formats, which FFmpeg scales to 8 bits by their own depth."""
    if not any(c.bits == 16 and not c.is_alpha for c in frame.format.components):
        return ()
    return dark_notes(where, reformatter.reformat(frame, format="gray16le").to_ndarray())


#: The kind of note of a frame's image file whose decoder reports damaged data it decoded around (a JPEG cut short).
DAMAGED = "damaged"


def damaged_notes(where: str, damage: str) -> tuple[tuple[str, str], ...]:
    """The note of a frame's image file (``where`` names it) whose decoder said ``damage`` of damaged data it decoded
    around (:func:`pcreg.formats.read_image_file_and_damage`; "" for none): part of the frame is its guess."""
    if not damage:
        return ()
    return ((DAMAGED, f"{where}: its decoder reports damaged data ({damage}): part of the frame is the decoder's "
             "guess, and its labels there may be off (later such frames not said)"),)


def transparent_notes(where: str, alpha: np.ndarray | None, *, later: str = LATER) -> tuple[tuple[str, str], ...]:
    """The note of a frame (``where`` names it) whose ``alpha`` (H, W) uint8 (None: the frame has none) is below 255
    (or 65535) somewhere: its colours are read as stored, without alpha; else none. ``later`` ends the note."""
    if alpha is None:
        return ()
    opaque = np.iinfo(alpha.dtype).max  # 255, or 65535 in a 16-bit file
    n = np.count_nonzero(alpha < opaque)
    if n == 0:
        return ()
    return ((TRANSPARENT, f"{where} has transparent pixels ({n} of its {alpha.size}, alpha below opaque): pcreg reads "
             "a frame's colours as stored, without alpha, and labels a transparent pixel by the colour it holds; "
             f"flatten the frames onto their background first if that colour is not the scene ({later})"),)


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
