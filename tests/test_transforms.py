import numpy as np
import pytest

from pcreg import transforms as tf
from pcreg.errors import InputError, RegistrationError


def test_apply_rigid_and_projective():
    T = tf.rigid2d(90.0, 1.0, 2.0)
    np.testing.assert_allclose(tf.apply(T, np.array([[1.0, 0.0]])), [[1.0, 3.0]], atol=1e-12)
    H = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.5, 0, 1.0]])
    np.testing.assert_allclose(tf.apply(H, np.array([[2.0, 4.0]])), [[1.0, 2.0]])


def test_about_point_keeps_the_centre():
    c = tf.image_center((360, 480))
    T = tf.about_point(tf.rigid2d(33.0), c)
    np.testing.assert_allclose(tf.apply(T, np.array([c])), [c], atol=1e-9)


def test_max_corner_error_of_a_shift():
    T = tf.rigid2d(0.0, 3.0, 4.0)
    assert tf.max_corner_error(T, np.eye(3), (10, 20)) == pytest.approx(5.0)
    assert tf.max_corner_error(T, T, (10, 20)) == 0.0


def test_lift_and_project_round_trip():
    T = tf.rigid2d(12.0, 5.0, -3.0)
    np.testing.assert_allclose(tf.project_to_2d(tf.lift_to_3d(T)), T)


def test_project_refuses_a_tilted_transform():
    M = np.eye(4)
    a = np.deg2rad(5.0)
    M[1:3, 1:3] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    with pytest.raises(RegistrationError, match="leaves the image plane"):
        tf.project_to_2d(M)


def test_rotation_disagreement():
    assert tf.rotation_disagreement_deg(tf.rigid2d(10.0), tf.rigid2d(13.0)) == pytest.approx(3.0)


def test_unknown_model():
    with pytest.raises(InputError, match="unknown motion model"):
        tf.check_model("warp")
    with pytest.raises(InputError, match="2-D clouds only"):
        tf.check_model("projective", 3)
