"""A video's places where frames are missing by its times, past its millionth frame (nine hours at 30 frames a
second): frame names grow a seventh digit there (``1000002``), which sorts before ``999998`` as text, so the
run's summary and what ``pcreg view`` and ``pcreg export`` say named a later place as the first."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from pcreg.runs.gaps import GapMarks, gaps_note

GAPS = {"places": 2, "missing": 3, "last": "1000002", "listed": {"999998": 1, "1000002": 2},
        "times": {"999998": 33333.2, "1000002": 33333.4}}


def test_the_first_place_is_the_first_in_frame_order():
    said = gaps_note(GAPS, "v.mkv")
    assert "before frames 999998 (at 9:15:33.2, 1 missing) and 1000002 (at 9:15:33.4, 2 missing)" in said, said
    assert "from frame 999998 on" in said, said


def test_the_runs_summary_names_the_first_place(capsys):
    run = SimpleNamespace(state={"gaps": GAPS}, frames=SimpleNamespace(path=Path("v.mkv")), out=Path("out"))
    GapMarks(run).summary()
    assert "the first before frame 999998;" in capsys.readouterr().err
