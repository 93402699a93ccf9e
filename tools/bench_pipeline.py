"""Per-frame cost of the default streaming step at 640x480, against DIS optical flow, stage by stage.

Every frame t of a stream goes, in the same run and in an alternating order, through

- ``step``: :meth:`pcreg.Propagator.step` with its defaults (``model="dense"``, anchored to the key
  frame: :func:`pcreg.register_dense` with :data:`pcreg.pipeline.stream.STREAM_DENSE`, from the
  identity on the first frame and from the previous frame's grid after it, naive Bayes log-odds, the
  key frame's prior warped along the field, fused): the whole frame, from a propagator fitted on
  frame 0 and its labels (:meth:`pcreg.Propagator.from_key_frame`), the frames in order;
- ``dis_medium``: OpenCV's DIS optical flow, medium preset (``cv2.DISOpticalFlow_create(
  cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)``), from frame t to the key frame, grey conversion included:
  the motion only, no labels;
- ``step_half``: the same step at half the frames' width and height (``Propagator(scale=0.5)``,
  ``pcreg run --scale 0.5``), its labels brought back to 640x480; ``step_flow_half`` and
  ``step_flow_quarter``: the step with DIS's flow (medium preset) as its motion at half and a quarter of
  the size (``pcreg run --model flow --scale S``), the trust rule, learning and the confidence on; and the
  step without parts of its trust rule, to show what each costs.

Both use the machine's cores: DIS through OpenCV's threads, the step through pcreg's helper thread
(:mod:`pcreg._threads`: half of each search, the frame's classification during the registration, ...).
The ratio ``step / dis_medium`` is taken per frame and summarised by its median. The step's stages
are its own clocks (:attr:`pcreg.pipeline.stream.StepReport.times`, :data:`pcreg.pipeline.stream.STEP_PARTS`): the
dense registration's pyramids and samples, correspondence search, solve, plausibility figure and
full-resolution field; the classifier's features and naive Bayes; the prior's warp and the fusion.
Error rates (unknown left out) show what the time buys: the step's labels, naive Bayes alone, and the
same prior fused along DIS's flow instead of the dense field.
Data: the synthetic ``syn2a`` stream rendered at 640x480, and CamVid ``0016E5`` (../shared/data/camvid,
15 labelled frames a second) resized from 480x360 to 640x480.

    python tools/bench_pipeline.py --out out/bench [--frames 30] [--data synthetic,camvid] [--cores 2]

Writes bench_pipeline.json, bench_pipeline.md and bench_pipeline.png into --out.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchlib import SHARED_DATA, checks_markdown, finish, machine_info

#: The step is meant to cost no more than the optical flow a user would pick instead: DIS's fast preset
#: (about the same labels as its medium preset at a quarter of the time) ...
TARGET_VS_DIS_FAST = 1.0
#: ... and, as a looser target, no more than DIS's medium preset, the evaluations' baseline.
TARGET_VS_DIS = 1.0
#: The trust map and the learning classifier together add at most this share to the step's time
#: (the default step against the same step with ``trust=None``, which also turns learning off).
TARGET_TRUST_SHARE = 0.15
SIZE = (640, 480)
METHODS = ("step", "step_half", "step_flow_half", "step_flow_quarter", "step_no_trust", "step_no_flow",
           "step_no_learning", "dis_medium", "dis_fast", "dis_ultrafast")
#: The step's variants beside the default (what each part of the trust rule costs): Propagator options.
VARIANTS = {"step_half": {"scale": 0.5}, "step_flow_half": {"model": "flow", "scale": 0.5},
            "step_flow_quarter": {"model": "flow", "scale": 0.25}, "step_no_trust": {"trust": None, "learning": None},
            "step_no_flow": {"flow": 0.0}, "step_no_learning": {"learning": None}}
#: The variants whose labels are scored (outside the clock), and the name of their error.
SCORED = {"step_half": "half", "step_flow_half": "flow_half", "step_flow_quarter": "flow_quarter"}
PRESETS = {"dis_medium": "MEDIUM", "dis_fast": "FAST", "dis_ultrafast": "ULTRAFAST"}


def load_frames(which: str, n: int, seed: int, data: Path):
    """(description, frames) of one stream at 640x480, or None when its data is absent."""
    import cv2

    from pcreg.datasets import Frame, load_folder, synthetic

    if which == "synthetic":
        return "synthetic syn2a, 640x480", synthetic("syn2a", n, seed, width=SIZE[0], height=SIZE[1])
    folder = data / "camvid" / "0016E5"
    if not folder.is_dir():
        print(f"skipping camvid: {folder} not found", file=sys.stderr)
        return None
    frames = []
    for f in load_folder(folder)[:n]:
        img = cv2.resize(f.image, SIZE, interpolation=cv2.INTER_LINEAR)
        lab = cv2.resize(f.labels, SIZE, interpolation=cv2.INTER_NEAREST)
        frames.append(Frame(img, lab, f.name))
    return "CamVid 0016E5 resized to 640x480", frames


def bench_stream(frames) -> dict:
    import cv2

    import pcreg
    from pcreg.classification.fusion import fuse, label_prior, labels_from_log_odds, prior_log_odds
    from pcreg.pipeline.prior import warp_prior
    from pcreg.pipeline.stream import STEP_PARTS, STEP_STAGES

    key = frames[0]
    prop = pcreg.Propagator.from_key_frame(key.image, key.labels)
    from pcreg.pipeline.trust import STREAM_TRUST

    variants = {}
    for m, kw in VARIANTS.items():
        opts = {"trust": replace(STREAM_TRUST, flow=kw["flow"])} if "flow" in kw else dict(kw)
        variants[m] = pcreg.Propagator(prop.classifier, **opts)
        variants[m].reset(key.image, key.labels)
    clf = prop.classifier
    pi = float(clf.class_prior_[1])
    key_prior = label_prior(key.labels, pi=pi, fusion=prop.fusion)
    dis = {m: cv2.DISOpticalFlow_create(getattr(cv2, f"DISOPTICAL_FLOW_PRESET_{p}")) for m, p in PRESETS.items()}
    h, w = key.image.shape[:2]
    grid = np.dstack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)))

    def dis_flow(image, m="dis_medium"):
        """Flow from the frame to the key frame, both grey conversions included (as the step, which
        builds the key frame's pyramid again every time)."""
        return dis[m].calc(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.cvtColor(key.image, cv2.COLOR_RGB2GRAY), None)

    # warm-up on the first frame: imports, compiled kernels, OpenCV's buffers
    for m in PRESETS:
        dis_flow(frames[1].image, m)
    for p in (prop, *variants.values()):
        p.step(frames[1].image)
        p.reset(key.image, key.labels)
    stages = list(STEP_STAGES) + [f"{s}.{p}" for s, parts in STEP_PARTS.items() for p in parts]
    rows = []
    for t in range(1, len(frames)):
        mov = frames[t]
        row = {"frame": mov.name, "ms": {}}
        outs: dict = {}
        order = METHODS if t % 2 else METHODS[::-1]
        for m in order:
            t0 = time.perf_counter()
            if m == "step":
                labels = prop.step(mov.image)
            elif m in variants:
                outs[m] = variants[m].step(mov.image)
            elif m == "dis_medium":
                flow = dis_flow(mov.image)
            else:
                dis_flow(mov.image, m)
            row["ms"][m] = 1e3 * (time.perf_counter() - t0)
        last = prop.last
        row["stages_ms"] = {s: 1e3 * float(last.times.get(s, float("nan"))) for s in stages}
        row["registered"] = last.registered
        row["start"] = last.start
        row["error_step"] = pcreg.error_rate(labels, mov.labels)
        for m, what in SCORED.items():  # outside the clock, as the step's
            row[f"error_{what}"] = pcreg.error_rate(outs[m], mov.labels)
        d = np.asarray(clf.decision_function(mov.image), dtype=np.float32)
        row["error_naive_bayes"] = pcreg.error_rate(labels_from_log_odds(d), mov.labels)
        q, _ = warp_prior(key_prior, grid + flow, shape=d.shape, pi=pi)
        fused = labels_from_log_odds(fuse(d, prior_log_odds(q, pi=pi), weight=prop.weight))
        row["error_dis_prior"] = pcreg.error_rate(fused, mov.labels)
        rows.append(row)
    med = {m: float(np.median([r["ms"][m] for r in rows])) for m in METHODS}
    return {"pairs": len(rows), "median_ms": med, "rows": rows,
            "p90_ms": {m: float(np.percentile([r["ms"][m] for r in rows], 90)) for m in METHODS},
            "ratio_step_over_dis": float(np.median([r["ms"]["step"] / r["ms"]["dis_medium"] for r in rows])),
            "ratio_step_over_dis_fast": float(np.median([r["ms"]["step"] / r["ms"]["dis_fast"] for r in rows])),
            "ratio_half_over_dis_fast": float(np.median([r["ms"]["step_half"] / r["ms"]["dis_fast"] for r in rows])),
            **{f"ratio_{what}_over_dis_fast": float(np.median([r["ms"][m] / r["ms"]["dis_fast"] for r in rows]))
               for m, what in SCORED.items() if m != "step_half"},
            "ratio_half_over_step": float(np.median([r["ms"]["step_half"] / r["ms"]["step"] for r in rows])),
            "ratio_step_over_no_trust": float(np.median([r["ms"]["step"] / r["ms"]["step_no_trust"] for r in rows])),
            "stages_median_ms": {s: float(np.nanmedian([r["stages_ms"][s] for r in rows])) for s in stages},
            "mean_error": {k: float(np.nanmean([r[f"error_{k}"] for r in rows]))
                           for k in ("step", *SCORED.values(), "naive_bayes", "dis_prior")},
            "refused": int(sum(not r["registered"] for r in rows)),
            "starts": {k: sum(r["start"] == k for r in rows) for k in ("cold", "warm", "restarted")}}


def render(report: dict) -> str:
    from pcreg.outputs import markdown_table

    from pcreg.pipeline.stream import STEP_PARTS

    lines = ["## The default streaming step per 640x480 frame (median ms; ratios per frame, then the median)\n"]
    checks = []
    for name, s in report["streams"].items():
        lines.append(f"### {s['description']} ({s['pairs']} frames)\n")
        body = [["Propagator.step (default: dense, key-anchored, trust and learning)", s["median_ms"]["step"],
                 s["p90_ms"]["step"], s["mean_error"]["step"]],
                ["Propagator.step at half size (scale=0.5: the step on the frame resized, the labels brought back)",
                 s["median_ms"]["step_half"], s["p90_ms"]["step_half"], s["mean_error"]["half"]],
                *([[f"Propagator.step on DIS medium's flow at {what} size (model=\"flow\", scale={sc:g}; trust, learning)",
                    s["median_ms"][m], s["p90_ms"][m], s["mean_error"][SCORED[m]]]
                   for m, what, sc in (("step_flow_half", "half", 0.5), ("step_flow_quarter", "a quarter", 0.25))
                   if m in s["median_ms"]]),
                ["Propagator.step with trust=None (one prior, no learning)", s["median_ms"]["step_no_trust"],
                 s["p90_ms"]["step_no_trust"], float("nan")],
                *([[f"Propagator.step without {what}", s["median_ms"][m], s["p90_ms"][m], float("nan")]
                   for m, what in (("step_no_flow", "the second motion (trust flow=0)"),
                                   ("step_no_learning", "learning (learning=None)")) if m in s["median_ms"]]),
                ["DIS optical flow, medium (motion only)", s["median_ms"]["dis_medium"], s["p90_ms"]["dis_medium"],
                 float("nan")],
                ["DIS optical flow, fast (motion only)", s["median_ms"]["dis_fast"], s["p90_ms"]["dis_fast"],
                 float("nan")],
                ["DIS optical flow, ultrafast (motion only)", s["median_ms"]["dis_ultrafast"],
                 s["p90_ms"]["dis_ultrafast"], float("nan")],
                ["naive Bayes alone (for the error)", float("nan"), float("nan"), s["mean_error"]["naive_bayes"]],
                ["the same prior along DIS's flow (for the error)", float("nan"), float("nan"),
                 s["mean_error"]["dis_prior"]]]
        lines.append(markdown_table(["method", "median ms", "p90 ms", "mean error %"], body, digits=1))
        starts = s.get("starts", {})
        lines.append(f"\nAt half size the step takes {s['ratio_half_over_step']:.2f} of the default's time (the median "
                     "of the ratios per frame).")
        lines.append(f"\nThe step's dense registrations: {starts.get('cold', 0)} cold (from the identity), "
                     f"{starts.get('warm', 0)} warm (from the previous frame's grid), {starts.get('restarted', 0)} "
                     "restarted cold by the evidence rule.")
        st = s["stages_median_ms"]
        stage_rows = []
        for stage, parts in STEP_PARTS.items():
            stage_rows.append([stage, st[stage]])
            stage_rows += [[f"- {p}", st[f"{stage}.{p}"]] for p in parts]
        stage_rows.append(["total", st["total"]])
        lines.append("\nStages of a step (median ms of each stage over the frames; the parts' medians need not add "
                     "up to their stage's). The classification runs on pcreg's helper thread while the registration "
                     "runs, so the stages add up to more than the total:\n")
        lines.append(markdown_table(["stage", "median ms"], stage_rows, digits=2))
        r = s["ratio_step_over_dis_fast"]
        checks.append((f"{name}: Propagator.step (default) / DIS fast <= {TARGET_VS_DIS_FAST:g}", f"{r:.2f}",
                       r <= TARGET_VS_DIS_FAST))
        r = s["ratio_half_over_dis_fast"]
        checks.append((f"{name}: Propagator.step at half size / DIS fast <= {TARGET_VS_DIS_FAST:g}", f"{r:.2f}",
                       r <= TARGET_VS_DIS_FAST))
        for what, label in (("flow_half", "half"), ("flow_quarter", "a quarter")):
            r = s[f"ratio_{what}_over_dis_fast"]
            checks.append((f"{name}: Propagator.step on DIS medium's flow at {label} size (trust and learning on) / "
                           f"DIS fast <= {TARGET_VS_DIS_FAST:g}", f"{r:.2f}", r <= TARGET_VS_DIS_FAST))
        r = s["ratio_step_over_dis"]
        checks.append((f"{name}: Propagator.step (default) / DIS medium <= {TARGET_VS_DIS:g}", f"{r:.2f}", r <= TARGET_VS_DIS))
        r = s["ratio_step_over_no_trust"] - 1.0
        checks.append((f"{name}: the trust map and learning add <= {100 * TARGET_TRUST_SHARE:.0f}% to the step",
                       f"{100 * r:+.0f}%", r <= TARGET_TRUST_SHARE))
    lines.append(checks_markdown(checks))
    load = report["machine"].get("load_average"), report["machine"].get("load_average_at_end")
    lines.append(f"\nLoad average (1, 5, 15 min) at the start {load[0]} and at the end {load[1]}, on "
                 f"{report['machine']['cpu_count']} CPUs: other work shared the machine when it is above 0.5 a CPU.\n")
    return "\n".join(lines)


def figure(report: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    streams = report["streams"]
    fig, axes = plt.subplots(len(streams), 1, figsize=(8.0, 1.2 + 1.6 * len(streams)), squeeze=False)
    # the calling thread's stages in order; the classification runs on the helper thread meanwhile
    main = [("register.pyramid", "pyramids, samples", "#8c564b"), ("register.search", "search", "#1f77b4"),
            ("register.solve", "solve", "#aec7e8"), ("register.evidence", "evidence", "#9467bd"),
            ("register.field", "field", "#17becf"), ("fuse.warp", "warp", "#98df8a"),
            ("fuse.trust", "trust and fusion", "#d62728"), ("fuse.fusion", "fusion", "#2ca02c"),
            ("fuse.confidence", "confidence", "#e377c2"), ("fuse.learn", "sure pixels", "#bcbd22")]
    beside = [("classify.learn", "learning", "#dbdb8d"), ("classify.bayes", "naive Bayes (features, tables)", "#ff7f0e"),
              ("classify.flow", "DIS ultrafast + its trust", "#c49c94")]
    for ax, (name, s) in zip(axes[:, 0], streams.items()):
        right = 0.0
        for row, parts in ((0, main), (1, beside)):
            left = 0.0
            for key, label, colour in parts:
                v = s["stages_median_ms"].get(key, 0.0)
                ax.barh(row, v, left=left, color=colour, label=label)
                left += v
            right = max(right, left)
        ax.text(right + 1, 0, f"{s['median_ms']['step']:.0f} ms (median step)", va="center", fontsize=8)
        ax.barh(2, s["median_ms"]["dis_medium"], color="#7f7f7f")
        ax.text(s["median_ms"]["dis_medium"] + 1, 2, f"{s['median_ms']['dis_medium']:.0f} ms", va="center", fontsize=8)
        ax.set_yticks([0, 1, 2], ["Propagator.step (default)", "its classification,\non the helper thread",
                                  "DIS medium"], fontsize=8)
        ax.invert_yaxis()
        ax.set_title(f"{s['description']}: step / DIS = {s['ratio_step_over_dis']:.2f}", fontsize=9)
        ax.grid(alpha=0.3, axis="x")
        ax.set_xlim(0, max(right, s["median_ms"]["dis_medium"]) * 1.4)  # room for the labels
    axes[-1, 0].set_xlabel("median ms per 640x480 frame")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=len(main) + len(beside), frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return fig


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--frames", type=int, default=30, help="frames per stream, the key frame included (default 30)")
    p.add_argument("--data", default="synthetic,camvid", help="streams: synthetic and/or camvid (default both)")
    p.add_argument("--shared-data", type=Path, default=SHARED_DATA, help="../shared/data")
    p.add_argument("--cores", type=int, default=2, help="pin the process to this many CPUs (default 2; 0: leave as is)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.frames < 3:
        print("--frames must be at least 3 (the key frame, a warm-up frame and one timed frame)", file=sys.stderr)
        return 2

    import cv2

    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if args.cores and cpus and len(cpus) > args.cores:
        os.sched_setaffinity(0, set(cpus[: args.cores]))
    if args.cores:
        cv2.setNumThreads(args.cores)
    report = {"machine": machine_info(), "targets": {"step_over_dis_fast": TARGET_VS_DIS_FAST,
                                                    "step_over_dis": TARGET_VS_DIS,
                                                    "trust_share": TARGET_TRUST_SHARE}, "streams": {}}
    for which in [s.strip() for s in args.data.split(",") if s.strip()]:
        loaded = load_frames(which, args.frames, args.seed, args.shared_data)
        if loaded is None:
            continue
        desc, frames = loaded
        print(f"{desc}: {len(frames)} frames ...", file=sys.stderr, flush=True)
        report["streams"][which] = {"description": desc, **bench_stream(frames)}
    return finish(args.out, "bench_pipeline", report, render, figure)


if __name__ == "__main__":
    raise SystemExit(main())
