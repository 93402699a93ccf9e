"""Whether an image repeats itself under a shift (tiles, a grid, a checkerboard): then a motion that differs
from a registration's by that shift aligns the images as well as it does, and no edge or intensity evidence
tells the two apart.

The central half of the image, reduced to at most :data:`SIDE` px, is correlated (zero-normalised) with the
whole at every shift up to a quarter of the image. A natural photograph's correlation falls from 1 at no
shift and stays low away from that lobe (0.72 at most over CamVid frames and scikit-image's photographs,
coins.png's rows of coins); a pattern that repeats peaks again, near 1, one period away.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from ..errors import RegistrationError

if TYPE_CHECKING:
    from .result import Repetition

SIDE = 256
"""The longer side (px) the image is reduced to before it is correlated with itself."""

LOBE = 0.5
"""The correlation that bounds the lobe around no shift: a peak counts only beyond a dip under it."""

REPEATS = 0.9
"""The correlation, away from that lobe, at which the image is taken to repeat itself."""


def repeat_shift(image: np.ndarray) -> tuple[float, float, float] | None:
    """The shortest shift ``(dx, dy)`` in px of ``image`` ((H, W) or (H, W, C), any numeric type) under which its
    central half matches itself with a correlation of at least :data:`REPEATS`, beyond the lobe around no shift,
    and that correlation: ``(dx, dy, correlation)``; None where there is none (or the image is under 16 px)."""
    factor = max(1.0, max(image.shape[:2]) / SIDE)
    if factor > 1:  # reduced as stored, before the float copy: its cost is the reduced image's (a 4000x3000 pair: 1.3 s)
        size = (max(1, round(image.shape[1] / factor)), max(1, round(image.shape[0] / factor)))
        image = cv2.resize(image if image.ndim == 2 or image.shape[2] <= 4 else image.astype(np.float32), size,
                           interpolation=cv2.INTER_AREA)
    grey = image.astype(np.float32) if image.ndim == 2 else image.astype(np.float32).mean(axis=2)
    h, w = grey.shape
    if min(h, w) < 16:
        return None
    y0, x0 = (h - h // 2) // 2, (w - w // 2) // 2
    ncc = cv2.matchTemplate(grey, grey[y0:y0 + h // 2, x0:x0 + w // 2], cv2.TM_CCOEFF_NORMED)
    ncc = np.nan_to_num(ncc, nan=0.0)  # a flat image correlates with nothing
    lobe = cv2.connectedComponents((ncc > LOBE).astype(np.uint8), connectivity=8)[1]
    away = np.where(lobe == lobe[y0, x0], -1.0, ncc) if ncc[y0, x0] > LOBE else ncc
    count, peaks = cv2.connectedComponents((away >= REPEATS).astype(np.uint8), connectivity=8)
    best = None
    for label in range(1, count):
        ys, xs = np.nonzero(peaks == label)
        top = np.argmax(away[ys, xs])
        dx, dy = (xs[top] - x0) * factor, (ys[top] - y0) * factor
        if best is None or np.hypot(dx, dy) < np.hypot(best[0], best[1]):
            best = (float(dx), float(dy), float(away[ys[top], xs[top]]))
    return best


def pair_repeats(reference: np.ndarray, moving: np.ndarray) -> Repetition | None:
    """The first image of a registered pair that repeats itself (:func:`repeat_shift`) as a
    :class:`~pcreg.registration.result.Repetition` (``image`` ``"reference"`` or ``"moving"``), or None: what
    :func:`pcreg.register` keeps in ``evidence.repeats`` with the model check on, with or without the plausibility
    test, since no test tells a result from one a period off."""
    from .result import Repetition

    for name, image in (("reference", reference), ("moving", moving)):
        found = repeat_shift(image)
        if found is not None:
            dx, dy, correlation = found
            return Repetition(name, (dx, dy), correlation)
    return None


def said_with_repeats(refusal: RegistrationError, reference: np.ndarray, moving: np.ndarray) -> RegistrationError:
    """``refusal`` of the pair with a clause first naming the image that repeats itself (:func:`pair_repeats`), or
    ``refusal`` itself: a pattern that repeats lines up under motions a period apart, and its mirror often as well,
    so what the refusal reads (too few edge points lined up, a mirror image) may be the pattern alone."""
    found = pair_repeats(reference, moving)
    if found is None:
        return refusal
    dx, dy = found.shift_px
    said = str(refusal).removeprefix("registration refused: ")
    return type(refusal)(f"registration refused: the {found.image} image repeats itself (shifted by about ({dx:.0f}, "
                         f"{dy:.0f}) px it matches itself), and a pattern that repeats may line up under several motions, or "
                         f"mirrored; {said}")
