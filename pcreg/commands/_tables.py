"""The reports' Markdown tables as the command line prints them to a terminal: each column padded to its widest
cell, so that the columns line up, and a table wider than the terminal turned (its rows as columns) where that
makes it narrower: ``evaluate stream``'s fourteen methods are fourteen rows, not a line of 230 characters that the
terminal wraps. The files keep their own layout; output to a file or a pipe is printed as the files hold it."""

from __future__ import annotations

import re
import unicodedata

#: A cell's border in a row of :func:`pcreg.outputs.markdown_table` (a ``|`` in a cell is written ``\\|``).
_BORDER = re.compile(r"(?<!\\)\|")
_RULE = re.compile(r"^\|(\s*:?-+:?\s*\|)+\s*$")
_NUMBER = re.compile(r"^[-+]?(\d[\d,]*\.?\d*|\.\d+|nan|inf)(%|x)?$")


def shown_width(text: str) -> int:
    """How many terminal columns ``text`` takes: two for a wide character (Chinese, Japanese, Korean), none
    for a mark on the character before it (an accent, a Thai or Devanagari vowel sign above or below) or a
    character of format (a zero-width space, an emoji's variation selector)."""
    return sum(0 if unicodedata.category(ch) in ("Mn", "Me", "Cf") else 2 if unicodedata.east_asian_width(ch) in "WF" else 1
               for ch in text)


def _cells(line: str) -> list[str]:
    inner = line.strip()[1:]
    if inner.endswith("|") and not inner.endswith("\\|"):
        inner = inner[:-1]
    return [c.strip() for c in _BORDER.split(inner)]


def _aligned(rows: list[list[str]]) -> list[str]:
    """``rows`` (the header first) as padded Markdown lines: numbers to the right of their columns."""
    widths = [max(shown_width(r[j]) for r in rows) for j in range(len(rows[0]))]

    def cell(text: str, j: int) -> str:
        pad = " " * (widths[j] - shown_width(text))
        return pad + text if _NUMBER.match(text) else text + pad

    lines = ["| " + " | ".join(cell(c, j) for j, c in enumerate(r)) + " |" for r in rows]
    lines.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return lines


def _table(lines: list[str], width: int) -> list[str]:
    """One table's lines (header, rule, rows) as printed to a terminal ``width`` columns wide."""
    rows = [_cells(line) for line in lines[:1] + lines[2:]]
    if len({len(r) for r in rows}) != 1:  # not a table of ours: as it is
        return lines
    shown = _aligned(rows)
    if shown_width(shown[0]) <= width or len(rows) < 2:
        return shown
    turned = _aligned([list(column) for column in zip(*rows)])
    return turned if shown_width(turned[0]) < shown_width(shown[0]) else shown


def terminal_tables(text: str, width: int) -> str:
    """``text`` (Markdown) with each table lined up, and turned where wider than ``width`` columns and narrower so."""
    lines, out, i = text.split("\n"), [], 0
    while i < len(lines):
        if lines[i].startswith("|") and i + 1 < len(lines) and _RULE.match(lines[i + 1]):
            j = i + 2
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            out += _table(lines[i:j], width)
            i = j
        else:
            out.append(lines[i])
            i += 1
    return "\n".join(out)


def printed(text: str) -> str:
    """``text`` as the command line prints it: :func:`terminal_tables` at the terminal's width when standard output
    is a terminal; else as it is."""
    import shutil
    import sys

    try:
        tty = sys.stdout.isatty()
    except (AttributeError, ValueError):  # replaced by an object without it, or closed
        tty = False
    return terminal_tables(text, shutil.get_terminal_size().columns) if tty else text
