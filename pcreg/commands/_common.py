"""Options and helpers shared by the command modules."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from pathlib import Path
from typing import Any

from ..validation import range_text


def arg_int(lo: int | None = None, hi: int | None = None):
    """An argparse ``type=`` for an integer in [lo, hi]."""

    def parse(text: str) -> int:
        try:
            v = int(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"expected an integer {'' if hi is None else 'in '}{range_text(lo, hi)}, got {v}")
        return v

    parse.__name__ = "integer"
    return parse


def arg_float(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False):
    """An argparse ``type=`` for a finite number in the range (``lo_open``: > lo)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and (v >= hi if hi_open else v > hi)):
            lo_s = "-inf" if lo is None else f"{lo:g}"
            hi_s = "inf" if hi is None else f"{hi:g}"
            raise argparse.ArgumentTypeError(f"expected a number in {'(' if lo_open else '['}{lo_s}, {hi_s}"
                                             f"{')' if hi_open else ']'}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


#: The largest side of a headless screenshot, points: 8192x8192 took 18 s with the software renderer here,
#: 16384x16384 ran out the viewer's deadline after 23 s instead of failing at once.
MAX_WINDOW_SIDE = 8192


def arg_window_size(text: str) -> str:
    """``"1600x900"``: a window size in points, each side 16..:data:`MAX_WINDOW_SIDE`; returned as the same text."""
    try:
        w, h = (int(v) for v in text.strip().lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if not (16 <= w <= MAX_WINDOW_SIDE and 16 <= h <= MAX_WINDOW_SIDE):
        raise argparse.ArgumentTypeError(f"each side must be in 16..{MAX_WINDOW_SIDE}, got {text!r}")
    return f"{w}x{h}"


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1 or v > 100_000:  # the library's limit on iterations
        raise argparse.ArgumentTypeError(f"expected a positive integer (at most 100000), got {v}")
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


#: What ``--force`` does for a command that resumes an earlier run in its ``--out`` (the evaluations, ``run``).
START_OVER = "start over: discard what an earlier run in --out finished, and overwrite the recording"


def add_record_arguments(p: argparse.ArgumentParser, *, force: str = "overwrite existing output files") -> None:
    g = p.add_argument_group("recording")
    g.add_argument("--record", metavar="FILE.rrd", help="write a rerun recording of every stage")
    g.add_argument("--record-raw", action="store_true", help="log images losslessly instead of JPEG")
    g.add_argument("--force", action="store_true", help=force)


def open_recorder(args: argparse.Namespace, *, name: str, layout: bool | str = True, inputs: tuple = ()):
    """A :class:`pcreg.recording.recorder.Recorder` for ``--record``, or the null recorder (in a null context):
    :func:`pcreg.recording.recorder.open_recording` (``inputs``: the command's files, which it must not be)."""
    from ..recording.null import NULL_RECORDER

    if not getattr(args, "record", None):
        return contextlib.nullcontext(NULL_RECORDER)
    from ..recording.recorder import open_recording

    return open_recording(args.record, name=name, raw=args.record_raw, force=args.force, layout=layout, inputs=inputs)


def init_refusal(exc: Exception, path: str):
    """An ``init ...`` refusal (``pcreg.icp``'s, ``pcreg.register``'s, ``pcreg.crosscheck``'s) of a matrix read from
    ``path`` (``--init FILE``), said of the file as one :class:`~pcreg.errors.InputError`: ``init must be ...`` as
    ``PATH: the initial guess must be ...``, ``init: WHY`` as ``PATH: the initial guess: WHY``; None for any other."""
    from ..errors import InputError

    said = str(exc)
    if not isinstance(exc, InputError) or not said.startswith("init"):
        return None
    return InputError(f"{path}: the initial guess{said[len('init'):]}")


def print_json(obj) -> None:
    """``obj`` as one JSON object on stdout, flushed: a stdout that refuses it (``> /dev/full``) fails here, in
    the command, and the program's stdout names itself in the error (:mod:`pcreg.cli`)."""
    from ..outputs import to_json

    sys.stdout.write(to_json(obj, strict=True) + "\n")  # NaN -> null: valid JSON for any reader
    sys.stdout.flush()


# ---------------------------------------------------------------------------------------------
# options of the evaluations
# ---------------------------------------------------------------------------------------------

BACKEND_CHOICES = ("reference", "open3d", "both")
MAX_SIDE = 8192  # synthetic frames: 8192x8192 RGB is 200 MB a frame
MAX_FRAMES = 100_000


def backends(value: str) -> tuple[str, ...]:
    """``--backend`` value -> backends to run, in order (``both``: reference, then open3d)."""
    return ("reference", "open3d") if value == "both" else (value,)


def int_list(text: str) -> tuple[int, ...]:
    """``"1,4,7,10"`` -> (1, 4, 7, 10); every value >= 1."""
    try:
        vals = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not vals or any(v < 1 or v > MAX_FRAMES for v in vals):
        raise argparse.ArgumentTypeError(f"expected comma-separated integers in 1..{MAX_FRAMES}, got {text!r}")
    return vals


def angle_list(text: str) -> tuple[float, ...]:
    """``"0,5,90"`` or ``"0:180:5"`` (start:stop:step, stop included) -> angles in degrees."""
    import numpy as np

    from ..validation import MAX_UNITS

    try:
        if ":" in text:
            a, b, s = (float(v) for v in text.split(":"))
            if not (np.isfinite(a) and np.isfinite(b) and np.isfinite(s)) or s <= 0:
                raise ValueError
            if abs(a) > 360 or abs(b) > 360:
                raise argparse.ArgumentTypeError(f"angles must be within +-360 degrees, got {text!r}")
            count = int(np.floor((b - a) / s + 0.5)) + 1 if b >= a else 0
            if count > MAX_UNITS:  # counted before anything is allocated
                raise argparse.ArgumentTypeError(f"{text!r} gives {count} angles; the limit is {MAX_UNITS}")
            vals = tuple(float(v) for v in np.round(np.arange(a, b + s / 2, s), 6))
        else:
            vals = tuple(float(v) for v in text.split(",") if v.strip())
            if len(vals) > MAX_UNITS:
                raise argparse.ArgumentTypeError(f"{len(vals)} angles; the limit is {MAX_UNITS}")
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected angles as A,B,C or START:STOP:STEP, got {text!r}") from None
    if not vals:  # "10:0:5" (stop below start) or ","
        raise argparse.ArgumentTypeError(f"{text!r} gives no angle (START:STOP:STEP needs STOP >= START)")
    if any(not np.isfinite(v) or abs(v) > 360 for v in vals):
        raise argparse.ArgumentTypeError(f"angles must be within +-360 degrees, got {text!r}")
    return vals


def size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 16 or h < 12:
        raise argparse.ArgumentTypeError(f"frames must be at least 16x12, got {text!r}")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise argparse.ArgumentTypeError(f"synthetic frames are at most {MAX_SIDE}x{MAX_SIDE}, got {text!r}")
    return (w, h)


def train(text: str) -> str:
    """``reference`` or ``first:K``."""
    t = text.strip().lower()
    if t == "reference":
        return t
    if t.startswith("first:") and t[6:].isdigit() and int(t[6:]) >= 1:
        return f"first:{int(t[6:])}"
    raise argparse.ArgumentTypeError(f"--train must be 'reference' or 'first:K' with K >= 1, got {text!r}")


#: --data's help, the same on every evaluation (classification's included: every one reads every kind).
DATA_HELP = ("synthetic | synthetic:syn1a,syn2b | camvid:PATH | folder:PATH | davis:PATH[:val|train|all] | lagr:PATH "
             "(default synthetic; davis at an official root: DAVIS 2016 val when its ImageSets names it, :train or "
             ":all for others)")


def add_data_arguments(parser: argparse.ArgumentParser) -> None:
    """--data, --frames, --size, --seed: which sequences an evaluation runs on."""
    parser.add_argument("--data", default="synthetic", help=DATA_HELP)
    parser.add_argument("--frames", type=arg_int(1, MAX_FRAMES), default=None,
                        help="frames per synthetic sequence (default 100); first frames of real ones (default all)")
    parser.add_argument("--size", type=size, default=None, metavar="WxH", help="synthetic frame size (default 640x480; real frames keep their own)")
    parser.add_argument("--seed", type=arg_int(0, 2**32 - 1), default=None,
                        help="seed of the synthetic data (default 0; real frames take none)")


def synthetic_size(args: argparse.Namespace) -> tuple[int, int] | None:
    """``--size``, which sizes synthetic frames: refused beside a real ``--data`` before anything is written
    (:func:`~pcreg.datasets.check_data_size`)."""
    from ..datasets import check_data_size

    check_data_size(args.data, args.size)
    return args.size


def synthetic_seed(args: argparse.Namespace) -> int:
    """``--seed`` (0 when not given), which seeds synthetic frames: refused beside a real ``--data`` before anything
    is written (:func:`~pcreg.datasets.check_data_seed`)."""
    from ..datasets import check_data_seed

    check_data_seed(args.data, args.seed)
    return 0 if args.seed is None else args.seed


def add_run_arguments(parser: argparse.ArgumentParser, *, out: str) -> None:
    """--backend, --levels, --iterations, --workers, --scheduler, --out and the recording options."""
    parser.add_argument("--backend", choices=BACKEND_CHOICES, default="reference",
                        help="ICP backend(s) (default reference)")
    parser.add_argument("--levels", type=arg_int(1, 8), default=4, help="pyramid levels, 1..8 (default 4)")
    parser.add_argument("--iterations", type=arg_int(1, 10_000), default=14, help="ICP iterations per level (default 14)")
    parser.add_argument("--workers", type=arg_int(1, 1024), default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", default=None, help="dask.distributed scheduler address instead of local processes")
    parser.add_argument("--out", default=out, help=f"output folder (default {out})")
    add_record_arguments(parser, force=START_OVER)


def check_out_beside_data(out: Path, data: str | None) -> None:
    """An :class:`~pcreg.errors.OutputError` when an evaluation's ``--out`` is, or lies inside, its ``--data``
    folder: the report's files would replace a frame of the same name (``stream.png``), and the next run would
    read them as frames or labels."""
    from ..datasets import data_folder
    from ..errors import OutputError
    from ..formats import resolved

    given = data_folder(data)
    if given is None:  # synthetic, or no folder (the data's own check says so)
        return
    folder, target = resolved(given), resolved(out)
    if target == folder or folder in target.parents:
        raise OutputError(f"--out {out}: inside the data folder {given}, where the report's files would replace "
                          "frames or labels and be read as ones; choose a folder outside it")


def run_command(args: argparse.Namespace, config: Any, *, name: str, evaluate, write_outputs,
                also: tuple[str, ...] = ()) -> int:
    """The shared body of ``pcreg evaluate rotation|sequence|stream``: run (recording in this process, else with
    ``--workers``/``--scheduler``), write the outputs, print the first backend's table, then each table of ``also``
    (``NAME`` of ``OUT/NAME.md``) that this run wrote, then the checks."""
    from .._runner import make_executor
    from ..outputs import OutputLock
    from ._tables import printed

    out = Path(args.out)
    check_out_beside_data(out, getattr(args, "data", None))
    recording = bool(getattr(args, "record", None))
    dropped = [o for o, given in (("--workers", args.workers > 1), ("--scheduler", args.scheduler)) if given]
    if recording and dropped:
        sys.stderr.write(f"pcreg: note: --record runs every unit in this process ({' and '.join(dropped)} ignored)\n")
    with OutputLock(out):  # a second run on the same --out is refused, not raced
        with open_recorder(args, name=f"pcreg evaluate {name}", layout=name) as rec:
            with make_executor(1 if recording else args.workers, scheduler=None if recording else args.scheduler) as ex:
                results = evaluate(config, out=out, force=args.force, executor=ex, recorder=rec)
        written = write_outputs(results, out, recording=None if getattr(rec, "discarded", False) else getattr(args, "record", None))
    print(f"wrote {len(written)} files to {out}")
    print(printed((out / f"{name}_{config.backends[0]}.md").read_text()), end="")
    for table in (out / f"{t}.md" for t in also):
        if table in written:
            print(printed(table.read_text()), end="")
    print((out / "checks.md").read_text(), end="")
    return 0
