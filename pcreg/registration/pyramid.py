"""One image's edge clouds at pyramid levels 0..levels-1, each built on first access.

:func:`~pcreg.registration.api.register` reads its images through :class:`CloudPyramid`: a search that
ends at level 1 never builds levels 2-3. The levels come from the image itself
(:meth:`CloudPyramid.from_image`, the clouds of :func:`~pcreg.registration.clouds.cloud_pyramid`), from
an :class:`~pcreg.registration.clouds.ImagePyramid` the caller keeps (:meth:`CloudPyramid.from_detections`,
a stream builds each frame's once), or from another pyramid mirrored left-right (:meth:`CloudPyramid.mirrored`).
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from .clouds import ImageCloud, ImagePyramid, level_cloud, per_level, usable_mask


class CloudPyramid:
    """The clouds of ``image`` at levels 0..levels-1, ``build(level)`` called once per level on access.

    image : (H, W, 3) uint8, the full-resolution image (the intensity generators read it).
    valid : (H, W) bool usable pixels at full resolution (all True where no mask applies).
    """

    def __init__(self, image: np.ndarray, valid: np.ndarray, *, levels: int, build: Callable[[int], ImageCloud],
                 build_all: Callable[[int], ImageCloud] | None = None):
        self.image, self.valid = image, valid
        self._levels, self._build, self._build_all = levels, build, build_all
        self._clouds: dict[int, ImageCloud] = {}

    def every_point(self, level: int) -> ImageCloud | None:
        """The cloud of ``level`` with every edge point, not capped by ``max_points`` (a random subset leaves gaps
        that a point's own copy, moved, falls into); None for a pyramid that cannot build it (a mirrored one)."""
        return None if self._build_all is None else self._build_all(level)

    @classmethod
    def from_image(cls, image: np.ndarray, *, levels: int, mask, max_points, seed: int, **options) -> CloudPyramid:
        """:func:`~pcreg.registration.clouds.cloud_pyramid`'s levels (same clouds, same seeds); ``options``
        as its (sampler, canny_percentile, ...)."""
        max_points = per_level(max_points, levels)
        mask = usable_mask(mask, image)
        images = [image]

        def build(level: int, cap: bool = True) -> ImageCloud:
            while len(images) <= level:
                images.append(cv2.pyrDown(images[-1]))
            return level_cloud(images[level], level=level, shape=image.shape[:2], mask=mask,
                               max_points=max_points[level] if cap else None, seed=seed, **options)

        valid = np.ones(image.shape[:2], bool) if mask is None else mask
        return cls(image, valid, levels=levels, build=build, build_all=lambda level: build(level, cap=False))

    @classmethod
    def from_detections(cls, image: np.ndarray, pyramid: ImagePyramid, *, levels: int, max_points,
                        seed: int) -> CloudPyramid:
        """The levels drawn from ``pyramid`` (built by the caller for ``image``) with
        :meth:`from_image`'s sizes and seeds."""
        max_points = per_level(max_points, levels)
        valid = pyramid.valid if pyramid.valid is not None else np.ones(pyramid.shape, bool)
        return cls(image, valid, levels=levels,
                   build=lambda level: pyramid.cloud(level, max_points=max_points[level], seed=seed),
                   build_all=lambda level: pyramid.cloud(level, max_points=None, seed=seed))

    def mirrored(self) -> CloudPyramid:
        """The pyramid of the image mirrored left-right, level by level on access."""
        return CloudPyramid(np.ascontiguousarray(self.image[:, ::-1]), np.ascontiguousarray(self.valid[:, ::-1]),
                            levels=self._levels, build=lambda level: mirror_cloud(self[level]))

    def __len__(self) -> int:
        return self._levels

    def __getitem__(self, level: int) -> ImageCloud:
        if not 0 <= level < self._levels:
            raise IndexError(level)
        if level not in self._clouds:
            self._clouds[level] = self._build(level)
        return self._clouds[level]


def mirror_cloud(c: ImageCloud) -> ImageCloud:
    """The cloud of the image mirrored left-right (x -> W - 1 - x, normals' x negated)."""
    pts = c.points.copy()
    pts[:, 0] = (c.shape[1] - 1) - pts[:, 0]
    nrm = c.normals.copy()
    nrm[:, 0] = -nrm[:, 0]
    return ImageCloud(points=pts, colors=c.colors, normals=nrm, shape=c.shape, level=c.level)
