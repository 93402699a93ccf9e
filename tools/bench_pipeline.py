"""Per-frame cost of streaming label propagation at 640x480, against dense optical flow and ECC.

Every frame t of a stream goes, in the same run and in a rotating order, through

- ``step_reference`` / ``step_open3d``: :meth:`pcreg.Propagator.step` (register to frame t - 1 with its
  kept pyramid, warp the label state in as a prior, classify, fuse: the whole frame), one propagator per
  ICP backend, each fitted on frame 0 and its labels (:meth:`pcreg.Propagator.from_key_frame`);
- ``register``: :func:`pcreg.register` alone on the pair (t - 1, t) (similarity, from the identity,
  both pyramids built), the registration a plain caller pays;
- ``dis_medium``: OpenCV's DIS optical flow, medium preset (``cv2.DISOpticalFlow_create(
  cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)``), grey conversion included: motion only, no labels;
- ``ecc_affine``: ``cv2.findTransformECCMultiScale`` (affine, 4 levels, tools/benchlib.py's baseline).

Ratios (``step_reference / dis_medium``, ``register / ecc_affine``) are taken per frame and summarised
by their median; the stage breakdown is the median of :attr:`pcreg.Propagator.last`'s stage times.
Error rates (unknown left out) of the propagated labels and of naive Bayes alone show what the time buys.
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
from pathlib import Path

import numpy as np

from benchlib import SHARED_DATA, checks_markdown, ecc, machine_info, write_report

TARGET_MS = 30.0
TARGET_VS_DIS = 1.0
TARGET_REGISTER_VS_ECC = 0.5
SIZE = (640, 480)


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


def bench_stream(frames, *, backends: tuple[str, ...]) -> dict:
    import cv2

    import pcreg

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    props = {b: pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, backend=b) for b in backends}
    clf = next(iter(props.values())).classifier

    def dis_flow(a, b):
        return dis.calc(cv2.cvtColor(a, cv2.COLOR_RGB2GRAY), cv2.cvtColor(b, cv2.COLOR_RGB2GRAY), None)

    # warm-up on the first pair: imports, compiled kernels, OpenCV's buffers
    dis_flow(frames[0].image, frames[1].image)
    ecc(frames[0].image, frames[1].image, motion="affine")
    pcreg.register(frames[0].image, frames[1].image, model="similarity", init="identity")
    methods = [f"step_{b}" for b in backends] + ["register", "dis_medium", "ecc_affine"]
    rows = []
    for t in range(1, len(frames)):
        ref, mov = frames[t - 1], frames[t]
        row = {"frame": mov.name, "ms": {}, "stages_ms": {}}
        k = t % len(methods)
        for m in methods[k:] + methods[:k]:
            t0 = time.perf_counter()
            if m.startswith("step_"):
                b = m[5:]
                labels = props[b].step(mov.image)
                dt = time.perf_counter() - t0
                last = props[b].last
                row["stages_ms"][b] = {s: 1e3 * v for s, v in last.times.items()}
                row[f"registered_{b}"] = last.registered
                row[f"error_{b}"] = pcreg.error_rate(labels, mov.labels)
            elif m == "register":
                pcreg.register(ref.image, mov.image, model="similarity", init="identity")
                dt = time.perf_counter() - t0
            elif m == "dis_medium":
                dis_flow(ref.image, mov.image)
                dt = time.perf_counter() - t0
            else:
                ecc(ref.image, mov.image, motion="affine")
                dt = time.perf_counter() - t0
            row["ms"][m] = 1e3 * dt
        row["error_naive_bayes"] = pcreg.error_rate(clf.predict(mov.image), mov.labels)
        rows.append(row)
    med = {m: float(np.median([r["ms"][m] for r in rows])) for m in methods}
    out = {"pairs": len(rows), "median_ms": med, "rows": rows,
           "ratio_step_over_dis": {b: float(np.median([r["ms"][f"step_{b}"] / r["ms"]["dis_medium"] for r in rows]))
                                   for b in backends},
           "ratio_register_over_ecc": float(np.median([r["ms"]["register"] / r["ms"]["ecc_affine"] for r in rows])),
           "stages_median_ms": {b: {s: float(np.median([r["stages_ms"][b][s] for r in rows]))
                                    for s in rows[0]["stages_ms"][b]} for b in backends},
           "p90_step_ms": {b: float(np.percentile([r["ms"][f"step_{b}"] for r in rows], 90)) for b in backends},
           "mean_error": {**{b: float(np.nanmean([r[f"error_{b}"] for r in rows])) for b in backends},
                          "naive_bayes": float(np.nanmean([r["error_naive_bayes"] for r in rows]))},
           "refused": {b: int(sum(not r[f"registered_{b}"] for r in rows)) for b in backends}}
    return out


def render(report: dict) -> str:
    from pcreg.outputs import markdown_table

    lines = ["## Streaming propagation per 640x480 frame (median ms; ratios per frame, then the median)\n"]
    checks = []
    for name, s in report["streams"].items():
        backends = list(s["ratio_step_over_dis"])
        lines.append(f"### {s['description']} ({s['pairs']} frames)\n")
        header = ["method", "median ms", "p90 ms", "mean error %"]
        body = []
        for b in backends:
            body.append([f"Propagator.step ({b})", s["median_ms"][f"step_{b}"], s["p90_step_ms"][b], s["mean_error"][b]])
        body.append(["naive Bayes alone (for the error)", float("nan"), float("nan"), s["mean_error"]["naive_bayes"]])
        for m, label in (("register", "pcreg.register (similarity, identity start)"),
                         ("dis_medium", "DIS optical flow, medium"), ("ecc_affine", "ECC affine, multi-scale")):
            body.append([label, s["median_ms"][m], float("nan"), float("nan")])
        lines.append(markdown_table(header, body, digits=1))
        stages = list(next(iter(s["stages_median_ms"].values())))
        lines.append("Stages of a step (median ms): " + "; ".join(
            f"{b}: " + ", ".join(f"{st} {s['stages_median_ms'][b][st]:.1f}" for st in stages) for b in backends) + ".\n")
        for b in backends:
            r = s["ratio_step_over_dis"][b]
            checks.append((f"{name}: Propagator.step ({b}) <= {TARGET_VS_DIS:g}x DIS medium", f"{r:.2f}x", r <= TARGET_VS_DIS))
            ms = s["median_ms"][f"step_{b}"]
            checks.append((f"{name}: Propagator.step ({b}) <= {TARGET_MS:g} ms", f"{ms:.1f} ms", ms <= TARGET_MS))
        r = s["ratio_register_over_ecc"]
        checks.append((f"{name}: pcreg.register <= {TARGET_REGISTER_VS_ECC:g}x ECC affine", f"{r:.2f}x",
                       r <= TARGET_REGISTER_VS_ECC))
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
    fig, axes = plt.subplots(len(streams), 1, figsize=(8.0, 1.2 + 1.6 * sum(len(s["median_ms"]) for s in streams.values()) / 3),
                             squeeze=False)
    colours = {"pyramid": "#8c564b", "register": "#1f77b4", "classify": "#ff7f0e", "fuse": "#2ca02c"}
    for ax, (name, s) in zip(axes[:, 0], streams.items()):
        labels, y = [], 0
        for b, st in s["stages_median_ms"].items():
            left = 0.0
            for stage in ("pyramid", "register", "classify", "fuse"):
                v = st.get(stage, 0.0)
                ax.barh(y, v, left=left, color=colours[stage], label=stage if y == 0 else None)
                left += v
            ax.text(left + 1, y, f"{s['median_ms'][f'step_{b}']:.0f} ms", va="center", fontsize=8)
            labels.append(f"Propagator.step ({b})")
            y += 1
        for m, label, c in (("register", "pcreg.register", "#17becf"), ("dis_medium", "DIS medium", "#7f7f7f"),
                            ("ecc_affine", "ECC affine", "#bcbd22")):
            ax.barh(y, s["median_ms"][m], color=c)
            ax.text(s["median_ms"][m] + 1, y, f"{s['median_ms'][m]:.0f} ms", va="center", fontsize=8)
            labels.append(label)
            y += 1
        ax.axvline(TARGET_MS, color="red", ls="--", lw=1, label=f"{TARGET_MS:g} ms")
        ax.set_yticks(range(len(labels)), labels, fontsize=8)
        ax.invert_yaxis()
        ax.set_title(s["description"], fontsize=9)
        ax.grid(alpha=0.3, axis="x")
        ax.legend(fontsize=7, loc="lower right")
    axes[-1, 0].set_xlabel("median ms per 640x480 frame")
    fig.tight_layout()
    return fig


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--frames", type=int, default=30, help="frames per stream (default 30)")
    p.add_argument("--data", default="synthetic,camvid", help="streams: synthetic and/or camvid (default both)")
    p.add_argument("--shared-data", type=Path, default=SHARED_DATA, help="../shared/data")
    p.add_argument("--backends", default="reference,open3d", help="Propagator backends (default reference,open3d)")
    p.add_argument("--cores", type=int, default=2, help="pin the process to this many CPUs (default 2; 0: leave as is)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    import cv2

    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if args.cores and cpus and len(cpus) > args.cores:
        os.sched_setaffinity(0, set(cpus[: args.cores]))
    if args.cores:
        cv2.setNumThreads(args.cores)
    report = {"machine": machine_info(), "targets": {"ms": TARGET_MS, "step_over_dis": TARGET_VS_DIS,
                                                    "register_over_ecc": TARGET_REGISTER_VS_ECC}, "streams": {}}
    backends = tuple(b.strip() for b in args.backends.split(",") if b.strip())
    for which in [s.strip() for s in args.data.split(",") if s.strip()]:
        loaded = load_frames(which, args.frames, args.seed, args.shared_data)
        if loaded is None:
            continue
        desc, frames = loaded
        print(f"{desc}: {len(frames)} frames ...", file=sys.stderr, flush=True)
        report["streams"][which] = {"description": desc, **bench_stream(frames, backends=backends)}
    report["machine"]["load_average_at_end"] = machine_info()["load_average"]
    md = render(report)
    write_report(args.out, "bench_pipeline", report, md, figure(report))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
