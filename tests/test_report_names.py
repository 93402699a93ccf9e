"""Names that are Markdown or HTML in an evaluation's Markdown tables: a clip and frames named with
``|``, markup, an entity, emphasis and letters beyond ASCII are each one cell that reads as the name."""

from __future__ import annotations

import contextlib
import io

import cv2
import pytest

import pcreg
from pcreg.cli import main
from pcreg.outputs import markdown_table, markdown_text

CLIP = "clip <b>|x&amp; *ü* `c`"
HOSTILE = ["a|b", "<script>alert(1)</script>", "&amp;", '"quotes"', "*em* _u_ [l](u)", "line\nbreak",
           "مرحبا 😀", "back\\slash", "L" * 300, "a <= 1 & b > 2", "<!-- c -->", "&#60;x", "_lead", "pcreg_half"]


def _cells(md: str) -> list[list[str]]:
    """The text of every body cell of the Markdown table in ``md``, as a GitHub-flavoured renderer reads it;
    and no HTML tag but the table's own."""
    from html.parser import HTMLParser

    markdown_it = pytest.importorskip("markdown_it")
    html = markdown_it.MarkdownIt("commonmark", {"html": True}).enable("table").render(md)
    rows: list[list[str]] = []

    class Cells(HTMLParser):
        cell: list[str] | None = None

        def handle_starttag(self, tag, attrs):
            assert tag in ("h3", "p", "table", "thead", "tbody", "tr", "th", "td"), f"markup {tag} from a name"
            if tag == "tr":
                rows.append([])
            elif tag in ("td", "th"):
                self.cell = []

        def handle_endtag(self, tag):
            if tag in ("td", "th"):
                rows[-1].append("".join(self.cell or []))
                self.cell = None

        def handle_data(self, data):
            if self.cell is not None:
                self.cell.append(data)

    parser = Cells(convert_charrefs=True)
    parser.feed(html)
    return rows


def test_a_markdown_table_cell_reads_as_its_text():
    rows = _cells(markdown_table(["name", "error %"], [[n, 1.5] for n in HOSTILE]))
    assert rows[0] == ["name", "error %"]
    assert [r[0] for r in rows[1:]] == [" ".join(n.splitlines()) for n in HOSTILE]
    assert all(r[1] == "1.50" for r in rows[1:])
    # a comparison, and a name with '_' inside, are written as they are (they read the same in the raw file)
    assert markdown_text("DIS fast <= 1 & > 0") == "DIS fast <= 1 & > 0" and markdown_text("pcreg_half") == "pcreg_half"


def _clip(folder, frame_name):
    """A clip of three synthetic frames and their labels in ``folder``, each named ``frame_name(i)``."""
    (folder / "images").mkdir(parents=True)
    (folder / "labels").mkdir()
    for i, f in enumerate(pcreg.synthetic("syn1a", 3, 0, width=96, height=72)):
        cv2.imwrite(str(folder / "images" / frame_name(i)), f.image[:, :, ::-1])
        cv2.imwrite(str(folder / "labels" / frame_name(i)), f.labels)


def test_an_evaluations_tables_name_a_hostile_clip_as_it_is(tmp_path):
    _clip(tmp_path / "data" / CLIP, lambda i: f"f|{i} <i>.png")
    out = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["evaluate", "stream", "--data", f"folder:{tmp_path / 'data'}", "--frames", "3",
                     "--methods", "plain,unregistered", "--out", str(out)]) == 0
    rows = _cells((out / "stream_reference.md").read_text(encoding="utf-8"))
    assert rows[1][0] == CLIP and len(rows[1]) == len(rows[0])
    per_frame = _cells((out / "stream_frames.md").read_text(encoding="utf-8"))
    assert all(len(r) == len(per_frame[0]) for r in per_frame)
    assert {r[0] for r in per_frame[1:]} == {CLIP}


def test_a_clip_named_in_a_script_no_font_holds_draws_its_figures_without_a_warning(tmp_path, capfd):
    """A clip named in Chinese (no font of this machine holds it): each figure drawn printed matplotlib's warning,
    two lines a character, on stderr. The figures are written, and no such warning is given."""
    import warnings

    _clip(tmp_path / "data" / "道路", lambda i: f"f{i}.png")
    out = tmp_path / "out"
    with warnings.catch_warnings(record=True) as shown:
        warnings.simplefilter("always")
        assert main(["evaluate", "stream", "--data", f"folder:{tmp_path / 'data'}", "--frames", "3",
                     "--methods", "plain,unregistered", "--out", str(out)]) == 0
    assert not [w for w in shown if "missing from font" in str(w.message)]
    assert "missing from font" not in capfd.readouterr().err
    assert (out / "stream.png").stat().st_size > 0
