"""Other public datasets' layouts given to ``--data davis:`` and ``--data camvid:``: each is read as pcreg reads
its own, or refused in one line that names the path and says how to give it (exit 2), never read otherwise."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets.davis import load_davis
from pcreg.errors import DatasetError
from _davis import frames_and_masks, write_palette
from _runs import one_line_errors


def _youtube_vos(root: Path, n: int = 6) -> Path:
    """YouTube-VOS's layout: ``JPEGImages/SEQ/NNNNN.jpg``, ``Annotations/SEQ/NNNNN.png`` on every fifth frame
    (palette PNGs), ``meta.json``."""
    for i, (img, mask) in enumerate(frames_and_masks(n)):
        (root / "JPEGImages" / "a1b2c3").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / "JPEGImages" / "a1b2c3" / f"{i:05d}.jpg"), img)
        if i % 5 == 0:
            (root / "Annotations" / "a1b2c3").mkdir(parents=True, exist_ok=True)
            write_palette(root / "Annotations" / "a1b2c3" / f"{i:05d}.png", (mask > 0).astype(np.uint8))
    meta = {"videos": {"a1b2c3": {"objects": {"1": {"category": "disc", "frames": ["00000", "00005"]}}}}}
    (root / "meta.json").write_text(json.dumps(meta))
    return root


def test_youtube_vos_layout_is_refused_saying_how_to_give_its_sequences(tmp_path, capsys):
    root = _youtube_vos(tmp_path / "train")
    for where in (root, root / "JPEGImages", root / "JPEGImages" / "a1b2c3"):
        with pytest.raises(DatasetError, match=r"YouTube-VOS's layout .* SEQ/images/ and SEQ/labels/"):
            load_davis(where)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{root}", "--methods", "plain", "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert str(root) in line and "YouTube-VOS" in line and "a mask for every frame" in line
    assert not out.exists()


def _ignore_255_clip(clip: Path, n: int = 3) -> Path:
    """``clip/images`` and ``clip/labels`` of CamVid's eleven classes as some loaders give them: ids 0..10 and
    255 for the pixels to ignore (void), where pcreg's ``camvid11`` has void 11."""
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(clip / "images" / f"f{i:02d}.png"), rng.integers(0, 256, (40, 48, 3), dtype=np.uint8))
        ids = np.full((40, 48), 255, np.uint8)
        ids[:, :44] = np.repeat(np.arange(11, dtype=np.uint8), 4)[None, :]
        cv2.imwrite(str(clip / "labels" / f"f{i:02d}.png"), ids)
    return clip


def test_labels_whose_void_is_255_are_refused_saying_how_to_give_them(tmp_path, capsys):
    clip = _ignore_255_clip(tmp_path / "data" / "c")
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{clip.parent}", "--classes", "camvid11", "--methods",
                 "plain", "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert str(clip / "labels" / "f00.png") in line and "label value 255 is not a class id" in line
    assert "write those pixels as this table's unknown, 11 (void)" in line
    assert main(["run", str(clip / "images"), "--labels", str(clip / "labels" / "f00.png"), "--classes", "camvid11",
                 "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert "Cityscapes' trainIds" in line and "write those pixels as this table's unknown, 11 (void)" in line
    assert not out.exists()


def test_labels_whose_void_is_255_run_and_score_through_a_table_whose_unknown_is_255(tmp_path, capsys):
    """A JSON table whose unknown is 255 reads such labels as they are: the run's labels and scores are those of
    the same labels with void written as 11 under ``camvid11``."""
    from pcreg.classes import CAMVID11, read_label_png
    from pcreg.classes.files import read_table_file, table_json

    clip = _ignore_255_clip(tmp_path / "data" / "c")
    table = json.loads(table_json(CAMVID11))
    table["classes"][-1]["id"] = table["unknown"] = 255
    (tmp_path / "t255.json").write_text(json.dumps(table))
    eleven = _ignore_255_clip(tmp_path / "data11" / "c")
    for f in (eleven / "labels").glob("*.png"):
        ids = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(f), np.where(ids == 255, 11, ids).astype(np.uint8))
    runs = {}
    for name, where, classes in (("255", clip, str(tmp_path / "t255.json")), ("11", eleven, "camvid11")):
        runs[name] = tmp_path / f"run{name}"
        assert main(["run", str(where / "images"), "--labels", str(where / "labels" / "f00.png"), "--classes",
                     classes, "--truth", str(where / "labels"), "--out", str(runs[name])]) == 0
    scored = {k: json.loads((v / "run.json").read_text())["truth"] for k, v in runs.items()}
    assert scored["255"] == scored["11"] and scored["255"]["known"] == 2 * 40 * 44
    t255 = read_table_file(tmp_path / "t255.json")
    assert t255.unknown == 255 and t255.n_known == 11
    for f in sorted(runs["11"].glob("f*.png")):
        want = read_label_png(f, CAMVID11)
        assert np.array_equal(read_label_png(runs["255"] / f.name, t255), np.where(want == 11, 255, want))


def test_key_labels_named_as_cityscapes_names_them_are_refused_saying_how_to_name_them(tmp_path, capsys):
    """Cityscapes names a frame's labels otherwise than the frame (``X_gtFine_labelTrainIds.png`` for
    ``X_leftImg8bit.png``): not matched by a guess; the line says how a key label is named."""
    frames, keys = tmp_path / "leftImg8bit", tmp_path / "gtFine"
    frames.mkdir()
    keys.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(frames / f"aachen_000000_{i:06d}_leftImg8bit.png"),
                    rng.integers(0, 256, (40, 48, 3), dtype=np.uint8))
    cv2.imwrite(str(keys / "aachen_000000_000000_gtFine_labelTrainIds.png"), np.arange(40 * 48).reshape(40, 48) % 2)
    out = tmp_path / "out"
    assert main(["run", str(frames), "--labels", str(keys), "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert "aachen_000000_000000_gtFine_labelTrainIds.png: names no frame" in line
    assert "NAME.png labels the frame NAME" in line
    assert not out.exists()


def test_an_object_mask_in_vocs_palette_given_without_its_table_is_refused_naming_it(tmp_path, capsys):
    """YouTube-VOS's (and DAVIS's) palette mask given to ``pcreg run`` without ``--classes davis``: refused, the
    line naming the palette and the table that reads it."""
    root = _youtube_vos(tmp_path / "train")
    key = root / "Annotations" / "a1b2c3" / "00000.png"
    out = tmp_path / "out"
    assert main(["run", str(root / "JPEGImages" / "a1b2c3"), "--labels", str(key), "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert str(key) in line and "VOC's colour map" in line and "--classes davis reads one object's mask" in line
    assert not out.exists()


def test_a_palette_mask_under_a_table_of_other_colours_says_the_table_takes_the_palettes(tmp_path, capsys):
    """A VOC palette mask of classes (labelme's) under a table file giving its background grey was refused pointing
    to ``--classes FILE``, the very option given: the line says the table's colours must be the palette's."""
    root = _youtube_vos(tmp_path / "train")
    key = root / "Annotations" / "a1b2c3" / "00000.png"
    table = tmp_path / "classes.json"
    table.write_text(json.dumps({"classes": [{"id": 0, "name": "background", "colour": [64, 64, 64]},
                                             {"id": 1, "name": "car", "colour": [128, 0, 0]},
                                             {"id": 255, "name": "void", "colour": [224, 224, 192]}], "unknown": 255}))
    out = tmp_path / "out"
    assert main(["run", str(root / "JPEGImages" / "a1b2c3"), "--labels", str(key), "--classes", str(table),
                 "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert str(key) in line and "'background' (64, 64, 64)" in line
    assert "each in its colour there (its background black; --classes FILE)" in line
    assert not out.exists()


def test_key_masks_of_two_objects_in_one_folder_are_refused_not_carried_into_each_other(tmp_path, capsys):
    """YouTube-VOS's valid split gives an object's mask on the frame it enters, with its own index: a key folder
    whose first mask shows object 1 and a later one object 2 alone would follow object 1 into object 2."""
    root = _youtube_vos(tmp_path / "valid", n=6)
    keys = root / "Annotations" / "a1b2c3"
    ids = np.zeros((48, 64), np.uint8)
    ids[30:40, 40:60] = 2  # object 2 enters on frame 5, alone in its mask
    write_palette(keys / "00005.png", ids)
    out = tmp_path / "out"
    args = ["run", str(root / "JPEGImages" / "a1b2c3"), "--labels", str(keys), "--classes", "davis", "--out", str(out)]
    assert main(args) == 2
    (line,) = one_line_errors(capsys)
    assert str(keys / "00005.png") in line and "object 2, where 00000.png shows object 1" in line
    assert not out.exists()
    ids[ids == 2] = 1  # the same object on both key frames: labelled from both
    write_palette(keys / "00005.png", ids)
    assert main(args) == 0
    assert sorted(p.name for p in out.glob("*.png")) == [f"{i:05d}.png" for i in range(6)]


def test_camvids_colour_labels_given_without_their_table_are_refused_naming_it(tmp_path, capsys):
    """CamVid's ``NAME_L.png`` (its 32 classes' colours) given to ``pcreg run`` with the default table: refused,
    the line naming the options that read it."""
    from pcreg.classes.camvid32 import CAMVID32

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        cv2.imwrite(str(frames / f"0001TP_{i:06d}.png"), rng.integers(0, 256, (40, 48, 3), dtype=np.uint8))
    colours = {name: c for name, c, _ in CAMVID32}
    rgb = np.zeros((40, 48, 3), np.uint8)
    rgb[:20], rgb[20:, :30], rgb[20:, 30:] = colours["Sky"], colours["Road"], colours["LaneMkgsDriv"]
    key = tmp_path / "0001TP_000000_L.png"
    cv2.imwrite(str(key), rgb[:, :, ::-1])
    out = tmp_path / "out"
    assert main(["run", str(frames), "--labels", str(key), "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert str(key) in line and "its colours are CamVid's: --classes camvid11 reads its classes" in line
    assert main(["run", str(frames), "--labels", str(key), "--classes", "camvid11", "--out", str(out)]) == 0


def test_cityscapes_colour_labels_with_an_opaque_alpha_channel_read_through_their_table(tmp_path):
    """Cityscapes' ``_color.png`` is RGBA, opaque everywhere: read through a table of its colours as RGB; a label
    image with transparent pixels is refused naming it."""
    from pcreg.classes import class_table
    from pcreg.classes.keys import read_key_labels
    from pcreg.errors import InputError

    table = {"classes": [{"id": 0, "name": "road", "colour": [128, 64, 128]},
                         {"id": 1, "name": "sidewalk", "colour": [244, 35, 232]},
                         {"id": 2, "name": "car", "colour": [0, 0, 142]},
                         {"id": 3, "name": "unlabeled", "colour": [0, 0, 0]}], "unknown": 3}
    (tmp_path / "cityscapes.json").write_text(json.dumps(table))
    ids = np.zeros((20, 30), np.uint8)
    ids[10:, :15], ids[10:, 15:], ids[0, 0] = 1, 2, 3
    rgba = np.dstack([np.array([c["colour"] for c in table["classes"]], np.uint8)[ids], np.full(ids.shape, 255, np.uint8)])
    path = tmp_path / "aachen_000000_000019_gtFine_color.png"
    cv2.imwrite(str(path), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
    np.testing.assert_array_equal(read_key_labels(path, class_table(str(tmp_path / "cityscapes.json"))), ids)
    rgba[:5, :, 3] = 0
    cv2.imwrite(str(path), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
    with pytest.raises(InputError, match="gtFine_color.png: colour labels with transparent pixels"):
        read_key_labels(path, class_table(str(tmp_path / "cityscapes.json")))


def test_frames_with_upper_case_suffixes_are_frames(tmp_path):
    """A camera's ``IMG_0001.JPG``: frames of ``pcreg run`` and of ``--data davis:`` as ``.jpg`` are, in name
    order, each output named after its frame."""
    seq = tmp_path / "cam"
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    for i, (img, mask) in enumerate(frames_and_masks(4)):
        cv2.imwrite(str(seq / "images" / f"IMG_{i + 1:04d}.JPG"), img)
        cv2.imwrite(str(seq / "labels" / f"IMG_{i + 1:04d}.png"), mask)
    clip = load_davis(seq)["cam"]
    assert [f.name for f in clip] == ["IMG_0001", "IMG_0002", "IMG_0003", "IMG_0004"]
    out = tmp_path / "out"
    assert main(["run", str(seq / "images"), "--labels", str(seq / "labels" / "IMG_0001.png"), "--classes", "davis",
                 "--out", str(out)]) == 0
    assert sorted(p.name for p in out.glob("*.png")) == [f"IMG_{i:04d}.png" for i in range(1, 5)]


def test_a_clip_whose_labels_folder_is_named_otherwise_is_refused_naming_it(tmp_path, capsys):
    """CamVid's colour labels in ``LabelsColor/`` beside ``images/`` were read as no labels at all: the clip loaded
    unlabelled and the evaluation refused it in a line naming no file."""
    clip = _ignore_255_clip(tmp_path / "data" / "c")
    (clip / "labels").rename(clip / "LabelsColor")
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"camvid:{clip.parent}", "--classes", "camvid11", "--methods",
                 "plain", "--out", str(out)]) == 2
    (line,) = one_line_errors(capsys)
    assert line.startswith(f"pcreg: error: {clip / 'labels'}: no such folder") and "if LabelsColor/ holds them" in line
    assert not out.exists()


@pytest.mark.parametrize("which", ["the clip", "a frame"])
def test_names_that_are_not_utf8_are_refused_before_the_evaluation_runs(tmp_path, capsys, which):
    """A clip folder or frames named in Latin-1 (a zip made on Windows, unpacked on Linux): the evaluation ran every
    unit, then failed writing its report (a bug, exit 1; no results.json), and again on every rerun."""
    import os

    import pcreg

    clip = tmp_path / "data" / os.fsdecode(b"caf\xe9" if which == "the clip" else b"clip")
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i, f in enumerate(pcreg.synthetic("syn1a", 3, 0, width=64, height=48)):
        name = os.fsdecode(b"f%d%s.png" % (i, b"\xff" if which == "a frame" else b""))
        (clip / "images" / name).write_bytes(cv2.imencode(".png", f.image[:, :, ::-1])[1].tobytes())  # OpenCV takes
        (clip / "labels" / name).write_bytes(cv2.imencode(".png", f.labels)[1].tobytes())  # no such path
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"folder:{tmp_path / 'data'}", "--methods", "plain",
                 "--out", str(out)]) == 2
    shown = r"'caf\xe9'" if which == "the clip" else r"a frame of clip named 'f0\xff'"
    err = one_line_errors(capsys)
    assert len(err) == 1 and shown in err[0] and "not UTF-8" in err[0], err
    assert not (out / "units").exists() or not any((out / "units").rglob("*.json"))
