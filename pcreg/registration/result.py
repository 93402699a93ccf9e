"""The result of a registration and of one ICP iteration: what ``register`` and ``icp`` return, what
both backends hand to a callback, and what every cross-checked implementation returns."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass

import numpy as np


FRAMES = ("T_ref_mov", "T_target_source")  # images, clouds


def _named(result: "RegistrationResult", name: str) -> np.ndarray:
    """``result.matrix`` under the name of its frames; the other name is an AttributeError that says why."""
    if result.frames != name:
        kind = "an image" if result.frames == "T_ref_mov" else "a cloud"
        raise AttributeError(f"{kind} registration's transform is {result.frames}, not {name}")
    return result.matrix


def _same(a: object, b: object) -> bool:
    """Two values of a result's field alike: arrays of one shape and the same values, floats (numpy's too) by value,
    NaN as NaN (an implementation that reports no fitness leaves NaN in both), the evidence's records field by field
    the same way, the rest by ``==``."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape
                and bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc" and b.dtype.kind in "fc")))
    if isinstance(a, (float, np.floating)) and isinstance(b, (float, np.floating)):
        return bool(a == b) or bool(a != a and b != b)
    if is_dataclass(a) and not isinstance(a, type) and type(a) is type(b):
        return _fields_alike(a, b)
    return bool(a == b)


def _fields_alike(a: object, b: object) -> bool:
    """Whether two results of one class are alike in every field that compares (:func:`_same`)."""
    return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a) if f.compare)  # type: ignore[arg-type]


class FieldsCompared:
    """``==`` field by field, the arrays by their values (:func:`_same`), for a dataclass made with ``eq=False`` (its
    generated ``==`` compares arrays as truth values, and raises): a copy, or a result unpickled, equals its original.
    The class gives its own ``__hash__``."""

    def __eq__(self, other: object) -> bool:
        if other.__class__ is not self.__class__:
            return NotImplemented
        return _fields_alike(self, other)


def _fmt_matrix(m: np.ndarray) -> str:
    return "[" + ", ".join("[" + ", ".join(f"{v:.6g}" for v in row) + "]" for row in np.asarray(m)) + "]"


@dataclass(frozen=True)
class ImageEvidence:
    """An image registration's evidence (:attr:`RegistrationResult.evidence`): how well its transform
    aligns the edges, and which hypothesis it came from.

    inlier_ratio : share of the moving edge points that land on the reference with a reference edge point
        within 1 px (``inlier_tolerance``) and the same edge direction.
    chance_ratio : the inlier ratio that content unrelated in edge direction would reach at the same
        distances; a true alignment is well above it.
    overlap : share of the moving edge points that land on the reference image.
    generator : which hypothesis generator's candidate won (``"edges"``, ``"fourier_mellin"``, ``"orb"``,
        or ``"init"`` for a given initial guess).
    model_fit : the result against a projective refinement of it (:class:`ModelFit`), or None.
    features : the result against the homography of SIFT matches (:class:`FeatureCheck`), or None.
    settling : the result refined again from starts a few px off (:class:`Settling`), or None.
    repeats : an image that repeats itself under a shift (:class:`Repetition`), or None where neither does or the
        checks were off.
    """

    inlier_ratio: float
    chance_ratio: float
    overlap: float
    generator: str
    model_fit: "ModelFit | None" = None
    features: "FeatureCheck | None" = None
    settling: "Settling | None" = None
    repeats: "Repetition | None" = None


@dataclass(frozen=True)
class ModelFit:
    """Whether a registration's model fits the images (:attr:`ImageEvidence.model_fit`), from a refinement of
    its transform by a richer model (:func:`pcreg.registration.plausibility.model_fit`).

    model : the richer model (``"projective"``).
    inlier_ratio, result_inlier_ratio : the richer transform's inlier ratio and the result's, both measured
        where the check measures (pyramid level 1, the tolerance doubled).
    largest_shift_px : how far the richer transform moves the moving edge points that land on the reference
        from where the result puts them (px, the largest).
    fits : False when the richer model aligns significantly more edge points and moves some by more than 3 px
        (:data:`~pcreg.registration.plausibility.SHIFT_PX`), or at least as many and moves some by more than 10 px
        (:data:`~pcreg.registration.plausibility.FAR_PX`): the images differ by more than the model allows, and the
        result is the model's best approximation, not their alignment.
    starts : the richer refinement's starts refined: 1, the result; 2, ORB's homography of the pair too, where it
        moved some of those edge points by more than 3 px from the result.
    """

    model: str
    inlier_ratio: float
    result_inlier_ratio: float
    largest_shift_px: float
    fits: bool
    starts: int = 1

    def to_dict(self) -> dict:
        return {"model": self.model, "inlier_ratio": float(self.inlier_ratio),
                "result_inlier_ratio": float(self.result_inlier_ratio),
                "largest_shift_px": float(self.largest_shift_px), "fits": bool(self.fits), "starts": int(self.starts)}


@dataclass(frozen=True)
class FeatureCheck:
    """A registration against the homography of the images' SIFT matches (:attr:`ImageEvidence.features`,
    :func:`pcreg.registration.features.feature_check`).

    matches : ratio-tested matches whose moving point the homography puts on the reference.
    inliers : the homography's inliers (MAGSAC, 3 px).
    largest_shift_px : how far the result puts a point of a 16 px grid of the moving image, inside the inliers'
        hull, from where the homography puts it (px, the largest).
    agree : None where the homography is not strongly supported (at most ``8 + 0.3 matches`` inliers, what chance
        matches reach: :data:`~pcreg.registration.features.SUPPORT`); else False when ``largest_shift_px``
        exceeds 3 px (:data:`~pcreg.registration.features.AGREE_PX`): the result is not where the features put
        the images.
    """

    matches: int
    inliers: int
    largest_shift_px: float
    agree: bool | None

    def to_dict(self) -> dict:
        return {"matches": int(self.matches), "inliers": int(self.inliers),
                "largest_shift_px": float(self.largest_shift_px), "agree": self.agree}


@dataclass(frozen=True)
class Settling:
    """What :func:`pcreg.registration.settling.settle` found (:attr:`ImageEvidence.settling`): the largest move of
    the landing edge points from the result to an alternative (px, 0 when every alternative came back), that
    alternative's inlier ratio and the result's (at the test's level), and whether a better alternative was taken
    (the replaced result is then one of the alternatives)."""

    shift_px: float
    inlier_ratio: float
    result_inlier_ratio: float
    taken: bool = False

    def to_dict(self) -> dict:
        return {"shift_px": self.shift_px, "inlier_ratio": self.inlier_ratio,
                "result_inlier_ratio": self.result_inlier_ratio, "taken": self.taken}


@dataclass(frozen=True)
class Repetition:
    """An image of the pair that matches itself under a shift (:attr:`ImageEvidence.repeats`,
    :func:`pcreg.registration.repetition.repeat_shift`): tiles, a grid, a brick wall. A motion that differs from the
    result by that shift aligns the images as well, so the result may be a period off; nothing in the images tells.

    image : ``"reference"`` or ``"moving"`` (the reference when both repeat).
    shift_px : (dx, dy), the shortest such shift (px).
    correlation : the image's correlation with itself under it (at least 0.9).
    """

    image: str
    shift_px: tuple[float, float]
    correlation: float

    def to_dict(self) -> dict:
        return {"image": self.image, "shift_px": [float(v) for v in self.shift_px], "correlation": float(self.correlation)}


@dataclass(frozen=True, repr=False, eq=False)
class RegistrationResult(FieldsCompared):
    """What both ICP backends and every cross-checked implementation return, so they can be compared
    field by field.

    matrix : (3, 3) or (4, 4) float64
        Homogeneous transform that maps moving/source coordinates into reference/target coordinates.
        It is also available by the name of its frames, as ``frames`` says: :attr:`T_ref_mov` for an
        image registration (:func:`pcreg.register`), :attr:`T_target_source` for a cloud registration
        (:func:`pcreg.icp`), as small_gicp names it.
    fitness : float
        Fraction of source points with a correspondence within the max distance (Open3D's definition).
    inlier_rmse : float
        RMS distance over those correspondences (0 when there are none), in the cloud's units.
    iterations : int
        ICP iterations run, summed over pyramid levels (-1 where the backend cannot tell).
    converged : bool or None
        The stopping rule fired before ``max_iteration`` at the finest level.
        A cross-checked implementation that does not report one of these four (a user's ``py:`` function
        that returns a bare matrix, say) leaves NaN, -1 or None there; ``register`` and ``icp`` set them all.
    backend : str
        ``"reference"`` or ``"open3d"`` (:func:`pcreg.register`, :func:`pcreg.icp`); in a cross-check,
        the implementation's name.
    seconds : float
        Wall time of the registration alone (no I/O, no imports); two results alike but for it are equal.
    evidence : ImageEvidence or None
        An image registration's evidence (:func:`pcreg.register`): its edge inlier, chance and overlap
        ratios and the generator of the winning hypothesis, also read as :attr:`inlier_ratio`,
        :attr:`chance_ratio`, :attr:`overlap` and :attr:`generator`; None for clouds and for a given
        transform (those read as NaN, and None for the generator).
    frames : str
        ``"T_ref_mov"`` (images: moving image -> reference image) or ``"T_target_source"`` (clouds:
        source cloud -> target cloud): the name ``matrix`` goes by.
    info : dict
        What a backend or implementation adds (a dense registration's evidence, an adapter's notes).
    trace : tuple of IcpIteration
        The iterations of a cross-checked implementation run with ``trace=True`` (the pose after each
        update, iteration 0 the initial guess), without their point arrays; empty otherwise.

    Two results are equal (``==``) when their matrices hold the same values and the other fields but
    ``seconds``, ``info`` and ``trace`` are equal, NaN as NaN.
    """

    matrix: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int
    converged: bool | None
    backend: str
    seconds: float = field(default=0.0, compare=False)
    evidence: ImageEvidence | None = None
    info: dict = field(default_factory=dict, compare=False)
    frames: str = "T_target_source"
    trace: tuple[IcpIteration, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        if self.frames not in FRAMES:
            raise ValueError(f"frames must be one of {', '.join(FRAMES)}, got {self.frames!r}")
        m = np.array(self.matrix, dtype=np.float64, copy=True)
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)

    def __hash__(self) -> int:
        return hash((self.backend, self.frames, self.iterations, self.matrix.shape))

    def __setstate__(self, state: dict) -> None:
        """Unpickled (a worker's result) or deep-copied as it was made: its matrix read-only."""
        self.__dict__.update(state)
        self.matrix.setflags(write=False)

    @property
    def inlier_ratio(self) -> float:
        """``evidence.inlier_ratio`` (NaN without evidence)."""
        return float("nan") if self.evidence is None else self.evidence.inlier_ratio

    @property
    def chance_ratio(self) -> float:
        """``evidence.chance_ratio`` (NaN without evidence)."""
        return float("nan") if self.evidence is None else self.evidence.chance_ratio

    @property
    def overlap(self) -> float:
        """``evidence.overlap`` (NaN without evidence)."""
        return float("nan") if self.evidence is None else self.evidence.overlap

    @property
    def generator(self) -> str | None:
        """``evidence.generator`` (None without evidence)."""
        return None if self.evidence is None else self.evidence.generator

    @property
    def model_fits(self) -> bool | None:
        """Whether the model fits the images (``evidence.model_fit``, :class:`ModelFit`); None where it was not
        checked (clouds, the projective model, the check turned off)."""
        fit = None if self.evidence is None else self.evidence.model_fit
        return None if fit is None else fit.fits

    @property
    def features_agree(self) -> bool | None:
        """Whether the result agrees with the homography of the images' SIFT matches (``evidence.features``,
        :class:`FeatureCheck`); None where it was not checked (clouds, the check turned off) or the features are
        too weak to say."""
        check = None if self.evidence is None else self.evidence.features
        return None if check is None else check.agree

    @property
    def trusted(self) -> bool:
        """False where a check of the result marked it (:attr:`model_fits` or :attr:`features_agree` False, or an
        image that repeats itself, ``evidence.repeats``: the result may be a period off), or where the clouds leave
        the transform free (``info["unconstrained"]``, a cross-checked implementation's pose on too few, coincident
        or collinear points: :meth:`pcreg.implementations.Implementation.run`)."""
        repeats = None if self.evidence is None else self.evidence.repeats
        return (self.model_fits is not False and self.features_agree is not False and repeats is None
                and not (self.info or {}).get("unconstrained"))

    @property
    def T_ref_mov(self) -> np.ndarray:
        """(3, 3) moving image -> reference image: the ``matrix`` of an image registration."""
        return _named(self, "T_ref_mov")

    @property
    def T_target_source(self) -> np.ndarray:
        """(d+1, d+1) source cloud -> target cloud: the ``matrix`` of a cloud registration."""
        return _named(self, "T_target_source")

    def __repr__(self) -> str:
        return (
            f"RegistrationResult(backend={self.backend!r}, fitness={self.fitness:.4f}, "
            f"inlier_rmse={self.inlier_rmse:.4g}, iterations={self.iterations}, converged={self.converged}, "
            + (f"inlier_ratio={self.inlier_ratio:.3f}, chance_ratio={self.chance_ratio:.3f}, overlap={self.overlap:.3f}, generator={self.generator!r}, "
               if self.generator is not None else "")
            + f"seconds={self.seconds:.4f}, {self.frames}={_fmt_matrix(self.matrix)})"
        )

    def to_dict(self) -> dict:
        """JSON-ready dict (``matrix`` as a list of rows; ``model_fit`` where the model was checked, ``features``
        where the result was checked against features, ``settling`` where it was refined again from starts a few
        px off, ``repeats`` where an image repeats itself)."""
        fit = None if self.evidence is None else self.evidence.model_fit
        check = None if self.evidence is None else self.evidence.features
        settling = None if self.evidence is None else self.evidence.settling
        repeats = None if self.evidence is None else self.evidence.repeats
        return {
            "matrix": self.matrix.tolist(),
            "fitness": float(self.fitness),
            "inlier_rmse": float(self.inlier_rmse),
            "iterations": int(self.iterations),
            "converged": None if self.converged is None else bool(self.converged),
            "backend": self.backend,
            "seconds": float(self.seconds),
            "inlier_ratio": None if np.isnan(self.inlier_ratio) else float(self.inlier_ratio),
            "chance_ratio": None if np.isnan(self.chance_ratio) else float(self.chance_ratio),
            "overlap": None if np.isnan(self.overlap) else float(self.overlap),
            "generator": self.generator,
            "frames": self.frames,
            **({} if fit is None else {"model_fit": fit.to_dict()}),
            **({} if check is None else {"features": check.to_dict()}),
            **({} if settling is None else {"settling": settling.to_dict()}),
            **({} if repeats is None else {"repeats": repeats.to_dict()}),
        }


@dataclass(frozen=True, repr=False, eq=False)
class IcpIteration(FieldsCompared):
    """One ICP iteration, handed to the optional per-iteration callback, and one step of a cross-checked
    implementation's :attr:`RegistrationResult.trace`.

    matrix : the pose after ``iteration`` updates (0 = the initial guess).
    source_points : (N, d) float64 — the source cloud moved by ``matrix`` (this level's units: pixels
    of the full-resolution image for image registration).
    target_indices : (N,) int — index of each source point's correspondence in ``target_points``, -1 for none.

    A callback always gets every field. In a trace the point arrays are None (the clouds are the pinned
    inputs; keeping them per step would hold the clouds once per iteration), ``target_indices`` is None
    and ``fitness`` and ``inlier_rmse`` NaN where the implementation does not report them.
    """

    backend: str
    level: int
    iteration: int
    matrix: np.ndarray
    fitness: float
    inlier_rmse: float
    source_points: np.ndarray | None = None
    target_points: np.ndarray | None = None
    target_indices: np.ndarray | None = None

    def __hash__(self) -> int:
        return hash((self.backend, self.level, self.iteration))

    def __repr__(self) -> str:
        return (f"IcpIteration(backend={self.backend!r}, level={self.level}, iteration={self.iteration}, "
                f"fitness={self.fitness:.4f}, inlier_rmse={self.inlier_rmse:.4g})")
