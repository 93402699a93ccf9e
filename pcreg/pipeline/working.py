"""A stream's working size: the frame size its steps run at, below the frames' own where asked.

A :class:`pcreg.Propagator` made with ``scale`` below 1 shrinks the key frame and every frame to that
share of their width and height (each pixel the mean of the pixels it covers, ``cv2.INTER_AREA``; the
labels by the one covering most of that area) and runs the whole step there: the dense registration, naive Bayes, the
DIS flow, the trust map and the learning. Only the labels and their confidence come back at the frame's
own size: the blurred fused log-odds and the confidence are resized bilinearly
(:func:`~pcreg.pipeline.trust.read_labels`), and a label is the sign of the resized log-odds, so borders
fall between pixels of the working size rather than on them.

Half size runs the step at 640x480 in 0.53-0.56 of the time, and lowered plain naive Bayes' error on the
eight shared CamVid clips by 48.4% against 49.7% at full size (docs/results.md, "Working size").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frame import PreparedFrame

__all__ = ["WorkingSize"]


@dataclass(frozen=True)
class WorkingSize:
    """The working size of frames of (H, W) ``shape`` at ``scale`` (0 < scale <= 1 of each side, at least
    one pixel): :attr:`shape`, and the conversions to it and back."""

    frame: tuple[int, int]
    scale: float = 1.0

    def __post_init__(self) -> None:
        from ..validation import check_float

        object.__setattr__(self, "scale", check_float(self.scale, "scale", lo=0, lo_open=True, hi=1))

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w) of the working size."""
        if self.scale == 1.0:
            return self.frame
        h, w = self.frame
        return max(1, round(h * self.scale)), max(1, round(w * self.scale))

    @property
    def scaled(self) -> bool:
        """Whether the working size is below the frames' own."""
        return self.shape != self.frame

    def check_for(self, motion, model: str, scale: float, advice: str = "") -> None:
        """Refuse this working size when the stream's ``motion`` (a :class:`~pcreg.pipeline.estimators.StreamMotion`
        of ``model``) cannot take it (its pyramid's levels, the dense grid's spacing, DIS's smallest side), naming the
        ``scale`` and ending with ``advice`` (or the frames' size when they are not scaled): when the key frame comes,
        not at the first frame."""
        from ..errors import InputError

        (H, W), (h, w) = self.frame, self.shape
        try:
            motion.check_size(self.shape)
        except InputError as exc:
            if not self.scaled:
                from ..registration.transforms import MODELS  # the global models, each on a pyramid of levels

                other = "; the dense model (the default) and the flow model take smaller frames" if model in MODELS else ""
                raise InputError(f"frames of {W}x{H} are too small for the {model} model ({exc}){other}") from None
            raise InputError(f"scale {scale:g} works at {w}x{h} for frames of {W}x{H}: too small for the "
                             f"{motion.name} ({exc}){advice}") from None

    def shrunk(self, frame: PreparedFrame) -> PreparedFrame:
        """``frame`` at the working size (itself at full size); made once and kept with the frame."""
        if not self.scaled:
            return frame
        import cv2

        h, w = self.shape
        return frame.derived(("working size", h, w), lambda rgb: PreparedFrame(
            cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)))

    def labels(self, labels: np.ndarray) -> np.ndarray:
        """(H, W) uint8 labels (class ids) at the working size: each working pixel takes the label that covers
        most of its area (the lowest on a tie), the same area the image's pixel is the mean of. (The
        nearest pixel, ``cv2.INTER_NEAREST``, takes each block's top-left one: the labels would sit
        ``(1/scale - 1) / 2`` px off the image, half a pixel at half size.)"""
        if not self.scaled:
            return labels
        import cv2

        h, w = self.shape
        lab = np.asarray(labels)
        values = np.unique(lab)
        shares = [cv2.resize((lab == k).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) for k in values]
        return values[np.argmax(np.stack(shares), axis=0)].astype(np.uint8)

    def grow(self, values: np.ndarray) -> np.ndarray:
        """(h, w) float32 values of the working size (or (h, w, K): K values a pixel) at the frames' size,
        bilinearly (itself at full size)."""
        a = np.ascontiguousarray(values, dtype=np.float32)
        if a.shape[:2] == self.frame:
            return a
        if a.shape[:2] != self.shape:
            raise ValueError(f"a map of shape {a.shape} in a stream working at {self.shape}")  # a caller's bug
        import cv2

        h, w = self.frame
        if a.ndim == 3:
            from .readout import channelwise

            return channelwise(lambda part: cv2.resize(part, (w, h), interpolation=cv2.INTER_LINEAR), a)
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_LINEAR)

    def _ratios(self) -> tuple[float, float]:
        (H, W), (h, w) = self.frame, self.shape
        return W / w, H / h

    def frame_matrix(self, matrix: np.ndarray) -> np.ndarray:
        """A 3x3 transform between two frames at the working size, in the frames' own pixels (pixel centres
        kept: ``x = sx * x_w + (sx - 1) / 2``); itself at full size."""
        if not self.scaled:
            return matrix
        sx, sy = self._ratios()
        S = np.array([[sx, 0.0, (sx - 1) / 2], [0.0, sy, (sy - 1) / 2], [0.0, 0.0, 1.0]])
        return S @ np.asarray(matrix, dtype=np.float64) @ np.linalg.inv(S)

    def frame_field(self, field: np.ndarray) -> np.ndarray:
        """An (h, w, 2) field of positions at the working size (each pixel's position in the other frame)
        as an (H, W, 2) field of positions in the frames' own pixels, bilinearly; itself at full size."""
        if not self.scaled:
            return field
        import cv2

        sx, sy = self._ratios()
        H, W = self.frame
        g = cv2.resize(np.ascontiguousarray(field, dtype=np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
        g[:, :, 0] = (g[:, :, 0] + 0.5) * sx - 0.5
        g[:, :, 1] = (g[:, :, 1] + 0.5) * sy - 0.5
        return g
