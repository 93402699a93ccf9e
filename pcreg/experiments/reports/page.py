"""An evaluation's output folder as data for the report page (``pcreg view OUT_DIR --web``).

:func:`load_report` reads the folder (results.json, config.json, checks.md, the figures); :func:`page_data`
turns it into what the page shows: the tables, built from results.json by the same functions that write
the Markdown and CSV tables, each row with the frame of the run's recording it corresponds to (from the
units' ``recording_frames``; ``None`` where the recording does not hold it), the checks and the figures.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

from ...errors import InputError
from ...formats import file_of, loads_json
from .files import recordings

__all__ = ["Report", "load_report", "page_data", "EXPERIMENTS"]

#: What each experiment's page is called.
EXPERIMENTS = {
    "sequence": "Sequence: register frame i+k to i, classify, fuse labels",
    "rotation": "Rotation: classify rotated frames before and after registration",
    "stream": "Stream: label every frame of a clip from its key frame",
    "classification": "Classification: naive Bayes cases I-III",
}

#: Files of the folder the page may fetch besides the figures.
TEXT_SUFFIXES = (".md", ".csv", ".json")


@dataclass(frozen=True)
class Report:
    """An output folder, read: which experiment, its results and config, checks.md, its figures' and
    other files' names, and the recording (.rrd) its run wrote in it."""

    folder: Path
    experiment: str
    results: dict
    config: dict
    checks: str | None
    figures: tuple[str, ...]
    files: tuple[str, ...]
    recordings: tuple[Path, ...]


def _experiment(results: dict) -> str | None:
    if "average_reduction" in results and "units" in results:
        return "stream"
    if "weight_search" in results:
        return "classification"
    backends = results.get("backends")
    if isinstance(backends, dict) and backends:
        datasets = next(iter(backends.values())).get("datasets") if isinstance(next(iter(backends.values())), dict) else None
        if isinstance(datasets, dict) and datasets:
            first = next(iter(datasets.values()))
            if isinstance(first, dict) and "angles" in first:
                return "rotation"
            if isinstance(first, dict) and "increments" in first:
                return "sequence"
    return None


def _own(path: Path, inside: Path) -> Path:
    """``path`` when it is a regular file of the folder ``inside`` (:func:`~pcreg.formats.file_of`); else a
    FileNotFoundError, as for a file that is not there: a link to a file elsewhere is not the report's to show (the
    page shows config.json and checks.md whole), and a pipe would never end its read."""
    if file_of(path, inside):
        return path
    raise FileNotFoundError(path)


def load_report(folder: str | Path) -> Report:
    """Read an evaluation's output folder; a missing folder, a folder without results.json, or a
    results.json that is not one evaluation's results is one line (:class:`InputError`)."""
    p = Path(folder)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if not p.is_dir():
        raise InputError(f"{p}: not a folder")
    rp = p / "results.json"
    if not rp.is_file() and (p / "run.json").is_file():  # a run's folder, whose run.json the review did not take
        raise InputError(f"{p / 'run.json'}: unreadable (not a run.json that pcreg run wrote)")
    if not rp.is_file():
        from ...runs.state import no_run, stopped_before_first_frame

        if stopped_before_first_frame(p):
            raise InputError(no_run(p))
    if not rp.is_file():
        raise InputError(f"{p}: no results.json here (an evaluation's output folder: pcreg evaluate ... --out {p})")
    try:
        results = loads_json(rp.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{rp}: not valid JSON (not UTF-8 text)") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{rp}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    except ValueError as exc:  # nested too deeply
        raise InputError(f"{rp}: not valid JSON ({exc})") from None
    except OSError as exc:
        raise InputError(f"{rp}: cannot read it ({exc.strerror or exc})") from None
    experiment = _experiment(results) if isinstance(results, dict) else None
    if experiment is None:
        raise InputError(f"{rp}: not the results of pcreg evaluate sequence, rotation, stream or classification")
    config = results.get("config") if isinstance(results.get("config"), dict) else {}
    inside = p.resolve()  # a link to a file elsewhere (/etc/passwd as notes.md) is not the report's to serve
    try:
        on_disk = loads_json(_own(p / "config.json", inside).read_text(encoding="utf-8"))
        if isinstance(on_disk, dict):
            config = on_disk
    except (OSError, ValueError):
        pass
    try:
        checks = _own(p / "checks.md", inside).read_text(encoding="utf-8")
    except (OSError, ValueError):
        checks = None
    names = sorted(f.name for f in p.iterdir() if not f.name.startswith(".") and file_of(f, inside))
    ours = recordings(p)  # an earlier run's recording left in the folder is not shown beside these numbers
    return Report(folder=p, experiment=experiment, results=results, config=config, checks=checks,
                  figures=tuple(n for n in names if n.lower().endswith(".png")),
                  files=tuple(n for n in names if n.lower().endswith(TEXT_SUFFIXES)),
                  recordings=tuple(p / n for n in names if n.lower().endswith(".rrd") and (ours is None or n in ours)))


# -- tables --------------------------------------------------------------------------------------


def _first_frame(frames: dict | None) -> int | None:
    return min(frames.values()) if frames else None


def _units(results: dict) -> list[dict]:
    return [u for u in results.get("units", []) if isinstance(u, dict)]


def _backend_tables(results: dict, R: Any, *, key: str, title: str, select: str, errors: Any,
                    row_frames: Callable[[str, str, dict], Iterable[int | None]],
                    footer: Callable[[dict, str], str] = lambda results, backend: "") -> list[dict]:
    """One table per backend, ``R.table(results, backend)``; ``row_frames(backend, dataset, entry)`` gives
    the recording frame of each of that dataset's rows (None: not recorded); ``footer(results, backend)`` what
    its Markdown file says under it."""
    out = []
    for b, bd in results["backends"].items():
        header, rows = R.table(results, b)
        frames = [f for name, d in bd["datasets"].items() for f in row_frames(b, name, d)]
        out.append(_table(f"{key}_{b}", f"{title}, backend {b}", header, rows, frames, select=select, errors=errors,
                          footer=footer(results, b)))
    return out


def _sequence_tables(results: dict) -> list[dict]:
    from . import sequence as R

    units = _units(results)

    def row_frames(b: str, name: str, d: dict) -> Iterable[int | None]:
        for k in d["increments"]:
            u = next((u for u in units if u.get("dataset") == name and str(u.get("k")) == str(k)
                      and u.get("backend") == b), None)
            yield _first_frame(u.get("recording_frames")) if u else None

    return _backend_tables(results, R, key="sequence", title="Mean error % over pairs (i, i+k)",
                           select="a clip and increment", errors=results.get("methods", ()), row_frames=row_frames,
                           footer=R.fewer_pairs)


def _rotation_tables(results: dict) -> list[dict]:
    from ..rotation import KEYS
    from . import rotation as R

    units = sorted(_units(results), key=lambda u: u.get("index", 0))

    def row_frames(b: str, name: str, d: dict) -> Iterable[int | None]:
        for a in d["angles"]:
            hits = [u["recording_frames"][a] for u in units if u.get("dataset") == name and u.get("backend") == b
                    and a in (u.get("recording_frames") or {})]
            yield hits[0] if hits else None

    return _backend_tables(results, R, key="rotation", title="Error % of rotated frames (mean over sampled frames)",
                           select="an angle (the first sampled frame)", errors=KEYS, row_frames=row_frames)


def _stream_tables(results: dict) -> list[dict]:
    from . import stream as R

    primary = results.get("primary_backend")
    units = [u for u in _units(results) if primary is None or u.get("backend") == primary]
    header, rows, footer = R.table(results)
    by_clip = {u.get("dataset"): u for u in units}
    frames = [_first_frame(by_clip[name].get("recording_frames")) if name in by_clip else None
              for name in results["datasets"]] + [None]
    reference = _table("stream_reference", "Mean error % per clip (last row: reduction against plain, %)",
                       header, rows[:-1], frames[:-1], select="a clip", errors=results["methods"], footer=footer)
    reduction = _table("stream_reduction", "Reduction against plain, mean over clips (%)", header[2:],
                       [rows[-1][2:]], [None], errors=results["methods"], better="higher")
    header, rows = R.per_frame(results)
    frames = [(u.get("recording_frames") or {}).get(str(r["index"])) for u in _units(results) for r in u["frames"]]
    if primary is not None:  # one row per frame of the primary backend's units, as the recording holds them
        keep = [u.get("backend") == primary for u in _units(results) for _ in u["frames"]]
        rows = [r for r, k in zip(rows, keep) if k]
        frames = [f for f, k in zip(frames, keep) if k]
    per_frame = _table("stream_frames", "Error % per frame", header, rows, frames, select="a frame of a clip",
                       errors=results["methods"])
    return [reference, reduction, per_frame, *_davis_tables(results)]


def _davis_tables(results: dict) -> list[dict]:
    """On DAVIS: J and F per sequence of every method and of the published ones (higher is better)."""
    from .stream_davis import DIGITS, davis_table

    if not results.get("davis"):
        return []
    tables = []
    for k in ("J", "F"):
        header, rows, footer = davis_table(results, k)
        tables.append(_table(f"davis_{k}", f"DAVIS: {k} per sequence (upper case: the published methods)", header,
                             rows, [None] * len(rows), errors=header[2:], better="higher", footer=footer, digits=DIGITS))
    return tables


def _classification_tables(results: dict) -> list[dict]:
    from . import classification as R

    return [_table(name, R.title(name, results), header, rows, [None] * len(rows), footer=R.footer(name, results))
            for name, (header, rows) in R.tables(results).items()]


def _cell(v: Any) -> Any:
    import math

    import numpy as np

    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v if v is None else str(v)


def _table(name: str, title: str, header: list, rows: list, frames: list, *, select: str | None = None,
           errors: tuple | list = (), better: str = "lower", footer: str = "", digits: int = 2) -> dict:
    """One table: ``columns``, ``rows`` (``cells``, the recording ``frame``, which cells are ``floats``:
    JSON does not tell 2.0 from 2, written with ``digits`` decimals), which columns compare the
    methods (``errors``: their indices; ``better``: whether lower or higher is better), what choosing a
    row selects, and ``footer``, the paragraphs its Markdown file has under it (what the figures are, and
    which do not compare)."""
    columns = [str(h) for h in header]
    return {"name": name, "title": title, "columns": columns, "select": select, "better": better, "digits": digits,
            "footer": [" ".join(p.split()) for p in footer.split("\n\n") if p.strip()],
            "errors": [i for i, c in enumerate(columns) if c in errors],
            "rows": [{"cells": [_cell(c) for c in row], "frame": f, "floats": [i for i, c in enumerate(row) if _is_float(c)]}
                     for row, f in zip(rows, frames)]}


def _is_float(v: Any) -> bool:
    """A value written with two decimals (as the Markdown tables write it), whole or not."""
    import numpy as np

    return isinstance(v, (float, np.floating))


_TABLES = {"sequence": _sequence_tables, "rotation": _rotation_tables, "stream": _stream_tables,
           "classification": _classification_tables}


def page_data(report: Report) -> dict:
    """What the report page shows (JSON-ready): the experiment, its config, tables, checks and figures."""
    try:
        tables = _TABLES[report.experiment](report.results)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise InputError(f"{report.folder / 'results.json'}: not the results of pcreg evaluate {report.experiment} "
                         f"as this version writes them ({type(exc).__name__}: {exc})") from None
    return {"experiment": report.experiment, "title": EXPERIMENTS[report.experiment], "folder": report.folder.name,
            "path": str(report.folder.resolve()), "config": report.config,
            "seconds": report.results.get("seconds"), "tables": tables, "checks": report.checks,
            "figures": list(report.figures), "files": list(report.files),
            "notes": [str(n) for key in ("data_notes", "notes") if isinstance(report.results.get(key), list)
                      for n in report.results[key] if n]}
