"""Key labels in CamVid's own 32 classes' colours (its download's ``NAME_L.png``): ``pcreg run --labels
--classes camvid11`` reads them as ``camvid11``'s eleven classes, by the grouping ``--data camvid:ROOT`` reads
the download with; a colour of neither is refused naming the file, the colour and a pixel."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.classes import CAMVID11, LAGR, read_label_png
from pcreg.classes.keys import read_key_labels
from pcreg.cli import main
from pcreg.errors import InputError
from _runs import one_line_errors

#: A colour of CamVid's 32 classes for each camvid11 id: most of them colours camvid11's table does not have
#: (a wall for building, a traffic cone for pole, a sidewalk for pavement, a bus for car, ...).
REPRESENTATIVE = {0: (128, 128, 128), 1: (64, 192, 0), 2: (0, 0, 64), 3: (128, 64, 128), 4: (0, 0, 192),
                  5: (192, 192, 0), 6: (0, 64, 64), 7: (64, 64, 128), 8: (192, 128, 192), 9: (64, 64, 0),
                  10: (192, 0, 192), 11: (0, 0, 0)}
LANE = (128, 0, 192)  # CamVid's driving lane marking: road


def camvid32(ids: np.ndarray) -> np.ndarray:
    """(H, W, 3) RGB: camvid11 ``ids`` in CamVid's 32 classes' colours, with a lane marking inside the road."""
    rgb = np.zeros(ids.shape + (3,), np.uint8)
    for i, colour in REPRESENTATIVE.items():
        rgb[ids == i] = colour
    ys, xs = np.nonzero(ids == 3)
    rgb[ys[:: 7], xs[:: 7]] = LANE
    return rgb


def _clip(shared_data: Path, tmp_path: Path, n: int = 3) -> tuple[Path, Path, np.ndarray]:
    """``frames/`` (the first ``n`` frames of a shared clip) and ``keys/NAME_L.png`` (its first frame's labels
    in the 32 classes' colours); and those labels' camvid11 ids."""
    clip = shared_data / "camvid" / "0001TP"
    if not clip.is_dir():
        pytest.skip(f"{clip} is absent")
    names = sorted(p.stem for p in (clip / "images").iterdir())[:n]
    frames, keys = tmp_path / "frames", tmp_path / "keys"
    frames.mkdir()
    keys.mkdir()
    for name in names:
        shutil.copy(clip / "images" / f"{name}.png", frames)
    ids = cv2.imread(str(clip / "labels" / f"{names[0]}.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(keys / f"{names[0]}_L.png"), camvid32(ids)[:, :, ::-1])
    return frames, keys, ids


@pytest.mark.data
def test_run_reads_camvids_own_colours_as_camvid11(shared_data, tmp_path, capsys):
    frames, keys, ids = _clip(shared_data, tmp_path)
    key = next(keys.iterdir())
    assert len(np.unique(camvid32(ids).reshape(-1, 3), axis=0)) > 8  # colours camvid11 lacks among them
    np.testing.assert_array_equal(read_key_labels(key, CAMVID11), ids)
    assert main(["run", str(frames), "--labels", str(keys), "--classes", "camvid11", "--out", str(tmp_path / "out"),
                 "--model", "flow", "--preset", "ultrafast"]) == 0, one_line_errors(capsys)
    out = read_label_png(tmp_path / "out" / f"{key.stem[:-2]}.png", CAMVID11)
    np.testing.assert_array_equal(out, ids)
    assert main(["run", str(frames), "--labels", str(key), "--classes", "camvid11", "--out", str(tmp_path / "one"),
                 "--model", "flow", "--preset", "ultrafast"]) == 0, one_line_errors(capsys)
    np.testing.assert_array_equal(read_label_png(tmp_path / "one" / f"{key.stem[:-2]}.png", CAMVID11), ids)


@pytest.mark.data
def test_a_colour_of_neither_is_refused_naming_the_file_the_colour_and_the_pixel(shared_data, tmp_path, capsys):
    frames, keys, ids = _clip(shared_data, tmp_path)
    key = next(keys.iterdir())
    rgb = camvid32(ids)
    rgb[5, 7] = (1, 2, 3)
    cv2.imwrite(str(key), rgb[:, :, ::-1])
    assert main(["run", str(frames), "--labels", str(keys), "--classes", "camvid11", "--out", str(tmp_path / "out"),
                 "--model", "flow"]) == 2
    (line,) = one_line_errors(capsys)
    assert line.startswith(f"pcreg: error: {key}: colour (1, 2, 3) (at x=7, y=5)"), line
    assert not (tmp_path / "out").exists()


def test_only_camvid11_reads_them_and_its_own_colours_read_as_before(tmp_path):
    ids = np.arange(12, dtype=np.uint8).repeat(2).reshape(4, 6)
    path = tmp_path / "f_L.png"
    cv2.imwrite(str(path), camvid32(ids)[:, :, ::-1])
    np.testing.assert_array_equal(read_key_labels(path, CAMVID11), ids)
    np.testing.assert_array_equal(read_key_labels(path, LAGR, "camvid"), read_key_labels(path, CAMVID11, "camvid"))
    with pytest.raises(InputError, match=r"colour \(128, 128, 128\) \(at x=0, y=0\) is no class.s colour"):
        read_key_labels(path, LAGR)
    own = tmp_path / "own.png"  # camvid11's colours, its pavement SegNet's (60, 40, 222): as they always read
    cv2.imwrite(str(own), CAMVID11.palette()[ids][:, :, ::-1])
    np.testing.assert_array_equal(read_key_labels(own, CAMVID11), ids)
    mixed = CAMVID11.palette()[ids]
    mixed[0, 0] = LANE
    cv2.imwrite(str(own), mixed[:, :, ::-1])
    expected = ids.copy()
    expected[0, 0] = 3
    np.testing.assert_array_equal(read_key_labels(own, CAMVID11), expected)
