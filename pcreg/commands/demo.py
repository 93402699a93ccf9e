"""``pcreg demo``: the whole story on small built-in synthetic data (what ``make demo`` runs), in under a minute on 2 cores once set up.

Writes OUT/report.md (tables and figures), one folder per experiment and OUT/demo.rrd.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ._common import add_record_arguments

    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    from ._common import arg_int

    parser.add_argument("--workers", type=arg_int(1, 1024), default=2, help="processes for Ch. 4 and 5 (default 2)")
    parser.add_argument("--frames", type=int, default=16, help="frames per synthetic sequence (default 16)")
    parser.add_argument("--no-record", action="store_true", help="do not write OUT/demo.rrd")
    add_record_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..outputs import check_output
    from ..errors import InputError
    from ..experiments.demo import DemoConfig, run_demo

    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    if args.frames < 8:
        raise InputError("--frames must be at least 8 (the demo's increments go up to 7)")
    if args.frames > 10_000:
        raise InputError(f"--frames must be at most 10000, got {args.frames}")
    if args.no_record and (args.record or args.record_raw):
        raise InputError(f"--no-record with {'--record' if args.record else '--record-raw'}: choose one")
    out = Path(args.out)
    config = DemoConfig(frames=args.frames)
    check_output(out / "report.md", force=args.force)
    record = None if args.no_record else Path(args.record or out / "demo.rrd")
    if record is not None:
        # OUT/demo.rrd without OUT/report.md (refused above unless --force) is what an interrupted demo
        # left: the rerun replaces it
        check_output(record, force=args.force or args.record is None)
    from ..outputs import OutputLock

    t0 = time.perf_counter()
    with OutputLock(out):  # a second demo on the same --out is refused, not raced
        report = run_demo(config, out=out, workers=args.workers, record=record, raw_images=args.record_raw)
    print(f"demo finished in {time.perf_counter() - t0:.0f} s: {report}")
    return 0


