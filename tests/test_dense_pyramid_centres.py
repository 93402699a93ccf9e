"""The dense registration's global transform on each pyramid level: cv2.pyrDown keeps the even pixels, so a
level's pixel j lies on full-resolution pixel 2^level j, and the global transform must be expressed there. A
rotation about the image's centre then starts every level where the content is, and an exact one is kept."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pcreg import register_dense
from pcreg.registration.dense.levels import _level_matrix
from pcreg.registration.motion import field_from_matrix

from _images import shapes_image


def _textured(h=192, w=256, seed=3):
    img = shapes_image(h, w, seed).astype(np.float32)
    noise = cv2.GaussianBlur(np.random.default_rng(seed).normal(0, 30, (h, w, 3)).astype(np.float32), (0, 0), 1.5)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def test_a_levels_transform_maps_the_pyramids_own_pixels():
    """A point ``p`` of level 2 lies at ``4 p`` at full size (cv2.pyrDown's even pixels, twice)."""
    ramp = np.tile(np.arange(64, dtype=np.float32), (64, 1))
    assert cv2.pyrDown(cv2.pyrDown(ramp))[8, 5] == pytest.approx(20.0)  # pixel 5 of level 2: full-size x = 20
    T = np.array([[0.0, -1.0, 100.0], [1.0, 0.0, 7.0], [0.0, 0.0, 1.0]])  # a quarter turn and a shift
    full = T @ np.array([20.0, 12.0, 1.0])  # level 2's pixel (5, 3) at full size, moved
    np.testing.assert_allclose(_level_matrix(T, 2) @ np.array([5.0, 3.0, 1.0]), full / np.array([4.0, 4.0, 1.0]))


@pytest.mark.parametrize("turn", [1, 2])  # 90 and 180 degrees: exact pixel permutations, no interpolation
def test_an_exact_quarter_or_half_turn_given_as_the_global_step_is_kept_to_a_fraction_of_a_pixel(turn):
    ref = _textured(192, 192) if turn == 1 else _textured()
    mov = np.ascontiguousarray(np.rot90(ref, turn))
    h, w = mov.shape[:2]
    # mov[y, x] = ref at (x, y) turned back: T_ref_mov of np.rot90 (counter-clockwise) by ``turn`` quarters
    T = {1: np.array([[0.0, -1.0, w - 1.0], [1.0, 0.0, 0.0], [0, 0, 1]]),
         2: np.array([[-1.0, 0.0, w - 1.0], [0.0, -1.0, h - 1.0], [0, 0, 1]])}[turn]
    truth = field_from_matrix(T, (h, w))
    np.testing.assert_array_equal(ref[truth[..., 1].astype(int), truth[..., 0].astype(int)], mov)
    res = register_dense(ref, mov, global_result=T)
    err = np.linalg.norm(res.field - truth, axis=2)[8:-8, 8:-8]
    # the levels' pixels of a half turn fall between the reference's (pyrDown keeps the even ones): sub-pixel
    # matches, not the 1.1 (quarter turn) and 1.6 px (half turn) the other centres left
    assert np.median(err) < 0.4, np.median(err)
    assert np.percentile(err, 95) < 1.0, np.percentile(err, 95)


def test_a_dense_result_says_no_check_judged_it_where_a_global_one_says_whether_one_marked_it():
    """``result.trusted`` raised AttributeError on a dense result, which a program branching on it met first
    (``pcreg register --json`` said null); it is None, and its global step's checks are ``global_result.trusted``."""
    ref = _textured()
    res = register_dense(ref, ref.copy())
    assert res.trusted is None and isinstance(res.global_result.trusted, bool)
