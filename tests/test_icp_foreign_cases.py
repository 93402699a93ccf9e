"""More of other projects' own ICP test cases, run through pcreg's ICP (:func:`pcreg.icp`) with their data
construction, expected values and tolerances. Sources: isl-org/Open3D python/test/t/registration/test_registration.py
(get_pcds; float32 and float64 clouds) and python/test/test_registration_dcreg.py (box, asymmetric box, cylinder and
offset-plane clouds), cpp/tests/pipelines/registration/SymmetricICP.cpp (input contracts); siavashk/pycpd
testing/rigid_test.py and testing/affine_test.py (data/fish_target.txt, under tests/data/pycpd); ClayFlannigan/icp
test.py test_best_fit. Left out as specific to the library's API, not a property of ICP: Open3D's
RegistrationResult constructor, get_information_matrix, the symmetric objective's RMSE and the DCReg
degeneracy-analysis fields; the cpp Registration.cpp cases on Open3D's downloaded DemoICPPointClouds (not stored
here; their get_pcds counterparts run below)."""

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

import pcreg
from pcreg import ICPOptions
from pcreg import transforms as tf
from pcreg.errors import InputError, RegistrationError
from pcreg.registration.closed_forms import estimate_umeyama
from pcreg.registration.normal_steps import estimate_point_to_plane

from _open3d_cases import GRID_INIT, GRID_SOURCE, GRID_TARGET, GRID_TARGET_NORMALS
from _open3d_cases import open3d_cloud as _cloud

reg = o3d.pipelines.registration
FISH = np.loadtxt(Path(__file__).parent / "data" / "pycpd" / "fish_target.txt")
DECIMAL_6 = 1.5e-6  # numpy's assert_array_almost_equal, pycpd's check: |a - b| < 1.5 x 10^-6


def test_open3d_convergence_criteria_defaults_are_pcreg_s():
    """test_registration.py test_icp_convergence_criteria_constructor: 30 iterations, relative fitness and RMSE 1e-6;
    pcreg states Open3D's stopping rule, so its defaults are these (the RMSE's for clouds one unit across or more:
    it shrinks with smaller ones)."""
    ours, theirs = ICPOptions(), reg.ICPConvergenceCriteria()
    unit = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert (ours.max_iteration, ours.relative_fitness, ours.stopping_rmse(unit)) == (30, 1e-6, 1e-6)
    assert (theirs.max_iteration, theirs.relative_fitness, theirs.relative_rmse) == (30, 1e-6, 1e-6)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("metric", ["none", "point_to_point", "point_to_plane"])
def test_open3d_get_pcds_in_float32_and_float64_as_legacy(dtype, metric):
    """test_evaluate_registration, test_icp_point_to_point, test_icp_point_to_plane: for either dtype of the clouds
    (Open3D's tensor API), fitness and inlier RMSE within 0.1 % of the legacy ICP's in float64 (distance 3.0, two
    iterations from their init; 'none': evaluate_registration at the identity)."""
    src, tgt, normals = (a.astype(dtype) for a in (GRID_SOURCE, GRID_TARGET, GRID_TARGET_NORMALS))
    if metric == "none":
        theirs = reg.evaluate_registration(_cloud(GRID_SOURCE), _cloud(GRID_TARGET), 3.0, np.eye(4))
        ours = pcreg.icp(src, tgt, ICPOptions(max_correspondence_distance=3.0, max_iteration=0))
    else:
        estimation = (reg.TransformationEstimationPointToPoint() if metric == "point_to_point"
                      else reg.TransformationEstimationPointToPlane())
        theirs = reg.registration_icp(_cloud(GRID_SOURCE), _cloud(GRID_TARGET, GRID_TARGET_NORMALS), 3.0, GRID_INIT,
                                      estimation, reg.ICPConvergenceCriteria(max_iteration=2))
        ours = pcreg.icp(src, tgt, ICPOptions(max_correspondence_distance=3.0, max_iteration=2, metric=metric),
                         init=GRID_INIT, target_normals=normals if metric == "point_to_plane" else None)
    np.testing.assert_allclose(ours.inlier_rmse, theirs.inlier_rmse, rtol=1e-3)
    np.testing.assert_allclose(ours.fitness, theirs.fitness, rtol=1e-3)


def test_open3d_point_to_plane_needs_the_target_s_normals():
    """SymmetricICP.cpp InputContracts: an estimation whose normals are missing throws; pcreg's point-to-plane ICP
    without the target's normals, or with normals of another shape, is bad input."""
    with pytest.raises(InputError, match="needs 3-D clouds, target_normals"):
        pcreg.icp(GRID_SOURCE, GRID_TARGET, ICPOptions(metric="point_to_plane"))
    with pytest.raises(InputError, match="target's shape"):
        pcreg.icp(GRID_SOURCE, GRID_TARGET, ICPOptions(metric="point_to_plane"), target_normals=GRID_TARGET_NORMALS[1:])


def _box(xs, ys, zs) -> tuple[np.ndarray, np.ndarray]:
    """test_registration_dcreg.py _make_(asymmetric_)box_clouds: points on a box's six faces, each with its face's
    outward normal."""
    points, normals = [], []
    for y in ys:
        for z in zs:
            points += [[xs[0], y, z], [xs[-1], y, z]]
            normals += [[-1, 0, 0], [1, 0, 0]]
    for x in xs:
        for z in zs:
            points += [[x, ys[0], z], [x, ys[-1], z]]
            normals += [[0, -1, 0], [0, 1, 0]]
    for x in xs:
        for y in ys:
            points += [[x, y, zs[0]], [x, y, zs[-1]]]
            normals += [[0, 0, -1], [0, 0, 1]]
    return np.array(points, dtype=float), np.array(normals, dtype=float)


def test_dcreg_box_point_to_plane_step_on_identity_correspondences():
    """test_dcreg_compute_transformation_matches_point_to_plane: the unit box's 24 face points moved by (0.03, -0.02,
    0.04); one point-to-plane step on the pairs (i, i) is Open3D's TransformationEstimationPointToPlane's, 1e-8."""
    target, normals = _box([0.0, 1.0], [0.0, 1.0], [0.0, 1.0])
    T = np.eye(4)
    T[:3, 3] = [0.03, -0.02, 0.04]
    source = tf.apply(np.linalg.inv(T), target)
    pairs = o3d.utility.Vector2iVector(np.column_stack([np.arange(len(target))] * 2))
    theirs = reg.TransformationEstimationPointToPlane().compute_transformation(
        _cloud(source), _cloud(target, normals), pairs)
    ours = estimate_point_to_plane(source, target, normals, np.ones(len(target)))
    np.testing.assert_allclose(ours, theirs, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(ours, T, atol=1e-8)


@pytest.mark.parametrize("metric", ["point_to_plane", "point_to_point"])
@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_dcreg_asymmetric_box_icp_reaches_the_motion(backend, metric):
    """test_dcreg_registration_icp_matches_point_to_plane_on_normal_geometry: the 150 points of an uneven grid on a
    1.30 x 0.80 x 1.10 box, turned by xyz angles (0.02, -0.015, 0.01) rad and moved by (0.035, -0.025, 0.03);
    distance 0.2, relative fitness and RMSE 1e-9, 20 iterations: the motion to 1e-8."""
    target, normals = _box([0.0, 0.23, 0.51, 0.88, 1.30], [0.0, 0.17, 0.39, 0.64, 0.80], [0.0, 0.19, 0.46, 0.73, 1.10])
    T = np.eye(4)
    T[:3, :3] = o3d.geometry.get_rotation_matrix_from_xyz([0.02, -0.015, 0.01])
    T[:3, 3] = [0.035, -0.025, 0.03]
    options = ICPOptions(backend=backend, metric=metric, max_correspondence_distance=0.2, relative_fitness=1e-9,
                         relative_rmse=1e-9, max_iteration=20)
    r = pcreg.icp(tf.apply(np.linalg.inv(T), target), target, options,
                  target_normals=normals if metric == "point_to_plane" else None)
    np.testing.assert_allclose(r.matrix, T, rtol=1e-8, atol=1e-8)
    assert r.fitness == 1.0 and r.inlier_rmse < 1e-12 and r.converged


def _cylinder_side() -> tuple[np.ndarray, np.ndarray]:
    """test_registration_dcreg.py _make_cylinder_side_clouds: 24 x 7 points on a unit cylinder's side, z in
    [-0.6, 0.6], normals radial."""
    theta = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    z = np.linspace(-0.6, 0.6, 7)
    points = np.array([[np.cos(a), np.sin(a), h] for a in theta for h in z])
    return points, points * [1.0, 1.0, 0.0]


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_dcreg_cylinder_point_to_plane_cannot_fix_the_motion_along_its_axis(backend):
    """test_dcreg_cylinder_degeneracy_is_stable: the side moved by (-0.12, 0.05, -0.35), whose motion along (and
    turn about) the axis no radial normal fixes. DCReg returns its minimum-norm answer, (0.12, -0.05, 0) and no
    turn; pcreg refuses to guess: the normals are bad input for a point-to-plane ICP, and where a floor that fixes
    them lies beyond the correspondence distance the result is refused (the reference step was the identity and the
    run "converged" where it started, inlier RMSE 0.199; Open3D's left the shift along the axis at 0)."""
    target, normals = _cylinder_side()
    source = target + [-0.12, 0.05, -0.35]
    options = ICPOptions(backend=backend, metric="point_to_plane", max_correspondence_distance=0.5)
    with pytest.raises(InputError, match="span 2 of 3 directions"):
        pcreg.icp(source, target, options, target_normals=normals)
    floor = np.array([[x, y, -5.0] for x in np.linspace(-1, 1, 5) for y in np.linspace(-1, 1, 5)])
    with_floor = np.vstack([target, floor])
    floor_normals = np.vstack([normals, np.tile([0.0, 0.0, 1.0], (len(floor), 1))])
    with pytest.raises(RegistrationError, match=r"paired with have normals .*span 2 of 3 directions"):
        pcreg.icp(source, with_floor, options, target_normals=floor_normals)


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_dcreg_offset_plane_point_to_point(backend):
    """test_dcreg_local_registration_uses_local_plane_without_normals: a 5 x 5 grid on the plane z = 1, the source
    0.1 below it; distance 0.5, relative fitness and RMSE 1e-9, 10 iterations: (0, 0, 0.1) to 1e-8, fitness 1 and
    inlier RMSE 0 to 1e-12. (DCReg fits local planes; pcreg's point-to-point ICP reaches it, and its point-to-plane
    ICP refuses normals that all point one way.)"""
    target = np.array([[0.2 * x + 0.5, 0.2 * y + 0.5, 1.0] for x in range(5) for y in range(5)])
    source = target + [0.0, 0.0, -0.1]
    options = ICPOptions(backend=backend, max_correspondence_distance=0.5, relative_fitness=1e-9, relative_rmse=1e-9,
                         max_iteration=10)
    r = pcreg.icp(source, target, options)
    np.testing.assert_allclose(r.matrix[:3, 3], [0.0, 0.0, 0.1], atol=1e-8)
    np.testing.assert_allclose(r.matrix[:3, :3], np.eye(3), atol=1e-8)
    assert r.fitness == pytest.approx(1.0, abs=1e-12) and r.inlier_rmse == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(InputError, match="span 1 of 3 directions"):
        pcreg.icp(source, target, ICPOptions(backend=backend, metric="point_to_plane", max_correspondence_distance=0.5),
                  target_normals=np.tile([0.0, 0.0, 1.0], (len(target), 1)))


@pytest.mark.parametrize("backend", ["reference", "open3d"])
@pytest.mark.parametrize("d", [2, 3])
def test_pycpd_rigid_fish_turned_30_degrees(d, backend):
    """rigid_test.py test_2D and test_3D: X = Y R + t with R a 30-degree turn (about z in 3-D, the fish at z = 0), t
    = (0.5, 1.0) or (0.5, 1.0, -2.0): scale 1, R, t and the moved points to six decimals. X = Y R is Y turned by
    R^T, so pcreg's T_target_source holds R^T."""
    a = np.pi / 6.0
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])[:d, :d]
    t = np.array([0.5, 1.0, -2.0])[:d]
    Y = np.column_stack([FISH, np.zeros(len(FISH))])[:, :d]
    X = Y @ R + t
    r = pcreg.icp(Y, X, ICPOptions(backend=backend, max_iteration=100))
    assert np.linalg.det(r.matrix[:d, :d]) == pytest.approx(1.0, abs=DECIMAL_6)
    np.testing.assert_allclose(r.matrix[:d, :d], R.T, atol=DECIMAL_6)
    np.testing.assert_allclose(r.matrix[:d, d], t, atol=DECIMAL_6)
    np.testing.assert_allclose(tf.apply(r.matrix, Y), X, atol=DECIMAL_6)


def _fish_affine(d: int, share: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """affine_test.py: X = Y B + t, B a shear of 0.5, t = (0.5, 1.0) (-2.0 in z); in 3-D the fish at z = 0 and at
    z = 1. ``share`` scales the shear and shift (1: theirs). Returns Y, X and T_target_source."""
    B = np.eye(d)
    B[0, 1] = 0.5 * share
    t = share * np.array([0.5, 1.0, -2.0])[:d]
    Y = FISH if d == 2 else np.vstack([np.column_stack([FISH, np.full(len(FISH), z)]) for z in (0.0, 1.0)])
    T = np.eye(d + 1)
    T[:d, :d], T[:d, d] = B.T, t
    return Y, Y @ B + t, T


@pytest.mark.parametrize("d", [2, 3])
def test_pycpd_affine_fish(d):
    """affine_test.py test_2D and test_3D. From the identity, their shear and shift lie outside affine ICP's basin
    (CPD's is wider): in 2-D the ICP ends in a local minimum whose inlier RMSE (0.08) says it is not a match, in 3-D
    it shrinks the two fish onto a plane and is refused. A tenth of their motion, and their motion from an init
    a tenth away, are recovered to six decimals."""
    Y, X, T = _fish_affine(d, 1.0)
    if d == 2:
        r = pcreg.icp(Y, X, ICPOptions(model="affine", max_iteration=100))
        assert r.inlier_rmse > 0.05 and np.abs(r.matrix - T).max() > 0.1
    else:
        with pytest.raises(RegistrationError, match=r"point\(s\), which cannot determine an affine transform"):
            pcreg.icp(Y, X, ICPOptions(model="affine", max_iteration=100))
    Ys, Xs, Ts = _fish_affine(d, 0.1)
    _, _, nine_tenths = _fish_affine(d, 0.9)
    for source, target, truth, init in ((Ys, Xs, Ts, None), (Y, X, T, nine_tenths)):
        r = pcreg.icp(source, target, ICPOptions(model="affine", max_iteration=100), init=init)
        np.testing.assert_allclose(r.matrix, truth, atol=DECIMAL_6)
        np.testing.assert_allclose(tf.apply(r.matrix, source), target, atol=DECIMAL_6)


def _clay_rotation(axis: np.ndarray, theta: float) -> np.ndarray:
    """ClayFlannigan/icp test.py rotation_matrix (Euler-Rodrigues)."""
    axis = axis / np.sqrt(axis @ axis)
    a = np.cos(theta / 2.0)
    b, c, d = -axis * np.sin(theta / 2.0)
    return np.array([[a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
                     [2 * (b * c + a * d), a * a + c * c - b * b - d * d, 2 * (c * d - a * b)],
                     [2 * (b * d - a * c), 2 * (c * d + a * b), a * a + d * d - b * b - c * c]])


def test_clayflannigan_best_fit_transform():
    """ClayFlannigan/icp (167cc4adc442487d2b1b331e18818a6f4d779d49) test.py test_best_fit: 10 random points, 100
    trials each moved by up to 0.1, turned by up to 0.1 rad about a random axis, noise sigma 0.01, correspondences
    given: the closed form (pcreg's Umeyama step) maps B onto A, and its R and t are R^T and -t, within 6 sigma."""
    rng = np.random.default_rng(0)
    A = rng.random((10, 3))
    for _ in range(100):
        t = rng.random(3) * 0.1
        R = _clay_rotation(rng.random(3), rng.random() * 0.1)
        B = (R @ (A + t).T).T + rng.standard_normal((10, 3)) * 0.01
        T = estimate_umeyama(B, A, np.ones(10), with_scale=False)
        np.testing.assert_allclose(tf.apply(T, B), A, atol=0.06)
        np.testing.assert_allclose(-T[:3, 3], t, atol=0.06)
        np.testing.assert_allclose(T[:3, :3].T, R, atol=0.06)
