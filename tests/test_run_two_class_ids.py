"""``pcreg run --classes TABLE`` with a table of two known classes whose ids are not ``lagr``'s 0 and 1 (and unknown
2): a JSON table of road 5, car 9 and void 255, say. Such labels were read through the table and then refused by
the two-class step, which takes ids 0, 1 and 2 only: from one label image in a line naming no file
("labels must be 0 (ground), 1 (obstacle) or 2 (unknown); found 255"), from a folder of key frames saying the
labels "must be 0 ground, 1 obstacle, 2 unknown". They are labelled by the many-class step in their own ids."""

from __future__ import annotations

import contextlib
import io
import json

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.export import read_labels
from _runs import frames_folder, one_line_errors

TABLE = {"classes": [{"id": 5, "name": "road", "colour": [128, 64, 128]}, {"id": 9, "name": "car", "colour": [64, 0, 128]},
                     {"id": 255, "name": "void", "colour": [0, 0, 0]}], "unknown": 255}
IDS = np.array([5, 9, 255], np.uint8)  # lagr's 0, 1, 2 in the table's ids


@pytest.fixture(scope="module")
def synthetic():
    return pcreg.synthetic("syn1a", 4, 0, width=96, height=72)


@pytest.mark.parametrize("labels", ["one label image", "a folder of key frames"])
def test_a_two_class_table_of_other_ids_labels_every_frame_in_its_ids(synthetic, tmp_path, capsys, labels):
    folder, keys = frames_folder(tmp_path, synthetic, keys=())
    (tmp_path / "table.json").write_text(json.dumps(TABLE))
    for k in (0, 3):
        cv2.imwrite(str(keys / f"f{k}.png"), IDS[synthetic[k].labels])
    (tmp_path / "truth").mkdir()
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(tmp_path / "truth" / f"f{i}.png"), IDS[f.labels])
    out = tmp_path / "out"
    given = keys / "f0.png" if labels == "one label image" else keys
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["run", str(folder), "--labels", str(given), "--out", str(out), "--classes", str(tmp_path / "table.json"),
                   "--truth", str(tmp_path / "truth"), "--model", "flow"])
    assert rc == 0, one_line_errors(capsys)
    table = pcreg.classes.read_table_file(tmp_path / "table.json")
    for i in range(4):
        assert set(np.unique(read_labels(out / f"f{i}.png", table))) <= {5, 9, 255}
    truth = json.loads((out / "run.json").read_text())["truth"]
    assert truth["frames"] == (3 if labels == "one label image" else 2) and truth["error"] < 10


def test_follow_object_names_a_two_class_table_of_other_ids(synthetic, tmp_path, capsys):
    folder, keys = frames_folder(tmp_path, synthetic, keys=())
    (tmp_path / "table.json").write_text(json.dumps(TABLE))
    cv2.imwrite(str(keys / "f0.png"), IDS[synthetic[0].labels])
    rc = main(["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(tmp_path / "out"), "--classes",
               str(tmp_path / "table.json"), "--follow", "object"])
    assert rc == 2 and one_line_errors(capsys) == [
        f"pcreg: error: --classes {tmp_path / 'table.json'}: --follow object follows one object (background and object, "
        "ids 0 and 1, 2 unknown), not the ids 5 road, 9 car, 255 void; use --follow scene (the default) for them"]
    assert not (tmp_path / "out").exists()
