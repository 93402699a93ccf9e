"""Streaming label propagation: one frame in, its labels out (a robot's camera, a video).

::

    prop = pcreg.Propagator.from_key_frame(key_image, key_labels)   # naive Bayes fitted on the key frame
    for image in frames:
        labels = prop.step(image)                                    # (H, W) uint8, 0 ground / 1 obstacle
        prop.last                                                    # what that step did

Each :meth:`Propagator.step`

1. registers the new frame to the key frame (``anchor="key"``, the default for two classes) or to the previous frame
   (``anchor="previous"``, the motions composed back to the key frame): with ``model="dense"`` (the
   default) a dense field (:func:`pcreg.register_dense`), with ``model="flow"`` DIS optical flow at
   ``preset`` (:func:`pcreg.registration.flow.dis_flow`), else one transform (:func:`pcreg.register`);
2. warps the key frame's labels, as a smoothed prior, into the new frame along that motion, and along
   a second motion found independently, DIS optical flow at its ultrafast preset (none when the first
   motion is a flow already);
3. classifies the new frame (naive Bayes log-odds) and fuses it with both priors, each weighted per
   pixel by how well the key frame carried along the same motion matches the new frame there (the
   trust rule, :mod:`pcreg.pipeline.trust`), and gives every label its confidence, the probability
   that it is right (:attr:`StepReport.confidence`);
4. lets naive Bayes learn from the pixels it labelled with sure priors, never beyond half the key
   frame's weight (:mod:`pcreg.pipeline.learning`).

With ``trust=None`` (and so no learning) step 3 is the fusion of one prior at ``weight``, per pixel from half to twice
``weight`` as the dense field's confidence goes from 0 to 1 (:func:`pixel_weight`), as the evaluations' motion
ablations run it.

A registration that fails (:class:`~pcreg.errors.RegistrationError`, or a degenerate transform) does not throw the key
frame's labels away: they are fused as they are, unwarped (the best prior that needs no motion), and the step says so
(``fallback``). Registration's own plausibility test, calibrated on photographs, is off here: in a stream the frames
show the same scene by construction, and a camera moving through a 3-D scene fails a global model's edge-inlier test
although its motion still carries labels well (measured on CamVid clips: the test refused most key-to-frame
registrations, and most of those would have lowered the error).

Why the defaults (measured on CamVid clips, first frame as the key frame; docs/results.md):

- **Anchored to the key frame.** Each frame is registered to the key frame directly, so motions are
  not composed and their errors not summed: frame-to-frame chains diverged on clips at one frame a
  second. (The warm start below starts from the previous frame's field, but matches the new frame
  against the key frame itself, and starts again from scratch where that start lost the frame.)
- **Dense, from the identity** on the first frame after a key frame (and on restarts). The field
  follows the motions that differ per object (parallax of the road against a facade); its coarsest
  gate reaches ``radius * 2^(levels - 1)`` = 48 px. A global similarity first gave no better labels
  and cost a registration more.
- **Warm: each step starts from the previous step's field** (:attr:`DenseStep.warm`). The key frame's
  field to frame t is close to its field to frame t - 1, so the registration starts there, at pyramid
  level 2 with the wide gate (12 px of further motion), skips the two coarser levels and runs 4
  iterations a level instead of 8. On the four shared CamVid clips this labelled frames as well as
  the cold start (35.1% below plain's error against 35.0%; 86% against 80% on the synthetic
  streams), at about 0.6-0.8 of the registration's time. What a warm start cannot follow (a jump
  beyond its gate, a cut) shows in the field's evidence against chance: a warm step whose evidence
  falls under half that of the last cold step runs again cold and keeps the better field
  (:attr:`DenseStep.restart_ratio`). From one frame to the next the cold evidence changed by a factor
  of 0.55 at the 1st percentile on those clips (0.38 at the least), while warm steps that lost a
  30-40 px jump fell to 0.02-0.37 of it; a false restart costs a cold registration, never accuracy.
  The first step after :meth:`~Propagator.reset`, and the one after a failed step, are cold. A step
  is then a function of the key frame, the new frame and the previous step's grid
  (:attr:`Propagator.carry`), which ``pcreg run`` saves with every frame, so an interrupted run still
  resumes exactly.
- **Trust, a second motion and learning** (:data:`~pcreg.pipeline.trust.STREAM_TRUST`,
  :data:`~pcreg.pipeline.learning.STREAM_LEARNING`): on the eight shared CamVid clips, each constant
  chosen with the clip scored left out, the trust rule took the mean reduction of plain's error from
  35.9% (one prior by the field's confidence) to 42.2%, and learning to 43.2%; the carried key frame
  matching the new frame is what tells a slid field or a changed scene, and two motions found
  independently are wrong in different places (docs/results.md, "Trust").
- **Plain colours** (:data:`STREAM_DENSE`): over seconds the low frequencies (road against sky and facade) are what
  tells regions apart; matching the texture part alone lost a fifth of the gain.
- **Weight 2** (:data:`STREAM_WEIGHT`): naive Bayes over ``rgb+hsv+row`` counts the same colour twice (RGB and HSV are
  two codings of one colour), so its log-odds are about twice as sure as a calibrated classifier's; the prior, built
  as a calibrated probability, is weighted to match. No label of a later frame is needed to choose it.
- **The weight follows the field's confidence** (:data:`~pcreg.pipeline.prior.CONFIDENCE_SPAN`): where the dense field
  has the evidence of many matched samples the warped labels are trusted more, where it was interpolated over a
  textureless or occluded area less, a factor of two either way around the weight (``weight`` where the confidence is
  1/3). On the four shared CamVid clips it took the mean reduction of plain's error from 31.9% to 35.0% (every clip
  better), and from 78.9% to 87.9% on 8-frame synthetic streams; the same weight everywhere raised to 3 gave 31.2% and
  85.6%, the weight in proportion to the confidence 27.7%.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable

import numpy as np

from .._calls import OneStream, one_caller
from .._threads import alongside
from .bars import Bars
from ..classification.features import DEFAULT_FEATURES
from ..classification.fusion import FusionConfig, label_prior, prior_log_odds
from .cuts import Scene, SceneCheck
from .report import PriorTerms, StepReport
from .estimators import STREAM_DENSE, Carry, ChainCarry, chain_after, check_stream_options, DenseStep, FlowEstimator, StreamMotion, motion_model, stream_motion
from .learning import STREAM_LEARNING, Learner, Learning, learns
from .multiclass import CLASS_ANCHOR, CLASS_PRIOR_SIGMA, CLASS_WEIGHT_SHARE, ClassRead, fused_class_labels, class_prior_maps, class_priors, prior_log_probs
from .prior import class_prior, fused_labels, fused_log_odds, pixel_weight, prior_on_moving
from .trust import CLASS_TRUST, STREAM_TRUST, Trusted, TrustedKey, TrustRule, least_confident
from .working import WorkingSize
from ..classes.keys import binary_table, check_key_classes, check_labels, lagr_ids
from ..errors import InputError
from ..frame import PreparedFrame
from ..registration.config import RegisterConfig
from ..registration.flow import DIS_MIN_SIDE
from ..registration.motion import Motion

if TYPE_CHECKING:
    from ..registration.dense import DenseReference
    from .estimators import Estimate

__all__ = ["Propagator", "StepReport", "PriorTerms", "check_labels", "STEP_STAGES", "STEP_PARTS", "STREAM_MODELS", "DenseStep", "Carry", "STREAM_DENSE",
           "STREAM_REGISTRATION", "STREAM_WEIGHT", "ANCHORS"]

#: Stages timed by every step (seconds in :attr:`StepReport.times`).
STEP_STAGES: tuple[str, ...] = ("register", "classify", "fuse", "total")
#: Their parts, timed as ``"stage.part"`` in :attr:`StepReport.times`: a dense registration's own
#: stages (:data:`pcreg.registration.dense.DENSE_STAGES`, its global step as ``global``; present when
#: the dense registration ran); beside it, the classifier's learning from the last frame (its histograms
#: counted, naive Bayes refitted), its log-odds and the trust rule's DIS flow; then the priors' warp, their
#: trust (:mod:`pcreg.pipeline.trust`), the fusion (with a trust rule, one pass with the trust, timed as
#: ``trust``), the labels' confidence and the frame's sure pixels kept for learning; a part not done is 0.
STEP_PARTS: dict[str, tuple[str, ...]] = {
    "register": ("global", "pyramid", "search", "solve", "evidence", "field"),
    "classify": ("learn", "bayes", "flow"),
    "fuse": ("warp", "trust", "fusion", "confidence", "learn"),
}
#: The stream's motions beside the global models (:data:`pcreg.registration.transforms.MODELS`): a dense
#: field, and DIS optical flow.
STREAM_MODELS: tuple[str, ...] = ("dense", "flow")
#: Where a frame is registered to: the key frame, or the previous frame (motions composed).
ANCHORS: tuple[str, ...] = ("key", "previous")
#: Fusion weight of the key frame's prior (see the module's docstring).
STREAM_WEIGHT = 2.0
#: A stream's global registration: from the identity, the photograph-calibrated test off.
STREAM_REGISTRATION = RegisterConfig.of(model="similarity", init="identity", min_inlier_ratio=None)


#: The advice that ends the refusal of a scale too small for the frames (what a caller that chose the scale itself,
#: not its user, replaces).
SCALE_ADVICE = "; choose a larger scale"


class Propagator(OneStream):
    """Propagate a key frame's labels along a stream of frames (see the module's docstring).

    classifier : a fitted ground/obstacle naive Bayes (:func:`pcreg.fit_classifier` on the key frame and
        its labels is the usual choice; it needs ``decision_function`` and ``class_prior_``). One of a class table
        of two known classes in other ids (0 and 1 with a void 255; road 5, car 9, void 255) runs the same step as
        in ``lagr``'s ids (:meth:`~pcreg.classification.bayes.NaiveBayesPixelClassifier.in_lagr_ids`), the key
        labels taken and the labels given in the table's ids (:func:`~pcreg.classes.keys.lagr_ids`); one of more
        classes the many-class step (:mod:`pcreg.pipeline.multiclass`).
    model : ``"dense"`` (default), ``"flow"`` (DIS optical flow from each frame to the key frame, medium
        preset; ``"flow:fast"``, ``"flow:ultrafast"``: another preset) or a global motion model
        (``similarity``, ``projective``, ...). With a flow the trust rule carries no second motion, and
        learning and the confidence are as with the dense field. On the shared CamVid clips
        (docs/results.md, "The flow model") ``"flow"`` at ``scale=0.5`` labels 47% below plain at a
        quarter of the default step's time, ``"flow:fast"`` at half size 43% at an eighth.
    anchor : ``"key"`` or ``"previous"`` (:data:`ANCHORS`); None (default): ``"key"`` for ground and
        obstacle, :data:`~pcreg.pipeline.multiclass.CLASS_ANCHOR` with more classes.
    backend, init : the registration's (:func:`pcreg.register`, also the dense model's global step).
    register : further :class:`~pcreg.registration.config.RegisterConfig` options (levels, iterations,
        points, the plausibility test, ...); ``backend``, ``init`` and a global ``model`` override its own.
    dense : :class:`DenseStep` options of the dense model.
    weight : fusion weight of the prior (0 = naive Bayes alone); with a dense field, per pixel from
        half to twice it by the field's confidence (:func:`~pcreg.pipeline.prior.pixel_weight`). fusion : how the prior is smoothed.
    trust : how far each carried prior is trusted per pixel, and a second prior carried by DIS flow
        (:class:`~pcreg.pipeline.trust.TrustRule`; the default :data:`~pcreg.pipeline.trust.STREAM_TRUST`);
        it also gives every label its confidence (:attr:`StepReport.confidence`). None: the prior at
        ``weight``, by the field's confidence alone, as :func:`~pcreg.pipeline.prior.fused_labels`.
    learning : how naive Bayes learns from the frames it labels (:class:`~pcreg.pipeline.learning.Learning`;
        with a trust rule and a pcreg :class:`~pcreg.classification.bayes.NaiveBayesPixelClassifier`
        only; None: it does not).
    scale : the working size, a share (0 < scale <= 1) of the frames' width and height the whole step
        runs at (:mod:`pcreg.pipeline.working`); the labels and their confidence come back at the frames'
        size, the report's other maps (log-odds, trust map, field) are at the working size. 0.5 runs a
        640x480 step in 0.53-0.56 of the time, for 48.4% below plain instead of 49.7% on the shared CamVid clips.
    """

    bars: Bars | None = None  #: the key frame's black bars, where a letterboxed frame keeps its labels (:mod:`pcreg.pipeline.bars`)

    def __init__(self, classifier, *, model: str = "dense", anchor: str | None = None, backend: str = "reference",
                 init: str = "identity", register: RegisterConfig | None = None, dense: DenseStep = STREAM_DENSE,
                 weight: float = STREAM_WEIGHT, fusion: FusionConfig = FusionConfig(),
                 trust: TrustRule | None = STREAM_TRUST, learning: Learning | None = STREAM_LEARNING,
                 scale: float = 1.0) -> None:
        from ..validation import check_float, short_repr

        for attr in ("decision_function", "class_prior_"):
            if not hasattr(classifier, attr):
                raise InputError(f"the classifier has no {attr}: fit a classifier first "
                                 "(pcreg.fit_classifier on the key frame and its labels)")
        # a table of two known classes in other ids than lagr's: the two-class step on the same model in lagr's
        # ids, its labels mapped back to the table's (:func:`~pcreg.classes.keys.lagr_ids`)
        table = getattr(classifier, "class_table", None)
        self._ids = lagr_ids(table) if table is not None and hasattr(classifier, "in_lagr_ids") else None
        nb = classifier if self._ids is None else classifier.in_lagr_ids()
        classes = list(np.asarray(getattr(nb, "classes_", [0, 1])).tolist())
        # ground and obstacle: classes 0 and 1 of a table that has no others (a key frame that shows only the
        # first two classes of a larger table is a many-class stream that has seen two of them so far)
        binary = classes == [0, 1] and (table is None or binary_table(table) or self._ids is not None)
        if not binary and not (len(classes) >= 2 and hasattr(classifier, "class_scores")
                                      and hasattr(classifier, "class_table")):
            raise InputError(f"the classifier must know ground and obstacle (classes [0, 1]), got {classes}; "
                             "other classes need a pcreg NaiveBayesPixelClassifier with its class table")
        model, preset = motion_model(model)
        if anchor is not None and (not isinstance(anchor, str) or anchor not in ANCHORS):
            raise InputError(f"unknown anchor {short_repr(anchor)}; choose one of {', '.join(ANCHORS)}")
        check_stream_options(weight, STREAM_WEIGHT, fusion, register, dense, trust, learning)
        self.classifier = classifier
        self._nb = nb  # what the step runs: ``classifier``, or it in lagr's ids
        self.model = model
        self.anchor: str = anchor or ("key" if binary else CLASS_ANCHOR)
        self.scale = check_float(scale, "scale", lo=0, lo_open=True, hi=1)
        base = register or STREAM_REGISTRATION
        self.config = base.replace(backend=backend, init=init,
                                   model=base.model if model in STREAM_MODELS else model)
        self.dense = dense
        # the dense registration's options, cold and warm, checked once here
        from ..registration.dense import DenseOptions, GlobalStep

        base = DenseOptions(seed=self.config.search.seed, global_step=GlobalStep(backend=self.config.backend))
        self._dense_options = (dense.options(base), dense.options(base, warm=True))
        self.preset = preset  # a flow's DIS preset (None for the other models)
        self._estimator: StreamMotion = stream_motion(model, preset, self.config, dense, self._dense_options)
        self.weight = float(weight)
        # K classes (any but ground and obstacle): the step of :mod:`pcreg.pipeline.multiclass`, its priors at
        # their share of the weight, and the stream's trust rule as it reads many classes
        self._classes = None if binary else np.asarray(classes, np.uint8)
        self._prior_weight = self.weight if self._classes is None else self.weight * CLASS_WEIGHT_SHARE
        if self._classes is not None and trust is STREAM_TRUST:
            trust = CLASS_TRUST
        self.fusion = fusion
        self.trust = trust
        self.learning = learning if trust is not None and learns(nb) else None
        self._learner: Learner | None = None
        self._flow = FlowEstimator("ultrafast" if trust is None else trust.preset)
        self._pi = class_prior(nb) if self._classes is None else class_priors(nb)
        # the key frame, checked once, and what every step reads of it, made once (:meth:`reset`)
        self._key: PreparedFrame | None = None  # at the working size
        self._key_labels: np.ndarray | None = None  # at the frames' size
        self._size: WorkingSize | None = None
        self._key_prior: np.ndarray | None = None
        self._key_trusted: TrustedKey | None = None  # its prior and colours as the trust rule reads them
        self._key_flow: tuple | None = None  # its grey levels and grid for the second motion's DIS
        self._key_scene: SceneCheck | None = None  # the cut test (:mod:`pcreg.pipeline.cuts`)
        self._key_prepared: DenseReference | tuple | None = None  # its pyramid (dense) or grey levels (flow)
        self._chain: tuple[PreparedFrame, Motion | None, int] | None = None  # (frame, motion to the key frame, frame)
        self._carry: Carry | None = None
        self._frame = 0
        self.last: StepReport | None = None

    @classmethod
    def from_key_frame(cls, image: np.ndarray, labels: np.ndarray, *, features=DEFAULT_FEATURES,
                       classes=None, **options) -> "Propagator":
        """A propagator whose classifier is fitted on the key frame (unknown pixels left out), reset to it.
        classes : the labels' class table (a :class:`~pcreg.classes.ClassTable` or what
        :func:`pcreg.classes.class_table` reads; default ``lagr``, ground and obstacle)."""
        from ..classes import class_table
        from ..classification.bayes import fit_classifier
        from ..datasets import Frame

        table = class_table(classes)
        key = PreparedFrame.of(image, name="key frame")
        lab = check_labels(labels, None, table)
        if not (lab != table.unknown).any():
            raise InputError(f"the key frame's labels are all unknown ({table.unknown}): nothing to fit or propagate")
        clf = fit_classifier([Frame(key.rgb, lab, "key")], features=features, classes=table)
        prop = cls(clf, **options)
        prop.reset(key, lab)
        return prop

    @one_caller
    def reset(self, image: np.ndarray, labels: np.ndarray) -> None:
        """Start at a labelled key frame: image (H, W, 3) uint8 RGB, labels (H, W) uint8, the ids of the
        classifier's class table (by default 0 ground, 1 obstacle, 2 unknown). A dense stream anchored to the
        key frame prepares it here, once (:func:`~pcreg.registration.dense.prepare_reference`: its pyramid),
        for every step's registration. A key frame refused leaves the stream as it was."""
        before = dict(self.__dict__)  # reset replaces its attributes, never changes one in place
        try:
            self._reset(image, labels)
        except BaseException:
            self.__dict__ = before
            raise

    def _reset(self, image: np.ndarray, labels: np.ndarray) -> None:
        full, table = PreparedFrame.of(image, name="key frame"), getattr(self.classifier, "class_table", None)
        lab = check_key_classes(check_labels(labels, full.shape, table), table, self._classes)
        self._size = size = WorkingSize(full.shape, self.scale)
        if size.scaled or self._estimator.checks_every_size:  # a size the motion cannot take: refused here
            size.check_for(self._estimator, self.model, self.scale, SCALE_ADVICE)
        full.check_key(lab, 2 if table is None else table.unknown)
        key = size.shrunk(full) if size.scaled else full.copy()  # the caller may reuse its array for the frames
        self._key, self._key_labels = key, lab
        self._key_trusted = self._key_flow = self._key_scene = None
        if self._ids is not None:  # the table's ids in lagr's: its known classes in id order 0 and 1, the unknown 2
            lut = np.full(256, 2, np.uint8)
            lut[self._ids] = (0, 1, 2)
            lab = lut[lab]
        self.bars = Bars.of(full.rgb, lab)
        small = size.labels(lab)
        if self._classes is not None:  # K classes: the prior's evidence per class, what every motion carries
            fusion = replace(self.fusion, sigma=CLASS_PRIOR_SIGMA) if self.fusion == FusionConfig() else self.fusion
            self._key_prior = prior_log_probs(class_prior_maps(small, self._classes, self._pi, fusion=fusion), self._pi)
        else:
            self._key_prior = label_prior(small, pi=self._pi, fusion=self.fusion)
        if self.trust is not None:
            evidence = self._key_prior if self._classes is not None else prior_log_odds(self._key_prior, pi=self._pi)
            self._key_trusted = TrustedKey(self.trust, self._prior_weight, key.rgb, evidence, size,
                                           classes=self.class_read, labels=small)
            if min(key.shape) >= DIS_MIN_SIDE:  # DIS takes no smaller frames
                if self._estimator.second_motion:
                    self._key_flow = self._flow.prepare(key)
                # the cut test, whatever the motions: a flow model carries no second motion, and a rule may give
                # it no weight, yet a cut leaves their labels as untrustworthy
                self._key_scene = SceneCheck(key.rgb)
        self._learner = None if self.learning is None else Learner(self._nb, self.learning)
        # every frame registers to the key frame: what the motion needs of it, prepared once
        self._key_prepared = self._estimator.prepare(key) if self.anchor == "key" else None
        self._chain = (key, None, 0)
        self._carry = None
        self._frame = 0
        self.last = None

    @one_caller
    def step(self, image: "np.ndarray | PreparedFrame") -> np.ndarray:
        """Labels (H, W) uint8 (0 ground, 1 obstacle; with more classes their ids) of the next frame, an
        image or a :class:`~pcreg.frame.PreparedFrame` (checked once here; naive Bayes, both motions and the learning
        take it as it is, and its features are kept with it); see :attr:`last` for what happened. A step that raises
        (an error of its classifier, Ctrl-C) leaves the stream as it was: the next step is the one it would have
        been without that frame."""
        key, size = self._key, self._size
        if key is None or size is None:
            raise InputError("Propagator.step before reset: give the key frame and its labels first")
        t_start = time.perf_counter()
        full = PreparedFrame.of(image, name="frame", shape=size.frame)
        frame, bars = size.shrunk(full), self.bars if self.bars is not None and self.bars.held(full.rgb) else None
        before = (self._frame, self._carry, self._chain, self.scene,
                  None if self._learner is None else self._learner.snapshot(), self.last)
        try:
            return self._step(key, frame, t_start, bars)
        except BaseException:
            self._frame, self._carry, self._chain, self.last = *before[:3], before[5]
            if self._key_scene is not None:
                self._key_scene.restore(before[3])
            if self._learner is not None:
                self._learner.rewind(before[4])
            raise

    def _step(self, key: PreparedFrame, frame: PreparedFrame, t_start: float, bars: Bars | None = None) -> np.ndarray:
        """:meth:`step` of a checked ``frame`` (at the working size), begun at ``t_start``, showing the key frame's ``bars``."""
        self._frame += 1
        times = dict.fromkeys(STEP_STAGES, 0.0)
        times.update({f"{stage}.{part}": 0.0 for stage, parts in STEP_PARTS.items() if stage != "register"
                      for part in parts})
        reference, ref_frame = (key, 0) if self.anchor == "key" else (self._chain[0], self._chain[2])
        # classified while this thread registers it (they are independent): the helper takes the second motion
        # first, the longer part, then naive Bayes, which this thread does itself if it is done before the
        # helper got to it (:func:`~pcreg._threads.alongside`); their times are their own, ``total`` the step's
        sides: list[Callable] = [lambda: self._classify(frame)]
        if self._key_trusted is not None:
            sides.insert(0, lambda: self._second_motion(frame))
        (est, times["register"]), classified = alongside(lambda: self._register(reference, frame), *sides)
        c = classified[-1]
        times.update(c.times)
        if len(classified) > 1:
            c.frame_blurred, c.flow, c.cut, times["classify.flow"] = classified[0]
            times["classify"] += times["classify.flow"]
        result, motion = est.result, est.motion
        if motion is not None and self.anchor == "previous" and self._chain[1] is not None:
            motion = self._chain[1].after(motion, frame.shape)  # the previous frame's motion to the key frame after it
        dense_times = getattr(result, "info", {}).get("times") if result is not None else None
        if dense_times is not None:
            times["register.global"] = float(result.global_result.seconds)
            times.update({f"register.{k}": float(v) for k, v in dense_times.items()})

        trusted: Trusted | None = None
        if self._key_trusted is None:
            labels = self._fuse(c.d, motion, times)
        else:
            moved = motion if motion is not None else Motion(matrix=np.eye(3))
            trusted = self._key_trusted.fuse(c.d, c.frame_blurred, moved.as_field(frame.shape), moved.confidence,
                                             c.flow, times)
            if c.degenerate or (c.cut is not None and c.cut["cut"]):  # a spike of a class, another scene: marked
                trusted = least_confident(trusted, 2 if self._classes is None else len(self._classes))
            labels = trusted.labels
            if self._learner is not None:
                t0 = time.perf_counter()
                self._learner.update(frame, trusted.fused, trusted.prior)
                times["fuse.learn"] = time.perf_counter() - t0
        if motion is not None and self.anchor == "previous":
            self._chain = (frame.copy(), motion, self._frame)  # the next step's reference, kept
        labels, trusted = (labels, trusted) if bars is None else bars.kept(labels, trusted)  # a letterbox's labels kept
        times["fuse"] = sum(times[f"fuse.{part}"] for part in STEP_PARTS["fuse"])
        times["total"] = time.perf_counter() - t_start
        self.last = StepReport(frame=self._frame, registration=result, reason=est.reason, fallback=motion is None,
                               reference=ref_frame, times=times, start=est.start, log_odds=c.d,
                               **({} if trusted is None else trusted.report(self.trust, self._prior_weight,
                                                                           {**({} if c.cut is None else {"cut": c.cut["cut"]}),
                                                                            "degenerate": c.degenerate},
                                                                           self._ids)))
        return self.table_labels(labels)

    def class_iou(self, labels: np.ndarray, confidence: np.ndarray, second: np.ndarray | None) -> dict[int, float]:
        """Each class's predicted IoU of ``labels`` read another way than a step reads them (between two key frames),
        by the table's ids (:func:`~pcreg.pipeline.trust.class_predicted_iou`; ``labels`` in the step's ids)."""
        from .trust import class_predicted_iou

        return class_predicted_iou(labels, confidence, second, self._ids)

    def table_labels(self, labels: np.ndarray) -> np.ndarray:
        """The two-class step's ``labels`` (0, 1; 2 unknown) in the classifier's class table's ids: themselves, but
        for a table of two known classes in other ids (:func:`~pcreg.classes.keys.lagr_ids`), whose labels the step
        makes in ``lagr``'s ids; :meth:`step` returns them so."""
        return labels if self._ids is None else self._ids[labels]

    def _classify(self, frame: PreparedFrame) -> "_Classified":
        """Naive Bayes' log-odds of the frame (the classifier as learned so far, what the last frame taught
        it counted first): all that needs no registration but the second motion (:meth:`_second_motion`)."""
        from ..classification.bayes import NaiveBayesPixelClassifier
        from .pair import checked_scores

        t0 = time.perf_counter()
        clf = self._nb if self._learner is None else self._learner.classifier
        t1 = time.perf_counter()
        image = frame if isinstance(clf, NaiveBayesPixelClassifier) else frame.rgb
        if isinstance(clf, NaiveBayesPixelClassifier):
            d = np.asarray(clf.decision_function(image) if self._classes is None else clf.class_scores(image),
                           dtype=np.float32)
        else:
            d = checked_scores(clf, image.shape[:2], None if self._classes is None else len(self._classes), image)
        t2 = time.perf_counter()
        degenerate = clf.degenerate_classes() if isinstance(clf, NaiveBayesPixelClassifier) else []
        return _Classified(d, times={"classify": t2 - t0, "classify.learn": t1 - t0, "classify.bayes": t2 - t1},
                           degenerate=degenerate)

    def _second_motion(self, frame: PreparedFrame) -> tuple[np.ndarray, tuple | None, dict | None, float]:
        """``(frame_blurred, flow, cut, seconds)``: the frame as residuals compare it (:func:`~pcreg.pipeline.trust.
        blurred`), the key frame's prior and residual carried along the DIS flow to it and the cut test
        (:class:`~pcreg.pipeline.cuts.SceneCheck`; the flow's None without the second motion, the cut test's
        for frames DIS does not take)."""
        from .trust import blurred

        t0 = time.perf_counter()
        frame_blurred, flow, cut = blurred(frame.rgb), None, None
        if self._key_flow is not None and self._key_trusted is not None and self._key_trusted.rule.flow > 0:
            field = self._flow.estimate(self._key, frame, prepared=self._key_flow).result.field
            flow = self._key_trusted.carried(frame_blurred, field)
        if self._key_scene is not None:
            cut = self._key_scene.test(frame.rgb)
        return frame_blurred, flow, cut, time.perf_counter() - t0

    def _fuse(self, d: np.ndarray, motion: Motion | None, times: dict) -> np.ndarray:
        """The labels without a trust rule: the key frame's prior along ``motion`` at :attr:`weight`, by
        the field's confidence (:func:`~pcreg.pipeline.prior.fused_labels`)."""
        if self._classes is not None:  # K classes: the key frame's evidence per class along ``motion``, the best class
            assert self._key_prior is not None  # reset made it
            return fused_class_labels(d, self._key_prior, motion, pixel_weight, self._prior_weight, self._classes,
                                      self._size, times)
        t0 = time.perf_counter()
        q = prior_on_moving(self._key_prior, motion, shape=d.shape, pi=self._pi)
        t1 = time.perf_counter()
        confidence = None if motion is None else motion.confidence
        size = self._size
        if size is not None and size.scaled:  # the fused log-odds brought to the frames' size, then their sign
            fused = fused_log_odds(d, q, confidence, weight=self.weight, pi=self._pi)
            labels = (size.grow(fused) > 0).astype(np.uint8)
        else:
            labels = fused_labels(d, q, confidence, weight=self.weight, pi=self._pi)
        times.update({"fuse.warp": t1 - t0, "fuse.fusion": time.perf_counter() - t1})
        return labels

    def _register(self, reference: PreparedFrame, frame: PreparedFrame) -> tuple["Estimate", float]:
        """The estimate of ``frame``'s motion to ``reference`` and its seconds (:meth:`~pcreg.pipeline.estimators.
        DenseEstimator.estimate`: a result, or a refusal and why); keeps the carry it leaves."""
        t0 = time.perf_counter()
        prepared = self._key_prepared if reference is self._key else None
        est = self._estimator.estimate(reference, frame, prepared=prepared,
                                       carry=self._carry if self.warm_starts else None)
        self._carry = est.carry if self.warm_starts else None
        return est, time.perf_counter() - t0

    @property
    def warm_starts(self) -> bool:
        """Whether dense steps start from the previous one (what :attr:`carry` is for)."""
        return self._estimator.warm_starts(self.anchor)

    @property
    def carry(self) -> Carry | ChainCarry | None:
        """What the next step starts from: a dense step's :class:`Carry` (None: it starts cold), or a chained
        stream's :class:`~pcreg.pipeline.estimators.ChainCarry` (the frame the next is registered to)."""
        if self.anchor == "previous" and self._chain is not None:
            return ChainCarry(self._chain[0].rgb, self._chain[1], self._chain[2])
        return self._carry

    @property
    def learned(self) -> np.ndarray | None:
        """What naive Bayes has learned from the stream so far ((N, F, 256) float64 histograms, N the class
        table's values (3 by default, and for two known classes in any ids, learned in ``lagr``'s),
        :class:`~pcreg.pipeline.learning.Learner`), or None without learning; ``pcreg run`` saves it
        with every frame."""
        return None if self._learner is None else self._learner.stream.copy()

    @property
    def scene(self) -> Scene | None:
        """The cut test's last frame of the key frame's scene (:class:`~pcreg.pipeline.cuts.Scene`), which the next
        step's frame is tested against, or None without the cut test; ``pcreg run`` saves it with the carry."""
        return None if self._key_scene is None else self._key_scene.scene

    def learned_later(self) -> Callable[[], np.ndarray | None]:
        """:attr:`learned` as it is now, computed when called, on any thread (``pcreg run`` writes it beside
        the next step); the step's own learning is left to the helper thread."""
        return (lambda: None) if self._learner is None else self._learner.stream_later()

    @one_caller
    def resume(self, frame: int, carry: "Carry | ChainCarry | None", learned: np.ndarray | None = None,
               scene: Scene | None = None) -> None:
        """Continue a stream after its step ``frame`` (counted from the key frame, as :attr:`StepReport.frame`)
        with the ``carry`` that step left (:attr:`carry`, as saved): the next step does what it would
        have done in the uninterrupted stream (a chained stream's is a :class:`~pcreg.pipeline.estimators.
        ChainCarry`). ``learned``: what the classifier had learned by then (:attr:`learned`); ``scene``: the cut
        test's last frame of the key frame's scene by then (:attr:`scene`; None: not known, the next frame is
        taken as one, and a cut before it is not found again)."""
        from ..registration.dense import finest_grid_shape
        from ..validation import check_int

        if self._key is None:
            raise InputError("Propagator.resume before reset: give the key frame and its labels first")
        frame = check_int(frame, "frame", lo=0)
        if scene is not None and not isinstance(scene, Scene):
            raise InputError("scene must be a pcreg.pipeline.cuts.Scene or None")
        if self._key_scene is not None:
            self._key_scene.check(scene)
        chain = self._chain
        if self.anchor == "previous":  # after the key frame itself, its own chain: no carry needed
            chain = (self._key, None, 0) if frame == 0 and carry is None else chain_after(carry, self._key, frame)
            carry = None
        if carry is not None and not isinstance(carry, Carry):
            raise InputError("carry must be a pcreg.pipeline.stream.Carry or None")
        if carry is not None and self.warm_starts:
            want = finest_grid_shape(self._key.rgb.shape, self._dense_options[0])
            if carry.grid.shape != (*want, 2):
                raise InputError(f"the carried grid is {carry.grid.shape[0]}x{carry.grid.shape[1]}, a stream of "
                                 f"these frames has {want[0]}x{want[1]}: it comes from another stream")
        if self._learner is not None:  # the last that refuses: a refused resume leaves the stream as it was
            self._learner.restore(learned)
        self._chain, self._frame = chain, frame
        self._carry = carry if self.warm_starts else None
        if self._key_scene is not None:
            self._key_scene.restore(scene)

    @property
    def working_size(self) -> WorkingSize | None:
        """The frames' size (its ``frame``: the labels' and the confidence's) and the size the steps run at (its ``shape``: the report's other maps'); None before :meth:`reset`."""
        return self._size

    @property
    def classes(self) -> np.ndarray | None:
        """With more than two classes (:mod:`pcreg.pipeline.multiclass`) the classifier's class ids, in the order of the class scores' channels; None for ground and obstacle."""
        return None if self._classes is None else self._classes.copy()

    @property
    def class_read(self) -> ClassRead | None:
        """With more than two classes what their read-out needs (:class:`~pcreg.pipeline.multiclass.ClassRead`:
        the class ids, the log class priors, the confidence's coefficients); None for ground and obstacle."""
        if self._classes is None:
            return None
        return ClassRead(self._classes.copy(), np.log(np.asarray(self._pi, np.float64)).astype(np.float32))

    @property
    def key_labels(self) -> np.ndarray | None:
        """(H, W) uint8 labels of the key frame (None before :meth:`reset`)."""
        return None if self._key_labels is None else self._key_labels.copy()


@dataclass
class _Classified:
    """What a step finds beside the frame's registration (:meth:`Propagator._classify`, ``_second_motion``)."""

    d: np.ndarray
    frame_blurred: np.ndarray | None = None
    flow: tuple[np.ndarray, np.ndarray] | None = None  # the key frame's prior and residual along the DIS flow
    cut: dict | None = None  # the cut test (:class:`~pcreg.pipeline.cuts.SceneCheck`)
    degenerate: list = field(default_factory=list)  # the classifier's classes fitted as spikes
    times: dict = field(default_factory=dict)

