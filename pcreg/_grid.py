"""Nearest-neighbour look-up on a pixel grid for image clouds (an O(1)-per-query stand-in for a KD-tree).

The target points are rasterised on the grid of their pyramid level; a distance transform with labels
(``cv2.distanceTransformWithLabels``) gives, for every cell, the nearest occupied cell, hence a target
point. A query point is answered with that point of its own cell: the true nearest neighbour up to
about one cell. The reference ICP uses it at coarse pyramid levels, where it only has to bring the
estimate into the finer level's basin; the finest level uses the exact KD-tree.
"""

from __future__ import annotations

import cv2
import numpy as np


class GridNearest:
    """``query(points, distance_upper_bound=...)`` like ``scipy.spatial.cKDTree.query`` with k=1.

    target : (M, 2) float64 points in full-resolution pixel coordinates.
    cell : cell size in those coordinates (2^level); offset : (cell - 1) / 2 (pixel-centre convention).
    shape : (H, W) of the full-resolution image; targets outside it are clipped to the border cells.
    """

    def __init__(self, target: np.ndarray, *, cell: float, shape: tuple[int, int], margin: int = 2):
        self.target = target
        self.cell = float(cell)
        self.offset = (self.cell - 1.0) / 2.0
        self.margin = margin
        h = int(np.ceil(shape[0] / cell)) + 2 * margin
        w = int(np.ceil(shape[1] / cell)) + 2 * margin
        self.shape = (h, w)
        cx, cy = self._cells(target)
        grid = np.full((h, w), 255, np.uint8)
        grid[cy, cx] = 0
        owner = np.full((h, w), -1, np.intp)
        owner[cy, cx] = np.arange(len(target))
        _, labels = cv2.distanceTransformWithLabels(grid, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
        zy, zx = np.nonzero(grid == 0)
        label_owner = np.full(int(labels.max()) + 1, -1, np.intp)
        label_owner[labels[zy, zx]] = owner[zy, zx]
        self.nearest = label_owner[labels]

    def _cells(self, pts: np.ndarray):
        h, w = self.shape
        cx = np.clip(np.rint((pts[..., 0] - self.offset) / self.cell).astype(np.intp) + self.margin, 0, w - 1)
        cy = np.clip(np.rint((pts[..., 1] - self.offset) / self.cell).astype(np.intp) + self.margin, 0, h - 1)
        return cx, cy

    def lookup(self, pts: np.ndarray) -> np.ndarray:
        """Index of the (approximately) nearest target point for points of any leading shape (..., 2)."""
        cx, cy = self._cells(pts)
        return self.nearest[cy, cx]

    def query(self, pts: np.ndarray, k: int = 1, distance_upper_bound: float = np.inf, workers: int = 1):
        idx = self.lookup(pts)
        dist = np.linalg.norm(pts - self.target[idx], axis=-1)
        far = dist >= distance_upper_bound
        dist = np.where(far, np.inf, dist)
        idx = np.where(far, len(self.target), idx)
        return dist, idx
