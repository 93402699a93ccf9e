"""One configuration for image registration, nested in every configuration that registers images.

:class:`RegisterConfig` holds :func:`pcreg.register`'s options (its defaults are ``register``'s), split by
the step that uses them, as ``register`` is:

- :class:`PyramidConfig`: how each image becomes a cloud per pyramid level (:mod:`.pyramid`);
- :class:`SearchConfig`: where the hypotheses come from (:mod:`.search`);
- :class:`IcpConfig`: the backend's ICP and the coarse-to-fine refinement (:mod:`.refine`);
- :class:`PlausibilityConfig`: the test a result must pass (:mod:`.plausibility`);

and the motion ``model``, which every step shares. Each part unpacks into the keyword arguments of its
own step (``config.icp.kwargs()``); :meth:`RegisterConfig.kwargs` gives all of them, ``register``'s
keyword arguments, so the algorithm never sees a config object. The pipeline
(:class:`~pcreg.pipeline.pair.PipelineConfig`) and the evaluations nest one.

Changing an option names it where it lives, or by its flat name, which is unique across the parts::

    cfg = RegisterConfig.of(model="similarity", init="identity", min_inlier_ratio=None)
    cfg.search.init                                  # "identity"
    cfg.replace(backend="open3d").icp.backend        # "open3d"
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..errors import InputError

BACKENDS = ("reference", "open3d")  # the ICP steps of steps.ICP_STEPS, in that order
INITS = ("auto", "global", "identity", "center")


class _Part:
    """A part of :class:`RegisterConfig`: frozen, its fields are ``register``'s keyword arguments."""

    def kwargs(self) -> dict[str, Any]:
        """This part's options as keyword arguments."""
        return {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]


@dataclass(frozen=True)
class PyramidConfig(_Part):
    """Clouds per level. levels : pyramid levels (1..8). sampler : ``"canny"`` edges or another of
    :data:`pcreg.registration.clouds.SAMPLERS`. max_points : moving points kept per level (finest first).
    reference_max_points : reference points kept per level. canny_percentile : the edge threshold."""

    levels: int = 4
    sampler: str = "canny"
    max_points: tuple[int, ...] = (2000, 800, 600, 400)
    reference_max_points: int | None = 60000
    canny_percentile: float = 85.0

    def __post_init__(self) -> None:
        if not isinstance(self.levels, int) or not 1 <= self.levels <= 8:
            raise InputError(f"levels must be an integer in 1..8, got {self.levels!r}")
        if self.max_points is not None and not isinstance(self.max_points, int):
            object.__setattr__(self, "max_points", tuple(self.max_points))


@dataclass(frozen=True)
class SearchConfig(_Part):
    """Hypotheses. init : ``"auto"``/``"global"`` (the global search), ``"identity"`` or ``"center"``.
    generators : the search's hypothesis generators, tried in order. angle_step : degrees between the
    rotations tried. n_candidates : hypotheses refined per generator. seed : random choices."""

    init: str = "auto"
    generators: tuple[str, ...] = ("fourier_mellin", "edges", "orb")
    angle_step: float = 15.0
    n_candidates: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.init, str) and self.init not in INITS:
            raise InputError(f"init must be {', '.join(INITS[:-1])} or {INITS[-1]}, got {self.init!r}")
        object.__setattr__(self, "generators",
                           (self.generators,) if isinstance(self.generators, str) else tuple(self.generators))


@dataclass(frozen=True)
class IcpConfig(_Part):
    """The ICP of every step. backend : ``"reference"`` or ``"open3d"``. iterations : per level.
    max_correspondence_distance : px at full resolution. refine : ``"none"`` or ``"point_to_line"``.
    weights : robust weights. relative_fitness, relative_rmse : the stopping rule per level."""

    backend: str = "reference"
    iterations: int = 14
    max_correspondence_distance: float = 2.5
    refine: str | None = "none"
    weights: str = "none"
    relative_fitness: float = 1e-4
    relative_rmse: float = 1e-3

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise InputError(f"unknown backend {self.backend!r}; choose one of {', '.join(BACKENDS)}")
        if not isinstance(self.iterations, int) or self.iterations < 1:
            raise InputError(f"iterations must be an integer >= 1, got {self.iterations!r}")


@dataclass(frozen=True)
class PlausibilityConfig(_Part):
    """The test. min_inlier_ratio : the share of moving points that must land within ``inlier_tolerance``
    px of a reference point (None turns the test off)."""

    min_inlier_ratio: float | None = 0.15
    inlier_tolerance: float = 1.0


_PARTS: dict[str, type[_Part]] = {"pyramid": PyramidConfig, "search": SearchConfig, "icp": IcpConfig,
                                  "plausibility": PlausibilityConfig}
_HOME = {f.name: part for part, cls in _PARTS.items() for f in fields(cls)}  # type: ignore[arg-type]


@dataclass(frozen=True)
class RegisterConfig:
    """Options of :func:`pcreg.register` by step; frozen, change with :meth:`replace`.

    model : the motion model, shared by every step. pyramid, search, icp, plausibility : the parts
    (:class:`PyramidConfig`, :class:`SearchConfig`, :class:`IcpConfig`, :class:`PlausibilityConfig`).
    """

    model: str = "rigid"
    pyramid: PyramidConfig = field(default_factory=PyramidConfig)
    search: SearchConfig = field(default_factory=SearchConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)

    def __post_init__(self) -> None:
        for name, cls in _PARTS.items():
            if not isinstance(getattr(self, name), cls):
                raise InputError(f"RegisterConfig.{name} must be a {cls.__name__} instance, got {type(getattr(self, name)).__name__}")
        # a model the backend cannot fit is refused when the configuration is made, not at its first pair
        # ("dense" is the pipeline's: a similarity refined by a field, pcreg.pipeline.pair.DENSE_GLOBAL_MODEL)
        if self.icp.backend == "open3d" and self.model != "dense":
            from .open3d_icp import check_model

            check_model(self.model)

    @classmethod
    def of(cls, **options: Any) -> "RegisterConfig":
        """The default configuration with ``options`` changed, each by its flat name (``backend=...``)."""
        return cls().replace(**options)

    @property
    def backend(self) -> str:
        """The ICP backend (``icp.backend``), which the pipeline and the evaluations report."""
        return self.icp.backend

    def kwargs(self) -> dict[str, Any]:
        """``register``'s keyword arguments (every option of every part)."""
        out: dict[str, Any] = {"model": self.model}
        for name in _PARTS:
            out.update(getattr(self, name).kwargs())
        return out

    def replace(self, **changes: Any) -> "RegisterConfig":
        """A copy with ``changes``: ``model``, a whole part (``icp=IcpConfig(...)``) or any option by its
        flat name (``backend="open3d"``, routed to its part)."""
        top = {k: changes.pop(k) for k in list(changes) if k == "model" or k in _PARTS}
        unknown = sorted(k for k in changes if k not in _HOME)
        if unknown:
            raise InputError(f"unknown registration option(s): {', '.join(unknown)}")
        by_part: dict[str, dict[str, Any]] = {}
        for k, v in changes.items():
            by_part.setdefault(_HOME[k], {})[k] = v
        for part, values in by_part.items():
            top[part] = replace(top.get(part, getattr(self, part)), **values)
        return replace(self, **top)
