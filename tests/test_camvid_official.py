"""CamVid as its own download lays it out: ``701_StillsRaw_full/SEQ_NNNNNN.png`` and
``LabeledApproved_full/SEQ_NNNNNN_L.png`` in the 32 classes' colours. ``--data camvid:ROOT`` finds one clip per
sequence and reads the 32 classes as ``camvid11``'s eleven (or ground and obstacle) by SegNet's grouping."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.classes.mappings import CAMVID_MAPPING
from pcreg.classes.table import CAMVID11
from pcreg.cli import main
from pcreg.datasets import load_dataset
from pcreg.datasets.camvid import CAMVID32
from pcreg.errors import DatasetError
from _runs import one_line_errors

#: A few of the 32 classes' colours (RGB) and the camvid11 id each becomes.
LANE, SIDEWALK, BUS, LIGHT, ROAD, SKY, VOID = (128, 0, 192), (0, 0, 192), (192, 128, 192), (0, 64, 64), \
    (128, 64, 128), (128, 128, 128), (0, 0, 0)
EXPECTED = {LANE: 3, SIDEWALK: 4, BUS: 8, LIGHT: 6, ROAD: 3, SKY: 0, VOID: 11}

FRAMES = {"0001TP": ["0001TP_006690", "0001TP_006720"], "0016E5": ["0016E5_07959", "0016E5_07961", "0016E5_07963"],
          "Seq05VD": ["Seq05VD_f00000", "Seq05VD_f00030"]}


def _colours(i: int) -> np.ndarray:
    """An 8x10 RGB label image of four of the colours, in bands that move with ``i``."""
    colours = list(EXPECTED)
    rgb = np.zeros((8, 10, 3), np.uint8)
    for x in range(10):
        rgb[:, x] = colours[(x // 3 + i) % len(colours)]
    rgb[0, 0] = LANE
    return rgb


def _official(root: Path, frames: str = "701_StillsRaw_full", labels: str = "LabeledApproved_full") -> Path:
    """CamVid's download in ``root``: every sequence's frames in one folder, their ``_L`` colour labels in another."""
    rng = np.random.default_rng(5)
    (root / frames).mkdir(parents=True)
    (root / labels).mkdir()
    (root / "label_colors.txt").write_text("".join(f"{r} {g} {b}\t{n}\n" for n, (r, g, b), _ in CAMVID32))
    i = 0
    for names in FRAMES.values():
        for name in names:
            cv2.imwrite(str(root / frames / f"{name}.png"), rng.integers(0, 256, (8, 10, 3), dtype=np.uint8))
            cv2.imwrite(str(root / labels / f"{name}_L.png"), _colours(i)[:, :, ::-1])
            i += 1
    return root


def _expected_ids(i: int) -> np.ndarray:
    rgb = _colours(i)
    out = np.full(rgb.shape[:2], 255, np.uint8)
    for colour, cid in EXPECTED.items():
        out[(rgb == colour).all(axis=2)] = cid
    assert (out != 255).all()
    return out


def test_the_download_is_one_clip_per_sequence_in_camvid11(tmp_path):
    root = _official(tmp_path / "CamVid")
    data = load_dataset(f"camvid:{root}", classes="camvid11")
    assert list(data) == list(FRAMES)
    i = 0
    for seq, names in FRAMES.items():
        assert [f.name for f in data[seq]] == names
        for f in data[seq]:
            image = cv2.imread(str(root / "701_StillsRaw_full" / f"{f.name}.png"))[:, :, ::-1]
            np.testing.assert_array_equal(f.image, image)
            np.testing.assert_array_equal(f.labels, _expected_ids(i))
            i += 1
    assert load_dataset(f"camvid:{root}", classes="camvid11", n_frames=1)["0016E5"][0].name == "0016E5_07959"


def test_the_download_reads_as_ground_and_obstacle_as_the_shared_clips_do(tmp_path):
    root = _official(tmp_path / "CamVid")
    lut = np.array([CAMVID_MAPPING[k] for k in range(12)], np.uint8)
    data = load_dataset(f"camvid:{root}")
    i = 0
    for seq in FRAMES:
        for f in data[seq]:
            np.testing.assert_array_equal(f.labels, lut[_expected_ids(i)])
            i += 1


def test_every_class_lands_on_a_camvid11_class_of_the_same_colour_where_both_have_it():
    """The 32 classes' grouping: CamVid's colours of the eleven are camvid11's (but for its pavement), and each
    class named as one of the eleven is grouped into it."""
    assert len(CAMVID32) == 32 and len({c for _, c, _ in CAMVID32}) == 32
    ours = {c.colour: c.id for c in CAMVID11.classes}
    same = {"Sky": 0, "Building": 1, "Column_Pole": 2, "Road": 3, "Sidewalk": 4, "Tree": 5, "SignSymbol": 6,
            "Fence": 7, "Car": 8, "Pedestrian": 9, "Bicyclist": 10, "Void": 11}
    for name, colour, cid in CAMVID32:
        assert cid in CAMVID11.ids
        assert ours.get(colour, cid) == cid, name
        if name in same:
            assert cid == same[name], name
    assert [n for n, _, c in CAMVID32 if c == CAMVID11.unknown] == ["Void"]


def test_frames_and_labels_folders_named_otherwise_beside_each_other(tmp_path):
    plain = load_dataset(f"camvid:{_official(tmp_path / 'a')}", classes="camvid11")
    _same_clips(load_dataset(f"camvid:{_official(tmp_path / 'b', 'frames', 'labels_L')}", classes="camvid11"), plain)


def _same_clips(data: dict, plain: dict) -> None:
    assert list(data) == list(plain)
    for seq in plain:
        for x, y in zip(plain[seq], data[seq]):
            assert x.name == y.name
            np.testing.assert_array_equal(x.image, y.image)
            np.testing.assert_array_equal(x.labels, y.labels)


def test_the_download_as_matlabs_example_unpacks_it(tmp_path):
    """MATLAB's CamVid example unzips the frames into ``CamVid/images/701_StillsRaw_full/`` and the labels into
    ``CamVid/labels/``: an ``images/`` of no frame, read as the download, from ``CamVid`` or the folder above it."""
    plain = load_dataset(f"camvid:{_official(tmp_path / 'a')}", classes="camvid11")
    root = tmp_path / "m" / "CamVid"
    (root / "images").mkdir(parents=True)
    shutil.copytree(tmp_path / "a" / "701_StillsRaw_full", root / "images" / "701_StillsRaw_full")
    shutil.copytree(tmp_path / "a" / "LabeledApproved_full", root / "labels")
    for where in (root, root.parent):
        _same_clips(load_dataset(f"camvid:{where}", classes="camvid11"), plain)


def test_a_colour_of_none_of_the_32_is_one_line_naming_the_file_and_the_colour(tmp_path, capsys):
    root = _official(tmp_path / "CamVid")
    bad = root / "LabeledApproved_full" / "0016E5_07961_L.png"
    rgb = _colours(3)
    rgb[2, 4] = (1, 2, 3)
    cv2.imwrite(str(bad), rgb[:, :, ::-1])
    with pytest.raises(DatasetError) as err:
        load_dataset(f"camvid:{root}", classes="camvid11")
    assert str(bad) in str(err.value) and "(1, 2, 3) (at x=4, y=2)" in str(err.value)
    assert "\n" not in str(err.value)
    assert main(["evaluate", "stream", "--data", f"camvid:{root}", "--methods", "unregistered",
                 "--out", str(tmp_path / "out")]) == 2
    (line,) = one_line_errors(capsys)
    assert str(bad) in line and "(1, 2, 3)" in line


@pytest.mark.parametrize("damage, message", [
    ("a frame without its label", "no label file"),
    ("a label of no frame", "label file without an image"),
    ("a frame of no sequence", "not named SEQ_NNNNNN.png"),
])
def test_mismatched_files_are_refused_naming_them(tmp_path, damage, message):
    root = _official(tmp_path / "CamVid")
    if damage == "a frame without its label":
        (root / "LabeledApproved_full" / "0001TP_006720_L.png").unlink()
    elif damage == "a label of no frame":
        (root / "701_StillsRaw_full" / "0001TP_006720.png").unlink()
    else:
        shutil.copy(root / "701_StillsRaw_full" / "0001TP_006720.png", root / "701_StillsRaw_full" / "extra.png")
    with pytest.raises(DatasetError, match=message):
        load_dataset(f"camvid:{root}")


def test_a_folder_of_neither_layout_still_says_where_frames_are_looked_for(tmp_path):
    (tmp_path / "x" / "misc").mkdir(parents=True)
    with pytest.raises(DatasetError, match="no frames .*701_StillsRaw_full"):
        load_dataset(f"camvid:{tmp_path / 'x'}")


def test_the_shared_layouts_32_colours_read_too_and_its_ids_as_before(tmp_path):
    """``images/`` with ``labels/NAME_L.png`` in the 32 colours (the download's files in pcreg's layout)."""
    clip = tmp_path / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i in range(2):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), np.zeros((8, 10, 3), np.uint8))
        cv2.imwrite(str(clip / "labels" / f"f{i}_L.png"), _colours(i)[:, :, ::-1])
    frames = load_dataset(f"camvid:{clip}", classes="camvid11")["clip"]
    np.testing.assert_array_equal(frames[1].labels, _expected_ids(1))


@pytest.mark.data
def test_shared_clips_relaid_as_the_download_read_the_same(shared_data, tmp_path):
    """The shared clips' frames with their labels in CamVid's colours (camvid11's, pavement as CamVid's
    sidewalk), laid out as the download: the same frames and labels as the shared clips give."""
    camvid = shared_data / "camvid"
    if not camvid.is_dir():
        pytest.skip(f"{camvid} is absent")
    root = tmp_path / "CamVid"
    (root / "701_StillsRaw_full").mkdir(parents=True)
    (root / "LabeledApproved_full").mkdir()
    colours = CAMVID11.palette()
    colours[4] = SIDEWALK
    shared = {}
    for clip in ("0006R0", "Seq05VD"):
        shared[clip] = load_dataset(f"camvid:{camvid / clip}", classes="camvid11", n_frames=3)[clip]
        for f in shared[clip]:
            shutil.copy(camvid / clip / "images" / f"{f.name}.png", root / "701_StillsRaw_full")
            cv2.imwrite(str(root / "LabeledApproved_full" / f"{f.name}_L.png"), colours[f.labels][:, :, ::-1])
    data = load_dataset(f"camvid:{root}", classes="camvid11")
    assert list(data) == list(shared)
    for clip, frames in shared.items():
        assert [f.name for f in data[clip]] == [f.name for f in frames]
        for x, y in zip(data[clip], frames):
            np.testing.assert_array_equal(x.image, y.image)
            np.testing.assert_array_equal(x.labels, y.labels)
