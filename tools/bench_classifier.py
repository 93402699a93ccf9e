"""Benchmark: per-frame prediction time of pcreg's lookup-table naive Bayes vs scikit-learn's GaussianNB.

Both classify the same 640x480 synthetic frames with the same fitted model (the scikit-learn model is
``clf.to_sklearn()``); the scikit-learn time includes building its (H*W, F) float64 feature matrix,
since that is what a plain ``GaussianNB.predict`` per frame costs. Medians over repeats, measured in
the same run; the ratio is the figure to compare across machines. Also checks that both predict the
same labels.

    python tools/bench_classifier.py --out out/bench [--repeats 30] [--sklearn-repeats 5]

Writes bench_classifier.json, bench_classifier.md and bench_classifier.png to --out.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchlib import machine_info, median_ms, write_report

FEATURE_SETS = ("thesis", "rgb+hsv+row", "rgb+hsv+lab+texture+row")
BUDGET_MS = 10.0


def _median_ms(fn, repeats: int) -> tuple[float, list[float]]:
    fn()  # warm-up (first-call allocations, lazy imports)
    return median_ms(fn, repeats)


def bench(*, repeats: int = 30, sklearn_repeats: int = 5, width: int = 640, height: int = 480,
          seed: int = 0) -> dict:
    """Timings per feature set (milliseconds, medians) and the agreement of the two predictions."""
    from pcreg.classification.bayes import NaiveBayesPixelClassifier, thesis_weight_search
    from pcreg.datasets import synthetic
    from pcreg.classification.features import feature_matrix

    frames = synthetic("syn1b", 12, seed, width=width, height=height)
    train, test = frames[:10], frames[10:]
    imgs, labs = [f.image for f in train], [f.labels for f in train]
    rows = []
    for fs in FEATURE_SETS:
        weights = thesis_weight_search(imgs, labs, seed=seed).weights if "thesis" in fs else None
        t0 = time.perf_counter()
        clf = NaiveBayesPixelClassifier(fs, weights=weights).fit(imgs, labs)
        fit_s = time.perf_counter() - t0
        nb = clf.to_sklearn()
        image = test[0].image
        ours_ms, ours_all = _median_ms(lambda: clf.predict(image), repeats)
        proba_ms, _ = _median_ms(lambda: clf.predict_log_proba(image), max(3, repeats // 5))
        sk_ms, sk_all = _median_ms(lambda: nb.predict(feature_matrix(image, fs, weights=weights)), sklearn_repeats)
        agree = float(np.mean(clf.predict(image).ravel() == nb.predict(feature_matrix(image, fs, weights=weights))))
        rows.append({"features": fs, "weights": weights, "fit_seconds_10_frames": fit_s,
                     "predict_ms": ours_ms, "predict_log_proba_ms": proba_ms, "sklearn_predict_ms": sk_ms,
                     "speedup": sk_ms / ours_ms, "agreement": agree, "within_budget": ours_ms <= BUDGET_MS,
                     "predict_ms_all": ours_all, "sklearn_predict_ms_all": sk_all})
    return {
        "frame": [width, height], "repeats": repeats, "sklearn_repeats": sklearn_repeats, "budget_ms": BUDGET_MS,
        "machine": machine_info(),
        "results": rows,
    }


def write(report: dict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pcreg.outputs import markdown_table

    header = ["features", "pcreg predict (ms)", "pcreg predict_log_proba (ms)", "sklearn GaussianNB.predict (ms)",
              "speed-up", "same labels", f"<= {BUDGET_MS:g} ms"]
    rows = [[r["features"], r["predict_ms"], r["predict_log_proba_ms"], r["sklearn_predict_ms"],
             f"{r['speedup']:.1f}x", f"{100 * r['agreement']:.3f}%", "yes" if r["within_budget"] else "NO"]
            for r in report["results"]]
    text = (f"### Naive Bayes prediction, one {report['frame'][0]}x{report['frame'][1]} frame (medians)\n\n"
            + markdown_table(header, rows))
    fig, ax = plt.subplots(figsize=(7, 3.2))
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r["predict_ms"] for r in report["results"]], 0.4, label="pcreg (lookup tables)")
    ax.barh(y + 0.2, [r["sklearn_predict_ms"] for r in report["results"]], 0.4, label="scikit-learn GaussianNB")
    ax.axvline(BUDGET_MS, color="k", ls="--", lw=1, label=f"{BUDGET_MS:g} ms budget")
    ax.set_yticks(y, [r["features"] for r in report["results"]])
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (median)")
    ax.legend(fontsize=8)
    return write_report(out, "bench_classifier", report, text, fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--sklearn-repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    report = bench(repeats=args.repeats, sklearn_repeats=args.sklearn_repeats, seed=args.seed)
    write(report, Path(args.out))
    print(Path(args.out, "bench_classifier.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
