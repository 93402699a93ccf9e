"""Dense registration against OpenCV's DIS optical flow (medium preset) on 640x480 pairs.

Each pair (frames t and t + 1 of a stream, resized to 640x480) is run by, interleaved so that both
see the same machine load:

- ``dis_medium``: ``cv2.DISOpticalFlow`` (medium preset) on the grey images;
- ``dense_step``: :func:`pcreg.register_dense` given the global result (the non-rigid ICP alone);
- ``global``: :func:`pcreg.register` (similarity, identity start, its plausibility test off as in the
  pipeline's dense model), the dense step's start;
- ``dense_total``: ``global`` + ``dense_step``, what ``register_dense`` costs from scratch.

The table gives medians (ms) and the ratios of medians to DIS measured in the same run.

    python tools/bench_dense.py --out out/bench [--pairs 10] [--repeats 3] [--cores 2] [--data camvid:PATH]

Writes bench_dense.json and bench_dense.md into --out.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np


def _images(data: str, n: int, seed: int) -> tuple[list[np.ndarray], str]:
    import cv2

    from pcreg.datasets import load_dataset, synthetic

    if data == "synthetic":
        return [f.image for f in synthetic("syn2a", n, seed, width=640, height=480)], "synthetic syn2a 640x480"
    seqs = load_dataset(data, n_frames=n)
    name, frames = max(seqs.items(), key=lambda kv: len(kv[1]))
    return ([cv2.resize(f.image, (640, 480), interpolation=cv2.INTER_LINEAR) for f in frames[:n]],
            f"{data.split(':')[0]} {name} resized to 640x480")


def bench(images: list[np.ndarray], *, repeats: int = 3) -> dict:
    """Per-pair times (ms) of each method, interleaved, and their medians and ratios to DIS."""
    import cv2

    from pcreg import RegisterConfig, register, register_dense

    similarity = RegisterConfig.of(model="similarity", init="identity", min_inlier_ratio=None)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    g = register(images[0], images[1], config=similarity)  # warm-up (imports, JIT)
    register_dense(images[0], images[1], global_result=g)
    rows = []
    for _ in range(repeats):
        for t in range(len(images) - 1):
            ref, mov = images[t], images[t + 1]
            g_ref, g_mov = cv2.cvtColor(ref, cv2.COLOR_RGB2GRAY), cv2.cvtColor(mov, cv2.COLOR_RGB2GRAY)
            r = {}
            t0 = time.perf_counter()
            dis.calc(g_mov, g_ref, None)
            r["dis_medium"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            g = register(ref, mov, config=similarity)
            r["global"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            register_dense(ref, mov, global_result=g)
            r["dense_step"] = time.perf_counter() - t0
            r["dense_total"] = r["global"] + r["dense_step"]
            rows.append({k: 1000.0 * v for k, v in r.items()})
    keys = ("dis_medium", "dense_step", "global", "dense_total")
    med = {k: float(np.median([r[k] for r in rows])) for k in keys}
    ratios = {k: med[k] / med["dis_medium"] for k in keys}
    return {"pairs": len(rows), "median_ms": med, "ratio_to_dis": ratios, "per_pair_ms": rows}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--pairs", type=int, default=10, help="consecutive pairs of the stream (default 10)")
    p.add_argument("--repeats", type=int, default=3, help="passes over the pairs (default 3)")
    p.add_argument("--data", default="synthetic", help="synthetic (default) or camvid:PATH (resized to 640x480)")
    p.add_argument("--cores", type=int, default=2, help="pin the process to this many CPUs (default 2)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    import cv2

    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if args.cores and cpus and len(cpus) > args.cores:
        os.sched_setaffinity(0, set(cpus[: args.cores]))
    cv2.setNumThreads(args.cores)
    images, desc = _images(args.data, args.pairs + 1, args.seed)
    result = bench(images, repeats=args.repeats)
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "cpus_used": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
               "cpus_total": os.cpu_count(), "loadavg_at_end": load, "python": platform.python_version()}

    from pcreg.outputs import atomic_write_json, atomic_write_text, markdown_table

    out = Path(args.out)
    atomic_write_json(out / "bench_dense.json", {"data": desc, "machine": machine,
                                                 "command": " ".join(["python", "tools/bench_dense.py", *(argv or sys.argv[1:])]),
                                                 **result})
    names = {"dis_medium": "DIS optical flow, medium preset", "dense_step": "dense step (given the global result)",
             "global": "global registration (similarity)", "dense_total": "register_dense from scratch"}
    rows = [[names[k], result["median_ms"][k], result["ratio_to_dis"][k]] for k in names]
    text = (f"### Dense registration vs DIS, {desc}: median ms per pair over {result['pairs']} pairs\n\n"
            + markdown_table(["method", "median ms", "ratio to DIS medium"], rows, digits=2)
            + f"\nMachine: {machine['processor']}, {machine['cpus_used']} of {machine['cpus_total']} CPUs, "
              f"load average at the end {None if load is None else tuple(round(v, 2) for v in load)}.\n")
    atomic_write_text(out / "bench_dense.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
