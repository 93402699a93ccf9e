"""The whole story on small built-in synthetic data (what ``make demo`` runs), in a few minutes.

1. Ch. 4 - naive Bayes alone (cases I-III, the thesis feature and RGB+HSV+row);
2. Ch. 5 - rotated frames classified before and after registering them back, both ICP backends;
3. the two ICP backends cross-checked on the same clouds;
4. Ch. 6-7 - pairs (i, i+k) registered, classified before/after, and labels propagated through the
   registration (the augmented methods), both backends, with a recording of every pair;
5. per-stage times of the pipeline.

Writes ``OUT/report.md`` (tables and figures), one folder per experiment and ``OUT/demo.rrd``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class DemoConfig:
    """The demo's data and sizes (written to OUT/config.json)."""

    presets: tuple[str, ...] = ("syn1a", "syn2b")
    frames: int = 16
    size: tuple[int, int] = (320, 240)
    increments: tuple[int, ...] = (1, 4, 7)
    angles: tuple[float, ...] = (0.0, 15.0, 30.0, 60.0, 90.0, 135.0, 180.0)
    seed: int = 0

    @property
    def data(self) -> str:
        return "synthetic:" + ",".join(self.presets)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..commands._common import add_record_arguments

    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument("--workers", type=int, default=2, help="processes for Ch. 4 and 5 (default 2)")
    parser.add_argument("--frames", type=int, default=16, help="frames per synthetic sequence (default 16)")
    parser.add_argument("--no-record", action="store_true", help="do not write OUT/demo.rrd")
    add_record_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from .._io import check_output
    from ..errors import InputError

    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    if args.frames < 8:
        raise InputError("--frames must be at least 8 (the demo's increments go up to 7)")
    out = Path(args.out)
    config = DemoConfig(frames=args.frames)
    check_output(out / "report.md", force=args.force)
    record = None if args.no_record else Path(args.record or out / "demo.rrd")
    if record is not None:
        check_output(record, force=args.force)
    t0 = time.perf_counter()
    report = run_demo(config, out=out, workers=args.workers, record=record, raw_images=args.record_raw)
    print(f"demo finished in {time.perf_counter() - t0:.0f} s: {report}")
    return 0


def _say(text: str) -> None:
    print(text, flush=True)


def run_demo(config: DemoConfig, *, out: str | Path, workers: int = 2, record: str | Path | None = None,
             raw_images: bool = False) -> Path:
    """Run every part and write ``out/report.md``; returns its path. Overwrites earlier demo output."""
    import numpy as np

    from .. import crosscheck
    from .._io import atomic_write_json, atomic_write_text, markdown_table
    from .._runner import make_executor
    from ..datasets import load_dataset
    from . import classification
    from . import rotation
    from . import sequence
    from ._common import plain_config

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    times: dict[str, float] = {}
    atomic_write_json(out / "config.json", plain_config(config))
    datasets = load_dataset(config.data, n_frames=config.frames, size=config.size, seed=config.seed)

    # 1. Ch. 4
    _say("1/5 naive Bayes alone (thesis Ch. 4)")
    t = time.perf_counter()
    k1 = tuple(sorted({max(1, config.frames // 4), config.frames // 2, 3 * config.frames // 4}))
    ccfg = classification.ClassificationConfig(data=config.data, frames=config.frames, size=config.size,
                                               seed=config.seed, case1_k=k1, case3_k=(2, 4), n_trials=30)
    with make_executor(workers) as ex:
        cres = classification.evaluate(ccfg, executor=ex, show_progress=False)
    classification.write_outputs(cres, out / "classification")
    times["Ch. 4 classification"] = time.perf_counter() - t

    # 2. Ch. 5
    _say("2/5 rotated frames, before and after registration (thesis Ch. 5), both backends")
    t = time.perf_counter()
    rcfg = rotation.RotationConfig(data=config.data, angles=config.angles, samples=1, backends=("reference", "open3d"),
                                   frames=config.frames, size=config.size, seed=config.seed)
    with make_executor(workers) as ex:
        rres = rotation.evaluate(rcfg, out=out / "rotation", force=True, executor=ex, show_progress=False)
    rotation.write_outputs(rres, out / "rotation")
    times["Ch. 5 rotation"] = time.perf_counter() - t

    # 3. cross-check of the backends
    _say("3/5 cross-check of the two ICP backends")
    t = time.perf_counter()
    first = next(iter(datasets.values()))
    cc = crosscheck(first[0].image, first[3].image).to_dict()
    atomic_write_json(out / "crosscheck.json", cc)
    times["cross-check"] = time.perf_counter() - t

    # 4. Ch. 6-7 with a recording
    _say("4/5 sequences: registration, before/after, label propagation (thesis Ch. 6-7), both backends")
    t = time.perf_counter()
    scfg = sequence.SequenceConfig(data=config.data, increments=config.increments, backends=("reference", "open3d"),
                                   frames=config.frames, size=config.size, seed=config.seed)
    if record is not None:
        from ..recording.recorder import Recorder

        with Recorder(record, recording_name="pcreg demo", kind="demo", raw_images=raw_images, force=True) as rec:
            sres = sequence.evaluate(scfg, out=out / "sequence", force=True, recorder=rec, show_progress=False)
    else:
        with make_executor(workers) as ex:
            sres = sequence.evaluate(scfg, out=out / "sequence", force=True, executor=ex, show_progress=False)
    sequence.write_outputs(sres, out / "sequence")
    times["Ch. 6-7 sequence" + (" (recorded)" if record is not None else "")] = time.perf_counter() - t

    # 5. the story figure and the report
    _say("5/5 report")
    name = next(iter(datasets))
    k_fig = config.increments[min(1, len(config.increments) - 1)]
    unit = next(u for u in sres["units"] if u["dataset"] == name and u["k"] == k_fig and u["backend"] == "reference")
    w_fig = unit["weight"]["weight"] if unit.get("weight") else 1.0
    _pair_figure(datasets[name], k=k_fig, weight=w_fig, out=out / "pair.png", title=name)
    stage_rows = []
    for b in scfg.backends:
        pairs = [p for u in sres["units"] if u["backend"] == b for p in u["pairs"]]
        med = {s: 1000.0 * float(np.median([p["times"][s] for p in pairs])) for s in ("register", "warp", "classify", "fuse")}
        stage_rows.append([b, len(pairs), *med.values(), sum(med.values())])
    text = _report(config, cres, rres, sres, cc, stage_rows, times, record, out)
    atomic_write_text(out / "report.md", text)
    return out / "report.md"


def _pair_figure(frames, *, k: int, weight: float, out: Path, title: str) -> None:
    """Reference, moving, warped, truth and the predictions of one pair (a figure to look at); the
    pixels that are not scored (unknown truth) are grey in the predictions too."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from .._io import atomic_save_figure
    from ..pipeline import PipelineConfig, fit_classifier, process_pair

    i = 0
    j = min(i + k, len(frames) - 1)
    clf = fit_classifier([frames[i]], features=PipelineConfig().features)
    res, ex = process_pair(frames[i], frames[j], clf, weight=weight, indices=(i, j), keep_arrays=True,
                           temporal_source=frames[i].labels)
    unknown = frames[j].labels == 2

    def shown(pred):
        return colours[np.where(unknown, 2, pred)]

    colours = np.array([[64, 160, 64], [200, 48, 48], [128, 128, 128]], dtype=np.uint8)
    panels = [
        (frames[i].image, f"reference frame {i}"),
        (frames[j].image, f"moving frame {j}"),
        (np.where(ex["valid"][..., None], ex["warped"], 0), "moving warped onto the reference"),
        (colours[frames[j].labels], f"truth of frame {j}"),
        (shown(ex["predicted"]["plain"]), f"naive Bayes: {res.errors['plain']:.1f}% error"),
        (shown(ex["predicted"]["augmented"]), f"augmented (w = {weight:g}): {res.errors['augmented']:.1f}% error"),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.4))
    for ax, (img, label) in zip(axes.flat, panels):
        ax.imshow(img)
        ax.set_title(label, fontsize=10)
        ax.axis("off")
    fig.suptitle(f"{title}: frame {j} registered to frame {i}; green ground, red obstacle, grey unknown (not scored)",
                 fontsize=11)
    fig.tight_layout()
    atomic_save_figure(fig, out)
    plt.close(fig)


_METHODS_TEXT = """Frame i + k is registered to frame i; naive Bayes is trained on frame i. Error rates in percent,
unknown truth left out; the fusion weight w is chosen on the first frames of each sequence, which are
not scored.

- `plain`: naive Bayes on frame i + k, against its labels.
- `thesis_before` / `thesis_after`: naive Bayes on frame i + k unregistered / warped onto frame i
  (black border included), against frame i's labels (the thesis's before and after).
- `thesis_after_masked` / `thesis_after_cropped`: the border classified from the unwarped frame / left out.
- `augmented`: naive Bayes fused with frame i's labels warped into frame i + k as a prior.
- `augmented_unregistered`: the same prior without the warp (what registration adds).
- `augmented_temporal`: labels used only at the start of each chain, then carried frame to frame.
- `propagated`: frame i's warped labels alone (naive Bayes where they say nothing).
"""


def _report(config, cres, rres, sres, cc, stage_rows, times, record, out: Path) -> str:
    from .._io import markdown_table
    from . import classification
    from . import rotation
    from . import sequence

    parts = ["# pcreg demo\n",
             f"Synthetic presets {', '.join(config.presets)} ({config.frames} frames of "
             f"{config.size[0]}x{config.size[1]}, seed {config.seed}). Every number below was computed by this run; "
             "the full-size evaluations are `pcreg evaluate classification|rotation|sequence`.\n"]
    parts.append("## 1. Naive Bayes alone (thesis Ch. 4)\n")
    for name, (header, rows) in classification.tables(cres).items():
        if name in ("case1", "case2"):
            parts.append(f"**{name}**\n\n" + markdown_table(header, rows))
    parts.append("![Case I](classification/case1.png)\n")
    parts.append("## 2. Rotated frames before and after registration (thesis Ch. 5)\n")
    header, rows = rotation.table(rres, "reference")
    parts.append("Backend reference:\n\n" + markdown_table(header, rows))
    header, rows = rotation.table(rres, "open3d")
    parts.append("\nBackend open3d:\n\n" + markdown_table(header, rows))
    parts.append("\n" + rotation.floors(rres))
    parts.append("![rotation](rotation/rotation.png)\n")
    parts.append("## 3. The two ICP backends on the same clouds\n")
    rows = [[b, cc[b]["fitness"], cc[b]["inlier_rmse"], cc[b]["iterations"], 1000.0 * cc[b]["seconds"]]
            for b in ("reference", "open3d")]
    parts.append(markdown_table(["backend", "fitness", "inlier RMSE px", "iterations", "ms"], rows, digits=4))
    parts.append(f"\nLargest corner disagreement {cc['max_corner_disagreement_px']:.4f} px, rotation "
                 f"{cc['rotation_disagreement_deg']:.4f} degrees (full report: crosscheck.json).\n")
    parts.append("## 4. Sequences: registration and label propagation (thesis Ch. 6-7)\n")
    parts.append("![pair](pair.png)\n")
    parts.append(_METHODS_TEXT)
    for b in sres["backends"]:
        header, rows = sequence.table(sres, b)
        parts.append(f"Backend {b}, mean error % over pairs (i, i+k):\n\n" + markdown_table(header, rows) + "\n")
    parts.append(sequence.floors(sres))
    for name in sres["datasets"]:
        parts.append(f"![{name}](sequence/sequence_{name}.png)\n")
    parts.append("![summary](sequence/sequence_summary.png)\n")
    parts.append("## 5. Pipeline stage times (median ms per pair in this run, this machine)\n")
    parts.append(markdown_table(["backend", "pairs", "register", "warp", "classify", "fuse", "total"], stage_rows, digits=1))
    parts.append("\n`tools/bench_pipeline.py` measures 640x480 frames.\n")
    parts.append("## Run\n")
    parts.append(markdown_table(["part", "seconds"], [[k, v] for k, v in times.items()], digits=1))
    if record is not None:
        parts.append(f"\nRecording: `{record}` (`pcreg view {record}`).\n")
    return "\n".join(parts)
