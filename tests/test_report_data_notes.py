"""What reading an evaluation's data met (a 16-bit frame whose values use only its lowest 12 bits, read as nearly
black; transparent pixels; damaged data decoded around) was said on stderr only: results.json's notes were empty and
no file of the report said it, so a report read later hid why its figures were off (augmented 18.8% against 5.4%).
Kept in results.json (``data_notes``), in data_notes.md and on the report page."""

import json
import shutil

import cv2
import numpy as np
import pytest

from pcreg.cli import main


@pytest.fixture(scope="module")
def clip(shared_data, tmp_path_factory):
    """Six frames of CamVid 0001TP_b, the fourth written as 16-bit values in the lowest 12 bits."""
    src = shared_data / "camvid" / "0001TP_b"
    clip = tmp_path_factory.mktemp("notes") / "clip"
    for sub in ("images", "labels"):
        (clip / sub).mkdir(parents=True)
        for p in sorted((src / sub).iterdir())[:6]:
            shutil.copy(p, clip / sub / p.name)
    frame = sorted((clip / "images").iterdir())[3]
    cv2.imwrite(str(frame), cv2.imread(str(frame)).astype(np.uint16) * 16)
    return clip, frame.stem


@pytest.mark.parametrize("experiment, options", [
    ("classification", ["--frames", "6", "--cases", "I", "--k", "2", "--trials", "2"]),
    ("sequence", ["--frames", "6", "-k", "1", "--levels", "2", "--iterations", "5"]),
])
def test_a_report_keeps_what_reading_its_data_met(clip, tmp_path, capsys, experiment, options):
    from pcreg.experiments.reports.page import load_report, page_data

    folder, name = clip
    out = tmp_path / experiment
    assert main(["evaluate", experiment, "--data", f"camvid:{folder}", *options, "--out", str(out)]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if line.startswith("pcreg: note:")]
    notes = json.loads((out / "results.json").read_text())["data_notes"]
    assert len(notes) == 1 and name in notes[0] and "only the lowest 12 of its 16 bits" in notes[0], notes
    assert said == [f"pcreg: note: {notes[0]}"]
    text = (out / "data_notes.md").read_text()
    assert text.startswith("### Notes on the data") and notes[0] in text
    assert notes[0] in page_data(load_report(out))["notes"]


def test_a_report_of_data_read_without_a_note_has_none(shared_data, tmp_path):
    out = tmp_path / "plain"
    assert main(["evaluate", "classification", "--data", f"camvid:{shared_data / 'camvid' / '0001TP_b'}", "--frames", "6",
                 "--cases", "I", "--k", "2", "--trials", "2", "--out", str(out)]) == 0
    assert "data_notes" not in json.loads((out / "results.json").read_text())
    assert not (out / "data_notes.md").exists()
