"""Finding a frame's motion, or saying why not: one seam for the stream, its baselines and the pairs.

Each way of finding a frame's motion is an estimator built once from its typed options, answering one
call, :meth:`estimate` ``(reference, image, *, prepared=None, carry=None)`` -> :class:`Estimate`: the
registration result (a :class:`~pcreg.registration.motion.Motion` through :attr:`Estimate.motion`) with
its evidence, or the reason it was refused, how it started, and what the next call may start from.

- :class:`GlobalEstimator`: one transform (:func:`pcreg.register` with a
  :class:`~pcreg.registration.config.RegisterConfig`), refused where degenerate;
- :class:`DenseEstimator`: a dense field (:func:`pcreg.register_dense`), warm from the previous
  frame's grid where it can be and cold again where the warm start loses the frame (:class:`DenseStep`,
  :class:`Carry`);
- :class:`FlowEstimator`: OpenCV's DIS optical flow at a preset, the baselines' motion.

The reference may come prepared (:func:`pcreg.registration.dense.prepare_reference`, its pyramid built
once): the caller holds it, as :class:`pcreg.Propagator` holds its key frame's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable, Protocol

import numpy as np

from ..errors import InputError, RegistrationError
from ..registration.config import RegisterConfig
from ..registration.motion import Motion

if TYPE_CHECKING:
    from ..registration.dense import DenseOptions, DenseReference

__all__ = ["DenseStep", "Carry", "ChainCarry", "chain_after", "STREAM_DENSE", "Estimate", "StreamMotion", "motion_model", "GlobalEstimator", "DenseEstimator",
           "FlowEstimator", "stream_motion", "pair_estimator", "check_stream_options"]


@dataclass(frozen=True)
class DenseStep:
    """Options of the dense registration of a stream (turned into :func:`pcreg.register_dense`'s
    :class:`~pcreg.registration.dense.DenseOptions` by :meth:`options`).

    texture : None matches plain colours (see the module's docstring). iterations : ICP iterations per
    level (8, :class:`~pcreg.registration.dense.DenseOptions`'s: the stiffness schedule 8, 4, 2, 1 gets four relaxed
    iterations to settle).
    max_points : moving samples per level (5,000 measured as accurate as 10,000 at two thirds of the time).
    global_start : ``"identity"`` or ``"register"`` (the stream's global registration first).
    warm : start each step from the previous step's grid (:class:`Carry`) at pyramid level
        ``warm_level`` with ``warm_iterations`` per level, instead of from the identity at the coarsest
        level (only anchored to the key frame and from the identity; see the module's docstring).
    restart_ratio : a warm step whose evidence (the matches' colour agreement against chance,
        ``info["evidence"]``) falls under this fraction of the last cold step's is run again cold, and
        the one with more evidence is kept.
    """

    texture: float | None = None
    iterations: int = 8
    max_points: int = 5000
    global_start: str = "identity"
    warm: bool = True
    warm_level: int = 2
    warm_iterations: int = 4
    restart_ratio: float = 0.5

    def __post_init__(self) -> None:
        from ..validation import check_bool, check_float, check_int

        if self.global_start not in ("identity", "register"):
            raise InputError(f"global_start must be identity or register, got {self.global_start!r}")
        object.__setattr__(self, "warm", check_bool(self.warm, "warm"))
        object.__setattr__(self, "iterations", check_int(self.iterations, "iterations", lo=1, hi=100_000))
        object.__setattr__(self, "warm_iterations", check_int(self.warm_iterations, "warm_iterations", lo=1,
                                                              hi=100_000))
        # register_dense's finest level (1) .. the coarsest it takes (7)
        object.__setattr__(self, "warm_level", check_int(self.warm_level, "warm_level", lo=1, hi=7))
        object.__setattr__(self, "restart_ratio", check_float(self.restart_ratio, "restart_ratio", lo=0, hi=1))

    def options(self, base: DenseOptions | None = None, *, warm: bool = False) -> DenseOptions:
        """:func:`pcreg.register_dense`'s options: ``base`` (the defaults when None) with this step's
        texture, iterations and samples (a warm step's iterations and start level with ``warm``)."""
        from ..registration.dense import DenseOptions

        base = DenseOptions() if base is None else base
        if warm:
            return replace(base, texture=self.texture, iterations=self.warm_iterations, max_points=self.max_points,
                           initial_level=self.warm_level)
        return replace(base, texture=self.texture, iterations=self.iterations, max_points=self.max_points)


@dataclass(frozen=True)
class Carry:
    """What a dense step hands to the next one (:attr:`Propagator.carry`): the dense field's control
    ``grid`` (:attr:`~pcreg.registration.dense.DenseRegistrationResult.grid`, float32) and the evidence
    of the last cold step (``reference_evidence``), the restart rule's yardstick. ``pcreg run`` saves it
    with every frame, so that a resumed run continues as the uninterrupted one did."""

    grid: np.ndarray
    reference_evidence: float

    def __post_init__(self) -> None:
        from ..validation import check_float

        raw = np.asarray(self.grid) if isinstance(self.grid, np.ndarray) else None
        if raw is None or raw.dtype.kind not in "iuf":
            raise InputError("a carried grid must be a numeric (rows, columns, 2) array")
        with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: inf, refused below
            g = np.array(raw, dtype=np.float32)
        if g.ndim != 3 or g.shape[2] != 2 or g.size == 0 or not np.all(np.isfinite(g)):
            raise InputError(f"a carried grid must be a finite (rows, columns, 2) array, got shape {g.shape}")
        evidence = check_float(self.reference_evidence, "a carried evidence", lo=0)
        g.setflags(write=False)
        object.__setattr__(self, "grid", g)
        object.__setattr__(self, "reference_evidence", evidence)


@dataclass(frozen=True, eq=False)
class ChainCarry:
    """What a chained step (``anchor="previous"``) hands to the next: the frame the next is registered to
    (``rgb``, (h, w, 3) uint8 at the working size), its ``motion`` to the key frame (None: it is the key
    frame itself) and its step (``frame``, 0 for the key frame). ``pcreg run`` saves it with every frame
    (:func:`pcreg.runs.files.write_carry`), so that a resumed chained run continues as the uninterrupted
    one did."""

    rgb: np.ndarray
    motion: Motion | None
    frame: int


def chain_after(carry, key, frame: int) -> tuple:
    """The chain a stream resumed after step ``frame`` continues from: ``carry`` a :class:`ChainCarry` of
    that step (or of an earlier one, when later registrations failed), ``key`` the stream's key frame
    (a :class:`~pcreg.frame.PreparedFrame` at the working size)."""
    from ..frame import PreparedFrame

    if not isinstance(carry, ChainCarry):
        raise InputError("a chained stream (anchor='previous') resumes from the ChainCarry its last step left")
    rgb = np.asarray(carry.rgb)
    if carry.frame > frame or carry.frame < 0 or rgb.shape != key.rgb.shape or rgb.dtype != np.uint8:
        raise InputError(f"the carried frame ({rgb.shape}, step {carry.frame}) is not of this stream's frames "
                         f"({key.rgb.shape}) before step {frame + 1}: it comes from another stream")
    if carry.frame == 0:
        return (key, None, 0)
    if carry.motion is None:
        raise InputError("a chained stream's carried frame after the key frame needs its motion to the key frame")
    # a copy of its own: the next step is registered to it, and the caller may write into its array
    return (PreparedFrame(np.array(rgb, order="C")), carry.motion, int(carry.frame))


STREAM_DENSE = DenseStep()


@dataclass(frozen=True, eq=False)
class Estimate:
    """What an estimator found: ``result`` (a registration result, a dense result with its field, or a
    :class:`~pcreg.registration.flow.FlowResult` for a flow) or None with the ``reason``; ``start``: how a
    dense registration started (``"cold"``, ``"warm"``, ``"restarted"``; None for the others);
    ``carry``: what the next estimate may start from (None: cold)."""

    result: object | None
    reason: str | None = None
    start: str | None = None
    carry: Carry | None = None

    @property
    def motion(self) -> Motion | None:
        """The motion found (None when refused)."""
        return None if self.result is None else Motion.of(self.result)


class StreamMotion(Protocol):
    """What a stream (:class:`pcreg.Propagator`) asks of the way it finds each frame's motion, so that it
    never asks which way that is.

    name : how a message names it (``"dense registration"``, ``"optical flow"``, ...).
    second_motion : whether the trust rule carries the key frame along DIS's flow too, as a second motion
        (not when the motion is itself a flow: it would be the same motion twice).
    checks_every_size : whether frames it cannot take are refused at the key frame even at the frames'
        own size (DIS crashes on them, a global model's pyramid cannot take them; a dense registration fails on
        them and the step falls back instead).
    """

    name: str
    second_motion: bool
    checks_every_size: bool

    def prepare(self, reference: np.ndarray) -> object | None:
        """What every estimate against ``reference`` shares, made once (None: nothing)."""

    def check_size(self, shape: tuple[int, int]) -> None:
        """An :class:`~pcreg.errors.InputError` for frames of ``shape`` it cannot take."""

    def warm_starts(self, anchor: str) -> bool:
        """Whether each estimate starts from the last one's :class:`Carry` in a stream anchored so."""

    def estimate(self, reference: np.ndarray, image: np.ndarray, *, prepared=None, carry=None) -> "Estimate":
        """The motion from ``image`` to ``reference``, or why not."""


def _refused(result, image: np.ndarray) -> str | None:
    """Why a result's transform cannot carry labels (a degenerate matrix), or None."""
    from ..registration.transforms import degeneracy

    why = degeneracy(result.matrix, image.shape)
    return None if why is None else f"registration refused: {why}"


class GlobalEstimator:
    """One transform per frame: :func:`pcreg.register` with ``config`` (and its ``callback``, called after
    every ICP iteration), a degenerate one refused."""

    second_motion, checks_every_size = True, True

    def __init__(self, config: RegisterConfig, *, callback: Callable | None = None) -> None:
        if not isinstance(config, RegisterConfig):
            raise InputError("config must be a pcreg.RegisterConfig")
        # a stream's motion is followed by its trust rule, not by a person reading a note
        self.config, self.callback = config.replace(model_check=False), callback
        self.name = f"{config.model} registration"

    def prepare(self, reference: np.ndarray) -> None:
        """Nothing: each frame's global registration builds its own pyramids."""
        return None

    def check_size(self, shape: tuple[int, int]) -> None:  # levels=N: a Propagator's register=; pcreg run takes none
        self.config.pyramid.check_shape(shape, cli=False)

    def warm_starts(self, anchor: str) -> bool:
        return False

    def estimate(self, reference: np.ndarray, image: np.ndarray, *, prepared=None, carry=None) -> Estimate:
        from ..registration.api import register

        try:
            result = register(reference, image, config=self.config, callback=self.callback)
        except RegistrationError as exc:
            return Estimate(None, str(exc))
        why = _refused(result, image)
        return Estimate(None, why) if why is not None else Estimate(result)


class DenseEstimator:
    """A dense field per frame (:func:`pcreg.register_dense`), with ``cold`` and ``warm`` options (the
    stream's: :meth:`DenseStep.options`); from the identity, or after ``config``'s global registration
    when ``step.global_start`` is ``"register"``. Given a :class:`Carry`, it starts warm from its grid,
    and runs again cold where the warm field's evidence falls under ``step.restart_ratio`` of the last
    cold field's, keeping the field with more evidence. ``callback``: the global registration's, called
    after every ICP iteration."""

    name, second_motion, checks_every_size = "dense registration", True, False

    def __init__(self, config: RegisterConfig, step: "DenseStep", cold: "DenseOptions", warm: "DenseOptions", *,
                 callback: Callable | None = None) -> None:
        self.config, self.step, self.cold, self.warm = config.replace(model_check=False), step, cold, warm
        self.callback = callback

    def check_size(self, shape: tuple[int, int]) -> None:
        self.cold.check_shape(shape)
        if self.step.global_start == "register":
            self.config.pyramid.check_shape(shape, cli=False)

    def warm_starts(self, anchor: str) -> bool:
        """From the previous step's grid: anchored to the key frame, from the identity, with ``step.warm``."""
        return self.step.warm and anchor == "key" and self.step.global_start == "identity"

    def prepare(self, reference: np.ndarray) -> "DenseReference":
        """The reference's pyramid, built once for every estimate against it."""
        from ..registration.dense import prepare_reference

        return prepare_reference(reference, options=self.cold)

    def estimate(self, reference: np.ndarray, image: np.ndarray, *, prepared: "DenseReference | None" = None,
                 carry: Carry | None = None) -> Estimate:
        attempt = ["cold" if carry is None else "warm"]
        try:
            result, start, evidence = self._field(reference, image, prepared, carry, attempt)
        except RegistrationError as exc:
            return Estimate(None, str(exc), attempt[0])
        why = _refused(result, image)
        if why is not None:
            return Estimate(None, why, start)
        return Estimate(result, None, start, Carry(result.grid, evidence))

    def _field(self, reference, image, prepared, carry, attempt: list):
        """``(result, start, the evidence the restart rule compares with)``; ``attempt[0]`` follows how
        the registration under way started, for a refusal's report."""
        from ..registration.api import register, register_dense

        T = (register(reference, image, config=self.config, callback=self.callback)
             if self.step.global_start == "register" else np.eye(3))

        def dense(options, initial=None):
            return register_dense(reference, image, options=options, global_result=T, initial=initial,
                                  prepared=prepared)

        if carry is None:
            result = dense(self.cold)
            return result, "cold", result.info["evidence"]
        try:
            result, start = dense(self.warm, carry.grid), "warm"
        except RegistrationError:
            result, start = None, "restarted"
        evidence = carry.reference_evidence
        if result is None or result.info["evidence"] < self.step.restart_ratio * evidence:
            attempt[0] = "restarted"
            again = dense(self.cold)
            if result is None or again.info["evidence"] >= result.info["evidence"]:
                result = again
            evidence, start = again.info["evidence"], "restarted"
        return result, start, evidence


def stream_motion(model: str, preset: str | None, config: RegisterConfig, step: DenseStep,
                  options: tuple["DenseOptions", "DenseOptions"]) -> StreamMotion:
    """A stream's motion by its ``model`` (:class:`pcreg.Propagator`'s, parsed into ``model`` and a flow's
    ``preset``): a dense field (``"dense"``: ``step``, cold and warm ``options``), DIS's flow (``"flow"``)
    or one global transform by ``config``."""
    if model == "dense":
        return DenseEstimator(config, step, *options)
    if model == "flow":
        return FlowEstimator(preset or "medium")
    return GlobalEstimator(config)


def pair_estimator(registration: RegisterConfig, *, callback: Callable | None = None
                   ) -> "GlobalEstimator | DenseEstimator":
    """How a pair of images is registered (:func:`pcreg.pipeline.pair.register_pair`): ``registration``'s
    global model, or with ``model="dense"`` a dense field from scratch after a global similarity. That
    global step is the dense step's start, not its answer: a 3-D scene fails a global model's
    plausibility test by design, so the test is off there and the dense step's own (on its field)
    decides."""
    if registration.model != "dense":
        return GlobalEstimator(registration, callback=callback)
    from ..registration.dense import DENSE_GLOBAL_MODEL, DenseOptions, GlobalStep

    start = registration.replace(model=DENSE_GLOBAL_MODEL, min_inlier_ratio=None)
    options = DenseOptions(seed=registration.search.seed, global_step=GlobalStep(backend=registration.backend))
    return DenseEstimator(start, DenseStep(global_start="register", warm=False), options, options, callback=callback)


class FlowEstimator:
    """OpenCV's DIS optical flow (:func:`pcreg.registration.flow.dis_field`) at ``preset``: a field with no
    evidence of its own, never refused (a :class:`~pcreg.registration.flow.FlowResult`). A reference
    prepared once (:meth:`prepare`: its grey levels and the pixel grid) is not converted again for every
    frame; the fields are the same."""

    name, second_motion, checks_every_size = "optical flow", False, True

    def __init__(self, preset: str = "medium") -> None:
        from ..registration.flow import PRESETS

        if preset not in PRESETS:
            raise InputError(f"unknown DIS preset {preset!r}; choose one of {', '.join(PRESETS)}")
        self.preset = preset

    def check_size(self, shape: tuple[int, int]) -> None:
        from ..registration.flow import DIS_MIN_SIDE

        if min(shape) < DIS_MIN_SIDE:
            raise InputError(f"DIS optical flow takes at least {DIS_MIN_SIDE} px a side")

    def warm_starts(self, anchor: str) -> bool:
        return False

    def prepare(self, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The reference's grey levels and its pixel grid's x and y (float32), for :meth:`estimate`."""
        import cv2

        from ..frame import as_rgb_uint8
        from ..registration.flow import pixel_grid

        grey = cv2.cvtColor(as_rgb_uint8(reference, name="reference image"), cv2.COLOR_RGB2GRAY)
        grey.setflags(write=False)
        return (grey, *pixel_grid(grey.shape))

    def estimate(self, reference: np.ndarray, image: np.ndarray, *, prepared=None, carry=None) -> Estimate:
        """The flow from ``image`` to the reference; with ``prepared`` (:meth:`prepare` of the reference)
        ``image`` must be a frame of its size (a :class:`~pcreg.frame.PreparedFrame` is not checked again)."""
        import cv2

        from ..frame import as_rgb_uint8
        from ..registration.flow import FlowResult, dis_field, dis_flow, flow_field

        if prepared is None:
            fld, seconds = dis_field(reference, image, preset=self.preset)
            return Estimate(FlowResult(fld, self.preset, seconds))
        grey, xs, ys = prepared
        t0 = time.perf_counter()
        frame = cv2.cvtColor(as_rgb_uint8(image, name="moving image"), cv2.COLOR_RGB2GRAY)
        fld = flow_field(dis_flow(frame, grey, self.preset), (xs, ys))
        return Estimate(FlowResult(fld, self.preset, time.perf_counter() - t0))


def motion_model(model) -> tuple[str, str | None]:
    """``(model, preset)`` of a :class:`~pcreg.pipeline.stream.Propagator`'s ``model``: ``"flow"`` or ``"flow:PRESET"`` (DIS's preset,
    :data:`pcreg.registration.flow.PRESETS`; medium by default) gives ``("flow", PRESET)``; ``"dense"`` and the
    global models ``(model, None)``; anything else an :class:`~pcreg.errors.InputError`."""
    from ..registration.flow import PRESETS
    from ..registration.transforms import MODELS
    from ..validation import short_repr

    if isinstance(model, str) and (model == "flow" or model.startswith("flow:")):
        preset = model.partition(":")[2] if ":" in model else "medium"
        if preset not in PRESETS:
            raise InputError(f"unknown DIS preset {short_repr(preset)} in model {short_repr(model)}; choose flow or "
                             f"flow:PRESET, PRESET one of {', '.join(PRESETS)}")
        return "flow", preset
    if not isinstance(model, str) or model not in ("dense", "flow") + MODELS:
        raise InputError(f"unknown model {short_repr(model)}; choose dense, flow or one of {', '.join(MODELS)}")
    return model, None


def check_stream_options(weight, calibrated_at: float, fusion, register, dense, trust, learning) -> None:
    """Refuse a :class:`pcreg.Propagator`'s options of the wrong kind (:class:`~pcreg.errors.InputError`), and warn
    (:class:`~pcreg.errors.UncalibratedWarning`) of a ``weight`` other than ``calibrated_at`` (the stream's, at which its
    confidence's coefficients were fitted), when it has a confidence (a ``trust`` rule)."""
    import warnings

    from ..classification.fusion import MAX_WEIGHT, FusionConfig
    from ..errors import UncalibratedWarning, outside_pcreg
    from ..validation import check_float
    from .learning import Learning
    from .trust import TrustRule

    weight = check_float(weight, "weight", lo=0, hi=MAX_WEIGHT)
    for what, value, kind, name in (("fusion", fusion, FusionConfig, "pcreg.classification.fusion.FusionConfig"),
                                    ("register", register, RegisterConfig, "pcreg.RegisterConfig"),
                                    ("dense", dense, DenseStep, "pcreg.pipeline.stream.DenseStep"),
                                    ("trust", trust, TrustRule, "pcreg.pipeline.trust.TrustRule or None"),
                                    ("learning", learning, Learning, "pcreg.pipeline.learning.Learning or None")):
        if not (isinstance(value, kind) or (value is None and what in ("register", "trust", "learning"))):
            raise InputError(f"{what} must be a {name}")
    if trust is not None and weight != calibrated_at:
        warnings.warn(UncalibratedWarning(f"Propagator(weight={weight:g}): the confidence and the predicted error are "
                                          f"calibrated at weight {calibrated_at:g}; at another they read surer, or less "
                                          "sure, than the labels are"), stacklevel=outside_pcreg())
