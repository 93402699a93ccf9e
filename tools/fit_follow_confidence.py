"""Fit the object follower's confidence with one DAVIS sequence left out, and score the one left out.

    python tools/fit_follow_confidence.py --data DAVIS:train --score DAVIS:val

The follower (:class:`pcreg.pipeline.follow.ObjectFollower`, ``pcreg run --follow object``) gives each
label the confidence ``sigmoid(a * |L| + b)`` of its fused log-odds ``L`` at the frame's size (its
``log_odds``). For each sequence, ``a`` and ``b`` are fitted (a logistic regression of "the label is right" on ``|L|``, every pixel
of the scored frames 1 to n-2) on the other sequences, and the sequence left out is scored by its expected
calibration error (:func:`pcreg.experiments.stream_methods.calibration`); the pooled row scores every
pixel with the fit that left its sequence out. The coefficients fitted on every sequence are the ones to
ship (:data:`pcreg.pipeline.follow.CONFIDENCE_SLOPE`, :data:`~pcreg.pipeline.follow.CONFIDENCE_OFFSET`).
The follower's labels do not depend on them, so each sequence runs once.

``--data`` and ``--score`` take what ``--data davis:`` does: a folder of sequences, or an official DAVIS root
with ``:train``, ``:val`` or ``:all`` (its ``ImageSets`` lists; val by default). ``--score``: sequences never
fitted on (DAVIS 2016's val set, where ``--data`` is its train set), each scored by the coefficients fitted on
every sequence of ``--data``, and pooled; a sequence in both is refused. ``--data`` defaults to the shared five,
which alone are too easy to fit on: fitted on them, the confidence predicted 3.13% error where val's 20 made
5.77%, every pixel pooled (docs/results.md, "The confidence").
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402, F401  (puts the checkout on the path)

#: |L| is kept in bins of this width (its largest value is 8: three terms clipped to +-4, weights 0.5, 0.5, 1).
STEP = 0.01
N_BINS = 1000


def record(frames) -> np.ndarray:
    """(2, N_BINS) counts of right (row 0) and wrong (row 1) labels per bin of |L| on the scored frames."""
    from pcreg.classification.davis_measures import scored_frames
    from pcreg.pipeline.follow import ObjectFollower

    follower = ObjectFollower.from_key_frame(frames[0].image, frames[0].labels)
    scored = set(scored_frames(len(frames)))
    counts = np.zeros((2, N_BINS), np.int64)
    for t in range(1, len(frames)):
        labels = follower.step(frames[t].image)
        if t not in scored:
            continue
        assert follower.log_odds is not None
        magnitude = np.abs(follower.log_odds)
        b = np.minimum((magnitude / STEP).astype(np.intp), N_BINS - 1).ravel()
        wrong = ((labels == 1) != (frames[t].labels == 1)).ravel()
        counts[0] += np.bincount(b[~wrong], minlength=N_BINS)
        counts[1] += np.bincount(b[wrong], minlength=N_BINS)
    return counts


def fit(counts: np.ndarray) -> tuple[float, float]:
    """``(a, b)`` of the logistic regression of "right" on |L| (bin centres, weighted by the counts; Newton)."""
    x = (np.arange(N_BINS) + 0.5) * STEP
    right, n = counts[0].astype(np.float64), counts.sum(axis=0).astype(np.float64)
    keep = n > 0
    x, right, n = x[keep], right[keep], n[keep]
    w = np.zeros(2)
    X = np.stack([x, np.ones_like(x)], axis=1)
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-(X @ w)))
        grad = X.T @ (right - n * p)
        hess = (X * (n * p * (1 - p))[:, None]).T @ X + 1e-9 * np.eye(2)
        delta = np.linalg.solve(hess, grad)
        w += delta
        if np.abs(delta).max() < 1e-10:
            break
    return float(w[0]), float(w[1])


def scored(counts: np.ndarray, a: float, b: float) -> np.ndarray:
    """(2, 256) counts at each 8-bit level of the confidence ``sigmoid(a |L| + b)`` (for calibration)."""
    from pcreg.experiments.stream_methods import CONFIDENCE_LEVELS

    x = (np.arange(N_BINS) + 0.5) * STEP
    level = np.rint((CONFIDENCE_LEVELS - 1) / (1.0 + np.exp(-(a * x + b)))).astype(np.intp)
    return np.stack([np.bincount(level, weights=counts[k], minlength=CONFIDENCE_LEVELS) for k in (0, 1)])


def score_on(path: str, a: float, b: float) -> dict:
    """Each sequence at ``path`` and all of them pooled, scored by ``sigmoid(a |L| + b)``: printed, and returned."""
    from pcreg.experiments.stream_methods import calibration

    keys = ("ece", "error", "error_top80")
    rows, pooled = {}, np.zeros((2, 256))
    print("\n| scored, never fitted on | ECE | error % | predicted error % | error % of the 80% most confident |")
    print("|---|---|---|---|---|")
    for name, frames in _load(path).items():
        counts = scored(record(frames), a, b)
        pooled += counts
        rows[name] = {k: calibration(counts)[k] for k in keys} | {"predicted": _predicted(counts)}
    rows["pooled"] = {k: calibration(pooled)[k] for k in keys} | {"predicted": _predicted(pooled)}
    for name, r in rows.items():
        print(f"| {name} | {r['ece']:.4f} | {r['error']:.2f} | {r['predicted']:.2f} | {r['error_top80']:.2f} |")
    return rows


def _load(arg: str) -> dict:
    """The sequences of ``arg``, a folder or ``ROOT:SPLIT`` as ``--data davis:`` takes them."""
    from pcreg.datasets.davis import load_davis
    from pcreg.datasets.davis_splits import parse_davis_arg

    path, split = parse_davis_arg(arg)
    return load_davis(path, split=split)


def _predicted(counts: np.ndarray) -> float:
    """The predicted error % of :func:`scored` counts: the mean of 1 - confidence over their pixels."""
    from pcreg.experiments.stream_methods import CONFIDENCE_LEVELS

    level = np.arange(CONFIDENCE_LEVELS) / (CONFIDENCE_LEVELS - 1)
    n = counts.sum(axis=0)
    return float(100.0 * ((1.0 - level) * n).sum() / n.sum())


def main() -> int:
    from pcreg.experiments.stream_methods import calibration

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", default=str(benchlib.SHARED_DATA / "davis"), help="DAVIS sequences")
    p.add_argument("--score", default=None, help="DAVIS sequences to score the fit on, never fitted on")
    p.add_argument("--out", default=None, help="write the table as JSON here")
    args = p.parse_args()
    data = _load(args.data)
    both = sorted(set(data) & set(_load(args.score))) if args.score else []
    if both:
        p.error(f"--score {args.score} holds sequences --data fits on: {', '.join(both)}")
    counts = {name: record(frames) for name, frames in data.items()}
    rows, pooled = [], np.zeros((2, 256))
    for name in counts:
        a, b = fit(sum(c for n, c in counts.items() if n != name))
        left = scored(counts[name], a, b)
        pooled += left
        cal = calibration(left)
        rows.append({"left_out": name, "a": a, "b": b, "ece": cal["ece"], "error": cal["error"],
                     "error_top80": cal["error_top80"]})
    all_a, all_b = fit(sum(counts.values()))
    result = {"folds": rows, "pooled_left_out": {k: calibration(pooled)[k] for k in ("ece", "error", "error_top80")},
              "shipped": {"a": all_a, "b": all_b},
              "in_sample": {k: calibration(scored(sum(counts.values()), all_a, all_b))[k] for k in ("ece", "error")}}
    print("| left out | a | b | ECE left out | error % | error % of the 80% most confident |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['left_out']} | {r['a']:.3f} | {r['b']:.3f} | {r['ece']:.4f} | {r['error']:.2f} | {r['error_top80']:.2f} |")
    pl = result["pooled_left_out"]
    print(f"| **pooled** | | | **{pl['ece']:.4f}** | {pl['error']:.2f} | {pl['error_top80']:.2f} |")
    print(f"shipped (every sequence of --data): a {all_a:.4f} b {all_b:.4f}; in-sample ECE {result['in_sample']['ece']:.4f}")
    if args.score:
        result["scored"] = score_on(args.score, all_a, all_b)
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
