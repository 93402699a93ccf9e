"""One configuration for image registration, nested in every configuration that registers images.

:class:`RegisterConfig` holds :func:`pcreg.register`'s options, split by the step that uses them, as
``register`` is:

- :class:`PyramidConfig`: how each image becomes a cloud per pyramid level (:mod:`.pyramid`);
- :class:`SearchConfig`: where the hypotheses come from (:mod:`.search`);
- :class:`IcpConfig`: the backend's ICP and the coarse-to-fine refinement (:mod:`.refine`);
- :class:`PlausibilityConfig`: the test a result must pass (:mod:`.plausibility`);

and the motion ``model``, which every step shares. The defaults are written here only, and each part
checks and normalises its options when it is made (an :class:`~pcreg.errors.InputError` for the first
bad one), so ``register`` takes a config that is already valid and builds each step from its part.
The pipeline (:class:`~pcreg.pipeline.pair.PipelineConfig`) and the evaluations nest one.

Changing an option names it where it lives, or by its flat name, which is unique across the parts::

    cfg = RegisterConfig.of(model="similarity", init="identity", min_inlier_ratio=None)
    cfg.search.init                                  # "identity"
    cfg.replace(backend="open3d").icp.backend        # "open3d"
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..errors import InputError
from ..validation import check_choice, check_count, check_counts, check_float, check_int, short_repr
from .choices import BACKENDS, WEIGHTS, check_open3d_model

INITS = ("auto", "global", "identity", "center")
REFINES = ("none", "point_to_line")

DEFAULT_MIN_INLIER_RATIO = 0.15
"""Default plausibility threshold of :func:`~pcreg.registration.api.register`: the share of tight (<= 1 px),
direction-consistent inliers an alignment must reach.

The argument: content unrelated to the reference reaches only the test's chance level, the share of
points that fall within 1 px of some reference edge times the chance that two unrelated edge directions
agree within 30° (about 1/6 for uniform directions). Measured after the full search and ICP (which
optimise the alignment, so this is the worst case), unrelated photographs, noise and procedural
textures against each other reach 0.01-0.09, and the permutation estimate of chance
(``chance_ratio``) is at most 0.20 even on dense, oriented textures (grass). True alignments of the
same content reach 0.5-0.95 on photographs and textures; consecutive street-scene frames 15 per second
apart 0.43-0.62. 0.15 lies above every unrelated alignment measured, with room below true ones; the
second test, ``inlier_ratio >= CHANCE_FACTOR x chance_ratio``, covers textures whose own chance level
comes near it. Mirror images are refused by comparison with their mirror (see
:func:`~pcreg.registration.api.register`).
"""


def _set(part: Any, name: str, value: Any) -> None:
    """Store a checked, normalised option on a frozen part."""
    object.__setattr__(part, name, value)


@dataclass(frozen=True)
class PyramidConfig:
    """Clouds per level. levels : pyramid levels (1..8). sampler : ``"canny"`` edges or another of
    :data:`pcreg.registration.clouds.SAMPLERS`. max_points : moving points kept per level (finest first),
    at random with the search's ``seed``. reference_max_points : reference points kept at each level (one cap): edges
    of a 480x360 street scene number 15-20k, a 512x512 texture 30-60k; a random subset of them biases
    nearest-neighbour matches, so the cap is high (it bounds the time on very large images).
    canny_percentile : the edge threshold."""

    levels: int = 4
    sampler: str = "canny"
    max_points: int | tuple[int | None, ...] | None = (2000, 800, 600, 400)
    reference_max_points: int | None = 60000
    canny_percentile: float = 85.0

    def __post_init__(self) -> None:
        from .clouds import SAMPLERS

        _set(self, "levels", check_int(self.levels, "levels", lo=1, hi=8))
        _set(self, "sampler", check_choice(self.sampler, "sampler", SAMPLERS))
        _set(self, "max_points", check_counts(self.max_points, "max_points"))
        _set(self, "reference_max_points", check_count(self.reference_max_points, "reference_max_points"))
        _set(self, "canny_percentile", check_float(self.canny_percentile, "canny_percentile", lo=0, hi=100))

    def check_shape(self, shape: tuple[int, ...], name: str = "images", *, cli: bool = True) -> None:
        """Refuse images of ``shape`` too small for the levels: the coarsest under 8 px a side (``name``: which
        image, for the message; it names the levels that would take them, ``levels=N`` and, with ``cli`` (a command
        that takes ``--levels``), ``--levels N``)."""
        side = min(shape[:2])
        if side >> (self.levels - 1) < 8:
            said = "images are" if name == "images" else f"{name} ({shape[1]}x{shape[0]}) is"
            fits = max((n for n in range(1, self.levels) if side >> (n - 1) >= 8), default=0)
            how = f"--levels {fits}; levels={fits} in Python" if cli else f"levels={fits}"
            fit = f"; {fits} level{'s' * (fits > 1)} take{'s' * (fits == 1)} it ({how})" if fits else ""
            raise InputError(f"{said} too small for {self.levels} pyramid levels (the shorter side needs at least "
                             f"{8 << (self.levels - 1)} px{fit})")


@dataclass(frozen=True)
class SearchConfig:
    """Hypotheses. init : ``"auto"``/``"global"`` (the global search), ``"identity"`` or ``"center"``
    (image centres aligned); a 3x3 start is :func:`~pcreg.registration.api.register`'s ``init``, not an
    option. generators : the search's hypothesis generators, tried in order. angle_step : degrees between
    the rotations tried. n_candidates : hypotheses refined per generator. seed : random choices."""

    init: str = "auto"
    generators: tuple[str, ...] = ("fourier_mellin", "edges", "orb")
    angle_step: float = 15.0
    n_candidates: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        from .global_search import GENERATORS

        if not isinstance(self.init, str) or self.init not in INITS:
            raise InputError(f"init must be {', '.join(INITS[:-1])} or {INITS[-1]} (a 3x3 matrix is register's "
                             f"init=, not a configuration), got {short_repr(self.init)}")
        generators = (self.generators,) if isinstance(self.generators, str) else self.generators
        try:
            generators = tuple(generators)
        except TypeError:
            raise InputError(f"generators must be a selection of {', '.join(GENERATORS)}, got {short_repr(generators)}") from None
        if not generators or any(not isinstance(g, str) or g not in GENERATORS for g in generators):
            raise InputError(f"generators must be a non-empty selection of {', '.join(GENERATORS)}, got {short_repr(generators)}")
        _set(self, "generators", generators)
        _set(self, "angle_step", check_float(self.angle_step, "angle_step", lo=0.01, hi=360))
        _set(self, "n_candidates", check_int(self.n_candidates, "n_candidates", lo=1, hi=360))
        _set(self, "seed", check_int(self.seed, "seed", lo=0, hi=2**31 - 1))  # OpenCV's RNG takes a C int


@dataclass(frozen=True)
class IcpConfig:
    """The ICP of every step. backend : ``"reference"`` or ``"open3d"``: the ICP of every step
    (candidates, levels, finish). iterations : per level. max_correspondence_distance : px at full
    resolution (x 2^level). refine : ``"none"`` (the same algorithm for both backends, so that their
    results compare; None reads as it) or ``"point_to_line"``: point-to-line iterations (Tukey weights)
    at full resolution after the levels, which removes the bias of matching edge points sampled at
    different places along the same edge (reference backend only). weights : robust weights (reference
    backend only). relative_fitness, relative_rmse : Open3D's stopping rule per level (absolute changes;
    the RMSE threshold is in full-resolution px, scaled by 2^level); the point-to-line finish uses at
    most 1e-6."""

    backend: str = "reference"
    iterations: int = 14
    max_correspondence_distance: float = 2.5
    refine: str | None = "none"
    weights: str = "none"
    relative_fitness: float = 1e-4
    relative_rmse: float = 1e-3

    def __post_init__(self) -> None:

        if not isinstance(self.backend, str) or self.backend not in BACKENDS:
            raise InputError(f"unknown backend {short_repr(self.backend)}; choose one of {', '.join(BACKENDS)}")
        _set(self, "iterations", check_int(self.iterations, "iterations", lo=1, hi=100_000))
        _set(self, "max_correspondence_distance", check_float(self.max_correspondence_distance,
                                                              "max_correspondence_distance", lo=0, lo_open=True, hi=1e6))
        _set(self, "refine", check_choice("none" if self.refine is None else self.refine, "refine", REFINES))
        if not isinstance(self.weights, str) or self.weights not in WEIGHTS:
            raise InputError(f"unknown robust weights {short_repr(self.weights)}; choose one of {', '.join(WEIGHTS)}")
        _set(self, "relative_fitness", check_float(self.relative_fitness, "relative_fitness", lo=0))
        _set(self, "relative_rmse", check_float(self.relative_rmse, "relative_rmse", lo=0))
        if self.refine == "point_to_line" and self.backend != "reference":
            raise InputError("refine='point_to_line' is a reference-backend finish (Open3D's ICP here is point-to-point); "
                             "use refine='none' with backend='open3d'")
        if self.weights != "none" and self.backend != "reference":
            raise InputError("robust weights are a reference-backend feature; Open3D's point-to-point ICP has none")


@dataclass(frozen=True)
class PlausibilityConfig:
    """The test (:mod:`pcreg.registration.plausibility`). min_inlier_ratio : the share of moving points
    that must land within ``inlier_tolerance`` px of a reference point (:data:`DEFAULT_MIN_INLIER_RATIO`;
    None turns the test off, and the checks of ``model_check`` with it). model_check : whether the result is checked: a result of a model narrower than
    the projective one against a projective refinement of it (:func:`pcreg.registration.plausibility.model_fit`:
    the result's ``model_fit``), a projective result against the homography of SIFT matches
    (:func:`pcreg.registration.features.feature_check`: its ``features``); the streams and evaluations, whose
    registrations a richer motion follows or which the checks would only slow, turn them off."""

    min_inlier_ratio: float | None = DEFAULT_MIN_INLIER_RATIO
    inlier_tolerance: float = 1.0
    model_check: bool = True

    def __post_init__(self) -> None:
        if self.min_inlier_ratio is not None:  # 0 turns the test off, as None does (and as --min-inlier-ratio 0)
            ratio = check_float(self.min_inlier_ratio, "min_inlier_ratio", lo=0, hi=1)
            _set(self, "min_inlier_ratio", ratio if ratio > 0 else None)
        _set(self, "inlier_tolerance", check_float(self.inlier_tolerance, "inlier_tolerance", lo=0, lo_open=True))
        if not isinstance(self.model_check, bool):
            raise InputError(f"model_check must be True or False, got {short_repr(self.model_check)}")


_PARTS: dict[str, Any] = {"pyramid": PyramidConfig, "search": SearchConfig, "icp": IcpConfig,
                          "plausibility": PlausibilityConfig}
_HOME = {f.name: part for part, cls in _PARTS.items() for f in fields(cls)}


@dataclass(frozen=True)
class RegisterConfig:
    """Options of :func:`pcreg.register` by step; frozen, change with :meth:`replace`.

    model : the motion model, shared by every step (one of :data:`pcreg.registration.transforms.MODELS`,
    or ``"dense"``: the similarity refined by a dense field). pyramid, search, icp, plausibility : the
    parts (:class:`PyramidConfig`, :class:`SearchConfig`, :class:`IcpConfig`, :class:`PlausibilityConfig`).
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
        # "dense" is the pipeline's: a similarity refined by a field (pcreg.pipeline.pair.DENSE_GLOBAL_MODEL)
        dense = isinstance(self.model, str) and self.model == "dense"
        if not dense:
            from .transforms import check_model

            check_model(self.model)
        # a model the backend cannot fit is refused when the configuration is made, not at its first pair
        if self.icp.backend == "open3d" and not dense:

            check_open3d_model(self.model)

    @classmethod
    def of(cls, **options: Any) -> "RegisterConfig":
        """The default configuration with ``options`` changed, each by its flat name (``backend=...``)."""
        return cls().replace(**options)

    @property
    def backend(self) -> str:
        """The ICP backend (``icp.backend``), which the pipeline and the evaluations report."""
        return self.icp.backend

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
