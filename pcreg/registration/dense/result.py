"""The dense registration's result types: :class:`DenseRegistrationResult` and the callback's
:class:`DenseIteration`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..motion import field_from_matrix
from ..result import FieldsCompared, RegistrationResult

__all__ = ["DenseIteration", "DenseRegistrationResult"]


@dataclass(frozen=True, repr=False)
class DenseIteration:
    """One iteration of the dense ICP, handed to the optional callback.

    level : pyramid level; iteration : index within the level; stiffness : the schedule's value;
    points : (N,) moving samples; inliers : how many got a non-zero weight; rms : weighted RMS of the
    match residuals (full-resolution px); grid : (gh, gw, 2) displacements (full-resolution px) of the
    control grid from the global transform.
    """

    level: int
    iteration: int
    stiffness: float
    points: int
    inliers: int
    rms: float
    grid: np.ndarray

    def __repr__(self) -> str:
        return (f"DenseIteration(level={self.level}, iteration={self.iteration}, stiffness={self.stiffness:g}, "
                f"points={self.points}, inliers={self.inliers}, rms={self.rms:.3g})")


@dataclass(frozen=True, repr=False, eq=False)
class DenseRegistrationResult(FieldsCompared):
    """A dense registration: the global transform and the field that refines it.

    matrix : (3, 3) float64 global ``T_ref_mov`` (the start of the dense step).
    field : (H, W, 2) float32 reference coordinates (x, y) of every moving pixel.
    confidence : (H, W) float32 in [0, 1]: evidence behind the field at each pixel.
    global_result : the :class:`~pcreg.registration.result.RegistrationResult` of the global step.
    fitness : share of the finest level's samples matched with a non-zero weight.
    inlier_rmse : weighted RMS of their residuals after the last step (full-resolution px).
    iterations : dense iterations run (all levels). seconds : wall time, global step included (a given
        global result's own ``seconds`` added).
    grid : (gh, gw, 2) float32 displacements (full-resolution px) of the finest level's control grid
        from the global transform: the field is the global transform plus their bilinear interpolation.
        A later registration of the same reference can start from it (``initial`` of
        :func:`pcreg.register_dense`).
    """

    matrix: np.ndarray
    field: np.ndarray
    confidence: np.ndarray
    global_result: RegistrationResult
    fitness: float
    inlier_rmse: float
    iterations: int
    seconds: float
    backend: str = "reference"
    converged: bool = True
    grid: np.ndarray | None = None
    info: dict = field(default_factory=dict, compare=False)

    def __hash__(self) -> int:
        return hash((self.backend, self.iterations, self.matrix.shape))

    def __post_init__(self) -> None:
        for name in ("matrix", "field", "confidence", "grid"):
            if getattr(self, name) is None:
                continue
            a = np.array(getattr(self, name), copy=True)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def T_ref_mov(self) -> np.ndarray:
        """(3, 3) the global ``T_ref_mov`` (``matrix``) the field refines."""
        return self.matrix

    @property
    def trusted(self) -> None:
        """None: no check judges a dense field (``pcreg register --json`` says null). Its global step's checks are
        :attr:`global_result`'s (``global_result.trusted``)."""
        return None

    @property
    def displacement(self) -> np.ndarray:
        """(H, W, 2) float32: the field minus the global transform (full-resolution px)."""
        return self.field - field_from_matrix(self.matrix, self.field.shape[:2])

    def __repr__(self) -> str:
        h, w = self.field.shape[:2]
        return (f"DenseRegistrationResult(field={w}x{h}, fitness={self.fitness:.4f}, "
                f"inlier_rmse={self.inlier_rmse:.4g}, iterations={self.iterations}, "
                f"mean_confidence={float(self.confidence.mean()):.3f}, seconds={self.seconds:.4f}, "
                f"global={self.global_result!r})")

    def to_dict(self) -> dict:
        """JSON-ready summary (the arrays are left out; ``matrix`` is the global transform). The
        displacement's median is taken over every second pixel along each axis (a stream writes one such
        summary a frame: a median of a full 640x480 field took most of its time)."""
        from ..clouds import magnitude

        d = self.global_result.to_dict()
        shift = self.displacement
        disp = magnitude(shift[:, :, 0], shift[:, :, 1])  # not cv2.magnitude: its last bit depends on the buffers
        d.update(model="dense", dense_fitness=float(self.fitness), dense_inlier_rmse=float(self.inlier_rmse),
                 dense_iterations=int(self.iterations), seconds=float(self.seconds),
                 global_seconds=float(self.global_result.seconds),
                 mean_confidence=float(self.confidence.mean()),
                 median_displacement=float(np.median(disp[::2, ::2])), max_displacement=float(disp.max()),
                 evidence=float(self.info.get("evidence", float("nan"))))
        return d
