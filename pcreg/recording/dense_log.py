"""A dense registration's field (``dense/``), in the moving image's pixel frame: :class:`DenseLogger`."""

from __future__ import annotations

import cv2
import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..errors import InputError
from .sink import Sink

__all__ = ["DenseLogger"]


def _turbo(m: np.ndarray, scale: float) -> np.ndarray:
    """``m`` from 0 to ``scale`` colour-mapped (TURBO), (H, W, 3) uint8 RGB."""
    u8 = np.clip(255.0 * m / max(scale, 1e-6), 0, 255).astype(np.uint8)
    return cv2.cvtColor(cv2.applyColorMap(u8, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)


class DenseLogger:
    """Logs dense fields to a :class:`~pcreg.recording.sink.Sink`."""

    def __init__(self, sink: Sink) -> None:
        self.sink = sink

    def log_dense(self, field: np.ndarray, *, matrix: np.ndarray | None = None, confidence: np.ndarray | None = None,
                  warped_prior: np.ndarray | None = None, quiver_step: int = 24) -> None:
        """Checked and copied here, drawn on the sink's thread.

        Displacements (``|field(p) - p|``) are colour-mapped (TURBO, 0 to their maximum, which is logged
        as ``dense/max_displacement``); ``dense/refinement`` shows ``|field(p) - T p|`` for the global
        ``matrix`` T; ``dense/quiver`` draws ``field(p) - p`` every ``quiver_step`` pixels; confidence and
        warped prior are grey images, 0..255.
        """
        f = np.array(field, dtype=np.float32)  # copies: drawn on the sink's thread
        if f.ndim != 3 or f.shape[2] != 2 or not np.all(np.isfinite(f)):
            raise InputError(f"field must be a finite (H, W, 2) array, got shape {f.shape}")
        M = None if matrix is None else np.array(matrix, dtype=np.float64)
        if M is not None and (M.shape != (3, 3) or not np.all(np.isfinite(M))):
            raise InputError("matrix must be a finite (3, 3) array")
        maps = {}
        for path, a in ((E.DENSE_CONFIDENCE, confidence), (E.DENSE_WARPED_PRIOR, warped_prior)):
            if a is not None:
                maps[path] = a = np.array(a, dtype=np.float32)
                if a.shape != f.shape[:2]:
                    raise InputError(f"{path.rsplit('/', 1)[-1]} must be (H, W) = {f.shape[:2]}, got {a.shape}")
        self.sink.later(lambda: self._draw(f, M, maps, max(1, int(quiver_step))))

    def _draw(self, f: np.ndarray, M: np.ndarray | None, maps: dict[str, np.ndarray], step: int) -> None:
        """:meth:`log_dense`'s drawing, on the sink's thread."""
        sink = self.sink
        h, w = f.shape[:2]
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        disp = f - np.dstack([xs, ys])
        mag = np.hypot(disp[..., 0], disp[..., 1])
        top = float(mag.max()) if mag.size else 0.0
        sink.send(E.DENSE_DISPLACEMENT, sink.image(_turbo(mag, top)))
        if M is not None:
            den = M[2, 0] * xs + M[2, 1] * ys + M[2, 2]
            gx = (M[0, 0] * xs + M[0, 1] * ys + M[0, 2]) / den
            gy = (M[1, 0] * xs + M[1, 1] * ys + M[1, 2]) / den
            ref = np.hypot(f[..., 0] - gx, f[..., 1] - gy)
            sink.send(E.DENSE_REFINEMENT, sink.image(_turbo(ref, float(ref.max()) if ref.size else 0.0)))
        for path, a in maps.items():
            sink.send(path, sink.image(np.clip(255.0 * np.nan_to_num(a), 0, 255).astype(np.uint8)))
        sy, sx = slice(step // 2, h, step), slice(step // 2, w, step)
        origins = np.column_stack([xs[sy, sx].ravel(), ys[sy, sx].ravel()])
        vectors = disp[sy, sx].reshape(-1, 2)
        sink.send(E.DENSE_QUIVER, rr.Arrows2D(origins=origins, vectors=vectors, colors=[255, 220, 0], radii=0.8))
        sink.scalar(E.DENSE_MAX_DISPLACEMENT, top)
