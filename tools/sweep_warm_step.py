"""The stream's warm dense step made cheaper, and what each saving costs in accuracy on the shared clips.

    python tools/sweep_warm_step.py --data camvid:../shared/data/camvid --out out/sweep_warm_step

Each variant of :class:`pcreg.pipeline.estimators.DenseStep` (fewer warm iterations, fewer samples, a
warm start at the finest level) labels every clip from its first frame, as the stream evaluation does;
a variant is scored by the mean over clips of its reduction of plain naive Bayes' error, its worst clip,
and the median time of its registration a frame. Clips run two at a time, each on one core.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402

#: The variants: DenseStep's options beside the default.
VARIANTS: dict[str, dict] = {
    "default: level 2, 4 iterations, 5,000 samples": {},
    "3 iterations": {"warm_iterations": 3},
    "2 iterations": {"warm_iterations": 2},
    "3,000 samples": {"max_points": 3000},
    "2,000 samples": {"max_points": 2000},
    "from level 1 (the finest)": {"warm_level": 1},
    "from level 1, 6 iterations": {"warm_level": 1, "warm_iterations": 6},
    "3 iterations, 3,000 samples": {"warm_iterations": 3, "max_points": 3000},
    "2 iterations, 3,000 samples": {"warm_iterations": 2, "max_points": 3000},
}


def clip(frames) -> dict:
    """Plain naive Bayes' mean error on the clip, and each variant's mean error and registration ms."""
    import pcreg
    from pcreg.classification.metrics import error_rate
    from pcreg.pipeline.estimators import DenseStep

    clf = pcreg.fit_classifier([frames[0]])
    out: dict = {"plain": float(np.mean([error_rate(clf.predict(f.image), f.labels) for f in frames[1:]]))}
    for name, options in VARIANTS.items():
        prop = pcreg.Propagator(clf, dense=DenseStep(**options))
        prop.reset(frames[0].image, frames[0].labels)
        errors, ms = [], []
        for f in frames[1:]:
            errors.append(error_rate(prop.step(f.image), f.labels))
            ms.append(1e3 * prop.last.times["register"])
        out[name] = {"error": float(np.mean(errors)), "register_ms": float(np.median(ms))}
    return out


def main(argv=None) -> int:
    from pcreg.datasets import load_dataset
    from pcreg.outputs import markdown_table

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=f"camvid:{benchlib.SHARED_DATA / 'camvid'}")
    ap.add_argument("--out", default="out/sweep_warm_step")
    args = ap.parse_args(argv)
    clips = load_dataset(args.data)
    with ProcessPoolExecutor(2) as pool:
        per_clip = dict(zip(clips, pool.map(clip, clips.values())))
    rows = []
    for name in VARIANTS:
        red = [100.0 * (r["plain"] - r[name]["error"]) / r["plain"] for r in per_clip.values()]
        rows.append([name, float(np.mean(red)), float(min(red)),
                     float(np.median([r[name]["register_ms"] for r in per_clip.values()]))])
    md = markdown_table(["warm step", "reduction %", "worst clip %", "registration ms"], rows, digits=1)
    report = {"machine": benchlib.machine_info(), "clips": per_clip}
    benchlib.write_report(args.out, "sweep_warm_step", report, md + "\n")
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
