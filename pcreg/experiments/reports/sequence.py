"""Report of the sequence evaluation (thesis Ch. 6-7): tables, checks and figures, from results."""

from __future__ import annotations

from pathlib import Path

from ...pipeline import METHODS
from ..results import Results


def _label(name: str, info: dict) -> str:
    m = info.get("mirrors")
    return f"{name} ({m})" if m else name


def _relative(plain, augmented) -> str:
    """How much lower augmented's error is than plain's, in words ("12.3% lower", or "4.5% higher")."""
    if not plain or augmented is None or plain != plain or augmented != augmented:
        return "n/a"
    change = 100.0 * (plain - augmented) / plain
    return f"{change:.1f}% lower" if change >= 0 else f"{-change:.1f}% higher"


def table(results: dict, backend: str) -> tuple[list, list]:
    """Header and rows: one row per dataset and k, error % per method, relative reduction of augmented."""
    header = ["dataset", "k", "pairs", "failed", "w", *METHODS, "augmented vs plain"]
    rows = []
    for name, d in results["backends"][backend]["datasets"].items():
        info = results["datasets"].get(name, {})
        for k, means in d["increments"].items():
            st = d["pairs"][k]
            p, a = means.get("plain"), means.get("augmented")
            rel = _relative(p, a)
            w = st.get("weight")
            rows.append([_label(name, info), int(k), st["pairs"], st["failed_pairs"],
                         "n/a" if w is None or not st["pairs"] else f"{w:g}", *[means.get(m, float("nan")) for m in METHODS], rel])
    return header, rows


def fewer_pairs(results: dict, backend: str) -> str:
    """The table's footer: each mean taken over fewer pairs than its row's ``pairs`` (those with no score: labels all
    unknown, an empty valid region for the cropped score, no fused frame yet for the temporal one); "" when none."""
    said = []
    for name, d in results["backends"][backend]["datasets"].items():
        for k, st in d["pairs"].items():
            scored = st.get("scored_pairs") or {}
            short = [f"{m} {n}" for m, n in scored.items() if n < st["pairs"]]
            if short:
                said.append(f"{name} k={k}: {', '.join(short)} of {st['pairs']}")
    return ("\n\nMeans over fewer pairs than `pairs` (the others have no score): " + "; ".join(said) + "\n") if said else ""


def checks(results: dict) -> str:
    """What registration-augmented classification should achieve, checked on this run (Markdown)."""
    import numpy as np

    def scored(v) -> bool:
        return v is not None and bool(np.isfinite(v))

    lines = ["### Checks\n"]
    for b, bd in results["backends"].items():
        lines.append(f"**backend {b}**\n")
        fails_aug, fails_reg, fails_mask, rel, reg_gain = [], [], [], [], []
        n_cells = n_reg = n_mask = 0
        for name, d in bd["datasets"].items():
            for k, m in d["increments"].items():
                if not d["pairs"][k]["pairs"]:
                    continue
                if scored(m["plain"]) and scored(m["augmented"]):  # else no pair has a score (its truth all unknown)
                    n_cells += 1
                    if not m["augmented"] < m["plain"]:
                        fails_aug.append(f"{name} k={k} ({m['augmented']:.2f} vs {m['plain']:.2f})")
                    rel.append(100.0 * (m["plain"] - m["augmented"]) / m["plain"] if m["plain"] else np.nan)
                if int(k) >= 4 and scored(m["augmented"]) and scored(m["augmented_unregistered"]):
                    n_reg += 1
                    reg_gain.append(m["augmented_unregistered"] - m["augmented"])
                    if not m["augmented"] < m["augmented_unregistered"]:
                        fails_reg.append(f"{name} k={k} ({m['augmented']:.2f} vs {m['augmented_unregistered']:.2f})")
                if m["thesis_after"] > m["thesis_before"]:
                    n_mask += 1
                    if not m["thesis_after_masked"] < m["thesis_before"]:
                        fails_mask.append(f"{name} k={k} ({m['thesis_after_masked']:.2f} vs {m['thesis_before']:.2f})")
        def ok(fails: list, cells: int) -> str:
            if not cells:  # nothing was scored: nothing is met
                return "no scored cell"
            return "met" if not fails else "NOT met: " + "; ".join(fails)

        lines.append(f"- augmented < plain on every sequence and increment ({n_cells} cells): {ok(fails_aug, n_cells)}")
        if rel and not np.isnan(rel).all():
            lines.append(f"- mean relative reduction of augmented vs plain: {np.nanmean(rel):.1f}% "
                         f"(min {np.nanmin(rel):.1f}%, max {np.nanmax(rel):.1f}%)")
        lines.append(f"- augmented < augmented_unregistered at k >= 4 ({n_reg} cells): {ok(fails_reg, n_reg)}")
        if reg_gain:
            lines.append(f"- mean gain of registration over the unregistered prior at k >= 4: "
                         f"{np.mean(reg_gain):.2f} percentage points")
        lines.append(f"- thesis_after_masked < thesis_before where thesis_after lost to thesis_before "
                     f"({n_mask} cells): {ok(fails_mask, n_mask) if n_mask else 'no such cell'}")
        lines.append("")
    if results.get("notes"):  # how a weight was chosen, or could not be: what the numbers above rest on
        lines += ["### Notes\n", *[f"- {n}" for n in results["notes"]], ""]
    return "\n".join(lines) + "\n"


def _figures(results: dict) -> dict:
    from ...outputs import pyplot

    plt = pyplot()
    import numpy as np

    from .style import METHOD_STYLE

    primary = results["primary_backend"]
    units = [u for u in results["units"] if u["backend"] == primary and u["pairs"]]
    figs = {}
    curve_methods = ("plain", "thesis_before", "thesis_after", "thesis_after_masked", "augmented",
                     "augmented_unregistered", "augmented_temporal")
    for name in results["datasets"]:
        us = sorted((u for u in units if u["dataset"] == name), key=lambda u: u["k"])
        if not us:
            continue
        fig, axes = plt.subplots(1, len(us), figsize=(4.6 * len(us), 3.8), squeeze=False, sharey=True)
        for ax, u in zip(axes[0], us):
            x = [p["moving"] for p in u["pairs"]]
            for m in curve_methods:
                label, colour, ls = METHOD_STYLE[m]
                ax.plot(x, [p["errors"][m] for p in u["pairs"]], ls, color=colour, lw=1.6 if m == "augmented" else 1.1,
                        label=label)
            fail = [p["moving"] for p in u["pairs"] if not p["registered"]]
            for f in fail:
                ax.axvline(f, color="red", alpha=0.3, lw=0.8)
            ax.set_title(f"k = {u['k']}  (w = {u['weight']['weight']:g})", fontsize=10)
            ax.set_xlabel("moving frame i + k")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("error (%)")
        axes[0][0].set_ylim(bottom=0)
        info = results["datasets"][name]
        fig.suptitle(f"{_label(name, info)}: per-pair error, backend {primary}", fontsize=11)
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False, bbox_to_anchor=(0.5, -0.08))
        fig.tight_layout()
        figs[f"sequence_{name}"] = fig
    # summary: mean error per method, one group per dataset, at each k
    names = list(results["datasets"])
    ks = sorted({int(k) for d in results["datasets"].values() for k in d["increments"]})
    bar_methods = ("plain", "thesis_before", "thesis_after", "thesis_after_masked", "augmented_unregistered",
                   "augmented", "augmented_temporal")
    if names and ks:
        fig, axes = plt.subplots(1, len(ks), figsize=(max(5.0, 1.1 * len(names)) * len(ks) / 1.6, 4.2),
                                 squeeze=False, sharey=True)
        for ax, k in zip(axes[0], ks):
            x = np.arange(len(names))
            wbar = 0.8 / len(bar_methods)
            for j, m in enumerate(bar_methods):
                label, colour, _ = METHOD_STYLE[m]
                vals = [results["datasets"][n]["increments"].get(str(k), {}).get(m, np.nan) for n in names]
                ax.bar(x + (j - (len(bar_methods) - 1) / 2) * wbar, vals, wbar, color=colour, label=label)
            ax.set_xticks(x, names, rotation=30, fontsize=8)
            ax.set_title(f"k = {k}", fontsize=10)
            ax.grid(alpha=0.3, axis="y")
        axes[0][0].set_ylabel(f"mean error (%), backend {primary}")
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False, bbox_to_anchor=(0.5, -0.1))
        fig.tight_layout()
        figs["sequence_summary"] = fig
    return figs


def write_outputs(results: Results, out: str | Path, *, recording: str | Path | None = None) -> list[Path]:
    """sequence_BACKEND.csv/.md, checks.md, the figures, config.json and results.json; ``recording``: the run's
    ``--record`` file (:func:`.files.write_files`)."""
    from .files import write_files

    doc = results.to_dict()
    tables = {f"sequence_{b}": (f"Sequence (thesis Ch. 6-7), backend {b}: mean error % over pairs (i, i+k)",
                                *table(doc, b), fewer_pairs(doc, b)) for b in doc["backends"]}
    return write_files(out, doc, recording=recording, tables=tables, texts={"checks.md": checks(doc)}, figures=_figures(doc))
