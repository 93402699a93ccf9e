"""Fit the object follower's confidence with one DAVIS sequence left out, and score the one left out.

    python tools/fit_follow_confidence.py --data DAVIS:train --score DAVIS:val

The follower (:class:`pcreg.pipeline.follow.ObjectFollower`, ``pcreg run --follow object``) gives each label the
confidence ``sigmoid(w . f + b)`` of three features ``f`` of its pixel
(:func:`pcreg.pipeline.follow_confidence.confidence_features`: the fused log-odds' magnitude ``|L|``, the distance to
the labels' edge, and their product). The follower is run over each
sequence once (its labels do not depend on the confidence), and a sample of the pixels of its scored frames (1 to n-2)
is kept: every :data:`SAMPLE`-th pixel of every :data:`SAMPLE`-th row, the grid shifted by one pixel and one row each
frame. For each sequence, ``w`` and ``b`` are fitted (scikit-learn's logistic regression of "the label is right" on
the features) on the other sequences' samples, and the sequence left out is scored on its own sample by its expected
calibration error and the error rate of its most confident 80%
(:func:`pcreg.experiments.stream_methods.calibration`); the pooled row scores every sample with the fit that left its
sequence out. The row "|L| alone" does the same with the first feature alone, the confidence before the features. The
weights fitted on every sequence are the ones to ship
(:data:`~pcreg.pipeline.follow_confidence.CONFIDENCE_WEIGHTS`, :data:`~pcreg.pipeline.follow_confidence.CONFIDENCE_INTERCEPT`).

``--data`` and ``--score`` take what ``--data davis:`` does: a folder of sequences, or an official DAVIS root
with ``:train``, ``:val`` or ``:all`` (its ``ImageSets`` lists; val by default). ``--score``: sequences never
fitted on (DAVIS 2016's val set, where ``--data`` is its train set), each scored by the weights fitted on every
sequence of ``--data``, and pooled; a sequence in both is refused. ``--data`` defaults to the shared five, which
alone are too easy to fit on (docs/results.md, "The confidence"). ``--samples FILE.npz`` keeps the samples of
``--data`` and reads them back in a later run with the same ``--data``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402, F401  (puts the checkout on the path)

#: The sample's stride, in pixels and rows.
SAMPLE = 18
#: The regression's inverse regularisation: large, a plain maximum-likelihood fit on millions of samples.
C = 1e4
#: The fits made and scored, each a title and the columns of the features it takes: ``|L|`` alone (the confidence
#: before the features), and the three features shipped.
MODELS = {"alone": ("|L| alone", [0]), "features": ("the three features", [0, 1, 2])}


def record(frames) -> tuple[np.ndarray, np.ndarray]:
    """``(features, right)``: (n, 3) float32 features and (n,) bool "the label is right" of the sampled pixels of the
    scored frames."""
    from pcreg.classification.davis_measures import scored_frames
    from pcreg.pipeline.follow import ObjectFollower
    from pcreg.pipeline.follow_confidence import CONFIDENCE_FEATURES, confidence_features

    follower = ObjectFollower.from_key_frame(frames[0].image, frames[0].labels)
    scored = set(scored_frames(len(frames)))
    features, right = [], []
    for t in range(1, len(frames)):
        labels = follower.step(frames[t].image)
        if t not in scored:
            continue
        assert follower.log_odds is not None
        at = (slice(t % SAMPLE, None, SAMPLE), slice(t % SAMPLE, None, SAMPLE))
        f = confidence_features(follower.log_odds, labels)
        features.append(f[(slice(None), *at)].reshape(len(f), -1).T)
        right.append(((labels == 1) == (frames[t].labels == 1))[at].ravel())
    if not features:
        return np.zeros((0, len(CONFIDENCE_FEATURES)), np.float32), np.zeros(0, bool)
    return np.concatenate(features), np.concatenate(right)


def fit(features: np.ndarray, right: np.ndarray) -> tuple[list[float], float]:
    """``(w, b)`` of the logistic regression of ``right`` on ``features`` (Newton's method: it converges to the
    maximum, where L-BFGS, stopped by its tolerance, left 7 of 30 folds of a fit of five features short of it)."""
    from sklearn.linear_model import LogisticRegression

    model = LogisticRegression(C=C, solver="newton-cholesky").fit(features.astype(np.float64), right)
    return [float(v) for v in model.coef_[0]], float(model.intercept_[0])


def scored(features: np.ndarray, right: np.ndarray, w, b: float) -> np.ndarray:
    """(2, 256) counts of right (row 0) and wrong (row 1) samples at each 8-bit level of ``sigmoid(w . f + b)``."""
    from pcreg.experiments.stream_methods import CONFIDENCE_LEVELS

    confidence = 1.0 / (1.0 + np.exp(-(features.astype(np.float64) @ np.asarray(w) + b)))
    level = np.rint((CONFIDENCE_LEVELS - 1) * confidence).astype(np.intp)
    return np.stack([np.bincount(level[right], minlength=CONFIDENCE_LEVELS),
                     np.bincount(level[~right], minlength=CONFIDENCE_LEVELS)])


def _row(counts: np.ndarray) -> dict:
    from pcreg.experiments.stream_methods import calibration

    cal = calibration(counts)
    if not cal.get("pixels"):  # a sequence too short to have a scored frame
        return {"ece": float("nan"), "error": float("nan"), "error_top80": float("nan"), "top80_share": float("nan")}
    return {"ece": cal["ece"], "error": cal["error"], "error_top80": cal["error_top80"],
            "top80_share": cal["error_top80"] / cal["error"] if cal["error"] else 0.0}


def left_out(samples: dict, columns: list[int]) -> tuple[list[dict], dict]:
    """Each sequence scored by the fit on the others (the features ``columns``), and every sample pooled."""
    rows, pooled = [], 0
    for name, (x, y) in samples.items():
        rest = [v for n, v in samples.items() if n != name]
        if len({bool(v) for _, r in rest for v in np.unique(r)}) < 2:
            raise SystemExit(f"fit_follow_confidence: with {name} left out, the other sequences' sampled labels are all "
                             "right (or all wrong): nothing to fit")
        w, b = fit(np.concatenate([v[0] for v in rest])[:, columns], np.concatenate([v[1] for v in rest]))
        counts = scored(x[:, columns], y, w, b)
        pooled = pooled + counts
        rows.append({"left_out": name, "w": w, "b": b, **_row(counts)})
    return rows, _row(pooled)


def _sequences(arg: str) -> dict:
    """``{name: (frames folder, masks folder)}`` of ``arg``, a folder or ``ROOT:SPLIT`` as ``--data davis:`` takes
    them (a folder of none, or none at all, ends the tool with its message)."""
    from pcreg.datasets.davis import find_sequences
    from pcreg.datasets.davis_splits import parse_davis_arg
    from pcreg.errors import PcregError

    try:
        path, split = parse_davis_arg(arg)
        return find_sequences(path, split=split)[0]
    except PcregError as e:
        raise SystemExit(f"fit_follow_confidence: {e}") from None


def _key(arg: str) -> str:
    """What the samples of ``arg`` are kept under: its folder resolved, and its split."""
    from pcreg.datasets.davis_splits import parse_davis_arg

    path, split = parse_davis_arg(arg)
    return f"{Path(path).resolve()}:{split}"


def _samples(arg: str, keep: str | None) -> dict:
    """``{sequence: (features, right)}`` of ``arg``, read from ``keep`` where it holds them."""
    import zipfile

    if keep and not keep.endswith(".npz"):  # numpy adds the suffix when it writes
        keep += ".npz"
    if keep and Path(keep).is_file():
        try:
            with np.load(keep) as z:
                kept = str(z["data"])
                if kept == _key(arg):
                    names = [str(n) for n in z["names"]]
                    return {n: (z[f"x_{i}"], z[f"y_{i}"]) for i, n in enumerate(names)}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
            raise SystemExit(f"fit_follow_confidence: {keep} holds no samples this tool kept ({e}); remove it, or name "
                             "another file") from None
        raise SystemExit(f"fit_follow_confidence: {keep} holds the samples of {kept}, not of {_key(arg)}: name another "
                         "file, or remove it")
    from tqdm import tqdm

    from pcreg.datasets.davis import load_objects
    from pcreg.errors import PcregError

    samples = {}
    for name, (frames, masks) in tqdm(_sequences(arg).items(), desc="sequences", unit="seq"):
        try:  # one sequence in memory at a time
            clips = load_objects(frames, masks, name=name)
        except PcregError as e:
            raise SystemExit(f"fit_follow_confidence: {e}") from None
        for clip, clip_frames in clips.items():
            samples[clip] = record(clip_frames)
            if not len(samples[clip][1]):
                print(f"{clip}: {len(clip_frames)} frames, none of them scored (1 to n-2): left out", file=sys.stderr)
                del samples[clip]
    if keep:
        arrays = {f"x_{i}": v[0] for i, v in enumerate(samples.values())} | {f"y_{i}": v[1] for i, v in enumerate(samples.values())}
        with open(f"{keep}.part", "wb") as f:  # whole or not at all: a stopped run leaves no half-written samples
            np.savez(f, data=_key(arg), names=np.array(list(samples)), **arrays)
        os.replace(f"{keep}.part", keep)
    return samples


def _table(title: str, rows: list[dict], pooled: dict) -> None:
    print(f"\n{title}\n\n| left out | ECE | error % | error % of the 80% most confident | its share |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['left_out']} | {r['ece']:.4f} | {r['error']:.2f} | {r['error_top80']:.2f} | {r['top80_share']:.3f} |")
    print(f"| **pooled** | **{pooled['ece']:.4f}** | {pooled['error']:.2f} | {pooled['error_top80']:.2f} | "
          f"**{pooled['top80_share']:.3f}** |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", default=str(benchlib.SHARED_DATA / "davis"), help="DAVIS sequences to fit on")
    p.add_argument("--score", default=None, help="DAVIS sequences to score the fit on, never fitted on")
    p.add_argument("--samples", default=None, help="keep the samples of --data in this .npz, and read them back")
    p.add_argument("--out", default=None, help="write the tables as JSON here")
    args = p.parse_args()
    for option, path in (("--samples", args.samples), ("--out", args.out)):  # said now, not after the follower ran
        if path and (Path(path).is_dir() or not Path(path).resolve().parent.is_dir()):
            p.error(f"{option} {path}: " + ("a folder, not a file" if Path(path).is_dir() else "its folder does not exist"))
    both = sorted(set(_sequences(args.data)) & set(_sequences(args.score))) if args.score else []
    if both:
        p.error(f"--score {args.score} holds sequences --data fits on: {', '.join(both)}")
    samples = _samples(args.data, args.samples)
    if len(samples) < 2 or len({bool(v) for _, y in samples.values() for v in np.unique(y)}) < 2:
        p.error(f"--data {args.data}: a fit with one sequence left out needs two sequences or more, and labels both "
                "right and wrong among their samples")
    result = {}
    for key, (title, columns) in MODELS.items():
        rows, pooled = left_out(samples, columns)
        _table(title, rows, pooled)
        w, b = fit(np.concatenate([v[0] for v in samples.values()])[:, columns],
                   np.concatenate([v[1] for v in samples.values()]))
        result[key] = {"folds": rows, "pooled_left_out": pooled, "shipped": {"w": w, "b": b}}
        print(f"fitted on every sequence of --data: w {', '.join(f'{v:.3f}' for v in w)}, b {b:.3f}")
    if args.score:
        scores = _samples(args.score, None)
        for key, (title, columns) in MODELS.items():
            fitted = result[key]["shipped"]
            rows = [{"left_out": n, **_row(scored(x[:, columns], y, fitted["w"], fitted["b"]))} for n, (x, y) in scores.items()]
            pooled = _row(sum(scored(x[:, columns], y, fitted["w"], fitted["b"]) for x, y in scores.values()))
            _table(f"scored, never fitted on ({title})", rows, pooled)
            result[key]["scored"] = {"rows": rows, "pooled": pooled}
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
