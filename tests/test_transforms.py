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


@pytest.mark.parametrize("angle", [1e-9, 1e-7, 1e-4, 0.5, 2.0, np.pi - 1e-6])
def test_rotation_angle_of_a_3d_rotation_keeps_full_precision_at_every_angle(angle):
    """Known-answer ICP tests measure the angle of R_estimate^T R_truth, which is tiny: the arccos of the trace
    returned 0 for 1e-9 rad and 9.9e-8 for 1e-7 rad."""
    from scipy.spatial.transform import Rotation

    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = Rotation.from_rotvec(angle * axis).as_matrix()
    assert tf.rotation_angle_deg(R) == pytest.approx(np.degrees(angle), rel=1e-6)
    T = np.eye(4)
    T[:3, :3] = R
    assert tf.rotation_disagreement_deg(np.eye(4), T) == pytest.approx(np.degrees(angle), rel=1e-6)


def test_rotation_angle_of_a_2d_homogeneous_transform_is_its_rotations():
    assert tf.rotation_angle_deg(tf.rigid2d(75.0, 30.0, -12.0)) == pytest.approx(75.0)
    assert tf.rotation_angle_deg(tf.rigid2d(-170.0)[:2, :2]) == pytest.approx(170.0)


def test_rotation_angle_of_a_3d_homogeneous_transform_is_its_rotations():
    """pcreg.icp's 3-D result is 4x4: its angle was read from the trace of the whole matrix, the 1 of its last row
    counted in (38.97 degrees for a turn of 57.3), and a similarity's scale was read as part of the turn."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.6, 0.8]).as_matrix()
    T[:3, 3] = [1.0, 2.0, 3.0]
    assert tf.rotation_angle_deg(T) == pytest.approx(np.degrees(1.0), rel=1e-12)
    T[:3, :3] *= 2.5  # a 3-D similarity: the angle of its rotation, as a 2-D similarity's
    assert tf.rotation_angle_deg(T) == pytest.approx(np.degrees(1.0), rel=1e-12)
    assert tf.rotation_angle_deg(tf.rigid2d(30.0, scale=2.0)) == pytest.approx(30.0)
    projective = np.eye(4)
    projective[3, 0] = 0.1
    for bad in (np.eye(5), np.ones((3, 4)), projective):
        with pytest.raises(InputError, match="rotation"):
            tf.rotation_angle_deg(bad)


def test_unknown_model():
    with pytest.raises(InputError, match="unknown motion model"):
        tf.check_model("warp")
    with pytest.raises(InputError, match="2-D clouds only"):
        tf.check_model("projective", 3)


def test_degeneracy_names_what_cannot_be_a_view():
    from pcreg.registration.transforms import degeneracy, rigid2d

    shape = (240, 320)
    assert degeneracy(np.eye(3), shape) is None
    assert degeneracy(rigid2d(170.0, 5.0, -8.0, scale=3.0), shape) is None
    H = np.eye(3)
    H[2, 0] = 1e-3  # a mild perspective, its horizon far outside the image
    assert degeneracy(H, shape) is None
    assert "finite" in degeneracy(np.full((3, 3), np.nan), shape)
    assert "infinity" in degeneracy(np.zeros((3, 3)), shape)
    far = np.eye(3)
    far[0, 2] = 1e12  # a translation however far is no horizon: registration says it overlaps nothing
    assert degeneracy(far, shape) is None and degeneracy(-far, shape) is None
    far[0, 2] = 1e300  # its corners' differences round away there: still a view, not a fold
    assert degeneracy(far, shape) is None
    assert "area" in degeneracy(np.diag([1.0, 1.0, 1e-300]), shape)  # a zoom by 1e300, not a fold
    H[2, 0] = -0.01  # the horizon line x = 100 crosses the image
    assert "infinity" in degeneracy(H, shape)
    assert "mirrors" in degeneracy(np.diag([1.0, -1.0, 1.0]), shape)
    assert "area" in degeneracy(np.diag([0.05, 0.05, 1.0]), shape)


def test_register_never_returns_a_degenerate_homography_with_the_test_off():
    """Projective registrations from small reference regions: each is refused or a proper view."""
    import pcreg
    from pcreg.errors import RegistrationError
    from pcreg.registration.transforms import degeneracy

    frames = pcreg.synthetic("syn2a", 3, 0, width=160, height=120)
    returned = refused = 0
    for y0, x0 in ((0, 0), (40, 60), (80, 110), (10, 100)):
        mask = np.zeros(frames[0].labels.shape, bool)
        mask[y0:y0 + 30, x0:x0 + 40] = True
        try:
            res = pcreg.register(frames[0].image, frames[2].image, model="projective", reference_mask=mask,
                                 config=pcreg.RegisterConfig.of(min_inlier_ratio=None), init="identity")
        except RegistrationError as exc:
            refused += 1
            assert str(exc).startswith(("registration", "the reference image")), exc
            continue
        returned += 1
        assert degeneracy(res.matrix, frames[2].shape) is None
    assert returned + refused == 4
