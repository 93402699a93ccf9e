"""Report of the stream evaluation: tables, checks and the figure, from results."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..results import Results
from ..stream_methods import confidence_method
from .stream_classes import classes_checks, classes_tables, is_many_classes


def table(results: dict) -> tuple[list, list, str]:
    """One row per clip: the frames scored (not the key frames, nor those of void truth), the mean error % of
    every method, and the average reduction against plain."""
    methods = results["methods"]
    header = ["clip", "frames scored", *methods]
    rows = [[name, c["scored"], *[c["means"][m] for m in methods]] for name, c in results["datasets"].items()]
    avg = results["average_reduction"]
    rows.append(["reduction vs plain, mean over clips (%)", "", *[avg[m] for m in methods]])
    footer = ("\n(error %, unknown truth left out; reduction vs plain: how much lower than plain, in percent of "
              "plain, averaged over the clips)\n")
    for name, c in results["datasets"].items():
        if c["means"].get("plain") == 0:  # 0 of 0: no reduction (:func:`pcreg.experiments.stream.summarise`)
            footer += f"\n{name}: naive Bayes alone made no error, no reduction to take; left out of the mean\n"
        if c.get("unscored"):  # frames whose truth is all unknown: no error to take
            footer += (f"\n{name}: {len(c['unscored'])} frame(s) not scored, their truth all unknown (void): "
                       f"{', '.join(c['unscored'][:6])}{', ...' if len(c['unscored']) > 6 else ''}\n")
    from .stream_davis import split_line

    if split_line(results):  # which of a DAVIS download's sequences, J and F in davis_J.md, davis_F.md
        footer += f"\n{split_line(results)}; J and F beside the published methods in davis_J.md and davis_F.md.\n"
    return header, rows, footer


def per_frame(results: dict) -> tuple[list, list]:
    """One row per scored frame of every clip: its index, key frame, frames since the key, each method's error."""
    methods = results["methods"]
    header = ["clip", "frame", "name", "key_frame", "since_key", *methods]
    rows = [[u["dataset"], r["index"], r["name"], r["key"], r["since_key"], *[r["errors"][m] for m in methods]]
            for u in results["units"] for r in u["frames"]]
    return header, rows


def calibration_table(results: dict) -> tuple[list, list, str]:
    """The confidence of pcreg (or of pcreg_object, when pcreg did not run) per clip and over all clips: expected
    calibration error, error of all known pixels and of the most confident 80%, and their ratio."""
    header = ["clip", "known pixels", "ECE", "error %", "error % of the most confident 80%", "ratio"]
    items = [(n, c.get("calibration") or {}) for n, c in results["datasets"].items()]
    items.append(("all clips", results.get("calibration") or {}))
    def fixed(v, digits: int) -> str:  # an ECE of 0.0036 read 0.00 at the tables' two decimals
        return "n/a" if v is None else f"{v:.{digits}f}"

    rows = [[n, c.get("pixels", 0), fixed(c.get("ece"), 4), c.get("error", float("nan")),
             c.get("error_top80", float("nan")), fixed(c.get("top80_ratio"), 3)] for n, c in items]
    run = "`pcreg run --follow object`" if confidence_method(results["methods"]) == "pcreg_object" else "`pcreg run`"
    footer = (f"\n(the confidence of each label {run} writes, 10 equal bins for the expected calibration error; "
              "unknown truth left out)\n")
    return header, rows, footer


def _calibration_checks(results: dict) -> list[str]:
    cal, method = results.get("calibration") or {}, confidence_method(results.get("methods", ("pcreg",)))
    if method is None:
        return []
    if not cal.get("pixels"):
        return [f"- {method}'s confidence: no scored pixel"]
    return [f"- {method}'s confidence is calibrated (expected calibration error <= 0.02 over all known pixels): "
            f"{'met' if cal['ece'] <= 0.02 else 'NOT met'} ({cal['ece']:.4f})",
            f"- the most confident 80% of known pixels have at most a third of the error rate of all: "
            f"{'met' if cal['top80_ratio'] <= 1 / 3 else 'NOT met'} ({cal['error_top80']:.2f}% against "
            f"{cal['error']:.2f}%, {cal['top80_ratio']:.3f}; they hold {0.8 * cal['top80_ratio']:.3f} of the errors)"]


def checks(results: dict) -> str:
    """pcreg against the DIS baselines, plain and the unregistered key frame (Markdown)."""
    avg, clips = results["average_reduction"], results["datasets"]
    lines = ["### Checks\n"]
    if "pcreg" not in avg:  # pcreg_object's confidence alone, when it ran
        return "\n".join(lines + ["- pcreg was not run", *_calibration_checks(results)]) + "\n"
    if is_many_classes(results):
        return "\n".join(lines + classes_checks(results) + _calibration_checks(results)) + "\n"
    base = [m for m in BASELINE_NAMES if m in avg]
    if base:
        best = max(base, key=lambda m: avg[m])
        ok = avg["pcreg"] >= avg[best]
        lines.append(f"- pcreg lowers plain's error at least as much as the better DIS baseline on average over "
                     f"the clips: {'met' if ok else 'NOT met'} ({avg['pcreg']:.1f}% vs {best} {avg[best]:.1f}%)")
    for other in ("plain", "unregistered"):
        if other not in results["methods"]:  # not run: nothing to check
            continue
        worse = [f"{n} ({c['means']['pcreg']:.2f} vs {c['means'][other]:.2f})" for n, c in clips.items()
                 if other in c["means"] and c["means"]["pcreg"] > c["means"][other]]
        lines.append(f"- pcreg never worse than {other} on any clip ({len(clips)} clip{'' if len(clips) == 1 else 's'}): "
                     + ("met" if not worse else "NOT met: " + "; ".join(worse)))
    lines += _calibration_checks(results)
    times = {m: float(np.median([c["ms_per_frame"][m] for c in clips.values()])) for m in results["methods"]
             if all(m in c.get("ms_per_frame", {}) for c in clips.values())} if clips else {}
    if "pcreg" in times and base:  # the clock's line only beside a baseline (it differs from run to run)
        others = ", ".join(f"{m} {times[m]:.0f} ms ({avg[m]:.1f}%)" for m in base if m in times)
        half = "".join(f", {what} {times[m]:.0f} ms ({avg[m]:.1f}%)" for m, what in
                       (("pcreg_half", "at half size"), ("pcreg_flow", "on DIS's flow at half size")) if m in times)
        lines.append(f"- time a frame, the median over clips (classification and fusion included in every method): "
                     f"pcreg {times['pcreg']:.0f} ms ({avg['pcreg']:.1f}% below plain){half}; "
                     f"{others or 'no DIS baseline run'}")
    return "\n".join(lines) + "\n"


def _figure(results: dict):
    """Error against frames since the key frame, one panel per clip, one line per method."""
    from ...outputs import pyplot

    plt = pyplot()

    units = results["units"]
    if not units:
        return None
    fig, axes = plt.subplots(1, len(units), figsize=(4.2 * len(units), 3.6), squeeze=False)
    style = {"plain": ("0.4", ":"), "unregistered": ("0.6", "--"), "pcreg": ("C3", "-"), "pcreg_half": ("C3", "--"),
             "pcreg_flow": ("C1", "-"),
             "flow_key": ("C0", "-"), "flow_previous": ("C0", "--"), "flowultrafast_key": ("C2", "-")}
    for ax, u in zip(axes[0], units):
        since = np.array([r["since_key"] for r in u["frames"]])
        for m in results["methods"]:
            if m not in style:
                continue
            err = np.array([r["errors"][m] for r in u["frames"]], dtype=float)
            order = np.argsort(since, kind="stable")
            ax.plot(since[order], err[order], color=style[m][0], ls=style[m][1], lw=1.4, label=m)
        ax.set_title(u["dataset"])
        ax.set_xlabel("frames since the key frame")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("error %")
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    return fig


def _reliability(results: dict):
    """The reliability figure: accuracy against confidence per bin, and the share of pixels per bin."""
    from ...outputs import pyplot

    plt = pyplot()

    curve = (results.get("calibration") or {}).get("curve")
    if not curve:
        return None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(8.4, 3.6))
    conf = [b["confidence"] for b in curve]
    ax.plot([0, 1], [0, 1], color="0.6", ls="--", lw=1, label="calibrated")
    ax.plot(conf, [b["accuracy"] for b in curve], "o-", color="C3", lw=1.4, label=confidence_method(results["methods"]))
    ax.set_xlabel("confidence of the label")
    ax.set_ylabel("share of labels that are right")
    ax.set_title(f"reliability (ECE {results['calibration']['ece']:.4f})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax2.bar(conf, [b["share"] for b in curve], width=0.08, color="C3")
    ax2.set_xlabel("confidence of the label")
    ax2.set_ylabel("share of known pixels")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def _accuracy_time(results: dict):
    """Each method's reduction of plain's error (mean over clips) against its time a frame (median over
    clips), classification and fusion included: what each costs for what it gains."""
    from ...outputs import pyplot

    plt = pyplot()

    clips, avg = results["datasets"], results["average_reduction"]
    points = [(m, float(np.median([c["ms_per_frame"][m] for c in clips.values()])), avg[m]) for m in results["methods"]
              if m != "plain" and clips and all(m in c.get("ms_per_frame", {}) for c in clips.values())]
    points = [p for p in points if p[1] > 0 and np.isfinite(p[2])]  # plain without error: no reduction to draw
    if not points:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for i, (m, ms, red) in enumerate(sorted(points, key=lambda p: p[1])):
        ax.scatter(ms, red, color="C3" if m.startswith("pcreg") else ("C0" if m in BASELINE_NAMES else "0.5"), zorder=3)
        # neighbours in time alternate above and below their points, so that close names do not overlap
        ax.annotate(m, (ms, red), textcoords="offset points", xytext=(4, 4 if i % 2 == 0 else -11), fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("ms a frame (median over clips; classification and fusion included)")
    ax.set_ylabel("lower than plain, mean over clips (%)")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


#: The DIS baselines (:data:`pcreg.experiments.stream.BASELINES`), drawn in one colour.
BASELINE_NAMES = ("flow_key", "flow_previous", "flowfast_key", "flowultrafast_key")


def write_outputs(results: Results, out: str | Path, *, recording: str | Path | None = None) -> list[Path]:
    """stream_<backend>.csv/.md (means), stream_frames.csv/.md, checks.md, stream.png, config and results; on
    DAVIS also davis_J and davis_F (:mod:`.stream_davis`). ``recording``: the run's ``--record`` file
    (:func:`.files.write_files`)."""
    from .files import write_files
    from .stream_davis import DIGITS, davis_tables

    doc = results.to_dict()
    b = doc["primary_backend"]
    h, rows, footer = table(doc)
    ph, prows = per_frame(doc)
    calibrated = confidence_method(doc["methods"])  # None: no method with a confidence ran, no table of one
    config = doc.get("config", {})
    several = config.get("keys") or config.get("key_every")  # --keys, --key-every: more than the first frame
    title = f"Labelling a stream from its key frame{'s' if several else ''}: mean error % per clip"
    davis = davis_tables(doc)
    tables = {f"stream_{b}": (title, h, rows, footer),
              "stream_frames": ("Error % per frame", ph, prows),
              **({} if calibrated is None else
                 {"stream_calibration": (f"{calibrated}'s confidence: calibration per clip", *calibration_table(doc))}),
              **davis, **classes_tables(doc)}
    return write_files(out, doc, recording=recording, tables=tables, texts={"checks.md": checks(doc)},
                       digits={name: DIGITS for name in davis},
                       figures={"stream": _figure(doc), "stream_reliability": _reliability(doc),
                                "stream_speed": _accuracy_time(doc)})
