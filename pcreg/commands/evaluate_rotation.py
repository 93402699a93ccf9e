"""``pcreg evaluate rotation``: thesis Ch. 5, rotated frames classified before and after registering them back.

Parses the options, builds a :class:`~pcreg.experiments.rotation.RotationConfig`, runs
:func:`~pcreg.experiments.rotation.evaluate` and writes :mod:`~pcreg.experiments.reports.rotation`.
"""

from __future__ import annotations

import argparse

from ..experiments.rotation import DEFAULT_ANGLES, RotationConfig
from ..registration.config import RegisterConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import _common as c

    c.add_data_arguments(parser)
    parser.add_argument("--angles", type=c.angle_list, default=DEFAULT_ANGLES, metavar="A,B,...|START:STOP:STEP",
                        help="rotation angles in degrees (default 0:180:5)")
    parser.add_argument("--samples", type=int, default=3, help="frames per dataset, evenly spaced (default 3)")
    parser.add_argument("--canvas", choices=("loose", "crop"), default="loose",
                        help="loose: the rotated frame is kept whole (default); crop: original size")
    c.add_run_arguments(parser, out="out/rotation")


def config_from_args(args: argparse.Namespace) -> RotationConfig:
    from ..errors import InputError
    from . import _common as c

    if args.samples < 1:
        raise InputError("--samples must be at least 1")
    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    if args.levels < 1 or args.levels > 8 or args.iterations < 1:
        raise InputError("--levels must be in 1..8 and --iterations at least 1")
    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    return RotationConfig(data=args.data, angles=tuple(args.angles), samples=args.samples, canvas=args.canvas,
                          backends=c.backends(args.backend), frames=args.frames, size=c.synthetic_size(args), seed=c.synthetic_seed(args),
                          registration=RegisterConfig.of(levels=args.levels, iterations=args.iterations))


def run(args: argparse.Namespace) -> int:
    from ..experiments.reports.rotation import write_outputs
    from ..experiments.rotation import evaluate
    from ._common import run_command

    return run_command(args, config_from_args(args), name="rotation", evaluate=evaluate, write_outputs=write_outputs)

