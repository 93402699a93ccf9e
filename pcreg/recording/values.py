"""Checks and conversions of what the recorder's loggers are given: pure functions, no rerun."""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

import numpy as np

from ..errors import InputError

__all__ = ["as_image", "as_points", "as_colors", "display_indices", "apply_homography", "plain", "numbers", "leaves"]


def as_image(image: Any, name: str) -> np.ndarray:
    """``image`` as an (H, W, 3) or (H, W) uint8 array; anything else is an :class:`~pcreg.errors.InputError`."""
    a = np.asarray(image)
    if a.dtype != np.uint8 or not (a.ndim == 3 and a.shape[2] == 3 or a.ndim == 2) or a.size == 0:
        raise InputError(f"{name} must be an (H, W, 3) RGB or (H, W) uint8 image, got {a.dtype} {a.shape}")
    return a


def as_points(points: Any, name: str) -> np.ndarray:
    """``points`` as (N, 2) float64 pixel coordinates."""
    a = np.asarray(points, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{name} must be (N, 2) pixel coordinates, got shape {a.shape}")
    return a


def as_colors(colors: Any, n: int, name: str) -> np.ndarray | None:
    """(N, 3) float in 0..1 or uint8 -> (N, 3) uint8."""
    if colors is None:
        return None
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise InputError(f"{name} must be (N, 3) with N = {n}, got shape {c.shape}")
    if c.dtype == np.uint8:
        return c[:, :3]
    return np.clip(np.rint(c[:, :3].astype(np.float32) * 255.0), 0, 255).astype(np.uint8)


def display_indices(n: int, limit: int) -> np.ndarray | slice:
    """Evenly spaced indices of at most ``limit`` of ``n`` items (deterministic, order kept):
    ``np.linspace(0, n - 1, limit)`` truncated, by its own arithmetic without its checks (under 2 us
    against 5, three times a recorded ICP iteration)."""
    if n <= limit:
        return slice(None)
    if limit <= 1:
        return np.zeros(max(limit, 0), np.intp)
    idx = (np.arange(limit, dtype=np.float64) * ((n - 1) / (limit - 1))).astype(np.intp)
    idx[-1] = n - 1
    return idx


def apply_homography(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 2) points by a (3, 3) homogeneous matrix."""
    h = points @ matrix[:2, :2].T + matrix[:2, 2]
    w = points @ matrix[2, :2] + matrix[2, 2]
    return h / w[:, None]


def plain(obj: Any) -> Any:
    """JSON-ready copy of a report or config: dataclasses and results become dicts."""
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return plain(obj.to_dict())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return plain(dataclasses.asdict(obj))
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def leaves(obj: Any, keys: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], float]]:
    """Every int/float leaf of a nested mapping (booleans left out) with the keys that lead to it."""
    if isinstance(obj, Mapping):
        return [leaf for k, v in obj.items() for leaf in leaves(v, (*keys, str(k)))]
    if isinstance(obj, (int, float, np.integer, np.floating)) and not isinstance(obj, (bool, np.bool_)):
        return [(keys, float(obj))]
    return []


def numbers(obj: Any, prefix: str = "") -> dict[str, float]:
    """Every int/float leaf of a nested dict, keyed by the path of keys joined with '/' (:func:`leaves`)."""
    return {"/".join(k for k in ((prefix,) if prefix else ()) + keys): v for keys, v in leaves(obj)}
