"""What the code that logs may ask of a recorder: :class:`RecorderProtocol`, the one list of its methods.

Experiments, the pipeline's hooks and the commands take a recorder and call these methods, and nothing
else; :class:`pcreg.recording.recorder.Recorder` (writes a recording) and
:class:`pcreg.recording.null.NullRecorder` (records nothing) both subclass the protocol, so mypy checks
each of them against it, method for method. Entity paths are named in :mod:`pcreg.recording.entities`.
This module imports nothing at run time.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol

if TYPE_CHECKING:
    import numpy as np

    from ..registration.result import IcpIteration

__all__ = ["RecorderProtocol"]


class RecorderProtocol(Protocol):
    """The methods a recorder offers; every array is checked and copied before the call returns.

    Images are (H, W, 3) uint8 RGB or (H, W) uint8 grey; pixel coordinates are (N, 2) float, x right and
    y down; label maps are (H, W) integer class ids (0 ground, 1 obstacle, 2 unknown).
    """

    #: False when nothing is recorded: a caller skips work done only for the recording.
    enabled: bool

    def set_frame(self, index: int) -> None:
        """Put what follows on the ``frame`` timeline at ``index`` (a new registration pair)."""

    def flush(self) -> None:
        """Block until everything logged so far is in the file."""

    def log_config(self, config: Any) -> None:
        """The run's configuration (a dict or a dataclass): the ``config`` document and a line on the log."""

    def log_text(self, text: str, level: str = "INFO") -> None:
        """A line on the text log; ``level`` is TRACE, DEBUG, INFO, WARN (or WARNING), ERROR or CRITICAL."""

    def log_failure(self, text: str) -> None:
        """A failure, as an ERROR line on the text log."""

    def log_images(self, *, reference: np.ndarray | None = None, moving: np.ndarray | None = None,
                   warped: np.ndarray | None = None, valid_mask: np.ndarray | None = None) -> None:
        """The pair's images: ``warped`` is the moving image on the reference's pixel grid (drawn over the
        reference at half opacity); ``valid_mask`` (H, W) bool, where ``warped`` has data. The moving
        image's size is the pair's (:meth:`log_transform` draws its border)."""

    def log_clouds(self, *, reference_points: np.ndarray | None = None, reference_colors: np.ndarray | None = None,
                   moving_points: np.ndarray | None = None, moving_colors: np.ndarray | None = None) -> None:
        """The pair's clouds: (N, 2) float pixel coordinates in their own image, colours (N, 3) float in
        0..1 or uint8. The moving cloud is also drawn in the reference, mapped by the pair's ``T_ref_mov``."""

    def log_transform(self, matrix: np.ndarray, *, name: str = "T_ref_mov",
                      moving_shape: tuple[int, int] | None = None) -> None:
        """A transform, exactly: (3, 3) homogeneous (drawn: the moving border mapped into the reference,
        ``moving_shape`` (H, W) or else the pair's moving image size) or (4, 4) (not drawn)."""

    def log_dense(self, field: np.ndarray, *, matrix: np.ndarray | None = None, confidence: np.ndarray | None = None,
                  warped_prior: np.ndarray | None = None, quiver_step: int = 24) -> None:
        """A dense registration: ``field`` (H, W, 2) float, the reference coordinates of every moving pixel;
        ``matrix`` (3, 3) the global ``T_ref_mov`` it refines; ``confidence`` and ``warped_prior`` (H, W)
        float in [0, 1]; arrows every ``quiver_step`` pixels."""

    def log_labels(self, *, truth: np.ndarray | None = None, predicted: np.ndarray | None = None,
                   prefix: str = "") -> None:
        """Label maps; ``prefix`` tells several predictions apart."""

    def log_classes(self, table: Any) -> None:
        """The class table (a :class:`~pcreg.classes.ClassTable`) the label maps' ids are of: each class's name
        and colour in the viewer, in place of 0 ground, 1 obstacle, 2 unknown."""

    def log_errors(self, errors: Mapping[str, float]) -> None:
        """Error rates in percent, by method; NaN is left out."""

    def icp_callback(self, backend: str, *, max_points: int = 300,
                     max_correspondences: int = 200) -> Callable[[IcpIteration], None] | None:
        """A callback for either ICP that logs its iterations (None: run the ICP without one)."""

    def log_crosscheck(self, report: Mapping[str, Any]) -> None:
        """A cross-check's report (results and dataclasses converted): the document and its numbers."""

    def log_crosscheck_target(self, points: np.ndarray) -> None:
        """The target cloud of a cloud cross-check, (N, 2) or (N, 3)."""

    def log_crosscheck_iteration(self, implementation: str, iteration: int, points: np.ndarray, *,
                                 error: float | None = None, fitness: float | None = None,
                                 inlier_rmse: float | None = None) -> None:
        """One implementation's iteration of a cloud cross-check: its moved source cloud and numbers."""
