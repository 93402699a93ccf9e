"""DAVIS 2017's multi-object masks: a palette PNG whose indices are the objects (0 the background, 255
void). ``--data davis:PATH`` follows and scores each object on its own (a clip ``SEQ_K`` each, the means
over objects, as davis2017-evaluation does); ``pcreg run --classes davis`` refuses such a key mask in one
line naming its objects instead of merging them."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.classes import DAVIS
from pcreg.classes.keys import read_key_labels
from pcreg.cli import main
from pcreg.datasets import load_dataset
from pcreg.datasets.davis import load_davis, load_objects, load_sequence
from pcreg.errors import DatasetError
from _davis import frames_and_masks, halves, shared_sequence, write_palette
from _runs import one_line_errors

def two_object_sequence(seq: Path, images, masks, *, void: bool = False) -> list[np.ndarray]:
    """``seq/images/NNNNN.jpg`` with ``seq/labels/NNNNN.png`` palette masks of two objects; the ids written."""
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    out = []
    for i, (img, mask) in enumerate(zip(images, masks)):
        cv2.imwrite(str(seq / "images" / f"{i:05d}.jpg"), img)
        out.append(halves(mask, void=void))
        write_palette(seq / "labels" / f"{i:05d}.png", out[-1])
    return out


def _synthetic(tmp_path: Path, n: int = 5, **kw) -> tuple[Path, list[np.ndarray]]:
    pairs = frames_and_masks(n)
    seq = tmp_path / "disc"
    return seq, two_object_sequence(seq, [p[0] for p in pairs], [p[1] for p in pairs], **kw)


def test_each_object_of_a_palette_mask_is_a_clip_of_its_own(tmp_path):
    seq, ids = _synthetic(tmp_path, void=True)
    clips = load_davis(seq)
    assert list(clips) == ["disc_1", "disc_2"]  # davis2017-evaluation's per-object names
    for k in (1, 2):
        for f, v in zip(clips[f"disc_{k}"], ids):
            want = (v == k).astype(np.uint8)
            want[v == 255] = 2  # void: unknown, neither object nor background
            np.testing.assert_array_equal(f.labels, want)
    assert clips["disc_1"][0].image is clips["disc_2"][0].image or \
        np.array_equal(clips["disc_1"][0].image, clips["disc_2"][0].image)
    assert list(load_dataset(f"davis:{seq}", n_frames=2)) == ["disc_1", "disc_2"]


def one_object_sequence(seq: Path, pairs, write_mask) -> Path:
    """``seq/images/NNNNN.jpg`` of ``pairs`` (image, 0/255 mask), each mask written by ``write_mask(i, path, mask)``."""
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    for i, (img, mask) in enumerate(pairs):
        cv2.imwrite(str(seq / "images" / f"{i:05d}.jpg"), img)
        write_mask(i, seq / "labels" / f"{i:05d}.png", mask)
    return seq


def test_a_one_object_sequence_keeps_its_name_and_a_0_255_palette_is_one_object(tmp_path):
    pairs = frames_and_masks(3)
    # DAVIS 2016's 0/255 saved as a palette
    seq = one_object_sequence(tmp_path / "one", pairs, lambda i, path, mask: write_palette(path, mask))
    frames = load_davis(seq)["one"]
    np.testing.assert_array_equal(frames[2].labels, pairs[2][1] > 0)
    assert load_sequence(seq / "images", seq / "labels")[0].name == "00000"


def test_a_palette_first_mask_then_0_255_masks_reads_every_frames_object(tmp_path):
    """One frame's mask saved again in an editor as a palette of ids 0/1, the others DAVIS 2016's 0/255: each mask
    reads as it is stored (255 was read as void on the later frames, every object pixel unscored: J 0 without a
    word)."""
    pairs = frames_and_masks(4)

    def write_mask(i, path, mask):
        return write_palette(path, (mask > 0).astype(np.uint8)) if i == 0 else cv2.imwrite(str(path), mask)

    seq = one_object_sequence(tmp_path / "mixed", pairs, write_mask)
    for f, (_, mask) in zip(load_davis(seq)["mixed"], pairs):
        np.testing.assert_array_equal(f.labels, (mask > 0).astype(np.uint8))


def test_a_grey_first_mask_then_a_palette_of_two_objects_is_refused_not_scored_as_their_union(tmp_path):
    """A first mask of one object (0/255), a later one a palette of objects 1 and 2: both were scored as the first
    frame's object, exit 0, the table as the sequence's untouched. Refused naming the later mask, as the other order
    is; a later palette of that one object is still read."""
    pairs = frames_and_masks(4)

    def write_mask(i, path, mask):
        return cv2.imwrite(str(path), mask) if i != 2 else write_palette(path, halves(mask))

    seq = one_object_sequence(tmp_path / "mixed", pairs, write_mask)
    with pytest.raises(DatasetError, match=r"00002\.png: a mask of 2 objects by palette index \(1, 2\) after a first mask of one"):
        load_davis(seq)
    write_palette(seq / "labels" / "00002.png", (pairs[2][1] > 0).astype(np.uint8))
    np.testing.assert_array_equal(load_davis(seq)["mixed"][2].labels, (pairs[2][1] > 0).astype(np.uint8))


def test_load_sequence_refuses_several_objects_naming_the_mask_and_its_ids(tmp_path):
    seq, _ = _synthetic(tmp_path, n=3)
    with pytest.raises(DatasetError) as err:
        load_sequence(seq / "images", seq / "labels")
    assert str(seq / "labels" / "00000.png") in str(err.value) and "palette indices 1, 2" in str(err.value)
    assert list(load_objects(seq / "images", seq / "labels", name="disc")) == ["disc_1", "disc_2"]


def test_an_object_clip_that_takes_another_sequences_name_is_refused(tmp_path):
    seq, _ = _synthetic(tmp_path / "root", n=3)
    other = tmp_path / "root" / "disc_1"
    (other / "images").mkdir(parents=True)
    (other / "labels").mkdir()
    for i, (img, mask) in enumerate(frames_and_masks(3)):
        cv2.imwrite(str(other / "images" / f"{i:05d}.jpg"), img)
        cv2.imwrite(str(other / "labels" / f"{i:05d}.png"), mask)
    with pytest.raises(DatasetError, match="has the name of another sequence"):
        load_davis(tmp_path / "root")


def test_evaluate_stream_scores_each_object_and_means_over_objects(tmp_path, capsys):
    seq, ids = _synthetic(tmp_path, n=5)
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--methods", "unregistered", "--out", str(out)]) == 0
    d = json.loads((out / "results.json").read_text())["davis"]
    assert list(d["sequences"]) == ["disc_1", "disc_2"] and d["objects"] == {"disc": ["disc_1", "disc_2"]}
    units = {u["dataset"]: u["davis"] for u in json.loads((out / "results.json").read_text())["units"]}
    for k in (1, 2):  # each object scored on frames 1 to n-2 against its own mask
        assert units[f"disc_{k}"]["frames"] == [1, 2, 3]
        assert d["sequences"][f"disc_{k}"]["J"]["unregistered"] == pytest.approx(np.mean(units[f"disc_{k}"]["J"]["unregistered"]))
    assert units["disc_1"]["J"] != units["disc_2"]["J"]
    assert d["mean"]["J"]["unregistered"] == pytest.approx(
        np.mean([d["sequences"][c]["J"]["unregistered"] for c in ("disc_1", "disc_2")]))
    table = (out / "davis_J.md").read_text()
    assert "| disc_1 | 3 |" in table and "| disc_2 | 3 |" in table and "mean over objects" in table
    assert "disc: disc_1, disc_2" in table


@pytest.mark.data
def test_a_shared_sequence_split_into_two_objects_is_scored_per_object(shared_data, tmp_path, capsys):
    src = shared_sequence(shared_data, "blackswan")
    n = 4
    images = [cv2.imread(str(src / "images" / f"{i:05d}.jpg")) for i in range(n)]
    masks = [cv2.imread(str(src / "labels" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) for i in range(n)]
    ids = two_object_sequence(tmp_path / "blackswan", images, masks)
    clips = load_davis(tmp_path / "blackswan")
    assert list(clips) == ["blackswan_1", "blackswan_2"]
    for k in (1, 2):
        assert (clips[f"blackswan_{k}"][0].labels == 1).sum() == (ids[0] == k).sum() > 1000
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--data", f"davis:{tmp_path / 'blackswan'}", "--methods", "unregistered",
                 "--out", str(out)]) == 0
    d = json.loads((out / "results.json").read_text())["davis"]
    assert {c: d["sequences"][c]["frames"] for c in d["sequences"]} == {"blackswan_1": 2, "blackswan_2": 2}
    assert all(0.5 < d["sequences"][c]["J"]["unregistered"] <= 1 for c in d["sequences"])
    # the published figures are of DAVIS 2016's one object, not of these halves
    assert all(v is None or np.isnan(v) for v in d["published"]["J"]["osvos"].values())
    assert "no figure for any of these 2 objects" in (out / "davis_J.md").read_text()  # two objects of one sequence


def test_pcreg_run_refuses_a_multi_object_key_mask_naming_it_and_its_objects(tmp_path, capsys):
    seq, _ = _synthetic(tmp_path, n=3)
    key = seq / "labels" / "00000.png"
    for args in (["--classes", "davis"], ["--mapping", "davis"]):
        out = tmp_path / f"out{len(args[0])}"
        assert main(["run", str(seq / "images"), "--labels", str(key), "--out", str(out), *args]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and str(key) in err[0] and "2 objects (palette indices 1, 2" in err[0]
        assert "one mask per object" in err[0]
        assert not out.exists()


def test_a_palettes_void_index_is_unknown_beside_one_object(tmp_path):
    ids = np.zeros((8, 10), np.uint8)
    ids[2:5, 2:6] = 1
    ids[0] = 255
    labels = read_key_labels(write_palette(tmp_path / "k.png", ids), DAVIS, "davis")
    want = (ids == 1).astype(np.uint8)
    want[0] = 2
    np.testing.assert_array_equal(labels, want)


def test_void_on_a_later_frame_is_unknown_when_the_first_frame_has_none(tmp_path):
    # the void index was taken from the first frame only: without void there, a later frame's 255 was background,
    # counted in the error % and fitted as background at a later key frame
    pairs = frames_and_masks(4)
    seq = tmp_path / "disc"
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    for i, (img, mask) in enumerate(pairs):
        cv2.imwrite(str(seq / "images" / f"{i:05d}.jpg"), img)
        ids = (mask > 0).astype(np.uint8)
        if i == 2:
            ids[:3] = 255
        write_palette(seq / "labels" / f"{i:05d}.png", ids)
    frames = load_sequence(seq / "images", seq / "labels")
    assert [set(np.unique(f.labels).tolist()) for f in frames] == [{0, 1}, {0, 1}, {0, 1, 2}, {0, 1}]
    assert (frames[2].labels[:3] == 2).all()
    for i, (_, mask) in enumerate(pairs):  # DAVIS 2016's 0/255 in a palette: 255 stays the object on every frame
        write_palette(seq / "labels" / f"{i:05d}.png", mask)
    assert all(((f.labels == 1) == (m > 0)).all() for f, (_, m) in zip(load_sequence(seq / "images", seq / "labels"), pairs))


def test_a_first_mask_all_object_is_refused_naming_its_file(tmp_path, capsys):
    """A first mask all object: refused as the sequence is read, in one line naming the mask (it was the classifier's
    fit, in ground and obstacle, naming no file: "training labels hold only one class (obstacle)")."""
    pairs = frames_and_masks(3)
    seq = one_object_sequence(tmp_path / "whole", pairs, lambda i, path, mask: cv2.imwrite(
        str(path), np.full_like(mask, 255) if i == 0 else mask))
    assert main(["evaluate", "stream", "--data", f"davis:{seq}", "--out", str(tmp_path / "out")]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {seq / 'labels' / '00000.png'}: the object's mask on the key "
                                       "frame covers the whole frame: no background pixel, which the classifier "
                                       "needs beside the object's"]
    assert not (tmp_path / "out" / "units").exists()


def test_a_first_object_too_small_to_follow_is_refused_before_any_clip_runs(tmp_path, capsys):
    """A sequence whose first mask holds an object of one pixel, beside one that is fine: the follower refused it
    only once the first sequence had run and its files were written. Refused before any clip runs; without the
    follower among the methods the sequences are scored."""
    pairs = frames_and_masks(3)
    data = tmp_path / "davis"
    one_object_sequence(data / "a", pairs, lambda i, path, mask: cv2.imwrite(str(path), mask))

    def speck(i, path, mask):
        if i == 0:
            mask = np.zeros_like(mask)
            mask[10, 10] = 255
        cv2.imwrite(str(path), mask)

    one_object_sequence(data / "b", pairs, speck)
    run = ["evaluate", "stream", "--data", f"davis:{data}", "--out", str(tmp_path / "out")]
    assert main([*run, "--methods", "plain,pcreg_object"]) == 2
    (line,) = one_line_errors(capsys)
    assert f"clip b of davis:{data}: the object on the key frame 00000 (1 px) covers no pixel at the size pcreg_object works at" in line
    assert not (tmp_path / "out").exists()
    assert main([*run, "--methods", "plain"]) == 0
