"""``pcreg evaluate classification``: thesis Ch. 4, naive Bayes alone (cases I-III and the weight search).

Parses the options, builds a :class:`~pcreg.experiments.classification.ClassificationConfig`, runs
:func:`~pcreg.experiments.classification.evaluate` (resumable: finished units are kept in OUT/units/)
and writes :mod:`~pcreg.experiments.reports.classification`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..experiments.classification import CASES, DEFAULT_FEATURE_SETS, ClassificationConfig



def _cases(text: str) -> tuple[str, ...]:
    vals = tuple(v.strip().upper() for v in text.split(",") if v.strip())
    bad = [v for v in vals if v not in CASES]
    if bad or not vals:
        raise argparse.ArgumentTypeError(f"cases are I, II, III (comma-separated), got {text!r}")
    return tuple(c for c in CASES if c in vals)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import _common as c

    parser.add_argument("--data", default="synthetic", help=c.DATA_HELP)
    parser.add_argument("--cases", type=_cases, default=CASES, help="cases to run, e.g. I,III (default I,II,III)")
    parser.add_argument("--features", nargs="+", default=list(DEFAULT_FEATURE_SETS), metavar="SET",
                        help="feature sets, each names joined by + from thesis, rgb, hsv, lab, texture, row "
                             "(default: thesis rgb+hsv+row)")
    parser.add_argument("--k", dest="case1_k", type=c.int_list, default=(), metavar="K,K,...",
                        help="Case I training frame counts (default 10%%..90%% of each sequence: 10..90 of 100)")
    parser.add_argument("--k3", dest="case3_k", type=c.int_list, default=(), metavar="K,K,...",
                        help="Case III frames per dataset (default 10%% and 20%% of each sequence)")
    from ._common import arg_int

    parser.add_argument("--frames", type=arg_int(1, c.MAX_FRAMES), default=None, help="frames per synthetic sequence (default 100); "
                        "first frames of real sequences (default all)")
    parser.add_argument("--size", type=c.size, default=None, metavar="WxH", help="synthetic frame size (default 640x480; real frames keep their own)")
    parser.add_argument("--trials", type=arg_int(1, 100_000), default=30, help="weight-search trials for the thesis feature (default 30)")
    parser.add_argument("--seed", type=arg_int(0, 2**32 - 1), default=0, help="seed of the weight search and synthetic data (default 0)")
    parser.add_argument("--workers", type=arg_int(1, 1024), default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", default=None, help="dask.distributed scheduler address instead of local processes")
    parser.add_argument("--out", default="out/classification", help="output folder (default out/classification)")
    parser.add_argument("--force", action="store_true", help="discard finished units and outputs of an earlier run")


def config_from_args(args: argparse.Namespace) -> ClassificationConfig:
    from ..errors import InputError
    from . import _common as c
    from ..classification.features import parse_features

    feats = tuple("+".join(parse_features(f)) for f in args.features)
    seen: dict[frozenset, str] = {}
    for f in feats:  # naive Bayes multiplies its features' likelihoods: their order changes nothing
        same = seen.get(frozenset(f.split("+")))
        if same == f:
            raise InputError(f"--features lists {f} twice")
        if same is not None:
            raise InputError(f"--features lists one feature set twice ({same} and {f}: the order of a set's features "
                             "changes nothing)")
        seen[frozenset(f.split("+"))] = f
    if args.trials < 1:
        raise InputError("--trials must be at least 1")
    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    return ClassificationConfig(data=args.data, cases=tuple(args.cases), features=feats,
                                case1_k=tuple(args.case1_k), case3_k=tuple(args.case3_k), n_trials=args.trials,
                                seed=args.seed, frames=args.frames, size=c.synthetic_size(args))


def run(args: argparse.Namespace) -> int:
    from .._runner import make_executor
    from ..experiments.classification import evaluate
    from ..experiments.reports.classification import write_outputs

    from ..outputs import OutputLock
    from ._common import check_out_beside_data
    from ._tables import printed

    config = config_from_args(args)
    out = Path(args.out)
    check_out_beside_data(out, args.data)
    with OutputLock(out):  # a second run on the same --out is refused, not raced
        with make_executor(args.workers, scheduler=args.scheduler) as executor:
            results = evaluate(config, out=out, force=args.force, executor=executor)
        written = write_outputs(results, out)
    print(f"wrote {len(written)} files to {out}")
    print(printed((out / "case1.md").read_text()) if "I" in config.cases else "", end="")
    return 0
