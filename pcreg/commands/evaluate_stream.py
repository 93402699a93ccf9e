"""``pcreg evaluate stream``: label every frame of a clip from its key frame, each method side by side.

Parses the options, builds a :class:`~pcreg.experiments.stream.StreamConfig`, runs
:func:`~pcreg.experiments.stream.evaluate` and writes :mod:`~pcreg.experiments.reports.stream`.
"""

from __future__ import annotations

import argparse

from ..experiments.stream import METHODS, StreamConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ._common import arg_int
    from . import _common as c

    c.add_data_arguments(parser)
    parser.add_argument("--key-every", type=arg_int(2, c.MAX_FRAMES), default=None, metavar="N",
                        help="a new key frame every N frames (default: the first frame only)")
    parser.add_argument("--methods", default=",".join(METHODS), metavar="M,M,...",
                        help=f"methods to run (default all: {', '.join(METHODS)})")
    parser.add_argument("--backend", choices=("reference", "open3d"), default="reference",
                        help="ICP backend of the registrations (default reference)")
    parser.add_argument("--workers", type=arg_int(1, 1024), default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", default=None, help="dask.distributed scheduler address instead of local processes")
    parser.add_argument("--out", default="out/stream", help="output folder (default out/stream)")
    c.add_record_arguments(parser)


def config_from_args(args: argparse.Namespace) -> StreamConfig:
    from ..errors import InputError

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(f"--methods: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(METHODS)}")
    if "plain" not in methods:
        methods = ("plain",) + methods  # every reduction is against plain
    frames = args.frames if args.frames is not None else (40 if args.data == "synthetic" else None)
    return StreamConfig(data=args.data, frames=frames, size=args.size, seed=args.seed, key_every=args.key_every,
                        backends=(args.backend,), methods=tuple(m for m in METHODS if m in methods))


def run(args: argparse.Namespace) -> int:
    from ..experiments.reports.stream import write_outputs
    from ..experiments.stream import evaluate
    from ._common import run_command

    return run_command(args, config_from_args(args), name="stream", evaluate=evaluate, write_outputs=write_outputs)
