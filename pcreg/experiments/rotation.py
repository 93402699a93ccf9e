"""Thesis Ch. 5: classify rotated frames before and after registering them back.

For sampled frames of each dataset, naive Bayes (RGB + HSV + row) is trained on the original frame; the
frame is rotated about its centre by each angle (default 0, 5, ..., 180 degrees) onto a canvas large
enough to hold all of it (``--canvas loose``, as MATLAB's ``imrotate`` does by default; ``crop`` keeps
the original size and loses the corners), then

- ``before``: the rotated frame, centred on the original's grid without registration, is classified
  and scored against the original labels (the thesis's "before");
- ``after``: the rotated frame is registered back to the original (``init="auto"``: a global rotation
  search, then ICP; rigid model), warped onto the original's grid and classified, black border
  included, and scored against the original labels;
- ``after_masked``: as ``after``, with the pixels that the warped image does not cover (outside the
  rotated frame's content) classified from the unregistered frame;
- ``after_cropped``: as ``after``, scored only where the warped image has content.

Each (dataset, sampled frame, backend) is one unit of work (``--workers``); finished units are kept in
``OUT/units/`` and skipped when the same command is run again. Outputs: results.json, config.json,
rotation_<backend>.csv/.md, floors.md and rotation.png (curves like the thesis's Figures 5.1-5.6).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..registration.config import RegisterConfig


DEFAULT_ANGLES = tuple(float(a) for a in range(0, 181, 5))
KEYS = ("before", "after", "after_masked", "after_cropped")


@dataclass(frozen=True)
class RotationConfig:
    """Everything that determines ``pcreg evaluate rotation``'s numbers (written as config.json).

    angles : degrees. samples : frames per dataset, evenly spaced (first, ..., last).
    canvas : ``loose`` (holds the whole rotated frame) or ``crop`` (original size).
    backends, data, frames, size, seed : as in ``pcreg evaluate sequence``.
    levels, iterations, model, features : registration and classifier options.
    """

    data: str = "synthetic"
    angles: tuple[float, ...] = DEFAULT_ANGLES
    samples: int = 3
    canvas: str = "loose"
    backends: tuple[str, ...] = ("reference",)
    frames: int | None = None
    size: tuple[int, int] | None = None
    seed: int = 0
    registration: RegisterConfig = RegisterConfig()
    features: tuple[str, ...] = ("rgb", "hsv", "row")


@dataclass(frozen=True)
class Unit:
    dataset: str
    index: int
    backend: str
    config: RotationConfig = field(repr=False)

    @property
    def key(self) -> str:
        return f"{self.dataset}/frame{self.index}_{self.backend}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import _common as c

    c.add_data_arguments(parser)
    parser.add_argument("--angles", type=c.angle_list, default=DEFAULT_ANGLES, metavar="A,B,...|START:STOP:STEP",
                        help="rotation angles in degrees (default 0:180:5)")
    parser.add_argument("--samples", type=int, default=3, help="frames per dataset, evenly spaced (default 3)")
    parser.add_argument("--canvas", choices=("loose", "crop"), default="loose",
                        help="loose: the rotated frame is kept whole (default); crop: original size")
    c.add_run_arguments(parser, out="out/rotation")


def config_from_args(args: argparse.Namespace) -> RotationConfig:
    from ..errors import InputError
    from . import _common as c

    if args.samples < 1:
        raise InputError("--samples must be at least 1")
    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    if args.levels < 1 or args.levels > 8 or args.iterations < 1:
        raise InputError("--levels must be in 1..8 and --iterations at least 1")
    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    return RotationConfig(data=args.data, angles=tuple(args.angles), samples=args.samples, canvas=args.canvas,
                          backends=c.backends(args.backend), frames=args.frames, size=args.size, seed=args.seed,
                          registration=RegisterConfig(levels=args.levels, iterations=args.iterations))


def run(args: argparse.Namespace) -> int:
    from ._common import run_command

    return run_command(args, config_from_args(args), name="rotation", evaluate=evaluate, write_outputs=write_outputs)


# ---------------------------------------------------------------------------------------------
# one frame
# ---------------------------------------------------------------------------------------------

def rotate_frame(image, labels, angle: float, *, canvas: str = "loose"):
    """Rotate a frame about its centre.

    image : (H, W, 3) uint8; labels : (H, W) uint8. Returns ``(image_r, labels_r, content, T_rot)``:
    the rotated image and labels (unknown = 2 outside the frame) on the canvas, ``content`` (H', W')
    bool where the rotated frame has data, and ``T_rot`` (3, 3) original -> canvas pixel coordinates.
    """
    import math

    import numpy as np

    from .. import warp
    from ..registration.transforms import about_point, image_center, rigid2d

    h, w = image.shape[:2]
    if canvas == "loose":
        a = math.radians(angle)
        cw = int(math.ceil(abs(w * math.cos(a)) + abs(h * math.sin(a)) - 1e-6))
        ch = int(math.ceil(abs(w * math.sin(a)) + abs(h * math.cos(a)) - 1e-6))
        shape = (max(ch, 8), max(cw, 8))
    else:
        shape = (h, w)
    T_rot = about_point(rigid2d(angle), image_center((h, w)), image_center(shape))
    image_r, content = warp(image, T_rot, shape=shape)
    labels_r, _ = warp(labels, T_rot, shape=shape, interpolation="nearest", fill=2)
    return image_r, labels_r, content, T_rot


def run_unit(unit: Unit, *, recorder=None, frame_counter: list[int] | None = None) -> dict:
    """Every angle for one sampled frame with one backend: a pure function of ``unit``. With a
    recorder, each angle is logged at the next index of the ``frame`` timeline (``frame_counter[0]``)."""
    import numpy as np

    from .. import register
    from .. import warp
    from ..errors import RegistrationError
    from ..classification.metrics import error_rate
    from ..classification.bayes import fit_classifier
    from ..registration.transforms import about_point, image_center, max_corner_error
    from ._common import angle_key, load_cached

    cfg = unit.config
    t0 = time.perf_counter()
    frame = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset][unit.index]
    clf = fit_classifier([frame], features=cfg.features)
    shape = frame.shape
    out = {"dataset": unit.dataset, "index": unit.index, "name": frame.name, "backend": unit.backend, "angles": {}}
    counter = frame_counter if frame_counter is not None else [0]
    for angle in cfg.angles:
        image_r, labels_r, content, T_rot = rotate_frame(frame.image, frame.labels, angle, canvas=cfg.canvas)
        T_centre = about_point(np.eye(3), image_center(image_r.shape), image_center(shape))
        unreg, _ = warp(image_r, T_centre, shape=shape)
        pred_before = clf.predict(unreg)
        row = {"before": error_rate(pred_before, frame.labels)}
        t_reg = time.perf_counter()
        try:
            res = register(frame.image, image_r, **cfg.registration.replace(backend=unit.backend).kwargs(),
                           callback=None if recorder is None else recorder.icp_callback(unit.backend))
            T, reason = res.matrix, None
        except RegistrationError as exc:
            res, T, reason = None, None, str(exc)
        row["seconds_register"] = time.perf_counter() - t_reg
        if T is not None:
            warped, inside = warp(image_r, T, shape=shape)
            has, _ = warp(content.astype(np.uint8), T, shape=shape, interpolation="nearest")
            valid = inside & has.astype(bool)
            pred_after = clf.predict(warped)
            row["after"] = error_rate(pred_after, frame.labels)
            pred_masked = np.where(valid, pred_after, pred_before)
            row["after_masked"] = error_rate(pred_masked, frame.labels)
            row["after_cropped"] = error_rate(pred_after, frame.labels, mask=valid)
            row["corner_error"] = max_corner_error(T @ T_rot, np.eye(3), shape)
            row["valid_fraction"] = float(valid.mean())
            row["fitness"] = float(res.fitness)
        else:  # no transform: a system would go on with the unregistered frame
            warped, valid, pred_after, pred_masked = unreg, np.ones(shape, bool), pred_before, pred_before
            row.update(after=row["before"], after_masked=row["before"], after_cropped=row["before"],
                       corner_error=None, valid_fraction=0.0, fitness=0.0)
        row["registered"] = T is not None
        row["reason"] = reason
        out["angles"][angle_key(angle)] = row
        if recorder is not None:
            recorder.set_frame(counter[0])
            counter[0] += 1
            prefix = f"{unit.dataset}/frame{unit.index}/{unit.backend}"
            recorder.log_text(f"{prefix}: rotated by {angle:g} degrees")
            recorder.log_images(reference=frame.image, moving=image_r, warped=warped, valid_mask=valid)
            if T is not None:
                recorder.log_transform(T)
            else:
                recorder.log_failure(f"{prefix} at {angle:g} degrees: {reason}")
            recorder.log_labels(truth=frame.labels)
            recorder.log_labels(predicted=pred_after, prefix="after")
            recorder.log_labels(predicted=pred_masked, prefix="after_masked")
            recorder.log_labels(predicted=pred_before, prefix="before")
            recorder.log_errors({f"{prefix}/{k}": row[k] / 100.0 for k in KEYS})
    out["seconds"] = time.perf_counter() - t0
    return out


# ---------------------------------------------------------------------------------------------
# the evaluation
# ---------------------------------------------------------------------------------------------

def sample_indices(n: int, samples: int) -> list[int]:
    """``samples`` frame indices evenly spaced over 0..n-1 (fewer for a short sequence)."""
    import numpy as np

    if n <= 0:
        return []
    return sorted({int(round(v)) for v in np.linspace(0, n - 1, min(samples, n))})


def evaluate(config: RotationConfig, *, out: str | Path | None = None, force: bool = False, executor=None,
             recorder=None, show_progress: bool | None = None) -> dict:
    """Run every unit (resuming from ``out/units``); returns what results.json holds."""
    from ..datasets import PRESETS
    from ..errors import DatasetError
    from ._common import UnitStore, load_cached, plain_config, run_resumable

    t0 = time.perf_counter()
    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed)
    units = []
    for name, frames in datasets.items():
        for i in sample_indices(len(frames), config.samples):
            if frames[i].labels is None:
                raise DatasetError(f"dataset {name}: frame {frames[i].name} has no labels")
            for b in config.backends:
                units.append(Unit(name, i, b, config))
    cfg_dict = plain_config(config)
    store = UnitStore(out, cfg_dict, force=force) if out is not None else None
    done, resumed = run_resumable(units, run_unit, store=store, cfg_dict=cfg_dict, recorder=recorder,
                                  executor=executor, desc="rotation", show_progress=show_progress)
    results = summarise(config, [done[u.key] for u in units])
    for name in results["datasets"]:
        if name in PRESETS:
            results["datasets"][name]["mirrors"] = PRESETS[name].mirrors
    results["resumed_units"] = resumed
    results["seconds"] = time.perf_counter() - t0
    return results


def summarise(config: RotationConfig, unit_results: list[dict]) -> dict:
    """results.json: per dataset and angle the mean over sampled frames (first backend at top level)."""
    import numpy as np

    from ._common import angle_key, plain_config

    primary = config.backends[0]
    by_backend: dict = {b: {"datasets": {}} for b in config.backends}
    for b in config.backends:
        names = list(dict.fromkeys(u["dataset"] for u in unit_results))
        for name in names:
            us = [u for u in unit_results if u["dataset"] == name and u["backend"] == b]
            angles = {}
            for a in config.angles:
                key = angle_key(a)
                rows = [u["angles"][key] for u in us]
                cell = {k: float(np.mean([r[k] for r in rows])) for k in KEYS}
                ce = [r["corner_error"] for r in rows if r["corner_error"] is not None]
                cell.update(frames=len(rows), failed=sum(not r["registered"] for r in rows),
                            corner_error_median=float(np.median(ce)) if ce else None,
                            seconds_register_median=float(np.median([r["seconds_register"] for r in rows])))
                angles[key] = cell
            by_backend[b]["datasets"][name] = {"frames": [u["name"] for u in us], "angles": angles}
    return {"config": plain_config(config), "primary_backend": primary,
            "datasets": {n: dict(d) for n, d in by_backend[primary]["datasets"].items()},
            "backends": by_backend, "units": unit_results}


# ---------------------------------------------------------------------------------------------
# tables, floors and figures
# ---------------------------------------------------------------------------------------------

def table(results: dict, backend: str) -> tuple[list, list]:
    """One row per dataset and angle: before, after, after_masked, after_cropped, registration."""
    header = ["dataset", "angle", *KEYS, "failed", "corner error px (median)"]
    rows = []
    for name, d in results["backends"][backend]["datasets"].items():
        m = results["datasets"].get(name, {}).get("mirrors")
        label = f"{name} ({m})" if m else name
        for a, c in d["angles"].items():
            ce = c["corner_error_median"]
            rows.append([label, a, *[c[k] for k in KEYS], f"{c['failed']}/{c['frames']}",
                         "n/a" if ce is None else f"{ce:.2f}"])
    return header, rows


def floors(results: dict) -> str:
    """With registration, the error at 90 and 180 degrees within 2 points of the error at 0."""
    from ._common import angle_key

    lines = ["### Floors\n"]
    for b, bd in results["backends"].items():
        lines.append(f"**backend {b}**\n")
        for name, d in bd["datasets"].items():
            a0 = d["angles"].get(angle_key(0.0))
            if a0 is None:
                lines.append(f"- {name}: 0 degrees not in the angle set")
                continue
            parts = []
            for a in (90.0, 180.0):
                c = d["angles"].get(angle_key(a))
                if c is None:
                    continue
                for key in ("after", "after_masked"):
                    diff = c[key] - a0[key]
                    parts.append(f"{key} {a:g}: {c[key]:.2f} ({diff:+.2f}, {'met' if abs(diff) <= 2 else 'NOT met'})")
            lines.append(f"- {name}: 0 degrees {a0['after']:.2f}; " + "; ".join(parts))
        lines.append("")
    return "\n".join(lines) + "\n"


def _figure(results: dict):
    import math

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results["datasets"])
    if not names:
        return None
    cols = min(3, len(names))
    rows_n = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.8 * cols, 3.6 * rows_n), squeeze=False, sharey=True)
    styles = {"before": ("#d62728", ":"), "after": ("#ff7f0e", "-"), "after_masked": ("#1f77b4", "-"),
              "after_cropped": ("#8c564b", "--")}
    for ax, name in zip(axes.flat, names):
        for b, bd in results["backends"].items():
            d = bd["datasets"][name]
            xs = [float(a) for a in d["angles"]]
            for key in KEYS:
                if key == "before" and b != results["primary_backend"]:
                    continue
                colour, ls = styles[key]
                lab = key if key == "before" else f"{key} ({b})"
                ax.plot(xs, [d["angles"][a][key] for a in d["angles"]], ls if b == results["primary_backend"] else "-.",
                        color=colour, marker="o" if b == results["primary_backend"] else "x", ms=3, lw=1.2,
                        alpha=1.0 if b == results["primary_backend"] else 0.6, label=lab)
        m = results["datasets"][name].get("mirrors")
        ax.set_title(f"{name} ({m})" if m else name, fontsize=10)
        ax.set_xlabel("rotation (degrees)")
        ax.grid(alpha=0.3)
        ax.set_xticks(range(0, 181, 30))
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for r in range(rows_n):
        axes[r][0].set_ylabel("error (%)")
    axes[0][0].set_ylim(bottom=0)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(4, len(labels)), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, -0.06 if rows_n > 1 else -0.12))
    fig.suptitle("Rotated frames classified before and after registering them back", fontsize=11)
    fig.tight_layout()
    return fig


def write_outputs(results: dict, out: str | Path) -> list[Path]:
    import matplotlib.pyplot as plt

    from .._io import atomic_save_figure, atomic_write_csv, atomic_write_json, atomic_write_text, markdown_table
    from ._common import nan_to_none

    out = Path(out)
    written = []
    for b in results["backends"]:
        header, rows = table(results, b)
        written.append(atomic_write_csv(out / f"rotation_{b}.csv", header, rows))
        written.append(atomic_write_text(out / f"rotation_{b}.md",
                                         f"### Rotation (thesis Ch. 5), backend {b}: error % (mean over sampled frames)\n\n"
                                         + markdown_table(header, rows)))
    written.append(atomic_write_text(out / "floors.md", floors(results)))
    fig = _figure(results)
    if fig is not None:
        written.append(atomic_save_figure(fig, out / "rotation.png"))
        plt.close(fig)
    written.append(atomic_write_json(out / "config.json", results["config"]))
    written.append(atomic_write_json(out / "results.json", nan_to_none(results)))
    return written
