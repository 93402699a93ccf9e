"""How much the fused log-odds are blurred before they are read as labels, chosen with one clip left out.

    python tools/sweep_smoothing.py --data camvid:../shared/data/camvid --out out/sweep_smoothing

Each clip is labelled from its first frame by the propagator as pcreg ships it, but with the labels read
from the fused log-odds as they are (``TrustRule(smooth=0)``; learning reads them so either way); each
frame's fused log-odds are then blurred by a Gaussian of each ``--sigmas`` (px at the rule's base width,
480) and read as labels. The baselines' fused log-odds (plain naive Bayes, the key frame's labels
unmoved, DIS medium from the key frame, as ``pcreg evaluate stream`` fuses them) get the same blurs, so
that what the blur gives every method is seen beside what it gives pcreg.

Scores: per clip, the reduction of plain naive Bayes' error (unblurred: the baseline of every table),
and pcreg's confidence over the clips (its expected calibration error and the error of the most
confident 80% against all). The choice: the blur with the best mean reduction over seven clips among
those that leave none of the seven worse than without a blur, scored on the eighth, for each clip.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402  (puts the checkout on the path)

METHODS = ("plain", "unregistered", "flow_key", "pcreg")


def clip(args: tuple) -> dict:
    """Mean error % of each method at each blur on one clip, and pcreg's confidence counts per blur."""
    frames, sigmas = args
    import pcreg
    from pcreg.classification.metrics import error_rate
    from pcreg.experiments.stream_methods import KeyPrior, calibration_counts
    from pcreg.pipeline.estimators import FlowEstimator
    from pcreg.pipeline.pair import log_odds
    from pcreg.pipeline.stream import STREAM_WEIGHT
    from pcreg.pipeline.trust import STREAM_TRUST, label_confidence, smoothed

    key = frames[0]
    clf = pcreg.fit_classifier([key])
    h, w = key.image.shape[:2]
    prop = pcreg.Propagator(clf, trust=replace(STREAM_TRUST, smooth=0.0))
    prop.reset(key.image, key.labels)
    flow = KeyPrior(clf, weight=STREAM_WEIGHT)  # the key frame's prior, as the DIS baseline fuses it
    flow.reset(key.image, key.labels)
    errors: dict = {m: {s: [] for s in sigmas} for m in METHODS}
    counts = {s: np.zeros((2, 256), np.int64) for s in sigmas}
    for f in frames[1:]:
        prop.step(f.image)
        report = prop.last
        d = report.log_odds
        prior = report.trust.prior_term((h, w))
        motion = FlowEstimator("medium").estimate(key.image, f.image).motion
        fused = {"plain": log_odds(clf, f.image), "unregistered": flow.fused(f.image, None),
                 "flow_key": flow.fused(f.image, motion), "pcreg": d + prior}
        for s in sigmas:
            rule = replace(STREAM_TRUST, smooth=s)
            for m, F in fused.items():
                errors[m][s].append(error_rate((smoothed(F, rule) > 0).astype(np.uint8), f.labels))
            shown = smoothed(fused["pcreg"], rule)
            counts[s] += calibration_counts(label_confidence(shown, d, prior), (shown > 0).astype(np.uint8), f.labels)
    return {"errors": {m: {s: float(np.mean(v)) for s, v in e.items()} for m, e in errors.items()},
            "counts": {s: c.tolist() for s, c in counts.items()}}


def leave_one_out(reductions: dict, names: list[str]) -> list[tuple[str, float, float, float]]:
    """(clip, blur chosen on the others, reduction on it, its reduction without a blur) per clip."""
    out = []
    for i, name in enumerate(names):
        others = [j for j in range(len(names)) if j != i]
        allowed = [s for s in reductions if all(reductions[s][others] >= reductions[0.0][others] - 1e-9)]
        best = max(allowed, key=lambda s: float(reductions[s][others].mean()))
        out.append((name, best, float(reductions[best][i]), float(reductions[0.0][i])))
    return out


def main(argv=None) -> int:
    from pcreg.datasets import load_dataset
    from pcreg.experiments.stream import calibration
    from pcreg.outputs import markdown_table

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=f"camvid:{benchlib.SHARED_DATA / 'camvid'}")
    ap.add_argument("--out", default="out/sweep_smoothing")
    ap.add_argument("--sigmas", default="0,1,2,3,4,6", help="blurs to try, px at width 480 (0: none; default 0,1,2,3,4,6)")
    args = ap.parse_args(argv)
    sigmas = sorted({0.0, *(float(x) for x in args.sigmas.split(","))})
    clips = load_dataset(args.data)
    names = list(clips)
    with ProcessPoolExecutor(2) as pool:
        per_clip = dict(zip(names, pool.map(clip, [(frames, sigmas) for frames in clips.values()])))
    plain = np.array([per_clip[c]["errors"]["plain"][0.0] for c in names])
    reductions = {m: {s: 100.0 * (plain - np.array([per_clip[c]["errors"][m][s] for c in names])) / plain
                      for s in sigmas} for m in METHODS}
    rows = []
    for s in sigmas:
        cal = calibration(sum(np.array(per_clip[c]["counts"][s]) for c in names))
        rows.append([f"{s:g}", *(float(reductions[m][s].mean()) for m in METHODS), float(reductions["pcreg"][s].min()),
                     float(cal["ece"]), float(cal["top80_ratio"])])
    md = ("### Each blur, every clip\n\n"
          + markdown_table(["blur (px at 480)", *(f"{m}: reduction %" for m in METHODS), "pcreg: worst clip %",
                            "pcreg: ECE", "pcreg: top 80% / all"], rows, digits=4) + "\n\n"
          + "### pcreg per clip (reduction of plain's error, %)\n\n"
          + markdown_table(["blur", *names], [[f"{s:g}", *(float(x) for x in reductions["pcreg"][s])] for s in sigmas],
                           digits=1) + "\n\n"
          + "### The blur chosen on seven clips, scored on the eighth\n\n")
    loo = leave_one_out(reductions["pcreg"], names)
    md += markdown_table(["clip left out", "blur chosen", "reduction on it %", "without a blur %"],
                         [[c, f"{s:g}", r, r0] for c, s, r, r0 in loo], digits=1)
    md += (f"\n\nMean over the clips left out: {np.mean([r for _, _, r, _ in loo]):.1f}% "
           f"(without a blur {np.mean([r0 for _, _, _, r0 in loo]):.1f}%); worst {min(r for _, _, r, _ in loo):.1f}%.\n")
    report = {"machine": benchlib.machine_info(), "sigmas": sigmas,
              "clips": {c: {"errors": {m: {f"{s:g}": v for s, v in e.items()} for m, e in per_clip[c]["errors"].items()}}
                        for c in names},
              "leave_one_out": [{"clip": c, "chosen": s, "reduction": r, "without": r0} for c, s, r, r0 in loo]}
    benchlib.write_report(args.out, "sweep_smoothing", report, md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
