"""The dense registration's options: :class:`DenseOptions`, one frozen value checked when it is made, with
its two parts, the field's :class:`Membrane` and the :class:`GlobalStep`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...validation import check_bool, check_choice, check_float, check_floats, check_int, check_matrix, short_repr
from ..config import BACKENDS, INITS, RegisterConfig
from ..transforms import MODELS
from .grid import _grid_shape

__all__ = ["DENSE_GLOBAL_MODEL", "MAX_MEMBRANE_WEIGHT", "STIFFNESS_SCHEDULE", "DenseOptions", "GlobalStep", "Membrane", "finest_grid_shape"]

#: Stiffness per iteration of a level (Amberg et al. 2007: stiff to relaxed); the last value repeats.
STIFFNESS_SCHEDULE: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
#: The largest membrane weight ``stiffness / (grid_spacing * strain)^2`` (the default's is 2): the grid's
#: equations multiply it by the grid's displacements (px) and sum it over a node's neighbours.
MAX_MEMBRANE_WEIGHT = 1e300
#: The global step of the dense model: a similarity (rotation, shift and the zoom of forward motion).
DENSE_GLOBAL_MODEL = "similarity"


def _put(options, name: str, value) -> None:
    """Store a checked, normalised option on a frozen value."""
    object.__setattr__(options, name, value)


@dataclass(frozen=True)
class Membrane:
    """The field's control grid and the membrane that keeps it smooth (:mod:`.grid`); part of
    :class:`DenseOptions`, checked when made.

    grid_spacing : control-grid spacing in pixels of each level (at least 2; at most the images' longer
        side, checked by :meth:`DenseOptions.check_shape`).
    stiffness : the schedule multiplying the membrane weight per iteration of a level (the last value repeats).
    strain : the largest plausible motion gradient (px per px), which sets the membrane weight
        ``stiffness / (grid_spacing * strain)^2`` (refused beyond float64's range for the grid's equations:
        :data:`MAX_MEMBRANE_WEIGHT`).
    edge_aware : weight each membrane edge by the moving image's colour change across it
        (:func:`~pcreg.registration.dense.grid._edge_weights`), so the field can bend at object outlines;
        False: a uniform membrane.
    cg_iterations : each step solves the grid's equations inexactly, with at most this many
        Jacobi-preconditioned conjugate-gradient iterations warm-started from the last field (the
        ICP iterates anyway); 0: an exact sparse LU solve each step.
    """

    grid_spacing: float = 8.0
    stiffness: tuple[float, ...] = STIFFNESS_SCHEDULE
    strain: float = 0.25
    edge_aware: bool = False
    cg_iterations: int = 30

    def __post_init__(self) -> None:
        _put(self, "grid_spacing", check_float(self.grid_spacing, "grid_spacing", lo=2))
        stiffness = check_floats(self.stiffness, "stiffness", lo=0, lo_open=True)
        if not stiffness:
            raise InputError("stiffness must be a non-empty sequence of positive numbers")
        _put(self, "stiffness", stiffness)
        _put(self, "strain", check_float(self.strain, "strain", lo=0, lo_open=True, hi=100))
        _put(self, "edge_aware", check_bool(self.edge_aware, "edge_aware"))
        _put(self, "cg_iterations", check_int(self.cg_iterations, "cg_iterations", lo=0, hi=100_000))
        self._check_weights()

    def _check_weights(self) -> None:
        """Refuse a membrane weight ``stiffness / (grid_spacing * strain)^2`` (as each level computes it) that
        float64 cannot hold in the grid's equations: above :data:`MAX_MEMBRANE_WEIGHT` (the equations overflow
        to inf, the field to NaN), or so small that its pull towards the global transform (``1e-4`` of it)
        is no normal number (a node without samples makes the equations singular)."""
        side = self.grid_spacing * self.strain
        cell = side * side  # inf past float64's range (a power would raise OverflowError), refused below
        for k in self.stiffness:
            alpha = k * (1.0 / cell) if cell > 0 else math.inf
            if not 1e-4 * alpha >= np.finfo(np.float64).tiny or not alpha <= MAX_MEMBRANE_WEIGHT:
                raise InputError(f"stiffness {k:g} with strain {self.strain:g} and grid_spacing {self.grid_spacing:g} "
                                 f"gives a membrane weight stiffness / (grid_spacing * strain)^2 of {alpha:.3g}, beyond "
                                 f"float64's range for the grid's equations (at most {MAX_MEMBRANE_WEIGHT:g}, and its "
                                 "ten-thousandth a normal number)")


@dataclass(frozen=True)
class GlobalStep:
    """The global step of :func:`pcreg.register_dense` (:func:`pcreg.register`, run unless it is given a
    ``global_result``); part of :class:`DenseOptions`, checked when made.

    model : its motion model (:data:`DENSE_GLOBAL_MODEL`, ``projective``, ...).
    levels, iterations : its pyramid levels and ICP iterations per level.
    init : its start (``"identity"``, ``"center"``, ``"auto"``/``"global"``, or a 3x3 matrix, kept as a
        tuple of rows so that the options stay hashable and compare by value).
    backend : ``"reference"`` or ``"open3d"``: its ICP, and the dense result's ``backend``.
    """

    model: str = DENSE_GLOBAL_MODEL
    levels: int = 4
    iterations: int = 14
    init: str | tuple[tuple[float, ...], ...] = "identity"
    backend: str = "reference"

    def __post_init__(self) -> None:
        if not isinstance(self.model, str) or self.model not in MODELS:
            raise InputError(f"unknown global motion model {short_repr(self.model)}; choose one of {', '.join(MODELS)}")
        _put(self, "levels", check_int(self.levels, "global_step.levels", lo=1, hi=8))
        _put(self, "iterations", check_int(self.iterations, "global_step.iterations", lo=1, hi=100_000))
        if isinstance(self.init, str):
            check_choice(self.init, "init", INITS)
        else:
            _put(self, "init", tuple(tuple(float(v) for v in row) for row in check_matrix(self.init, "init", 3)))
        _put(self, "backend", check_choice(self.backend, "backend", BACKENDS))

    @property
    def start(self) -> str | np.ndarray:
        """``init`` as :func:`pcreg.register` takes it (a matrix as a (3, 3) float64 array)."""
        return self.init if isinstance(self.init, str) else np.array(self.init, dtype=np.float64)

    def config(self, seed: int) -> RegisterConfig:
        """:func:`pcreg.register`'s configuration of this step, its random choices from ``seed``."""
        return RegisterConfig.of(backend=self.backend, model=self.model, levels=self.levels,
                                 iterations=self.iterations, seed=seed, model_check=False)  # a field follows


@dataclass(frozen=True)
class DenseOptions:
    """Options of :func:`pcreg.register_dense`; frozen (change with ``dataclasses.replace``, a part with
    ``replace(options, membrane=replace(options.membrane, strain=0.5))``), checked when made
    (:class:`~pcreg.errors.InputError` for the first bad one, in the order below; each part checks its own).

    levels : pyramid levels of the dense step (the coarsest is ``levels - 1``); finest_level : the
        finest level it works at (1: half resolution, as DIS's medium preset; 0: full resolution).
    iterations : ICP iterations per level (the stiffness schedule runs within each level). 8: the
        schedule's four stiff steps, then four at the final stiffness to settle; with 4 the final
        stiffness got one step, and the pairwise evaluation's dense share was 0.60 points on CamVid
        against 0.73 with 8 (synthetic presets 3.90 and 3.98), at about twice the dense step's time.
    radius : gate at the coarsest level, fine_radius : at the others (pixels of the level): a finer
        level starts from the coarser level's field, within about a pixel of it there (two here).
    max_points : moving samples per level at most (at random with ``seed``).
    texture : match on each level's texture part (:func:`~pcreg.registration.dense.levels._texture`), the image minus its Gaussian blur
        of ``texture`` pixels of the level; None matches the plain colours. 4: on the pairwise evaluation
        (``evaluate sequence --model dense``) a wider blur keeps more of real scenes' colour and helps
        (CamVid, sigma 1 / 2 / 4 / 8 / 16: 46.2 / 45.4 / 48.4 / 49.3 / 47.9% below plain), while the
        synthetic presets' exposure and shadow changes want a narrow one (98.0 / 98.1 / 97.8 / 96.4 /
        94.6%); 4 is the widest that keeps them where sigma 1 had them (within 0.5 points).
    chance_factor : plausibility test on the field (off by default): refuse with
        :class:`~pcreg.errors.RegistrationError` when the matches under the field are not this many
        times closer in colour than on unrelated content (:func:`~pcreg.registration.dense.coarse_to_fine._plausibility`; the result's
        ``info["evidence"]`` holds the figure either way). Without it, unrelated images are refused
        only by the global step's own test (:func:`pcreg.register`, when it runs here).
    initial_level : where a registration given an ``initial`` grid starts (``finest_level`` .. 7, capped
        at the coarsest level; see ``initial`` of :func:`pcreg.register_dense`).
    seed : the random choices of both steps (the dense step's samples, the global step's search).
    membrane : the control grid and its smoothness (:class:`Membrane`).
    global_step : the global step's options (:class:`GlobalStep`); its ``backend`` is the result's.
    """

    levels: int = 5
    finest_level: int = 1
    iterations: int = 8
    radius: int = 3
    fine_radius: int = 2
    max_points: int = 10000
    texture: float | None = 4.0
    chance_factor: float | None = None
    initial_level: int = 2
    seed: int = 0
    membrane: Membrane = Membrane()
    global_step: GlobalStep = GlobalStep()

    def __post_init__(self) -> None:
        _put(self, "levels", check_int(self.levels, "levels", lo=1, hi=8))
        _put(self, "finest_level", check_int(self.finest_level, "finest_level", lo=0, hi=self.levels - 1))
        _put(self, "iterations", check_int(self.iterations, "iterations", lo=1, hi=100_000))
        _put(self, "radius", check_int(self.radius, "radius", lo=1, hi=64))
        _put(self, "fine_radius", check_int(self.fine_radius, "fine_radius", lo=1, hi=64))
        _put(self, "max_points", check_int(self.max_points, "max_points", lo=16))
        if self.texture is not None:
            _put(self, "texture", check_float(self.texture, "texture", lo=0, lo_open=True))
        if self.chance_factor is not None:
            _put(self, "chance_factor", check_float(self.chance_factor, "chance_factor", lo=0))
        _put(self, "initial_level", check_int(self.initial_level, "initial_level", lo=0, hi=7))
        _put(self, "seed", check_int(self.seed, "seed", lo=0))
        for name, part in (("membrane", Membrane), ("global_step", GlobalStep)):
            if not isinstance(getattr(self, name), part):
                raise InputError(f"DenseOptions.{name} must be a {part.__name__}, got {type(getattr(self, name)).__name__}")

    def check_shape(self, shape: tuple[int, ...]) -> None:
        """Refuse options that do not fit images of ``shape``: a grid spacing or a texture blur beyond
        the images' longer side."""
        side = max(shape[:2])
        check_float(self.membrane.grid_spacing, "grid_spacing", hi=side)
        if self.texture is not None:
            check_float(self.texture, "texture", hi=side)


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
    return _grid_shape(h, w, float(options.membrane.grid_spacing))

