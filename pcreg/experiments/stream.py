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
- ``pcreg_object``: what ``pcreg run --follow object`` does: one moving object followed from the key frame's
  mask (:class:`pcreg.pipeline.follow.ObjectFollower`), for DAVIS; not meant for CamVid's scenes.

``pcreg``'s confidence (:attr:`pcreg.pipeline.stream.StepReport.confidence`; ``pcreg_object``'s when ``pcreg`` does
not run, :func:`~pcreg.experiments.stream_methods.confidence_method`) is scored too, pooled over
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
from typing import ClassVar

import numpy as np

from ..errors import InputError
from ..recording.interface import RecorderProtocol
from ..recording.null import NULL_RECORDER
from .results import Results
from .stream_davis import DavisScores, chain, check_davis_config, is_davis, summarise_davis
from .stream_methods import (BASELINES, CONFIDENCE_LEVELS, METHODS, OBJECT_METHOD, PCREG_METHODS, PRESET_OF,  # noqa: F401
                             Timed, calibration, calibration_counts, calibration_stamp,
                             confidence_method, make_method)

@dataclass(frozen=True)
class StreamConfig:
    """Everything that determines ``pcreg evaluate stream``'s numbers (written as config.json).

    data : a ``--data`` value. frames : first frames of each clip (default all; synthetic default 40).
    size, seed : synthetic data. key_every : a new key frame every N frames (None: the first only), each
        labelling the frames after it. keys : key frames anywhere, every other frame labelled from the
        key frames around it in both directions (:mod:`pcreg.experiments.stream_keys`; None: as
        ``key_every``).
    backends : the ICP backend (one). methods : which of :data:`METHODS` to run.
    classes : a class table with more than two classes (``camvid11``, a labelmap.txt, ...): every class is
        labelled and scored, beside the baselines in the same classes (:mod:`.stream_classes`; the key
        frames from ``keys``, the first by default); the label files are read through the table (CamVid's
        own ids with ``camvid11``). None: ground and obstacle.
    """

    report: ClassVar[str] = "stream"  #: its report's name (:data:`~.reports.files.REPORT_NAMES`)

    data: str = "synthetic"
    frames: int | None = None
    size: tuple[int, int] | None = None
    seed: int = 0
    key_every: int | None = None
    keys: str | None = None
    backends: tuple[str, ...] = ("reference",)
    methods: tuple[str, ...] = METHODS
    classes: str | None = None

    def to_dict(self) -> dict:
        """The fields, ``classes`` only when a table is chosen (the config of a two-class evaluation is
        what it was before tables); with a table from a file, ``class_table``, the table the file held
        (:func:`pcreg.classes.table_json`): the file edited since is another configuration, and the report
        names the classes that were scored."""
        import json
        from dataclasses import asdict

        from ..classes import TABLES, class_table, table_json

        doc = asdict(self)
        if self.classes is None:
            doc.pop("classes")
        elif self.classes not in TABLES:
            doc["class_table"] = json.loads(table_json(class_table(self.classes)))
        return doc


def key_frames(n: int, key_every: int | None) -> list[int]:
    """Indices of the key frames of a clip of ``n`` frames."""
    return list(range(0, n, key_every)) if key_every else [0]


def clip_where(name: str, config: StreamConfig) -> str:
    """A clip's name in a refusal, with the data it was read from, to find it: ``0001TP of camvid:PATH``."""
    return f"{name} of {config.data}"


def check_clip(name: str, frames, classes: str | None = None) -> None:
    """Refuse a clip the protocol cannot score, with one line: fewer than two frames, a frame without
    labels, labels of another size than their image, or a key frame with no known label or of one class alone."""
    from ..errors import DatasetError

    if len(frames) < 2:
        shown = f" ({frames[0].name})" if frames else ""
        raise DatasetError(f"clip {name} has {len(frames)} frame(s){shown}; a stream needs a key frame and one more")
    for f in frames:
        if f.labels is None:
            raise DatasetError(f"clip {name}: frame {f.name} has no labels; the stream evaluation scores every frame")
        if f.labels.shape != f.image.shape[:2]:
            raise DatasetError(f"clip {name}: the labels of frame {f.name} are {f.labels.shape[1]}x"
                               f"{f.labels.shape[0]}, its image {f.image.shape[1]}x{f.image.shape[0]}")
        if f.image.shape != frames[0].image.shape:
            raise DatasetError(f"clip {name}: frame {f.name} is {f.image.shape[1]}x{f.image.shape[0]}, the clip's "
                               f"first frame {frames[0].image.shape[1]}x{frames[0].image.shape[0]}")
    if classes is not None:
        from ..classes import class_table

        table = class_table(classes)
        for f in frames:
            table.check_labels(f.labels, f"clip {name}: frame {f.name}")
        return
    if not (frames[0].labels < 2).any():
        raise DatasetError(f"clip {name}: the key frame {frames[0].name} has no known label (all unknown)")
    held = np.unique(frames[0].labels[frames[0].labels < 2])
    if held.size == 1:  # naive Bayes is fitted on both (a DAVIS mask's are refused as it is read, naming its file)
        raise DatasetError(f"clip {name}: the labels of the key frame {frames[0].name} hold one class only, "
                           f"{('ground', 'obstacle')[int(held[0])]}; the classifier that starts the stream needs pixels "
                           "of both ground and obstacle")


def _can_start(labels: np.ndarray, methods) -> bool:
    """Whether every method of ``methods`` can start from a later key frame of ``labels``: naive Bayes is fitted
    on both classes (nothing known, or one class alone, as a DAVIS object occluded or out of view leaves them,
    cannot be), and the object follower needs an object it can follow (:func:`~pcreg.pipeline.follow.can_follow`).
    One that some method cannot keeps the current key frame, for every method, and is scored as any other frame."""
    if not ((labels == 0).any() and (labels == 1).any()):
        return False
    if OBJECT_METHOD in methods:
        from ..pipeline.follow import can_follow

        return can_follow(labels)
    return True


def run_clip(frames, *, methods=METHODS, key_every: int | None = None, backend: str = "reference",
             on_frame=None) -> dict:
    """Every method on one clip: ``{"frames": [{index, name, key, since_key, errors}], "means", "seconds"}``.
    Each stretch from a key frame to the next is one pass of each method
    (:func:`pcreg.pipeline.engine.propagate`), forwards from its key frame. ``on_frame(index, frame,
    predictions, key_frame)`` is called after every scored frame (a recording hook)."""
    from ..classification.bayes import fit_classifier
    from ..classification.metrics import error_rate
    from .._progress import unit_work
    from ..pipeline.engine import propagate, stretches

    n = len(frames)
    keys = [k for k in key_frames(n, key_every) if k == 0 or _can_start(frames[k].labels, methods)]
    unit_work(sum(len(s.frames) for s in stretches(keys, n)) * len(methods))
    seconds = dict.fromkeys(methods, 0.0)
    counts, calibrated = np.zeros((2, CONFIDENCE_LEVELS), np.int64), confidence_method(methods)
    rows = []
    for s in stretches(keys, n):
        key = s.first
        assert key is not None  # frame 0 is a key frame: each stretch runs forwards from its earlier one
        clf = fit_classifier([frames[key]])
        errors: dict[int, dict] = {t: {} for t in s.frames}
        preds: dict[int, dict] = {t: {} for t in s.frames}
        for m in methods:
            labeller = make_method(m, clf, backend)
            try:
                labeller.reset(frames[key].image, frames[key].labels)
            except InputError as exc:  # the method's own scale, which no option sets, too small for these frames
                from ..pipeline.stream import SCALE_ADVICE

                if not str(exc).endswith(SCALE_ADVICE):
                    raise
                raise InputError(f"--methods {m}: {str(exc).removesuffix(SCALE_ADVICE)}; give larger frames "
                                 f"or leave {m} out of --methods") from None
            timed = Timed(labeller)
            for t, _, labels in propagate(timed, ((t, frames[t].image) for t in s.frames)):
                errors[t][m] = error_rate(labels, frames[t].labels)
                if m == calibrated and labeller.last.confidence is not None:
                    counts += calibration_counts(labeller.last.confidence, labels, frames[t].labels)
                if on_frame is not None:
                    preds[t][m] = labels
            seconds[m] += timed.seconds
        for t in s.frames:
            rows.append({"index": t, "name": frames[t].name, "key": key, "since_key": t - key, "errors": errors[t]})
            if on_frame is not None:
                on_frame(t, frames[t], preds.pop(t), frames[key])
    scored = [r for r in rows if not all(np.isnan(e) for e in r["errors"].values())]  # truth all unknown: NaN each
    means = {m: float(np.nanmean([r["errors"][m] for r in scored])) if scored else float("nan") for m in methods}
    per_frame_ms = {m: 1000.0 * s / max(1, len(rows)) for m, s in seconds.items()}
    return {"frames": rows, "means": means, "ms_per_frame": per_frame_ms, "key_frames": keys,
            "calibration": counts.tolist(), "calibrated": calibration_stamp(methods)}


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
    frames = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed, classes=cfg.classes)[unit.dataset]
    recorded: dict[str, int] = {}
    hook = _recording_hook(recorder, unit.dataset, frame_counter if frame_counter is not None else [0], recorded,
                           classes=cfg.classes)
    davis = None
    if is_davis(cfg.data):  # the benchmark's J and F, frame by frame (:mod:`.stream_davis`)
        davis = DavisScores(len(frames))
        hook = chain(hook, davis.on_frame)
    try:  # what the keys or a method cannot take of the clip (a key object too small to follow), naming the clip
        out = _run_methods(cfg, frames, unit.backend, hook)
    except InputError as exc:
        clip = f"clip {clip_where(unit.dataset, cfg)}:"
        raise InputError(str(exc) if str(exc).startswith(clip) else f"{clip} {exc}") from None
    out["frames"], unscored = _scored_rows(out["frames"])
    if not out["frames"]:
        from ..errors import DatasetError

        raise DatasetError(f"clip {clip_where(unit.dataset, cfg)}: the truth of every frame that is not a key frame is all unknown "
                           f"({', '.join(unscored[:4])}): nothing to score")
    out["means"] = {m: float(np.mean([r["errors"][m] for r in out["frames"]])) for m in cfg.methods}
    if unscored:
        out["unscored"] = unscored
    out.update(dataset=unit.dataset, backend=unit.backend, n_frames=len(frames), seconds=time.perf_counter() - t0,
               width=frames[0].shape[1], height=frames[0].shape[0])
    if recorded:
        out["recording_frames"] = recorded
    if davis is not None:
        out["davis"] = davis.result()
    return out


def _run_methods(cfg: StreamConfig, frames, backend: str, hook) -> dict:
    """The clip's result by the protocol ``cfg`` chooses: many classes, key frames anywhere, or key frames
    every ``key_every`` frames."""
    if cfg.classes is not None:
        from ..classes import class_table
        from .stream_classes import run_clip_classes
        from .stream_keys import key_indices

        keys = key_indices(cfg.keys or "first", len(frames), frames, backend=backend, classes=cfg.classes)
        return run_clip_classes(frames, keys, class_table(cfg.classes), methods=cfg.methods, backend=backend,
                                on_frame=hook)
    if cfg.keys is not None:
        from .stream_keys import key_indices, run_clip_keys

        keys = key_indices(cfg.keys, len(frames), frames, backend=backend)
        return run_clip_keys(frames, keys, methods=cfg.methods, backend=backend, on_frame=hook)
    return run_clip(frames, methods=cfg.methods, key_every=cfg.key_every, backend=backend, on_frame=hook)


def _scored_rows(rows: list[dict]) -> tuple[list[dict], list[str]]:
    """The rows of frames with known truth, and the names of those whose truth is all unknown (void), whose
    error is NaN for every method: they are left out of the means, and the report names them."""
    void = [all(np.isnan(v) for v in r["errors"].values()) for r in rows]
    return [r for r, v in zip(rows, void) if not v], [r["name"] for r, v in zip(rows, void) if v]


def _recording_hook(rec: RecorderProtocol, clip: str, counter: list[int], recorded: dict[str, int], *,
                    classes: str | None = None):
    """``on_frame`` of a clip that logs each scored frame at the next ``counter``; ``classes``: the table the
    labels are ids of (None: ground, obstacle and unknown)."""
    if not rec.enabled:  # nothing to log: the clip runs without a per-frame hook
        return None
    rec.log_text(f"stream {clip}: start")
    if classes is not None:
        from ..classes import class_table

        rec.log_classes(class_table(classes))

    def on_frame(t, frame, preds, key_frame) -> None:
        rec.set_frame(counter[0])
        recorded[str(t)] = counter[0]
        counter[0] += 1
        rec.log_images(reference=key_frame.image, moving=frame.image)  # every method carries the key frame
        rec.log_labels(truth=frame.labels)
        for m in ("plain", "pcreg", "flow_key"):
            if m in preds:
                rec.log_labels(predicted=preds[m], prefix=m)

    return on_frame


def kept(unit, result: dict) -> bool:
    """Whether a clip's kept result holds what :func:`summarise` reads of it: every method's mean, the confidence
    counts (``calibration``; the follower's made with its coefficients of now, :func:`calibration_stamp`), on DAVIS
    its J and F (``davis``), with ``--classes`` its IoU; a clip kept without them is run again, not left out."""
    from .units import holds

    cfg = unit.config
    needs = ("frames", "means", "ms_per_frame", "key_frames", "n_frames", "width", "height", "calibration",
             *(("davis",) if is_davis(cfg.data) else ()), *(("miou", "iou") if cfg.classes is not None else ()))
    stamp = calibration_stamp(cfg.methods)  # the follower's counts, kept by a version whose confidence differs
    return (holds(result, unit, needs, same=("dataset", "backend")) and isinstance(result["means"], dict)
            and all(m in result["means"] for m in cfg.methods) and (stamp is None or result.get("calibrated") == stamp))


def plan_units(config: StreamConfig, names: list[str]) -> list:
    from .units import Unit

    return [Unit(f"{d}_{b}", d, (("backend", b),), config) for d in names for b in config.backends]


def evaluate(config: StreamConfig, *, out=None, force: bool = False, executor=None, recorder=NULL_RECORDER,
             show_progress: bool | None = None) -> Results:
    """Run every clip (resuming from ``out/units`` when ``out`` is given); returns its :class:`Results`."""
    from .._progress import Tally
    from .units import evaluate_units, load_cached, say_damage

    check_davis_config(config)
    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed, classes=config.classes)
    data_notes = say_damage(datasets)
    for name, frames in datasets.items():
        clip = clip_where(name, config)
        check_clip(clip, frames, config.classes)
        if OBJECT_METHOD in config.methods:  # refused before any clip runs, as the other key masks' faults are
            from ..errors import DatasetError
            from ..pipeline.follow import can_follow

            key = frames[0].labels
            if (key == 1).any() and not can_follow(key):
                raise DatasetError(f"clip {clip}: the object on the key frame {frames[0].name} ({int((key == 1).sum())} "
                                   f"px) covers no pixel at the size {OBJECT_METHOD} works at: too small to follow "
                                   f"(--methods without {OBJECT_METHOD} scores the others)")
        if config.keys is not None:  # each clip's key frames checked before any clip runs
            from .stream_keys import check_key_spec

            try:
                check_key_spec(config.keys, len(frames))
            except InputError as exc:
                raise InputError(f"clip {clip}: {exc}") from None
    return evaluate_units(plan_units(config, list(datasets)), run_unit, config, summarise=summarise, out=out,
                          force=force, executor=executor, recorder=recorder, show_progress=show_progress, kept=kept,
                          data_notes=data_notes,
                          desc=Tally("stream", "frame", lambda u: (len(datasets[u.dataset]) - 1) * len(config.methods)))


def reduction(plain: float, value: float) -> float:
    """How much lower than ``plain`` ``value`` is, in percent of ``plain``."""
    return 100.0 * (plain - value) / plain if plain else float("nan")


def _finite_mean(values: list[float]) -> float:
    """The mean of the finite ``values``; NaN when none is."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def summarise(config: StreamConfig, unit_results: list[dict]) -> Results:
    """Per clip the mean error of every method and its reduction against plain; the
    average reduction over the clips that have one (plain made some error); the units (per-frame errors)
    themselves."""
    from .units import plain_config

    clips = {}
    for r in unit_results:
        means = r["means"]
        clips[r["dataset"]] = {"frames": r["n_frames"], "scored": len(r["frames"]), "width": r["width"],
                               "height": r["height"], "key_frames": r["key_frames"], "means": means,
                               "reduction": {m: reduction(means["plain"], v) for m, v in means.items()},
                               "ms_per_frame": r["ms_per_frame"],
                               "calibration": calibration(r.get("calibration", np.zeros((2, CONFIDENCE_LEVELS)))),
                               **({"unscored": r["unscored"]} if r.get("unscored") else {}),
                               **({"miou": r["miou"], "iou": r["iou"]} if "miou" in r else {}),
                               **({"classes_not_in_keys": r["classes_not_in_keys"]}
                                  if r.get("classes_not_in_keys") else {})}
    pooled = sum((np.asarray(r.get("calibration", np.zeros((2, CONFIDENCE_LEVELS))), np.int64) for r in unit_results),
                 np.zeros((2, CONFIDENCE_LEVELS), np.int64))
    # a clip on which plain makes no error has no reduction (NaN): the mean is over the clips that have one
    average = {m: _finite_mean([c["reduction"][m] for c in clips.values()]) for m in config.methods} if clips else {}
    sections = {"average_reduction": average, "calibration": calibration(pooled)}
    if is_davis(config.data):
        sections["davis"] = summarise_davis(config, unit_results)
    return Results("stream", plain_config(config), clips, unit_results, primary_backend=config.backends[0],
                   methods=tuple(config.methods), sections=sections)
