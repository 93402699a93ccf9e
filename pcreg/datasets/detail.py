"""How much fine detail a frame holds for its size, and the note ``pcreg run`` gives of a key frame that holds
less than its size suggests (brought up from a smaller size, or soft).

A frame brought up in size keeps all its detail through a round trip to its old size and back; a sharp frame
loses much of it. :func:`detail_scale` finds the smallest of :data:`SCALES` whose round trip (shrunk with
``cv2.INTER_AREA``, brought back with ``cv2.INTER_CUBIC``) keeps :data:`KEPT_DETAIL` of the grey frame's fine
detail, the energy of its Laplacian. Measured on every 25th frame (docs/results.md, "Frames of other sizes"):
CamVid's own 480x360 frames lose 48-62% of it at 0.75, DAVIS's 854x480 30-48%; the same CamVid frames brought up
to 640x480 lose 13-17% at 0.75 and 57-69% at 0.5, to 960x720 8-11% at 0.5. A stream's dense
step, whose sizes are in pixels and were set on frames 480 px wide, labels the frames brought up better at the
scale found (two classes, the eight clips: 49.9% below plain at 0.75 against 45.7% at full size for 640x480,
49.0% at 0.5 against 46.5% for 960x720), and faster.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KEPT_DETAIL", "SCALES", "detail_kept", "detail_scale", "scale_note"]

#: The share of a frame's fine detail a round trip to a smaller size must keep for the frame to be called no
#: sharper than that size: three quarters (any limit of the loss from 0.18 to 0.30 finds the same scales on the
#: shared clips, at their own size and brought up to 640x480 and 960x720, and on DAVIS).
KEPT_DETAIL = 0.75
#: The scales tried, smallest first (``--scale`` values). Not below a half: at larger factors the measure reads
#: the interpolation's own ripple (CamVid frames brought up four times keep 41% at 0.5 and 70% at 0.75, and are
#: not said; three times, 84% at 0.75, said at 0.75).
SCALES = (0.5, 0.75)


def detail_kept(image: np.ndarray, scale: float) -> float:
    """The share of ``image``'s fine detail (the energy of its grey levels' Laplacian) a round trip to ``scale``
    of its size keeps (1 for a frame without any)."""
    import cv2

    grey = (image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2GRAY))
    grey = grey.astype(np.float32)
    h, w = grey.shape
    energy = float(np.mean(cv2.Laplacian(grey, cv2.CV_32F) ** 2))
    if energy == 0:
        return 1.0
    small = cv2.resize(grey, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    back = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    return 1.0 - float(np.mean(cv2.Laplacian(grey - back, cv2.CV_32F) ** 2)) / energy


def detail_scale(image: np.ndarray, *, longer_side: float = 16) -> float:
    """The smallest of :data:`SCALES` at which ``image`` keeps :data:`KEPT_DETAIL` of its fine detail and its longer
    side ``longer_side`` pixels or more, 1.0 when none does (a frame as sharp as its size)."""
    return _scale_kept(image, longer_side)[0]


def _scale_kept(image: np.ndarray, longer_side: float) -> tuple[float, float]:
    """:func:`detail_scale` and the share of the detail kept there (1.0 at 1.0)."""
    h, w = image.shape[:2]
    for s in SCALES:
        if min(h, w) * s >= 16 and max(h, w) * s >= longer_side:
            kept = detail_kept(image, s)
            if kept >= KEPT_DETAIL:
                return s, kept
    return 1.0, 1.0


def scale_note(image: np.ndarray, where: str, config) -> str | None:
    """The note of a key frame ``image`` (``where`` names it) that holds no more detail than a smaller size would,
    not below :data:`~pcreg.pipeline.readout.BASE_WIDTH` (the width the stream's sizes were set at) on its longer
    side, for a run of ``config`` (a :class:`~pcreg.pipeline.config.PropagatorConfig`) at full size with the dense
    model, which follows a scene; None otherwise (a smooth 320x240 frame is not said: the step was not measured to
    gain below that width)."""
    from ..pipeline.readout import BASE_WIDTH

    if config.scale != 1.0 or config.model != "dense" or config.follow != "scene":
        return None
    s, kept = _scale_kept(image, BASE_WIDTH)
    if s == 1.0:
        return None
    h, w = image.shape[:2]
    return (f"{where} holds no more detail than at {s:g} of its size ({round(w * s)}x{round(h * s)}: a round trip "
            f"there keeps {kept:.0%} of its fine detail), as frames brought up from a smaller size do; on such frames "
            f"`--scale {s:g}` labelled the shared clips more accurately and is faster (the step's sizes are in pixels, "
            f"set on frames {BASE_WIDTH:g} px wide)")
