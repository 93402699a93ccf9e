"""DAVIS's measures in ``pcreg evaluate stream --data davis:PATH``: J and F of every method, beside the
benchmark's published methods.

Each clip runs as any other (:func:`pcreg.experiments.stream.run_clip`: the first frame's mask is the key
frame's labels, every method labels the frames after it); :class:`DavisScores`, a per-frame hook, scores
each method's labels (1 the object) against the frame's mask with the benchmark's J and F
(:mod:`pcreg.classification.davis_measures`) on frames 1 to n-2. :func:`summarise_davis` averages them per
sequence, then over sequences, and sets the published results on the same sequences beside them
(:func:`pcreg.datasets.davis.published`).

With ``--key-every N`` the later key frames are not scored (their mask is given; one with no object pixel, no
background, or with ``pcreg_object`` an object too small to follow, is no key frame and is scored); ``--keys`` is refused:
the benchmark gives the first frame's mask only.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["is_davis", "check_davis_config", "DavisScores", "chain", "summarise_davis"]

#: The measures, in table order.
MEASURES: tuple[str, ...] = ("J", "F")


def is_davis(data: str) -> bool:
    """Whether a ``--data`` value names DAVIS sequences (``davis:PATH``)."""
    return str(data).partition(":")[0].strip().lower() == "davis"


def check_davis_config(config) -> None:
    """Refuse what the benchmark's protocol cannot score: ``--keys`` (key frames other than the first), and
    ``--classes`` (a table's classes: DAVIS's masks are one object against its background, scored by J and F)."""
    from ..errors import InputError

    if is_davis(config.data) and config.keys is not None:
        raise InputError("--keys with --data davis:PATH: DAVIS's benchmark keys the first frame's mask alone, as "
                         "the default does: leave --keys out (--key-every N keys later masks too, outside the "
                         "benchmark's protocol)")
    if is_davis(config.data) and getattr(config, "classes", None) is not None:
        raise InputError(f"--classes with --data davis:PATH: DAVIS's masks are one object against its background, "
                         f"not {config.classes}'s classes; leave --classes out (J and F score the object)")


class DavisScores:
    """An ``on_frame(index, frame, predictions)`` hook that keeps J and F of every method on the scored
    frames (1 to n-2) of an ``n``-frame sequence."""

    def __init__(self, n: int) -> None:
        self.n = int(n)
        self.frames: list[int] = []
        self.values: dict[str, dict[str, list[float]]] = {k: {} for k in MEASURES}

    def on_frame(self, t: int, frame, predictions: dict, key_frame=None) -> None:
        from ..classification.davis_measures import boundary_f, jaccard, scored_frames

        if t not in scored_frames(self.n):
            return
        truth = frame.labels == 1
        self.frames.append(int(t))
        for m, labels in predictions.items():
            mask = np.asarray(labels) == 1
            self.values["J"].setdefault(m, []).append(jaccard(mask, truth))
            self.values["F"].setdefault(m, []).append(boundary_f(mask, truth))

    def result(self) -> dict:
        """``{"frames": [index], "J": {method: [value per frame]}, "F": ..., "means": {"J": {method: mean}, ...}}``."""
        from ..classification.davis_measures import sequence_mean

        means = {k: {m: sequence_mean(dict(zip(self.frames, v)), self.n) for m, v in self.values[k].items()}
                 for k in MEASURES}
        return {"frames": list(self.frames), **self.values, "means": means}


def chain(*hooks: Callable | None) -> Callable | None:
    """One ``on_frame`` hook calling each of ``hooks`` that is not None, in order (None when none is)."""
    live = [h for h in hooks if h is not None]
    if not live:
        return None
    if len(live) == 1:
        return live[0]

    def on_frame(*args) -> None:
        for h in live:
            h(*args)

    return on_frame


def summarise_davis(config, unit_results: list[dict]) -> dict:
    """The ``davis`` section of the stream evaluation's results: which sequences (``split``: name, split
    file, sequences, how many folders there were, one line describing it), per sequence each method's mean
    J and F over its scored frames (``sequences``), their means over the sequences (``mean``), and the
    published methods' figures on the same sequences (``published``: source, file, methods, J and F per
    method and sequence, NaN where it has none; ``mean`` over the sequences that have a figure and ``counted``,
    how many those are). With sequences of several objects (DAVIS 2017), each object is a row ``SEQ_K`` of its
    own and ``objects`` names them per sequence: the means are then over objects, as davis2017-evaluation's
    ``J-Mean`` and ``F-Mean`` are (``evaluation_method.py``: ``np.mean(J["M"])``, one entry per object).
    Where the published figures cover some sequences only, or pcreg scored some only (fewer than 3 frames score
    none), ``covered`` names those pcreg scored and every published method has a figure of, and ``mean_covered``
    gives every method's mean, pcreg's and the published ones, over them alone: the means that compare."""
    from ..classification.davis_measures import benchmark_mean
    from ..datasets.davis import objects_of, published, select_sequences
    from ..datasets.davis_splits import parse_davis_arg

    units = [u for u in unit_results if "davis" in u]
    methods = list(config.methods)
    # a sequence with no scored frame (fewer than 3) has no value of any method: NaN, left out of the means
    seqs: dict[str, dict] = {u["dataset"]: {"frames": len(u["davis"]["frames"]),
                                            **{k: {m: u["davis"]["means"][k].get(m, float("nan")) for m in methods}
                                               for k in MEASURES}}
                             for u in units}
    mean = {k: {m: benchmark_mean(s[k][m] for s in seqs.values()) for m in methods} for k in MEASURES}
    path, split = parse_davis_arg(config.data.partition(":")[2])
    found, _, chosen = select_sequences(path, split=split)
    pub = published(path)
    names = list(seqs)
    table = {k: {p: {n: pub[k][p].get(n, float("nan")) for n in names} for p in pub["methods"]} for k in MEASURES}
    given = {k: {p: [v for v in table[k][p].values() if np.isfinite(v)] for p in pub["methods"]} for k in MEASURES}
    pub_mean = {k: {p: float(np.mean(v)) if v else float("nan") for p, v in given[k].items()} for k in MEASURES}
    counted = {k: {p: len(v) for p, v in given[k].items()} for k in MEASURES}
    scored = [n for n in names if all(np.isfinite(seqs[n][k][m]) for k in MEASURES for m in methods)]
    covered = [n for n in scored if pub["methods"] and all(np.isfinite(table[k][p][n]) for k in MEASURES
                                                            for p in pub["methods"])]
    doc = {"split": chosen.to_dict(), "sequences": seqs, "methods": methods, "mean": mean,
           "published": {"source": pub["source"], "file": pub["file"], "methods": pub["methods"], **table,
                         "mean": pub_mean, "counted": counted, "covered": covered,
                         "frames": {n: pub["frames"][n] for n in names if n in pub.get("frames", {})}}}
    objects = objects_of(names, found)
    if objects:  # DAVIS 2017: a row per object, the means over objects
        doc["objects"] = objects
    if covered and len(covered) < len(names):
        doc["mean_covered"] = {k: {**{m: benchmark_mean(seqs[n][k][m] for n in covered) for m in methods},
                                   **{p: float(np.mean([table[k][p][n] for n in covered])) for p in pub["methods"]}}
                               for k in MEASURES}
    return doc
