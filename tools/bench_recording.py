"""Cost of recording: the time ``--record`` adds to pcreg's real sequence pipeline (a ratio measured in
the same run) and the size of the recording per 100 recorded 640x480 pairs.

One unit of ``pcreg evaluate sequence`` (a dataset at k = 1, one backend) is run with and without a
:class:`pcreg.recording.recorder.Recorder`, alternating, ``--repeats`` times: the same code path as
``pcreg evaluate sequence --record`` (images as JPEG, the transform, labels, error series, ICP
iterations). The ratio is median(on) / median(off).

    python tools/bench_recording.py --out out/bench [--pairs 100] [--repeats 3] [--data synthetic:syn1a ...]

By default it measures two sequences: syn1a (synthetic, whose noise textures are JPEG's hardest case)
and, where ``../shared/data`` is present, the first CamVid clip (real video), both at 640x480; a CamVid
clip has fewer than 100 labelled pairs, so its size is scaled to 100 pairs.

Writes ``recording.json`` and ``recording.md`` to ``--out``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from benchlib import SHARED_DATA, checks_markdown, machine_info, write_report

TARGET_RATIO = 1.10
TARGET_MB_PER_100 = 15.0
CAMVID = SHARED_DATA / "camvid"


def measure(data: str, pairs: int, repeats: int, backend: str) -> dict:
    """One sequence of ``data`` at 640x480: its unit run alternately without and with a recorder."""
    from pcreg.experiments import sequence
    from pcreg.experiments.units import Unit, load_cached
    from pcreg.recording.recorder import Recorder

    # The first 10% of a sequence choose the fusion weight and are not scored (nor recorded).
    frames = int(round(pairs / 0.9)) + 2
    size = (640, 480) if data.startswith("synthetic") else None  # real frames keep their own size
    config = sequence.SequenceConfig(data=data, increments=(1,), backends=(backend,), frames=frames, size=size)
    name = next(iter(load_cached(data, frames=config.frames, size=config.size, seed=0)))
    unit = Unit(f"{name}/k1_{backend}", name, (("k", 1), ("backend", backend)), config)
    sequence.run_unit(unit)  # warm-up: imports, caches, compiled kernels
    off, on, sizes, scored = [], [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            t0 = time.perf_counter()
            res = sequence.run_unit(unit)
            off.append(time.perf_counter() - t0)
            scored = len(res["pairs"])
            path = Path(tmp) / f"run{r}.rrd"
            t0 = time.perf_counter()
            with Recorder(path, recording_name=f"bench {r}") as rec:
                sequence.run_unit(unit, recorder=rec, frame_counter=[0])
            on.append(time.perf_counter() - t0)  # the file is complete when the recorder closes
            sizes.append(path.stat().st_size)
    t_off, t_on = statistics.median(off), statistics.median(on)
    return {"data": data, "sequence": name, "pairs": scored, "seconds_off": off, "seconds_on": on,
            "ms_per_pair_off": 1e3 * t_off / max(1, scored), "ms_per_pair_on": 1e3 * t_on / max(1, scored),
            "overhead_ratio": t_on / t_off, "recording_mb": statistics.median(sizes) / 1e6,
            "recording_mb_per_100_pairs": statistics.median(sizes) / 1e6 * 100.0 / max(1, scored)}


def main(argv: list[str] | None = None) -> int:
    from pcreg.outputs import markdown_table
    from pcreg.recording.recorder import DEFAULT_JPEG_QUALITY

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench", help="folder for recording.json / recording.md (default out/bench)")
    ap.add_argument("--pairs", type=int, default=100, help="recorded pairs per run, at most (default 100)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--data", action="append",
                    help="a sequence's data, once or more (default synthetic:syn1a, and the first CamVid clip "
                         "of ../shared/data/camvid where it is present)")
    ap.add_argument("--backend", default="reference")
    args = ap.parse_args(argv)
    data = args.data or ["synthetic:syn1a"] + ([f"camvid:{CAMVID}"] if CAMVID.is_dir() else [])
    runs = [measure(d, args.pairs, args.repeats, args.backend) for d in data]
    report = {"backend": args.backend, "jpeg_quality": DEFAULT_JPEG_QUALITY, "repeats": args.repeats, "runs": runs,
              "targets": {"overhead_ratio_max": TARGET_RATIO, "recording_mb_per_100_pairs_max": TARGET_MB_PER_100},
              "machine": machine_info()}
    checks = []
    for r in runs:
        checks += [
            (f"{r['sequence']}: recording adds at most {100 * (TARGET_RATIO - 1):.0f}%", f"{r['overhead_ratio']:.3f}x",
             r["overhead_ratio"] <= TARGET_RATIO),
            (f"{r['sequence']}: at most {TARGET_MB_PER_100:g} MB per 100 pairs", f"{r['recording_mb_per_100_pairs']:.1f} MB",
             r["recording_mb_per_100_pairs"] <= TARGET_MB_PER_100),
        ]
    text = (f"### Recording cost: a `pcreg evaluate sequence` unit at 640x480 (k = 1, {args.backend}), "
            f"median of {args.repeats} alternating runs\n\n"
            + markdown_table(["sequence", "pairs", "ms/pair off", "ms/pair on", "ratio on/off", "MB per 100 pairs"],
                             [[r["sequence"], r["pairs"], r["ms_per_pair_off"], r["ms_per_pair_on"], r["overhead_ratio"],
                               r["recording_mb_per_100_pairs"]] for r in runs], digits=3)
            + "\n" + checks_markdown(checks))
    write_report(args.out, "recording", report, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
