"""Thesis Ch. 6-7: register frame i+k to frame i, classify before/after, and propagate labels.

For every dataset, increment k (default 1, 4, 7, 10) and ICP backend, the pairs (i, i+k) are run
through :func:`pcreg.pipeline.run_sequence` (4 pyramid levels, 14 ICP iterations per level) and every
method of :data:`pcreg.pipeline.METHODS` is scored per pair (error %, unknown truth left out).

Protocol: naive Bayes (RGB + HSV + row) is trained on each pair's reference frame (``--train
reference``, the thesis's way) or on the first K frames (``--train first:K``). The fusion weight is
chosen on the first C frames of each sequence only (C = the training frames for ``first:K``, else 10%
of the sequence, at least 2; ``--fusion-frames``), and only pairs whose moving frame comes after them
are scored, for every method alike.

Each (dataset, k, backend) is one unit of work (``--workers``); finished units are kept in
``OUT/units/`` and skipped when the same command is run again. Outputs: results.json, config.json,
sequence_<backend>.csv/.md, checks.md, sequence_<dataset>.png (per-pair error curves like the
thesis's Figures 6.1-6.9) and sequence_summary.png.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, ClassVar

from ..classification.features import DEFAULT_FEATURES
from .results import Results
from ..pipeline import PIPELINE_REGISTRATION
from ..registration.config import RegisterConfig
from ..recording.interface import RecorderProtocol
from ..recording.null import NULL_RECORDER


DEFAULT_INCREMENTS = (1, 4, 7, 10)
#: Label maps logged per pair with ``--record`` (all methods' error rates are logged).
RECORDED_PREDICTIONS = ("plain", "augmented", "augmented_temporal")


@dataclass(frozen=True)
class SequenceFusion:
    """How ``pcreg evaluate sequence`` fuses each pair's propagated prior (:attr:`SequenceConfig.fusion`).

    frames : C, the first frames of each sequence the fusion weight is chosen on (None: the default,
        :func:`pcreg.pipeline.resolve_fusion_frames`). weight : a fixed weight (None: chosen on the first
        C frames). eps, sigma : the prior's mixing and blur (:class:`pcreg.classification.fusion.FusionConfig`).
    """

    frames: int | None = None
    weight: float | None = None
    eps: float = 0.05
    sigma: float = 2.0

    def config(self):
        """The pipeline's :class:`~pcreg.classification.fusion.FusionConfig` (checked when made)."""
        from ..classification.fusion import FusionConfig

        return FusionConfig(weight=self.weight, eps=self.eps, sigma=self.sigma)


@dataclass(frozen=True)
class SequenceConfig:
    """Everything that determines ``pcreg evaluate sequence``'s numbers (written as config.json by
    :meth:`to_dict`).

    data : a ``--data`` value. increments : k values. backends : ICP backends, in order (the first is
    the one whose means are the top-level numbers of results.json). frames : frames per synthetic
    sequence (default 100) or first frames of real ones (default all). size : synthetic (width, height).
    seed : synthetic data. train : ``reference`` or ``first:K``. fusion : the frames the fusion weight
    is chosen on, a fixed weight, the prior's mixing and blur (:class:`SequenceFusion`). registration (its
    backend is set per unit from ``backends``), features: the pipeline (:class:`pcreg.pipeline.PipelineConfig`).
    """

    report: ClassVar[str] = "sequence"  #: its report's name (:data:`~.reports.files.REPORT_NAMES`)

    data: str = "synthetic"
    increments: tuple[int, ...] = DEFAULT_INCREMENTS
    backends: tuple[str, ...] = ("reference",)
    frames: int | None = None
    size: tuple[int, int] | None = None
    seed: int = 0
    train: str = "reference"
    fusion: SequenceFusion = SequenceFusion()
    registration: RegisterConfig = PIPELINE_REGISTRATION
    features: tuple[str, ...] = DEFAULT_FEATURES

    def pipeline(self, backend: str):
        from ..pipeline import PipelineConfig

        return PipelineConfig(registration=self.registration.replace(backend=backend), features=tuple(self.features),
                              fusion=self.fusion.config())

    def to_dict(self) -> dict[str, Any]:
        """config.json: the fields in order, ``fusion`` written flat in its place as ``fusion_frames``,
        ``fusion_weight``, ``eps`` and ``sigma`` (so earlier output folders resume)."""
        doc: dict[str, Any] = {}
        for name, value in asdict(self).items():
            if name == "fusion":
                doc.update(fusion_frames=value["frames"], fusion_weight=value["weight"], eps=value["eps"],
                           sigma=value["sigma"])
            else:
                doc[name] = value
        return doc


# ---------------------------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------------------------

def run_unit(unit, *, recorder=NULL_RECORDER, frame_counter: list[int] | None = None) -> dict:
    """One (dataset, k, backend): a pure function of ``unit`` (data from the per-process cache).
    With a recorder, every scored pair is logged (images, transform, warp, labels, error rates) at the
    next index of the recording's ``frame`` timeline (``frame_counter[0]``, advanced per pair), and the
    result's ``recording_frames`` maps each pair's moving frame to that index."""
    from ..errors import InputError
    from ..pipeline import run_sequence
    from .units import load_cached

    cfg = unit.config
    t0 = time.perf_counter()
    frames = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset]
    recorded: dict[str, int] = {}
    on_pair, icp = _recording_hooks(recorder, unit, frame_counter if frame_counter is not None else [0], recorded)
    try:
        res = run_sequence(frames, k=unit.k, config=cfg.pipeline(unit.backend), train=cfg.train,
                           fusion_frames=cfg.fusion.frames, on_pair=on_pair, icp_callback=icp)
        out = res.to_dict()
        out["error"] = None
    except InputError as exc:  # e.g. a training frame with one class only: the unit fails, the run goes on
        out = {"k": unit.k, "backend": unit.backend, "pairs": [], "means": {}, "failures": [], "notes": [str(exc)],
               "error": str(exc)}
    out.update(dataset=unit.dataset, frames=len(frames), seconds=time.perf_counter() - t0,
               width=frames[0].shape[1] if frames else None, height=frames[0].shape[0] if frames else None)
    if recorded:
        out["recording_frames"] = recorded
    return out


def _recording_hooks(rec: RecorderProtocol, unit, counter: list[int], recorded: dict[str, int]):
    if not rec.enabled:  # nothing to log: the pipeline keeps no arrays for it
        return None, None
    prefix = f"{unit.dataset}/k{unit.k}/{unit.backend}"
    rec.log_text(f"sequence {prefix}: start")

    def on_pair(result, frames, arrays) -> None:
        ref, mov = frames
        rec.set_frame(counter[0])
        recorded[str(result.moving)] = counter[0]
        counter[0] += 1
        rec.log_text(f"{prefix}: frame {result.moving} registered to frame {result.reference}")
        rec.log_images(reference=ref.image, moving=mov.image, warped=arrays.warped, valid_mask=arrays.valid)
        if result.registered:
            rec.log_transform(result.registration["matrix"])
            if arrays.motion is not None and arrays.motion.is_field:  # a dense registration's field
                rec.log_dense(arrays.motion.field, matrix=result.registration["matrix"], confidence=arrays.motion.confidence,
                              warped_prior=arrays.warped_prior)
        else:
            rec.log_failure(f"{prefix}: frames {result.reference} -> {result.moving}: {result.reason}")
        rec.log_labels(truth=mov.labels)
        for method in RECORDED_PREDICTIONS:
            if method in arrays.predicted:
                rec.log_labels(predicted=arrays.predicted[method], prefix=method)
        rec.log_errors({f"{prefix}/{m}": v for m, v in result.errors.items()})

    # A sequence recording shows the ICP of every pair thinly (its frames, labels and errors are the point):
    # its iterations are still 10% (synthetic) to 39% (CamVid, about 40 iterations a pair) of a
    # recording's size (docs/benchmarks.md#recording).
    return on_pair, rec.icp_callback(unit.backend, max_points=64, max_correspondences=24)


# ---------------------------------------------------------------------------------------------
# the evaluation
# ---------------------------------------------------------------------------------------------

def _scored_pairs(pairs: list, methods) -> dict:
    """{method: how many of ``pairs`` (their dicts) have a finite error}: the pairs its mean is taken over (a pair
    whose labels are all unknown, or whose valid region is empty for the cropped score, has none)."""
    return {m: sum(1 for p in pairs if _finite(p["errors"].get(m))) for m in methods}


def _finite(v) -> bool:
    import math

    return v is not None and math.isfinite(float(v))


def plan_units(config: SequenceConfig, names: list[str]) -> list:
    from .units import Unit

    return [Unit(f"{d}/k{k}_{b}", d, (("k", k), ("backend", b)), config)
            for d in names for k in config.increments for b in config.backends]


def kept(unit, result: dict) -> bool:
    """Whether a kept unit holds what :func:`summarise` reads of it, every method's mean among it unless the unit
    failed (else it is run again: a method an earlier pcreg did not have would read nan)."""
    from ..pipeline import METHODS
    from .units import holds

    return (holds(result, unit, ("pairs", "means", "failures", "notes", "frames", "width", "height"),
                  same=("dataset", "k", "backend")) and isinstance(result["means"], dict)
            and (bool(result.get("error")) or all(m in result["means"] for m in METHODS)))


def evaluate(config: SequenceConfig, *, out: str | Path | None = None, force: bool = False, executor=None,
             recorder=NULL_RECORDER, show_progress: bool | None = None) -> Results:
    """Run every unit (resuming from ``out/units`` when ``out`` is given); returns its :class:`Results`."""
    from ..errors import DatasetError, InputError
    from .units import discard_units, evaluate_units, load_cached, say_damage

    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed)
    data_notes = say_damage(datasets)
    for name, frames in datasets.items():
        if frames and any(f.labels is None for f in frames):
            raise DatasetError(f"dataset {name} has unlabelled frames; the sequence evaluation scores every frame")
    plan = plan_units(config, list(datasets))
    results = evaluate_units(plan, run_unit, config, summarise=summarise, out=out, force=force, executor=executor,
                             recorder=recorder, desc="sequence", show_progress=show_progress, kept=kept,
                             data_notes=data_notes)
    units = results.units
    if units and not any(u["pairs"] for u in units):  # a report without a number is the input's fault
        if out is not None:  # nothing kept: the corrected command resumes nothing and is not refused
            discard_units(out, plan)
        u = next((u for u in units if u["notes"]), units[0])
        why = u["notes"][-1] if u["notes"] else "no pairs"  # why no pair was scored comes last (before: the weights')
        raise InputError(f"no pair was scored ({u['dataset']} k={u['k']}: {why})")
    if units and not any(_scored_pairs(u["pairs"], ("plain",))["plain"] for u in units):  # a table of NaN
        if out is not None:  # (the thesis's columns score unknown truth too: they alone are no comparison)
            discard_units(out, plan)
        u = next(u for u in units if u["pairs"])
        moving = [str(p["moving"]) for p in u["pairs"]]
        raise DatasetError(f"no pair was scored ({u['dataset']} k={u['k']}: the truth of every moving frame is all "
                           f"unknown, moving frame(s) {', '.join(moving[:4])}{', ...' if len(moving) > 4 else ''}): nothing to score")
    return results


def summarise(config: SequenceConfig, unit_results: list[dict]) -> Results:
    """results.json: top-level means for the first backend, per-backend means, pair counts, units."""
    from ..pipeline import METHODS
    from .units import plain_config

    primary = config.backends[0]
    out_datasets: dict = {}
    by_backend: dict = {b: {"datasets": {}} for b in config.backends}
    notes = []
    for r in unit_results:
        name, k, b = r["dataset"], str(r["k"]), r["backend"]
        means = {m: r["means"].get(m, float("nan")) for m in METHODS}
        d = out_datasets.setdefault(name, {"frames": r["frames"], "width": r["width"], "height": r["height"],
                                           "increments": {}, "pairs": {}})
        stats = {"pairs": len(r["pairs"]), "failed_pairs": len(r["failures"]),
                 "scored_pairs": _scored_pairs(r["pairs"], METHODS),
                 "weight": r.get("weight", {}).get("weight") if r.get("weight") else None,
                 "temporal_weight": (r.get("temporal_weight") or {}).get("weight"),
                 "fusion_frames": r.get("fusion_frames"), "notes": r["notes"]}
        by_backend[b]["datasets"].setdefault(name, {"increments": {}, "pairs": {}})
        by_backend[b]["datasets"][name]["increments"][k] = means
        by_backend[b]["datasets"][name]["pairs"][k] = stats
        if b == primary:
            d["increments"][k] = means
            d["pairs"][k] = stats
        notes += [f"{name} k={k} {b}: {n}" for n in r["notes"]]
    return Results("sequence", plain_config(config), out_datasets, unit_results, primary_backend=primary,
                   methods=tuple(METHODS), backends=by_backend, notes=tuple(notes))

