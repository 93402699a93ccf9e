"""DAVIS 2017's multi-object masks saved otherwise than as a palette PNG: grey, the object ids as values
(0, 1, 2, ...), or RGB in DAVIS's palette colours. ``--data davis:PATH`` reads each object on its own and
``pcreg run --classes davis`` refuses them, exactly as it does the palette PNG; a DAVIS 2016 0/255 mask is
still one object, and a mask that could be read two ways is refused saying what it holds."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.classes import DAVIS, voc_colormap
from pcreg.classes.keys import read_key_labels
from pcreg.cli import main
from pcreg.datasets import load_dataset
from pcreg.datasets.davis import load_davis
from pcreg.errors import DatasetError, InputError
from _davis import frames_and_masks, halves, shared_sequence, write_palette
from _runs import one_line_errors

PALETTE = voc_colormap(256)  # DAVIS's palette: 1 (128, 0, 0), 2 (0, 128, 0), ..., 255 (224, 224, 192)


def _write(path: Path, ids: np.ndarray, how: str) -> None:
    if how == "palette":
        write_palette(path, ids)
    elif how == "grey":
        cv2.imwrite(str(path), ids)
    else:
        cv2.imwrite(str(path), PALETTE[ids][:, :, ::-1])


def _sequence(seq: Path, images, masks, how: str) -> list[np.ndarray]:
    """``seq/images`` and ``seq/labels`` of two objects (each mask's halves) saved ``how``; the ids."""
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    out = []
    for i, (img, mask) in enumerate(zip(images, masks)):
        cv2.imwrite(str(seq / "images" / f"{i:05d}.jpg"), img)
        out.append(halves(mask))
        if i == len(images) - 1:
            out[-1][out[-1] == 1] = 0  # the last frame shows object 2 alone: it is still object 2
        _write(seq / "labels" / f"{i:05d}.png", out[-1], how)
    return out


def _same_clips(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for clip in a:
        assert [f.name for f in a[clip]] == [f.name for f in b[clip]]
        for x, y in zip(a[clip], b[clip]):
            np.testing.assert_array_equal(x.labels, y.labels)


@pytest.mark.parametrize("how", ["grey", "rgb"])
def test_grey_and_rgb_masks_of_several_objects_read_as_the_palette_png(tmp_path, how):
    pairs = frames_and_masks(4)
    images, masks = [p[0] for p in pairs], [p[1] for p in pairs]
    ids = _sequence(tmp_path / "palette" / "disc", images, masks, "palette")
    _sequence(tmp_path / how / "disc", images, masks, how)
    palette, other = load_davis(tmp_path / "palette"), load_davis(tmp_path / how)
    assert list(other) == ["disc_1", "disc_2"]
    _same_clips(other, palette)
    np.testing.assert_array_equal(other["disc_2"][-1].labels, ids[-1] == 2)
    assert not other["disc_1"][-1].labels.any()


@pytest.mark.parametrize("how", ["grey", "rgb"])
def test_pcreg_run_refuses_them_as_it_refuses_the_palette_png(tmp_path, capsys, how):
    pairs = frames_and_masks(3)
    _sequence(tmp_path / "disc", [p[0] for p in pairs], [p[1] for p in pairs], how)
    key = tmp_path / "disc" / "labels" / "00000.png"
    assert main(["run", str(tmp_path / "disc" / "images"), "--labels", str(key), "--classes", "davis",
                 "--out", str(tmp_path / "out")]) == 2
    (line,) = one_line_errors(capsys)
    assert str(key) in line and "2 objects (object ids 1, 2" in line and "one mask per object" in line
    assert not (tmp_path / "out").exists()


def test_one_object_reads_as_before(tmp_path):
    mask = frames_and_masks(1)[0][1]
    for value in (255, 1, 7):  # DAVIS 2016's 0/255, and a mask of one other value
        cv2.imwrite(str(tmp_path / "k.png"), np.where(mask > 0, value, 0).astype(np.uint8))
        np.testing.assert_array_equal(read_key_labels(tmp_path / "k.png", DAVIS, "davis"), mask > 0)
    for colour in ((255, 255, 255), (200, 30, 10), (128, 0, 0)):  # one colour, of the palette or not
        rgb = np.zeros(mask.shape + (3,), np.uint8)
        rgb[mask > 0] = colour
        cv2.imwrite(str(tmp_path / "k.png"), rgb[:, :, ::-1])
        np.testing.assert_array_equal(read_key_labels(tmp_path / "k.png", DAVIS, "davis"), mask > 0)


def test_16_bit_masks_read_as_their_8_bit_values(tmp_path, capsys):
    # a 16-bit grey mask was refused ("an object mask must be an 8-bit image, got uint16"), even 0/65535
    pairs = frames_and_masks(4)
    images, masks = [p[0] for p in pairs], [p[1] for p in pairs]
    _sequence(tmp_path / "palette" / "disc", images, masks, "palette")
    (tmp_path / "wide" / "disc").mkdir(parents=True)
    shutil.copytree(tmp_path / "palette" / "disc" / "images", tmp_path / "wide" / "disc" / "images")
    (tmp_path / "wide" / "disc" / "labels").mkdir()
    for i, mask in enumerate(masks):  # object ids 1 and 2 in 16 bits
        ids = halves(mask)
        if i == len(masks) - 1:
            ids[ids == 1] = 0
        cv2.imwrite(str(tmp_path / "wide" / "disc" / "labels" / f"{i:05d}.png"), ids.astype(np.uint16))
    _same_clips(load_davis(tmp_path / "wide"), load_davis(tmp_path / "palette"))
    key = tmp_path / "k.png"
    cv2.imwrite(str(key), (masks[0] > 0).astype(np.uint16) * 65535)  # one object, 0 and 65535
    np.testing.assert_array_equal(read_key_labels(key, DAVIS, "davis"), masks[0] > 0)
    assert main(["run", str(tmp_path / "palette" / "disc" / "images"), "--labels", str(key), "--classes", "davis",
                 "--out", str(tmp_path / "out")]) == 0
    two = np.where(masks[0] > 0, 300, 0).astype(np.uint16)
    two[:, :5] = 301
    cv2.imwrite(str(key), two)
    with pytest.raises(InputError, match="16-bit mask of values 300, 301: not one object"):
        read_key_labels(key, DAVIS, "davis")


def test_a_smoothed_grey_mask_without_255_is_one_object(tmp_path):
    """A 0/M object mask (M below 255: a tool that saves 0/1 scaled, 0/200) resized, its edge smoothed: one object as
    the 0/255 one, never one object per value of its edge; grey ids of objects 1, 2, 3 stay three objects."""
    image, mask = frames_and_masks(1)[0]
    seq = tmp_path / "seq"
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    cv2.imwrite(str(seq / "images" / "00000.jpg"), image)
    for peak in (255, 200):
        soft = cv2.resize(cv2.resize(np.where(mask > 0, peak, 0).astype(np.uint8), None, fx=0.5, fy=0.5,
                                     interpolation=cv2.INTER_AREA), mask.shape[::-1], interpolation=cv2.INTER_LINEAR)
        assert len(np.unique(soft)) > 4 and soft.max() == peak
        cv2.imwrite(str(tmp_path / f"soft{peak}.png"), soft)
        labels = read_key_labels(tmp_path / f"soft{peak}.png", DAVIS, "davis")
        np.testing.assert_array_equal(labels, (soft > 0).astype(np.uint8))
        shutil.copy(tmp_path / f"soft{peak}.png", seq / "labels" / "00000.png")
        clips = load_dataset(f"davis:{seq}")
        assert [len(frames) for frames in clips.values()] == [1], list(clips)
    ids = halves(mask)
    ids[(ids == 2) & (np.arange(mask.shape[0])[:, None] > mask.shape[0] // 2)] = 3
    cv2.imwrite(str(seq / "labels" / "00000.png"), ids)
    assert len(load_dataset(f"davis:{seq}")) == 3


def test_masks_that_read_two_ways_are_refused_saying_what_they_hold(tmp_path):
    mask = frames_and_masks(1)[0][1]
    soft = cv2.resize(cv2.resize(mask, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA), mask.shape[::-1],
                      interpolation=cv2.INTER_LINEAR)  # a 0/255 mask resized: its edge smoothed
    assert len(np.unique(soft)) > 3 and soft.max() == 255
    cv2.imwrite(str(tmp_path / "soft.png"), soft)
    labels = read_key_labels(tmp_path / "soft.png", DAVIS, "davis")  # one object, its edge the object's, as before
    assert np.array_equal(labels, (soft > 0).astype(np.uint8))
    ids = halves(mask)
    ids[cv2.dilate((mask > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > (mask > 0)] = 255  # a void band
    cv2.imwrite(str(tmp_path / "void.png"), ids)  # objects 1 and 2 with 255 void: their insides far from it
    with pytest.raises(InputError, match=r"void.png: a grey mask of values 0, 1, 2 and 255, .*palette PNG"):
        read_key_labels(tmp_path / "void.png", DAVIS, "davis")
    rgb = PALETTE[halves(mask)]
    rgb[0, 0] = (200, 30, 10)  # a colour of no palette beside two of it
    cv2.imwrite(str(tmp_path / "odd.png"), rgb[:, :, ::-1])
    with pytest.raises(InputError, match=r"odd.png: .*\(200, 30, 10\) \(at x=0, y=0\) none of DAVIS's palette"):
        read_key_labels(tmp_path / "odd.png", DAVIS, "davis")
    seq = tmp_path / "seq"
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    cv2.imwrite(str(seq / "images" / "00000.jpg"), frames_and_masks(1)[0][0])
    shutil.copy(tmp_path / "void.png", seq / "labels" / "00000.png")
    with pytest.raises(DatasetError, match="a grey mask of values"):
        load_dataset(f"davis:{seq}")


@pytest.mark.data
@pytest.mark.parametrize("factor", [2, 4])
def test_a_0_255_mask_shrunk_with_its_thin_parts_is_one_object(shared_data, tmp_path, factor):
    """A 0/255 mask shrunk (INTER_AREA, as a 1080p mask is brought to 480p) whose thin parts become values between
    with no 255 beside them (kite-surf's lines at a quarter; a 1 px string at a half) was refused as "objects with
    255 void?". Read as one object, its thin parts in it; objects saved as grey ids with 255 void are refused as
    before, and a grey object of 128 beside the 255 one too."""
    mask = cv2.imread(str(sorted((shared_data / "davis" / "kite-surf" / "labels").iterdir())[0]), cv2.IMREAD_GRAYSCALE)
    big = cv2.resize(mask, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    cv2.line(big, (100, 100), (600, 300), 255, 1)  # a string
    small = cv2.resize(big, None, fx=1 / factor, fy=1 / factor, interpolation=cv2.INTER_AREA)
    assert len(np.unique(small)) > 3
    cv2.imwrite(str(tmp_path / "small.png"), small)
    np.testing.assert_array_equal(read_key_labels(tmp_path / "small.png", DAVIS, "davis"), (small > 0).astype(np.uint8))
    k = (mask > 0).astype(np.uint8)
    grey = np.where(k > 0, 1, 0).astype(np.uint8)
    grey[(cv2.dilate(k, np.ones((11, 11), np.uint8)) - k) > 0] = 255  # object 1 with DAVIS 2017's void around it
    beside = mask.copy()
    cv2.circle(beside, (100, 100), 30, 128, -1)
    for name, refused in (("grey.png", grey), ("beside.png", beside)):
        cv2.imwrite(str(tmp_path / name), refused)
        with pytest.raises(InputError, match="beyond 4 px of the 255s"):
            read_key_labels(tmp_path / name, DAVIS, "davis")


def test_a_shared_sequence_as_grey_and_rgb_ids_reads_as_its_palette_png(shared_data, tmp_path):
    src = shared_sequence(shared_data, "blackswan")
    n = 3
    images = [cv2.imread(str(src / "images" / f"{i:05d}.jpg")) for i in range(n)]
    masks = [cv2.imread(str(src / "labels" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) for i in range(n)]
    for how in ("palette", "grey", "rgb"):
        _sequence(tmp_path / how / "blackswan", images, masks, how)
    palette = load_davis(tmp_path / "palette")
    assert list(palette) == ["blackswan_1", "blackswan_2"]
    _same_clips(load_davis(tmp_path / "grey"), palette)
    _same_clips(load_davis(tmp_path / "rgb"), palette)


def test_one_objects_grey_ids_with_a_void_border_are_refused_not_read_as_object(tmp_path):
    """DAVIS 2017's one object saved as grey ids: 1 the object, 255 its void border. Read as one object, the
    border would be object pixels; it is refused as the mask of several objects with void is, and the same
    mask as a palette PNG reads the border as unknown."""
    image, mask = frames_and_masks(1, shape=(96, 128))[0]
    ids = (mask > 0).astype(np.uint8)
    ids[cv2.dilate(ids, np.ones((5, 5), np.uint8)) > ids] = 255  # a void band around the object, as DAVIS 2017
    assert (ids == 1).any() and (ids == 255).any()
    cv2.imwrite(str(tmp_path / "grey.png"), ids)
    with pytest.raises(InputError, match=r"grey.png: a grey mask of values 0, 1 and 255, .*object 1 with 255 void"
                                         r".*255 void, as DAVIS 2017"):
        read_key_labels(tmp_path / "grey.png", DAVIS, "davis")
    want = (ids == 1).astype(np.uint8)
    want[ids == 255] = 2
    np.testing.assert_array_equal(read_key_labels(write_palette(tmp_path / "p.png", ids), DAVIS, "davis"), want)
    seq = tmp_path / "seq"
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    cv2.imwrite(str(seq / "images" / "00000.jpg"), image)
    shutil.copy(tmp_path / "grey.png", seq / "labels" / "00000.png")
    with pytest.raises(DatasetError, match="00000.png: a grey mask of values 0, 1 and 255"):
        load_dataset(f"davis:{seq}")


@pytest.mark.parametrize("peak, how", [(200, "blurred"), (200, "resized"), (255, "blurred")])
def test_a_mask_smoothed_wider_than_its_edge_is_refused_saying_so(tmp_path, capsys, peak, how):
    """A 0/M mask blurred, or resized more than 4 times, its values between beyond 4 px of M: without 255,
    ``--data davis:`` read each value as an object, a clip of its own (dozens of clips, silently), and ``pcreg run
    --classes davis`` refused "a mask of 39 objects"; with 255 it was "objects 1, 2, 4, ... with 255 void?". It is
    refused saying what it looks like and how to save it, and ``pcreg run`` without --classes says so too."""
    pairs = frames_and_masks(2, shape=(96, 128))
    binary = np.where(pairs[0][1] > 0, peak, 0).astype(np.uint8)
    soft = cv2.GaussianBlur(binary, (0, 0), 4) if how == "blurred" else \
        cv2.resize(cv2.resize(binary, (16, 12), interpolation=cv2.INTER_AREA), (128, 96), interpolation=cv2.INTER_LINEAR)
    assert soft.max() == peak and len(np.unique(soft)) > 20
    seq = tmp_path / "seq"
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    for i, (image, _) in enumerate(pairs):
        cv2.imwrite(str(seq / "images" / f"{i:05d}.jpg"), image)
        cv2.imwrite(str(seq / "labels" / f"{i:05d}.png"), soft)
    said = f"a grey mask of values rising gradually from 0 to {peak} over more than 4 px"
    with pytest.raises(DatasetError, match=said):
        load_dataset(f"davis:{seq}")
    key = seq / "labels" / "00000.png"
    with pytest.raises(InputError, match=f"{said}.*threshold it"):
        read_key_labels(key, DAVIS, "davis")
    assert main(["run", str(seq / "images"), "--labels", str(key), "--out", str(tmp_path / "out")]) == 2
    (line,) = one_line_errors(capsys)
    assert "is not a class id" in line and f"it holds values rising gradually from 0 to {peak}" in line, line


@pytest.mark.parametrize("under", ["the object's colour", "black"])
def test_a_mask_with_transparent_pixels_is_refused_as_labels_of_two_classes_are(tmp_path, under):
    """An object mask with an alpha channel: an area erased in an editor keeps its colour under alpha 0, and was read
    as object (with an object of white under it, the whole area; with black, a mask read right by chance), where
    labels of two classes with transparent pixels are refused."""
    mask = np.zeros((48, 64, 4), np.uint8)
    mask[10:30, 10:40] = (255, 255, 255, 255)
    mask[:, :, 3] = np.where(mask[:, :, 0] > 0, 255, 0)
    mask[30:40, 10:40] = (255, 255, 255, 0) if under == "the object's colour" else (0, 0, 0, 0)
    cv2.imwrite(str(tmp_path / "m.png"), mask)
    with pytest.raises(InputError, match=r"m\.png: an object mask with transparent pixels .* flatten it onto black"):
        read_key_labels(tmp_path / "m.png", DAVIS, "davis")
    mask[:, :, 3] = 255  # opaque: read by its colours
    cv2.imwrite(str(tmp_path / "m.png"), mask)
    assert read_key_labels(tmp_path / "m.png", DAVIS, "davis")[20, 20] == 1
