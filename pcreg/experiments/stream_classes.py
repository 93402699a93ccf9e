"""``pcreg evaluate stream --classes TABLE``: a clip labelled into every class of a table (CamVid's eleven),
from key frames, beside the baselines in the same classes.

Each frame that is not a key frame is scored: its pixel error (void truth left out), and over the clip
each class's IoU (a class counts where the clip's truth or labels have it) and their mean, mIoU.

The methods (:data:`CLASS_METHODS`), each fitted on, or carried from, the same key frames; a frame
between two key frames takes both, weighted by its distance in frames to each (the nearer more,
linearly), as the two-class baselines do (:mod:`pcreg.experiments.stream_keys`):

- ``plain``: naive Bayes over the table's classes, fitted on all the key frames, alone;
- ``unregistered``: the key frames' labels, unmoved (no classifier);
- ``flow_labels``: the key frames' labels carried by DIS optical flow (medium preset) from each key frame
  (no classifier);
- ``flow_key``: naive Bayes fused with the key frames' prior carried by DIS from each key frame, at the
  stream's weight (2, as the two-class baselines; a quarter of it, pcreg's share with many classes, made
  this baseline 3-15 points worse on the clips tried), read out through pcreg's blur
  (:data:`~pcreg.pipeline.trust.CLASS_TRUST`);
- ``pcreg``: :func:`~pcreg.pipeline.keyframes.label_clip` with the table.
"""

from __future__ import annotations

import time

import numpy as np

from ..classification.metrics import class_iou

__all__ = ["CLASS_METHODS", "run_clip_classes", "class_iou", "mean_iou"]

#: Methods of the many-class protocol, in table order.
CLASS_METHODS: tuple[str, ...] = ("plain", "unregistered", "flow_labels", "flow_key", "pcreg")


def confusion(labels: np.ndarray, truth: np.ndarray, unknown: int) -> np.ndarray:
    """(256, 256) int64 counts of (truth, label) over the pixels whose truth is not ``unknown``."""
    keep = truth != unknown
    idx = truth[keep].astype(np.int64) * 256 + labels[keep].astype(np.int64)
    return np.bincount(idx, minlength=256 * 256).reshape(256, 256)


def mean_iou(conf: np.ndarray) -> float:
    """The mean of :func:`class_iou` in percent."""
    iou = class_iou(conf)
    return 100.0 * float(np.mean(list(iou.values()))) if iou else float("nan")


def _around(t: int, a: int | None, b: int | None) -> list[tuple[int, float]]:
    if a is not None and b is not None:
        return [(a, (b - t) / (b - a)), (b, (t - a) / (b - a))]
    return [(k, 1.0) for k in (a, b) if k is not None]


class _Baseline:
    """A many-class baseline over one stretch (:func:`pcreg.pipeline.engine.propagate`)."""

    def __init__(self, method: str, classifier, frames, stretch, priors: dict, flow) -> None:
        from ..pipeline.multiclass import class_priors

        self.method, self.clf, self.frames, self.s, self.priors, self.flow = method, classifier, frames, stretch, priors, flow
        self.log_pi = np.log(class_priors(classifier)).astype(np.float32)
        self.t = stretch.start

    def step(self, image: np.ndarray) -> np.ndarray:
        from ..pipeline.multiclass import carried_log_probs, smoothed_scores
        from ..pipeline.readout import scaled
        from ..pipeline.stream import STREAM_WEIGHT
        from ..pipeline.trust import CLASS_TRUST

        t, s, classes = self.t, self.s, self.clf.classes_
        self.t += 1
        if self.method == "plain":
            return classes[np.argmax(self.clf.class_scores(image), axis=2)]
        labels_only = self.method in ("unregistered", "flow_labels")
        evidence = None
        for k, share in _around(t, s.first, s.last):
            part = self.priors[k]
            if self.method != "unregistered":  # 0 (the class prior alone) outside the key frame
                part = carried_log_probs(part, self.flow.estimate(self.frames[k].image, image).result.field)
            evidence = share * part if evidence is None else evidence + share * part
        assert evidence is not None
        if labels_only:  # the labels' own probabilities: the evidence over the class prior, times it
            return classes[np.argmax(evidence + self.log_pi, axis=2)]
        fused = self.clf.class_scores(image) + np.float32(STREAM_WEIGHT) * evidence
        return classes[np.argmax(smoothed_scores(fused, scaled(CLASS_TRUST.smooth, fused.shape[1])), axis=2)]


def run_clip_classes(frames, keys: list[int], table, *, methods=CLASS_METHODS, backend: str = "reference",
                     on_frame=None) -> dict:
    """Every method on one clip (``frames``: objects with ``image``, ``labels`` (ids of ``table``) and
    ``name``) with these key frames: per frame each method's error (%), per method the clip's confusion
    matrix, mIoU and ms a frame, and pcreg's calibration counts. ``on_frame(index, frame, predictions,
    key_frame)`` is called for every scored frame once every method has labelled the clip, in the clip's order
    (a recording hook)."""
    from ..classification.bayes import fit_classifier
    from ..pipeline.engine import propagate, stretches
    from ..pipeline.estimators import FlowEstimator
    from ..pipeline.keyframes import label_clip
    from ..pipeline.multiclass import class_prior_maps, class_priors, prior_log_probs
    from .._progress import unit_work
    from .stream_methods import CONFIDENCE_LEVELS, Timed, calibration_counts, counted, kernels_ready

    n = len(frames)
    unit_work((n - len(set(keys))) * len(methods))
    clf = fit_classifier([frames[k] for k in keys], classes=table)
    pi = class_priors(clf)
    priors = {k: prior_log_probs(class_prior_maps(frames[k].labels, clf.classes_, pi), pi) for k in keys}
    seconds = dict.fromkeys(methods, 0.0)
    conf_m = {m: np.zeros((256, 256), np.int64) for m in methods}
    errors: dict[int, dict] = {}
    preds: dict[int, dict] = {}  # each method's labels by frame, kept for on_frame only
    counts = np.zeros((2, CONFIDENCE_LEVELS), np.int64)
    unknown = table.unknown
    if "pcreg" in methods:
        kernels_ready()  # compiled before the clock starts, as a Timed step's
        t0 = time.perf_counter()
        ours = label_clip(lambda t: frames[t].image, n, {k: frames[k].labels for k in keys}, backend=backend,
                          classes=table, on_frame=counted(keys))
        seconds["pcreg"] = time.perf_counter() - t0
        for f in ours:
            if f.index in keys:
                continue
            truth = frames[f.index].labels
            errors.setdefault(f.index, {})["pcreg"] = _error(f.labels, truth, unknown)
            if on_frame is not None:
                preds.setdefault(f.index, {})["pcreg"] = f.labels
            conf_m["pcreg"] += confusion(f.labels, truth, unknown)
            assert f.confidence is not None
            counts += calibration_counts(f.confidence, f.labels, truth, unknown)
    flow = FlowEstimator("medium")
    for s in stretches(keys, n):
        for m in (m for m in methods if m != "pcreg"):
            timed = Timed(_Baseline(m, clf, frames, s, priors, flow))
            for t, _, labels in propagate(timed, ((t, frames[t].image) for t in s.frames)):
                truth = frames[t].labels
                errors.setdefault(t, {})[m] = _error(labels, truth, unknown)
                if on_frame is not None:
                    preds.setdefault(t, {})[m] = labels
                conf_m[m] += confusion(labels, truth, unknown)
            seconds[m] += timed.seconds
    rows = []
    for t in sorted(errors):
        key = min(keys, key=lambda k: (abs(t - k), k))
        rows.append({"index": t, "name": frames[t].name, "key": key, "since_key": abs(t - key), "errors": errors[t]})
        if on_frame is not None:
            on_frame(t, frames[t], preds.pop(t, {}), frames[key])
    return {"frames": rows, "key_frames": sorted(keys), "classes_not_in_keys": _not_in_keys(frames, keys, rows, unknown),
            "means": {m: float(np.mean([r["errors"][m] for r in rows])) if rows else float("nan") for m in methods},
            "miou": {m: mean_iou(conf_m[m]) for m in methods},
            "iou": {m: class_iou(conf_m[m]) for m in methods},
            "calibration": counts.tolist(),
            "ms_per_frame": {m: 1000.0 * sec / max(1, len(rows)) for m, sec in seconds.items()}}


def _not_in_keys(frames, keys: list[int], rows: list[dict], unknown: int) -> list[int]:
    """The ids of the classes that the scored frames' truth has and no key frame's labels show: no method
    can label them (each learns or carries its classes from the key frames), so their IoU is 0."""
    shown = set().union(*(np.unique(frames[k].labels).tolist() for k in keys))
    truth = set().union(*(np.unique(frames[r["index"]].labels).tolist() for r in rows))
    return sorted(int(c) for c in truth - shown - {unknown})


def _error(labels: np.ndarray, truth: np.ndarray, unknown: int) -> float:
    keep = truth != unknown
    return 100.0 * float(np.mean(labels[keep] != truth[keep])) if keep.any() else float("nan")

