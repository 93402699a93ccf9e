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
    from .._runner import check_workers
    from ..recording.sink import check_path

    out = Path(args.out)
    config = DemoConfig(frames=args.frames)
    check_output(out / "report.md", force=args.force)
    if not args.force:
        check_no_other_results(out)
    check_workers(args.workers)  # each before the first file is written
    record = None if args.no_record else Path(args.record or out / "demo.rrd")
    if record is not None:
        # OUT/demo.rrd without OUT/report.md (refused above unless --force) is what an interrupted demo
        # left: the rerun replaces it
        check_path(record, force=args.force or args.record is None)
    from ..outputs import OutputLock

    t0 = time.perf_counter()
    with OutputLock(out):  # a second demo on the same --out is refused, not raced
        report = run_demo(config, out=out, workers=args.workers, record=record, raw_images=args.record_raw)
    print(f"demo finished in {time.perf_counter() - t0:.0f} s: {report}")
    return 0




#: The folders of ``OUT`` the demo's evaluations write (each resumable evaluation's ``--out``).
STAGES = ("classification", "rotation", "sequence", "stream")


def check_no_other_results(out: Path) -> None:
    """An :class:`~pcreg.errors.OutputError` when ``out`` holds what the demo would replace and did not write: a
    config.json that is not a demo's, or a stage folder (:data:`STAGES`) holding an evaluation's results without
    the demo's config.json beside it (``pcreg demo --out out`` beside ``pcreg evaluate classification``'s default
    ``out/classification``). An interrupted demo's folder is the demo's: a rerun replaces it."""
    from dataclasses import fields

    from ..errors import OutputError
    from ..experiments.demo import DemoConfig
    from ..formats import loads_json

    config = out / "config.json"
    if config.exists():
        try:
            ours = set(loads_json(config.read_text(encoding="utf-8"))) == {f.name for f in fields(DemoConfig)}
        except (OSError, ValueError, TypeError):
            ours = False
        if not ours:
            raise OutputError(f"{config} is not a demo's: {out} holds another command's results, which the demo "
                              "would replace (use another --out, or --force to replace them)")
        return
    for stage in STAGES:
        if (out / stage / "config.json").exists() or (out / stage / "units").exists():
            raise OutputError(f"{out / stage} holds an evaluation's results, which the demo would replace (use "
                              "another --out, or --force to replace them)")
