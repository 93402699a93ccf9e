import numpy as np
import pytest

from pcreg import transforms as tf
from pcreg import warp
from pcreg.errors import InputError

from _images import moved, rigid_about_centre, shapes_image


def test_warp_inverts_a_known_motion():
    ref = shapes_image()
    T = rigid_about_centre(ref.shape, 20.0, 8.0, -5.0)
    warped, valid = warp(moved(ref, T), T, shape=ref.shape)
    assert warped.shape == ref.shape and valid.dtype == bool
    inner = valid.copy()
    inner[:, :] &= np.pad(np.ones((ref.shape[0] - 8, ref.shape[1] - 8), bool), 4)
    import cv2

    inner = cv2.erode(inner.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    diff = np.abs(warped.astype(int) - ref.astype(int))[inner]
    assert np.median(diff) <= 2
    # pixels that came from outside the moving image are invalid and black
    assert not valid.all()
    black = np.all(warped == 0, axis=2)
    assert black.any() and not (black & valid).any()


def test_identity_is_lossless_and_valid_everywhere():
    img = shapes_image()
    warped, valid = warp(img, np.eye(3))
    np.testing.assert_array_equal(warped, img)
    assert valid.all()


def test_labels_with_nearest_and_fill():
    labels = np.zeros((40, 60), np.uint8)
    labels[:, 30:] = 1
    warped, valid = warp(labels, tf.rigid2d(0, 10, 0), interpolation="nearest", fill=2)
    assert set(np.unique(warped)) <= {0, 1, 2}
    assert np.all(warped[:, :10] == 2) and not valid[:, :10].any()
    assert np.all(warped[:, 41:] == 1)


def test_multichannel_float_posteriors():
    post = np.random.default_rng(0).random((30, 40, 6)).astype(np.float32)
    warped, _ = warp(post, tf.rigid2d(0, 1, 0))
    assert warped.shape == (30, 40, 6) and warped.dtype == np.float32
    np.testing.assert_allclose(warped[:, 1:], post[:, :-1], atol=1e-6)


def test_projective_and_other_sizes():
    img = shapes_image()
    H = np.array([[1.0, 0.0, 2.0], [0.0, 1.0, 1.0], [1e-4, 0.0, 1.0]])
    warped, valid = warp(img, H, shape=(100, 120))
    assert warped.shape == (100, 120, 3) and valid.shape == (100, 120)


@pytest.mark.parametrize("image, T, message", [
    (np.zeros((0, 4)), np.eye(3), "expected an"),
    (np.zeros((4, 4)), np.eye(2), "3x3"),
    (np.zeros((4, 4)), np.zeros((3, 3)), "singular"),
    (np.zeros((4, 4)), np.full((3, 3), np.nan), "finite"),
])
def test_warp_bad_input(image, T, message):
    with pytest.raises(InputError, match=message):
        warp(image, T)
