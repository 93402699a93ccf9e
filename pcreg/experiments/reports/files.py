"""Writing a report's files: Markdown and CSV tables, PNG figures, config.json and, last, results.json."""

from __future__ import annotations

from pathlib import Path


def write_files(out: str | Path, results: dict, *, tables: dict | None = None, texts: dict | None = None,
                figures: dict | None = None) -> list[Path]:
    """Write, each atomically: ``tables`` {name: (title, header, rows[, footer])} as NAME.csv and NAME.md
    (title above the table, the optional Markdown footer below), ``texts`` {file name: Markdown}, ``figures`` {name: matplotlib figure} as NAME.png
    (closed after), then config.json and results.json (NaN written as null). Returns the paths."""
    import matplotlib.pyplot as plt

    from ...outputs import atomic_save_figure, atomic_write_csv, atomic_write_json, atomic_write_text, markdown_table
    from ..units import nan_to_none

    out = Path(out)
    written = []
    for name, (title, header, rows, *footer) in (tables or {}).items():
        written.append(atomic_write_csv(out / f"{name}.csv", header, rows))
        written.append(atomic_write_text(out / f"{name}.md",
                                         f"### {title}\n\n" + markdown_table(header, rows) + "".join(footer)))
    for name, text in (texts or {}).items():
        written.append(atomic_write_text(out / name, text))
    for name, fig in (figures or {}).items():
        if fig is None:
            continue
        written.append(atomic_save_figure(fig, out / f"{name}.png"))
        plt.close(fig)
    written.append(atomic_write_json(out / "config.json", results["config"]))
    written.append(atomic_write_json(out / "results.json", nan_to_none(results)))
    return written
