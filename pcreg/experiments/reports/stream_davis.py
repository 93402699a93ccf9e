"""The DAVIS tables of the stream evaluation: J and F per sequence of every method run, beside the
benchmark's published methods (the ``davis`` section of :mod:`pcreg.experiments.stream_davis`)."""

from __future__ import annotations

import math

#: Decimals of J and F in the tables: three, a tenth of a point of IoU, the precision they are compared at (two
#: hid differences of up to 0.01 between pcreg and a published method).
DIGITS = 3

_WHAT = {"J": "J, region similarity (the object's intersection over union; 1 when both masks are empty)",
         "F": "F, boundary accuracy (the boundary F-measure, boundaries matched within ceil(0.008 x the image's "
              "diagonal) px)"}


def davis_table(results: dict, measure: str) -> tuple[list, list, str]:
    """One row per sequence and a last row of means over the sequences: each method's mean ``measure``
    ("J" or "F") over the scored frames, then each published method's (upper case)."""
    d = results["davis"]
    ours, pub = d["methods"], d["published"]
    header = ["sequence", "frames scored", *ours, *[p.upper() for p in pub["methods"]]]
    rows = [[n, s["frames"], *[s[measure][m] for m in ours], *[pub[measure][p][n] for p in pub["methods"]]]
            for n, s in d["sequences"].items()]
    objects = d.get("objects") or {}
    rows.append(["mean over objects" if objects else "mean over sequences", sum(s["frames"] for s in d["sequences"].values()),
                 *[d["mean"][measure][m] for m in ours], *[pub["mean"][measure][p] for p in pub["methods"]]])
    covered = pub.get("covered", [])
    short = [n for n, s in d["sequences"].items() if not s["frames"]]
    if d.get("mean_covered"):
        rows.append([f"mean over the {len(covered)} {'scored ' if short else ''}with published figures",
                     sum(d["sequences"][n]["frames"] for n in covered),
                     *[d["mean_covered"][measure][m] for m in [*ours, *pub["methods"]]]])
    footer = (f"\n({_WHAT[measure]}; frames 1 to n-2 of each sequence of n, averaged per sequence, then over the "
              f"sequences, as the DAVIS 2016 benchmark's evaluation does. Upper case: the methods the benchmark "
              f"published, from {pub['source']}; nan where it has no figure for the sequence)\n")
    if d.get("split"):
        footer += f"\nSequences: {d['split']['described']}.\n"
    if objects:
        each = "; ".join(f"{seq}: {', '.join(clips)}" for seq, clips in objects.items())
        footer += (f"\nSequences of several objects (DAVIS 2017): a row SEQ_K is object K, followed from its own mask on "
                   f"the first frame and scored on its own, every other object background ({each}). The means are over "
                   "objects, a sequence with one object counting once, as the DAVIS 2017 evaluation "
                   "(davis2017-evaluation) averages.\n")
    footer += _published_note(d, measure, short)
    if short:
        footer += _short_note(d, measure, short)
    if results["config"].get("frames"):
        footer += (f"\nOnly the first {results['config']['frames']} frames of each sequence were run (--frames): the "
                   "published figures are over whole sequences, and the two do not compare.\n")
    else:
        footer += _fewer_frames_note(d)
    if results["config"].get("key_every"):
        footer += (f"\nA key frame every {results['config']['key_every']} frames (--key-every): those frames' masks "
                   "were given, and they are not scored (but for one some method cannot start from, its mask of no object, no "
                   "background, or with pcreg_object an object too small to follow: it is no key frame, and is scored).\n")
    return header, rows, footer


def _short_note(d: dict, measure: str, short: list[str]) -> str:
    """What is said of sequences of fewer than 3 frames: none scored, so left out of pcreg's means; where the
    published methods have figures of them, the published means count them, and the two means do not compare."""
    pub = d["published"]
    counted = [n for n in short if any(isinstance(v, (int, float)) and math.isfinite(v)
                                       for v in (pub[measure][p].get(n) for p in pub["methods"]))]
    said = f"\n{', '.join(short)}: fewer than 3 frames, none scored (frames 1 to n-2): nan, left out of the means"
    if not counted:
        return said + ".\n"
    compares = (f": the row of the {len(pub.get('covered', []))} scored with published figures does" if d.get("mean_covered")
                else "")
    return (said + f" of pcreg's methods; the published means count {', '.join(counted)}, so the means over "
            f"sequences do not compare{compares}.\n")


def _fewer_frames_note(d: dict) -> str:
    """What is said of sequences scored over other frames than the published figures are (a copy of the data
    that lacks frames at its end, or was cut): their figures and the published ones do not compare."""
    published = d["published"].get("frames", {})
    other = [f"{n} {s['frames']} against {published[n]}" for n, s in d["sequences"].items()
             if n in published and s["frames"] and s["frames"] != published[n]]
    if not other:
        return ""
    return (f"\nScored over other frames than the published figures are ({'; '.join(other)} frames): the sequence "
            "does not hold the benchmark's frames, and its figures and the published ones do not compare.\n")


def _published_note(d: dict, measure: str, short: list[str]) -> str:
    """What the published means are over: every sequence, some (how many), or none (``short``: the sequences none
    of whose frames is scored, which the row that compares leaves out, and is named for)."""
    pub, n = d["published"], len(d["sequences"])
    what = "objects" if d.get("objects") else "sequences"  # DAVIS 2017's rows are objects, a sequence's each
    scored = "scored " if short else ""  # as the row is named
    counted = pub.get("counted", {}).get(measure)
    if not pub["methods"] or counted is None:
        return ""
    if not any(counted.values()):
        return f"\nThe published methods have no figure for any of these {n} {what}: their means are nan.\n"
    if all(c == n for c in counted.values()):
        return ""
    each = ", ".join(f"{p.upper()} {c}" for p, c in counted.items())
    return (f"\nThe published means are over the {what} with a figure only ({each} of {n}); the row of the "
            f"{len(pub.get('covered', []))} {scored}with every published figure compares pcreg's methods with them on the same "
            f"{what}.\n" if d.get("mean_covered") else
            f"\nThe published means are over the {what} with a figure only ({each} of {n}).\n")


def split_line(results: dict) -> str:
    """One line naming the DAVIS sequences evaluated (empty without a ``davis`` section or its split)."""
    split = (results.get("davis") or {}).get("split")
    return f"DAVIS sequences evaluated: {split['described']}" if split else ""


def davis_tables(results: dict) -> dict:
    """``{name: (title, header, rows, footer)}`` for :func:`pcreg.experiments.reports.files.write_files`:
    ``davis_J`` and ``davis_F``; none without a ``davis`` section."""
    if not results.get("davis"):
        return {}
    return {f"davis_{k}": (f"DAVIS: {k} per sequence, beside the published methods", *davis_table(results, k))
            for k in ("J", "F")}
