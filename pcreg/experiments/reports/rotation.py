"""Report of the rotation evaluation (thesis Ch. 5): tables, checks and the figure, from results."""

from __future__ import annotations

from pathlib import Path

from ..results import Results
from ..rotation import KEYS


def table(results: dict, backend: str) -> tuple[list, list]:
    """One row per dataset and angle: before, after, after_masked, after_cropped, registration."""
    header = ["dataset", "angle", *KEYS, "failed", "corner error px (median)", "(worst)"]
    rows = []
    for name, d in results["backends"][backend]["datasets"].items():
        m = results["datasets"].get(name, {}).get("mirrors")
        label = f"{name} ({m})" if m else name
        for a, c in d["angles"].items():
            ce, worst = c["corner_error_median"], c.get("corner_error_max")  # results of before 0.3 hold no worst
            rows.append([label, a, *[c[k] for k in KEYS], f"{c['failed']}/{c['frames']}",
                         "n/a" if ce is None else f"{ce:.2f}", "n/a" if worst is None else f"{worst:.2f}"])
    return header, rows


def checks(results: dict) -> str:
    """With registration, the error at 90 and 180 degrees within 2 points of the error at 0."""
    from ..units import angle_key

    lines = ["### Checks: after registration, 90 and 180 degrees within 2 points of 0 degrees\n"]
    for b, bd in results["backends"].items():
        lines.append(f"**backend {b}**\n")
        for name, d in bd["datasets"].items():
            a0 = d["angles"].get(angle_key(0.0))
            if a0 is None:
                lines.append(f"- {name}: 0 degrees not in the angle set")
                continue
            parts = []
            for a in (90.0, 180.0):
                c = d["angles"].get(angle_key(a))
                if c is None:
                    continue
                every = [x for x, cc in ((a, c), (0.0, a0)) if cc.get("frames") and cc.get("failed") == cc["frames"]]
                if every:
                    parts.append(f"{a:g}: not measured, registration refused on every frame at {every[0]:g} degrees")
                    continue
                for key in ("after", "after_masked"):
                    diff = c[key] - a0[key]
                    parts.append(f"{key} {a:g}: {c[key]:.2f} ({diff:+.2f}, {'met' if abs(diff) <= 2 else 'NOT met'})")
            refused = [f"{c['failed']} of {c['frames']} frames at {float(a):g} degrees" for a, c in d["angles"].items()
                       if c.get("failed")]
            lines.append(f"- {name}: 0 degrees {a0['after']:.2f}; "
                         + ("; ".join(parts) if parts else "neither 90 nor 180 degrees in the angle set")
                         + (f" (registration refused on {', '.join(refused)}: those frames are scored unregistered)"
                            if refused else ""))
        lines.append("")
    return "\n".join(lines) + "\n"


def _figure(results: dict):
    import math

    from ...outputs import pyplot

    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    names = list(results["datasets"])
    if not names:
        return None
    cols = min(3, len(names))
    rows_n = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.8 * cols, 3.6 * rows_n), squeeze=False, sharey=True)
    styles = {"before": ("#d62728", ":"), "after": ("#ff7f0e", "-"), "after_masked": ("#1f77b4", "-"),
              "after_cropped": ("#8c564b", "--")}
    for ax, name in zip(axes.flat, names):
        for b, bd in results["backends"].items():
            d = bd["datasets"][name]
            xs = [float(a) for a in d["angles"]]
            for key in KEYS:
                if key == "before" and b != results["primary_backend"]:
                    continue
                colour, ls = styles[key]
                lab = key if key == "before" else f"{key} ({b})"
                ax.plot(xs, [d["angles"][a][key] for a in d["angles"]], ls if b == results["primary_backend"] else "-.",
                        color=colour, marker="o" if b == results["primary_backend"] else "x", ms=3, lw=1.2,
                        alpha=1.0 if b == results["primary_backend"] else 0.6, label=lab)
        refused = [(float(a), c) for a, c in results["backends"][results["primary_backend"]]["datasets"][name]["angles"].items()
                   if c.get("failed")]
        if refused:  # scored unregistered there: marked, not passed off as a registration's result
            ax.plot([a for a, _ in refused], [c["after"] for _, c in refused], "s", mfc="none", mec="black", ms=8,
                    label="registration refused (scored unregistered)")
        m = results["datasets"][name].get("mirrors")
        ax.set_title(f"{name} ({m})" if m else name, fontsize=10)
        ax.set_xlabel("rotation (degrees)")
        ax.grid(alpha=0.3)
        ax.xaxis.set_major_locator(MaxNLocator(nbins=7, steps=[1, 1.5, 3, 5, 10]))  # 0, 30, ... 180 by default
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for r in range(rows_n):
        axes[r][0].set_ylabel("error (%)")
    axes[0][0].set_ylim(bottom=0)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(4, len(labels)), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, -0.06 if rows_n > 1 else -0.12))
    fig.suptitle("Rotated frames classified before and after registering them back", fontsize=11)
    fig.tight_layout()
    return fig


def write_outputs(results: Results, out: str | Path, *, recording: str | Path | None = None) -> list[Path]:
    """rotation_BACKEND.csv/.md, checks.md, rotation.png, config.json and results.json; ``recording``: the run's
    ``--record`` file (:func:`.files.write_files`)."""
    from .files import write_files

    doc = results.to_dict()
    tables = {f"rotation_{b}": (f"Rotation (thesis Ch. 5), backend {b}: error % (mean over sampled frames)",
                                *table(doc, b)) for b in doc["backends"]}
    return write_files(out, doc, recording=recording, tables=tables, texts={"checks.md": checks(doc)},
                       figures={"rotation": _figure(doc)})
