"""Thesis Ch. 4: naive Bayes terrain classification alone (cases I, II, III and the weight search).

- Table 4.1: per dataset, the thesis feature's weights (w_r, w_g, w_b) from 30 random trials, lowest
  training error on all of its frames.
- Case I: per dataset, train on the first k frames (k = 10, 20, ..., 90 of 100; 10%..90% of shorter
  or longer sequences), test on the remaining frames.
- Case II: train on all frames of one dataset, test on all frames of every dataset.
- Case III: train on the first k frames of every dataset (k = 10 and 20 of 100), test on all frames.

Each (case, feature set, training set) is one unit of work, run through an executor (``--workers``).
Error rates are pooled over the test pixels (unknown truth left out) and given in percent.
Finished units are kept in ``OUT/units/`` and skipped when the same command is run again.
Outputs in ``--out``: results.json, config.json, table41_weights / case1 / case2 / case3 as .csv and
.md, and case1.png, case2.png, case3.png.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar
from pathlib import Path

from ..classification.features import DEFAULT_FEATURES
from .results import Results

CASES = ("I", "II", "III")
DEFAULT_FEATURE_SETS = ("thesis", "+".join(DEFAULT_FEATURES))
CASE1_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
CASE3_FRACTIONS = (0.1, 0.2)
OUTPUT_FILES = (
    "results.json", "config.json",
    "table41_weights.csv", "table41_weights.md",
    "case1.csv", "case1.md", "case1.png",
    "case2.csv", "case2.md", "case2.png",
    "case3.csv", "case3.md", "case3.png",
)


@dataclass(frozen=True)
class ClassificationConfig:
    """Everything needed to rerun ``pcreg evaluate classification`` (written as config.json).

    data : a ``--data`` value (see :func:`pcreg.datasets.load_dataset`).
    cases : subset of ("I", "II", "III").
    features : feature sets, each ``"+"``-joined names of :mod:`pcreg.classification.features`; ``"thesis"`` uses the
        weights found by the 30-trial search on each training set.
    case1_k, case3_k : explicit training-frame counts (per dataset); empty = fractions of its length.
    case1_fractions, case3_fractions : the default k as fractions of each sequence's length.
    n_trials : weight-search trials. seed : seed of the weight search and of synthetic data.
    frames : frames per synthetic sequence (default 100) / first frames of real sequences (default all).
    size : (width, height) of synthetic frames (default 640x480).
    exclude_unknown : leave unknown pixels out of training and scoring.
    """

    report: ClassVar[str] = "classification"  #: its report's name (:data:`~.reports.files.REPORT_NAMES`)

    data: str = "synthetic"
    cases: tuple[str, ...] = CASES
    features: tuple[str, ...] = DEFAULT_FEATURE_SETS
    case1_k: tuple[int, ...] = ()
    case3_k: tuple[int, ...] = ()
    case1_fractions: tuple[float, ...] = CASE1_FRACTIONS
    case3_fractions: tuple[float, ...] = CASE3_FRACTIONS
    n_trials: int = 30
    seed: int = 0
    frames: int | None = None
    size: tuple[int, int] | None = None
    exclude_unknown: bool = True


# ---------------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------------

def check_datasets(datasets: dict, *, exclude_unknown: bool = True) -> dict:
    """Per dataset: frames, size, class fractions; DatasetError for unlabelled or one-class data."""
    import numpy as np

    from ..errors import DatasetError

    if not datasets:
        raise DatasetError("no datasets to evaluate")
    info = {}
    for name, frames in datasets.items():
        if not frames:
            raise DatasetError(f"dataset {name}: no frames")
        unlabelled = [f.name for f in frames if f.labels is None]
        if unlabelled:
            raise DatasetError(f"dataset {name}: frame {unlabelled[0]} has no labels (classification needs labelled frames)")
        counts = np.zeros(3, dtype=np.int64)
        for f in frames:
            counts += np.bincount(f.labels.reshape(-1), minlength=3)[:3]
        scored = counts[:2] if exclude_unknown else counts
        if np.count_nonzero(scored) < 2:
            only = "ground" if counts[0] else "obstacle" if counts[1] else "unknown"
            raise DatasetError(f"dataset {name} has one class only ({only}); classification needs ground and obstacle pixels")
        h, w = frames[0].shape
        info[name] = {"frames": len(frames), "width": w, "height": h,
                      "fraction": {"ground": counts[0] / counts.sum(), "obstacle": counts[1] / counts.sum(),
                                   "unknown": counts[2] / counts.sum()}}
    return info


def resolve_k(n: int, explicit: tuple[int, ...], fractions: tuple[float, ...], *, dataset: str, case: str,
              need_test: bool) -> list[int]:
    """Training-frame counts for one sequence of ``n`` frames (explicit counts, else fractions of n)."""
    from ..errors import DatasetError

    if need_test and n < 2:  # k = 0 would train on no frame
        raise DatasetError(f"dataset {dataset} has {n} frame(s): Case {case} trains on its first frames and tests on "
                           "the rest, which needs at least 2 (leave it out with --cases, or give more frames)")
    if explicit:
        ks = list(explicit)
    else:
        ks = sorted({min(max(1, int(round(f * n))), n - 1 if need_test else n) for f in fractions})
    for k in ks:
        if k > n or (need_test and k >= n):
            why = "it needs at least one test frame" if need_test else "it trains on k frames of each"
            raise DatasetError(f"k={k} is larger than dataset {dataset} ({n} frames; Case {case}: {why})")
    return ks


def _unit(key: str, case: str, features: str, train: tuple, test: tuple, result_key: tuple,
          config: ClassificationConfig):
    from .units import Unit

    return Unit(key, train[0][0] if len(train) == 1 else "", (("case", case), ("features", features), ("train", train),
                                                              ("test", test), ("result_key", result_key)), config)


def plan_units(config: ClassificationConfig, lengths: dict[str, int]) -> tuple[list, dict]:
    """All units of the configured cases, and the k values chosen per dataset. A unit fits on its
    ``train`` frame ranges ((dataset, start, stop), ...) and scores on each of its ``test`` ranges."""
    names = list(lengths)
    units: list = []
    ks: dict = {}
    if "I" in config.cases:
        ks["I"] = {d: resolve_k(n, config.case1_k, config.case1_fractions, dataset=d, case="I", need_test=True)
                   for d, n in lengths.items()}
    if "III" in config.cases:
        if config.case3_k:
            ks["III"] = {d: resolve_k(n, config.case3_k, (), dataset=d, case="III", need_test=False)
                         for d, n in lengths.items()}
        else:  # a level per fraction, each dataset's k that fraction of its length; levels alike everywhere run once
            levels: list[dict[str, int]] = []
            for f in config.case3_fractions:
                level = {d: resolve_k(n, (), (f,), dataset=d, case="III", need_test=False)[0] for d, n in lengths.items()}
                if level not in levels:
                    levels.append(level)
            ks["III"] = {d: [level[d] for level in levels] for d in lengths}
    everything = tuple((d, 0, lengths[d]) for d in names)
    for fs in config.features:
        if "I" in config.cases:
            for d in names:
                for k in ks["I"][d]:
                    units.append(_unit(f"I/{fs}/{d}_k{k}", "I", fs, ((d, 0, k),), ((d, k, lengths[d]),), (fs, d, k),
                                       config))
        if "II" in config.cases:
            for d in names:
                units.append(_unit(f"II/{fs}/{d}", "II", fs, ((d, 0, lengths[d]),), everything, (fs, d), config))
        if "III" in config.cases:
            for i in range(len(next(iter(ks["III"].values())))):
                train = tuple((d, 0, ks["III"][d][i]) for d in names)
                units.append(_unit(f"III/{fs}/split{i}", "III", fs, train, everything, (fs, i), config))
    return units, ks


# ---------------------------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------------------------

def _frames(datasets: dict, ranges) -> list:
    return [f for d, a, b in ranges for f in datasets[d][a:b]]


def run_unit(unit) -> dict:
    """Fit one classifier and score it: a pure function of ``unit`` (data loaded or taken from the
    per-process cache). Returns JSON-ready numbers."""
    import numpy as np

    from ..classification.bayes import NaiveBayesPixelClassifier
    from ..classification.weight_search import thesis_weight_search
    from ..classification.features import parse_features
    from ..classification.metrics import confusion_matrix, error_from_confusion

    from .units import load_cached

    cfg = unit.config
    t0 = time.perf_counter()
    datasets = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)
    train = _frames(datasets, unit.train)
    images = [f.image for f in train]
    labels = [f.labels for f in train]
    feats = parse_features(unit.features)
    weights = None
    search = None
    if "thesis" in feats:
        search = thesis_weight_search(images, labels, n_trials=cfg.n_trials, seed=cfg.seed,
                                      exclude_unknown=cfg.exclude_unknown)
        weights = search.weights
    clf = NaiveBayesPixelClassifier(feats, weights=weights, exclude_unknown=cfg.exclude_unknown).fit(images, labels)
    t_fit = time.perf_counter() - t0
    per_test = []
    total = np.zeros((3, 3), dtype=np.int64)
    for d, a, b in unit.test:
        conf = np.zeros((3, 3), dtype=np.int64)
        frame_errors = []
        for f in datasets[d][a:b]:
            c = confusion_matrix(clf.predict(f.image), f.labels, exclude_unknown=cfg.exclude_unknown)
            conf += c
            frame_errors.append(error_from_confusion(c))
        total += conf
        scored = [e for e in frame_errors if not np.isnan(e)]
        per_test.append({"dataset": d, "frames": [a, b], "error": error_from_confusion(conf),
                         "mean_frame_error": float(np.mean(scored)) if scored else float("nan"),
                         "frame_errors": frame_errors, "confusion": conf.tolist()})
    if unit.test and not total.any():  # a table of NaN is no result
        from ..errors import DatasetError

        raise DatasetError(f"{cfg.data}: case {unit.case}: the truth of every frame it tests is all unknown (frames "
                           f"{', '.join(f'{a}-{b - 1} of {d}' for d, a, b in unit.test)}): nothing to score")
    return {
        "case": unit.case, "features": unit.features, "key": list(unit.result_key),
        "train": [list(r) for r in unit.train], "train_frames": len(train),
        "weights": None if weights is None else list(weights),
        "weight_search": None if search is None else search.to_dict(),
        "training_error": clf.score_error(images, labels) if unit.case == "II" else None,
        "error": error_from_confusion(total), "confusion": total.tolist(), "tests": per_test,
        "theta": clf.theta_.tolist(), "var": clf.var_.tolist(), "classes": clf.classes_.tolist(),
        "class_prior": clf.class_prior_.tolist(), "feature_names": list(clf.feature_names_),
        "seconds": {"fit": t_fit, "total": time.perf_counter() - t0},
    }


def run_weight_search(unit) -> dict:
    """Table 4.1 row: the 30-trial weight search on all frames of one dataset (``unit.dataset``)."""
    from ..classification.weight_search import thesis_weight_search
    from .units import load_cached

    cfg = unit.config
    fr = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset]
    s = thesis_weight_search([f.image for f in fr], [f.labels for f in fr], n_trials=cfg.n_trials, seed=cfg.seed,
                             exclude_unknown=cfg.exclude_unknown)
    return {"dataset": unit.dataset, **s.to_dict()}


def _kept(unit, result: dict) -> bool:
    """Whether a kept unit holds what the report reads of it (else it is run again)."""
    from .units import holds

    if not unit.params:  # a weight search
        return holds(result, unit, ("weights", "error"), same=("dataset",))
    return (holds(result, unit, ("error", "tests", "train_frames", "training_error", "key"), same=("case", "features"))
            and result["key"] == list(unit.result_key))


# ---------------------------------------------------------------------------------------------
# the evaluation
# ---------------------------------------------------------------------------------------------

def evaluate(config: ClassificationConfig, *, out: str | Path | None = None, force: bool = False, executor=None,
             show_progress: bool | None = None) -> Results:
    """Run the configured cases (resuming from ``out/units`` when ``out`` is given: finished units are
    kept there as they land); returns every number as :class:`~pcreg.experiments.results.Results`."""
    from ..datasets import PRESETS
    from .units import Unit, UnitStore, load_cached, plain_config, run_resumable, say_damage

    t0 = time.perf_counter()
    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed)
    data_notes = say_damage(datasets)
    info = check_datasets(datasets, exclude_unknown=config.exclude_unknown)
    for name in info:
        if name in PRESETS:
            info[name]["mirrors"] = PRESETS[name].mirrors
    lengths = {d: len(v) for d, v in datasets.items()}
    units, ks = plan_units(config, lengths)
    cfg_dict = plain_config(config)
    store = UnitStore(out, cfg_dict, force=force, report=config.report) if out is not None else None
    searches = []
    if any("thesis" in fs.split("+") for fs in config.features):
        jobs = [Unit(f"weights/{d}", d, (), config) for d in datasets]
        done, _ = run_resumable(jobs, run_weight_search, store=store, cfg_dict=cfg_dict, executor=executor,
                                desc="weight search", show_progress=show_progress, kept=_kept)
        searches = [done[u.key] for u in jobs]
    done, resumed = run_resumable(units, run_unit, store=store, cfg_dict=cfg_dict, executor=executor,
                                  desc="classification", show_progress=show_progress, kept=_kept)
    results = [done[u.key] for u in units]
    notes = []
    scaled = [d for d, n in lengths.items() if n != 100]
    if scaled and not config.case1_k and "I" in config.cases:
        notes.append("Case I: k is 10%..90% of each sequence's length (the thesis: 10..90 of 100 frames); "
                     + ", ".join(f"{d}: {lengths[d]} frames" for d in scaled))
    if scaled and not config.case3_k and "III" in config.cases:
        notes.append("Case III: k per dataset is 10% and 20% of its length (the thesis: 10 and 20 of 100)")
    return Results("classification", cfg_dict, info, results, resumed_units=resumed, seconds=time.perf_counter() - t0,
                   notes=tuple(notes), data_notes=data_notes or None, sections={"k": ks, "weight_search": searches})

