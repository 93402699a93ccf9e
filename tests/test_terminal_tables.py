"""The reports' tables as the command line prints them to a terminal: lined up, and a table wider than the terminal
turned where that makes it narrower; to a file or a pipe as the files hold them."""

import io

from pcreg.commands._tables import printed, shown_width, terminal_tables
from pcreg.outputs import markdown_table

METHODS = ["plain", "unregistered", "pcreg", "pcreg_half", "pcreg_flow", "dense_key", "dense_previous", "similarity_key",
           "similarity_previous", "flow_key", "flow_previous", "flowfast_key", "flowultrafast_key", "pcreg_object"]


def _stream_table() -> str:
    rows = [["syn1a", 3, *[float(i) for i in range(14)]], ["道路 a|b", 3, *[10.5 + i for i in range(14)]],
            ["reduction vs plain, mean over clips (%)", "", *[-1.25 * i for i in range(14)]]]
    return "### Title\n\n" + markdown_table(["clip", "frames scored", *METHODS], rows) + "\n(a footer)\n"


def test_a_table_wider_than_the_terminal_is_turned_and_lined_up():
    text = _stream_table()
    assert shown_width(text.splitlines()[2]) > 120
    shown = terminal_tables(text, 120)
    lines = shown.splitlines()
    assert lines[:2] == ["### Title", ""] and lines[-1] == "(a footer)"
    table = [line for line in lines if line.startswith("|")]
    assert len(table) == 2 + 15  # the header, its rule, then "frames scored" and each method: a row each
    assert len({shown_width(line) for line in table}) == 1 and shown_width(table[0]) <= 120
    cells = [[c.strip() for c in line.strip("|").split(" | ")] for line in table]
    assert cells[0][:2] == ["clip", "syn1a"] and cells[0][2] == "道路 a\\|b"  # an escaped | stays in its cell
    assert cells[2] == ["frames scored", "3", "3", ""]
    assert cells[3 + METHODS.index("flow_key")] == ["flow_key", "9.00", "19.50", "-11.25"]
    assert table[3].startswith("| plain               |  0.00 |     10.50 |")  # numbers to the right of their column
    assert shown.replace(" ", "").replace("-", "") != text.replace(" ", "").replace("-", "")


def test_a_table_that_fits_keeps_its_layout_lined_up():
    text = "| a | bb |\n|---|---|\n| 1.50 | x |\n| 10.25 | yyy |\n"
    assert terminal_tables(text, 80) == "| a     | bb  |\n|-------|-----|\n|  1.50 | x   |\n| 10.25 | yyy |\n"
    wide = _stream_table()
    assert terminal_tables(wide, 400).splitlines()[2].startswith("| clip ")  # it fits: not turned


def test_to_a_file_or_a_pipe_the_tables_are_printed_as_the_files_hold_them(monkeypatch):
    text = _stream_table()
    monkeypatch.setattr("sys.stdout", io.StringIO())
    assert printed(text) == text


def test_evaluate_prints_its_tables_turned_on_a_narrow_terminal(tmp_path, monkeypatch, capsys):
    from pcreg.cli import main

    monkeypatch.setattr("sys.stdout.isatty", lambda: True, raising=False)
    monkeypatch.setenv("COLUMNS", "100")
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--frames", "3", "--size", "96x72", "--data", "synthetic:syn1a",
                 "--methods", "unregistered,pcreg,flow_key,flow_previous,flowfast_key,flowultrafast_key", "--out", str(out)]) == 0
    printed_text = capsys.readouterr().out
    kept = (out / "stream_reference.md").read_text()
    assert kept.splitlines()[2].startswith("| clip | frames scored | plain | unregistered |")  # the file as before
    assert "| plain             |" in printed_text and "| flowultrafast_key |" in printed_text


def test_marks_above_and_below_and_characters_of_format_take_no_column():
    assert [shown_width(t) for t in ("ที่", "हिंदी", "🚗\ufe0f", "a\u200bb", "e\u0301", "道路")] == [1, 4, 2, 2, 1, 4]
