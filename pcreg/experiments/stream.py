"""Label a stream from one labelled key frame: ``pcreg evaluate stream``.

Protocol, per clip: the first frame is the key frame (``key_every=N`` adds one every N frames). Naive
Bayes (RGB + HSV + row) is fitted on the current key frame only, and every later frame up to the next
key frame is labelled by each method, in the same run, and scored against its ground truth (error %,
unknown truth left out). No label of a non-key frame is used for anything but scoring: the fusion
weight is the fixed :data:`pcreg.pipeline.stream.STREAM_WEIGHT`.

The methods (:data:`METHODS`):

- ``plain``: naive Bayes alone.
- ``unregistered``: the key frame's labels fused as they are (no motion).
- ``pcreg``: exactly what ``pcreg run`` does (:class:`pcreg.Propagator` with its defaults; its labels read
  the fused log-odds blurred, :func:`pcreg.pipeline.trust.smoothed`, where every other method reads each
  pixel alone).
- ``pcreg_half``: the same at half the frames' width and height (``pcreg run --scale 0.5``: the step on the
  frames resized, the labels brought back to the frames' size; :mod:`pcreg.pipeline.working`).
- ``pcreg_flow``: the same at half size with DIS's flow (medium preset) as its motion instead of the dense
  registration (``pcreg run --model flow --scale 0.5``): the trust rule, learning and the blur on the flow.
- ``dense_key`` / ``dense_previous``, ``similarity_key`` / ``similarity_previous``: the propagator with
  that registration model, each frame registered to the key frame, or to the previous frame with the
  motions composed back to the key frame (chained).
- ``flow_key`` / ``flow_previous``: the baselines, the same fusion with OpenCV's DIS optical flow
  (medium preset) as the motion, anchored or chained the same way; ``flowfast_key`` and
  ``flowultrafast_key``: anchored, with DIS's fast and ultrafast presets, what a user who weighs
  labels against time would pick (each method's time a frame is in ``ms_per_frame``).

``pcreg``'s confidence (:attr:`pcreg.pipeline.stream.StepReport.confidence`) is scored too, pooled over
the known pixels of every scored frame (:func:`calibration`): the expected calibration error over ten
bins of confidence, and the error of the most confident 80% of pixels against the error of all.

On DAVIS (``--data davis:PATH``) every method is also scored with the benchmark's J and F, beside the
published methods (:mod:`pcreg.experiments.stream_davis`).

Each clip is one unit of work (``--workers``, ``--scheduler``); finished units are kept in
``OUT/units/`` and skipped when the same command runs again.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..recording.interface import RecorderProtocol
from ..recording.null import NULL_RECORDER
from .results import Results
from .stream_davis import DavisScores, chain, check_davis_config, is_davis, summarise_davis

#: Methods scored per frame, in table order.
METHODS: tuple[str, ...] = ("plain", "unregistered", "pcreg", "pcreg_half", "pcreg_flow", "dense_key", "dense_previous",
                            "similarity_key", "similarity_previous", "flow_key", "flow_previous", "flowfast_key",
                            "flowultrafast_key")
#: The ``pcreg`` methods: what ``pcreg run`` does with these options.
PCREG_METHODS: dict[str, dict] = {"pcreg": {}, "pcreg_half": {"scale": 0.5}, "pcreg_flow": {"model": "flow", "scale": 0.5}}
#: The DIS baselines, and the preset of each (``flow``: medium).
BASELINES: tuple[str, ...] = ("flow_key", "flow_previous", "flowfast_key", "flowultrafast_key")
PRESET_OF: dict[str, str] = {"flow": "medium", "flowfast": "fast", "flowultrafast": "ultrafast"}


@dataclass(frozen=True)
class StreamConfig:
    """Everything that determines ``pcreg evaluate stream``'s numbers (written as config.json).

    data : a ``--data`` value. frames : first frames of each clip (default all; synthetic default 40).
    size, seed : synthetic data. key_every : a new key frame every N frames (None: the first only), each
        labelling the frames after it. keys : key frames anywhere, every other frame labelled from the
        key frames around it in both directions (:mod:`pcreg.experiments.stream_keys`; None: as
        ``key_every``).
    backends : the ICP backend (one). methods : which of :data:`METHODS` to run.
    """

    data: str = "synthetic"
    frames: int | None = None
    size: tuple[int, int] | None = None
    seed: int = 0
    key_every: int | None = None
    keys: str | None = None
    backends: tuple[str, ...] = ("reference",)
    methods: tuple[str, ...] = METHODS


def _propagator(method: str, classifier, backend: str):
    """``pcreg``: the propagator as ``pcreg run`` makes it; the other models and anchors as ablations of
    the motion alone: the prior at the one weight, by the field's confidence (no trust rule, no learning)."""
    from ..pipeline.stream import Propagator

    if method in PCREG_METHODS:
        return Propagator(classifier, backend=backend, **PCREG_METHODS[method])
    model, anchor = method.split("_")
    return Propagator(classifier, model=model, anchor=anchor, backend=backend, trust=None, learning=None)


#: Levels of the confidence histograms (:func:`calibration_counts`): the 8-bit steps of a confidence PNG.
CONFIDENCE_LEVELS = 256


def calibration_counts(confidence: np.ndarray, labels: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(2, 256) int64: over the known pixels, how many labels were right (row 0) and wrong (row 1) at
    each 8-bit level of their confidence (``round(255 * confidence)``)."""
    known = truth < 2
    level = np.rint(np.asarray(confidence, np.float32)[known] * (CONFIDENCE_LEVELS - 1)).astype(np.intp)
    wrong = (labels[known] == 1) != (truth[known] == 1)
    return np.stack([np.bincount(level[~wrong], minlength=CONFIDENCE_LEVELS),
                     np.bincount(level[wrong], minlength=CONFIDENCE_LEVELS)]).astype(np.int64)


def calibration(counts) -> dict:
    """From :func:`calibration_counts` (summed over frames): the expected calibration error over 10 equal
    bins of confidence (``ece``), the error % of all known pixels (``error``) and of the most confident
    80% of them (``error_top80``, the share at the cut-off level taken in proportion), their ratio, and
    the reliability curve (per bin: mean confidence, accuracy, share of pixels)."""
    c = np.asarray(counts, dtype=np.float64)
    right, wrong = c[0], c[1]
    n = right + wrong
    total = n.sum()
    if total == 0:
        return {"pixels": 0}
    conf = np.arange(CONFIDENCE_LEVELS) / (CONFIDENCE_LEVELS - 1)
    bins = np.minimum((conf * 10).astype(int), 9)
    ece, curve = 0.0, []
    for b in range(10):
        m = bins == b
        nb = n[m].sum()
        if nb == 0:
            continue
        mean_conf, acc = float((n[m] * conf[m]).sum() / nb), float(right[m].sum() / nb)
        ece += nb / total * abs(acc - mean_conf)
        curve.append({"bin": b, "confidence": mean_conf, "accuracy": acc, "share": float(nb / total)})
    keep, kept_wrong = 0.8 * total, 0.0
    for level in range(CONFIDENCE_LEVELS - 1, -1, -1):  # most confident first
        if n[level] == 0:
            continue
        take = min(n[level], keep)
        kept_wrong += wrong[level] * take / n[level]
        keep -= take
        if keep <= 0:
            break
    error, top = 100.0 * wrong.sum() / total, 100.0 * kept_wrong / (0.8 * total)
    return {"pixels": int(total), "ece": float(ece), "error": float(error), "error_top80": float(top),
            "top80_ratio": float(top / error) if error else float("nan"), "curve": curve}


class _KeyPrior:
    """What the baselines share: the key frame's prior, fused with each frame's naive Bayes log-odds."""

    def __init__(self, classifier, *, weight: float) -> None:
        from ..classification.fusion import FusionConfig
        from ..pipeline.prior import class_prior

        self.classifier, self.weight, self.fusion = classifier, weight, FusionConfig()
        self._pi = class_prior(classifier)

    def reset(self, image: np.ndarray, labels: np.ndarray) -> None:
        from ..classification.fusion import label_prior, prior_log_odds

        self._prior = label_prior(labels, pi=self._pi, fusion=self.fusion)
        self._key_log_odds = prior_log_odds(self._prior, pi=self._pi)

    def fused(self, image: np.ndarray, motion) -> np.ndarray:
        """The frame's fused log-odds with the key frame's prior carried by ``motion`` (None: not moved)."""
        from ..classification.fusion import fuse
        from ..pipeline.pair import log_odds
        from ..pipeline.prior import warped_prior_log_odds

        d = log_odds(self.classifier, image)
        if motion is None:
            l_prior = self._key_log_odds
        else:
            l_prior = warped_prior_log_odds(self._prior, motion, shape=d.shape, pi=self._pi)
        return fuse(d, l_prior, weight=self.weight)

    def _labels(self, image: np.ndarray, motion) -> np.ndarray:
        """The frame's labels, each pixel read alone (:meth:`fused`)."""
        from ..classification.fusion import labels_from_log_odds

        return labels_from_log_odds(self.fused(image, motion))


class _Flow(_KeyPrior):
    """The DIS baseline with a propagator's interface: the key frame's prior warped by the flow."""

    def __init__(self, classifier, anchor: str, preset: str = "medium") -> None:
        from ..pipeline.stream import STREAM_WEIGHT

        super().__init__(classifier, weight=STREAM_WEIGHT)
        self.anchor, self.preset = anchor, preset

    def reset(self, image: np.ndarray, labels: np.ndarray) -> None:
        super().reset(image, labels)
        self._key, self._prev, self._motion = image, image, None

    def step(self, image: np.ndarray) -> np.ndarray:
        from ..pipeline.estimators import FlowEstimator

        motion = FlowEstimator(self.preset).estimate(self._key if self.anchor == "key" else self._prev, image).motion
        if self.anchor == "previous" and self._motion is not None:
            motion = self._motion.after(motion, image.shape[:2])
        self._prev, self._motion = image, motion
        return self._labels(image, motion)


class _Fixed(_KeyPrior):
    """``plain`` (weight 0) and ``unregistered`` (the key frame's prior, no motion)."""

    def step(self, image: np.ndarray) -> np.ndarray:
        return self._labels(image, None)


def make_method(method: str, classifier, backend: str):
    """A fresh labeller of ``method`` (:data:`METHODS`) with ``reset(image, labels)`` and ``step(image)``."""
    from ..pipeline.stream import STREAM_WEIGHT

    if method == "plain":
        return _Fixed(classifier, weight=0.0)
    if method == "unregistered":
        return _Fixed(classifier, weight=STREAM_WEIGHT)
    if method in BASELINES:
        kind, anchor = method.split("_")
        return _Flow(classifier, anchor, PRESET_OF[kind])
    return _propagator(method, classifier, backend)


def key_frames(n: int, key_every: int | None) -> list[int]:
    """Indices of the key frames of a clip of ``n`` frames."""
    return list(range(0, n, key_every)) if key_every else [0]


def check_clip(name: str, frames) -> None:
    """Refuse a clip the protocol cannot score, with one line: fewer than two frames, a frame without
    labels, labels of another size than their image, or a key frame with no known label."""
    from ..errors import DatasetError

    if len(frames) < 2:
        raise DatasetError(f"clip {name} has {len(frames)} frame(s); a stream needs a key frame and one more")
    for f in frames:
        if f.labels is None:
            raise DatasetError(f"clip {name}: frame {f.name} has no labels; the stream evaluation scores every frame")
        if f.labels.shape != f.image.shape[:2]:
            raise DatasetError(f"clip {name}: the labels of frame {f.name} are {f.labels.shape[1]}x"
                               f"{f.labels.shape[0]}, its image {f.image.shape[1]}x{f.image.shape[0]}")
        if f.image.shape != frames[0].image.shape:
            raise DatasetError(f"clip {name}: frame {f.name} is {f.image.shape[1]}x{f.image.shape[0]}, the clip's "
                               f"first frame {frames[0].image.shape[1]}x{frames[0].image.shape[0]}")
    if not (frames[0].labels < 2).any():
        raise DatasetError(f"clip {name}: the key frame {frames[0].name} has no known label (all unknown)")


def run_clip(frames, *, methods=METHODS, key_every: int | None = None, backend: str = "reference",
             on_frame=None) -> dict:
    """Every method on one clip: ``{"frames": [{index, name, key, since_key, errors}], "means", "seconds"}``.
    ``on_frame(index, frame, predictions)`` is called after every scored frame (a recording hook)."""
    from ..classification.bayes import fit_classifier
    from ..classification.metrics import error_rate

    keys = set(key_frames(len(frames), key_every))
    seconds = dict.fromkeys(methods, 0.0)
    counts = np.zeros((2, CONFIDENCE_LEVELS), np.int64)
    rows, labellers, key = [], {}, 0
    for t, f in enumerate(frames):
        if t in keys:
            if not (f.labels < 2).any():  # a later key frame with nothing known keeps the current one
                keys.discard(t)
            else:
                key = t
                clf = fit_classifier([f])
                labellers = {m: make_method(m, clf, backend) for m in methods}
                for lab in labellers.values():
                    lab.reset(f.image, f.labels)
                continue
        preds, errors = {}, {}
        for m, lab in labellers.items():
            t0 = time.perf_counter()
            preds[m] = lab.step(f.image)
            seconds[m] += time.perf_counter() - t0
            errors[m] = error_rate(preds[m], f.labels)
        confidence = getattr(getattr(labellers.get("pcreg"), "last", None), "confidence", None)
        if confidence is not None:
            counts += calibration_counts(confidence, preds["pcreg"], f.labels)
        rows.append({"index": t, "name": f.name, "key": key, "since_key": t - key, "errors": errors})
        if on_frame is not None:
            on_frame(t, f, preds)
    means = {m: float(np.nanmean([r["errors"][m] for r in rows])) if rows else float("nan") for m in methods}
    per_frame_ms = {m: 1000.0 * s / max(1, len(rows)) for m, s in seconds.items()}
    return {"frames": rows, "means": means, "ms_per_frame": per_frame_ms, "key_frames": sorted(keys),
            "calibration": counts.tolist()}


# ---------------------------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------------------------

def run_unit(unit, *, recorder=NULL_RECORDER, frame_counter: list[int] | None = None) -> dict:
    """One clip: a pure function of ``unit`` (data from the per-process cache). With a recorder, each
    scored frame is logged at the next index of the ``frame`` timeline (``frame_counter[0]``), and the
    result's ``recording_frames`` maps each frame's index in the clip to that index."""
    from .units import load_cached

    cfg = unit.config
    t0 = time.perf_counter()
    frames = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset]
    recorded: dict[str, int] = {}
    hook = _recording_hook(recorder, unit.dataset, frame_counter if frame_counter is not None else [0], recorded)
    davis = None
    if is_davis(cfg.data):  # the benchmark's J and F, frame by frame (:mod:`.stream_davis`)
        davis = DavisScores(len(frames))
        hook = chain(hook, davis.on_frame)
    if cfg.keys is not None:
        from .stream_keys import key_indices, run_clip_keys

        keys = key_indices(cfg.keys, len(frames), frames, backend=unit.backend)
        out = run_clip_keys(frames, keys, methods=cfg.methods, backend=unit.backend)
    else:
        out = run_clip(frames, methods=cfg.methods, key_every=cfg.key_every, backend=unit.backend, on_frame=hook)
    out.update(dataset=unit.dataset, backend=unit.backend, n_frames=len(frames), seconds=time.perf_counter() - t0,
               width=frames[0].shape[1], height=frames[0].shape[0])
    if recorded:
        out["recording_frames"] = recorded
    if davis is not None:
        out["davis"] = davis.result()
    return out


def _recording_hook(rec: RecorderProtocol, clip: str, counter: list[int], recorded: dict[str, int]):
    if not rec.enabled:  # nothing to log: the clip runs without a per-frame hook
        return None
    rec.log_text(f"stream {clip}: start")

    def on_frame(t, frame, preds) -> None:
        rec.set_frame(counter[0])
        recorded[str(t)] = counter[0]
        counter[0] += 1
        rec.log_images(moving=frame.image)
        rec.log_labels(truth=frame.labels)
        for m in ("plain", "pcreg", "flow_key"):
            if m in preds:
                rec.log_labels(predicted=preds[m], prefix=m)

    return on_frame


def plan_units(config: StreamConfig, names: list[str]) -> list:
    from .units import Unit

    return [Unit(f"{d}_{b}", d, (("backend", b),), config) for d in names for b in config.backends]


def evaluate(config: StreamConfig, *, out=None, force: bool = False, executor=None, recorder=NULL_RECORDER,
             show_progress: bool | None = None) -> Results:
    """Run every clip (resuming from ``out/units`` when ``out`` is given); returns its :class:`Results`."""
    from .units import evaluate_units, load_cached

    check_davis_config(config)
    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed)
    for name, frames in datasets.items():
        check_clip(name, frames)
    return evaluate_units(plan_units(config, list(datasets)), run_unit, config, summarise=summarise, out=out,
                          force=force, executor=executor, recorder=recorder, desc="stream",
                          show_progress=show_progress)


def reduction(plain: float, value: float) -> float:
    """How much lower than ``plain`` ``value`` is, in percent of ``plain``."""
    return 100.0 * (plain - value) / plain if plain else float("nan")


def summarise(config: StreamConfig, unit_results: list[dict]) -> Results:
    """Per clip the mean error of every method and its reduction against plain; the
    average reduction over clips; the units (per-frame errors) themselves."""
    from .units import plain_config

    clips = {}
    for r in unit_results:
        means = r["means"]
        clips[r["dataset"]] = {"frames": r["n_frames"], "scored": len(r["frames"]), "width": r["width"],
                               "height": r["height"], "key_frames": r["key_frames"], "means": means,
                               "reduction": {m: reduction(means["plain"], v) for m, v in means.items()},
                               "ms_per_frame": r["ms_per_frame"],
                               "calibration": calibration(r.get("calibration", np.zeros((2, CONFIDENCE_LEVELS))))}
    pooled = sum((np.asarray(r.get("calibration", np.zeros((2, CONFIDENCE_LEVELS))), np.int64) for r in unit_results),
                 np.zeros((2, CONFIDENCE_LEVELS), np.int64))
    average = {m: float(np.mean([c["reduction"][m] for c in clips.values()])) for m in config.methods} if clips else {}
    sections = {"average_reduction": average, "calibration": calibration(pooled)}
    if is_davis(config.data):
        sections["davis"] = summarise_davis(config, unit_results)
    return Results("stream", plain_config(config), clips, unit_results, primary_backend=config.backends[0],
                   methods=tuple(config.methods), sections=sections)
