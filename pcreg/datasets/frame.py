"""A labelled frame: the unit every loader returns, and the ground-truth motion between two."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


def _readonly(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


@dataclass(frozen=True, eq=False, repr=False)
class Frame:
    """One frame of a sequence.

    image : (H, W, 3) uint8 RGB.
    labels : (H, W) uint8 class ids (of :data:`~pcreg.classes.LAGR` by default: 0 ground, 1 obstacle,
        2 unknown; a classifier checks them against its class table), or None for an unlabelled frame.
    name : str, unique within its sequence (e.g. the file stem).
    pose : (3, 3) float64 ``T_canvas_frame`` or None: maps this frame's pixel coordinates (x right,
        y down, (0, 0) the centre of the top-left pixel) into one coordinate frame common to the whole
        sequence, so the ground truth between two frames is ``inv(reference.pose) @ moving.pose``
        (see :func:`relative_transform`). Known for synthetic sequences only.
    damage : what the image's decoder said of damaged data it decoded around (libjpeg's ``Corrupt JPEG data:
        premature end of data segment``: part of the image is its guess), "" for an image that decoded whole
        (:func:`damage_notes` says it).
    notes : what else reading the image met that its figures may show, one line each (transparent pixels, whose
        alpha pcreg does not read; 16-bit values in the lowest bits, read as nearly black:
        :func:`pcreg.datasets.frame_notes.stored_notes`); () for none (:func:`damage_notes` says them).

    The arrays are read-only views; the caller's arrays are not copied or modified.
    """

    image: np.ndarray
    labels: np.ndarray | None
    name: str
    pose: np.ndarray | None = None
    damage: str = ""
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise InputError(f"frame {self.name!r}: image must be (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
        object.__setattr__(self, "image", _readonly(image))
        if self.labels is not None:
            labels = np.asarray(self.labels)
            if labels.dtype != np.uint8 or labels.shape != image.shape[:2]:
                raise InputError(f"frame {self.name!r}: labels must be (H, W) uint8 matching the image "
                                 f"{image.shape[:2]}, got {labels.shape} {labels.dtype}")
            object.__setattr__(self, "labels", _readonly(labels))
        if self.pose is not None:
            pose = np.array(self.pose, dtype=np.float64)
            if pose.shape != (3, 3):
                raise InputError(f"frame {self.name!r}: pose must be 3x3, got {pose.shape}")
            pose.flags.writeable = False
            object.__setattr__(self, "pose", pose)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return (int(self.image.shape[0]), int(self.image.shape[1]))

    @property
    def labelled(self) -> bool:
        return self.labels is not None

    def __repr__(self) -> str:
        h, w = self.shape
        lab = "None" if self.labels is None else f"({h}, {w}) uint8"
        pose = "None" if self.pose is None else "(3, 3)"
        return f"Frame(name={self.name!r}, image=({h}, {w}, 3) uint8, labels={lab}, pose={pose})"


def relative_transform(reference: Frame, moving: Frame) -> np.ndarray | None:
    """Ground-truth ``T_ref_mov`` (3, 3) float64, mapping the moving frame's pixel coordinates into the
    reference frame's: ``inv(reference.pose) @ moving.pose``; None when either pose is unknown."""
    for name, f in (("reference", reference), ("moving", moving)):
        if not hasattr(f, "pose"):
            raise InputError(f"{name} must be a Frame, got {type(f).__name__}")
    if reference.pose is None or moving.pose is None:
        return None
    return np.linalg.solve(reference.pose, moving.pose)


def damage_notes(datasets: dict[str, list[Frame]], said: int = 3) -> list[str]:
    """One line for each of the first ``said`` frames of ``datasets`` (``{clip: frames}``) whose image decoded
    around damaged data (:attr:`Frame.damage`), and one counting the rest: scored without a word, such a frame's
    figures come in part from the decoder's guesses; then the same for the frames whose reading met something else
    (:attr:`Frame.notes`: transparent pixels, 16-bit values read as nearly black); then the frames grey among a clip's
    colour frames (a frame saved as grey in a colour clip, which the colour features read otherwise)."""
    damaged = [(clip, f) for clip, frames in datasets.items() for f in frames if f.damage]
    lines = [f"clip {clip}, frame {f.name}: its decoder reports damaged data ({f.damage}): part of the image is the "
             "decoder's guess, and the figures of the frames it is in may be off" for clip, f in damaged[:said]]
    if len(damaged) > said:
        lines.append(f"{len(damaged) - said} more frame(s) decode around damaged data the same way")
    noted = [(clip, f) for clip, frames in datasets.items() for f in frames if f.notes]
    lines += [f"clip {clip}, frame {f.name}: {line}" for clip, f in noted[:said] for line in f.notes]
    if len(noted) > said:
        lines.append(f"{len(noted) - said} more frame(s) read with such notes")
    grey = [(clip, f) for clip, frames in datasets.items() for f in _grey_among_colour(frames)]
    lines += [f"clip {clip}, frame {f.name}: grey among the clip's colour frames (its three colours equal at every "
              "pixel: saved as grey, or black): the colour features read it otherwise than the frames around it, and "
              "the figures of the frames it is in may be off" for clip, f in grey[:said]]
    if len(grey) > said:
        lines.append(f"{len(grey) - said} more frame(s) grey among colour frames")
    return lines


def _grey_among_colour(frames: list[Frame]) -> list[Frame]:
    """The frames of a clip whose three colours are equal at every pixel, where another frame of the clip is in
    colour (a clip all grey is a grey clip, and says nothing)."""
    grey = [f for f in frames if f.image.ndim == 3 and f.image.shape[2] == 3
            and np.array_equal(f.image[:, :, 0], f.image[:, :, 1]) and np.array_equal(f.image[:, :, 1], f.image[:, :, 2])]
    return grey if len(grey) < len(frames) else []
