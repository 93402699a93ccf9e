"""Result types shared by both ICP backends."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _fmt_matrix(m: np.ndarray) -> str:
    return "[" + ", ".join("[" + ", ".join(f"{v:.6g}" for v in row) + "]" for row in np.asarray(m)) + "]"


@dataclass(frozen=True, repr=False)
class RegistrationResult:
    """What both ICP backends return, so they can be compared field by field.

    matrix : (3, 3) or (4, 4) float64
        Homogeneous transform that maps moving/source coordinates into reference/target
        coordinates (``T_ref_mov``).
    fitness : float
        Fraction of source points with a correspondence within the max distance (Open3D's definition).
    inlier_rmse : float
        RMS distance over those correspondences (0 when there are none), in the cloud's units.
    iterations : int
        ICP iterations run, summed over pyramid levels (-1 where the backend cannot tell).
    converged : bool
        The stopping rule fired before ``max_iteration`` at the finest level.
    backend : str
        ``"reference"`` or ``"open3d"``.
    seconds : float
        Wall time of the registration alone (no I/O, no imports).
    """

    matrix: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int
    converged: bool
    backend: str
    seconds: float = 0.0
    info: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        m = np.array(self.matrix, dtype=np.float64, copy=True)
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)

    def __repr__(self) -> str:
        return (
            f"RegistrationResult(backend={self.backend!r}, fitness={self.fitness:.4f}, "
            f"inlier_rmse={self.inlier_rmse:.4g}, iterations={self.iterations}, converged={self.converged}, "
            f"seconds={self.seconds:.4f}, matrix={_fmt_matrix(self.matrix)})"
        )

    def to_dict(self) -> dict:
        """JSON-ready dict (``matrix`` as a list of rows)."""
        return {
            "matrix": self.matrix.tolist(),
            "fitness": float(self.fitness),
            "inlier_rmse": float(self.inlier_rmse),
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "backend": self.backend,
            "seconds": float(self.seconds),
        }


@dataclass(frozen=True, repr=False)
class IcpIteration:
    """One ICP iteration, handed to the optional per-iteration callback.

    source_points : (N, d) float64 — the source cloud moved by ``matrix`` (this level's units: pixels
    of the full-resolution image for image registration).
    target_indices : (N,) int — index of each source point's correspondence in ``target_points``, -1 for none.
    """

    backend: str
    level: int
    iteration: int
    matrix: np.ndarray
    fitness: float
    inlier_rmse: float
    source_points: np.ndarray
    target_points: np.ndarray
    target_indices: np.ndarray

    def __repr__(self) -> str:
        return (f"IcpIteration(backend={self.backend!r}, level={self.level}, iteration={self.iteration}, "
                f"fitness={self.fitness:.4f}, inlier_rmse={self.inlier_rmse:.4g})")
