"""Other projects' tests of the closed forms of a fit from given pairs (Kabsch / Umeyama, weighted; affine and
homography least squares), run through pcreg's closed forms (:mod:`pcreg.registration.closed_forms`, the step of
the reference ICP) and, where the case is a registration, :func:`pcreg.icp`. Sources, each named in its test:
scipy/scipy scipy/spatial/transform/tests/test_rotation.py (``Rotation.align_vectors``), scikit-image/scikit-image
tests/skimage/transform/test_geometric.py (``estimate_transform``, ``EuclideanTransform``, ``SimilarityTransform``,
``AffineTransform``, ``ProjectiveTransform``), mikedh/trimesh tests/test_registration.py (``procrustes``, ``icp``).
Left out as specific to the library's API, not a property of the fit: scipy's sensitivity matrix, infinite weights
and input-shape errors; scikit-image's parameter properties (``rotation``, ``shear``, repr) and non-rigid
transforms; trimesh's ``translation=False`` and ``reflection=True`` (pcreg's fits always move and never mirror),
its mesh targets (a dense sampling of the box's surface stands in for the box below) and its non-rigid ICPs."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pcreg
from pcreg import ICPOptions
from pcreg import transforms as tf
from pcreg.errors import RegistrationError
from pcreg.registration.closed_forms import (_dlt_normal_pairs, estimate, estimate_affine, estimate_projective,
                                            estimate_umeyama)

DECIMAL_7 = 1.5e-7  # numpy's assert_almost_equal default, scikit-image's check: |a - b| < 1.5 x 10^-7


def _align_vectors(a, b, weights=None) -> np.ndarray:
    """The rotation R that turns the vectors ``b`` (N, 3) onto ``a`` (Wahba's problem, scipy's align_vectors), from
    pcreg's rigid closed form: each vector and its negative as a pair of points, so that both sets are centred
    on the origin and Umeyama's Σ is scipy's B = Σ w a bᵀ (up to the positive factor 1 / Σ w)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=np.float64)
    T = estimate_umeyama(np.vstack([b, -b]), np.vstack([a, -a]), np.r_[w, w], with_scale=False)
    np.testing.assert_allclose(T[:3, 3], 0.0, atol=1e-14 * max(1.0, float(np.abs(a).max())))
    return T[:3, :3]


def _rssd(R, a, b, weights=None) -> float:
    w = np.ones(len(a)) if weights is None else np.asarray(weights)
    return float(np.sqrt(w @ np.sum((np.asarray(b) @ R.T - np.asarray(a)) ** 2, axis=1)))


# ---------------------------------------------------------------------------------------------------
# scipy/scipy scipy/spatial/transform/tests/test_rotation.py, test_align_vectors_*
# ---------------------------------------------------------------------------------------------------

def test_scipy_align_vectors_no_rotation_no_noise_and_improper_case():
    """test_align_vectors_no_rotation (the identity to 1e-12), test_align_vectors_no_noise (five vectors turned by
    their seed's rotation: its quaternion, rssd 0) and test_align_vectors_improper_rotation (scipy #10444: two vectors
    whose SVD has det(U) det(V) = -1; the fit must still be a rotation that maps y onto x, to their 1e-6)."""
    x = np.array([[1.0, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(_align_vectors(x, x), np.eye(3), atol=1e-12)
    rng = np.random.default_rng(14697284569885399755764481408308808739)
    c = Rotation.random(rng=rng)
    b = rng.normal(size=(5, 3))
    R = _align_vectors(c.apply(b), b)
    est = Rotation.from_matrix(R).as_quat()
    np.testing.assert_allclose(est * np.sign(est @ c.as_quat()), c.as_quat(), rtol=1e-7)
    assert _rssd(R, c.apply(b), b) < 1e-7
    x = np.array([[0.89299824, -0.44372674, 0.0752378], [0.60221789, -0.47564102, -0.6411702]])
    y = np.array([[0.02386536, -0.82176463, 0.5693271], [-0.27654929, -0.95191427, -0.1318321]])
    R = _align_vectors(x, y)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(y @ R.T, x, atol=1e-6)
    assert _rssd(R, x, y) < 1e-7


def test_scipy_align_vectors_rssd_and_scaled_weights():
    """test_align_vectors_rssd_sensitivity (rssd 0.141421356237308 to 1e-6; pcreg gives no sensitivity matrix) and
    test_align_vectors_scaled_weights (ten unrelated unit vectors: weights times 2 give the same rotation, the rssd
    times sqrt 2)."""
    a = np.array([[0.0, 1, 0], [0, 1, 1], [0, 1, 1]])
    b = np.array([[1.0, 0, 0], [1, 1.1, 0], [1, 0.9, 0]])
    assert _rssd(_align_vectors(a, b), a, b) == pytest.approx(0.141421356237308, abs=1e-6)
    a = Rotation.random(10, rng=0).apply([1, 0, 0])
    b = Rotation.random(10, rng=1).apply([1, 0, 0])
    R1, R2 = _align_vectors(a, b, np.ones(10)), _align_vectors(a, b, 2 * np.ones(10))
    np.testing.assert_allclose(R1, R2, atol=1e-12)
    assert np.sqrt(2) * _rssd(R1, a, b) == pytest.approx(_rssd(R2, a, b, 2 * np.ones(10)), abs=1e-6)


def test_scipy_align_vectors_noise():
    """test_align_vectors_noise: 100 vectors turned by their seed's rotation, each then by its own random turn of
    sigma 1 degree (Markley's attitude noise): every component of the error's rotation vector within 1.5 sigma."""
    rng = np.random.default_rng(146972845698875399755764481408308808739)
    rot = Rotation.random(rng=rng)
    vectors = rng.normal(size=(100, 3))
    sigma = np.deg2rad(1)
    noisy = Rotation.from_rotvec(rng.normal(size=(100, 3), scale=sigma)).apply(rot.apply(vectors))
    est = Rotation.from_matrix(_align_vectors(noisy, vectors))
    np.testing.assert_allclose((rot * est.inv()).as_rotvec(), 0.0, atol=1.5 * sigma)


def test_scipy_align_vectors_primary_only_and_parallel_take_the_least_rotation():
    """test_align_vectors_primary_only (one pair of random unit vectors, 100 times: R b = a to 1e-12) and
    test_align_vectors_parallel (b = y onto a = x gives their [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], the least
    rotation; b = a the identity). One pair fixes one direction only (Σ of rank 1), and scipy and pcreg both
    take the rotation of least angle (pcreg's ``_least_rotation``); the 2-D closed form (atan2) does the same."""
    for mat_a, mat_b in zip(Rotation.random(100, rng=0).as_matrix(), Rotation.random(100, rng=1).as_matrix()):
        a, b = mat_a[0], mat_b[0]
        R = _align_vectors(a[None], b[None])
        np.testing.assert_allclose(R @ b, a, atol=1e-12)
        assert Rotation.from_matrix(R).magnitude() == pytest.approx(np.arccos(np.clip(a @ b, -1, 1)), abs=1e-9)
        a2, b2 = a[:2] / np.linalg.norm(a[:2]), b[:2] / np.linalg.norm(b[:2])
        T2 = estimate_umeyama(np.array([b2, -b2]), np.array([a2, -a2]), np.ones(2), with_scale=False)
        np.testing.assert_allclose(T2[:2, :2] @ b2, a2, atol=1e-12)
    x, y = np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    np.testing.assert_allclose(_align_vectors(x[None], y[None]), [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(_align_vectors(x[None], x[None]), np.eye(3), atol=1e-12)


def test_scipy_align_vectors_antiparallel_is_a_half_turn():
    """test_align_vectors_antiparallel: a primary vector and its negative (with a secondary vector, weight 1e10 for
    scipy's infinity, and alone): a turn of pi that maps b[0] onto a[0] to 1e-12; and primaries 1e-4 rad short of
    antiparallel, where scipy's answer with an infinite weight is pcreg's with 1e10 to 1e-12 (their tolerance)."""
    for a in np.array([[[1.0, 0, 0], [0, 1, 0]], [[0, 1, 0], [1, 0, 0]], [[0, 0, 1], [0, 1, 0]]]):
        b = np.array([-a[0], a[1]])
        for R in (_align_vectors(a, b, [1e10, 1]), _align_vectors(a[:1], b[:1])):
            assert Rotation.from_matrix(R).magnitude() == pytest.approx(np.pi, abs=1e-12)
            np.testing.assert_allclose(R @ b[0], a[0], atol=1e-12)
    b = np.array([[-1.0, 0, 0], [0, 1, 0]])
    for dR in Rotation.from_rotvec(Rotation.random(100, rng=0).as_rotvec() * 1e-4):
        a = np.array([dR.apply([1.0, 0, 0]), [0, 1, 0]])
        theirs, _ = Rotation.align_vectors(a, b, weights=[np.inf, 1])
        np.testing.assert_allclose(_align_vectors(a, b, [1e10, 1]), theirs.as_matrix(), atol=1e-12)


def test_scipy_align_vectors_a_heavy_primary_is_met_as_their_constrained_fit():
    """test_align_vectors_align_constrain (weight infinity for the primary; 1e10 here, as their
    test_align_vectors_near_inf): their matrix [[0, 0, 1], [1, 0, 0], [0, 1, 0]] with rssd 0, then 1.0 for an inexact
    secondary, then rssd 1.3101595297515016 for their random pair; and test_align_vectors_near_inf: 100 random pairs
    and triples with weights (1e10, 1) and (1e10, 2, 1) against scipy's infinite weight, within their 1e-4."""
    a = np.array([[0.0, 1, 0], [0, 1, 1]])
    expected = np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])
    for b, rssd in ((np.array([[1.0, 0, 0], [1, 1, 0]]), 0.0), (np.array([[1.0, 0, 0], [1, 2, 0]]), 1.0)):
        R = _align_vectors(a, b, [1e10, 1])
        np.testing.assert_allclose(R, expected, atol=1e-9)
        assert _rssd(R, a[1:], b[1:]) == pytest.approx(rssd, abs=1e-9)
    a, b = np.array([[-1.0, 3, 2], [1, -1, 2]]), np.array([[1.0, 2, 3], [-2, 3, -1]])
    R = _align_vectors(a, b, [1e10, 1])
    np.testing.assert_allclose(R @ b[0], a[0], atol=1e-9)
    assert _rssd(R, a[1:], b[1:]) == pytest.approx(1.3101595297515016, abs=1e-9)
    mats = [Rotation.random(100, rng=10 + i).as_matrix() for i in range(6)]
    for i in range(100):
        for k, weights in ((2, [1e10, 1]), (3, [1e10, 2, 1])):
            a = np.array([(j + 1) * mats[j][i][0] for j in range(k)])
            b = np.array([(j + k + 1) * mats[j + k][i][0] for j in range(k)])
            theirs, _ = Rotation.align_vectors(a, b, weights=[np.inf, *weights[1:]])
            np.testing.assert_allclose(_align_vectors(a, b, weights), theirs.as_matrix(), atol=1e-4)


def test_scipy_zero_length_vectors_fix_no_rotation():
    """test_align_vectors_invalid_input, "Cannot align zero length primary vectors": scipy's fit raises. pcreg's
    closed form is the ICP's step, which pairs that fix no direction leave where it is (Σ = 0: no rotation, by
    design, as the least rotation that fits); the registration itself refuses such points (pcreg.icp)."""
    np.testing.assert_array_equal(_align_vectors([[1.0, 2, 3]], [[0.0, 0, 0]]), np.eye(3))
    with pytest.raises(RegistrationError, match="coincident"):
        pcreg.icp(np.zeros((4, 3)), np.eye(3), ICPOptions())


# ---------------------------------------------------------------------------------------------------
# scikit-image/scikit-image tests/skimage/transform/test_geometric.py
# ---------------------------------------------------------------------------------------------------

SRC = np.array([[-12.3705, -10.5075], [-10.7865, 15.4305], [8.6985, 10.8675], [11.4975, -9.5715],
                [7.8435, 7.4835], [-5.3325, 6.5025], [6.7905, -6.3765], [-6.1695, -0.8235]])
DST = np.array([[0, 0], [0, 5800], [4900, 5800], [4900, 0], [4479, 4580], [1176, 3660], [3754, 790], [1024, 1931]],
               dtype=np.float64)


def _ssq(T, src, dst) -> float:
    return float(np.sum((tf.apply(T, src) - dst) ** 2))


def _assert_least_squares(T, src, dst, entries) -> None:
    """Their _assert_least_squares: each of the matrix's ``entries`` moved by +-0.001 raises the sum of squares."""
    baseline = _ssq(T, src, dst)
    for i, update in itertools.product(entries, (0.001, -0.001)):
        moved = T.copy()
        moved.flat[i] += update
        assert _ssq(moved, src, dst) > baseline


@pytest.mark.parametrize("model, k", [("rigid", 2), ("similarity", 2), ("affine", 3), ("projective", 4)])
def test_skimage_estimation_exact_from_the_fewest_points_and_over_determined(model, k):
    """test_euclidean_estimation (SRC[:2] onto SRC[:2] + 10), test_similarity_estimation (SRC[:2] onto DST[:2]),
    test_affine_estimation (3 points), test_projective_estimation (4 points): the fewest pairs a model takes are
    met exactly (to their 7 decimals on coordinates up to 5800); over-determined (all 8 pairs of SRC onto DST), the
    fit is invertible (inverse(T(SRC)) = SRC), rigid and similarity keep a rotation times a scale. With exactly 4
    pairs the homography's DLT matrix is 8 x 9 and pcreg's reduced SVD left out its null vector: the "fit" missed
    the points by 4700."""
    dst = SRC[:2] + 10 if model == "rigid" else DST[:k]
    np.testing.assert_allclose(tf.apply(estimate(SRC[:k], dst, np.ones(k), model), SRC[:k]), dst, atol=1e-9)
    T = estimate(SRC, DST, np.ones(8), model)
    np.testing.assert_allclose(tf.apply(np.linalg.inv(T), tf.apply(T, SRC)), SRC, atol=DECIMAL_7)
    if model in ("rigid", "similarity"):
        assert T[0, 0] == pytest.approx(T[1, 1], abs=DECIMAL_7) and T[0, 1] == pytest.approx(-T[1, 0], abs=DECIMAL_7)


def test_skimage_over_determined_fits_are_least_squares():
    """Their _assert_least_squares (test_estimate_affine_3d) on SRC onto DST: every entry of the affine fit moved by
    +-0.001 raises the sum of squares; for rigid and similarity, their parameters (angle, scale, shift) moved so.
    (Not for the homography: the DLT minimises an algebraic error, as scikit-image's, which they do not test so.)"""
    _assert_least_squares(estimate_affine(SRC, DST, np.ones(8)), SRC, DST, range(6))
    for scale in (False, True):
        T = estimate_umeyama(SRC, DST, np.ones(8), with_scale=scale)
        c, angle = np.sqrt(np.linalg.det(T[:2, :2])), np.degrees(np.arctan2(T[1, 0], T[0, 0]))
        baseline = _ssq(T, SRC, DST)
        for dc, da, dx, dy in np.vstack([np.eye(4), -np.eye(4)])[:, :] * 1e-3:
            if dc and not scale:
                continue
            moved = tf.rigid2d(angle + np.degrees(da), T[0, 2] + dx, T[1, 2] + dy, scale=c + dc)
            assert _ssq(moved, SRC, DST) > baseline


@pytest.mark.parametrize("with_scale", [False, True])
def test_skimage_3d_euclidean_and_similarity_estimation(with_scale):
    """test_3d_euclidean_similarity_estimation: 1000 points of their seed, turned by intrinsic XYZ Euler angles,
    scaled by randint(0, 20) (4 with their seed), shifted: rotation, scale and translation to 7 decimals."""
    rng = np.random.RandomState(1832148575)
    src = rng.rand(1000, 3)
    M = Rotation.from_euler("XYZ", rng.random((3,)) * 2 * np.pi - np.pi).as_matrix()
    scale = rng.randint(0, 20)
    assert scale == 4
    M = M * scale if with_scale else M
    t = rng.random((3,))
    T = estimate_umeyama(src, src @ M.T + t, np.ones(1000), with_scale=with_scale)
    np.testing.assert_allclose(T[:3, :3], M, atol=DECIMAL_7)
    np.testing.assert_allclose(T[:3, 3], t, atol=DECIMAL_7)


def test_skimage_estimate_affine_3d_with_noise():
    """test_estimate_affine_3d: 25 points spread 2^7..2^9 along the axes, their matrix, noise U(0, 1): the linear
    part to 2 decimals, the translation to 0 decimals, and least squares."""
    rng = np.random.RandomState(4284506661)
    src = rng.random((25, 3)) * 2 ** np.arange(7, 10)
    M = np.array([[4.8, 0.1, 0.2, 25], [0.0, 1.0, 0.1, 30], [0.0, 0.0, 1.0, -2], [0.0, 0.0, 0.0, 1.0]])
    noisy = tf.apply(M, src) + rng.random((25, 3))
    T = estimate_affine(src, noisy, np.ones(25))
    np.testing.assert_allclose(T[:, :-1], M[:, :-1], atol=1.5e-2)
    np.testing.assert_allclose(T[:, -1], M[:, -1], atol=1.5)
    _assert_least_squares(T, src, noisy, range(12))


def test_skimage_projective_weighted_estimation():
    """test_projective_weighted_estimation: weights of one give the unweighted fit (4 and 8 pairs); a repeated point
    of weight 1e-15 changes the over-determined fit by less than 3 decimals."""
    for k in (4, 8):
        np.testing.assert_allclose(estimate_projective(SRC[:k], DST[:k], np.ones(k)),
                                   estimate_projective(SRC[:k], DST[:k], 2 * np.ones(k)), atol=DECIMAL_7)
    weights = np.ones(9)
    weights[0] = 1e-15
    again = np.arange(-1, 8)
    np.testing.assert_allclose(estimate_projective(SRC[again], DST[again], weights),
                               estimate_projective(SRC, DST, np.ones(8)), atol=1.5e-3)


def test_a_projective_icp_of_four_points_meets_them():
    """The same four-pair DLT inside the ICP: four corners of a square and their image by a homography, paired
    correctly from the identity. Its step missed them and the run shrank the source onto two target points, which
    pcreg then refused; now one step lands on the homography."""
    src = np.array([[0.0, 0], [10, 0], [10, 10], [0, 10]])
    H = np.array([[1.02, 0.01, 0.3], [-0.01, 0.99, -0.2], [1e-3, -5e-4, 1.0]])
    for weights in ("none", "huber"):
        r = pcreg.icp(src, tf.apply(H, src), ICPOptions(model="projective", weights=weights))
        np.testing.assert_allclose(r.matrix, H, atol=1e-12)
        assert r.converged and r.fitness == 1.0


@pytest.mark.parametrize("d", [2, 3])
def test_skimage_identity(d):
    """test_identity: ten normal points of their seed onto themselves give the identity for every model."""
    src = np.random.RandomState(3083558688).randn(10, d)
    for model in ("translation", "rigid", "similarity", "affine", "projective")[:5 if d == 2 else 4]:
        np.testing.assert_allclose(estimate(src, src, np.ones(10), model), np.eye(d + 1), atol=1e-12)


def test_skimage_degenerate_points_are_refused():
    """test_degenerate (ten points all at the origin: every model's estimation fails) and test_degenerate_2 (four
    random points whose y is one value, a line: the homography fails, 20 times). pcreg's registration refuses such
    points for every model, and its homography step raises rather than return a matrix; scikit-image also returns a
    (minimum-norm) affine from two points, where pcreg's registration refuses too few points (contract differs: a
    fit the points do not determine is not returned)."""
    zeros = np.zeros((10, 2))
    for model in ("rigid", "similarity", "affine", "projective"):
        with pytest.raises(RegistrationError, match="coincident"):
            pcreg.icp(zeros, zeros, ICPOptions(model=model))
    for model in ("similarity", "projective"):
        with pytest.raises(RegistrationError, match="degenerate"):
            estimate(zeros, zeros, np.ones(10), model)
    rng = np.random.RandomState(1286963959)
    for _ in range(20):
        src, dst = rng.rand(4, 2) * 100, rng.rand(4, 2) * 100
        src[:, 1] = rng.rand()
        for solve in ("svd", "normal"):
            with pytest.raises(RegistrationError, match="degenerate homography"):
                estimate_projective(src, dst, np.ones(4), solve=solve)
        assert _dlt_normal_pairs(src, dst, np.arange(4), np.ones(4))[1] == 4  # the compiled ICP's step
        with pytest.raises(RegistrationError, match="collinear"):
            pcreg.icp(src, dst, ICPOptions(model="projective"))
    for model, k in (("affine", 2), ("projective", 3)):
        with pytest.raises(RegistrationError, match="too few"):
            pcreg.icp(SRC[:k], DST[:k], ICPOptions(model=model))


# ---------------------------------------------------------------------------------------------------
# mikedh/trimesh tests/test_registration.py
# ---------------------------------------------------------------------------------------------------

def _random_motion(rng) -> np.ndarray:
    """As their g.random_transforms: a random rotation and a translation."""
    M = np.eye(4)
    M[:3, :3] = Rotation.random(rng=rng).as_matrix()
    M[:3, 3] = (rng.random(3) - 0.5) * 1000
    return M


@pytest.mark.parametrize("scale, a_flip, a_scale, weight", list(itertools.product([False, True], repeat=4)))
def test_trimesh_procrustes_every_option(scale, a_flip, a_scale, weight):
    """test_procrustes: 1000 points in [-500, 500]^3 moved by a random motion, then mirrored in y (a_flip) and/or
    scaled by 0.1235234 (a_scale), fitted with or without a scale, with weights of one on every third point or
    none: where the model can hold the motion (no mirror; no scale or a scale fitted) it is found; the determinant
    is positive always (pcreg never mirrors: their reflection=False) and 1 without a scale; all-ones weights and
    no weights give the same fit (pcreg's weights of 2 stand for "None")."""
    rng = np.random.default_rng(8 * scale + 4 * a_flip + 2 * a_scale + weight)
    a = (rng.random((1000, 3)) - 0.5) * 1000
    M = _random_motion(rng)
    if a_flip:
        M = M @ np.diag([1.0, -1.0, 1.0, 1.0])
    if a_scale:
        M = M @ np.diag([0.1235234] * 3 + [1.0])
    b = tf.apply(M, a)
    w = np.ones(len(a))
    if weight:
        w = np.zeros(len(a))
        w[::3] = 1.0
    T = estimate_umeyama(a, b, w, with_scale=scale)
    if not weight:
        np.testing.assert_allclose(estimate_umeyama(a, b, 2 * w, with_scale=scale), T, atol=1e-9)
    if not a_flip and (not a_scale or scale):
        np.testing.assert_allclose(T, M, atol=1e-9)
        assert w @ np.sum((tf.apply(T, a) - b) ** 2, axis=1) / w.sum() < 0.001
    det = np.linalg.det(T[:3, :3])
    assert det > 1e-8
    if not scale:
        assert det == pytest.approx(1.0)


def test_trimesh_procrustes_float_weights():
    """test_procrustes_float_weights: a unit box's 8 corners, the same in both clouds, followed by unrelated points
    (theirs: featuretype.STL's and rabbit.obj's vertices; 500 uniform ones each here), b turned 0.456456 rad about
    (0.14586, 2.0, 0.8946513) through (100.1456, 51456.123, 447.2): weights on the corners alone, of one or of
    (0, 1, ..., 7) / 7, give their motion; no weights do not."""
    rng = np.random.default_rng(7)
    box = np.array(list(itertools.product([-0.5, 0.5], repeat=3)))
    a, b = np.vstack([box, rng.random((500, 3))]), np.vstack([box, rng.random((500, 3)) * 3])
    axis = np.array([0.14586, 2.0, 0.8946513])
    R = np.eye(4)
    R[:3, :3] = Rotation.from_rotvec(0.456456 * axis / np.linalg.norm(axis)).as_matrix()
    M = tf.about_point(R, (100.1456, 51456.123, 447.2))
    b = tf.apply(M, b)
    for corners in (np.ones(8), np.arange(8) / 7.0):
        w = np.r_[corners, np.zeros(500)]
        np.testing.assert_allclose(estimate_umeyama(a, b, w, with_scale=False), M, atol=1e-8)
        np.testing.assert_allclose(estimate_umeyama(a, b, w, with_scale=True), M, atol=1e-8)
    assert not np.allclose(estimate_umeyama(a, b, np.ones(len(a)), with_scale=False), M)


def test_trimesh_procrustes_scale_is_the_least_squares_one_not_the_ratio_of_spreads():
    """Contract differs by design: trimesh's procrustes scales by the ratio of the clouds' RMS spreads (and its
    weighted rotation "won't yield the optimal rotation", their docstring); pcreg's is Umeyama's least-squares fit
    (c = tr(DS) / sigma_p^2, Eq. 42), whose weighted residual is the smallest. On noisy, non-uniformly weighted
    pairs pcreg's fit has a smaller weighted residual than the spread ratio with pcreg's rotation, and its scale is
    below the ratio (Cauchy-Schwarz); without noise both are the motion's."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(200, 3)) * [3.0, 2.0, 1.0]
    M = _random_motion(rng) @ np.diag([1.7] * 3 + [1.0])
    b = tf.apply(M, a) + rng.normal(size=a.shape) * 2.0
    w = rng.random(200)
    T = estimate_umeyama(a, b, w, with_scale=True)
    mean = lambda p: w @ p / w.sum()  # noqa: E731
    spread = lambda p: np.sqrt(w @ np.sum((p - mean(p)) ** 2, axis=1) / w.sum())  # noqa: E731
    c = np.cbrt(np.linalg.det(T[:3, :3]))
    ratio = T.copy()
    ratio[:3, :3] *= spread(b) / spread(a) / c
    ratio[:3, 3] = mean(b) - ratio[:3, :3] @ mean(a)
    cost = lambda T_: float(w @ np.sum((tf.apply(T_, a) - b) ** 2, axis=1))  # noqa: E731
    assert c < spread(b) / spread(a) and cost(T) < cost(ratio)
    for scaled in (1.001, 0.999):
        moved = T.copy()
        moved[:3, :3] *= scaled
        moved[:3, 3] = mean(b) - moved[:3, :3] @ mean(a)
        assert cost(moved) > cost(T)


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_trimesh_icp_points(backend):
    """test_icp_points: 1000 points in [-500, 500]^3; 20 of them drawn with repeats, in another order, turned 1
    degree about z: ICP of the 20 onto the 1000 gives a cost below 1e-3 and the inverse of the turn (np.allclose),
    and moves each of the 20 onto its point."""
    rng = np.random.default_rng(0)
    a = (rng.random((1000, 3)) - 0.5) * 1000
    M = np.eye(4)
    M[:3, :3] = Rotation.from_rotvec([0.0, 0.0, np.radians(1.0)]).as_matrix()
    index = rng.choice(np.arange(len(a)), 20)
    r = pcreg.icp(tf.apply(M, a[index]), a, ICPOptions(backend=backend))
    assert r.inlier_rmse ** 2 < 1e-3 and r.fitness == 1.0
    np.testing.assert_allclose(np.linalg.inv(r.matrix), M, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(tf.apply(r.matrix, tf.apply(M, a[index])), a[index], rtol=1e-5, atol=1e-8)


def _box_surface(n_side: int) -> np.ndarray:
    """A unit box's six faces, each an n_side x n_side grid (edges shared once)."""
    g = np.linspace(-0.5, 0.5, n_side)
    u, v = (x.ravel() for x in np.meshgrid(g, g))
    faces = []
    for axis, side in itertools.product(range(3), (-0.5, 0.5)):
        face = np.empty((u.size, 3))
        face[:, axis], face[:, (axis + 1) % 3], face[:, (axis + 2) % 3] = side, u, v
        faces.append(face)
    return np.unique(np.vstack(faces), axis=0)


@pytest.mark.parametrize("seed", range(5))
def test_trimesh_icp_mesh_ten_points_onto_a_box(seed):
    """test_icp_mesh: 10 points sampled on a unit box, moved by (0.1, 0.1, 0.1), ICP onto the box: cost (the
    mean squared distance) below 0.01. The box's surface is a 51 x 51 grid per face here (pcreg takes clouds)."""
    box = _box_surface(51)
    X = box[np.random.default_rng(seed).choice(len(box), 10, replace=False)] + 0.1
    r = pcreg.icp(X, box, ICPOptions())
    assert r.fitness == 1.0 and r.inlier_rmse ** 2 < 0.01


# ---------------------------------------------------------------------------------------------------
# opencv/opencv modules/calib3d/test/test_affine_partial2d_estimator.cpp and test_affine2d_estimator.cpp
# ---------------------------------------------------------------------------------------------------

def test_opencv_partial_affine_from_two_points_and_affine_from_three():
    """EstimateAffinePartial2D test2Points (500 similarities, angle in [0, 2 pi), scale in [0, 3), shift in
    [-2, 2]^2, from the points (U(1, 2), U(5, 6)) and (U(3, 4), U(3, 4))) and EstimateAffine2D test3Points (500
    affines with entries in [1, 3), a third point (U(1, 2), U(3, 4))): the motion to their 1e-3 (float32 points
    there; 1e-9 here in float64). Their testNPoints is RANSAC's and LMedS's outlier rejection, which pcreg's closed
    forms do not do (its global search calls OpenCV's own for it)."""
    rng = np.random.default_rng(11)
    for _ in range(500):
        angle, scale = rng.uniform(0, 360), rng.uniform(0, 3)
        similarity = tf.rigid2d(angle, *rng.uniform(-2, 2, 2), scale=scale)
        affine = np.vstack([rng.uniform(1, 3, (2, 3)), [0, 0, 1]])
        src = np.array([[rng.uniform(1, 2), rng.uniform(5, 6)], [rng.uniform(3, 4), rng.uniform(3, 4)],
                        [rng.uniform(1, 2), rng.uniform(3, 4)]])
        np.testing.assert_allclose(estimate_umeyama(src[:2], tf.apply(similarity, src[:2]), np.ones(2), with_scale=True),
                                   similarity, atol=1e-9)
        np.testing.assert_allclose(estimate_affine(src, tf.apply(affine, src), np.ones(3)), affine, atol=1e-9)
