"""``pcreg evaluate stream``: label every frame of a clip from its key frame, each method side by side.

Parses the options, builds a :class:`~pcreg.experiments.stream.StreamConfig`, runs
:func:`~pcreg.experiments.stream.evaluate` and writes :mod:`~pcreg.experiments.reports.stream`.
"""

from __future__ import annotations

import argparse

from ..experiments.stream import METHODS, StreamConfig
from ..experiments.stream_classes import CLASS_METHODS
from ..experiments.stream_keys import KEY_METHODS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ._common import arg_int
    from . import _common as c

    c.add_data_arguments(parser)
    parser.add_argument("--key-every", type=arg_int(2, c.MAX_FRAMES), default=None, metavar="N",
                        help="a new key frame every N frames (default: the first frame only)")
    parser.add_argument("--keys", default=None, metavar="SPEC",
                        help="key frames anywhere, every other frame labelled from those around it, both ways: "
                             "first, first,last, every:N, spaced:N (N evenly spaced), suggest:N (chosen without truth) "
                             "or frame indices")
    parser.add_argument("--methods", default=None, metavar="M,M,...",
                        help=f"methods to run (default all: {', '.join(METHODS)}; with --keys: {', '.join(KEY_METHODS)}; "
                             f"with --classes: {', '.join(CLASS_METHODS)})")
    parser.add_argument("--classes", default=None, metavar="TABLE",
                        help="label and score every class of a table of more than two (camvid11, or a labelmap.txt or JSON "
                             "file): pixel error, per-class IoU and mIoU beside the baselines in the same classes "
                             "(default: lagr, ground and obstacle)")
    parser.add_argument("--backend", choices=("reference", "open3d"), default="reference",
                        help="ICP backend of the registrations (default reference)")
    parser.add_argument("--workers", type=arg_int(1, 1024), default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", default=None, help="dask.distributed scheduler address instead of local processes")
    parser.add_argument("--out", default="out/stream", help="output folder (default out/stream)")
    c.add_record_arguments(parser, force=c.START_OVER)


def config_from_args(args: argparse.Namespace) -> StreamConfig:
    from ..errors import InputError
    from . import _common as c

    classes = _many_classes(getattr(args, "classes", None))
    allowed = CLASS_METHODS if classes is not None else METHODS if args.keys is None else KEY_METHODS
    if classes is not None and args.key_every is not None:
        raise InputError("--classes takes its key frames from --keys (first by default), not --key-every")
    if args.keys is not None and args.key_every is not None:
        raise InputError("--keys and --key-every choose the key frames two ways: give one")
    if args.keys is not None and not args.keys.strip():
        raise InputError("--keys: give first, first,last, every:N, spaced:N, suggest:N or frame indices")
    given = ",".join(allowed) if args.methods is None else args.methods
    methods = tuple(m.strip() for m in given.split(",") if m.strip())
    unknown = [m for m in methods if m not in allowed]
    if unknown or not methods:
        raise InputError(f"--methods: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(allowed)}")
    if "plain" not in methods:
        methods = ("plain",) + methods  # every reduction is against plain
    frames = args.frames if args.frames is not None else (40 if args.data == "synthetic" else None)
    return StreamConfig(data=args.data, frames=frames, size=c.synthetic_size(args), seed=c.synthetic_seed(args), key_every=args.key_every,
                        keys=args.keys, backends=(args.backend,), methods=tuple(m for m in allowed if m in methods),
                        classes=classes)


def _many_classes(spec: str | None) -> str | None:
    """``--classes``: the table's spec when it has more than two classes (checked here), else None (``lagr``,
    ground and obstacle, is the two-class evaluation); another table of two classes is an :class:`InputError`:
    the two-class evaluation scores the data's ground and obstacle, not that table's classes."""
    if spec is None:
        return None
    from ..classes import DEFAULT_TABLE, class_table
    from ..errors import InputError

    table = class_table(spec)
    if table.n_known > 2:
        return spec
    if not table.agrees(DEFAULT_TABLE):
        raise InputError(f"--classes {spec}: a table of {table.n_known} classes; the two-class evaluation scores "
                         "ground and obstacle (--classes lagr, the default), and a table of more classes is scored "
                         "class by class")
    return None


def run(args: argparse.Namespace) -> int:
    from ..experiments.reports.stream import write_outputs
    from ..experiments.stream import evaluate
    from ..experiments.stream_davis import is_davis
    from ._common import run_command

    if is_davis(args.data):  # which of a download's sequences, said before the run (and in its tables)
        from ..datasets.davis import select_sequences
        from ..datasets.davis_splits import parse_davis_arg

        path, split = parse_davis_arg(args.data.partition(":")[2])
        print(f"DAVIS: {select_sequences(path, split=split)[2].describe()}")
    # the headlines printed after the error table: with --classes the mIoU (OUT/stream_miou.md), on DAVIS the
    # benchmark's J and F beside its published methods
    return run_command(args, config_from_args(args), name="stream", evaluate=evaluate, write_outputs=write_outputs,
                       also=("stream_miou", "davis_J", "davis_F"))
