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
sequence_<backend>.csv/.md, floors.md, sequence_<dataset>.png (per-pair error curves like the
thesis's Figures 6.1-6.9) and sequence_summary.png.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path


DEFAULT_INCREMENTS = (1, 4, 7, 10)
#: Label maps logged per pair with ``--record`` (all methods' error rates are logged).
RECORDED_PREDICTIONS = ("plain", "augmented", "augmented_temporal")
TABLE_METHODS = ("plain", "thesis_before", "thesis_after", "thesis_after_masked", "thesis_after_cropped",
                 "augmented", "augmented_unregistered", "augmented_temporal", "propagated", "augmented_flow")


@dataclass(frozen=True)
class SequenceConfig:
    """Everything that determines ``pcreg evaluate sequence``'s numbers (written as config.json).

    data : a ``--data`` value. increments : k values. backends : ICP backends, in order (the first is
    the one whose means are the top-level numbers of results.json). frames : frames per synthetic
    sequence (default 100) or first frames of real ones (default all). size : synthetic (width, height).
    seed : synthetic data. train : ``reference`` or ``first:K``. fusion_frames : C (None: default).
    fusion_weight : fixed weight (None: chosen on the first C frames). eps, sigma : the prior's mixing
    and blur (:class:`pcreg.classification.fusion.FusionConfig`). levels, iterations, init, model, features: the
    pipeline (:class:`pcreg.pipeline.PipelineConfig`).
    """

    data: str = "synthetic"
    increments: tuple[int, ...] = DEFAULT_INCREMENTS
    backends: tuple[str, ...] = ("reference",)
    frames: int | None = None
    size: tuple[int, int] | None = None
    seed: int = 0
    train: str = "reference"
    fusion_frames: int | None = None
    fusion_weight: float | None = None
    eps: float = 0.05
    sigma: float = 2.0
    levels: int = 4
    iterations: int = 14
    init: str = "identity"
    model: str = "auto"
    features: tuple[str, ...] = ("rgb", "hsv", "row")

    def pipeline(self, backend: str):
        from ..classification.fusion import FusionConfig
        from ..pipeline import PipelineConfig

        return PipelineConfig(backend=backend, model=self.model, levels=self.levels, iterations=self.iterations,
                              init=self.init, features=tuple(self.features),
                              fusion=FusionConfig(weight=self.fusion_weight, eps=self.eps, sigma=self.sigma))


@dataclass(frozen=True)
class Unit:
    """One unit of work: one dataset at one increment with one backend."""

    dataset: str
    k: int
    backend: str
    config: SequenceConfig = field(repr=False)

    @property
    def key(self) -> str:
        return f"{self.dataset}/k{self.k}_{self.backend}"


# ---------------------------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import _common as c

    c.add_data_arguments(parser)
    parser.add_argument("--increments", "-k", type=c.int_list, default=DEFAULT_INCREMENTS, metavar="K,K,...",
                        help="frame increments k (default 1,4,7,10)")
    parser.add_argument("--train", type=c.train, default="reference",
                        help="reference (train on each pair's reference frame, default) or first:K")
    parser.add_argument("--fusion-frames", type=int, default=None, metavar="C",
                        help="frames at the start of each sequence that choose the fusion weight and are not "
                             "scored (default: the training frames for first:K, else 10%% of the sequence, >= 2)")
    parser.add_argument("--fusion-weight", type=float, default=None, metavar="W",
                        help="fixed fusion weight instead of choosing it on the fusion frames")
    parser.add_argument("--init", choices=("identity", "auto"), default="identity",
                        help="registration start: identity (default) or auto (global rotation search)")
    parser.add_argument("--model", default="auto",
                        help="motion model: auto (similarity for both backends), rigid, similarity, affine, "
                             "projective, or dense (the global similarity refined by a dense field)")
    c.add_run_arguments(parser, out="out/sequence")


def config_from_args(args: argparse.Namespace) -> SequenceConfig:
    from ..errors import InputError
    from ..registration.transforms import MODELS
    from . import _common as c

    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    if args.fusion_frames is not None and args.fusion_frames < 0:
        raise InputError("--fusion-frames must be >= 0")
    if args.fusion_weight is not None and not args.fusion_weight >= 0:
        raise InputError("--fusion-weight must be >= 0")
    if args.levels < 1 or args.levels > 8 or args.iterations < 1:
        raise InputError("--levels must be in 1..8 and --iterations at least 1")
    if args.model not in ("auto", "dense") and args.model not in MODELS:
        raise InputError(f"--model must be auto, dense or one of {', '.join(MODELS)}")
    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    return SequenceConfig(data=args.data, increments=tuple(sorted(set(args.increments))),
                          backends=c.backends(args.backend), frames=args.frames, size=args.size, seed=args.seed,
                          train=args.train, fusion_frames=args.fusion_frames, fusion_weight=args.fusion_weight,
                          levels=args.levels, iterations=args.iterations, init=args.init, model=args.model)


def run(args: argparse.Namespace) -> int:
    from ._common import run_command

    return run_command(args, config_from_args(args), name="sequence", evaluate=evaluate, write_outputs=write_outputs)


# ---------------------------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------------------------

def run_unit(unit: Unit, *, recorder=None, frame_counter: list[int] | None = None) -> dict:
    """One (dataset, k, backend): a pure function of ``unit`` (data from the per-process cache).
    With a recorder, every scored pair is logged (images, transform, warp, labels, error rates) at the
    next index of the recording's ``frame`` timeline (``frame_counter[0]``, advanced per pair)."""
    from ..errors import InputError
    from ..pipeline import run_sequence
    from ._common import load_cached

    cfg = unit.config
    t0 = time.perf_counter()
    frames = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset]
    on_pair = icp = None
    if recorder is not None:
        on_pair, icp = _recording_hooks(recorder, unit, frame_counter if frame_counter is not None else [0])
    try:
        res = run_sequence(frames, k=unit.k, config=cfg.pipeline(unit.backend), train=cfg.train,
                           fusion_frames=cfg.fusion_frames, on_pair=on_pair, icp_callback=icp)
        out = res.to_dict()
        out["error"] = None
    except InputError as exc:  # e.g. a training frame with one class only: the unit fails, the run goes on
        out = {"k": unit.k, "backend": unit.backend, "pairs": [], "means": {}, "failures": [], "notes": [str(exc)],
               "error": str(exc)}
    out.update(dataset=unit.dataset, frames=len(frames), seconds=time.perf_counter() - t0,
               width=frames[0].shape[1] if frames else None, height=frames[0].shape[0] if frames else None)
    return out


def _recording_hooks(rec, unit: Unit, counter: list[int]):
    prefix = f"{unit.dataset}/k{unit.k}/{unit.backend}"
    rec.log_text(f"sequence {prefix}: start")

    def on_pair(result, frames, extras) -> None:
        ref, mov = frames
        rec.set_frame(counter[0])
        counter[0] += 1
        rec.log_text(f"{prefix}: frame {result.moving} registered to frame {result.reference}")
        rec.log_images(reference=ref.image, moving=mov.image, warped=extras["warped"], valid_mask=extras["valid"])
        if result.registered:
            rec.log_transform(result.registration["matrix"])
        else:
            rec.log_failure(f"{prefix}: frames {result.reference} -> {result.moving}: {result.reason}")
        rec.log_labels(truth=mov.labels)
        for method in RECORDED_PREDICTIONS:
            if method in extras["predicted"]:
                rec.log_labels(predicted=extras["predicted"][method], prefix=method)
        rec.log_errors({f"{prefix}/{m}": v / 100.0 for m, v in result.errors.items()})

    return on_pair, rec.icp_callback(unit.backend, max_points=200, max_correspondences=80)


# ---------------------------------------------------------------------------------------------
# the evaluation
# ---------------------------------------------------------------------------------------------

def plan_units(config: SequenceConfig, names: list[str]) -> list[Unit]:
    return [Unit(d, k, b, config) for d in names for k in config.increments for b in config.backends]


def evaluate(config: SequenceConfig, *, out: str | Path | None = None, force: bool = False, executor=None,
             recorder=None, show_progress: bool | None = None) -> dict:
    """Run every unit (resuming from ``out/units`` when ``out`` is given); returns what results.json holds."""
    from ..datasets import PRESETS
    from ..errors import DatasetError
    from ._common import UnitStore, load_cached, plain_config, run_resumable

    t0 = time.perf_counter()
    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed)
    for name, frames in datasets.items():
        if frames and any(f.labels is None for f in frames):
            raise DatasetError(f"dataset {name} has unlabelled frames; the sequence evaluation scores every frame")
    cfg_dict = plain_config(config)
    store = UnitStore(out, cfg_dict, force=force) if out is not None else None
    units = plan_units(config, list(datasets))
    done, resumed = run_resumable(units, run_unit, store=store, cfg_dict=cfg_dict, recorder=recorder,
                                  executor=executor, desc="sequence", show_progress=show_progress)
    results = summarise(config, [done[u.key] for u in units], datasets)
    for name in results["datasets"]:
        if name in PRESETS:
            results["datasets"][name]["mirrors"] = PRESETS[name].mirrors
    results["resumed_units"] = resumed
    results["seconds"] = time.perf_counter() - t0
    return results


def summarise(config: SequenceConfig, unit_results: list[dict], datasets: dict) -> dict:
    """results.json: top-level means for the first backend, per-backend means, pair counts, units."""
    from ..pipeline import METHODS
    from ._common import plain_config

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
    return {"config": plain_config(config), "primary_backend": primary, "methods": list(METHODS),
            "datasets": out_datasets, "backends": by_backend, "notes": notes, "units": unit_results}


# ---------------------------------------------------------------------------------------------
# tables, floors and figures
# ---------------------------------------------------------------------------------------------

def _label(name: str, info: dict) -> str:
    m = info.get("mirrors")
    return f"{name} ({m})" if m else name


def table(results: dict, backend: str) -> tuple[list, list]:
    """Header and rows: one row per dataset and k, error % per method, relative reduction of augmented."""
    header = ["dataset", "k", "pairs", "failed", "w", *TABLE_METHODS, "augmented vs plain"]
    rows = []
    for name, d in results["backends"][backend]["datasets"].items():
        info = results["datasets"].get(name, {})
        for k, means in d["increments"].items():
            st = d["pairs"][k]
            p, a = means.get("plain"), means.get("augmented")
            rel = f"{100.0 * (p - a) / p:.1f}% lower" if (p and a is not None and p == p and a == a) else "n/a"
            w = st.get("weight")
            rows.append([_label(name, info), int(k), st["pairs"], st["failed_pairs"],
                         "n/a" if w is None else f"{w:g}", *[means.get(m, float("nan")) for m in TABLE_METHODS], rel])
    return header, rows


def floors(results: dict) -> str:
    """The issue's floors for this run, checked honestly (Markdown)."""
    import numpy as np

    lines = ["### Floors\n"]
    for b, bd in results["backends"].items():
        lines.append(f"**backend {b}**\n")
        fails_aug, fails_reg, fails_mask, rel, reg_gain = [], [], [], [], []
        n_cells = n_reg = n_mask = 0
        for name, d in bd["datasets"].items():
            for k, m in d["increments"].items():
                if not d["pairs"][k]["pairs"]:
                    continue
                n_cells += 1
                if not m["augmented"] < m["plain"]:
                    fails_aug.append(f"{name} k={k} ({m['augmented']:.2f} vs {m['plain']:.2f})")
                rel.append(100.0 * (m["plain"] - m["augmented"]) / m["plain"] if m["plain"] else np.nan)
                if int(k) >= 4:
                    n_reg += 1
                    reg_gain.append(m["augmented_unregistered"] - m["augmented"])
                    if not m["augmented"] < m["augmented_unregistered"]:
                        fails_reg.append(f"{name} k={k} ({m['augmented']:.2f} vs {m['augmented_unregistered']:.2f})")
                if m["thesis_after"] > m["thesis_before"]:
                    n_mask += 1
                    if not m["thesis_after_masked"] < m["thesis_before"]:
                        fails_mask.append(f"{name} k={k} ({m['thesis_after_masked']:.2f} vs {m['thesis_before']:.2f})")
        ok = lambda fails: "met" if not fails else "NOT met: " + "; ".join(fails)  # noqa: E731
        lines.append(f"- augmented < plain on every sequence and increment ({n_cells} cells): {ok(fails_aug)}")
        if rel:
            lines.append(f"- mean relative reduction of augmented vs plain: {np.nanmean(rel):.1f}% "
                         f"(min {np.nanmin(rel):.1f}%, max {np.nanmax(rel):.1f}%)")
        lines.append(f"- augmented < augmented_unregistered at k >= 4 ({n_reg} cells): {ok(fails_reg)}")
        if reg_gain:
            lines.append(f"- mean gain of registration over the unregistered prior at k >= 4: "
                         f"{np.mean(reg_gain):.2f} percentage points")
        lines.append(f"- thesis_after_masked < thesis_before where thesis_after lost to thesis_before "
                     f"({n_mask} cells): {ok(fails_mask) if n_mask else 'no such cell'}")
        lines.append("")
    return "\n".join(lines) + "\n"


def _figures(results: dict) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from ._common import METHOD_STYLE

    primary = results["primary_backend"]
    units = [u for u in results["units"] if u["backend"] == primary and u["pairs"]]
    figs = {}
    curve_methods = ("plain", "thesis_before", "thesis_after", "thesis_after_masked", "augmented",
                     "augmented_unregistered", "augmented_temporal")
    for name in results["datasets"]:
        us = sorted((u for u in units if u["dataset"] == name), key=lambda u: u["k"])
        if not us:
            continue
        fig, axes = plt.subplots(1, len(us), figsize=(4.6 * len(us), 3.8), squeeze=False, sharey=True)
        for ax, u in zip(axes[0], us):
            x = [p["moving"] for p in u["pairs"]]
            for m in curve_methods:
                label, colour, ls = METHOD_STYLE[m]
                ax.plot(x, [p["errors"][m] for p in u["pairs"]], ls, color=colour, lw=1.6 if m == "augmented" else 1.1,
                        label=label)
            fail = [p["moving"] for p in u["pairs"] if not p["registered"]]
            for f in fail:
                ax.axvline(f, color="red", alpha=0.3, lw=0.8)
            ax.set_title(f"k = {u['k']}  (w = {u['weight']['weight']:g})", fontsize=10)
            ax.set_xlabel("moving frame i + k")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("error (%)")
        axes[0][0].set_ylim(bottom=0)
        info = results["datasets"][name]
        fig.suptitle(f"{_label(name, info)}: per-pair error, backend {primary}", fontsize=11)
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False, bbox_to_anchor=(0.5, -0.08))
        fig.tight_layout()
        figs[f"sequence_{name}"] = fig
    # summary: mean error per method, one group per dataset, at each k
    names = list(results["datasets"])
    ks = sorted({int(k) for d in results["datasets"].values() for k in d["increments"]})
    bar_methods = ("plain", "thesis_before", "thesis_after", "thesis_after_masked", "augmented_unregistered",
                   "augmented", "augmented_temporal")
    if names and ks:
        fig, axes = plt.subplots(1, len(ks), figsize=(max(5.0, 1.1 * len(names)) * len(ks) / 1.6, 4.2),
                                 squeeze=False, sharey=True)
        for ax, k in zip(axes[0], ks):
            x = np.arange(len(names))
            wbar = 0.8 / len(bar_methods)
            for j, m in enumerate(bar_methods):
                label, colour, _ = METHOD_STYLE[m]
                vals = [results["datasets"][n]["increments"].get(str(k), {}).get(m, np.nan) for n in names]
                ax.bar(x + (j - (len(bar_methods) - 1) / 2) * wbar, vals, wbar, color=colour, label=label)
            ax.set_xticks(x, names, rotation=30, fontsize=8)
            ax.set_title(f"k = {k}", fontsize=10)
            ax.grid(alpha=0.3, axis="y")
        axes[0][0].set_ylabel(f"mean error (%), backend {primary}")
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False, bbox_to_anchor=(0.5, -0.1))
        fig.tight_layout()
        figs["sequence_summary"] = fig
    return figs


def write_outputs(results: dict, out: str | Path) -> list[Path]:
    """Tables, floors, figures, config.json and (last) results.json, each written atomically."""
    import matplotlib.pyplot as plt

    from .._io import atomic_save_figure, atomic_write_csv, atomic_write_json, atomic_write_text, markdown_table
    from ._common import nan_to_none

    out = Path(out)
    written = []
    for b in results["backends"]:
        header, rows = table(results, b)
        written.append(atomic_write_csv(out / f"sequence_{b}.csv", header, rows))
        text = (f"### Sequence (thesis Ch. 6-7), backend {b}: mean error % over pairs (i, i+k)\n\n"
                + markdown_table(header, rows))
        written.append(atomic_write_text(out / f"sequence_{b}.md", text))
    written.append(atomic_write_text(out / "floors.md", floors(results)))
    for name, fig in _figures(results).items():
        written.append(atomic_save_figure(fig, out / f"{name}.png"))
        plt.close(fig)
    written.append(atomic_write_json(out / "config.json", results["config"]))
    written.append(atomic_write_json(out / "results.json", nan_to_none(results)))
    return written
