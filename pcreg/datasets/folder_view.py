"""How a folder's frames are shown against how pcreg reads them: one EXIF orientation and one size for all.

pcreg reads a frame's pixels as the file stores them (an EXIF orientation is never applied), and so reads the key
labels and writes every label PNG on that grid. That is right for every frame as long as all of them are stored
the same way. A phone stores a photograph taken upright in the sensor's landscape grid and tags it (orientation 6):
a folder where some frames carry another orientation than the key frame holds frames whose pixels are turned against
the key frame's though a viewer shows them alike, and a square frame would be labelled turned without a word. Such a
frame is refused where it is read, with the way to turn the frames first; and a key frame whose orientation the
labels' size cannot tell (a half turn, a mirror, a square frame), or a quarter turn with labels that fit the pixels as
stored (which a viewer or a CVAT task shows turned), is said in a note kept in run.json (``"orientation"``).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

__all__ = ["GOES_ON", "ORIENTATION", "FolderView", "file_view"]

#: The kind of note (run.json's ``"notes"``) of a key frame's EXIF orientation (:meth:`FolderView.notes`).
ORIENTATION = "orientation"
#: What a refusal of a frame of another size adds: the frames before it are kept (a run started over puts its earlier
#: run back instead, :mod:`pcreg.runs.earlier`, which takes these words away).
GOES_ON = " (the frames before it are labelled and kept: the same command goes on from it)"

#: What to do with frames stored otherwise than shown, said in every refusal and note of this module.
TURN = ("turn every frame as it is shown first (exiftran -ai *.jpg, or Pillow's ImageOps.exif_transpose), then draw "
        "the key labels on the turned key frame")


def file_view(path: Path) -> tuple[int | None, tuple[int, int] | None]:
    """``(orientation, (H, W))`` of an image file from its header: its EXIF orientation (2..8, None where it has none
    or 1, :func:`pcreg.formats.exif_orientation`), and its size as stored (None where Pillow cannot read the header:
    the frame's decoding says why)."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    from ..formats import exif_orientation

    try:
        with warnings.catch_warnings():  # pcreg's pixel limit holds; Pillow's lower one is for its own decoding
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as image:
                size = (int(image.height), int(image.width))
                if image.format == "TIFF":  # Pillow gives its size turned by its Orientation tag: as stored, its tags'
                    size = (int(image.tag_v2.get(257, size[0])), int(image.tag_v2.get(256, size[1])))
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError, Image.DecompressionBombError):
        return None, None
    return exif_orientation(path), size


def _said(orientation: int | None) -> str:
    from ..formats import ORIENTATION_VIEWS

    if orientation is None:
        return "has no EXIF orientation (shown as stored)"
    return f"has EXIF orientation {orientation} (shown {ORIENTATION_VIEWS[orientation]})"


class FolderView:
    """The key frame's (a folder's first chosen frame, ``key``) orientation and size, each later frame checked
    against them as it is read (:meth:`check`)."""

    def __init__(self, key: Path) -> None:
        self.key = key
        self.orientation, self.shape = file_view(key)

    def notes(self) -> tuple[tuple[str, str], ...]:
        """The key frame's note: its EXIF orientation, where viewers show it of the same size as stored (a half turn, a
        mirror, or a quarter turn of a square frame), so that labels drawn on the view fit the stored pixels as well;
        or a quarter turn of labels that fit the pixels as stored (labels of the size turned are refused for their size),
        whose masks a viewer or a CVAT task of these frames shows turned against them; none without one."""
        o, shape = self.orientation, self.shape
        if o is None or shape is None:
            return ()
        if o >= 5 and shape[0] != shape[1]:  # labels of the size shown are refused: these were drawn on the pixels as stored
            return ((ORIENTATION, f"{self.key}: the first frame {_said(o)}, as every frame must, and the key labels fit "
                     "the pixels as stored, which pcreg labels (its label PNGs and exports lie on them so): a viewer, or a CVAT task made of these "
                     f"frames, shows them turned, where those masks do not fit; to label the frames as shown, {TURN}, "
                     "and run again with --force"),)
        return ((ORIENTATION, f"{self.key}: the key frame {_said(o)}, at the size it is stored: pcreg reads "
                 "the frames' pixels as stored and takes --labels as drawn on them so (the label PNGs it writes lie "
                 f"on them so too); if the labels were drawn on the frame as a viewer shows it, {TURN}, and run again "
                 "with --force"),)

    def check(self, path: Path, shape: tuple[int, int]) -> None:
        """An :class:`InputError` naming the frame at ``path`` (decoded of ``shape`` (H, W)) when it carries another
        EXIF orientation than the key frame, or has another size."""
        from ..formats import exif_orientation

        if path == self.key:
            return
        orientation = exif_orientation(path)  # its size is the decoded frame's: the header is not read for it
        if orientation != self.orientation:
            raise InputError(f"{path} {_said(orientation)}, the first frame {self.key.name} {_said(self.orientation)}: "
                             "pcreg reads the pixels as stored, so this frame's are turned against the first frame's "
                             f"where a viewer shows them alike; {TURN}")
        if self.shape is not None and tuple(shape) != self.shape:
            h, w = shape
            raise InputError(f"{path}: {w}x{h} px, the first frame {self.key.name} {self.shape[1]}x{self.shape[0]}: "
                             f"pcreg labels frames of one size; resize or crop it to {self.shape[1]}x{self.shape[0]}{GOES_ON}")
