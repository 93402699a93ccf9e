"""Cost of recording: the time ``--record`` adds to pcreg's real sequence pipeline (a ratio measured in
the same run) and the size of the recording per 100 recorded 640x480 pairs.

One unit of ``pcreg evaluate sequence`` (a dataset at k = 1, one backend) is run with and without a
:class:`pcreg.recording.recorder.Recorder`, alternating, ``--repeats`` times: the same code path as
``pcreg evaluate sequence --record`` (images as JPEG, the transform, labels, error series, ICP
iterations). The ratio is median(on) / median(off).

    python tools/bench_recording.py --out out/bench [--pairs 100] [--repeats 3] [--data synthetic:syn1a]

Writes ``recording.json`` and ``recording.md`` to ``--out``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from benchlib import checks_markdown, machine_info, write_report

TARGET_RATIO = 1.10
TARGET_MB_PER_100 = 15.0


def main(argv: list[str] | None = None) -> int:
    from pcreg.experiments import sequence
    from pcreg.experiments.units import Unit, load_cached
    from pcreg.outputs import markdown_table
    from pcreg.recording.recorder import DEFAULT_JPEG_QUALITY, Recorder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench", help="folder for recording.json / recording.md (default out/bench)")
    ap.add_argument("--pairs", type=int, default=100, help="recorded pairs per run (default 100)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--data", default="synthetic:syn1a", help="one sequence (default synthetic:syn1a, 640x480)")
    ap.add_argument("--backend", default="reference")
    args = ap.parse_args(argv)
    # The first 10% of a sequence choose the fusion weight and are not scored (nor recorded).
    frames = int(round(args.pairs / 0.9)) + 2
    synthetic = args.data.startswith("synthetic")
    config = sequence.SequenceConfig(data=args.data, increments=(1,), backends=(args.backend,),
                                     frames=frames if synthetic else None, size=(640, 480) if synthetic else None)
    name = next(iter(load_cached(args.data, frames=config.frames, size=config.size, seed=0)))
    unit = Unit(f"{name}/k1_{args.backend}", name, (("k", 1), ("backend", args.backend)), config)
    sequence.run_unit(unit)  # warm-up: imports, caches, compiled kernels
    off, on, sizes, pairs = [], [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            t0 = time.perf_counter()
            res = sequence.run_unit(unit)
            off.append(time.perf_counter() - t0)
            pairs = len(res["pairs"])
            path = Path(tmp) / f"run{r}.rrd"
            t0 = time.perf_counter()
            with Recorder(path, recording_name=f"bench {r}") as rec:
                sequence.run_unit(unit, recorder=rec, frame_counter=[0])
            on.append(time.perf_counter() - t0)  # the file is complete when the recorder closes
            sizes.append(path.stat().st_size)
    t_off, t_on = statistics.median(off), statistics.median(on)
    mb_per_100 = statistics.median(sizes) / 1e6 * 100.0 / max(1, pairs)
    report = {"data": args.data, "sequence": name, "backend": args.backend, "pairs": pairs,
              "jpeg_quality": DEFAULT_JPEG_QUALITY, "repeats": args.repeats, "seconds_off": off, "seconds_on": on,
              "ms_per_pair_off": 1e3 * t_off / max(1, pairs), "ms_per_pair_on": 1e3 * t_on / max(1, pairs),
              "overhead_ratio": t_on / t_off, "recording_mb": statistics.median(sizes) / 1e6,
              "recording_mb_per_100_pairs": mb_per_100,
              "targets": {"overhead_ratio_max": TARGET_RATIO, "recording_mb_per_100_pairs_max": TARGET_MB_PER_100},
              "machine": machine_info()}
    text = (f"### Recording cost: `pcreg evaluate sequence` unit ({name}, k = 1, {args.backend}), "
            f"median of {args.repeats} alternating runs\n\n"
            + markdown_table(["pairs", "ms/pair off", "ms/pair on", "ratio on/off", "MB per 100 pairs"],
                             [[pairs, report["ms_per_pair_off"], report["ms_per_pair_on"], report["overhead_ratio"],
                               mb_per_100]], digits=3)
            + "\n" + checks_markdown([
                (f"recording adds at most {100 * (TARGET_RATIO - 1):.0f}%", f"{report['overhead_ratio']:.3f}x",
                 report["overhead_ratio"] <= TARGET_RATIO),
                (f"at most {TARGET_MB_PER_100:g} MB per 100 pairs", f"{mb_per_100:.1f} MB", mb_per_100 <= TARGET_MB_PER_100),
            ]))
    write_report(args.out, "recording", report, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
