"""Options and helpers shared by the command modules."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return v


def float_list(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not vals or any(not (v > 0 and math.isfinite(v)) for v in vals):
        raise argparse.ArgumentTypeError(f"expected comma-separated positive numbers, got {text!r}")
    return vals


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("recording")
    g.add_argument("--record", metavar="FILE.rrd", help="write a rerun recording of every stage")
    g.add_argument("--record-raw", action="store_true", help="log images losslessly instead of JPEG")
    g.add_argument("--force", action="store_true", help="overwrite existing output files")


def open_recorder(args: argparse.Namespace, *, name: str, layout: bool | str = True):
    """A :class:`pcreg.recording.recorder.Recorder` for ``--record``, or a null context."""
    if not getattr(args, "record", None):
        return contextlib.nullcontext(None)
    from ..recording.recorder import Recorder

    return Recorder(args.record, recording_name=name, raw_images=args.record_raw, force=args.force,
                    blueprint=layout)


def print_json(obj) -> None:
    from .._io import to_json

    sys.stdout.write(to_json(obj, strict=True) + "\n")
