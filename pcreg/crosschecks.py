"""Run both ICP backends on identical inputs and report where they differ.

Identical inputs: the same clouds (extracted or downsampled once), the same initial guess, the same
correspondence distances, iteration limits and stopping rule (Open3D's, ``relative_fitness`` and
``relative_rmse`` compared as absolute changes). The reference backend runs with exact KD-tree
correspondences, point-to-point, no robust weights — the configuration that must reproduce Open3D.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .errors import InputError
from .registration.clouds import as_rgb_uint8, cloud_pyramid, load_image
from .registration.api import _global_search, check_cloud, icp
from .registration.result import IcpIteration, RegistrationResult
from .registration.transforms import apply, corners, rotation_disagreement_deg

CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts", ".npy")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")


@dataclass(frozen=True)
class CrosscheckConfig:
    """Settings shared by both backends."""

    model: str = "rigid"
    levels: int = 4
    iterations: int = 30
    relative_fitness: float = 1e-6
    relative_rmse: float = 1e-6
    max_correspondence_distance: float = 2.5  # px at level 0 for images (x 2^level); cloud units otherwise
    max_points: tuple[int, ...] = (3000, 1500, 800, 400)
    voxel_sizes: tuple[float, ...] | None = None  # clouds: None = derived from the source's point spacing
    init: str = "auto"
    seed: int = 0


@dataclass(frozen=True)
class CrosscheckReport:
    kind: str  # "images" or "clouds"
    reference: RegistrationResult
    open3d: RegistrationResult
    config: CrosscheckConfig
    max_corner_disagreement_px: float | None = None
    rotation_disagreement_deg: float | None = None
    translation_disagreement: float | None = None
    matrix_relative_disagreement: float = 0.0
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        out = {"kind": self.kind, "reference": self.reference.to_dict(), "open3d": self.open3d.to_dict(),
               "matrix_relative_disagreement": self.matrix_relative_disagreement,
               "reference_seconds": self.reference.seconds, "open3d_seconds": self.open3d.seconds}
        if self.kind == "images":
            out["max_corner_disagreement_px"] = self.max_corner_disagreement_px
        out["rotation_disagreement_deg"] = self.rotation_disagreement_deg
        out["translation_disagreement"] = self.translation_disagreement
        out["config"] = asdict(self.config)
        out.update(self.extra)
        return out


def load_cloud(path: str | os.PathLike) -> np.ndarray:
    """Points (N, 3) (or (N, 2) from a .npy) from .ply/.pcd/.xyz/.pts via Open3D, or .npy via numpy."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            pts = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise InputError(f"{path}: not a numpy array file ({exc})") from None
    elif suffix in CLOUD_SUFFIXES:
        import open3d as o3d

        pcd = o3d.io.read_point_cloud(str(path))
        pts = np.asarray(pcd.points)
        if pts.size == 0:
            raise InputError(f"{path}: no points could be read (empty or not a {suffix} point cloud)")
    else:
        raise InputError(f"{path}: unknown point-cloud format {suffix!r} (use {', '.join(CLOUD_SUFFIXES)})")
    return check_cloud(pts, str(path))


def _relative(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.max(np.abs(A - B)) / max(1.0, float(np.max(np.abs(A)))))


def default_voxel_sizes(points: np.ndarray) -> tuple[float, ...]:
    """A coarse-to-fine voxel schedule from the cloud's bounding-box diagonal D: (D/75, D/150, D/300).

    With correspondence distances of twice the voxel size, the coarsest level reaches misalignments of
    a scan pair taken a step apart (misaligned by ~1% of the scene); the finest refines on a dense cloud.
    """
    diag = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    if not diag > 0:
        raise InputError("cannot derive a voxel size: the cloud's points coincide")
    return (diag / 75, diag / 150, diag / 300)


def crosscheck_clouds(source: np.ndarray, target: np.ndarray, *, config: CrosscheckConfig = CrosscheckConfig(),
                      init: np.ndarray | None = None,
                      callback: Callable[[IcpIteration], None] | None = None) -> CrosscheckReport:
    """Both backends on two clouds with the same voxel schedule and initial guess (identity by default)."""
    src = check_cloud(source, "source")
    tgt = check_cloud(target, "target")
    voxels = config.voxel_sizes or default_voxel_sizes(src)
    kw = dict(model=config.model, init=init, voxel_sizes=voxels, max_iteration=config.iterations,
              relative_fitness=config.relative_fitness, relative_rmse=config.relative_rmse, count_iterations=True)
    a = icp(src, tgt, backend="reference", callback=callback, **kw)
    b = icp(src, tgt, backend="open3d", callback=callback, **kw)
    d = src.shape[1]
    return CrosscheckReport(
        kind="clouds", reference=a, open3d=b, config=config,
        rotation_disagreement_deg=rotation_disagreement_deg(a.matrix, b.matrix),
        translation_disagreement=float(np.linalg.norm(a.matrix[:d, d] - b.matrix[:d, d])),
        matrix_relative_disagreement=_relative(a.matrix, b.matrix),
        extra={"voxel_sizes": list(voxels), "source_points": len(src), "target_points": len(tgt)})


def crosscheck_images(reference_image: np.ndarray, moving_image: np.ndarray, *,
                      config: CrosscheckConfig = CrosscheckConfig(),
                      callback: Callable[[IcpIteration], None] | None = None) -> CrosscheckReport:
    """Both backends coarse to fine on the same image clouds from the same (global-search) initial guess."""
    ref = as_rgb_uint8(reference_image, name="reference image")
    mov = as_rgb_uint8(moving_image, name="moving image")
    ref_levels = cloud_pyramid(ref, levels=config.levels, seed=config.seed)
    mov_levels = cloud_pyramid(mov, levels=config.levels, max_points=config.max_points, seed=config.seed + 1)
    from .errors import RegistrationError

    if len(ref_levels[0]) < 3 or len(mov_levels[0]) < 3:
        raise RegistrationError("an image has no usable edges (a flat or empty image?)")
    T0 = np.eye(3)
    if config.init in ("auto", "global"):
        g = min(3, config.levels - 1)
        Ts, score = _global_search(ref_levels[g], mov_levels[g], angles=np.arange(0.0, 360.0, 10.0))
        T0 = Ts[int(np.argmax(score))]
    results = {}
    for backend in ("reference", "open3d"):
        T, total, seconds = T0, 0, 0.0
        res = None
        for level in range(config.levels - 1, -1, -1):
            s, t = mov_levels[level].points, ref_levels[level].points
            if len(s) < 3 or len(t) < 3:
                continue
            res = icp(s, t, backend=backend, model=config.model, init=T,
                      max_correspondence_distance=config.max_correspondence_distance * 2**level,
                      max_iteration=config.iterations, relative_fitness=config.relative_fitness,
                      relative_rmse=config.relative_rmse, count_iterations=True,
                      callback=callback)
            T, total, seconds = res.matrix, total + max(res.iterations, 0), seconds + res.seconds
        results[backend] = RegistrationResult(matrix=T, fitness=res.fitness, inlier_rmse=res.inlier_rmse,
                                              iterations=total, converged=res.converged, backend=backend,
                                              seconds=seconds)
    a, b = results["reference"], results["open3d"]
    c = corners(mov.shape)
    return CrosscheckReport(
        kind="images", reference=a, open3d=b, config=config,
        max_corner_disagreement_px=float(np.max(np.linalg.norm(apply(a.matrix, c) - apply(b.matrix, c), axis=1))),
        rotation_disagreement_deg=rotation_disagreement_deg(a.matrix, b.matrix),
        translation_disagreement=float(np.linalg.norm(a.matrix[:2, 2] - b.matrix[:2, 2])),
        matrix_relative_disagreement=_relative(a.matrix, b.matrix),
        extra={"initial_matrix": T0.tolist()})


def crosscheck(reference, moving, *, config: CrosscheckConfig = CrosscheckConfig(), callback=None) -> CrosscheckReport:
    """Cross-check the backends: register ``moving`` onto ``reference`` (two images or two point clouds,
    arrays or file paths); for clouds the reference is the ICP target and the moving cloud the source.

    Image arrays are (H, W, 3)/(H, W); cloud arrays (N, 2|3). Paths are read by suffix: images through
    OpenCV, clouds (.ply/.pcd/.xyz/.pts) through Open3D, .npy through numpy.
    """
    def kind_of(x):
        if isinstance(x, (str, os.PathLike)):
            suffix = Path(x).suffix.lower()
            if suffix in CLOUD_SUFFIXES:
                return "clouds", load_cloud(x)
            if suffix in IMAGE_SUFFIXES or not suffix:
                return "images", load_image(x)
            raise InputError(f"{x}: unknown file type {suffix!r} (an image or a point cloud)")
        arr = np.asarray(x)
        if arr.ndim == 2 and arr.shape[1] in (2, 3) and arr.shape[0] > 16 and np.issubdtype(arr.dtype, np.floating):
            return "clouds", arr
        return "images", arr

    ka, A = kind_of(reference)
    kb, B = kind_of(moving)
    if ka != kb:
        raise InputError(f"cannot cross-check {ka[:-1]} against {kb[:-1]}: give two images or two clouds")
    if ka == "clouds":
        return crosscheck_clouds(B, A, config=config, callback=callback)
    return crosscheck_images(A, B, config=config, callback=callback)
