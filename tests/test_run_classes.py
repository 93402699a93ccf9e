"""``pcreg run --classes``: key labels read through a class table, label PNGs written as palette PNGs in
its colours, the table kept in run.json only when it is not the default, and bad tables and labels
refused in one line naming the file, exit 2, with what a run already wrote kept."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.classes import CAMVID11, DAVIS, LAGR, is_palette_png, write_label_png
from pcreg.cli import main
from pcreg.export import read_labels
from _runs import drifting_frames, frames_folder, one_line_errors

N = 4


@pytest.fixture(scope="module")
def synthetic():
    return pcreg.synthetic("syn1a", N, 0, width=160, height=120)


def _run(args, capsys) -> tuple[int, list[str]]:
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main([str(a) for a in args])
        except SystemExit as exc:  # argparse
            rc = int(exc.code or 0)
    return rc, one_line_errors(capsys)


def _identity(out) -> dict:
    return json.loads((out / "run.json").read_text())["run"]


def test_a_binary_run_writes_palette_pngs_that_read_back_as_key_labels(synthetic, tmp_path, capsys):
    """The default table names nothing new in run.json; each label PNG is a palette PNG in lagr's colours whose
    values are the labels; a run's own output is a key frame of another run, with the same labels."""
    folder, keys = frames_folder(tmp_path, synthetic, keys=(0,))
    out = tmp_path / "out"
    rc, err = _run(["run", folder, "--labels", keys / "f0.png", "--out", out, "--model", "flow"], capsys)
    assert rc == 0, err
    assert "classes" not in _identity(out)
    data = (out / "f2.png").read_bytes()
    assert is_palette_png(data)
    from PIL import Image

    with Image.open(out / "f2.png") as im:
        assert tuple(im.getpalette()[:9]) == (34, 197, 94, 255, 40, 40, 0, 0, 0)
        np.testing.assert_array_equal(np.asarray(im), read_labels(out / "f2.png"))
    again = tmp_path / "again"
    rc, err = _run(["run", folder, "--labels", out / "f0.png", "--out", again, "--model", "flow"], capsys)
    assert rc == 0, err
    for i in range(N):
        assert (again / f"f{i}.png").read_bytes() == (out / f"f{i}.png").read_bytes()


def test_classes_davis_is_mapping_davis(synthetic, tmp_path, capsys):
    """``--classes davis`` reads an object mask as ``--mapping davis`` does: the same run.json, the same labels,
    written in the davis table's colours."""
    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    mask = np.where(synthetic[0].labels == 1, 255, 0).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    outs = []
    for i, args in enumerate((["--classes", "davis"], ["--mapping", "davis"])):
        outs.append(tmp_path / f"o{i}")
        rc, err = _run(["run", folder, "--labels", tmp_path / "mask.png", "--out", outs[-1], "--model", "flow", *args],
                       capsys)
        assert rc == 0, err
    assert _identity(outs[0]) == _identity(outs[1]) and "classes" not in _identity(outs[0])
    assert (outs[0] / "f3.png").read_bytes() == (outs[1] / "f3.png").read_bytes()
    np.testing.assert_array_equal(read_labels(outs[0] / "f0.png", DAVIS), (mask > 0).astype(np.uint8))


def test_a_table_from_a_file_is_kept_in_run_json_and_resume_compares_it(synthetic, tmp_path, capsys):
    """Key labels in a labelmap.txt's colours; the table in run.json; the same run resumes, another table is
    refused without touching the run."""
    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    (tmp_path / "labelmap.txt").write_text("# label:color_rgb:parts:actions\nbackground:0,0,0::\n"
                                           "floor:10,200,10::\nwall:200,10,10::\n")
    colours = np.array([(10, 200, 10), (200, 10, 10), (0, 0, 0)], np.uint8)
    cv2.imwrite(str(tmp_path / "key.png"), colours[synthetic[0].labels][:, :, ::-1])
    out = tmp_path / "out"
    base = ["run", folder, "--labels", tmp_path / "key.png", "--out", out, "--model", "flow"]
    rc, err = _run([*base, "--classes", tmp_path / "labelmap.txt"], capsys)
    assert rc == 0, err
    named = _identity(out)["classes"]
    assert [c["name"] for c in named["classes"]] == ["floor", "wall", "background"] and named["unknown"] == 2
    np.testing.assert_array_equal(read_labels(out / "f0.png", pcreg.classes.read_labelmap(tmp_path / "labelmap.txt")),
                                  synthetic[0].labels)
    rc, err = _run([*base, "--classes", tmp_path / "labelmap.txt"], capsys)
    assert rc == 0, err  # all done: the same run
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    (tmp_path / "other.txt").write_text("background:0,0,0::\nfloor:10,200,10::\nrock:200,10,10::\n")
    rc, err = _run([*base, "--classes", tmp_path / "other.txt"], capsys)
    assert rc == 2 and len(err) == 1 and "holds a run with other options" in err[0], err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    # a table against none, or one of other length: the tables as a person tells them apart, where a Python dict
    # cut off at its first class's colour was said
    (tmp_path / "four.txt").write_text("background:0,0,0::\nfloor:10,200,10::\nwall:200,10,10::\nsky:1,2,3::\n")
    rc, err = _run([*base, "--classes", tmp_path / "four.txt"], capsys)
    assert rc == 2 and "classes.classes: a table of 3 classes (floor, wall, background) then, a table of 4 classes (" in err[0], err
    assert "{" not in err[0], err


def test_more_than_two_classes_reach_the_classifier(synthetic, tmp_path, capsys, monkeypatch):
    """A table of more than two known classes is handed to PropagatorConfig.from_key_frame as ``classes=``
    (two-class tables are not: the binary stream as it was)."""
    from pcreg.pipeline.config import PropagatorConfig

    seen = []

    def spy(self, image, labels, *, classes=None):
        seen.append(classes)
        raise pcreg.errors.InputError("stopped here")

    monkeypatch.setattr(PropagatorConfig, "from_key_frame", spy)
    folder, keys = frames_folder(tmp_path, synthetic, keys=(0,))
    camvid = np.where(synthetic[0].labels == 2, 11, synthetic[0].labels + 3).astype(np.uint8)  # road, pavement, void
    cv2.imwrite(str(tmp_path / "camvid.png"), camvid)
    for args in (["--labels", tmp_path / "camvid.png", "--classes", "camvid11"], ["--labels", keys / "f0.png"]):
        rc, err = _run(["run", folder, "--out", tmp_path / "o", *args], capsys)
        assert rc == 2 and err == ["pcreg: error: stopped here"], err
    assert seen == [CAMVID11, None]


def test_a_key_frame_with_only_the_first_two_classes_of_a_larger_table_runs_many_class(synthetic, tmp_path,
                                                                                     capsys):
    """A camvid11 key frame that shows only sky (0) and building (1) is a many-class stream that has seen two of
    its classes: it runs as one (it once took the two-class step, which stopped at the third frame), labels
    only those two classes, and writes the table's colours."""
    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    two = np.where(synthetic[0].labels == 2, 11, synthetic[0].labels).astype(np.uint8)
    (tmp_path / "two").mkdir()
    cv2.imwrite(str(tmp_path / "two" / "f0.png"), two)
    prop = pcreg.Propagator.from_key_frame(synthetic[0].image, two, classes=CAMVID11)
    assert prop.class_read is not None and prop.anchor == "previous"
    out = tmp_path / "out"
    rc, err = _run(["run", folder, "--labels", tmp_path / "two" / "f0.png", "--classes", "camvid11", "--out", out,
                    "--confidence"], capsys)
    assert rc == 0, err
    for i in range(1, N):
        labels = read_labels(out / f"f{i}.png", CAMVID11)
        assert set(np.unique(labels)) == {0, 1}
    from PIL import Image

    with Image.open(out / "f2.png") as im:
        assert tuple(im.getpalette()[:6]) == tuple(c for k in CAMVID11.classes[:2] for c in k.colour)


def _case(tmp_path, synthetic, how: str):
    """(extra arguments, the file named, what is said) of one bad input."""
    key = tmp_path / "key.png"
    lab = synthetic[0].labels.copy()
    if how == "a value not in the table":
        lab[3, 4] = 7
        cv2.imwrite(str(key), lab)
        return [], key, "label value 7 is not a class id (0 ground, 1 obstacle, 2 unknown); labels of other classes " \
            "need their table: --classes camvid11 (CamVid's ids), --classes FILE (a CVAT labelmap.txt or a JSON table), " \
            "which pcreg run and evaluate stream take"  # evaluate sequence and rotation said it too, without --classes
    if how == "a colour not in the table":
        rgb = LAGR.paint(lab)
        rgb[3, 4] = (1, 2, 3)
        cv2.imwrite(str(key), rgb[:, :, ::-1])
        return [], key, "colour (1, 2, 3) (at x=4, y=3) is no class's colour"
    cv2.imwrite(str(key), lab)
    lm = tmp_path / "labelmap.txt"
    if how == "duplicate names":
        lm.write_text("background:0,0,0::\nroad:1,1,1::\nroad:2,2,2::\n")
        return ["--classes", lm], lm, "two classes named 'road'"
    if how == "duplicate colours":
        lm.write_text("background:0,0,0::\nroad:1,1,1::\ncar:1,1,1::\n")
        return ["--classes", lm], lm, "share the colour (1, 1, 1)"
    if how == "one class":
        lm.write_text("background:0,0,0::\nroad:1,1,1::\n")
        return ["--classes", lm], lm, "1 class(es) besides 'background' (the pixels nobody labelled, not a class)"
    keys = tmp_path / "keys"  # key frames that disagree: palettes of two tables (frames_folder made it)
    write_label_png(keys / "f0.png", lab, LAGR)
    write_label_png(keys / "f3.png", synthetic[3].labels, DAVIS)
    return ["--keys-folder"], keys / "f3.png", "its palette colours index"


@pytest.mark.parametrize("how", ["a value not in the table", "a colour not in the table", "duplicate names",
                                 "duplicate colours", "one class", "key frames that disagree"])
def test_bad_tables_and_labels_end_in_one_line_and_keep_what_was_written(synthetic, tmp_path, capsys, how):
    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    out = tmp_path / "out"
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), synthetic[0].labels)
    rc, err = _run(["run", folder, "--labels", good, "--out", out, "--model", "flow"], capsys)
    assert rc == 0, err
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    extra, named, said = _case(tmp_path, synthetic, how)
    labels = named.parent if extra == ["--keys-folder"] else tmp_path / "key.png"
    extra = [] if extra == ["--keys-folder"] else extra
    rc, err = _run(["run", folder, "--labels", labels, "--out", out, "--model", "flow", "--force", *extra], capsys)
    assert rc == 2 and len(err) == 1 and str(named) in err[0] and said in err[0], err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_follow_object_with_more_than_two_classes_is_refused_before_anything_is_written(synthetic, tmp_path, capsys):
    """--follow object follows one object: a table of eleven classes is refused in one line naming it, exit 2,
    and no output folder is made (it once ran, reading ids 2 and up as unknown and dropping them)."""
    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    (tmp_path / "k").mkdir()
    cv2.imwrite(str(tmp_path / "k" / "f0.png"), synthetic[0].labels)  # ids 0, 1, 2: sky, building, pole
    out = tmp_path / "out"
    rc, err = _run(["run", folder, "--labels", tmp_path / "k" / "f0.png", "--classes", "camvid11", "--follow", "object",
                    "--out", out], capsys)
    assert rc == 2 and len(err) == 1 and "--classes camvid11" in err[0] and "--follow object" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("labels", ["folder", "file"])
def test_colour_keys_refused_by_the_default_table_point_to_the_labelmap_beside_them(tmp_path, capsys, labels):
    """Colour key labels with a CVAT ``labelmap.txt`` saved beside them, run without ``--classes``: the refusal
    names that file and the option that reads it; with it, the run labels."""
    from _runs import ROAD_AND_CAR, colour_keys, drifting_frames

    folder, _ = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    keys = colour_keys(tmp_path / "keys")
    (keys / "labelmap.txt").write_text("# label:color_rgb:parts:actions\n" + ROAD_AND_CAR)
    given = keys if labels == "folder" else keys / "f0.png"
    run = ["run", folder, "--labels", given, "--out", tmp_path / "out"]
    rc, err = _run(run, capsys)
    assert rc == 2 and len(err) == 1, err
    assert "not labels of the table in use (0 ground, 1 obstacle, 2 unknown)" in err[0] and err[0].endswith(
        f"{keys / 'labelmap.txt'} lies beside it: --classes {keys / 'labelmap.txt'} reads them through its table"), err
    (keys / "labelmap.txt").write_text("# label:color_rgb:parts:actions\nbackground:0,0,0::\nroad:128,64,128::\n")
    rc, err = _run(run, capsys)  # a labelmap.txt that does not read them either: the refusal as it was
    assert rc == 2 and "colour (128, 64, 128)" in err[0] and "lies beside" not in err[0], err
    (keys / "labelmap.txt").write_text("# label:color_rgb:parts:actions\n" + ROAD_AND_CAR)
    rc, err = _run([*run, "--classes", keys / "labelmap.txt"], capsys)
    assert rc == 0, err
    from pcreg.classes import read_table_file

    table = read_table_file(keys / "labelmap.txt")
    assert set(np.unique(read_labels(tmp_path / "out" / "f1.png", table)).tolist()) == {table.id_of("road"),
                                                                                          table.id_of("car")}


@pytest.mark.parametrize("table", ["camvid11", "davis"])
def test_a_runs_recording_names_and_colours_the_classes_of_its_table(synthetic, tmp_path, capsys, table):
    """A ``pcreg run --record`` recording always named and coloured its label maps as ground, obstacle and unknown
    in colours of no table, whatever ``--classes`` said: a camvid11 run's sky showed as green "ground", its road
    unnamed in a colour the viewer chose. The recording now holds the run's class table, as its PNGs do."""
    from pcreg.recording.readback import read_recording

    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    ids = {"camvid11": (3, 4, 11), "davis": (0, 1, 0)}[table]  # road, pavement, void; background, object
    key = np.choose(synthetic[0].labels, ids).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "key.png"), key)
    rc, err = _run(["run", folder, "--labels", tmp_path / "key.png", "--classes", table, "--out", tmp_path / "out",
                    "--model", "flow", "--record", tmp_path / "run.rrd"], capsys)
    assert rc == 0, err
    context = read_recording(tmp_path / "run.rrd").latest("/")["AnnotationContext:context"].to_pylist()[0]
    shown = {c["class_id"]: (c["class_description"]["info"]["label"], c["class_description"]["info"]["color"])
             for c in context}
    expected = {"camvid11": CAMVID11, "davis": DAVIS}[table]
    assert shown == {c.id: (c.name, int.from_bytes(bytes([*c.colour, 255]), "big")) for c in expected.classes}


def test_the_closing_message_gives_the_predicted_error_the_class_predicted_worst_and_the_review(synthetic, tmp_path,
                                                                                              capsys):
    """A run ends with its predicted error (the mean of steps.jsonl's, its worst frame), the class of the lowest
    mean predicted IoU (with two classes too), and the command that shows the labels on the frames."""
    folder, keys = frames_folder(tmp_path, synthetic, keys=(0,))
    camvid = np.where(synthetic[0].labels == 2, 11, synthetic[0].labels + 3).astype(np.uint8)  # road, pavement, void
    cv2.imwrite(str(tmp_path / "camvid.png"), camvid)
    out = tmp_path / "out dir"
    assert main(["run", str(folder), "--labels", str(tmp_path / "camvid.png"), "--classes", "camvid11",
                 "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    errors = {s["name"]: s["predicted_error"] for s in steps}
    worst = max(errors, key=lambda n: errors[n])
    ious: dict[int, list[float]] = {}
    for s in steps:
        for c, v in s["predicted_iou"].items():
            ious.setdefault(int(c), []).append(v)
    low = min(ious, key=lambda c: np.mean(ious[c]))
    assert said[1] == (f"predicted error: {np.mean(list(errors.values())):.2f}% of a frame's pixels on average over "
                       f"{N - 1} frame(s), {errors[worst]:.2f}% at most ({worst.removesuffix('.png')}); the class "
                       f"predicted worst: {CAMVID11.name_of(low)}, IoU {np.mean(ious[low]):.2f} on average over the "
                       f"{len(ious[low])} frame(s) that show it")
    assert said[2] == f"to review the labels on the frames: pcreg view '{out}' --web"
    two = tmp_path / "two"  # two classes: the same, ground's and obstacle's IoU
    assert main(["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(two), "--model", "flow"]) == 0
    said = capsys.readouterr().out.splitlines()
    steps = [json.loads(line) for line in (two / "steps.jsonl").read_text().splitlines()]
    ious = {c: [s["predicted_iou"][str(c)] for s in steps if str(c) in s["predicted_iou"]] for c in (0, 1)}
    low = min((c for c in ious if ious[c]), key=lambda c: np.mean(ious[c]))
    assert said[1].endswith(f"; the class predicted worst: {LAGR.name_of(low)}, IoU {np.mean(ious[low]):.2f} on "
                            f"average over the {len(ious[low])} frame(s) that show it")


def test_a_key_frames_run_scored_against_the_truth_gives_each_class_iou_beside_the_predicted(synthetic, tmp_path,
                                                                                               capsys):
    """--truth in eleven classes from a folder of key frames: each step's ``iou`` is its classes' IoU against the
    truth (a class the truth or the labels hold; void truth left out), and the closing message gives each class's
    mean over the frames that show it, its mean predicted IoU in brackets, and the mean over the classes."""
    from pcreg.classification.metrics import class_iou, confusion_matrix

    camvid = [np.where(f.labels == 2, 11, f.labels + 3).astype(np.uint8) for f in synthetic]  # road, pavement, void
    folder, keys = frames_folder(tmp_path, synthetic, keys=())
    truth = tmp_path / "truth"
    truth.mkdir()
    for i, lab in enumerate(camvid):
        cv2.imwrite(str(truth / f"f{i}.png"), lab)
        if i in (0, N - 1):
            cv2.imwrite(str(keys / f"f{i}.png"), lab)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(keys), "--classes", "camvid11", "--truth", str(truth),
                 "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert len(steps) == N - 2
    for s in steps:
        iou = class_iou(confusion_matrix(read_labels(out / s["name"], CAMVID11), camvid[s["frame"]], classes=CAMVID11))
        assert s["iou"] == {str(c): v for c, v in iou.items()} and set(iou) <= {3, 4}
    ious = {c: [s["iou"][c] for s in steps if c in s["iou"]] for c in ("3", "4")}
    predicted = {c: [s["predicted_iou"][c] for s in steps if c in s["predicted_iou"]] for c in ("3", "4")}
    line = next(x for x in said if x.startswith("IoU against the truth"))
    assert line == ("IoU against the truth, each class's mean over the frames that show it (predicted from the confidence "
                    f"in brackets): road {np.mean(ious['3']):.2f} ({np.mean(predicted['3']):.2f}), pavement "
                    f"{np.mean(ious['4']):.2f} ({np.mean(predicted['4']):.2f}); the mean over all 2 classes "
                    f"{(np.mean(ious['3']) + np.mean(ious['4'])) / 2:.2f}")


def test_the_truth_line_of_a_large_table_lists_its_lowest_classes_and_how_many_more():
    """Up to twelve classes against the truth are listed in the table's order; more (a table of 150), the twelve of
    the lowest IoU, lowest first, then how many more steps.jsonl holds, and the mean over them all."""
    from pcreg.runs.summary import LISTED, truth_summary

    table = pcreg.classes.parse_table_json(json.dumps(
        {"classes": [{"id": i, "name": f"c{i}", "colour": [i, 0, 0]} for i in range(21)], "unknown": 20}), "t")
    iou = {str(c): round(1.0 - c / 40, 3) for c in range(20)}  # c0 the highest
    steps = {1: {"iou": iou, "predicted_iou": {"19": 0.25}}, 2: {"iou": {"19": 0.5}}}
    line = truth_summary(steps, table)
    lowest = [f"c{c} {float(np.mean([iou[str(c)]] + ([0.5] if c == 19 else []))):.2f}" for c in range(19, 7, -1)]
    lowest[0] += " (0.25)"
    assert line == ("\nIoU against the truth, each class's mean over the frames that show it (predicted from the confidence "
                    f"in brackets) (the {LISTED} lowest): " + ", ".join(lowest) + ", and 8 more classes in steps.jsonl; "
                    f"the mean over all 20 classes {np.mean([float(iou[str(c)]) for c in range(19)] + [(iou['19'] + 0.5) / 2]):.2f}")
    small = truth_summary({1: {"iou": {"3": 0.5, "1": 0.25}}}, table)
    assert small.endswith(": c1 0.25, c3 0.50; the mean over all 2 classes 0.38")


def test_the_closing_message_names_the_key_frames_classes_the_labels_lost(synthetic, tmp_path, capsys):
    """A class the key frame holds that a frame's labels do not has no predicted IoU there and nothing the confidence
    can be unsure of: the run ends naming it, in how many frames and from which. Here a one-pixel sign symbol in the
    key frame, which the step does not carry (each step's labels hold it or not, as its predicted IoU says)."""
    folder, _ = frames_folder(tmp_path, synthetic, keys=())
    camvid = np.where(synthetic[0].labels == 2, 11, synthetic[0].labels + 3).astype(np.uint8)  # road, pavement, void
    camvid[60, 80] = 6  # sign symbol, one pixel
    cv2.imwrite(str(tmp_path / "camvid.png"), camvid)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(tmp_path / "camvid.png"), "--classes", "camvid11",
                 "--out", str(out), "--model", "flow"]) == 0
    said = capsys.readouterr().out.splitlines()
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    lost = [s["name"] for s in steps if "6" not in s["predicted_iou"]]
    assert lost, "the step carried the one-pixel class: the test needs it lost"
    line = next(x for x in said if x.startswith("classes the key frame(s) hold that the labels lost: "))
    assert line.startswith(f"classes the key frame(s) hold that the labels lost: sign symbol in {len(lost)} frame(s) "
                           f"from {lost[0].removesuffix('.png')}")
    assert all("3" in s["predicted_iou"] and "4" in s["predicted_iou"] for s in steps)  # road and pavement kept: not named
    assert "road in" not in line and "pavement in" not in line


def test_the_lost_classes_of_a_key_frames_run_are_those_of_each_steps_own_key_frames(tmp_path):
    """In a run from several key frames a step is labelled from the key frames around it (its ``keys``): a class only
    a later key frame holds is not lost before it; a key frame's label file that cannot be read says nothing."""
    from pcreg.runs.files import write_labels
    from pcreg.runs.summary import key_classes, lost_summary

    road = np.full((8, 8), 3, np.uint8)
    car = road.copy()
    car[:2, :2] = 8
    write_labels(tmp_path / "k0.png", road, CAMVID11)
    write_labels(tmp_path / "k9.png", car, CAMVID11)
    steps = {1: {"keys": ["k0.png"], "predicted_iou": {"3": 0.9}},
             5: {"keys": ["k0.png", "k9.png"], "predicted_iou": {"3": 0.9}},
             6: {"keys": ["k0.png", "k9.png"], "predicted_iou": {"3": 0.9, "8": 0.5}},
             7: {"keys": ["k9.png"], "predicted_iou": {"3": 0.9}},
             8: {"keys": ["gone.png"], "predicted_iou": {}}}
    line = lost_summary(steps, key_classes(tmp_path, CAMVID11, None), lambda t: f"f{t}", CAMVID11)
    assert line == ("\nclasses the key frame(s) hold that the labels lost: car in 2 frame(s) from f5 (a class that left "
                    "the view, or one the labels missed: the predicted error cannot tell)")
    assert lost_summary({1: steps[1]}, key_classes(tmp_path, CAMVID11, None), str, CAMVID11) == ""


def test_a_class_drawn_on_neither_key_frame_around_a_stretch_is_noted(tmp_path, capsys):
    """Key frames that each draw some of the classes: the frames between two that leave out a class another key
    frame draws were labelled without it, and predicted 0.03% wrong where 24% were (a road drawn on the first key
    frame only). The run notes it before the first frame, naming the class and the key frames."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    table = tmp_path / "three.json"
    table.write_text(json.dumps({"classes": [{"id": 0, "name": "road", "colour": [128, 64, 128]},
                                             {"id": 1, "name": "sky", "colour": [128, 128, 128]},
                                             {"id": 2, "name": "tree", "colour": [128, 128, 0]},
                                             {"id": 3, "name": "void", "colour": [0, 0, 0]}], "unknown": 3}))
    keys = tmp_path / "keys"
    keys.mkdir()
    lab = np.zeros((48, 64), np.uint8)
    lab[:, 20:40], lab[:, 40:] = 1, 2
    cv2.imwrite(str(keys / "f0.png"), lab)
    later = np.where(lab == 0, 3, lab).astype(np.uint8)  # the road left unknown
    for name in ("f3.png", "f5.png"):
        cv2.imwrite(str(keys / name), later)
    assert main(["run", str(folder), "--labels", str(keys), "--classes", str(table), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert (f"--labels {keys}: road, drawn on other key frames, on neither of f3.png and f5.png, which label the "
            "frames around them: those frames are not given it") in err, err
    cv2.imwrite(str(keys / "f3.png"), lab)
    cv2.imwrite(str(keys / "f5.png"), lab)
    assert main(["run", str(folder), "--labels", str(keys), "--classes", str(table), "--out", str(tmp_path / "p")]) == 0
    assert "on neither of" not in capsys.readouterr().err


def test_a_class_colour_of_text_or_no_dimension_is_refused_by_name():
    """A colour of text was read digit by digit ('128' as (1, 2, 8)); a 0-d array raised a bare TypeError."""
    from pcreg.classes import ClassTable, LabelClass
    from pcreg.errors import InputError

    for colour in ("128", b"abc", {128: 1, 64: 2, 129: 3}, np.array(5), (1, 2, 3.5)):
        with pytest.raises(InputError, match="has colour .* not three integers 0..255"):
            ClassTable((LabelClass(0, "road", colour), LabelClass(1, "sky", (1, 2, 4)), LabelClass(2, "u", (0, 0, 0))), 2)
    with pytest.raises(InputError, match="class 0's name 5 is not text"):
        ClassTable((LabelClass(0, 5, (9, 9, 9)), LabelClass(1, "sky", (1, 2, 4)), LabelClass(2, "u", (0, 0, 0))), 2)


def test_the_closing_lines_quote_a_class_name_that_holds_a_list_s_comma():
    """A class named ``car, parked`` read as two classes in the closing lines' lists (``car, parked 0.50, road
    0.25``): a name holding a comma, a semicolon, a quote or a list's own word is quoted there, as in the messages."""
    from pcreg.runs.summary import predicted_summary, truth_summary

    table = pcreg.classes.parse_table_json(json.dumps({"classes": [
        {"id": 0, "name": "road", "colour": [1, 0, 0]}, {"id": 1, "name": "car, parked", "colour": [2, 0, 0]},
        {"id": 2, "name": "void", "colour": [0, 0, 0]}], "unknown": 2}), "t")
    steps = {1: {"iou": {"0": 0.75, "1": 0.5}, "predicted_iou": {"0": 0.75, "1": 0.25}, "predicted_error": 3.0}}
    assert "road 0.75 (0.75), 'car, parked' 0.50 (0.25); the mean" in truth_summary(steps, table)
    assert "the class predicted worst: 'car, parked', IoU 0.25" in predicted_summary(steps, str, table, Path("out"))


def test_the_truth_line_says_when_it_is_over_fewer_frames_than_were_labelled():
    """A run of an earlier pcreg scored against the truth and taken further: its earlier steps kept no IoU, and the line
    gave the mean over the frames labelled since as if it were over them all."""
    from pcreg.runs.summary import truth_summary

    steps = {1: {"iou": {"0": 0.5, "1": 0.25}}, 2: {"predicted_error": 1.0}, 3: {"iou": {"0": 0.75}}}
    line = truth_summary(steps, pcreg.classes.LAGR)
    assert line.startswith("\nIoU against the truth, each class's mean over the frames that show it, among the 2 of the "
                           "3 frames whose step holds one (predicted from the confidence in brackets): "), line
    assert ": ground 0.62, obstacle 0.25; the mean over all 2 classes 0.44" in line
    assert ", among the" not in truth_summary({1: steps[1], 3: steps[3]}, pcreg.classes.LAGR)
