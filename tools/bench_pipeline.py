"""Per-frame throughput of the registration-augmented classification pipeline on 640x480 frames.

A stream of frames: each new frame t is registered to frame t - 1 (clouds + ICP), the label prior of
frame t - 1 is warped into it, naive Bayes classifies it and the two are fused. Stages are timed with
``time.perf_counter`` per frame; the table gives medians (and the 90th percentile of the total) for
both ICP backends, measured in the same run. ``clouds`` (one frame's cloud pyramid) is shown for
information: it is part of ``register``, which builds both frames' clouds.

    python tools/bench_pipeline.py --out out/bench [--frames 40] [--cores 2] [--data synthetic|camvid:PATH]

Writes bench_pipeline.json, bench_pipeline.md and bench_pipeline.png into --out.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

FLOOR_MS = 30.0


def _frames(data: str, n: int, seed: int):
    import cv2

    from pcreg.datasets import Frame, load_dataset, synthetic

    if data == "synthetic":
        return synthetic("syn2a", n, seed, width=640, height=480), "synthetic syn2a 640x480"
    seqs = load_dataset(data, n_frames=n)
    name, frames = max(seqs.items(), key=lambda kv: len(kv[1]))
    out = []
    for f in frames[:n]:
        img = cv2.resize(f.image, (640, 480), interpolation=cv2.INTER_LINEAR)
        lab = cv2.resize(f.labels, (640, 480), interpolation=cv2.INTER_NEAREST)
        out.append(Frame(img, lab, f.name))
    return out, f"{data.split(':')[0]} {name} resized to 640x480"


def bench(frames, *, backend: str, init: str, repeats: int = 1) -> dict:
    """Stage times (ms) per frame pair (t - 1, t) of ``frames``, and their medians."""
    from pcreg import cloud_pyramid, register
    from pcreg.classification.fusion import FusionConfig, fuse, labels_from_log_odds, prior_from_labels, prior_log_odds, smooth_prior, warp_prior
    from pcreg.classification.bayes import fit_classifier
    from pcreg.pipeline import PIPELINE_REGISTRATION, log_odds

    clf = fit_classifier([frames[0]])
    pi = float(clf.class_prior_[1])
    fusion = FusionConfig()
    model = PIPELINE_REGISTRATION.model
    register(frames[0].image, frames[1].image, backend=backend, model=model, init=init)  # warm-up (imports, JIT)
    rows = []
    for _ in range(repeats):
        for t in range(1, len(frames)):
            ref, mov = frames[t - 1], frames[t]
            s = {}
            t0 = time.perf_counter()
            cloud_pyramid(mov.image, levels=4)
            s["clouds"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            res = register(ref.image, mov.image, backend=backend, model=model, init=init)
            s["register"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            q = smooth_prior(prior_from_labels(ref.labels, pi=pi), pi=pi, eps=fusion.eps, sigma=fusion.sigma)
            q_mov, _ = warp_prior(q, res.matrix, shape=mov.shape, pi=pi)
            s["warp"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            d = log_odds(clf, mov.image)
            s["classify"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            labels_from_log_odds(fuse(d, prior_log_odds(q_mov, pi=pi), weight=3.0))
            s["fuse"] = time.perf_counter() - t0
            s["total"] = s["register"] + s["warp"] + s["classify"] + s["fuse"]
            rows.append({k: 1000.0 * v for k, v in s.items()})
    keys = ("clouds", "register", "warp", "classify", "fuse", "total")
    med = {k: float(np.median([r[k] for r in rows])) for k in keys}
    return {"backend": backend, "model": model, "init": init, "pairs": len(rows), "median_ms": med,
            "p90_total_ms": float(np.percentile([r["total"] for r in rows], 90)),
            "frames_per_second": 1000.0 / med["total"], "per_pair_ms": rows}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--frames", type=int, default=40, help="frames in the stream (default 40)")
    p.add_argument("--data", default="synthetic", help="synthetic (default) or camvid:PATH (resized to 640x480)")
    p.add_argument("--cores", type=int, default=2, help="pin the process to this many CPUs (default 2)")
    p.add_argument("--inits", default="identity,auto", help="registration starts to time (default identity,auto)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    import cv2

    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if args.cores and cpus and len(cpus) > args.cores:
        os.sched_setaffinity(0, set(cpus[: args.cores]))
    cv2.setNumThreads(args.cores)
    frames, desc = _frames(args.data, args.frames, args.seed)
    results = []
    for init in [s.strip() for s in args.inits.split(",") if s.strip()]:
        for backend in ("reference", "open3d"):
            print(f"{backend} init={init} ...", file=sys.stderr, flush=True)
            results.append(bench(frames, backend=backend, init=init))
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "cpus_used": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
               "cpus_total": os.cpu_count(), "loadavg_at_end": load, "python": platform.python_version()}

    from pcreg.outputs import atomic_save_figure, atomic_write_json, atomic_write_text, markdown_table

    out = Path(args.out)
    summary = [{k: v for k, v in r.items() if k != "per_pair_ms"} for r in results]
    atomic_write_json(out / "bench_pipeline.json", {"data": desc, "floor_ms": FLOOR_MS, "machine": machine,
                                                    "command": " ".join(["python", "tools/bench_pipeline.py", *(argv or sys.argv[1:])]),
                                                    "results": results})
    header = ["backend", "model", "init", "pairs", "clouds (in register)", "register", "warp", "classify", "fuse",
              "total median", "total p90", "frames/s", f"<= {FLOOR_MS:g} ms"]
    rows = [[r["backend"], r["model"], r["init"], r["pairs"], *[r["median_ms"][k] for k in
             ("clouds", "register", "warp", "classify", "fuse", "total")], r["p90_total_ms"], r["frames_per_second"],
             "met" if r["median_ms"]["total"] <= FLOOR_MS else "NOT met"] for r in summary]
    text = (f"### Pipeline throughput, {desc} (median ms per frame)\n\n" + markdown_table(header, rows, digits=1)
            + f"\nMachine: {machine['processor']}, {machine['cpus_used']} of {machine['cpus_total']} CPUs, "
              f"load average at the end {None if load is None else tuple(round(v, 2) for v in load)}.\n")
    atomic_write_text(out / "bench_pipeline.md", text)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.2 + 0.35 * len(summary)))
    stages = ("register", "warp", "classify", "fuse")
    colours = ("#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd")
    labels = [f"{r['backend']} ({r['model']}, init {r['init']})" for r in summary]
    left = np.zeros(len(summary))
    for st, c in zip(stages, colours):
        vals = np.array([r["median_ms"][st] for r in summary])
        ax.barh(labels, vals, left=left, color=c, label=st)
        left += vals
    for y, r in enumerate(summary):
        ax.text(left[y] + 1, y, f"{r['median_ms']['total']:.0f} ms", va="center", fontsize=8)
    ax.axvline(FLOOR_MS, color="red", ls="--", lw=1, label=f"floor {FLOOR_MS:g} ms")
    ax.set_xlabel("median ms per 640x480 frame")
    ax.set_title(f"Pipeline stages, {desc}", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(alpha=0.3, axis="x")
    ax.invert_yaxis()
    fig.tight_layout()
    atomic_save_figure(fig, out / "bench_pipeline.png")
    plt.close(fig)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
