"""Time and memory of the stream's step with eleven classes against two, in one run.

Time: one CamVid clip's frames at 640x480 (resized from 480x360), its first frame the key frame, labelled
once with CamVid's eleven classes (``camvid11``) and once with ground and obstacle (CamVid's ids mapped to
``lagr``). The two propagators step through the same frames, alternately, so that both see the same load;
each step's time is :attr:`StepReport.times` ``total``; the medians are compared.

Memory: the eleven-class propagator steps ``--frames`` times (2,000 by default) through the clip played
forwards and backwards at ``--size``; the process's resident memory (VmRSS) is sampled every 50 steps, and
its growth from the warm step (:data:`WARM_STEP`) to the end is compared to the target.

    python tools/bench_classes.py --out out/bench [--clip 0001TP] [--repeats 60] [--frames 2000] [--size 320x240]

Writes bench_classes.json, bench_classes.md and bench_classes.png (memory against the step).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from benchlib import SHARED_DATA, checks_markdown, finish, machine_info

#: An eleven-class step may take at most this many times the two-class step (medians, one run).
TARGET_TIME_RATIO = 2.0
#: Resident memory may grow at most this share from the warm step to the end.
TARGET_RSS_GROWTH = 0.05
#: Steps before memory is measured against (compiled kernels and allocator pools settle).
WARM_STEP = 100
#: CamVid's ids mapped to ground (0), obstacle (1) and unknown (2), as ``--mapping camvid`` reads them.
CAMVID_TO_LAGR = np.array([2, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 2] + [2] * 244, np.uint8)


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def load_clip(name: str, size: tuple[int, int] | None):
    import cv2

    folder = SHARED_DATA / "camvid" / name
    if not folder.is_dir():
        sys.exit(f"{folder} is absent: this benchmark reads the shared CamVid clips")
    images, labels = [], []
    for p in sorted((folder / "images").iterdir()):
        im = cv2.imread(str(p))[:, :, ::-1]
        lab = cv2.imread(str(folder / "labels" / p.name), cv2.IMREAD_UNCHANGED)
        if size is not None:
            im = cv2.resize(im, size, interpolation=cv2.INTER_AREA)
            lab = cv2.resize(lab, size, interpolation=cv2.INTER_NEAREST)
        images.append(np.ascontiguousarray(im))
        labels.append(lab)
    return images, labels


def time_steps(images, labels, repeats: int) -> dict:
    from pcreg.classes import CAMVID11, LAGR
    from pcreg.pipeline.stream import Propagator

    props = {"two": Propagator.from_key_frame(images[0], CAMVID_TO_LAGR[labels[0]], classes=LAGR),
             "eleven": Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11)}
    times: dict[str, list[float]] = {k: [] for k in props}
    parts: dict[str, dict[str, list[float]]] = {k: {} for k in props}
    order = list(range(1, len(images)))
    for r in range(repeats):
        t = order[r % len(order)]
        for name, prop in props.items():
            prop.step(images[t])
            if r == 0:
                continue  # the first step compiles
            times[name].append(1000.0 * prop.last.times["total"])
            for stage in ("register", "classify", "fuse"):
                parts[name].setdefault(stage, []).append(1000.0 * prop.last.times[stage])
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {"median_ms": med, "ratio": med["eleven"] / med["two"],
            "stages_ms": {k: {s: float(np.median(v)) for s, v in p.items()} for k, p in parts.items()},
            "classes": len(props["eleven"].classes), "steps": repeats - 1}


def memory_soak(images, labels, n: int) -> dict:
    from pcreg.classes import CAMVID11
    from pcreg.pipeline.stream import Propagator

    prop = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11)
    m = len(images)
    period = 2 * (m - 1)
    samples = []
    from tqdm import tqdm

    for i in tqdm(range(1, n + 1), desc="steps", disable=None):
        r = i % period
        prop.step(images[r if r < m else period - r])
        if i % 50 == 0 or i in (WARM_STEP, n):  # the last step too: its growth since step WARM_STEP measured
            samples.append((i, rss_mb()))
    warm = next(v for i, v in samples if i >= WARM_STEP)
    end = samples[-1][1]
    return {"samples": samples, "warm_mb": warm, "end_mb": end, "growth": (end - warm) / warm, "steps": n}


def render(r: dict) -> str:
    t, mem = r["time"], r["memory"]
    rows = [[k, f"{v:.1f}", *(f"{t['stages_ms'][k][s]:.1f}" for s in ("register", "classify", "fuse"))]
            for k, v in t["median_ms"].items()]
    from pcreg.outputs import markdown_table

    return ("## The step with eleven classes against two\n\n"
            + markdown_table(["classes", "step ms (median)", "register", "classify", "fuse"], rows) + "\n\n"
            + checks_markdown([
                (f"an eleven-class step at 640x480 <= {TARGET_TIME_RATIO:g}x the two-class step",
                 f"{t['ratio']:.2f}x ({t['steps']} steps each)", t["ratio"] <= TARGET_TIME_RATIO),
                (f"resident memory over {mem['steps']} eleven-class steps grows <= {100 * TARGET_RSS_GROWTH:g}% "
                 f"after step {WARM_STEP}",
                 f"{mem['warm_mb']:.0f} MB -> {mem['end_mb']:.0f} MB ({100 * mem['growth']:+.1f}%)",
                 mem["growth"] <= TARGET_RSS_GROWTH)]))


def figure(r: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    s = np.array(r["memory"]["samples"])
    ax.plot(s[:, 0], s[:, 1], marker=".")
    ax.set_xlabel("step")
    ax.set_ylabel("resident memory (MB)")
    ax.set_title("Eleven classes: memory over a long stream")
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--clip", default="0001TP")
    ap.add_argument("--repeats", type=int, default=60)
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--size", default="320x240")
    a = ap.parse_args(argv)
    if a.frames <= WARM_STEP:
        ap.error(f"--frames must be more than {WARM_STEP}: memory is measured from step {WARM_STEP} on")
    if a.repeats < 1:
        ap.error("--repeats must be at least 1")
    w, h = (int(v) for v in a.size.split("x"))
    images, labels = load_clip(a.clip, (640, 480))
    report = {"machine": machine_info(), "time": time_steps(images, labels, a.repeats + 1)}
    small, small_labels = load_clip(a.clip, (w, h))
    report["memory"] = memory_soak(small, small_labels, a.frames)
    return finish(a.out, "bench_classes", report, render, figure)


if __name__ == "__main__":
    raise SystemExit(main())
