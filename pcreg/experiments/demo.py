"""The whole story on small built-in synthetic data (what ``make demo`` runs), in under a minute on 2 cores once set up.

1. Ch. 4 - naive Bayes alone (cases I-III, the thesis feature and RGB+HSV+row);
2. Ch. 5 - rotated frames classified before and after registering them back, both ICP backends;
3. the two ICP backends cross-checked on the same clouds;
4. Ch. 6-7 - pairs (i, i+k) registered, classified before/after, and labels propagated through the
   registration (the augmented methods), both backends, with a recording of every pair;
5. a stream labelled from its key frame (what ``pcreg run`` does) beside naive Bayes, the key frame's
   labels unwarped and DIS optical flow;
6. per-stage times of the pipeline.

Writes ``OUT/report.md`` (tables and figures), one folder per experiment and ``OUT/demo.rrd``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from .results import Results


@dataclass(frozen=True)
class DemoConfig:
    """The demo's data and sizes (written to OUT/config.json)."""

    presets: tuple[str, ...] = ("syn1a", "syn2b")
    frames: int = 16
    size: tuple[int, int] = (320, 240)
    increments: tuple[int, ...] = (1, 4, 7)
    angles: tuple[float, ...] = (0.0, 15.0, 30.0, 60.0, 90.0, 135.0, 180.0)
    seed: int = 0

    @property
    def data(self) -> str:
        return "synthetic:" + ",".join(self.presets)


def _say(text: str) -> None:
    from .._runner import check_interrupted

    check_interrupted()  # between the parts
    print(text, flush=True)


def _classification(config: DemoConfig, out: Path, workers: int) -> Results:
    """Ch. 4: naive Bayes alone, cases I-III."""
    from .._runner import make_executor
    from . import classification
    from .reports import classification as classification_report

    k1 = tuple(sorted({max(1, config.frames // 4), config.frames // 2, 3 * config.frames // 4}))
    ccfg = classification.ClassificationConfig(data=config.data, frames=config.frames, size=config.size,
                                               seed=config.seed, case1_k=k1, case3_k=(2, 4), n_trials=30)
    with make_executor(workers) as ex:
        cres = classification.evaluate(ccfg, executor=ex, show_progress=False)
    classification_report.write_outputs(cres, out / "classification")
    return cres


def _rotation(config: DemoConfig, out: Path, workers: int) -> Results:
    """Ch. 5: rotated frames before and after registration, both backends."""
    from .._runner import make_executor
    from . import rotation
    from .reports import rotation as rotation_report

    rcfg = rotation.RotationConfig(data=config.data, angles=config.angles, samples=1, backends=("reference", "open3d"),
                                   frames=config.frames, size=config.size, seed=config.seed)
    with make_executor(workers) as ex:
        rres = rotation.evaluate(rcfg, out=out / "rotation", force=True, executor=ex, show_progress=False)
    rotation_report.write_outputs(rres, out / "rotation")
    return rres


def _crosscheck(datasets: dict, out: Path) -> dict:
    """The two ICP backends cross-checked on frames 0 and 3 of the first sequence."""
    from ..implementations.crosscheck import crosscheck
    from ..outputs import atomic_write_json

    first = next(iter(datasets.values()))
    cc = crosscheck(first[0].image, first[3].image).to_dict()
    atomic_write_json(out / "crosscheck.json", cc)
    return cc


def _sequence(config: DemoConfig, out: Path, workers: int, record: str | Path | None,
              raw_images: bool) -> tuple:
    """Ch. 6-7: the pairs of every increment, both backends; recorded in this process when ``record``
    is given, else run by ``workers`` processes."""
    from .._runner import make_executor
    from . import sequence
    from .reports import sequence as sequence_report

    scfg = sequence.SequenceConfig(data=config.data, increments=config.increments, backends=("reference", "open3d"),
                                   frames=config.frames, size=config.size, seed=config.seed)
    if record is not None:
        from ..recording.recorder import Recorder

        with Recorder(record, recording_name="pcreg demo", kind="demo", raw_images=raw_images, force=True) as rec:
            sres = sequence.evaluate(scfg, out=out / "sequence", force=True, recorder=rec, show_progress=False)
    else:
        with make_executor(workers) as ex:
            sres = sequence.evaluate(scfg, out=out / "sequence", force=True, executor=ex, show_progress=False)
    sequence_report.write_outputs(sres, out / "sequence")
    return scfg, sres


def _stream(config: DemoConfig, out: Path, workers: int) -> Results:
    """Each preset as a stream from its first frame: pcreg's propagation and the baselines."""
    from .._runner import make_executor
    from . import stream
    from .reports import stream as stream_report

    cfg = stream.StreamConfig(data=config.data, frames=config.frames, size=config.size, seed=config.seed,
                              methods=("plain", "unregistered", "pcreg", "flow_key"))
    with make_executor(workers) as ex:
        res = stream.evaluate(cfg, out=out / "stream", force=True, executor=ex, show_progress=False)
    stream_report.write_outputs(res, out / "stream")
    return res


def _pair_figure(config: DemoConfig, datasets: dict, sres: Results, out: Path) -> None:
    """The story figure: the first sequence's pair at the second increment, with its chosen weight."""
    from .reports.demo import pair_figure

    name = next(iter(datasets))
    k_fig = config.increments[min(1, len(config.increments) - 1)]
    unit = next(u for u in sres.units if u["dataset"] == name and u["k"] == k_fig and u["backend"] == "reference")
    w_fig = unit["weight"]["weight"] if unit.get("weight") else 1.0
    pair_figure(datasets[name], k=k_fig, weight=w_fig, out=out / "pair.png", title=name)


def _stage_rows(backends: tuple[str, ...], sres: Results) -> list[list]:
    """Per backend: pairs, the median ms of each pipeline stage, and their sum."""
    import numpy as np

    rows = []
    for b in backends:
        pairs = [p for u in sres.units if u["backend"] == b for p in u["pairs"]]
        med = {s: 1000.0 * float(np.median([p["times"][s] for p in pairs])) for s in ("register", "warp", "classify", "fuse")}
        rows.append([b, len(pairs), *med.values(), sum(med.values())])
    return rows


def run_demo(config: DemoConfig, *, out: str | Path, workers: int = 2, record: str | Path | None = None,
             raw_images: bool = False) -> Path:
    """Run every part and write ``out/report.md``; returns its path. Overwrites earlier demo output."""
    from ..datasets import load_dataset
    from ..outputs import atomic_write_json, atomic_write_text
    from .reports.demo import report
    from .units import plain_config

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    times: dict[str, float] = {}
    atomic_write_json(out / "config.json", plain_config(config))
    datasets = load_dataset(config.data, n_frames=config.frames, size=config.size, seed=config.seed)

    _say("1/6 naive Bayes alone (thesis Ch. 4)")
    t = time.perf_counter()
    cres = _classification(config, out, workers)
    times["Ch. 4 classification"] = time.perf_counter() - t

    _say("2/6 rotated frames, before and after registration (thesis Ch. 5), both backends")
    t = time.perf_counter()
    rres = _rotation(config, out, workers)
    times["Ch. 5 rotation"] = time.perf_counter() - t

    _say("3/6 cross-check of the two ICP backends")
    t = time.perf_counter()
    cc = _crosscheck(datasets, out)
    times["cross-check"] = time.perf_counter() - t

    _say("4/6 sequences: registration, before/after, label propagation (thesis Ch. 6-7), both backends")
    t = time.perf_counter()
    scfg, sres = _sequence(config, out, workers, record, raw_images)
    times["Ch. 6-7 sequence" + (" (recorded)" if record is not None else "")] = time.perf_counter() - t

    _say("5/6 a stream labelled from its key frame, beside the baselines")
    t = time.perf_counter()
    stres = _stream(config, out, workers)
    times["stream"] = time.perf_counter() - t

    _say("6/6 report")
    _pair_figure(config, datasets, sres, out)
    # the report reads the results.json documents, as the evaluations' own reports do
    text = report(config, cres.to_dict(), rres.to_dict(), sres.to_dict(), cc, _stage_rows(scfg.backends, sres), times,
                  record, out, stres.to_dict())
    atomic_write_text(out / "report.md", text)
    return out / "report.md"
