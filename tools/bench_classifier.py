"""Benchmark: per-frame prediction time of pcreg's lookup-table naive Bayes vs scikit-learn's GaussianNB.

Both classify the same 640x480 synthetic frames with the same fitted model (the scikit-learn model is
``clf.to_sklearn()``); the scikit-learn time includes building its (H*W, F) float64 feature matrix,
since that is what a plain ``GaussianNB.predict`` per frame costs. Medians over repeats, measured in
the same run; the ratio is the figure to compare across machines. Also checks that both predict the
same labels.

Then the cost of classes: fitting (histograms and parameters) and scoring every class
(``class_scores``, ``log_posteriors``) with two classes (lagr) and eleven (camvid11), at 640x480, on a
shared CamVid clip's frames resized there (nearest-neighbour labels; synthetic blocks of colour when
``../shared/data`` is absent), with the peak of memory each allocates (``tracemalloc``, which sees NumPy's
arrays). Timings are medians within one run; compare the ratios.

    python tools/bench_classifier.py --out out/bench [--repeats 30] [--sklearn-repeats 5] [--class-repeats 15]

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
CAMVID = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "camvid" / "0016E5"  # all eleven classes
CLASS_FEATURES = "rgb+hsv+row"


def _median_ms(fn, repeats: int) -> tuple[float, list[float]]:
    fn()  # warm-up (first-call allocations, lazy imports)
    return median_ms(fn, repeats)


def bench(*, repeats: int = 30, sklearn_repeats: int = 5, width: int = 640, height: int = 480,
          seed: int = 0) -> dict:
    """Timings per feature set (milliseconds, medians) and the agreement of the two predictions."""
    from pcreg.classification.bayes import NaiveBayesPixelClassifier
    from pcreg.classification.weight_search import thesis_weight_search
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


def _class_frames(width: int, height: int, n: int = 3) -> tuple[list, list, str]:
    """``n`` (image, CamVid class ids) pairs at width x height, and where they come from."""
    import cv2

    from pcreg.classes import CAMVID11, read_label_png

    if (CAMVID / "labels").is_dir():
        names = sorted(p.name for p in (CAMVID / "labels").glob("*.png"))[:n]
        images = [cv2.resize(cv2.imread(str(CAMVID / "images" / m))[:, :, ::-1], (width, height),
                             interpolation=cv2.INTER_LINEAR) for m in names]
        labels = [cv2.resize(read_label_png(CAMVID / "labels" / m, CAMVID11), (width, height),
                             interpolation=cv2.INTER_NEAREST) for m in names]
        return images, labels, f"{CAMVID.name} {names[0]}..{names[-1]}"
    rng = np.random.default_rng(0)
    labels = [np.broadcast_to((np.arange(width) * 12 // width).astype(np.uint8), (height, width)).copy()
              for _ in range(n)]
    images = [np.clip(rng.integers(20, 235, (12, 3))[lab] + rng.normal(0, 12, (height, width, 3)), 0, 255)
              .astype(np.uint8) for lab in labels]
    return images, labels, "synthetic blocks (../shared/data absent)"


def _peak_mib(fn) -> float:
    import tracemalloc

    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def bench_classes(*, repeats: int = 15, width: int = 640, height: int = 480) -> dict:
    """Fit and per-class scoring at two classes (CamVid's ids mapped to lagr) and at eleven (camvid11)."""
    from pcreg.classes import CAMVID11, LAGR
    from pcreg.classification.bayes import NaiveBayesPixelClassifier
    from pcreg.datasets.folder import CAMVID_MAPPING, mapping_lut

    images, ids, source = _class_frames(width, height)
    lagr = [mapping_lut(CAMVID_MAPPING)[lab] for lab in ids]
    train, test = slice(0, 2), images[2]
    rows = []
    for table, labels in ((LAGR, lagr), (CAMVID11, ids)):
        def fit():
            return NaiveBayesPixelClassifier(CLASS_FEATURES, classes=table).fit(images[train], labels[train])

        clf = fit()
        groups = clf.feature_groups(test)
        row = {"table": table.source, "K": len(clf.classes_), "fit_ms": _median_ms(fit, max(3, repeats // 3))[0],
               "fit_peak_mib": _peak_mib(fit),
               "features_ms": _median_ms(lambda: clf.feature_groups(test), repeats)[0],
               "class_scores_ms": _median_ms(lambda: clf.class_scores(test, groups=groups), repeats)[0],
               "log_posteriors_ms": _median_ms(lambda: clf.log_posteriors(test, groups=groups), repeats)[0],
               "predict_ms": _median_ms(lambda: clf.predict(test), repeats)[0],
               "scores_peak_mib": _peak_mib(lambda: clf.log_posteriors(test, groups=groups))}
        if len(clf.classes_) == 2:
            row["decision_function_ms"] = _median_ms(lambda: clf.decision_function(test, groups=groups), repeats)[0]
        rows.append(row)
    return {"frame": [width, height], "features": CLASS_FEATURES, "source": source, "repeats": repeats,
            "results": rows, "ratio_11_to_2": {k: rows[1][k] / rows[0][k] for k in
                                               ("fit_ms", "class_scores_ms", "log_posteriors_ms", "predict_ms",
                                                "fit_peak_mib", "scores_peak_mib")}}


def _classes_text(c: dict) -> str:
    from pcreg.outputs import markdown_table

    header = ["table", "K", "fit 2 frames (ms)", "fit peak (MiB)", "features (ms)", "class_scores (ms)",
              "log_posteriors (ms)", "predict (ms)", "decision_function (ms)", "scoring peak (MiB)"]
    rows = [[r["table"], r["K"], r["fit_ms"], r["fit_peak_mib"], r["features_ms"], r["class_scores_ms"],
             r["log_posteriors_ms"], r["predict_ms"], r.get("decision_function_ms", "-"), r["scores_peak_mib"]]
            for r in c["results"]]
    ratio = ", ".join(f"{k} {v:.2f}x" for k, v in c["ratio_11_to_2"].items())
    return (f"\n\n### Classes: two (lagr) and eleven (camvid11), one {c['frame'][0]}x{c['frame'][1]} frame, "
            f"features {c['features']} (medians; {c['source']})\n\n" + markdown_table(header, rows)
            + f"\n\nEleven classes against two: {ratio}.\n")


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
    if "classes" in report:
        text += _classes_text(report["classes"])
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
    parser.add_argument("--class-repeats", type=int, default=15)
    args = parser.parse_args(argv)
    report = bench(repeats=args.repeats, sklearn_repeats=args.sklearn_repeats, seed=args.seed)
    report["classes"] = bench_classes(repeats=args.class_repeats)
    write(report, Path(args.out))
    print(Path(args.out, "bench_classifier.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
