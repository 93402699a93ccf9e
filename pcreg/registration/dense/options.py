"""The dense registration's options."""

from __future__ import annotations

from dataclasses import dataclass

from ...errors import InputError
from ...validation import check_bool, check_float, check_floats, check_int
from .grid import _grid_shape

__all__ = ["DENSE_GLOBAL_MODEL", "STIFFNESS_SCHEDULE", "DenseOptions", "dense_options", "finest_grid_shape"]

#: Stiffness per iteration of a level (Amberg et al. 2007: stiff to relaxed); the last value repeats.
STIFFNESS_SCHEDULE: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
#: The global step of the dense model: a similarity (rotation, shift and the zoom of forward motion).
DENSE_GLOBAL_MODEL = "similarity"


@dataclass(frozen=True)
class DenseOptions:
    """The dense step's options of :func:`pcreg.register_dense`, checked (see its docstring for each)."""

    levels: int = 5
    finest_level: int = 1
    iterations: int = 8
    grid_spacing: float = 8.0
    radius: int = 3
    fine_radius: int = 2
    max_points: int = 10000
    stiffness: tuple[float, ...] = STIFFNESS_SCHEDULE
    strain: float = 0.25
    edge_aware: bool = False
    cg_iterations: int = 30
    texture: float | None = 4.0
    chance_factor: float | None = None


def dense_options(shape: tuple[int, ...], *, levels, finest_level, iterations, grid_spacing, radius, fine_radius,
                  max_points, stiffness, strain, edge_aware, cg_iterations, texture,
                  chance_factor) -> DenseOptions:
    """The options checked, in the order their errors are reported (images of ``shape``)."""
    levels = check_int(levels, "levels", lo=1, hi=8)
    finest_level = check_int(finest_level, "finest_level", lo=0, hi=levels - 1)
    iterations = check_int(iterations, "iterations", lo=1, hi=100_000)
    radius = check_int(radius, "radius", lo=1, hi=64)
    fine_radius = check_int(fine_radius, "fine_radius", lo=1, hi=64)
    max_points = check_int(max_points, "max_points", lo=16)
    grid_spacing = check_float(grid_spacing, "grid_spacing", lo=2, hi=max(shape[:2]))
    cg_iterations = check_int(cg_iterations, "cg_iterations", lo=0, hi=100_000)
    stiffness = check_floats(stiffness, "stiffness", lo=0, lo_open=True)
    if not stiffness:
        raise InputError("stiffness must be a non-empty sequence of positive numbers")
    strain = check_float(strain, "strain", lo=0, lo_open=True, hi=100)
    edge_aware = check_bool(edge_aware, "edge_aware")
    if texture is not None:
        texture = check_float(texture, "texture", lo=0, lo_open=True, hi=max(shape[:2]))
    if chance_factor is not None:
        chance_factor = check_float(chance_factor, "chance_factor", lo=0)
    return DenseOptions(levels=levels, finest_level=finest_level, iterations=iterations, grid_spacing=grid_spacing,
                        radius=radius, fine_radius=fine_radius, max_points=max_points, stiffness=stiffness,
                        strain=strain, edge_aware=edge_aware, cg_iterations=cg_iterations, texture=texture,
                        chance_factor=chance_factor)


def _coarsest_level(shape: tuple[int, ...], options: DenseOptions) -> int:
    """The coarsest pyramid level worked at: ``levels - 1``, or finer where the image would be under 16 px."""
    coarsest = options.levels - 1
    while coarsest > options.finest_level and min(shape[:2]) >> coarsest < 16:
        coarsest -= 1
    return coarsest


def finest_grid_shape(shape: tuple[int, ...], options: DenseOptions) -> tuple[int, int]:
    """The finest level's control grid (rows, columns) for images of ``shape`` (full size)."""
    h, w = shape[:2]
    for _ in range(options.finest_level):
        h, w = (h + 1) // 2, (w + 1) // 2  # cv2.pyrDown's sizes
    return _grid_shape(h, w, float(options.grid_spacing))

