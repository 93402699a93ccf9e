"""PyTorch3D's tests/test_points_alignment.py, its protocols run in numpy through :func:`pcreg.icp`:
``corresponding_points_alignment`` on normally distributed clouds moved by a random rotation (and scale), with a
reflection, and with 1 to 3 points; ``iterative_closest_point`` restarted from the pose after its third iteration
(test_init_transformation) and on batches of clouds of 4 to n points (test_heterogeneous_inputs). Correspondences
are pcreg's nearest neighbours, so the alignment cases start at the truth, where they are the given ones."""

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pcreg
from pcreg import ICPOptions
from pcreg import transforms as tf
from pcreg.errors import PcregError, RegistrationError


def _random_similarity(rng: np.random.Generator, d: int, scale: bool) -> np.ndarray:
    """As their generate_pcl_transformation: a random rotation, a normal translation, a scale in [0.1, 1.1)."""
    if d == 3:
        R = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    else:
        U, _, Vt = np.linalg.svd(rng.standard_normal((d, d)))
        R = U @ np.diag([1.0] * (d - 1) + [np.sign(np.linalg.det(U @ Vt))]) @ Vt
    T = np.eye(d + 1)
    T[:d, :d] = (rng.random() + 0.1 if scale else 1.0) * R
    T[:d, d] = rng.standard_normal(d)
    return T


@pytest.mark.parametrize("backend", ["reference", "open3d"])
@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("estimate_scale", [False, True])
def test_corresponding_points_alignment_recovers_a_random_motion(backend, d, estimate_scale):
    """test_corresponding_points_alignment, 100 points: the rotation, translation and scale to 1e-5 (their atol),
    ten random motions a case."""
    rng = np.random.default_rng(42)
    options = ICPOptions(backend=backend, model="similarity" if estimate_scale else "rigid", max_iteration=100)
    for _ in range(10):
        X = rng.standard_normal((100, d))
        truth = _random_similarity(rng, d, estimate_scale)
        r = pcreg.icp(X, tf.apply(truth, X), options, init=truth)
        np.testing.assert_allclose(r.matrix, truth, atol=1e-5)
        assert np.linalg.det(r.matrix[:d, :d]) > 0


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("n", [1, 2])
def test_too_few_points_for_a_3d_motion_are_refused(d, n):
    """test_corresponding_points_alignment with 1 and 2 points, where they check nothing (the motion is not
    determined): a 3-D motion, or a single point, is refused; two points fix a 2-D one and give it back."""
    rng = np.random.default_rng(n)
    X = rng.standard_normal((n, d))
    truth = _random_similarity(rng, d, False)
    if n * (d == 2) == 2:
        r = pcreg.icp(X, tf.apply(truth, X), init=truth)
        np.testing.assert_allclose(r.matrix, truth, atol=1e-9)
        return
    with pytest.raises(PcregError, match="too few"):
        pcreg.icp(X, tf.apply(truth, X), init=truth)


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_a_reflection_is_not_returned_by_the_rigid_model(backend):
    """test_corresponding_points_alignment with reflect=True and allow_reflection=False: the determinant of the
    estimated rotation is +1, and the fit of a mirrored cloud is not claimed to be exact."""
    rng = np.random.default_rng(7)
    X = rng.standard_normal((100, 3))
    r = pcreg.icp(X, X * [1.0, -1.0, 1.0], ICPOptions(backend=backend, max_iteration=100))
    assert np.linalg.det(r.matrix[:3, :3]) == pytest.approx(1.0, abs=2e-5)
    assert r.inlier_rmse > 0.05


@pytest.mark.parametrize("backend", ["reference", "open3d"])
@pytest.mark.parametrize("d", [2, 3])
def test_icp_restarted_from_its_third_pose_ends_where_it_ended(backend, d):
    """test_init_transformation: ICP between two unrelated normal clouds (30 or 100 points, 4 to n kept), then
    again from its pose after the third iteration: the same transform to 3e-5 (their atol)."""
    rng = np.random.default_rng(d)
    options = ICPOptions(backend=backend, max_iteration=100)
    for nx, ny in [(30, 30), (30, 100), (100, 30), (100, 100)]:
        X = rng.standard_normal((int(rng.integers(4, nx + 1)), d))
        Y = rng.standard_normal((int(rng.integers(4, ny + 1)), d))
        history: list[np.ndarray] = []
        r = pcreg.icp(X, Y, options, callback=lambda it: history.append(it.matrix))
        again = pcreg.icp(X, Y, options, init=history[min(3, len(history) - 1)])
        np.testing.assert_allclose(again.matrix, r.matrix, atol=3e-5)


def test_open3d_similarity_icp_whose_scale_collapses_is_refused_without_a_numpy_warning():
    """A 2-D cloud of three points and a mirrored, scaled copy (their reflect and estimate_scale cases): Open3D's
    similarity step shrinks the source onto one target point (scale 7e-33), and its next step divides by that point's
    zero spread and returns NaN. It was refused as "moved the source away", after numpy warned "invalid value
    encountered in det" on the NaN matrix; now the NaN is the refusal's reason, and nothing warns."""
    X = np.array([[1.35974754, 1.22472108], [-0.51030708, -0.29796951], [-0.52738419, 0.56972636]])
    Y = np.array([[0.43445105, -1.5659158], [0.86414089, -1.91579043], [0.86806477, -1.71641652]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(RegistrationError, match="NaN"):
            pcreg.icp(X, Y, ICPOptions(backend="open3d", model="similarity", max_iteration=100))


def test_a_collapsed_lifted_plane_is_not_called_a_mirror():
    """The 2-D projection of a 3-D result whose in-plane part is singular (a scale of 0) says so."""
    collapsed = np.diag([0.0, 0.0, 1.0, 1.0])
    with pytest.raises(RegistrationError, match="collapses"):
        tf.project_to_2d(collapsed)
