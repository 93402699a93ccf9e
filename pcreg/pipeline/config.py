"""A stream's configuration as one frozen, validated value: :class:`PropagatorConfig`.

What ``pcreg run`` takes from its command line (the motion, its DIS preset, the ICP backend, the global
registration's start, the fusion weight, the working size, whether it follows the scene or one object) is
checked once, when the value is made, and travels as it is: to each :class:`pcreg.Propagator` a run makes (:meth:`PropagatorConfig.propagator`),
and into the run's identity in ``run.json``, which a resumed run must match
(:meth:`PropagatorConfig.identity`; :func:`pcreg.runs.state.run_identity`).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError

__all__ = ["PropagatorConfig", "DEFAULT_PRESET", "FOLLOWS"]

#: DIS's preset of ``model="flow"`` when none is named.
DEFAULT_PRESET = "medium"
#: What a run follows: the scene (:class:`pcreg.Propagator`, the default) or one moving object
#: (:class:`pcreg.pipeline.follow.ObjectFollower`).
FOLLOWS: tuple[str, ...] = ("scene", "object")


@dataclass(frozen=True)
class PropagatorConfig:
    """How a run's propagators carry labels (:class:`pcreg.Propagator`'s options of the same names).

    model : ``"dense"`` (default), ``"flow"`` (DIS's optical flow at ``preset``) or a global model.
    preset : DIS's preset with ``model="flow"`` (None: :data:`DEFAULT_PRESET`); refused with another model.
    backend : the ICP backend of the registrations. init : the global registration's start. Both are a global
        model's: refused with ``dense`` and ``flow``, whose fields start from the identity.
    weight : the prior's fusion weight (0: naive Bayes alone).
    scale : the working size, a share of the frames' width and height (0 < scale <= 1).
    follow : ``"scene"`` (default: the options above) or ``"object"``: one moving object followed from its
        key-frame mask (:class:`~pcreg.pipeline.follow.ObjectFollower`, its own motion and working size, so
        the options above keep their defaults). On the five shared DAVIS sequences it takes J from 0.552 to
        0.756; on CamVid's scenes it is worse than plain naive Bayes on three clips of eight.
    """

    model: str = "dense"
    preset: str | None = None
    backend: str = "reference"
    init: str = "identity"
    weight: float = 2.0
    scale: float = 1.0
    follow: str = "scene"

    def __post_init__(self) -> None:
        from ..classification.fusion import MAX_WEIGHT
        from ..registration.choices import BACKENDS
        from ..registration.flow import PRESETS
        from ..validation import check_float, short_repr

        if self.follow not in FOLLOWS:
            raise InputError(f"unknown --follow {short_repr(self.follow)}; choose one of {', '.join(FOLLOWS)}")
        if self.follow == "object":
            default = PropagatorConfig()  # before the scene's own checks: they name options it refuses
            changed = [f"--{name}" for name in ("model", "preset", "backend", "init", "weight", "scale")
                       if getattr(self, name) != getattr(default, name)]
            if changed:
                raise InputError(f"{', '.join(changed)}: the scene stream's, not --follow object's (it has its own "
                                 "motion and working size)")
        if self.backend not in BACKENDS:
            raise InputError(f"unknown backend {short_repr(self.backend)}; choose one of {', '.join(BACKENDS)}")
        if self.model in ("dense", "flow"):  # the stream's field starts from the identity: no global registration
            given = [f"--{name} {getattr(self, name)}" for name in ("backend", "init")
                     if getattr(self, name) != getattr(PropagatorConfig, name)]
            if given:
                raise InputError(f"{', '.join(given)}: the global registration's, for a global --model (similarity, "
                                 f"affine, ...), which --model {self.model} does not run")
        if self.preset is not None and self.model != "flow":
            raise InputError(f"--preset is DIS's, for --model flow (not {self.model})")
        if self.preset is not None and self.preset not in PRESETS:
            raise InputError(f"unknown DIS preset {short_repr(self.preset)}; choose one of {', '.join(PRESETS)}")
        if not (isinstance(self.weight, (int, float)) and 0 <= self.weight <= MAX_WEIGHT):
            raise InputError(f"--weight must be a number in 0..{MAX_WEIGHT:g}, got {self.weight}")
        object.__setattr__(self, "weight", float(self.weight))
        object.__setattr__(self, "scale", check_float(self.scale, "--scale", lo=0, lo_open=True, hi=1))

    def options(self) -> dict:
        """The options as :class:`pcreg.Propagator` takes them and as a run's identity names them: a flow's
        preset in its model's name (``"flow:medium"``), the scale only when below 1 (so that runs from
        before either was named still resume)."""
        model = f"flow:{self.preset or DEFAULT_PRESET}" if self.model == "flow" else self.model
        out: dict = {"backend": self.backend, "model": model, "init": self.init, "weight": self.weight}
        if self.scale != 1.0:
            out["scale"] = self.scale
        if self.follow != "scene":
            out["follow"] = self.follow
        return out

    def propagator(self, classifier, *, learns: bool = True):
        """A :class:`pcreg.Propagator` of ``classifier`` with these options, learning from the stream as
        the stream does by default (:data:`~pcreg.pipeline.learning.STREAM_LEARNING`) or, ``learns=False``,
        not at all (between two key frames); with ``follow="object"`` an
        :class:`~pcreg.pipeline.follow.ObjectFollower` (which learns nothing; ``classifier`` only scores
        naive Bayes alone beside it)."""
        from .follow import ObjectFollower
        from .learning import STREAM_LEARNING
        from .stream import Propagator

        if self.follow == "object":
            return ObjectFollower(classifier)
        return Propagator(classifier, **self.options(), learning=STREAM_LEARNING if learns else None)

    def from_key_frame(self, image, labels, *, classes=None):
        """:meth:`propagator`'s labeller with its classifier fitted on the key frame ``image`` and its
        ``labels`` (unknown pixels left out), reset to them (each kind's own ``from_key_frame``).
        ``classes``: the labels' class table (a :class:`~pcreg.classes.ClassTable`; None: ``lagr``), handed
        to the classifier (:func:`~pcreg.classification.bayes.fit_classifier`)."""
        from .follow import ObjectFollower
        from .stream import Propagator

        if self.follow == "object":
            return ObjectFollower.from_key_frame(image, labels)
        if classes is None:
            return Propagator.from_key_frame(image, labels, **self.options())
        from ..classification.bayes import fit_classifier
        from ..datasets import Frame
        from ..frame import PreparedFrame

        key = PreparedFrame.of(image, name="key frame")
        prop = Propagator(fit_classifier([Frame(key.rgb, labels, "key")], classes=classes), **self.options())
        prop.reset(key, labels)
        return prop
