"""One configuration for image registration, nested in every configuration that registers images.

:class:`RegisterConfig` holds :func:`pcreg.register`'s options (its defaults are ``register``'s); the
pipeline (:class:`~pcreg.pipeline.pair.PipelineConfig`) and the evaluations nest one and unpack it into ``register``'s
keyword arguments with :meth:`RegisterConfig.kwargs`, so the algorithm never sees a config object.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from ..errors import InputError

BACKENDS = ("reference", "open3d")  # the ICP steps of steps.ICP_STEPS, in that order


@dataclass(frozen=True)
class RegisterConfig:
    """Options of :func:`pcreg.register` (see there for each); frozen, change with :meth:`replace`.

    backend : ``"reference"`` or ``"open3d"``. model : motion model. levels : pyramid levels.
    iterations : ICP iterations per level. init : ``"auto"``/``"global"`` (global search),
    ``"identity"`` or ``"center"``. The rest as ``register``'s keyword arguments of the same name.
    """

    backend: str = "reference"
    model: str = "rigid"
    levels: int = 4
    iterations: int = 14
    init: str = "auto"
    sampler: str = "canny"
    max_points: tuple[int, ...] = (2000, 800, 600, 400)
    reference_max_points: int | None = 60000
    max_correspondence_distance: float = 2.5
    refine: str | None = "none"
    weights: str = "none"
    relative_fitness: float = 1e-4
    relative_rmse: float = 1e-3
    angle_step: float = 15.0
    n_candidates: int = 2
    generators: tuple[str, ...] = ("fourier_mellin", "edges", "orb")
    min_inlier_ratio: float | None = 0.15
    inlier_tolerance: float = 1.0
    canny_percentile: float = 85.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise InputError(f"unknown backend {self.backend!r}; choose one of {', '.join(BACKENDS)}")
        if isinstance(self.init, str) and self.init not in ("auto", "global", "identity", "center"):
            raise InputError(f"init must be auto, global, identity or center, got {self.init!r}")
        if not isinstance(self.levels, int) or not 1 <= self.levels <= 8:
            raise InputError(f"levels must be an integer in 1..8, got {self.levels!r}")
        if not isinstance(self.iterations, int) or self.iterations < 1:
            raise InputError(f"iterations must be an integer >= 1, got {self.iterations!r}")
        object.__setattr__(self, "max_points", tuple(self.max_points))
        object.__setattr__(self, "generators",
                           (self.generators,) if isinstance(self.generators, str) else tuple(self.generators))

    def kwargs(self) -> dict:
        """``register``'s keyword arguments (every field)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def replace(self, **changes) -> "RegisterConfig":
        """A copy with ``changes`` (``dataclasses.replace``)."""
        return replace(self, **changes)
