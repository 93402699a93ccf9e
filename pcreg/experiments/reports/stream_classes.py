"""The stream evaluation's report with many classes (``--classes``): mIoU per clip, IoU per class, and the
checks of pcreg against every baseline in the same classes (:mod:`pcreg.experiments.stream_classes`)."""

from __future__ import annotations

import numpy as np

#: pcreg's mIoU should lie at least this many points above the best baseline's (mean over clips).
MIOU_MARGIN = 3.0
#: pcreg's pixel error should be below a baseline's on at least this share of the clips.
CLIP_SHARE = 7 / 8


def is_many_classes(results: dict) -> bool:
    """Whether the results come from ``--classes`` (each clip has an mIoU)."""
    return any("miou" in c for c in results["datasets"].values())


def _baselines(results: dict) -> list[str]:
    return [m for m in results["methods"] if m != "pcreg"]


def classes_tables(results: dict) -> dict:
    """``{name: (title, header, rows, footer)}``: ``stream_miou`` (per clip, each method's mIoU and the
    mean) and ``stream_iou`` (per class, each method's IoU, the mean over the clips that have the class);
    none without ``--classes``."""
    if not is_many_classes(results):
        return {}
    from ...classes import class_table, parse_table_json

    methods, clips = results["methods"], results["datasets"]
    rows = [[name, *[c["miou"][m] for m in methods]] for name, c in clips.items()]
    rows.append(["mean over clips", *[float(np.mean([c["miou"][m] for c in clips.values()])) for m in methods]])
    config = results["config"]  # a file's table as the run read it (the file may have changed, or gone, since)
    table = (parse_table_json(config["class_table"], config["classes"]) if config.get("class_table")
             else class_table(config["classes"]))
    ids = sorted({int(k) for c in clips.values() for m in methods for k in c["iou"][m]})
    per_class = []
    for k in ids:
        vals = [[c["iou"][m].get(str(k), c["iou"][m].get(k)) for c in clips.values()] for m in methods]
        per_class.append([table.name_of(k), *[100.0 * float(np.mean([v for v in vs if v is not None]))
                                              if any(v is not None for v in vs) else float("nan") for vs in vals]])
    unseen = _not_in_keys(clips, table)
    return {"stream_miou": ("Every class: mIoU % per clip", ["clip", *methods], rows,
                            "\n(the mean over the classes that the clip's truth or labels have of each class's IoU)\n"
                            + unseen),
            "stream_iou": ("Every class: IoU % per class, the mean over the clips that have it", ["class", *methods],
                           per_class, unseen)}


def _not_in_keys(clips: dict, table) -> str:
    """One line per clip naming the classes its truth has that none of its key frames shows: no method learns
    or carries them from the key frames, so each method's IoU of them is 0 on that clip."""
    lines = [f"\n{name}: no key frame shows {', '.join(table.name_of(k) for k in c['classes_not_in_keys'])}: "
             f"no method can label {'it' if len(c['classes_not_in_keys']) == 1 else 'them'} (each learns or "
             f"carries its classes from the key frames), an IoU of 0 on this clip\n"
             for name, c in clips.items() if c.get("classes_not_in_keys")]
    return "".join(lines)


def classes_checks(results: dict) -> list[str]:
    """The checks of pcreg against each baseline: pixel error on average and clip by clip, and mIoU."""
    clips, methods = results["datasets"], results["methods"]
    if "pcreg" not in methods:
        return ["- pcreg was not run"]
    mean = {m: float(np.mean([c["means"][m] for c in clips.values()])) for m in methods}
    miou = {m: float(np.mean([c["miou"][m] for c in clips.values()])) for m in methods}
    lines = []
    for b in _baselines(results):
        wins = sum(c["means"]["pcreg"] < c["means"][b] for c in clips.values())
        need = int(np.ceil(CLIP_SHARE * len(clips)))
        ok = mean["pcreg"] < mean[b] and wins >= need
        lines.append(f"- pcreg's pixel error below {b}'s on average and on at least {need} of {len(clips)} clips: "
                     f"{'met' if ok else 'NOT met'} ({mean['pcreg']:.2f}% vs {mean[b]:.2f}%, below on {wins})")
    base = _baselines(results)
    if base:
        best = max(base, key=lambda m: miou[m])
        ok = miou["pcreg"] >= miou[best] + MIOU_MARGIN
        lines.append(f"- pcreg's mIoU at least {MIOU_MARGIN:g} points above the best baseline's: "
                     f"{'met' if ok else 'NOT met'} ({miou['pcreg']:.1f} vs {best} {miou[best]:.1f})")
    return lines
