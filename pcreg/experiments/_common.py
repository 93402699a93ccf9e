"""Helpers shared by the registration evaluations (rotation, sequence, demo).

- a per-process cache of loaded datasets (units of work run in worker processes);
- option parsers (``--increments``, ``--angles``, ``--size``, ``--backend``, ``--train``);
- :class:`UnitStore`: finished units kept as JSON files in the output folder, so that a rerun with the
  same configuration skips them (an interrupted run resumes) and a different configuration is refused
  unless ``--force``.
"""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any

BACKEND_CHOICES = ("reference", "open3d", "both")

_DATA_CACHE: dict = {}


def load_cached(data: str, *, frames: int | None, size: tuple[int, int] | None, seed: int) -> dict:
    """:func:`pcreg.datasets.load_dataset`, cached per process (one data set at a time)."""
    key = (data, frames, tuple(size) if size else None, seed)
    if key not in _DATA_CACHE:
        from ..datasets import load_dataset

        _DATA_CACHE.clear()
        _DATA_CACHE[key] = load_dataset(data, n_frames=frames, size=tuple(size) if size else None, seed=seed)
    return _DATA_CACHE[key]


def backends(value: str) -> tuple[str, ...]:
    """``--backend`` value -> backends to run, in order (``both``: reference, then open3d)."""
    return ("reference", "open3d") if value == "both" else (value,)


def int_list(text: str) -> tuple[int, ...]:
    """``"1,4,7,10"`` -> (1, 4, 7, 10); every value >= 1."""
    try:
        vals = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not vals or any(v < 1 for v in vals):
        raise argparse.ArgumentTypeError(f"expected comma-separated integers >= 1, got {text!r}")
    return vals


def angle_list(text: str) -> tuple[float, ...]:
    """``"0,5,90"`` or ``"0:180:5"`` (start:stop:step, stop included) -> angles in degrees."""
    import numpy as np

    try:
        if ":" in text:
            a, b, s = (float(v) for v in text.split(":"))
            if s <= 0:
                raise ValueError
            vals = tuple(float(v) for v in np.round(np.arange(a, b + s / 2, s), 6))
        else:
            vals = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected angles as A,B,C or START:STOP:STEP, got {text!r}") from None
    if not vals or any(abs(v) > 360 for v in vals):
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
    return (w, h)


def train(text: str) -> str:
    """``reference`` or ``first:K``."""
    t = text.strip().lower()
    if t == "reference":
        return t
    if t.startswith("first:") and t[6:].isdigit() and int(t[6:]) >= 1:
        return f"first:{int(t[6:])}"
    raise argparse.ArgumentTypeError(f"--train must be 'reference' or 'first:K' with K >= 1, got {text!r}")


def angle_key(angle: float) -> str:
    """JSON key of an angle: ``"90"``, ``"2.5"``."""
    return f"{angle:g}"


def plain_config(config: Any) -> dict:
    """A frozen dataclass config as JSON-ready dict (tuples as lists)."""
    return json.loads(json.dumps(asdict(config), default=str))


class UnitStore:
    """Finished units of one evaluation, one JSON file each under ``out/units/``.

    Opening the store compares ``config`` with ``out/config.json``: the same configuration resumes
    (finished units are loaded, not rerun); a different one raises :class:`~pcreg.errors.OutputError`
    unless ``force``, which clears the old units. ``force`` with the same configuration reruns all.
    """

    def __init__(self, out: str | Path, config: dict, *, force: bool) -> None:
        from .._io import atomic_write_json
        from ..errors import OutputError

        self.out = Path(out)
        self.dir = self.out / "units"
        cfg_path = self.out / "config.json"
        if self.out.exists() and not self.out.is_dir():
            raise OutputError(f"{self.out} exists and is not a folder")
        old = None
        if cfg_path.is_file():
            try:
                old = json.loads(cfg_path.read_text())
            except (OSError, ValueError):
                old = None
        if force:
            if self.dir.is_dir():
                shutil.rmtree(self.dir)
        elif old is not None and old != config:
            raise OutputError(f"{self.out} holds results of a different configuration "
                              "(use --force to replace them, or another --out)")
        elif old is None and (self.out / "results.json").exists():
            raise OutputError(f"{self.out}/results.json exists without a readable config.json (use --force)")
        atomic_write_json(cfg_path, config)

    def path(self, key: str) -> Path:
        return self.dir / f"{key}.json"

    def load(self, key: str) -> dict | None:
        """The finished unit ``key``, or None (a damaged file counts as not finished)."""
        p = self.path(key)
        if not p.is_file():
            return None
        try:
            return json.loads(p.read_text())
        except (OSError, ValueError):
            return None

    def save(self, key: str, result: dict) -> None:
        from .._io import atomic_write_json

        atomic_write_json(self.path(key), result)


def add_data_arguments(parser: argparse.ArgumentParser) -> None:
    """--data, --frames, --size, --seed: which sequences an evaluation runs on."""
    parser.add_argument("--data", default="synthetic",
                        help="synthetic | synthetic:syn1a,syn2b | camvid:PATH | folder:PATH | lagr:PATH (default synthetic)")
    parser.add_argument("--frames", type=int, default=None,
                        help="frames per synthetic sequence (default 100); first frames of real ones (default all)")
    parser.add_argument("--size", type=size, default=None, metavar="WxH", help="synthetic frame size (default 640x480)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic data (default 0)")


def add_run_arguments(parser: argparse.ArgumentParser, *, out: str) -> None:
    """--backend, --levels, --iterations, --workers, --scheduler, --out and the recording options."""
    from ..commands._common import add_record_arguments, positive_int

    parser.add_argument("--backend", choices=BACKEND_CHOICES, default="reference",
                        help="ICP backend(s) (default reference)")
    parser.add_argument("--levels", type=positive_int, default=4, help="pyramid levels (default 4)")
    parser.add_argument("--iterations", type=positive_int, default=14, help="ICP iterations per level (default 14)")
    parser.add_argument("--workers", type=positive_int, default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", default=None, help="dask.distributed scheduler address instead of local processes")
    parser.add_argument("--out", default=out, help=f"output folder (default {out})")
    add_record_arguments(parser)


def run_command(args: argparse.Namespace, config: Any, *, name: str, evaluate, write_outputs) -> int:
    """The shared body of ``pcreg evaluate rotation|sequence``: run (recording in this process, else with
    ``--workers``/``--scheduler``), write the outputs, print the first backend's table and the floors."""
    from ..commands._common import open_recorder
    from .._runner import make_executor

    out = Path(args.out)
    recording = bool(getattr(args, "record", None))
    if recording and args.workers > 1:
        print("note: --record runs every unit in this process (--workers ignored)")
    with open_recorder(args, name=f"pcreg evaluate {name}") as rec:
        with make_executor(1 if recording else args.workers, scheduler=None if recording else args.scheduler) as ex:
            results = evaluate(config, out=out, force=args.force, executor=ex, recorder=rec)
    written = write_outputs(results, out)
    print(f"wrote {len(written)} files to {out}")
    print((out / f"{name}_{config.backends[0]}.md").read_text(), end="")
    print((out / "floors.md").read_text(), end="")
    return 0


def run_resumable(units: list, run_unit, *, store: "UnitStore | None", cfg_dict: dict, recorder=None,
                  executor=None, desc: str = "", show_progress: bool | None = None) -> tuple[dict, int]:
    """Run the units not finished yet (``store`` keeps each result as it lands), in this process when
    recording (one recorder, frames in order), else through ``executor``.

    Returns the results by unit key (finished and new) and how many came from an earlier run.
    """
    from .._runner import _InlineExecutor, run_units

    done: dict[str, dict] = {}
    todo = []
    for u in units:
        prev = store.load(u.key) if store is not None else None
        if prev is not None:
            done[u.key] = prev
        else:
            todo.append(u)

    def keep(unit, result: dict) -> None:
        done[unit.key] = result
        if store is not None:
            store.save(unit.key, result)

    if recorder is not None:
        recorder.log_config(cfg_dict)
        counter = [0]
        for u in todo:
            keep(u, run_unit(u, recorder=recorder, frame_counter=counter))
    else:
        run_units(run_unit, todo, executor=executor or _InlineExecutor(), desc=desc, on_result=keep,
                  show_progress=show_progress)
    return done, len(units) - len(todo)


def nan_to_none(obj: Any) -> Any:
    """Replace float NaN/inf with None (strict JSON for results.json)."""
    import math

    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [nan_to_none(v) for v in obj]
    return obj


METHOD_STYLE = {
    "plain": ("naive Bayes (plain)", "#444444", "-"),
    "thesis_before": ("thesis: before registration", "#d62728", ":"),
    "thesis_after": ("thesis: after registration", "#ff7f0e", "--"),
    "thesis_after_masked": ("after, border from unwarped frame", "#bcbd22", "-."),
    "thesis_after_cropped": ("after, border left out", "#8c564b", "-."),
    "augmented": ("augmented (registered label prior)", "#1f77b4", "-"),
    "augmented_unregistered": ("augmented, prior not registered", "#17becf", "--"),
    "augmented_temporal": ("augmented, temporal", "#9467bd", "-"),
    "augmented_flow": ("augmented, prior warped by DIS flow", "#e377c2", "--"),
    "propagated": ("warped labels alone", "#2ca02c", ":"),
}
