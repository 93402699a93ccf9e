"""What each working size costs and gives: pcreg's labels at several ``scale``s against DIS's three presets.

    python tools/sweep_scale.py --data camvid:../shared/data/camvid --out out/sweep_scale [--scales 1,0.75,0.5,0.375,0.25]
        [--flow-presets medium,fast,ultrafast] [--flow-scales 1,0.5,0.25] [--workers 2] [--frames N]

Each clip is labelled from its first frame, in one run, by the propagator as ``pcreg run --scale S`` makes it
for each ``S`` (the whole step on the frames resized, the labels and confidence brought back to the
frames' size; :mod:`pcreg.pipeline.working`), by the same with DIS's flow as its motion
(``pcreg run --model flow --preset P --scale S``: the trust rule, learning and the confidence on the flow)
for each preset and size, and by the DIS baselines of ``pcreg evaluate stream`` (the
key frame's prior along DIS's flow from the key frame, medium, fast and ultrafast presets; and the same
with their fused log-odds blurred as pcreg's labels read them, :func:`pcreg.pipeline.trust.smoothed`,
since the blur helps every method). Per clip: the
reduction of plain naive Bayes' error and each method's median ms a frame (two clips at a time, one
per core; classification and fusion included). The working size is the user's choice of time against
labels, not a constant fitted here: the table shows every clip, so that what a size costs on the worst
clip is seen beside the mean.

Writes sweep_scale.json, sweep_scale.md and sweep_scale.png into --out.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402  (puts the checkout on the path)

BASELINES = ("flow_key", "flowfast_key", "flowultrafast_key")


def clip(args: tuple) -> dict:
    """Mean error % and median ms a frame of each method on one clip."""
    frames, scales, flow_presets, flow_scales = args
    import pcreg
    from pcreg.classification.metrics import error_rate
    from pcreg.experiments.stream_methods import PRESET_OF, KeyPrior, make_method
    from pcreg.pipeline.estimators import FlowEstimator
    from pcreg.pipeline.stream import STREAM_WEIGHT
    from pcreg.pipeline.trust import STREAM_TRUST, smoothed

    key = frames[0]
    clf = pcreg.fit_classifier([key])
    methods = {f"scale {s:g}": pcreg.Propagator(clf, scale=s) for s in scales}
    methods.update({f"flow {p}, scale {s:g}": pcreg.Propagator(clf, model=f"flow:{p}", scale=s)
                    for p in flow_presets for s in flow_scales})
    methods["plain"] = make_method("plain", clf, "reference")
    flows = {m: KeyPrior(clf, weight=STREAM_WEIGHT) for m in BASELINES}  # the key frame's prior, as DIS's baselines fuse it
    for m in (*methods.values(), *flows.values()):
        m.reset(key.image, key.labels)
    names = [*methods, *flows, *(f"{m} blurred" for m in flows)]
    errors: dict = {m: [] for m in names}
    ms: dict = {m: [] for m in names}
    for f in frames[1:]:
        for name, m in methods.items():
            t0 = time.perf_counter()
            labels = m.step(f.image)
            ms[name].append(1e3 * (time.perf_counter() - t0))
            errors[name].append(error_rate(labels, f.labels))
        for name, flow in flows.items():  # as the evaluation's baseline, and its log-odds blurred as pcreg's are
            t0 = time.perf_counter()
            preset = PRESET_OF[name.split("_")[0]]
            fused = flow.fused(f.image, FlowEstimator(preset).estimate(key.image, f.image).motion)
            t1 = time.perf_counter()
            blurred = (smoothed(fused, STREAM_TRUST) > 0).astype(np.uint8)
            t2 = time.perf_counter()
            ms[name].append(1e3 * (t1 - t0))
            ms[f"{name} blurred"].append(1e3 * (t2 - t0))
            errors[name].append(error_rate((fused > 0).astype(np.uint8), f.labels))
            errors[f"{name} blurred"].append(error_rate(blurred, f.labels))
    return {"error": {m: float(np.mean(e)) for m, e in errors.items()},
            "ms": {m: float(np.median(v)) for m, v in ms.items()}, "size": list(key.image.shape[:2])}


def figure(points: list[tuple[str, float, float]]):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.2, 4.6))
    ours = sorted([p for p in points if p[0].startswith("scale")], key=lambda p: p[1])
    ax.plot([p[1] for p in ours], [p[2] for p in ours], "o-", color="C3", label="pcreg at each working size")
    for name, x, y in ours:
        ax.annotate(name.replace("scale ", ""), (x, y), textcoords="offset points", xytext=(4, 5), fontsize=8)
    presets = sorted({p[0].split(",")[0] for p in points if p[0].startswith("flow ")})
    for preset, colour in zip(presets, ("C1", "C4", "C5")):
        line = sorted([p for p in points if p[0].startswith(preset + ",")], key=lambda p: p[1])
        ax.plot([p[1] for p in line], [p[2] for p in line], "^-", color=colour,
                label=f"pcreg on DIS {preset.split()[1]} (--model flow), each size")
        for name, x, y in line:
            ax.annotate(name.split("scale ")[1], (x, y), textcoords="offset points", xytext=(4, 5), fontsize=7)
    for blurred, colour, label in ((False, "C0", "DIS from the key frame"),
                                   (True, "C2", "DIS, its log-odds blurred as pcreg's")):
        dis = sorted([p for p in points if not p[0].startswith(("scale", "flow ")) and p[0].endswith("blurred") == blurred],
                     key=lambda p: p[1])
        ax.plot([p[1] for p in dis], [p[2] for p in dis], "s--", color=colour, label=label)
        for name, x, y in dis:
            ax.annotate(name.split("_")[0].replace("flow", "") or "medium", (x, y), textcoords="offset points",
                        xytext=(4, -11), fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("ms a frame (median over clips; classification and fusion included)")
    ax.set_ylabel("lower than plain, mean over clips (%)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="center right")
    fig.tight_layout()
    return fig


def main(argv=None) -> int:
    from pcreg.datasets import load_dataset
    from pcreg.outputs import markdown_table

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=f"camvid:{benchlib.SHARED_DATA / 'camvid'}")
    ap.add_argument("--out", default="out/sweep_scale")
    ap.add_argument("--workers", type=int, default=2, help="clips at a time, one process each (1: in this process)")
    ap.add_argument("--frames", type=int, default=None, help="first frames of each clip (default all)")
    ap.add_argument("--scales", default="1,0.75,0.5,0.375,0.25", help="working sizes to try (default 1,0.75,0.5,0.375,0.25)")
    ap.add_argument("--flow-presets", default="medium,fast,ultrafast",
                    help="DIS presets of the flow model to try (default medium,fast,ultrafast; empty: none)")
    ap.add_argument("--flow-scales", default="1,0.5,0.25", help="the flow model's working sizes (default 1,0.5,0.25)")
    args = ap.parse_args(argv)
    scales = sorted({float(x) for x in args.scales.split(",")}, reverse=True)
    flow_presets = [p for p in args.flow_presets.split(",") if p]
    flow_scales = sorted({float(x) for x in args.flow_scales.split(",")}, reverse=True)
    clips = load_dataset(args.data, n_frames=args.frames)
    names = list(clips)
    jobs = [(frames, scales, flow_presets, flow_scales) for frames in clips.values()]
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            per_clip = dict(zip(names, pool.map(clip, jobs)))
    else:
        per_clip = dict(zip(names, map(clip, jobs)))
    plain = np.array([per_clip[c]["error"]["plain"] for c in names])
    methods = ([f"scale {s:g}" for s in scales] + [f"flow {p}, scale {s:g}" for p in flow_presets for s in flow_scales]
               + list(BASELINES)) + [f"{m} blurred" for m in BASELINES]
    red = {m: 100.0 * (plain - np.array([per_clip[c]["error"][m] for c in names])) / plain for m in methods}
    ms = {m: float(np.median([per_clip[c]["ms"][m] for c in names])) for m in methods}
    sizes = sorted({tuple(per_clip[c]["size"]) for c in names})
    md = (f"### Each working size, motion and DIS preset over {len(names)} clips ({', '.join(f'{w}x{h}' for h, w in sizes)})\n\n"
          + markdown_table(["method", "reduction of plain's error, mean %", "worst clip %", "ms a frame (median)"],
                           [[m, float(red[m].mean()), float(red[m].min()), ms[m]] for m in methods], digits=1)
          + "\n\n### Per clip (reduction of plain's error, %)\n\n"
          + markdown_table(["method", *names], [[m, *(float(x) for x in red[m])] for m in methods], digits=1) + "\n")
    report = {"machine": benchlib.machine_info(), "scales": scales, "flow_presets": flow_presets,
              "flow_scales": flow_scales, "clips": per_clip,
              "reduction": {m: [float(x) for x in red[m]] for m in methods}, "median_ms": ms}
    benchlib.write_report(args.out, "sweep_scale", report, md,
                          figure([(m, ms[m], float(red[m].mean())) for m in methods]))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
