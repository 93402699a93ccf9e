import numpy as np
import pytest

import pcreg
from pcreg import ICPOptions
from pcreg import transforms as tf
from pcreg.errors import RegistrationError
from pcreg.registration.kdtree import KDTreeIndex
from pcreg.registration.reference import (
    check_rank,
    estimate,
    estimate_horn_quaternion,
    estimate_umeyama,
    icp_reference,
    robust_weights,
)


def random_rotation_3d(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


@pytest.mark.parametrize("model", ["translation", "rigid", "similarity", "affine", "projective"])
def test_closed_forms_recover_exact_2d_transforms(model):
    rng = np.random.default_rng(0)
    p = rng.uniform(-50, 50, (40, 2))
    T = {"translation": tf.rigid2d(0, 3, -2), "rigid": tf.rigid2d(37, 3, -2),
         "similarity": tf.rigid2d(-20, 1, 5, scale=1.3),
         "affine": np.array([[1.1, 0.2, 3], [-0.1, 0.9, 1], [0, 0, 1.0]]),
         "projective": np.array([[1.0, 0.1, 3], [0.05, 1.1, 2], [1e-3, -2e-3, 1.0]])}[model]
    q = tf.apply(T, p)
    np.testing.assert_allclose(estimate(p, q, np.ones(len(p)), model), T, atol=1e-9)


@pytest.mark.parametrize("model", ["rigid", "similarity", "affine"])
def test_closed_forms_recover_exact_3d_transforms(model):
    rng = np.random.default_rng(1)
    p = rng.normal(size=(30, 3))
    T = np.eye(4)
    T[:3, :3] = random_rotation_3d(rng) * (1.5 if model == "similarity" else 1.0)
    if model == "affine":
        T[:3, :3] += rng.normal(scale=0.1, size=(3, 3))
    T[:3, 3] = [1, -2, 3]
    np.testing.assert_allclose(estimate(p, tf.apply(T, p), np.ones(30), model), T, atol=1e-9)


def test_horn_quaternion_matches_umeyama_svd_on_noisy_data():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(100, 3))
    T = np.eye(4)
    T[:3, :3] = random_rotation_3d(rng)
    T[:3, 3] = [0.5, 0.1, -0.3]
    q = tf.apply(T, p) + rng.normal(scale=0.05, size=p.shape)
    w = rng.uniform(0.5, 1.5, 100)
    np.testing.assert_allclose(estimate_horn_quaternion(p, q, w), estimate_umeyama(p, q, w, with_scale=False),
                               atol=1e-10)


def test_umeyama_never_returns_a_reflection():
    # Points mirrored in x: the best orthogonal map is a reflection; the det(U)det(V) rule forbids it.
    rng = np.random.default_rng(3)
    p = rng.normal(size=(20, 2)) * [5, 1]
    q = p * [-1, 1]
    T = estimate_umeyama(p, q, np.ones(20), with_scale=False)
    assert np.linalg.det(T[:2, :2]) == pytest.approx(1.0)


@pytest.mark.parametrize("direction", [[1.0, 2.0, 2.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
def test_pairs_along_one_line_take_the_least_rotation_that_fits_them(direction):
    """Umeyama's rotation is unique only when the cross-covariance has rank d - 1 or more. Pairs whose source
    points lie on one line (or whose targets do: every source point nearest to two target points, as ICP's
    first step from far away) fix one direction and leave the turn about it free; the step takes the least
    rotation that maps the one direction onto the other, not what the SVD's null space happens to hold (a
    93 degree turn for a 48 degree fit before), and no rotation when the pairs fix nothing."""
    t = np.linspace(-1.0, 1.0, 7)
    d = np.asarray(direction) / np.linalg.norm(direction)
    p, q = np.outer(t, d) + [1.0, 2.0, 3.0], np.outer(t, [0.0, 0.0, 1.0]) - [0.5, 0.0, 0.0]
    for with_scale in (False, True):
        T = estimate_umeyama(p, q, np.ones(len(p)), with_scale=with_scale)
        R = T[:3, :3] / np.cbrt(np.linalg.det(T[:3, :3]))
        np.testing.assert_allclose(R @ d, [0.0, 0.0, 1.0], atol=1e-12)
        angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(np.degrees(np.arccos(d[2])), abs=1e-9)
        np.testing.assert_allclose(tf.apply(T, p.mean(axis=0)[None]), q.mean(axis=0)[None], atol=1e-12)
    T = estimate_umeyama(p, np.tile([1.0, 1.0, 1.0], (len(p), 1)), np.ones(len(p)), with_scale=False)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=0)


@pytest.mark.parametrize("direction", [[1.0, 2.0, 2.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
def test_horn_s_step_on_pairs_along_one_line_takes_the_least_rotation_as_umeyama_s(direction):
    """Horn's quaternion step on the same pairs: where they fix one direction its largest eigenvalue is double and
    the eigenvector was whichever eigh returned (a 76 degree turn where 48 fit, 180 where 90 did); it takes
    Umeyama's least rotation, and none when the pairs fix nothing."""
    t = np.linspace(-1.0, 1.0, 7)
    d = np.asarray(direction) / np.linalg.norm(direction)
    p, q = np.outer(t, d) + [1.0, 2.0, 3.0], np.outer(t, [0.0, 0.0, 1.0]) - [0.5, 0.0, 0.0]
    w = np.ones(len(p))
    np.testing.assert_allclose(estimate_horn_quaternion(p, q, w), estimate_umeyama(p, q, w, with_scale=False),
                               atol=1e-12)
    T = estimate_horn_quaternion(p, np.tile([1.0, 1.0, 1.0], (len(p), 1)), w)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=0)



def test_the_dlt_normal_solve_is_the_svd_solve():
    # The model check's projective step solves the DLT from its 9 x 9 normal matrix; on Hartley-normalised points
    # it is the SVD's homography to rounding, with noise, unequal weights and pairs weighted out.
    rng = np.random.default_rng(7)
    H = np.array([[1.05, -0.2, 30.0], [0.15, 0.95, -12.0], [3e-4, -2e-4, 1.0]])
    p = rng.uniform(0, 500, (3000, 2))
    q = tf.apply(H, p) + rng.normal(0, 0.7, p.shape)
    w = rng.uniform(0.2, 1.0, len(p))
    w[::5] = 0.0
    svd = estimate(p, q, w, "projective")
    normal = estimate(p, q, w, "projective", dlt="normal")
    np.testing.assert_allclose(normal, svd, rtol=1e-9, atol=1e-12)
    assert tf.max_corner_error(normal, H, (500, 500)) < 0.5
    target = rng.uniform(0, 200, (800, 2))
    source = tf.apply(np.linalg.inv(np.array([[1.01, 0.01, 1.0], [-0.01, 0.99, -0.5], [1e-4, 5e-5, 1.0]])), target)
    runs = [icp_reference(source, target, ICPOptions(model="projective", max_correspondence_distance=5,
                                                     max_iteration=30), dlt=dlt) for dlt in ("svd", "normal")]
    np.testing.assert_allclose(runs[1].matrix, runs[0].matrix, rtol=1e-9, atol=1e-12)
    assert runs[1].iterations == runs[0].iterations and runs[1].fitness == runs[0].fitness

def test_the_compiled_dlt_is_the_numpy_dlt():
    # The compiled projective loop's DLT sums the normal matrix one pair at a time over the matched pairs: the
    # NumPy normal solve's homography to rounding, with noise, unequal weights, pairs weighted out and unmatched.
    from pcreg.registration.closed_forms import _dlt_normal_pairs, estimate_projective

    rng = np.random.default_rng(11)
    H = np.array([[0.97, 0.12, -25.0], [-0.08, 1.04, 14.0], [-2e-4, 3e-4, 1.0]])
    p = rng.uniform(0, 400, (2500, 2))
    q = tf.apply(H, p) + rng.normal(0, 0.5, p.shape)
    order = rng.permutation(len(p))  # the matches point anywhere in the target
    target = np.empty_like(q)
    target[order] = q
    match = order.copy()
    match[::7] = -1
    w = rng.uniform(0.1, 2.0, len(p))
    w[::5] = 0.0
    kept = match >= 0
    numpy = estimate_projective(p[kept], target[match[kept]], w[kept], solve="normal")
    compiled, error = _dlt_normal_pairs(p, target, match, w)
    assert error == 0
    np.testing.assert_allclose(compiled, numpy, rtol=1e-9, atol=1e-15)
    assert tf.max_corner_error(compiled, H, (400, 400)) < 0.5
    assert _dlt_normal_pairs(np.zeros((6, 2)), np.zeros((6, 2)), np.arange(6), np.ones(6))[1] != 0


def test_the_compiled_projective_icp_is_the_numpy_loop():
    # The model check's refinement (projective, dlt="normal", no weights, a KD-tree) runs compiled; the NumPy loop
    # (here through scipy's cKDTree, which it takes as it is) gives the same iterations, fitness and homography.
    from scipy.spatial import cKDTree

    from pcreg.registration.reference import _icp_projective

    rng = np.random.default_rng(5)
    t = np.linspace(0, 2 * np.pi, 1500, endpoint=False)
    curve = np.column_stack([200 + 120 * np.cos(t) + 30 * np.cos(5 * t), 150 + 90 * np.sin(3 * t)])
    target = np.vstack([curve + rng.normal(0, 0.3, curve.shape), rng.uniform(0, 400, (500, 2))])
    H = np.array([[1.02, 0.03, 2.0], [-0.02, 0.99, -1.5], [4e-5, -3e-5, 1.0]])
    source = tf.apply(np.linalg.inv(H), target[::2]) + rng.normal(0, 0.4, (1000, 2))
    options = ICPOptions(model="projective", max_correspondence_distance=5, max_iteration=40)
    numpy = icp_reference(source, target, options, dlt="normal", tree=cKDTree(target))
    steps = []
    compiled = _icp_projective(source, target, np.eye(3), KDTreeIndex(target), max_distance=5.0, max_iteration=40,
                               relative_fitness=options.relative_fitness, relative_rmse=options.stopping_rmse(source, target),
                               callback=steps.append, level=0, start=0.0)
    assert numpy.iterations > 5 and compiled.iterations == numpy.iterations and len(steps) == numpy.iterations + 1
    assert compiled.converged == numpy.converged and compiled.fitness == numpy.fitness
    np.testing.assert_allclose(compiled.inlier_rmse, numpy.inlier_rmse, rtol=1e-12)
    np.testing.assert_allclose(compiled.matrix, numpy.matrix, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(steps[-1].matrix, compiled.matrix)
    assert tf.max_corner_error(compiled.matrix, H, (300, 400)) < 0.5
    # without a callback, in one call, and as icp_reference runs it
    once = icp_reference(source, target, options, dlt="normal")
    np.testing.assert_array_equal(once.matrix, compiled.matrix)
    assert once.iterations == compiled.iterations


@pytest.mark.parametrize("model", ["translation", "rigid", "similarity", "affine", "projective"])
def test_point_to_line_converges_on_lines(model):
    # Points on a closed curve with normals: point-to-line steps recover a small motion.
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    target = np.column_stack([60 * np.cos(t) + 10 * np.cos(3 * t), 40 * np.sin(t)])
    tangent = np.gradient(target, axis=0)
    normals = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    T = {"translation": tf.rigid2d(0, 1.5, -1), "rigid": tf.rigid2d(2, 1.5, -1),
         "similarity": tf.rigid2d(2, 1.5, -1, scale=1.02),
         "affine": np.array([[1.02, 0.01, 1.5], [-0.01, 0.99, -1], [0, 0, 1.0]]),
         "projective": np.array([[1.02, 0.01, 1.5], [-0.01, 0.99, -1], [2e-4, -1e-4, 1.0]])}[model]
    source = tf.apply(np.linalg.inv(T), target[::3])
    M = icp_reference(source, target, ICPOptions(model=model, max_correspondence_distance=10, metric="point_to_line",
                                                 max_iteration=50), target_normals=normals).matrix
    assert tf.max_corner_error(M, T, (100, 140)) < 0.05


def test_robust_weights():
    d = np.array([0.1, 0.2, 0.3, 10.0])
    np.testing.assert_array_equal(robust_weights(d, "trimmed", trim_fraction=0.75), [1, 1, 1, 0])
    hub = robust_weights(d, "huber")
    assert hub[0] == 1.0 and hub[-1] < 0.1
    assert robust_weights(d, "tukey")[-1] == 0.0
    assert np.all(robust_weights(d, "none") == 1.0)


def test_outliers_need_robust_weights():
    rng = np.random.default_rng(4)
    target = rng.uniform(0, 100, (300, 2))
    T = tf.rigid2d(3, 1.0, -0.5)
    source = tf.apply(np.linalg.inv(T), target)
    source[:60] = rng.uniform(0, 100, (60, 2))  # 20% gross outliers with correspondences of their own
    plain = icp_reference(source, target, ICPOptions(max_correspondence_distance=5, max_iteration=60)).matrix
    robust = icp_reference(source, target, ICPOptions(max_correspondence_distance=5, max_iteration=60,
                                                      weights="tukey")).matrix
    assert tf.max_corner_error(robust, T, (100, 100)) < tf.max_corner_error(plain, T, (100, 100))
    assert tf.max_corner_error(robust, T, (100, 100)) < 0.05


def test_stopping_rule_and_callback():
    rng = np.random.default_rng(5)
    target = rng.uniform(0, 100, (500, 2))
    source = tf.apply(np.linalg.inv(tf.rigid2d(2, 1, 1)), target)
    seen = []
    r = icp_reference(source, target, ICPOptions(max_correspondence_distance=10, max_iteration=100), callback=seen.append)
    assert r.converged and r.iterations < 100 and r.backend == "reference"
    assert [s.iteration for s in seen] == list(range(r.iterations + 1))
    assert seen[-1].fitness == r.fitness and seen[-1].inlier_rmse == r.inlier_rmse
    np.testing.assert_array_equal(seen[-1].matrix, r.matrix)
    # Disabled thresholds: exactly max_iteration updates.
    assert icp_reference(source, target, ICPOptions(max_correspondence_distance=10, max_iteration=7, relative_fitness=0,
                                                    relative_rmse=0)).iterations == 7


@pytest.mark.parametrize("d, model", [(2, "rigid"), (2, "similarity"), (3, "rigid"), (3, "translation")])
def test_the_compiled_loop_runs_the_same_steps_whichever_way_it_is_driven(d, model, monkeypatch):
    """All iterations in one compiled call, one a call (with a callback), and both on every thread
    (large clouds): the same iterations, matches and transform."""
    from pcreg.registration import nn

    rng = np.random.default_rng(11)
    target = rng.uniform(0, 100, (800, d))
    T = tf.rigid2d(4, 2, -1)
    if d == 3:
        T = np.eye(4)
        T[:3, :3] = tf.rigid2d(3)  # as a 3x3 matrix: a rotation by 3 degrees about z
        T[:3, 3] = [1.5, -1.0, 0.5]
    source = tf.apply(np.linalg.inv(T), target)[:600] + rng.normal(0, 0.05, (600, d))
    options = ICPOptions(model=model, max_correspondence_distance=6.0, max_iteration=40)
    fused = icp_reference(source, target, options)
    seen = []
    stepped = icp_reference(source, target, options, callback=seen.append)
    monkeypatch.setattr(nn, "PARALLEL_MIN_QUERIES", 1)
    threaded = icp_reference(source, target, options)
    threaded_stepped = icp_reference(source, target, options, callback=lambda it: None)
    assert 2 < fused.iterations < 40 and fused.converged
    for r in (stepped, threaded, threaded_stepped):
        assert (r.iterations, r.converged, r.fitness) == (fused.iterations, fused.converged, fused.fitness)
        np.testing.assert_array_equal(r.matrix, fused.matrix)  # the same matches, the same sums: to the bit
    assert [s.iteration for s in seen] == list(range(fused.iterations + 1))


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("far", [1e5, 1e8])
def test_a_stray_target_point_far_away_does_not_cost_the_closed_form_its_precision(d, far):
    """The compiled loop sums the pairs' moments about the target's bounding box's centre; one stray point far
    away put that centre among nothing, and the one-pass moments lost the rotation (0.2 degrees off at 1e5, 47
    at 1e6, where Open3D's and the weighted step's are exact)."""
    rng = np.random.default_rng(5)
    target = rng.uniform(0, 1, (500, d))
    T = tf.rigid2d(4, 0.02, -0.01)
    if d == 3:
        T = np.eye(4)
        T[:3, :3] = tf.rigid2d(3)
        T[:3, 3] = [0.02, -0.01, 0.015]
    source = tf.apply(np.linalg.inv(T), target)
    stray = np.vstack([target, np.full((1, d), far)])
    for options in (ICPOptions(max_correspondence_distance=0.1, max_iteration=60),
                    ICPOptions(max_correspondence_distance=0.1, max_iteration=60, weights="huber")):
        r = icp_reference(source, stray, options)
        assert np.abs(r.matrix - T).max() < 1e-9, options.weights


def test_a_similarity_of_coinciding_points_is_refused_in_the_compiled_loop():
    target = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    source = np.array([[0.2, 0.2], [0.2, 0.2], [0.2, 0.2]])
    with pytest.raises(RegistrationError, match="coincide"):
        icp_reference(source, target, ICPOptions(model="similarity", max_correspondence_distance=5.0))


def test_no_correspondences_means_no_motion_and_not_converged():
    a = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    r = icp_reference(a, a + 100, ICPOptions(max_correspondence_distance=1.0))
    np.testing.assert_array_equal(r.matrix, np.eye(3))
    assert r.fitness == 0.0 and r.inlier_rmse == 0.0 and not r.converged and r.iterations == 0


@pytest.mark.parametrize("weights", ["none", "huber"])  # the compiled loop, and the loop with weights
def test_too_few_pairs_for_the_model_stop_the_run_not_converged(weights):
    """One pair within the gate in 3-D does not determine a rotation: the run stops where it started, and
    does not say it converged (it said so before, from an identity step that changed nothing)."""
    rng = np.random.default_rng(0)
    source = rng.random((400, 3))
    t = np.radians(30)
    rot = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    target = source @ rot.T + [0.3, 0.1, 0]
    r = icp_reference(source, target, ICPOptions(max_correspondence_distance=0.0172, weights=weights))
    assert r.fitness * len(source) < 3
    np.testing.assert_array_equal(r.matrix, np.eye(4))
    assert not r.converged and r.iterations == 0
    near = icp_reference(source, source + 0.01, ICPOptions(max_correspondence_distance=0.05, weights=weights))
    assert near.converged and near.iterations > 0


@pytest.mark.parametrize("pts, model, message", [
    (np.array([[0.0, 0.0]]), "rigid", "too few"),
    (np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]), "affine", "collinear"),
    (np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]), "rigid", "coincident"),
    (np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0]]), "projective", "collinear"),
])
def test_degenerate_points(pts, model, message):
    with pytest.raises(RegistrationError, match=message):
        check_rank(pts, model)


def _wavy_surface(n: int, rng, lo: float = 0.0, hi: float = 1.0):
    """Points of z = 0.1 sin(3x) cos(2y) over [lo, hi]^2 and their unit normals."""
    x, y = rng.uniform(lo, hi, n), rng.uniform(lo, hi, n)
    pts = np.column_stack([x, y, 0.1 * np.sin(3 * x) * np.cos(2 * y)])
    normals = np.column_stack([-0.3 * np.cos(3 * x) * np.cos(2 * y), 0.2 * np.sin(3 * x) * np.sin(2 * y), np.ones(n)])
    return pts, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_point_to_plane_reaches_the_surface_with_either_backend_step_for_step():
    """3-D point-to-plane (Open3D's TransformationEstimationPointToPlane, and the reference's same
    linearisation): a source sampled apart from the target reaches the true motion where point-to-point
    is held back by the sampling, and the two backends take the same steps."""
    import pcreg
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    target, normals = _wavy_surface(4000, rng)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(0.05 * np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])).as_matrix()
    T[:3, 3] = [0.02, -0.015, 0.01]
    surface, _ = _wavy_surface(1500, rng, 0.1, 0.9)
    source = (surface - T[:3, 3]) @ T[:3, :3]  # T_target_source = T
    steps = {}
    for backend in ("reference", "open3d"):
        seen: list = []
        r = pcreg.icp(source, target, ICPOptions(backend=backend, metric="point_to_plane", max_correspondence_distance=0.1),
                      target_normals=normals, callback=lambda it, seen=seen: seen.append(it.matrix))
        assert np.abs(r.matrix - T).max() < 5e-4 and r.fitness == 1.0
        steps[backend] = seen
    assert len(steps["reference"]) == len(steps["open3d"])
    assert max(np.abs(a - b).max() for a, b in zip(steps["reference"], steps["open3d"])) < 1e-9
    plain = pcreg.icp(source, target, ICPOptions(max_correspondence_distance=0.1, max_iteration=100))
    assert np.abs(plain.matrix - T).max() > 10 * np.abs(r.matrix - T).max()


@pytest.mark.parametrize("options, dims, with_normals", [
    ({"metric": "point_to_plane"}, 3, False),
    ({"metric": "point_to_plane", "model": "similarity"}, 3, True),
    ({"metric": "point_to_plane"}, 2, True),
    ({"metric": "point_to_plane", "schedule": "voxels"}, 3, True),
    ({"backend": "open3d"}, 3, True),
])
def test_point_to_plane_refuses_what_it_cannot_do(options, dims, with_normals):
    import pcreg
    from pcreg import VoxelSchedule

    rng = np.random.default_rng(1)
    pts, normals = _wavy_surface(200, rng)
    if options.get("schedule") == "voxels":
        options = {**options, "schedule": VoxelSchedule(voxel_sizes=(0.1,), max_iterations=(10,))}
    with pytest.raises(pcreg.InputError):
        pcreg.icp(pts[:, :dims], pts[:, :dims], ICPOptions(**options), target_normals=normals[:, :dims] if with_normals else None)


def _hostile_backend_input(case: str, source: np.ndarray, target: np.ndarray):
    """``(source, target, init)`` of one bad call of a backend's ICP, made from two good 3-D clouds."""
    init = None
    if case == "nan source":
        source = source.copy()
        source[3, 1] = np.nan
    elif case == "inf target":
        target = target.copy()
        target[0, 0] = np.inf
    elif case == "2-D source, 3-D target":
        source = source[:, :2]
    elif case == "3-D source, 2-D target":
        target = target[:, :2]
    elif case == "(3, N) arrays":
        source, target = source.T, target.T
    elif case == "empty target":
        target = target[:0]
    elif case == "open3d cloud":
        import open3d as o3d

        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source))
    elif case == "3x3 init":
        init = np.eye(3)
    elif case == "5x5 init":
        init = np.eye(5)
    elif case == "nan init":
        init = np.full((4, 4), np.nan)
    return source, target, init


@pytest.mark.parametrize("backend", ["reference", "open3d"])
@pytest.mark.parametrize("case, said", [
    ("nan source", "source: 1 point"), ("inf target", "target: 1 point"),
    ("2-D source, 3-D target", "source is 2-D but target is 3-D"),
    ("3-D source, 2-D target", "source is 3-D but target is 2-D"), ("(3, N) arrays", "got shape"),
    ("empty target", "empty"), ("open3d cloud", "np.asarray"), ("3x3 init", "4x4"), ("5x5 init", "4x4"),
    ("nan init", "NaN"),
])
def test_each_backends_icp_refuses_bad_clouds_and_inits_at_its_door(backend, case, said):
    """Each backend's ICP, called directly as researchers do, refuses what it cannot register with an InputError
    that says why. Before: a 2-D source against a 3-D target, a NaN source point or a NaN init came back as a
    result (fitness 1, 0.995, and a NaN matrix); the rest were numpy's IndexError, Open3D's TypeError or
    RuntimeError, an AttributeError, or the KD-tree's plain ValueError."""
    from pcreg.errors import InputError
    from pcreg.registration.open3d_icp import icp_open3d

    rng = np.random.default_rng(0)
    source = rng.uniform(-1, 1, (200, 3))
    target = source + [0.05, -0.02, 0.03]
    source, target, init = _hostile_backend_input(case, source, target)
    run = icp_reference if backend == "reference" else icp_open3d
    with pytest.raises(InputError, match=said):
        run(source, target, ICPOptions(max_correspondence_distance=1.0), init=init)


def test_the_reference_icp_refuses_a_projective_model_in_3d():
    from pcreg.errors import InputError

    cloud = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    with pytest.raises(InputError, match="2-D clouds only"):
        icp_reference(cloud, cloud + 0.01, ICPOptions(model="projective", max_correspondence_distance=1.0))


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_each_backends_icp_takes_lists_float32_and_fortran_order_as_the_float64_array(backend):
    from pcreg.registration.open3d_icp import icp_open3d

    rng = np.random.default_rng(2)
    source = rng.uniform(-1, 1, (200, 3))
    target = source + [0.03, -0.02, 0.01]
    run = icp_reference if backend == "reference" else icp_open3d
    options = ICPOptions(max_correspondence_distance=1.0)
    plain = run(source, target, options)
    for s, t in ((source.tolist(), target.tolist()), (np.asfortranarray(source), np.asfortranarray(target)),
                 (source.astype(np.float32).astype(np.float64), target.astype(np.float32))):
        r = run(s, t, options)
        np.testing.assert_allclose(r.matrix, plain.matrix, atol=1e-6)


@pytest.mark.parametrize("weights", ["none", "huber"])  # the compiled loop, and the loop with weights
@pytest.mark.parametrize("d", [2, 3])
def test_a_translation_needs_one_pair_in_3d_as_in_2d(d, weights):
    """A translation is fixed by one pair in any dimension: in 3-D the run asked for three, as a rotation does, so
    one or two source points within the gate left the source where it started (the identity, fitness 1, not
    converged) while the same clouds in 2-D were moved onto the target."""
    shift = np.array([0.3, -0.2, 0.1])[:d]
    for source in (np.zeros((1, d)), np.eye(d)[:2] * 5.0):
        r = icp_reference(source, source + shift, ICPOptions(model="translation", max_correspondence_distance=1.0,
                                                               weights=weights))
        np.testing.assert_allclose(r.matrix[:d, d], shift, atol=1e-12)
        assert r.converged and r.inlier_rmse < 1e-12


def test_a_3d_affine_step_needs_four_pairs():
    """Three pairs leave a 3-D affine step free along their plane's normal (least squares took the minimum-norm
    solution, which flattens the source): the run stops where it is, not converged, as with too few pairs in 2-D."""
    from pcreg.registration.closed_forms import pairs_needed, rank_problem

    assert [pairs_needed(m, 3) for m in ("translation", "rigid", "similarity", "affine")] == [1, 3, 3, 4]
    rng = np.random.default_rng(1)
    target = rng.uniform(0, 10, (100, 3))
    source = np.r_[target[:3] + 0.1, rng.uniform(100, 110, (10, 3))]
    r = icp_reference(source, target, ICPOptions(model="affine", max_correspondence_distance=0.5))
    np.testing.assert_array_equal(r.matrix, np.eye(4))
    assert not r.converged and r.iterations == 0
    assert "too few" in rank_problem(target[:3], "affine")


def _turned_about_x(angle: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([angle, 0.0, 0.0]).as_matrix()
    return T


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_a_rigid_result_whose_pairs_all_lie_on_one_target_line_is_refused(backend):
    """An L-shaped source whose x arm alone reaches the target (turned 17 degrees about that arm; the rest of the
    target beyond the correspondence distance): both clouds determine a rotation, the pairs at the result do not.
    Both backends returned the identity from the identity and a 126-degree turn from another start, each converged
    with the same fitness and inlier RMSE, nothing to tell them apart. With the gate wide enough to pair the whole
    target the same clouds give a rotation, not refused."""
    xs = np.linspace(0, 10, 101)
    arm = np.column_stack([xs, 0 * xs, 0 * xs])
    source = np.vstack([arm, np.column_stack([np.zeros(50), np.linspace(0.2, 5, 50), np.zeros(50)])])
    far = np.random.default_rng(3).uniform(-1, 1, (50, 3)) + [5, 20, 20]
    target = np.vstack([tf.apply(_turned_about_x(0.3), arm), far])
    for start in (np.eye(4), _turned_about_x(2.5)):
        with pytest.raises(RegistrationError, match=r"at the result the 10\d pair\(s\) within the correspondence distance "
                                                    r"0.5 leave the rotation undetermined \(their target points are collinear"):
            pcreg.icp(source, target, pcreg.ICPOptions(backend=backend, max_correspondence_distance=0.5), init=start)
    turned = np.vstack([tf.apply(_turned_about_x(0.3), source), far])
    fit = pcreg.icp(source, turned, pcreg.ICPOptions(backend=backend, max_correspondence_distance=1.0))
    np.testing.assert_allclose(fit.matrix, _turned_about_x(0.3), atol=1e-9)


def test_a_line_thin_enough_to_pass_as_a_cloud_is_refused_at_the_result():
    """A line 10 long and 1e-7 thick passes the clouds' own check (more than 1e-9 of its length across); Open3D's
    step turned it half about itself, converged, fitness 1. Its pairs' cross-covariance has rank 1: refused."""
    rng = np.random.default_rng(5)
    source = np.column_stack([np.linspace(-5, 5, 100), rng.normal(0, 1e-7, 100), rng.normal(0, 1e-7, 100)])
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.05]).as_matrix()
    T[:2, 3] = 0.1, 0.2
    for backend in ("reference", "open3d"):
        with pytest.raises(RegistrationError, match=r"leave the rotation undetermined \(their cross-covariance has rank 1"):
            pcreg.icp(source, tf.apply(T, source), pcreg.ICPOptions(backend=backend, max_correspondence_distance=1.0))
