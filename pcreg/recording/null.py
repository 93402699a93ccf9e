"""The recorder that records nothing, so that the experiments have one code path with or without ``--record``.

Like pycpd's ``callback=lambda **kw: None``: an experiment takes a recorder and calls it; without a
recording it is :data:`NULL_RECORDER`, which implements every method of
:class:`~pcreg.recording.interface.RecorderProtocol` by doing nothing, and whose
:meth:`NullRecorder.icp_callback` is ``None`` (the ICP then runs with no callback at all). ``enabled``
tells the two apart where a caller must plan differently (a recording is written by one process, in frame
order). This module imports nothing but the protocol: making one costs nothing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from .interface import RecorderProtocol

if TYPE_CHECKING:
    import numpy as np

__all__ = ["NULL_RECORDER", "NullRecorder"]


class NullRecorder(RecorderProtocol):
    """Stands for a :class:`pcreg.recording.recorder.Recorder` when nothing is recorded: every method returns None."""

    enabled = False

    def set_frame(self, index: int) -> None:
        return None

    def flush(self) -> None:
        return None

    def log_config(self, config: Any) -> None:
        return None

    def log_text(self, text: str, level: str = "INFO") -> None:
        return None

    def log_failure(self, text: str) -> None:
        return None

    def log_images(self, *, reference: np.ndarray | None = None, moving: np.ndarray | None = None,
                   warped: np.ndarray | None = None, valid_mask: np.ndarray | None = None) -> None:
        return None

    def log_clouds(self, *, reference_points: np.ndarray | None = None, reference_colors: np.ndarray | None = None,
                   moving_points: np.ndarray | None = None, moving_colors: np.ndarray | None = None) -> None:
        return None

    def log_transform(self, matrix: np.ndarray, *, name: str = "T_ref_mov",
                      moving_shape: tuple[int, int] | None = None) -> None:
        return None

    def log_dense(self, field: np.ndarray, *, matrix: np.ndarray | None = None, confidence: np.ndarray | None = None,
                  warped_prior: np.ndarray | None = None, quiver_step: int = 24) -> None:
        return None

    def log_labels(self, *, truth: np.ndarray | None = None, predicted: np.ndarray | None = None,
                   prefix: str = "") -> None:
        return None

    def log_classes(self, table: Any) -> None:
        return None

    def log_errors(self, errors: Mapping[str, float]) -> None:
        return None

    def icp_callback(self, backend: str, *, max_points: int = 300, max_correspondences: int = 200) -> None:
        """No callback: the ICP is not slowed by one that would drop every iteration."""
        return None

    def log_crosscheck(self, report: Mapping[str, Any]) -> None:
        return None

    def log_crosscheck_target(self, points: np.ndarray) -> None:
        return None

    def log_crosscheck_iteration(self, implementation: str, iteration: int, points: np.ndarray, *,
                                 error: float | None = None, fitness: float | None = None,
                                 inlier_rmse: float | None = None) -> None:
        return None

    def __repr__(self) -> str:
        return "NULL_RECORDER"


NULL_RECORDER = NullRecorder()
