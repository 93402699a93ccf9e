"""``pcreg evaluate sequence``: thesis Ch. 6-7, register frame i+k to frame i, classify, propagate labels.

Parses the options, builds a :class:`~pcreg.experiments.sequence.SequenceConfig`, runs
:func:`~pcreg.experiments.sequence.evaluate` and writes :mod:`~pcreg.experiments.reports.sequence`.
"""

from __future__ import annotations

import argparse

from ..experiments.sequence import DEFAULT_INCREMENTS, SequenceConfig, SequenceFusion
from ..pipeline import PIPELINE_REGISTRATION

def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import _common as c

    c.add_data_arguments(parser)
    parser.add_argument("--increments", "-k", type=c.int_list, default=DEFAULT_INCREMENTS, metavar="K,K,...",
                        help="frame increments k (default 1,4,7,10)")
    parser.add_argument("--train", type=c.train, default="reference",
                        help="reference (train on each pair's reference frame, default) or first:K")
    from ..classification.fusion import MAX_WEIGHT
    from ._common import arg_float, arg_int

    parser.add_argument("--fusion-frames", type=arg_int(0, c.MAX_FRAMES), default=None, metavar="C",
                        help="frames at the start of each sequence that choose the fusion weight and are not "
                             "scored (default: the training frames for first:K, else 10%% of the sequence, >= 2)")
    parser.add_argument("--fusion-weight", type=arg_float(0, MAX_WEIGHT), default=None, metavar="W",
                        help="fixed fusion weight instead of choosing it on the fusion frames")
    parser.add_argument("--init", choices=("identity", "auto"), default="identity",
                        help="registration start: identity (default) or auto (global rotation search)")
    parser.add_argument("--model", default="similarity",
                        help="motion model: similarity (default), translation, rigid, affine, projective, or "
                             "dense (the similarity refined by a dense field, pcreg.register_dense)")
    c.add_run_arguments(parser, out="out/sequence")


def config_from_args(args: argparse.Namespace) -> SequenceConfig:
    from ..errors import InputError
    from ..registration.transforms import MODELS
    from . import _common as c

    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    if args.fusion_frames is not None and args.fusion_frames < 0:
        raise InputError("--fusion-frames must be >= 0")
    if args.fusion_weight is not None and not args.fusion_weight >= 0:
        raise InputError("--fusion-weight must be >= 0")
    if args.levels < 1 or args.levels > 8 or args.iterations < 1:
        raise InputError("--levels must be in 1..8 and --iterations at least 1")
    if args.model not in MODELS + ("dense",):
        raise InputError(f"--model must be one of {', '.join(MODELS + ('dense',))}")
    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    if args.frames is not None and args.fusion_frames is not None and args.fusion_frames > args.frames:
        raise InputError(f"--fusion-frames {args.fusion_frames} is more than --frames {args.frames}")
    registration = PIPELINE_REGISTRATION.replace(levels=args.levels, iterations=args.iterations, init=args.init,
                                                 model=args.model)
    for backend in c.backends(args.backend):  # a model a backend cannot fit is refused before any unit runs
        registration.replace(backend=backend)
    return SequenceConfig(data=args.data, increments=tuple(sorted(set(args.increments))),
                          backends=c.backends(args.backend), frames=args.frames, size=c.synthetic_size(args), seed=c.synthetic_seed(args),
                          train=args.train, fusion=SequenceFusion(frames=args.fusion_frames, weight=args.fusion_weight),
                          registration=registration)


def run(args: argparse.Namespace) -> int:
    from ..experiments.reports.sequence import write_outputs
    from ..experiments.sequence import evaluate
    from ._common import run_command

    return run_command(args, config_from_args(args), name="sequence", evaluate=evaluate, write_outputs=write_outputs)

