"""Writing a report's files: Markdown and CSV tables, PNG figures, config.json and, last, results.json.

Beside them, :data:`MANIFEST` names the files the report wrote, so that the next report, or a run that starts
over (``--force``), removes those it does not write again: a table or figure of a clip, backend or option no
longer run is not left in the folder (and on the report page) beside the new numbers.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The file of an output folder that names, one a line, the files its report wrote besides results.json.
MANIFEST = ".report_files"
#: The report's file of what reading the data met (results.json's ``data_notes``), written when there is any.
DATA_NOTES = "data_notes.md"
#: What each evaluation's report names its files by, beside :data:`DATA_NOTES`: ``NAME.csv|md|png`` or
#: ``NAME_*.csv|md|png`` of one of these names, and its checks.md.
REPORT_NAMES = {"stream": ("stream", "davis"), "sequence": ("sequence",), "rotation": ("rotation",),
                "classification": ("table41", "case1", "case2", "case3")}
_CHECKED = ("stream", "sequence", "rotation")  # the reports with a checks.md


def in_the_way(out: Path, experiment: str) -> Path | None:
    """A file in ``out`` that the report of ``experiment`` (a key of :data:`REPORT_NAMES`) would write over while
    ``out`` holds no evaluation (no config.json beside a results.json, :data:`MANIFEST` or units/; a config.json alone
    may be anyone's): a person's own checks.md, say, no evaluation wrote; None when there is none."""
    def held(n: str) -> bool:
        return os.path.lexists(out / n)

    if not out.is_dir() or held("run.json") or (held("config.json") and any(map(held, ("results.json", MANIFEST, "units")))):
        return None  # a run's folder (refused as one), or an evaluation's: its config.json beside its results or units
    names = REPORT_NAMES[experiment]
    for q in sorted(out.iterdir()):
        stem, suffix = q.stem, q.suffix.lower()
        if q.name == DATA_NOTES or (q.name == "checks.md" and experiment in _CHECKED) or (suffix in (".csv", ".md", ".png")
                                                   and any(stem == n or stem.startswith(f"{n}_") for n in names)):
            return q
    return None


def _manifest(out: Path) -> list[str] | None:
    """The files :data:`MANIFEST` names: plain names in ``out`` only (None for a missing or unreadable one)."""
    try:
        text = (out / MANIFEST).read_text(encoding="utf-8")
    except (OSError, ValueError):
        return None
    return [n for n in text.splitlines() if n and Path(n).name == n and not n.startswith(".")
            and n not in ("config.json", "results.json")]


def _listed(out: Path) -> list[str]:
    """The files the report wrote that the next one removes unless it writes them again: :data:`MANIFEST`'s but
    the recording (``--record FILE.rrd``), a file the command was told to write, never removed."""
    return [n for n in _manifest(out) or () if not _is_recording(n)]


def _is_recording(name: str) -> bool:
    return name.lower().endswith(".rrd")


def recordings(out: str | Path) -> list[str] | None:
    """The recordings in ``out`` of the run whose report is there (the ``--record`` file it wrote in ``out``), as
    :data:`MANIFEST` names them; None for a folder without one (a report of pcreg 0.2 or earlier): a recording an
    earlier run left in the folder is not this report's."""
    listed = _manifest(Path(out))
    return None if listed is None else [n for n in listed if _is_recording(n)]


def _remove(out: Path, names) -> None:
    from ...errors import OutputError

    for name in names:
        try:
            (out / name).unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise OutputError(f"cannot remove {out / name}, a file of the earlier report: {exc.strerror or exc}") from None


def remove_report(out: str | Path) -> None:
    """Remove the report an earlier run wrote in ``out``: its results.json and every file its :data:`MANIFEST`
    names (config.json and the units are the caller's)."""
    out = Path(out)
    _remove(out, ["results.json", *_listed(out), MANIFEST])


def write_files(out: str | Path, results: dict, *, tables: dict | None = None, texts: dict | None = None,
                figures: dict | None = None, recording: str | Path | None = None, digits: dict | None = None) -> list[Path]:
    """Write, each atomically: ``tables`` {name: (title, header, rows[, footer])} as NAME.csv and NAME.md
    (title above the table, the optional Markdown footer below; its numbers with two decimals, or as many as
    ``digits`` {name: decimals} gives), ``texts`` {file name: Markdown}, ``figures`` {name: matplotlib figure} as NAME.png
    (closed after), then config.json, :data:`MANIFEST` and results.json (NaN written as null); the files the
    earlier report's manifest names and this one does not write are removed, and the temporary files a report
    killed mid-write left of those it writes. ``recording``: the run's ``--record`` file, which the manifest names
    when it lies in ``out`` (:func:`recordings`). Returns the paths."""
    import matplotlib.pyplot as plt

    from ...outputs import (atomic_save_figure, atomic_write_csv, atomic_write_json, atomic_write_text, finite,
                           markdown_table, remove_leftovers)

    out = Path(out)
    earlier = _listed(out)
    written = []
    if results.get("data_notes"):  # kept beside the tables, not on the terminal alone
        texts = {**(texts or {}), DATA_NOTES: "### Notes on the data\n\nThe figures of these frames may be off.\n\n"
                 + "".join(f"- {n}\n" for n in results["data_notes"])}
    for name, (title, header, rows, *footer) in (tables or {}).items():
        written.append(atomic_write_csv(out / f"{name}.csv", header, rows))
        written.append(atomic_write_text(out / f"{name}.md",
                                         f"### {title}\n\n" + markdown_table(header, rows, digits=(digits or {}).get(name, 2))
                                         + "".join(footer)))
    for name, text in (texts or {}).items():
        written.append(atomic_write_text(out / name, text))
    for name, fig in (figures or {}).items():
        if fig is None:
            continue
        written.append(atomic_save_figure(fig, out / f"{name}.png"))
        plt.close(fig)
    names = [p.name for p in written]
    _remove(out, [n for n in earlier if n not in names])
    written.append(atomic_write_json(out / "config.json", results["config"]))
    ours = [Path(recording).name] if recording is not None and _inside(Path(recording), out) else []
    atomic_write_text(out / MANIFEST, "".join(f"{n}\n" for n in names + ours))
    written.append(atomic_write_json(out / "results.json", finite(results)))
    remove_leftovers(out, [*names, *earlier, "config.json", MANIFEST, "results.json"])  # those of a report killed mid-write
    return written


def _inside(path: Path, out: Path) -> bool:
    """Whether ``path`` is a file directly in the folder ``out`` (links followed)."""
    from ...formats import resolved

    return resolved(path.parent) == resolved(out)
