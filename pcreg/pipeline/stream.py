"""Streaming label propagation: one frame in, its labels out (a robot's camera, a video).

::

    clf = pcreg.fit_classifier([pcreg.Frame(key_image, key_labels)])     # naive Bayes on the key frame
    prop = pcreg.Propagator(clf, backend="reference", model="similarity")
    prop.reset(key_image, key_labels)                                    # the labelled key frame
    for image in frames:
        labels = prop.step(image)                                        # (H, W) uint8, 0 ground / 1 obstacle
        prop.last                                                        # what that step did

Each :meth:`Propagator.step` registers the new frame to the previous one (:func:`pcreg.register`, the
previous frame's cloud pyramid kept from its own step), warps the label state of the previous frame
into the new one as a prior, classifies the new frame (naive Bayes log-odds) and fuses the two
(:func:`pcreg.pipeline.temporal_update`). The new frame then becomes the reference. A registration that
is refused (:class:`~pcreg.errors.RegistrationError`, or a degenerate transform) makes that frame's
labels plain naive Bayes; the reference and its label state stay those of the last registered frame,
so the next frame is registered to it (one bad frame, a blur or a flash, does not end the chain).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..classification.fusion import FusionConfig, labels_from_log_odds
from ..errors import InputError, RegistrationError
from ..registration.config import RegisterConfig
from ..registration.result import RegistrationResult

__all__ = ["Propagator", "StepReport", "STEP_STAGES"]

#: Stages timed by every step (seconds in :attr:`StepReport.times`).
STEP_STAGES: tuple[str, ...] = ("pyramid", "register", "classify", "fuse", "total")


@dataclass(frozen=True)
class StepReport:
    """What one :meth:`Propagator.step` did.

    frame : steps since the last :meth:`~Propagator.reset` (1 for the first step).
    registration : the :class:`~pcreg.registration.result.RegistrationResult` (``T_ref_mov``: the new
        frame into the reference frame), or None when refused.
    reason : why the registration was refused (None when it was not).
    fallback : True when the labels are plain naive Bayes (no prior was fused).
    reference : the frame (counted like ``frame``, 0 = the key frame) the new frame was registered to.
    times : seconds per stage (:data:`STEP_STAGES`); ``fuse`` includes warping the prior.
    """

    frame: int
    registration: RegistrationResult | None
    reason: str | None
    fallback: bool
    reference: int
    times: dict = field(default_factory=dict)

    @property
    def registered(self) -> bool:
        return self.registration is not None

    def to_dict(self) -> dict:
        return {"frame": self.frame, "registered": self.registered, "reason": self.reason,
                "fallback": self.fallback, "reference": self.reference,
                "registration": None if self.registration is None else self.registration.to_dict(),
                "times": {k: float(v) for k, v in self.times.items()}}


class Propagator:
    """Propagate a key frame's labels along a stream of frames (see the module's docstring).

    classifier : a fitted ground/obstacle naive Bayes (:func:`pcreg.fit_classifier` on the key frame and
        its labels is the usual choice; it needs ``decision_function`` and ``class_prior_``).
    backend, model, init : the registration's (:func:`pcreg.register`); ``init="identity"`` because
        consecutive frames are close (``"auto"`` adds the global rotation search).
    register : further :class:`~pcreg.registration.config.RegisterConfig` options (levels, iterations,
        points, ...); ``backend``, ``model`` and ``init`` above override its own.
    weight : fusion weight of the prior (1 = Bayes' rule for a calibrated prior; 0 = naive Bayes alone).
    fusion : how the prior is smoothed (:class:`~pcreg.classification.fusion.FusionConfig`).
    """

    def __init__(self, classifier, *, backend: str = "reference", model: str = "similarity",
                 init: str = "identity", register: RegisterConfig | None = None, weight: float = 1.0,
                 fusion: FusionConfig = FusionConfig()) -> None:
        for attr in ("decision_function", "class_prior_"):
            if not hasattr(classifier, attr):
                raise InputError(f"the classifier has no {attr}: fit a pcreg.NaiveBayesPixelClassifier first "
                                 "(pcreg.fit_classifier on the key frame and its labels)")
        classes = list(np.asarray(getattr(classifier, "classes_", [0, 1])).tolist())
        if classes != [0, 1]:
            raise InputError(f"the classifier must know ground and obstacle (classes [0, 1]), got {classes}")
        if not (np.isfinite(weight) and weight >= 0):
            raise InputError(f"weight must be a finite number >= 0, got {weight}")
        if register is not None and not isinstance(register, RegisterConfig):
            raise InputError("register must be a pcreg.RegisterConfig")
        self.classifier = classifier
        self.config = (register or RegisterConfig()).replace(backend=backend, model=model, init=init)
        self.weight = float(weight)
        self.fusion = fusion
        self._pi = float(np.asarray(classifier.class_prior_)[1])
        self._ref_image: np.ndarray | None = None
        self._ref_pyramid = None
        self._ref_labels: np.ndarray | None = None
        self._ref_frame = 0
        self._frame = 0
        self.last: StepReport | None = None

    @classmethod
    def from_key_frame(cls, image: np.ndarray, labels: np.ndarray, *, features=("rgb", "hsv", "row"),
                       **options) -> "Propagator":
        """A propagator whose classifier is fitted on the key frame (unknown pixels left out), reset to it."""
        from ..classification.bayes import fit_classifier
        from ..datasets import Frame

        img, lab = _check_image(image), _check_labels(labels, None)
        clf = fit_classifier([Frame(img, lab, "key")], features=features)
        prop = cls(clf, **options)
        prop.reset(img, lab)
        return prop

    # -------------------------------------------------------------------------------------------
    def _pyramid(self, image: np.ndarray):
        from ..registration.clouds import image_pyramid

        c = self.config
        return image_pyramid(image, levels=c.levels, mask="auto", sampler=c.sampler,
                             canny_percentile=c.canny_percentile)

    def reset(self, image: np.ndarray, labels: np.ndarray) -> None:
        """Start a chain at a labelled key frame: image (H, W, 3) uint8 RGB, labels (H, W) uint8 with
        0 ground, 1 obstacle, 2 unknown."""
        img = _check_image(image)
        lab = _check_labels(labels, img.shape[:2])
        self._ref_image = img
        self._ref_pyramid = self._pyramid(img)
        self._ref_labels = lab
        self._ref_frame = 0
        self._frame = 0
        self.last = None

    def step(self, image: np.ndarray) -> np.ndarray:
        """Labels (H, W) uint8 (0 ground, 1 obstacle) of the next frame; see :attr:`last` for what happened."""
        from .pair import log_odds
        from .temporal import temporal_update
        from ..registration.api import register

        if self._ref_image is None:
            raise InputError("Propagator.step before reset: give the key frame and its labels first")
        t_start = time.perf_counter()
        img = _check_image(image)
        if img.shape != self._ref_image.shape:
            raise InputError(f"frame of shape {img.shape} in a stream of {self._ref_image.shape} frames")
        self._frame += 1
        times = dict.fromkeys(STEP_STAGES, 0.0)
        t0 = time.perf_counter()
        pyramid = self._pyramid(img)
        times["pyramid"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        result, reason = None, None
        try:
            result = register(self._ref_image, img, **self.config.kwargs(), reference_pyramid=self._ref_pyramid,
                              moving_pyramid=pyramid)
            M = result.matrix
            if not np.all(np.isfinite(M)) or abs(np.linalg.det(M[:2, :2])) < 1e-6:
                result, reason = None, "registration returned a degenerate transform"
        except RegistrationError as exc:
            reason = str(exc)
        times["register"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        d = log_odds(self.classifier, img)
        times["classify"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        reference = self._ref_frame
        if result is not None:
            fused, state = temporal_update(d, self._ref_labels, result.matrix, pi=self._pi, weight=self.weight,
                                           fusion=self.fusion)
            labels = labels_from_log_odds(fused)
            self._ref_image, self._ref_pyramid, self._ref_labels = img, pyramid, state
            self._ref_frame = self._frame
        else:
            labels = labels_from_log_odds(d)
        times["fuse"] = time.perf_counter() - t0
        times["total"] = time.perf_counter() - t_start
        self.last = StepReport(frame=self._frame, registration=result, reason=reason, fallback=result is None,
                               reference=reference, times=times)
        return labels

    @property
    def labels_state(self) -> np.ndarray | None:
        """(H, W) uint8 label state of the current reference frame (2 where the chain knows nothing)."""
        return None if self._ref_labels is None else self._ref_labels.copy()


def _check_image(image) -> np.ndarray:
    from ..registration.clouds import as_rgb_uint8

    return as_rgb_uint8(image, name="frame")


def _check_labels(labels, shape) -> np.ndarray:
    lab = np.asarray(labels)
    if lab.ndim == 3 and lab.shape[2] in (1, 3, 4):
        lab = lab[:, :, 0]
    if lab.ndim != 2:
        raise InputError(f"labels must be an (H, W) array, got shape {lab.shape}")
    if shape is not None and lab.shape != tuple(shape):
        raise InputError(f"labels of shape {lab.shape} for an image of shape {tuple(shape)}")
    if not (np.issubdtype(lab.dtype, np.integer) or lab.dtype == np.bool_):
        raise InputError(f"labels must be integers (0 ground, 1 obstacle, 2 unknown), got {lab.dtype}")
    if lab.size and (lab.min() < 0 or lab.max() > 2):
        raise InputError(f"labels must be 0 (ground), 1 (obstacle) or 2 (unknown); found {int(lab.max())}")
    return lab.astype(np.uint8)
