"""Cases other ICP projects test their own ICP with, run through pcreg's ICP (:func:`pcreg.icp`, the reference
closed forms). Each test names the project and file whose case it mirrors; the numbers are theirs where they
publish expected values, and Open3D's own answer on the same input where they compare against it."""

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

import pcreg
from pcreg import ICPOptions
from pcreg import transforms as tf
from pcreg.errors import InputError, RegistrationError
from pcreg.registration.closed_forms import estimate_umeyama
from pcreg.registration.normal_steps import estimate_point_to_plane

from _open3d_cases import (EST_CORRESPONDENCES, EST_SOURCE, EST_TARGET, EST_TARGET_NORMALS, GRID_INIT,
                           GRID_SOURCE, GRID_TARGET, GRID_TARGET_NORMALS)
from _open3d_cases import open3d_cloud as _cloud

reg = o3d.pipelines.registration


def test_open3d_point_to_point_step_and_rmse_on_given_correspondences():
    """Open3D test_transformation_estimation.py: the RMSE of the given pairs, 0.706437, and after one
    point-to-point step, 0.578255 (Umeyama's closed form here; Open3D's legacy estimation gives the same
    matrix)."""
    q = EST_TARGET[EST_CORRESPONDENCES]
    rmse = lambda p: float(np.sqrt(np.mean(np.sum((p - q) ** 2, axis=1))))  # noqa: E731
    assert rmse(EST_SOURCE) == pytest.approx(0.706437, rel=1e-4)
    T = estimate_umeyama(EST_SOURCE, q, np.ones(len(q)), with_scale=False)
    assert rmse(tf.apply(T, EST_SOURCE)) == pytest.approx(0.578255, rel=1e-4)
    pairs = o3d.utility.Vector2iVector(np.column_stack([np.arange(len(q)), EST_CORRESPONDENCES]))
    theirs = reg.TransformationEstimationPointToPoint().compute_transformation(
        _cloud(EST_SOURCE), _cloud(EST_TARGET), pairs)
    np.testing.assert_allclose(T, theirs, atol=1e-12)


def test_open3d_point_to_plane_step_with_normals_that_are_not_unit():
    """Open3D test_transformation_estimation.py, point-to-plane: its normals are not of unit length, and
    Open3D takes them as given; pcreg's step takes them as given too, and gives Open3D's matrix."""
    q = EST_TARGET[EST_CORRESPONDENCES]
    n = EST_TARGET_NORMALS[EST_CORRESPONDENCES]
    T = estimate_point_to_plane(EST_SOURCE, q, n, np.ones(len(q)))
    pairs = o3d.utility.Vector2iVector(np.column_stack([np.arange(len(q)), EST_CORRESPONDENCES]))
    theirs = reg.TransformationEstimationPointToPlane().compute_transformation(
        _cloud(EST_SOURCE), _cloud(EST_TARGET, EST_TARGET_NORMALS), pairs)
    np.testing.assert_allclose(T, theirs, atol=1e-11)
    assert abs(np.linalg.det(T[:3, :3]) - 1) < 1e-12


def test_open3d_evaluate_registration_fitness_and_inlier_rmse():
    """Open3D test_registration.py test_evaluate_registration: at distance 3.0 and the identity, pcreg's
    fitness (pairs / source points) and inlier RMSE are Open3D's legacy evaluate_registration's."""
    theirs = reg.evaluate_registration(_cloud(GRID_SOURCE), _cloud(GRID_TARGET), 3.0, np.eye(4))
    ours = pcreg.icp(GRID_SOURCE, GRID_TARGET, ICPOptions(max_correspondence_distance=3.0, max_iteration=0))
    assert ours.fitness == pytest.approx(theirs.fitness, abs=1e-15)
    assert ours.inlier_rmse == pytest.approx(theirs.inlier_rmse, rel=1e-12)
    np.testing.assert_array_equal(ours.matrix, np.eye(4))


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_open3d_icp_point_to_point_two_iterations_from_their_init(backend):
    """Open3D test_registration.py test_icp_point_to_point: two iterations from their init (rounded to three
    decimals, so not quite a rotation: det 1.00013, which pcreg takes as Open3D does): Open3D's matrix,
    fitness and inlier RMSE."""
    criteria = reg.ICPConvergenceCriteria(max_iteration=2)
    theirs = reg.registration_icp(_cloud(GRID_SOURCE), _cloud(GRID_TARGET), 3.0, GRID_INIT,
                                  reg.TransformationEstimationPointToPoint(), criteria)
    ours = pcreg.icp(GRID_SOURCE, GRID_TARGET,
                     ICPOptions(backend=backend, max_correspondence_distance=3.0, max_iteration=2), init=GRID_INIT)
    np.testing.assert_allclose(ours.matrix, theirs.transformation, atol=1e-10)
    assert ours.fitness == pytest.approx(theirs.fitness) and ours.inlier_rmse == pytest.approx(theirs.inlier_rmse)
    assert ours.iterations == 2 and not ours.converged


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_open3d_icp_point_to_plane_two_iterations_from_their_init(backend):
    """Open3D test_registration.py test_icp_point_to_plane: the same clouds with the target's normals,
    point-to-plane, two iterations: Open3D's matrix, fitness and inlier RMSE (a point distance, as Open3D's)."""
    criteria = reg.ICPConvergenceCriteria(max_iteration=2)
    theirs = reg.registration_icp(_cloud(GRID_SOURCE), _cloud(GRID_TARGET, GRID_TARGET_NORMALS), 3.0, GRID_INIT,
                                  reg.TransformationEstimationPointToPlane(), criteria)
    ours = pcreg.icp(GRID_SOURCE, GRID_TARGET, ICPOptions(backend=backend, metric="point_to_plane",
                                                                max_correspondence_distance=3.0, max_iteration=2),
                     init=GRID_INIT, target_normals=GRID_TARGET_NORMALS)
    np.testing.assert_allclose(ours.matrix, theirs.transformation, atol=1e-10)
    assert ours.fitness == pytest.approx(theirs.fitness) and ours.inlier_rmse == pytest.approx(theirs.inlier_rmse)


@pytest.mark.parametrize("d", [2, 3])
def test_the_correspondence_distance_is_a_strict_bound_as_open3d_s(d):
    """Open3D's ICP pairs a point with a target strictly closer than max_correspondence_distance: a source
    point exactly at the distance has no pair (evaluate_registration: fitness 0), a hair beyond it has."""
    target = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 4.0]])[:, :d]
    source = target + np.eye(d)[0] * 0.5
    lifted = lambda p: np.column_stack([p, np.zeros(len(p))]) if d == 2 else p  # noqa: E731
    for distance, pairs in ((0.5, 0), (np.nextafter(0.5, 1.0), len(source))):
        theirs = reg.evaluate_registration(_cloud(lifted(source)), _cloud(lifted(target)), distance, np.eye(4))
        assert len(theirs.correspondence_set) == pairs
        for backend in ("reference", "open3d"):
            options = ICPOptions(backend=backend, max_correspondence_distance=distance, max_iteration=0)
            if pairs == 0:
                with pytest.raises(RegistrationError, match="no source point lies within"):
                    pcreg.icp(source, target, options)
            else:
                r = pcreg.icp(source, target, options)
                assert r.fitness == theirs.fitness == 1.0 and r.inlier_rmse == pytest.approx(0.5)


def test_umeyama_1991_worked_example_similarity_and_no_reflection():
    """Umeyama (1991), section IV's example (also imagingbook's ProcrustesExample "Umeyama-Test"):
    (0,0), (1,0), (0,2) onto (0,0), (-1,0), (0,2), a mirror image. The similarity is c = 0.721,
    R = [[0.832, 0.555], [-0.555, 0.832]], t = (-0.8, 0.4); the rigid fit is a rotation (det +1), never the
    reflection that maps the points exactly."""
    p = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    q = np.array([[0.0, 0.0], [-1.0, 0.0], [0.0, 2.0]])
    T = estimate_umeyama(p, q, np.ones(3), with_scale=True)
    c = np.sqrt(np.linalg.det(T[:2, :2]))
    assert c == pytest.approx(0.721, abs=5e-4)
    np.testing.assert_allclose(T[:2, :2] / c, [[0.832, 0.555], [-0.555, 0.832]], atol=5e-4)
    np.testing.assert_allclose(T[:2, 2], [-0.8, 0.4], atol=1e-12)
    rigid = estimate_umeyama(p, q, np.ones(3), with_scale=False)
    assert np.linalg.det(rigid[:2, :2]) == pytest.approx(1.0)
    for model in ("rigid", "similarity"):
        assert np.linalg.det(pcreg.icp(p, q, ICPOptions(model=model)).matrix[:2, :2]) > 0


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_a_mirrored_3d_cloud_gives_a_rotation_not_a_reflection(backend):
    rng = np.random.default_rng(0)
    source = rng.normal(size=(50, 3)) * [3.0, 2.0, 1.0]
    r = pcreg.icp(source, source * [1.0, 1.0, -1.0], ICPOptions(backend=backend))
    assert np.linalg.det(r.matrix[:3, :3]) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("d, backend", [(2, "reference"), (3, "reference"), (3, "open3d")])
def test_pycpd_rigid_case_with_a_known_scale(d, backend):
    """pycpd testing/rigid_test.py (test_2D, test_3D: a rotation about z and a shift, s, R and t recovered),
    here with a scale of 1.2, a 10-degree turn and a small shift, within ICP's basin from the identity (for
    some other random 2-D clouds it is not: ICP stops in a local minimum there, as it does)."""
    source = np.random.default_rng(1).normal(size=(100, d))
    R = Rotation.from_euler("z", 10, degrees=True).as_matrix()[:d, :d]
    T = np.eye(d + 1)
    T[:d, :d] = 1.2 * R
    T[:d, d] = [0.05, 0.1, -0.02][:d]
    r = pcreg.icp(source, tf.apply(T, source), ICPOptions(backend=backend, model="similarity", max_iteration=100))
    np.testing.assert_allclose(r.matrix, T, atol=1e-9)
    assert r.converged and r.fitness == 1.0


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_a_similarity_icp_that_shrinks_the_source_to_a_point_is_refused(backend):
    """pycpd's 3-D rigid case taken further (scale 2.5, 30 degrees, shift (0.5, 1, -2)), where CPD recovers
    the motion: a similarity ICP from the identity shrank the source onto one target point, and both backends'
    steps returned that (determinant 1e-102) as converged with a fitness of 1 and an inlier RMSE of 0."""
    source = np.random.default_rng(0).normal(size=(100, 3))
    T = np.eye(4)
    T[:3, :3] = 2.5 * Rotation.from_euler("z", 30, degrees=True).as_matrix()
    T[:3, 3] = [0.5, 1.0, -2.0]
    with pytest.raises(RegistrationError, match=r"reach 1 target point.*shrank the source onto them"):
        pcreg.icp(source, tf.apply(T, source), ICPOptions(backend=backend, model="similarity", max_iteration=200))


def test_a_2d_similarity_collapse_is_refused_and_a_near_one_is_not():
    source = np.random.default_rng(5).normal(size=(100, 2))
    with pytest.raises(RegistrationError, match="shrank the source"):
        pcreg.icp(source, 0.3 * source + 3.0, ICPOptions(model="similarity", max_iteration=200))
    with pytest.raises(RegistrationError, match="shrank the source"):  # stopped by max_iteration, not converged
        pcreg.icp(source, 0.3 * source + 3.0, ICPOptions(model="similarity", max_iteration=12))
    r = pcreg.icp(source, 0.3 * source + 0.05, ICPOptions(model="similarity", max_iteration=200))
    assert np.sqrt(np.linalg.det(r.matrix[:2, :2])) == pytest.approx(0.3)
    # one pair from the start: the run stops where it is, not converged, and is returned as such (as for rigid)
    grid = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), axis=-1).reshape(-1, 2)
    far = np.vstack([grid[:1] + 0.01, grid[1:] + 100.0])
    r = pcreg.icp(grid, far, ICPOptions(model="similarity", max_correspondence_distance=0.5))
    assert not r.converged and r.iterations == 0 and r.fitness == pytest.approx(0.01)


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_a_million_units_from_the_origin_keeps_float64_precision(d, backend):
    """Georeferenced clouds (KISS-ICP's and small_gicp's scans sit far from their origin): a small rigid
    motion of a 20-unit cloud moved 1e6 from the origin is recovered to 1e-8."""
    rng = np.random.default_rng(d)
    source = rng.uniform(-10, 10, (200, d))
    T = np.eye(d + 1)
    T[:d, :d] = Rotation.from_euler("xyz", [2, -1, 3], degrees=True).as_matrix()[:d, :d] if d == 3 else tf.rigid2d(3)[:2, :2]
    T[:d, d] = [0.2, -0.1, 0.05][:d]
    target = tf.apply(T, source)
    r = pcreg.icp(source + 1e6, target + 1e6, ICPOptions(backend=backend, max_correspondence_distance=2.0,
                                                          max_iteration=100))
    assert np.abs(tf.apply(r.matrix, source + 1e6) - (target + 1e6)).max() < 1e-8
    assert r.converged


def test_tiny_clouds_stop_on_open3d_s_absolute_thresholds_unless_scaled():
    """A cloud 1e-6 across: Open3D's stopping rule compares absolute changes (1e-6 its default), which any step
    on such a cloud meets, so both backends given it stop after the same first step, short of the motion;
    thresholds in the clouds' units recover it (pcreg's default scales with clouds under a unit across)."""
    rng = np.random.default_rng(1)
    source = rng.uniform(-1, 1, (200, 2)) * 1e-6
    T = tf.rigid2d(5.0, 0.05e-6, 0.02e-6)
    target = tf.apply(T, source)
    first = [pcreg.icp(source, target, ICPOptions(backend=b, relative_rmse=1e-6)) for b in ("reference", "open3d")]
    assert all(r.iterations == 1 for r in first)
    np.testing.assert_allclose(first[0].matrix, first[1].matrix, atol=1e-12)
    scaled = pcreg.icp(source, target, ICPOptions(relative_fitness=0.0, relative_rmse=1e-18, max_iteration=100))
    assert np.abs(tf.apply(scaled.matrix, source) - target).max() < 1e-18


def test_duplicated_points_change_nothing():
    rng = np.random.default_rng(2)
    source = rng.uniform(-5, 5, (60, 2))
    target = tf.apply(tf.rigid2d(3, 0.1, 0), source)
    once = pcreg.icp(source, target, ICPOptions())
    for s, t in ((np.vstack([source, source]), target), (source, np.repeat(target, 3, axis=0))):
        r = pcreg.icp(s, t, ICPOptions())
        np.testing.assert_allclose(r.matrix, once.matrix, atol=1e-12)
        assert r.fitness == 1.0


def test_one_point():
    one, there = np.array([[1.0, 2.0]]), np.array([[1.5, 2.5]])
    r = pcreg.icp(one, there, ICPOptions(model="translation"))
    np.testing.assert_allclose(r.matrix[:2, 2], [0.5, 0.5])
    with pytest.raises(RegistrationError, match="too few"):
        pcreg.icp(one, there, ICPOptions(model="rigid"))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf_are_bad_input(bad):
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    broken = points.copy()
    broken[1, 1] = bad
    for s, t in ((broken, points), (points, broken)):
        with pytest.raises(InputError, match="NaN or inf"):
            pcreg.icp(s, t)


def test_pairs_of_zero_weight_count_for_nothing():
    """Weighted closed form: pairs of weight 0 change nothing (the same step as without them)."""
    rng = np.random.default_rng(4)
    p = rng.normal(size=(30, 3))
    q = tf.apply(np.array([[0.0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]), p)
    wild = np.vstack([q[:20], rng.normal(size=(10, 3)) * 50])
    w = np.r_[np.ones(20), np.zeros(10)]
    for scale in (False, True):
        np.testing.assert_allclose(estimate_umeyama(p, wild, w, with_scale=scale),
                                   estimate_umeyama(p[:20], q[:20], np.ones(20), with_scale=scale), atol=1e-12)


@pytest.mark.parametrize("d", [2, 3])
def test_a_rigid_result_held_by_too_few_pairs_to_fix_its_rotation_is_not_returned_as_converged(d):
    """Two source points of 52 within the gate in 3-D (one in 2-D) fix no rotation about them: Open3D's step took
    one anyway (a half turn about a skew axis, inlier RMSE 1.7e-15) and pcreg.icp returned it as converged; it is
    refused now, and so is its turn when the iterations stopped the run (a half turn at one iteration, returned as
    not converged). The reference's step needs the pairs a rotation takes: it stops where it started, not
    converged, and that is returned as before."""
    rng = np.random.default_rng(0)
    target = rng.uniform(0, 10, (200, d))
    source = np.r_[target[:d - 1] + np.eye(d)[0] * 0.05, rng.uniform(100, 110, (50, d))]
    with pytest.raises(RegistrationError, match=rf"^registration refused: at the result only {d - 1} source "
                                                rf"point\(s\) of {len(source)} .* needs {d} .* rotation"):
        pcreg.icp(source, target, ICPOptions(backend="open3d", max_correspondence_distance=0.3))
    with pytest.raises(RegistrationError, match="at the result only"):  # stopped by its iterations, its steps taken:
        pcreg.icp(source, target, ICPOptions(backend="open3d", max_correspondence_distance=0.3, max_iteration=1))
    for iterations in (1, 30):
        r = pcreg.icp(source, target, ICPOptions(max_correspondence_distance=0.3, max_iteration=iterations))
        np.testing.assert_array_equal(r.matrix, np.eye(d + 1))
        assert not r.converged and r.iterations == 0


@pytest.mark.parametrize("metric, d, pairs", [("point_to_plane", 3, 4), ("point_to_plane", 3, 5), ("point_to_line", 2, 2)])
def test_a_step_of_one_equation_a_pair_with_fewer_pairs_than_unknowns_is_not_returned_as_converged(metric, d, pairs):
    """A point-to-plane step solves for six unknowns from one equation a pair: with four or five pairs its system is
    singular whatever the pairs, the reference took no motion for the answer, and the run said it converged where it
    started (fitness 0.05, the identity). It stops there, not converged, as a point-to-point step short of pairs
    does; point to line in 2-D (three unknowns of a rigid motion) the same."""
    rng = np.random.default_rng(19)
    target = rng.uniform(-1, 1, (80, d))
    normals = rng.normal(size=(80, d))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    source = np.r_[target[:pairs] + 0.01, rng.uniform(5, 6, (80 - pairs, d))]
    r = pcreg.icp(source, target, ICPOptions(metric=metric, max_correspondence_distance=0.05), target_normals=normals)
    assert r.fitness == pytest.approx(pairs / 80) and not r.converged and r.iterations == 0
    np.testing.assert_array_equal(r.matrix, np.eye(d + 1))
    if metric == "point_to_plane":  # Open3D's step takes them, and "converged" on a motion they do not fix: refused
        with pytest.raises(RegistrationError, match=r"only \d source point\(s\) of 80 .* needs 6 to fix its "
                                                    r"rotation \(one equation a pair, point to plane\)"):
            pcreg.icp(source, target, ICPOptions(backend="open3d", metric=metric, max_correspondence_distance=0.05),
                      target_normals=normals)
