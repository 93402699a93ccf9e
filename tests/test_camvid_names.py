"""CamVid's own label names: its download names the label image of frame ``NAME.png`` ``NAME_L.png``
(``LabeledApproved_full/``). ``--data camvid:PATH`` reads ``labels/NAME_L.png`` as frame NAME's labels as it
reads ``labels/NAME.png``; a label file matching no frame, or a frame with both, is one line and exit 2."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets import load_dataset, load_folder
from pcreg.errors import DatasetError
from _runs import one_line_errors


def _clip(folder: Path, n: int = 3, *, suffix: str = "") -> Path:
    """``folder/images/fNN.png`` with CamVid ids in ``folder/labels/fNN{suffix}.png``."""
    rng = np.random.default_rng(3)
    (folder / "images").mkdir(parents=True)
    (folder / "labels").mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / "images" / f"f{i:02d}.png"), rng.integers(0, 256, (8, 10, 3), dtype=np.uint8))
        cv2.imwrite(str(folder / "labels" / f"f{i:02d}{suffix}.png"), rng.integers(0, 12, (8, 10), dtype=np.uint8))
    return folder


def _same(a, b) -> None:
    assert [f.name for f in a] == [f.name for f in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.image, y.image)
        np.testing.assert_array_equal(x.labels, y.labels)


def _renamed(src: Path, dst: Path, names: list[str] | None = None) -> Path:
    """A copy of the clip ``src`` with every label file ``NAME.png`` named ``NAME_L.png``."""
    shutil.copytree(src, dst)
    for p in sorted((dst / "labels").iterdir()):
        if names is None or p.stem in names:
            p.rename(p.with_name(f"{p.stem}_L.png"))
    return dst


def test_labels_named_as_camvid_names_them_read_as_the_plain_names(tmp_path):
    plain = _clip(tmp_path / "plain")
    own = _renamed(plain, tmp_path / "own")
    _same(load_folder(own), load_folder(plain))
    mixed = _renamed(plain, tmp_path / "mixed", names=["f01"])  # some of each
    _same(load_dataset(f"camvid:{mixed}")["mixed"], load_dataset(f"camvid:{plain}")["plain"])


def test_a_frame_named_like_a_label_file_stays_a_frame(tmp_path):
    """``x_L.png`` is a label file only when ``x`` is a frame and ``x_L`` is not."""
    clip = _clip(tmp_path / "c", 2)
    shutil.copy(clip / "images" / "f01.png", clip / "images" / "f01_L.png")
    shutil.copy(clip / "labels" / "f01.png", clip / "labels" / "f01_L.png")
    frames = load_folder(clip)
    assert [f.name for f in frames] == ["f00", "f01", "f01_L"]


@pytest.mark.parametrize("damage, message", [
    ("both names", "a second label file of frame f01 (beside f01.png)"),
    ("a label of no frame", "f07_L.png: label file without an image"),
    ("a frame without its label", "no label file"),
])
def test_mismatched_names_are_one_line_and_exit_2(tmp_path, capsys, damage, message):
    clip = _renamed(_clip(tmp_path / "plain"), tmp_path / "clip")
    if damage == "both names":
        shutil.copy(clip / "labels" / "f01_L.png", clip / "labels" / "f01.png")
    elif damage == "a label of no frame":
        (clip / "labels" / "f02_L.png").rename(clip / "labels" / "f07_L.png")
        (clip / "images" / "f02.png").unlink()
    else:
        (clip / "labels" / "f02_L.png").unlink()
    with pytest.raises(DatasetError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_folder(clip)
    assert main(["evaluate", "stream", "--data", f"camvid:{clip}", "--methods", "unregistered",
                 "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and message in err[0]
    if damage == "a frame without its label":
        assert "f02_L.png, as CamVid names them" in err[0]


@pytest.mark.data
def test_a_shared_clip_with_camvids_own_label_names_reads_as_it_is(shared_data, tmp_path):
    src = shared_data / "camvid" / "0001TP"
    if not src.is_dir():
        pytest.skip(f"{src} is absent")
    names = sorted(p.name for p in (src / "images").iterdir())[:3]
    clip = tmp_path / "0001TP"
    for sub in ("images", "labels"):
        (clip / sub).mkdir(parents=True)
    for n in names:  # 0001TP_006690.png beside labels/0001TP_006690_L.png, as the download names them
        shutil.copy(src / "images" / n, clip / "images" / n)
        shutil.copy(src / "labels" / n, clip / "labels" / n.replace(".png", "_L.png"))
    got = load_dataset(f"camvid:{clip}")["0001TP"]
    _same(got, load_dataset(f"camvid:{src}", n_frames=3)["0001TP"])
    assert got[0].name == "0001TP_006690"
