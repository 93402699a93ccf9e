"""``pcreg evaluate stream`` on clips unlike the shared ones: frames whose truth is all void, key frames that
leave nothing to score, too few classes on a key frame; each a table without NaN or one line naming the clip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pcreg.cli import main

#: pcreg's labels (0 ground, 1 obstacle, 2 unknown) as CamVid ids: road, building, void.
CAMVID_ID = np.array([3, 1, 11], np.uint8)


def _clip(folder: Path, n: int, *, void: tuple[int, ...] = (), seed: int = 0) -> Path:
    """A CamVid-layout clip of ``n`` synthetic frames (96x72), the frames in ``void`` labelled void all over."""
    import cv2

    import pcreg

    (folder / "images").mkdir(parents=True)
    (folder / "labels").mkdir()
    for i, f in enumerate(pcreg.synthetic("syn1a", n, seed, width=96, height=72)):
        lab = np.full(f.labels.shape, 11, np.uint8) if i in void else CAMVID_ID[f.labels]
        cv2.imwrite(str(folder / "images" / f"f{i:02d}.png"), f.image[:, :, ::-1])
        cv2.imwrite(str(folder / "labels" / f"f{i:02d}.png"), lab)
    return folder


@pytest.mark.parametrize("classes", [[], ["--classes", "camvid11"]], ids=["two_classes", "camvid11"])
def test_a_frame_whose_truth_is_all_void_is_left_out_and_named(tmp_path, capsys, classes):
    """With --classes camvid11 a frame labelled void all over made the clip's mean error NaN in every table
    (and its check 'NOT met (nan% vs nan%)'); with two classes it was counted as scored."""
    _clip(tmp_path / "data" / "clip", 4, void=(2,))
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", *classes, "--methods", "plain",
                 "--out", str(out)]) == 0
    capsys.readouterr()
    res = json.loads((out / "results.json").read_text())
    clip = res["datasets"]["clip"]
    assert clip["scored"] == 2 and clip["unscored"] == ["f02"]
    rows = res["units"][0]["frames"]
    assert [r["name"] for r in rows] == ["f01", "f03"]
    assert np.isfinite(clip["means"]["plain"])
    assert clip["means"]["plain"] == pytest.approx(np.mean([r["errors"]["plain"] for r in rows]))
    table = (out / "stream_reference.md").read_text()
    assert "nan" not in table and "clip: 1 frame(s) not scored, their truth all unknown (void): f02" in table
    # the count is of the frames scored (2), not of the clip's (4, in results.json)
    head, row = (out / "stream_reference.csv").read_text().splitlines()[:2]
    assert head == "clip,frames scored,plain" and row.startswith("clip,2,") and clip["frames"] == 4


@pytest.mark.parametrize("given", [["--classes", "camvid11", "--methods", "plain"], []])
def test_a_clip_whose_frames_to_score_are_all_void_is_refused(tmp_path, capsys, given):
    """One line; numpy's "Mean of empty slice" warning came before it (two classes, every method)."""
    import warnings

    _clip(tmp_path / "data" / "clip", 3, void=(1, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", *given,
                     "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"clip clip of camvid:{tmp_path / 'data'}: the truth of every frame that is not a key frame is all unknown" in err


@pytest.mark.parametrize("keys, message", [
    ("spaced:3", "clip a: --keys spaced:3: spaced:N needs 1 <= N <= 2"),
    ("every:1", "clip a: --keys every:1: every one of the clip's 2 frames is a key frame"),
    ("suggest:2", "clip a: --keys suggest:2: every one of the clip's 2 frames is a key frame"),
])
def test_key_frames_a_clip_cannot_take_are_refused_naming_it_before_any_clip_runs(tmp_path, capsys, keys, message):
    """The refusal named no clip (which of a folder's?), and came when that clip's turn came."""
    _clip(tmp_path / "data" / "a", 2)
    _clip(tmp_path / "data" / "b", 5, seed=1)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", "--keys", keys, "--methods", "plain",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.replace("clip a:", f"clip a of camvid:{tmp_path / 'data'}:") in err, err
    assert not (out / "units").is_dir() or not any((out / "units").iterdir())  # no clip ran


def test_a_key_frame_of_one_class_names_its_clip(tmp_path, capsys):
    import cv2

    clip = _clip(tmp_path / "data" / "clip", 3)
    cv2.imwrite(str(clip / "labels" / "f00.png"), np.full((72, 96), 3, np.uint8))  # road only
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", "--classes", "camvid11",
                 "--methods", "plain", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"clip clip of camvid:{tmp_path / 'data'}: training labels hold only one class (road)" in err
    void = _clip(tmp_path / "void" / "clip", 3, void=(0,))  # void only: it said "only one class (none)"
    assert main(["evaluate", "stream", "--data", f"camvid:{void.parent}", "--classes", "camvid11",
                 "--methods", "plain", "--out", str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"clip clip of camvid:{void.parent}: training labels hold no class (every pixel void)" in err, err


def test_classes_no_key_frame_shows_are_named_under_the_class_tables(tmp_path, capsys):
    """Sky only in frames after the key frame: its IoU was 0.00 for every method with no word why."""
    import cv2

    clip = _clip(tmp_path / "data" / "clip", 4)
    for name in ("f02", "f03"):  # sky (0) and a pole (2) in the top corner, after the key frame f00
        lab = cv2.imread(str(clip / "labels" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        lab[:8, :16], lab[:8, 16:20] = 0, 2
        cv2.imwrite(str(clip / "labels" / f"{name}.png"), lab)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", "--classes", "camvid11",
                 "--methods", "plain,unregistered", "--out", str(out)]) == 0
    capsys.readouterr()
    res = json.loads((out / "results.json").read_text())
    clip_res = res["datasets"]["clip"]
    assert clip_res["classes_not_in_keys"] == [0, 2] and clip_res["iou"]["plain"]["0"] == 0.0
    line = "clip: no key frame shows sky, pole: no method can label them"
    for table in ("stream_iou.md", "stream_miou.md"):
        assert line in (out / table).read_text()
    assert res["datasets"]["clip"]["scored"] == 3 and "miou" in clip_res  # the numbers as before, one line more


def test_a_clip_whose_key_frames_show_every_class_names_none(tmp_path, capsys):
    _clip(tmp_path / "data" / "clip", 3)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", "--classes", "camvid11",
                 "--methods", "plain", "--out", str(out)]) == 0
    capsys.readouterr()
    assert "classes_not_in_keys" not in json.loads((out / "results.json").read_text())["datasets"]["clip"]
    assert "no key frame shows" not in (out / "stream_iou.md").read_text()


@pytest.mark.parametrize("classes", [[], ["--classes", "camvid11"]], ids=["two_classes", "camvid11"])
def test_hidden_files_in_a_clip_folder_are_skipped(tmp_path, capsys, classes):
    """macOS leaves ``._NAME.png`` (resource forks, not images) and ``.DS_Store`` beside the frames on a USB drive:
    read as frames, they stopped the evaluation; pcreg run already skipped them."""
    runs = {}
    for case in ("clean", "hidden"):
        clip = _clip(tmp_path / case / "clip", 3)
        if case == "hidden":
            for sub in ("images", "labels"):
                (clip / sub / "._f00.png").write_bytes(b"\x00\x05\x16\x07 not an image")
                (clip / sub / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1")
        out = tmp_path / f"out_{case}"
        assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / case}", *classes, "--methods", "plain",
                     "--out", str(out)]) == 0, capsys.readouterr().err
        res = json.loads((out / "results.json").read_text())
        runs[case] = ([(r["name"], r["errors"]) for r in res["units"][0]["frames"]], res["datasets"]["clip"]["frames"])
    capsys.readouterr()
    assert runs["hidden"] == runs["clean"] and runs["clean"][1] == 3


def test_a_clip_that_plain_labels_without_error_leaves_the_mean_reduction_of_the_others(tmp_path):
    """A clip on which naive Bayes alone makes no error has no reduction against it (0 of 0): its NaN made every
    method's mean reduction over the clips NaN, the last row of the table nan and the checks 'NOT met (nan% ...)'.
    The mean is over the clips that have one, and the table names the clip left out."""
    import cv2

    _clip(tmp_path / "data" / "a", 4)
    easy = tmp_path / "data" / "b"
    (easy / "images").mkdir(parents=True)
    (easy / "labels").mkdir()
    image, lab = np.zeros((72, 96, 3), np.uint8), np.full((72, 96), CAMVID_ID[0], np.uint8)
    image[:36], lab[:36] = 255, CAMVID_ID[1]  # white obstacle above a black road: no pixel in doubt
    for i in range(4):
        cv2.imwrite(str(easy / "images" / f"f{i:02d}.png"), image)
        cv2.imwrite(str(easy / "labels" / f"f{i:02d}.png"), lab)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", "--methods", "unregistered",
                 "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["datasets"]["b"]["means"]["plain"] == 0 and res["datasets"]["b"]["reduction"]["plain"] is None
    for m in ("plain", "unregistered"):
        assert res["average_reduction"][m] == pytest.approx(res["datasets"]["a"]["reduction"][m])
    table = (out / "stream_reference.md").read_text()
    assert "| nan |" not in table.split("reduction vs plain")[1].splitlines()[0]
    assert "b: naive Bayes alone made no error, no reduction to take; left out of the mean" in table


@pytest.mark.parametrize("options", [["--keys", "first,last"], ["--classes", "camvid11"]], ids=["keys", "camvid11"])
def test_a_recording_of_key_frames_or_classes_holds_every_scored_frame(tmp_path, capsys, options):
    """``evaluate stream --record`` with --keys or --classes wrote a recording of its config and log alone: those
    protocols never called the recording's hook, and nothing said so. Each scored frame is now in it, in order,
    with its truth and the methods' labels, under the classes of the table they are ids of."""
    from pcreg.classes import CAMVID11, LAGR
    from pcreg.recording.readback import image, read_recording, segmentation

    import pcreg

    _clip(tmp_path / "data" / "clip", 5)
    rrd, out = tmp_path / "s.rrd", tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", *options, "--methods", "plain,pcreg",
                 "--out", str(out), "--record", str(rrd), "--record-raw"]) == 0
    capsys.readouterr()
    scored = [r["index"] for r in json.loads((out / "results.json").read_text())["units"][0]["frames"]]
    assert scored == ([1, 2, 3] if options[0] == "--keys" else [1, 2, 3, 4])
    rec = read_recording(rrd)
    assert sorted(r.times["frame"] for r in rec.get("labels/truth")) == list(range(len(scored)))
    frames = pcreg.synthetic("syn1a", 5, 0, width=96, height=72)
    camvid = options[0] == "--classes"
    for counter, t in enumerate(scored):
        np.testing.assert_array_equal(image(rec.moving(counter)), frames[t].image)
        truth = segmentation(rec.latest("labels/truth", frame=counter))
        np.testing.assert_array_equal(truth, (CAMVID_ID[frames[t].labels] if camvid else frames[t].labels))
        for m in ("plain", "pcreg"):
            assert segmentation(rec.latest(f"labels/predicted/{m}", frame=counter)).shape == truth.shape
    context = rec.latest("/")["AnnotationContext:context"].to_pylist()[0]
    names = {c["class_id"]: c["class_description"]["info"]["label"] for c in context}
    if camvid:
        assert names == {c.id: c.name for c in CAMVID11.classes}
    else:
        assert names == {0: "ground", 1: "obstacle", 2: "unknown"} == {c.id: c.name for c in LAGR.classes}


def test_key_frames_suggested_for_a_table_of_many_classes_are_chosen_in_its_classes(tmp_path, capsys):
    """``--classes camvid11 --keys suggest:2`` ran its first pass in ground and obstacle: 'label values must be
    0 ground, 1 obstacle, 2 unknown; got 3', exit 2, for a clip the same run takes with ``--keys first,last``."""
    _clip(tmp_path / "data" / "clip", 5)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{tmp_path / 'data'}", "--classes", "camvid11",
                 "--keys", "suggest:2", "--methods", "plain", "--out", str(out)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    keys = json.loads((out / "results.json").read_text())["units"][0]["key_frames"]
    assert len(keys) == 2 and keys[0] == 0 and 0 < keys[1] < 5
