"""An image that repeats itself under a shift (tiles, a checkerboard): a registration of it may be a period off
with nothing in its evidence to tell, so ``pcreg register`` says so; photographs do not repeat."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.registration.repetition import repeat_shift


def _tiles(period: int = 48) -> np.ndarray:
    """A floor of one (period x period) patch of a synthetic frame, 10 x 8 times."""
    patch = pcreg.synthetic("syn2a", n_frames=1)[0].image[100:100 + period, 200:200 + period]
    return np.tile(patch, (8, 10, 1))


@pytest.mark.parametrize("period", [24, 48])
def test_the_shift_of_tiles_is_one_period(period):
    dx, dy, ncc = repeat_shift(_tiles(period))
    assert abs(np.hypot(dx, dy) - period) <= 2 and min(abs(dx), abs(dy)) <= 2 and ncc > 0.9, (dx, dy, ncc)


def test_a_checkerboard_repeats_and_flat_or_random_images_do_not():
    yy, xx = np.mgrid[:360, :480]
    board = ((yy // 20 + xx // 20) % 2 * 255).astype(np.uint8)
    dx, dy, _ = repeat_shift(board)
    assert abs(abs(dx) - 20) <= 2 and abs(abs(dy) - 20) <= 2  # the diagonal neighbour of a square
    assert repeat_shift(np.full((360, 480), 128, np.uint8)) is None
    assert repeat_shift(np.random.default_rng(0).integers(0, 256, (360, 480, 3), dtype=np.uint8)) is None
    assert repeat_shift(board[:10, :10]) is None


def test_photographs_do_not_repeat(shared_data):
    paths = sorted((shared_data / "photos").glob("*.png")) + sorted((shared_data / "camvid").glob("*/images/*0.png"))
    assert len(paths) > 20
    found = {p.name: repeat_shift(cv2.imread(str(p))) for p in paths}
    assert not {name: shift for name, shift in found.items() if shift is not None}


def test_pcreg_register_says_when_the_images_repeat(tmp_path, capsys):
    tiles = _tiles()
    ref, mov = tmp_path / "tiles.png", tmp_path / "moved.png"
    cv2.imwrite(str(ref), tiles)
    cv2.imwrite(str(mov), np.roll(tiles, (30, 29), axis=(0, 1)))  # registered a period off: (19, 18), not (-29, -30)
    assert main(["register", str(ref), str(mov)]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "repeats itself" in line]
    assert len(notes) == 1 and notes[0].startswith(f"pcreg: note: {ref} repeats itself: shifted by about ("), notes
    assert notes[0].endswith("the result may be a period off")
    assert main(["register", str(ref), str(mov), "--json"]) == 0  # a script reading --json sees the same note
    out = capsys.readouterr()
    assert json.loads(out.out)["notes"] == [n.removeprefix("pcreg: note: ") for n in out.err.splitlines()] != []
    main(["crosscheck", str(ref), str(mov)])  # the backends cross-checked on the same images: the same note
    assert [line for line in capsys.readouterr().err.splitlines() if "repeats itself" in line] == notes
    frame = pcreg.synthetic("syn2a", n_frames=1)[0].image
    cv2.imwrite(str(ref), frame)
    cv2.imwrite(str(mov), np.roll(frame, (3, 5), axis=(0, 1)))
    assert main(["register", str(ref), str(mov), "--json"]) == 0
    out = capsys.readouterr()
    assert "repeats itself" not in out.err and json.loads(out.out)["notes"] == []


def test_the_python_api_marks_a_result_on_images_that_repeat():
    """``pcreg.register`` keeps what ``pcreg register`` notes: ``evidence.repeats``, and ``trusted`` False, since a
    result a period off lines up as many edges; with the checks off nothing is said (the streams)."""
    tiles = _tiles()
    result = pcreg.register(tiles, np.roll(tiles, (30, 29), axis=(0, 1)))
    found = result.evidence.repeats
    assert found is not None and found.image == "reference" and found.correlation >= 0.9, found
    assert abs(np.hypot(*found.shift_px) - 48) <= 2 and not result.trusted
    assert result.to_dict()["repeats"] == {"image": "reference", "shift_px": list(found.shift_px),
                                           "correlation": found.correlation}
    assert result.model_fits is not False  # the model check alone passes it: nothing else marked it
    untested = pcreg.register(tiles, np.roll(tiles, (30, 29), axis=(0, 1)), config=pcreg.RegisterConfig.of(min_inlier_ratio=None))
    assert untested.evidence.repeats == found and not untested.trusted  # no plausibility test tells a period either
    frame = pcreg.synthetic("syn2a", n_frames=1)[0].image
    plain = pcreg.register(frame, np.roll(frame, (3, 5), axis=(0, 1)))
    assert plain.evidence.repeats is None and plain.trusted and "repeats" not in plain.to_dict()
    unchecked = pcreg.register(tiles, np.roll(tiles, (30, 29), axis=(0, 1)), config=pcreg.RegisterConfig.of(model_check=False))
    assert unchecked.evidence.repeats is None


def test_a_refusal_of_images_that_repeat_says_so_first(tmp_path, capsys):
    """A pair of tiles turned a quarter was refused as a mirror image, or as not pinning the motion down, without a
    word of the pattern; the refusal now names the image that repeats first (the command by its file), and a
    refusal of images that do not repeat is as it was."""
    tiles = np.tile(pcreg.synthetic("syn2a", n_frames=1)[0].image[100:124, 200:224], (16, 20, 1))
    turn = cv2.getRotationMatrix2D((239.5, 191.5), 90, 1.0) + [[0, 0, 20], [0, 0, -13]]
    moved = cv2.warpAffine(tiles, turn, (480, 384))
    with pytest.raises(pcreg.errors.RegistrationError) as refused:
        pcreg.register(tiles, moved)
    said = str(refused.value)
    assert said.startswith("registration refused: the reference image repeats itself (shifted by about ("), said
    assert said.count("registration refused") == 1 and len(said) < 1000  # the command's line keeps it whole
    ref, mov = tmp_path / "tiles.png", tmp_path / "turned.png"
    cv2.imwrite(str(ref), tiles[:, :, ::-1])  # the same pixels as the arrays (OpenCV writes BGR)
    cv2.imwrite(str(mov), moved[:, :, ::-1])
    assert main(["register", str(ref), str(mov)]) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"pcreg: registration refused: {ref} repeats itself (shifted by about ("), err
    frame = pcreg.synthetic("syn2a", n_frames=1)[0].image
    with pytest.raises(pcreg.errors.RegistrationError) as plain:
        pcreg.register(frame, np.random.default_rng(2).integers(0, 256, frame.shape, dtype=np.uint8))
    assert "repeats itself" not in str(plain.value)
