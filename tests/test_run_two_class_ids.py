"""``pcreg run --classes TABLE`` with a table of two known classes whose ids are not ``lagr``'s 0 and 1 (and unknown
2): a JSON table of road 5, car 9 and void 255, say, or 0 and 1 with void 255. Such labels were read through the table
and then refused by the two-class step, which takes ids 0, 1 and 2 only: from one label image in a line naming no file
("labels must be 0 (ground), 1 (obstacle) or 2 (unknown); found 255"), from a folder of key frames saying the
labels "must be 0 ground, 1 obstacle, 2 unknown". Then they were labelled by the many-class step, whose confidence,
fitted on eleven classes, predicted 2-3 times fewer errors than there were. Now they run the two-class step, their
ids mapped to 0, 1 and 2 on the way in and back on the way out: labels, confidence and predicted errors those of the
same labels coded 0, 1 and 2, bit for bit, every file in the table's ids."""

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
from _runs import frames_folder, one_line_errors, timeless

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


VOID = {"classes": [{"id": 0, "name": "ground", "colour": [34, 197, 94]}, {"id": 1, "name": "obstacle", "colour": [255, 40, 40]},
                    {"id": 255, "name": "void", "colour": [0, 0, 0]}], "unknown": 255}
CODINGS = [(TABLE, IDS), (VOID, np.array([0, 1, 255], np.uint8))]


def _camvid(shared_data, n: int):
    """The first ``n`` frames of CamVid's 0001TP (RGB) and their labels as ground (0), obstacle (1) and unknown (2)."""
    from pcreg.classes.mappings import mapping_lut

    folder = shared_data / "camvid" / "0001TP"
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent (the shared CamVid clips)")
    names = sorted(p.name for p in (folder / "images").iterdir())[:n]
    images = [cv2.imread(str(folder / "images" / name))[:, :, ::-1].copy() for name in names]
    lut = mapping_lut("camvid")
    return images, [lut[cv2.imread(str(folder / "labels" / name), cv2.IMREAD_UNCHANGED)] for name in names]


@pytest.mark.parametrize("coding", CODINGS, ids=["5-9-255", "0-1-255"])
def test_the_propagator_labels_two_classes_in_any_ids_as_in_lagrs(shared_data, coding):
    spec, ids = coding
    table = pcreg.classes.parse_table_json(json.dumps(spec), "table")
    images, labels = _camvid(shared_data, 5)
    lagr = pcreg.Propagator.from_key_frame(images[0], labels[0])
    other = pcreg.Propagator.from_key_frame(images[0], ids[labels[0]], classes=table)
    assert other.classes is None and np.array_equal(other.key_labels, ids[labels[0]])
    for image in images[1:]:
        expected = lagr.step(image)
        np.testing.assert_array_equal(other.step(image), ids[expected])
        np.testing.assert_array_equal(other.last.confidence, lagr.last.confidence)
        assert other.last.predicted_error == lagr.last.predicted_error
        np.testing.assert_array_equal(other.classifier.predict(image), ids[lagr.classifier.predict(image)])


def _run(tmp_path, name: str, images, keys: dict, spec, ids, *extra: str) -> tuple[int, object]:
    """``pcreg run`` of ``images`` from the key frames ``keys`` (position: labels 0/1/2) coded as ``ids`` in the
    table ``spec`` (None: lagr's own), into ``tmp_path / name``; (exit code, out)."""
    root = tmp_path / name
    (root / "frames").mkdir(parents=True)
    (root / "keys").mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(root / "frames" / f"f{i}.png"), image[:, :, ::-1])
    for k, lab in keys.items():
        cv2.imwrite(str(root / "keys" / f"f{k}.png"), ids[lab])
    given = root / "keys" / "f0.png" if list(keys) == [0] else root / "keys"
    args = ["run", str(root / "frames"), "--labels", str(given), "--out", str(root / "out"), "--confidence",
            "--model", "flow", "--scale", "0.5", *extra]
    if spec is not None:
        (root / "table.json").write_text(json.dumps(spec))
        args += ["--classes", str(root / "table.json")]
    with contextlib.redirect_stdout(io.StringIO()):
        return main(args), root / "out"


@pytest.mark.parametrize("keys", [(0,), (0, 3)], ids=["one label image", "a folder of key frames"])
@pytest.mark.parametrize("coding", CODINGS, ids=["5-9-255", "0-1-255"])
def test_a_run_of_two_classes_in_any_ids_writes_lagrs_labels_in_its_ids(shared_data, tmp_path, capsys, coding, keys):
    spec, ids = coding
    images, labels = _camvid(shared_data, 5)
    lagr = np.array([0, 1, 2], np.uint8)
    rc, out = _run(tmp_path, "lagr", images, {k: labels[k] for k in keys}, None, lagr)
    assert rc == 0, one_line_errors(capsys)
    rc, other = _run(tmp_path, "other", images, {k: labels[k] for k in keys}, spec, ids)
    assert rc == 0, one_line_errors(capsys)
    table = pcreg.classes.parse_table_json(json.dumps(spec), "table")
    for i in range(5):
        written = read_labels(other / f"f{i}.png", table)
        np.testing.assert_array_equal(written, ids[read_labels(out / f"f{i}.png")])
        from PIL import Image

        with Image.open(other / f"f{i}.png") as im:  # a palette PNG in the table's ids and colours
            palette = np.asarray(im.getpalette()[: 3 * 256], np.uint8).reshape(-1, 3)
            assert im.mode == "P" and set(np.unique(np.asarray(im))) <= set(ids.tolist())
        for c in spec["classes"]:
            assert palette[c["id"]].tolist() == c["colour"]
        if i not in keys:
            assert (other / f"confidence/f{i}.png").read_bytes() == (out / f"confidence/f{i}.png").read_bytes()
    steps = [[timeless(line) for line in (run / "steps.jsonl").read_text().splitlines()] for run in (out, other)]
    ious = [[s.pop("predicted_iou") for s in run] for run in steps]  # each class's, by its id in the run's table
    assert steps[0] == steps[1]
    assert ious[1] == [{str(ids[int(k)]): v for k, v in iou.items()} for iou in ious[0]]
    assert json.loads((other / "run.json").read_text())["run"]["step"] == "two-class"


def test_a_run_begun_when_its_table_ran_the_many_class_step_is_refused_on_resuming(shared_data, tmp_path, capsys):
    images, labels = _camvid(shared_data, 3)
    rc, out = _run(tmp_path, "void", images, {0: labels[0]}, VOID, CODINGS[1][1])
    assert rc == 0, one_line_errors(capsys)
    state = json.loads((out / "run.json").read_text())
    del state["run"]["step"]  # as a run of this table begun before it ran the two-class step
    state["done"] = 2
    (out / "run.json").write_text(json.dumps(state))
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    rc, _ = _run_again(tmp_path / "void", out)
    errors = one_line_errors(capsys)
    assert rc == 2 and len(errors) == 1 and errors[0].startswith(f"pcreg: error: {out} holds a run with other options")
    assert "step" in errors[0] and errors[0].endswith("use --force to start over or another --out")
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    rc, _ = _run_again(tmp_path / "void", out, "--force")
    assert rc == 0, one_line_errors(capsys)
    assert json.loads((out / "run.json").read_text())["run"]["step"] == "two-class"


def _run_again(root, out, *extra: str) -> tuple[int, object]:
    args = ["run", str(root / "frames"), "--labels", str(root / "keys" / "f0.png"), "--out", str(out), "--confidence",
            "--model", "flow", "--scale", "0.5", "--classes", str(root / "table.json"), *extra]
    with contextlib.redirect_stdout(io.StringIO()):
        return main(args), out
