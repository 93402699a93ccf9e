"""Report of the classification evaluation (thesis Ch. 4): Table 4.1, cases I-III as tables and figures."""

from __future__ import annotations

from pathlib import Path

from ..results import Results


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
        fractions = [] if same or config["case1_k"] else list(config["case1_fractions"])
        if same:
            top = [f"k={k}" for k in ks[names[0]]]
        elif fractions:  # each cell under the fraction that gave its k (:func:`_fraction_columns`)
            top = [f"k={100 * f:g}%" for f in fractions]
        else:
            top = [f"k{i + 1}" for i in range(cols)]
        header = ["dataset", "features"] + top
        rows = []
        for fs in config["features"]:
            for d in names:
                by_k = {u["key"][2]: u for u in units if u["case"] == "I" and u["features"] == fs and u["key"][1] == d}
                cells = [by_k[k]["error"] if same else f"{by_k[k]['error']:.2f} (k={k})" for k in ks[d]]
                if fractions:
                    cells = _fraction_columns(cells, ks[d], fractions, info[d]["frames"])
                rows.append([_label(d, info), fs, *cells, *[""] * (len(top) - len(cells))])
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


def _fraction_columns(cells: list, ks: list[int], fractions: list[float], n: int) -> list:
    """A sequence of ``n`` frames' Case I cells (one per k of ``ks``), each under the first of ``fractions`` whose
    k it is (:func:`pcreg.experiments.classification.resolve_k`; a short sequence's fractions round to fewer k),
    "" under the others."""
    from ..classification import resolve_k

    by_k = dict(zip(ks, cells))
    out = []
    for f in fractions:
        k = resolve_k(n, (), (f,), dataset="", case="I", need_test=True)[0]
        out.append(by_k.pop(k, ""))
    return out if not by_k else cells  # a k of no fraction (results of other fractions): in k order, as they were


_TITLES = {
    "table41_weights": "Table 4.1: thesis feature weights, {trials} random trials (lowest training error)",
    "case1": "Table 4.2 (Case I): error % when training on the first k frames, testing on the rest",
    "case2": "Table 4.3 (Case II): error % when training on all of one dataset, testing on each",
    "case3": "Table 4.4 (Case III): error % when training on k frames of every dataset, testing on all",
}


def title(name: str, results: dict) -> str:
    """The title of table ``name`` (the thesis's 30 trials of the weight search as many as this run's ``--trials``)."""
    trials = results["config"].get("n_trials")
    return _TITLES.get(name, name).replace("{trials}", "the" if trials is None else str(trials))


def _figures(results: dict) -> dict:
    """matplotlib figures for case1/case2/case3 (like the thesis's Figures 4.1-4.2)."""
    from ...outputs import pyplot

    plt = pyplot()
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


def footer(name: str, results: dict) -> str:
    """What is said under the table ``name`` (Markdown, a paragraph a note): Case I's notes under case1, Case III's
    under case3."""
    notes = [n for n in results.get("notes", []) if (name == "case1" and str(n).startswith("Case I:"))
             or (name == "case3" and str(n).startswith("Case III:"))]
    return "".join(f"\nNote: {n}.\n" for n in notes)


def write_outputs(results: Results, out: str | Path) -> list[Path]:
    """The tables (.csv, .md), figures, config.json and (last) results.json, atomically; returns the paths."""
    from .files import write_files

    doc = results.to_dict()
    specs = {name: (title(name, doc), header, rows, footer(name, doc)) for name, (header, rows) in tables(doc).items()}
    return write_files(out, doc, tables=specs, figures=_figures(doc))
