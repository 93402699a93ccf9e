"""Choose the stream's trust constants with one clip left out, for each clip, and score the clip left out.

    python tools/fit_trust.py --data camvid:../shared/data/camvid --out out/fit_trust

Three choices, each made on all clips but one and scored on that one (the table per clip is what
docs/results.md shows):

1. **The trust rule** (:class:`pcreg.pipeline.trust.TrustRule`: ``dense``, ``flow``, ``residual``), from a
   grid, by the mean reduction of plain naive Bayes' error over the other clips; no learning.
2. **The learning** (:class:`pcreg.pipeline.learning.Learning`: ``share``, ``decay``, ``sure``), from a
   grid, the same way, with the trust rule as pcreg ships it.
3. **The confidence's coefficients** (:data:`pcreg.pipeline.trust.CONFIDENCE_COEFFICIENTS`): a logistic
   regression of "the label is right" on :func:`pcreg.pipeline.trust.confidence_features`, fitted on
   the other clips' pixels; the clip left out is scored by its expected calibration error and by the
   error of its most confident 80% of pixels against the error of all. The coefficients fitted on every
   clip are the ones to ship.

Each clip's first frame is its key frame. Every map is kept at one pixel in ``--stride`` along each axis
(all pixels are scored the same way, so this estimates each clip's error); the propagator's
registrations run once per clip, with the shipped rule, and each grid point re-weighs what they carried.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402  (puts the checkout on the path)

RULE_GRID = {"dense": (1.0, 1.5, 2.0, 3.0), "flow": (0.5, 1.0, 1.5, 2.0), "residual": (20.0, 40.0, 80.0, 1e6)}
LEARNING_GRID = {"share": (0.25, 0.5, 1.0), "decay": (0.0, 0.5, 0.9), "sure": (2.0, 4.0, 8.0)}


def record(frames, stride: int) -> list[dict]:
    """Run the shipped propagator (no learning) over a clip and keep, per frame, what a rule needs."""
    import pcreg

    key = frames[0]
    prop = pcreg.Propagator.from_key_frame(key.image, key.labels, learning=None)
    rows = []
    for f in frames[1:]:
        prop.step(f.image)
        m = prop.last.trust
        s = (slice(None, None, stride), slice(None, None, stride))
        rows.append({"image": f.image, "truth": f.labels[s], "d": prop.last.log_odds[s],
                     **{k: None if getattr(m, k) is None else np.asarray(getattr(m, k))[s]
                        for k in ("primary_prior", "primary_residual", "confidence", "second_prior", "second_residual")}})
    return rows


def error(fused: np.ndarray, truth: np.ndarray) -> float:
    known = truth < 2
    return 100.0 * float(np.count_nonzero((fused[known] > 0) != (truth[known] == 1))) / max(1, int(known.sum()))


def rule_errors(rows: list[dict], rule, learning=None, classifier=None) -> tuple[float, float]:
    """(plain's mean error, the rule's mean error) over a clip's frames, learning as it goes if asked."""
    from pcreg.pipeline.learning import Learner, Learning
    from pcreg.pipeline.trust import trust_maps

    learner = None if learning is None else Learner(classifier, Learning(learning.share, learning.decay,
                                                                         learning.sure, stride=1))
    plain, fused = [], []
    for r in rows:
        d = r["d"]
        if learner is not None:
            stride = r["image"].shape[0] // d.shape[0] if d.shape[0] else 1
            d = learner.classifier.decision_function(r["image"])[::stride, ::stride][:d.shape[0], :d.shape[1]]
        maps = trust_maps(rule, weight=2.0, primary_prior=r["primary_prior"], primary_residual=r["primary_residual"],
                          confidence=r["confidence"], second_prior=r["second_prior"], second_residual=r["second_residual"])
        prior = maps.prior_term(d.shape)
        F = d + prior
        plain.append(error(r["d"], r["truth"]))
        fused.append(error(F, r["truth"]))
        if learner is not None:
            small = r["image"][::stride, ::stride][:d.shape[0], :d.shape[1]]
            learner.update(np.ascontiguousarray(small), F, prior)
    return float(np.mean(plain)), float(np.mean(fused))


def leave_one_out(names: list[str], table: np.ndarray, grid: list[dict]) -> list[dict]:
    """table (grid points, clips) of reductions; per clip the grid point best on the others, and its score."""
    out = []
    for j, name in enumerate(names):
        others = [i for i in range(len(names)) if i != j]
        best = int(np.argmax(table[:, others].mean(axis=1)))
        out.append({"clip": name, "chosen": grid[best], "reduction": float(table[best, j])})
    return out


def grid_points(grid: dict) -> list[dict]:
    return [dict(zip(grid, values)) for values in itertools.product(*grid.values())]


def choose_rule(clips: dict) -> dict:
    from pcreg.pipeline.trust import TrustRule

    names, points = list(clips), grid_points(RULE_GRID)
    table = np.array([[_reduction(*rule_errors(clips[n], TrustRule(**p))) for n in names] for p in points])
    return {"grid": RULE_GRID, "loo": leave_one_out(names, table, points),
            "all": points[int(np.argmax(table.mean(axis=1)))], "all_reduction": float(table.mean(axis=1).max())}


def choose_learning(clips: dict, classifiers: dict) -> dict:
    from pcreg.pipeline.learning import Learning
    from pcreg.pipeline.trust import STREAM_TRUST

    names, points = list(clips), grid_points(LEARNING_GRID)
    none = {n: _reduction(*rule_errors(clips[n], STREAM_TRUST)) for n in names}
    table = np.array([[_reduction(*rule_errors(clips[n], STREAM_TRUST, Learning(**p), classifiers[n])) for n in names]
                      for p in points])
    return {"grid": LEARNING_GRID, "loo": leave_one_out(names, table, points), "without": none,
            "all": points[int(np.argmax(table.mean(axis=1)))]}


def _reduction(plain: float, value: float) -> float:
    return 100.0 * (plain - value) / plain if plain else float("nan")


def confidence_samples(frames, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """The shipped propagator over a clip: (features (N, 4), right (N,)) at its known pixels."""
    import pcreg
    from pcreg.pipeline.trust import confidence_features

    key = frames[0]
    prop = pcreg.Propagator.from_key_frame(key.image, key.labels)
    X, y = [], []
    for f in frames[1:]:
        labels = prop.step(f.image)
        d = prop.last.log_odds
        prior = prop.last.trust.prior_term(labels.shape)
        fused = d + prior
        feats = confidence_features(fused, d, prior)
        s = (slice(None, None, stride), slice(None, None, stride))
        known = f.labels[s] < 2
        X.append(np.stack([q[s][known] for q in feats], axis=1))
        y.append(((labels[s] == 1) == (f.labels[s] == 1))[known])
    return np.concatenate(X), np.concatenate(y)


def calibration_of(p: np.ndarray, right: np.ndarray) -> dict:
    bins = np.minimum((p * 10).astype(int), 9)
    ece = sum(float((bins == b).mean()) * abs(float(right[bins == b].mean()) - float(p[bins == b].mean()))
              for b in range(10) if (bins == b).any())
    order = np.argsort(-p, kind="stable")
    top = order[: int(0.8 * len(p))]
    wrong = ~right
    return {"ece": ece, "error": 100.0 * float(wrong.mean()), "error_top80": 100.0 * float(wrong[top].mean()),
            "ratio": float(wrong[top].mean() / wrong.mean()) if wrong.any() else float("nan")}


def fit_confidence(samples: dict) -> dict:
    """The logistic coefficients, each clip left out and scored with :data:`~pcreg.pipeline.trust.MIN_CONFIDENCE`
    as the confidence ships, and fitted on every clip."""
    from sklearn.linear_model import LogisticRegression

    from pcreg.pipeline.trust import MIN_CONFIDENCE

    def fit(names):
        X = np.concatenate([samples[n][0] for n in names])
        y = np.concatenate([samples[n][1] for n in names])
        m = LogisticRegression(max_iter=1000).fit(X, y)
        return m, [float(m.intercept_[0]), *map(float, m.coef_[0])]

    loo, ps, ys = [], [], []
    for n in samples:
        m, coef = fit([o for o in samples if o != n])
        p = np.maximum(m.predict_proba(samples[n][0])[:, 1], MIN_CONFIDENCE)
        loo.append({"clip": n, "coefficients": coef, **calibration_of(p, samples[n][1])})
        ps.append(p)
        ys.append(samples[n][1])
    _, coef = fit(list(samples))
    return {"loo": loo, "pooled": calibration_of(np.concatenate(ps), np.concatenate(ys)), "coefficients": coef}


def markdown(doc: dict) -> str:
    lines = ["### The trust rule, each clip left out\n", "| clip left out | dense | flow | residual | reduction on it (%) |",
             "|---|---|---|---|---|"]
    for r in doc["rule"]["loo"]:
        c = r["chosen"]
        lines.append(f"| {r['clip']} | {c['dense']:g} | {c['flow']:g} | {c['residual']:g} | {r['reduction']:.1f} |")
    lines.append(f"| mean | | | | {np.mean([r['reduction'] for r in doc['rule']['loo']]):.1f} |")
    lines += ["\n### Learning from the stream, each clip left out\n",
              "| clip left out | share | decay | sure | reduction on it (%) | without learning (%) |", "|---|---|---|---|---|---|"]
    for r in doc["learning"]["loo"]:
        c = r["chosen"]
        lines.append(f"| {r['clip']} | {c['share']:g} | {c['decay']:g} | {c['sure']:g} | {r['reduction']:.1f} | "
                     f"{doc['learning']['without'][r['clip']]:.1f} |")
    lines.append(f"| mean | | | | {np.mean([r['reduction'] for r in doc['learning']['loo']]):.1f} | "
                 f"{np.mean(list(doc['learning']['without'].values())):.1f} |")
    lines += ["\n### The confidence, each clip left out\n",
              "| clip left out | coefficients (intercept, log1p abs F, purity 15, purity 33, agreement 33) | ECE | "
              "error % | error % of the most confident 80% | ratio |", "|---|---|---|---|---|---|"]
    for r in doc["confidence"]["loo"]:
        coef = ", ".join(f"{c:.3f}" for c in r["coefficients"])
        lines.append(f"| {r['clip']} | {coef} | {r['ece']:.4f} | {r['error']:.2f} | {r['error_top80']:.2f} | "
                     f"{r['ratio']:.3f} |")
    p = doc["confidence"]["pooled"]
    lines.append(f"| all, pooled | {', '.join(f'{c:.3f}' for c in doc['confidence']['coefficients'])} (fitted on all) | "
                 f"{p['ece']:.4f} | {p['error']:.2f} | {p['error_top80']:.2f} | {p['ratio']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from pcreg.classification.bayes import fit_classifier
    from pcreg.datasets import load_dataset

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=f"camvid:{benchlib.SHARED_DATA / 'camvid'}")
    ap.add_argument("--stride", type=int, default=3, help="keep one pixel in STRIDE along each axis (default 3)")
    ap.add_argument("--out", default="out/fit_trust")
    args = ap.parse_args(argv)
    clips = load_dataset(args.data)
    recorded = {n: record(f, args.stride) for n, f in clips.items()}
    classifiers = {n: fit_classifier([f[0]]) for n, f in clips.items()}
    doc = {"rule": choose_rule(recorded), "learning": choose_learning(recorded, classifiers)}
    doc["confidence"] = fit_confidence({n: confidence_samples(f, args.stride) for n, f in clips.items()})
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_trust.json").write_text(json.dumps(doc, indent=1))
    (out / "fit_trust.md").write_text(markdown(doc))
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
