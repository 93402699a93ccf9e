"""Thesis Ch. 4: naive Bayes terrain classification alone (cases I, II, III and the weight search).

- Table 4.1: per dataset, the thesis feature's weights (w_r, w_g, w_b) from 30 random trials, lowest
  training error on all of its frames.
- Case I: per dataset, train on the first k frames (k = 10, 20, ..., 90 of 100; 10%..90% of shorter
  or longer sequences), test on the remaining frames.
- Case II: train on all frames of one dataset, test on all frames of every dataset.
- Case III: train on the first k frames of every dataset (k = 10 and 20 of 100), test on all frames.

Each (case, feature set, training set) is one unit of work, run through an executor (``--workers``).
Error rates are pooled over the test pixels (unknown truth left out) and given in percent.
Outputs in ``--out``: results.json, config.json, table41_weights / case1 / case2 / case3 as .csv and
.md, and case1.png, case2.png, case3.png.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from pathlib import Path

CASES = ("I", "II", "III")
DEFAULT_FEATURES = ("thesis", "rgb+hsv+row")
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

    data: str = "synthetic"
    cases: tuple[str, ...] = CASES
    features: tuple[str, ...] = DEFAULT_FEATURES
    case1_k: tuple[int, ...] = ()
    case3_k: tuple[int, ...] = ()
    case1_fractions: tuple[float, ...] = CASE1_FRACTIONS
    case3_fractions: tuple[float, ...] = CASE3_FRACTIONS
    n_trials: int = 30
    seed: int = 0
    frames: int | None = None
    size: tuple[int, int] | None = None
    exclude_unknown: bool = True


@dataclass(frozen=True)
class Unit:
    """One unit of work: fit on ``train`` and score on each entry of ``test``.

    train, test : ((dataset, start, stop), ...) frame ranges. key : identifies the result.
    """

    case: str
    features: str
    train: tuple[tuple[str, int, int], ...]
    test: tuple[tuple[str, int, int], ...]
    key: tuple
    data: str
    frames: int | None
    size: tuple[int, int] | None
    seed: int
    n_trials: int
    exclude_unknown: bool


# ---------------------------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------------------------

def _int_list(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if any(v < 1 or v > 100_000 for v in vals):
        raise argparse.ArgumentTypeError(f"frame counts must be at least 1, got {text!r}")
    return vals


def _size(text: str) -> tuple[int, int]:
    from ._common import size

    return size(text)


def _cases(text: str) -> tuple[str, ...]:
    vals = tuple(v.strip().upper() for v in text.split(",") if v.strip())
    bad = [v for v in vals if v not in CASES]
    if bad or not vals:
        raise argparse.ArgumentTypeError(f"cases are I, II, III (comma-separated), got {text!r}")
    return tuple(c for c in CASES if c in vals)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default="synthetic",
                        help="synthetic | synthetic:syn1a,syn2b | camvid:PATH | folder:PATH | lagr:PATH (default synthetic)")
    parser.add_argument("--cases", type=_cases, default=CASES, help="cases to run, e.g. I,III (default I,II,III)")
    parser.add_argument("--features", nargs="+", default=list(DEFAULT_FEATURES), metavar="SET",
                        help="feature sets, each names joined by + from thesis, rgb, hsv, lab, texture, row "
                             "(default: thesis rgb+hsv+row)")
    parser.add_argument("--k", dest="case1_k", type=_int_list, default=(), metavar="K,K,...",
                        help="Case I training frame counts (default 10%%..90%% of each sequence: 10..90 of 100)")
    parser.add_argument("--k3", dest="case3_k", type=_int_list, default=(), metavar="K,K,...",
                        help="Case III frames per dataset (default 10%% and 20%% of each sequence)")
    from ..validation import arg_int

    parser.add_argument("--frames", type=arg_int(1, 100_000), default=None, help="frames per synthetic sequence (default 100); "
                        "first frames of real sequences (default all)")
    parser.add_argument("--size", type=_size, default=None, metavar="WxH", help="synthetic frame size (default 640x480)")
    parser.add_argument("--trials", type=arg_int(1, 100_000), default=30, help="weight-search trials for the thesis feature (default 30)")
    parser.add_argument("--seed", type=arg_int(0, 2**32 - 1), default=0, help="seed of the weight search and synthetic data (default 0)")
    parser.add_argument("--workers", type=arg_int(1, 1024), default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", default=None, help="dask.distributed scheduler address instead of local processes")
    parser.add_argument("--out", default="out/classification", help="output folder (default out/classification)")
    parser.add_argument("--force", action="store_true", help="overwrite existing outputs")


def config_from_args(args: argparse.Namespace) -> ClassificationConfig:
    from ..errors import InputError
    from ..classification.features import parse_features

    feats = tuple("+".join(parse_features(f)) for f in args.features)
    if len(set(feats)) != len(feats):
        raise InputError("a feature set is listed twice in --features")
    if args.trials < 1:
        raise InputError("--trials must be at least 1")
    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    return ClassificationConfig(data=args.data, cases=tuple(args.cases), features=feats,
                                case1_k=tuple(args.case1_k), case3_k=tuple(args.case3_k), n_trials=args.trials,
                                seed=args.seed, frames=args.frames, size=args.size)


def run(args: argparse.Namespace) -> int:
    from .._io import OutputLock
    from .._runner import make_executor
    from ._common import UnitStore, plain_config

    config = config_from_args(args)
    out = Path(args.out)
    with OutputLock(out):  # one run per folder; finished units resume like the other evaluations
        store = UnitStore(out, plain_config(config), force=args.force)
        with make_executor(args.workers, scheduler=args.scheduler) as executor:
            results = evaluate(config, executor=executor, store=store)
        written = write_outputs(results, out)
    print(f"wrote {len(written)} files to {out}")
    print((out / "case1.md").read_text() if "I" in config.cases else "", end="")
    return 0


# ---------------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------------

_DATA_CACHE: dict = {}


def _load(data: str, frames: int | None, size: tuple[int, int] | None, seed: int) -> dict:
    key = (data, frames, size, seed)
    if key not in _DATA_CACHE:
        from ..datasets import load_dataset

        _DATA_CACHE.clear()
        _DATA_CACHE[key] = load_dataset(data, n_frames=frames, size=size, seed=seed)
    return _DATA_CACHE[key]


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

    if explicit:
        ks = list(explicit)
    else:
        ks = sorted({min(max(1, int(round(f * n))), n - 1 if need_test else n) for f in fractions})
    for k in ks:
        if k > n or (need_test and k >= n):
            why = "it needs at least one test frame" if need_test else "it trains on k frames of each"
            raise DatasetError(f"k={k} is larger than dataset {dataset} ({n} frames; Case {case}: {why})")
    return ks


def plan_units(config: ClassificationConfig, lengths: dict[str, int]) -> tuple[list[Unit], dict]:
    """All units of the configured cases, and the k values chosen per dataset."""
    common = dict(data=config.data, frames=config.frames, size=config.size, seed=config.seed,
                  n_trials=config.n_trials, exclude_unknown=config.exclude_unknown)
    names = list(lengths)
    units: list[Unit] = []
    ks: dict = {}
    if "I" in config.cases:
        ks["I"] = {d: resolve_k(n, config.case1_k, config.case1_fractions, dataset=d, case="I", need_test=True)
                   for d, n in lengths.items()}
    if "III" in config.cases:
        per = {d: resolve_k(n, config.case3_k, config.case3_fractions, dataset=d, case="III", need_test=False)
               for d, n in lengths.items()}
        n_levels = min(len(v) for v in per.values())
        ks["III"] = {d: v[:n_levels] for d, v in per.items()}
    everything = tuple((d, 0, lengths[d]) for d in names)
    for fs in config.features:
        if "I" in config.cases:
            for d in names:
                for k in ks["I"][d]:
                    units.append(Unit("I", fs, ((d, 0, k),), ((d, k, lengths[d]),), (fs, d, k), **common))
        if "II" in config.cases:
            for d in names:
                units.append(Unit("II", fs, ((d, 0, lengths[d]),), everything, (fs, d), **common))
        if "III" in config.cases:
            for i in range(len(next(iter(ks["III"].values())))):
                train = tuple((d, 0, ks["III"][d][i]) for d in names)
                units.append(Unit("III", fs, train, everything, (fs, i), **common))
    return units, ks


# ---------------------------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------------------------

def _frames(datasets: dict, ranges) -> list:
    return [f for d, a, b in ranges for f in datasets[d][a:b]]


def run_unit(unit: Unit) -> dict:
    """Fit one classifier and score it: a pure function of ``unit`` (data loaded or taken from the
    per-process cache). Returns JSON-ready numbers."""
    import numpy as np

    from ..classification.bayes import NaiveBayesPixelClassifier, thesis_weight_search
    from ..classification.features import parse_features
    from ..classification.metrics import confusion_matrix, error_from_confusion

    t0 = time.perf_counter()
    datasets = _load(unit.data, unit.frames, unit.size, unit.seed)
    train = _frames(datasets, unit.train)
    images = [f.image for f in train]
    labels = [f.labels for f in train]
    feats = parse_features(unit.features)
    weights = None
    search = None
    if "thesis" in feats:
        search = thesis_weight_search(images, labels, n_trials=unit.n_trials, seed=unit.seed,
                                      exclude_unknown=unit.exclude_unknown)
        weights = search.weights
    clf = NaiveBayesPixelClassifier(feats, weights=weights, exclude_unknown=unit.exclude_unknown).fit(images, labels)
    t_fit = time.perf_counter() - t0
    per_test = []
    total = np.zeros((3, 3), dtype=np.int64)
    for d, a, b in unit.test:
        conf = np.zeros((3, 3), dtype=np.int64)
        frame_errors = []
        for f in datasets[d][a:b]:
            c = confusion_matrix(clf.predict(f.image), f.labels, exclude_unknown=unit.exclude_unknown)
            conf += c
            frame_errors.append(error_from_confusion(c))
        total += conf
        per_test.append({"dataset": d, "frames": [a, b], "error": error_from_confusion(conf),
                         "mean_frame_error": float(np.nanmean(frame_errors)) if frame_errors else float("nan"),
                         "frame_errors": frame_errors, "confusion": conf.tolist()})
    return {
        "case": unit.case, "features": unit.features, "key": list(unit.key),
        "train": [list(r) for r in unit.train], "train_frames": len(train),
        "weights": None if weights is None else list(weights),
        "weight_search": None if search is None else search.to_dict(),
        "training_error": clf.score_error(images, labels) if unit.case == "II" else None,
        "error": error_from_confusion(total), "confusion": total.tolist(), "tests": per_test,
        "theta": clf.theta_.tolist(), "var": clf.var_.tolist(), "classes": clf.classes_.tolist(),
        "class_prior": clf.class_prior_.tolist(), "feature_names": list(clf.feature_names_),
        "seconds": {"fit": t_fit, "total": time.perf_counter() - t0},
    }


def run_weight_search(args: tuple) -> dict:
    """Table 4.1 row: the 30-trial weight search on all frames of one dataset."""
    from ..classification.bayes import thesis_weight_search

    data, frames, size, seed, n_trials, exclude_unknown, name = args
    datasets = _load(data, frames, size, seed)
    fr = datasets[name]
    s = thesis_weight_search([f.image for f in fr], [f.labels for f in fr], n_trials=n_trials, seed=seed,
                             exclude_unknown=exclude_unknown)
    return {"dataset": name, **s.to_dict()}


# ---------------------------------------------------------------------------------------------
# the evaluation
# ---------------------------------------------------------------------------------------------

def _run_kept(fn, jobs: list, keys: list[str], *, store, executor, desc: str, show_progress) -> list:
    """``run_units`` with the finished ones taken from ``store`` (a :class:`UnitStore`, or None) and each
    new result saved there as it lands, so an interrupted run resumes."""
    from .._runner import run_units

    results: list = [None] * len(jobs)
    todo = []
    for i, k in enumerate(keys):
        prev = store.load(k) if store is not None else None
        if prev is not None:
            results[i] = prev
        else:
            todo.append(i)
    index = {id(jobs[i]): i for i in todo}

    def keep(job, result) -> None:
        i = index[id(job)]
        results[i] = result
        if store is not None:
            store.save(keys[i], result)

    run_units(fn, [jobs[i] for i in todo], executor=executor, desc=desc, on_result=keep,
              show_progress=show_progress)
    return results


def _unit_key(key) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9_.+-]", "_", "_".join(str(k) for k in key))


def evaluate(config: ClassificationConfig, *, executor=None, show_progress: bool | None = None,
             store=None) -> dict:
    """Run the configured cases; returns every number (what results.json holds). Writes nothing but
    the finished units into ``store`` (a :class:`~pcreg.experiments._common.UnitStore`), when given."""
    from .._runner import _InlineExecutor, run_units
    from ..datasets import PRESETS

    t0 = time.perf_counter()
    executor = executor or _InlineExecutor()
    datasets = _load(config.data, config.frames, config.size, config.seed)
    info = check_datasets(datasets, exclude_unknown=config.exclude_unknown)
    for name in info:
        if name in PRESETS:
            info[name]["mirrors"] = PRESETS[name].mirrors
    lengths = {d: len(v) for d, v in datasets.items()}
    units, ks = plan_units(config, lengths)
    searches = []
    if any("thesis" in fs.split("+") for fs in config.features):
        jobs = [(config.data, config.frames, config.size, config.seed, config.n_trials, config.exclude_unknown, d)
                for d in datasets]
        searches = _run_kept(run_weight_search, jobs, [f"weights_{_unit_key([d])}" for d in datasets],
                             store=store, executor=executor, desc="weight search", show_progress=show_progress)
    results = _run_kept(run_unit, units, [f"{u.case}_{_unit_key(u.key)}" for u in units], store=store,
                        executor=executor, desc="classification", show_progress=show_progress)
    notes = []
    scaled = [d for d, n in lengths.items() if n != 100]
    if scaled and not config.case1_k and "I" in config.cases:
        notes.append("Case I: k is 10%..90% of each sequence's length (the thesis: 10..90 of 100 frames); "
                     + ", ".join(f"{d}: {lengths[d]} frames" for d in scaled))
    if scaled and not config.case3_k and "III" in config.cases:
        notes.append("Case III: k per dataset is 10% and 20% of its length (the thesis: 10 and 20 of 100)")
    return {
        "config": asdict(config),
        "datasets": info,
        "k": ks,
        "notes": notes,
        "weight_search": searches,
        "units": results,
        "seconds": time.perf_counter() - t0,
    }


# ---------------------------------------------------------------------------------------------
# tables and figures
# ---------------------------------------------------------------------------------------------

def _label(name: str, info: dict) -> str:
    m = info.get(name, {}).get("mirrors")
    return f"{name} ({m})" if m else name


def tables(results: dict) -> dict[str, tuple[list, list]]:
    """The thesis-style tables: {name: (header, rows)} for table41_weights, case1, case2, case3."""
    info = results["datasets"]
    names = list(info)
    config = results["config"]
    out: dict[str, tuple[list, list]] = {}
    if results["weight_search"]:
        rows = [[_label(s["dataset"], info), *[f"{w:.3f}" for w in s["weights"]], s["error"]]
                for s in results["weight_search"]]
        out["table41_weights"] = (["dataset", "w_r", "w_g", "w_b", "training error %"], rows)
    units = results["units"]
    if "I" in config["cases"]:
        ks = results["k"]["I"]
        cols = max(len(v) for v in ks.values())
        same = len({tuple(v) for v in ks.values()}) == 1
        if same:
            top = [f"k={k}" for k in ks[names[0]]]
        elif not config["case1_k"] and len(config["case1_fractions"]) == cols:
            top = [f"k={100 * f:g}%" for f in config["case1_fractions"]]
        else:
            top = [f"k{i + 1}" for i in range(cols)]
        header = ["dataset", "features"] + top
        rows = []
        for fs in config["features"]:
            for d in names:
                by_k = {u["key"][2]: u for u in units if u["case"] == "I" and u["features"] == fs and u["key"][1] == d}
                cells = []
                for k in ks[d]:
                    e = by_k[k]["error"]
                    cells.append(e if same else f"{e:.2f} (k={k})")
                rows.append([_label(d, info), fs, *cells])
        out["case1"] = (header, rows)
    if "II" in config["cases"]:
        header = ["trained on", "features", *[f"test {d}" for d in names], "test all"]
        rows = []
        for fs in config["features"]:
            for d in names:
                u = next(u for u in units if u["case"] == "II" and u["features"] == fs and u["key"][1] == d)
                rows.append([_label(d, info), fs, *[t["error"] for t in u["tests"]], u["error"]])
        out["case2"] = (header, rows)
    if "III" in config["cases"]:
        ks = results["k"]["III"]
        header = ["k per dataset", "features", "training frames", *[f"test {d}" for d in names], "test all"]
        rows = []
        for fs in config["features"]:
            for u in (u for u in units if u["case"] == "III" and u["features"] == fs):
                i = u["key"][1]
                kdesc = sorted({ks[d][i] for d in names})
                rows.append([",".join(map(str, kdesc)), fs, u["train_frames"], *[t["error"] for t in u["tests"]],
                             u["error"]])
        out["case3"] = (header, rows)
    return out


_TITLES = {
    "table41_weights": "Table 4.1: thesis feature weights, 30 random trials (lowest training error)",
    "case1": "Table 4.2 (Case I): error % when training on the first k frames, testing on the rest",
    "case2": "Table 4.3 (Case II): error % when training on all of one dataset, testing on each",
    "case3": "Table 4.4 (Case III): error % when training on k frames of every dataset, testing on all",
}


def _figures(results: dict) -> dict:
    """matplotlib figures for case1/case2/case3 (like the thesis's Figures 4.1-4.2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    info = results["datasets"]
    names = list(info)
    config = results["config"]
    feats = config["features"]
    units = results["units"]
    figs = {}
    if "I" in config["cases"]:
        fig, axes = plt.subplots(1, len(feats), figsize=(5.2 * len(feats), 4), squeeze=False, sharey=True)
        for ax, fs in zip(axes[0], feats):
            for d in names:
                us = sorted((u for u in units if u["case"] == "I" and u["features"] == fs and u["key"][1] == d),
                            key=lambda u: u["key"][2])
                ax.plot([100.0 * u["key"][2] / info[d]["frames"] for u in us], [u["error"] for u in us],
                        marker="o", label=_label(d, info))
            ax.set_title(f"Case I, features {fs}")
            ax.set_xlabel("training frames (% of the sequence)")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("error (%)")
        axes[0][-1].legend(fontsize=8)
        figs["case1"] = fig
    for case, fname in (("II", "case2"), ("III", "case3")):
        if case not in config["cases"]:
            continue
        fig, axes = plt.subplots(1, len(feats), figsize=(5.2 * len(feats), 4), squeeze=False, sharey=True)
        for ax, fs in zip(axes[0], feats):
            us = [u for u in units if u["case"] == case and u["features"] == fs]
            x = np.arange(len(names) + 1)
            width = 0.8 / max(len(us), 1)
            for j, u in enumerate(us):
                errs = [t["error"] for t in u["tests"]] + [u["error"]]
                lab = (f"trained on {_label(u['key'][1], info)}" if case == "II"
                       else f"{u['train_frames']} training frames")
                ax.bar(x + (j - (len(us) - 1) / 2) * width, errs, width, label=lab)
            ax.set_xticks(x, [*names, "all"], rotation=30, fontsize=8)
            ax.set_title(f"Case {case}, features {fs}")
            ax.grid(alpha=0.3, axis="y")
        axes[0][0].set_ylabel("error on test set (%)")
        axes[0][-1].legend(fontsize=7)
        figs[fname] = fig
    return figs


def write_outputs(results: dict, out: str | Path) -> list[Path]:
    """Write the tables, figures, config.json and (last) results.json atomically; returns the paths."""
    import matplotlib.pyplot as plt

    from .._io import atomic_save_figure, atomic_write_csv, atomic_write_json, atomic_write_text, markdown_table
    from ._common import nan_to_none

    out = Path(out)
    written = []
    for name, (header, rows) in tables(results).items():
        written.append(atomic_write_csv(out / f"{name}.csv", header, rows))
        text = f"### {_TITLES[name]}\n\n" + markdown_table(header, rows)
        notes = [n for n in results["notes"] if (name == "case1" and n.startswith("Case I:"))
                 or (name == "case3" and n.startswith("Case III:"))]
        if notes:
            text += "\n" + "\n".join(f"Note: {n}." for n in notes) + "\n"
        written.append(atomic_write_text(out / f"{name}.md", text))
    for name, fig in _figures(results).items():
        written.append(atomic_save_figure(fig, out / f"{name}.png"))
        plt.close(fig)
    written.append(atomic_write_json(out / "config.json", results["config"]))
    written.append(atomic_write_json(out / "results.json", nan_to_none(results)))  # strict JSON: NaN -> null
    return written
