"""Other nearest-neighbour searches' own test cases, run through pcreg's exact searches (the KD-tree
:class:`~pcreg.registration.kdtree.KDTreeIndex` of the reference ICP, and the grid
:class:`~pcreg.registration.nn.GridIndex` kept as its baseline), with the answers of a brute-force search or of
scipy's cKDTree; and pycpd's rigid cases through pcreg's cross-check. Sources:

- scipy/scipy at 3dbf660a919b1479cdf30d533176053b428d08d3, scipy/spatial/tests/test_kdtree.py;
- jlblancoc/nanoflann at 7812aa08260b6971af2230b1ac446d54f7939822, tests/test_kdtree_basic.cpp and the checks in
  tests/test_helpers.h (tests/test_main.cpp holds only gtest's main there);
- siavashk/pycpd at e5ca02d2501fb4b633c1664de939c336ffa2349e, testing/rigid_test.py on data/fish_target.txt
  (checked in under tests/data/pycpd).

Each test names the case it mirrors. pcreg's searches answer k=1 queries in 2-D and 3-D, Euclidean only; where
the others take other options (k > 1, L1 and L-infinity, ball and box queries, trees of any dimension) the case
is ported where it applies and the refusal is checked where pcreg refuses. Where pcreg differs by design it is
said so: an empty index is refused (scipy and nanoflann answer "no neighbour"), a NaN query has no neighbour
(scipy refuses it), the distance bound is strict (nanoflann's radius search counts d^2 <= r^2), and ties go to
the lowest index."""

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

import pcreg
from pcreg import ICPOptions
from pcreg.errors import InputError
from pcreg.implementations.crosscheck import crosscheck_implementations
from pcreg.registration.kdtree import KDTreeIndex
from pcreg.registration.nn import GridIndex

INDEXES = [KDTreeIndex, GridIndex]
FISH = Path(__file__).parent / "data" / "pycpd" / "fish_target.txt"
CUBE = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 1], [1, 0, 0], [1, 0, 1], [1, 1, 0], [1, 1, 1]], float)


def brute_force(q: np.ndarray, data: np.ndarray, bound: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """(squared distance, index) of each query's nearest point with d^2 < bound^2, ties to the lowest index,
    (bound^2, -1) where none; distances summed axis by axis as the searches do."""
    d2 = np.zeros((len(q), len(data)))
    with np.errstate(over="ignore"):  # squares beyond float range are inf, as in the searches
        for a in range(data.shape[1]):
            diff = q[:, None, a] - data[None, :, a]
            d2 = d2 + diff * diff
    best = d2.min(axis=1)
    inside = best < bound * bound
    return np.where(inside, best, bound * bound), np.where(inside, np.argmax(d2 == best[:, None], axis=1), -1)


def _assert_brute_force(index, q, data, bound=np.inf):
    want_d2, want_i = brute_force(q, data, bound)
    for workers in (1, 2):
        d2, idx = index.nearest(q, bound, workers=workers)
        np.testing.assert_array_equal(idx, want_i)
        np.testing.assert_array_equal(d2, want_d2)


# --- scipy test_kdtree.py --------------------------------------------------------------------------------------

@pytest.mark.parametrize("index_type", INDEXES)
@pytest.mark.parametrize("m", [2, 3])
@pytest.mark.parametrize("far", [False, True])
def test_scipy_random_and_random_far_nearest_and_points_near(index_type, m, far):
    """_Test_random / _Test_random_far (100 normal points, leafsize 2; the query normal, or shifted by 10):
    test_nearest (no point nearer than the answer) and test_points_near (bound d = 0.2). scipy's cases are
    4-D; here 2-D and 3-D, with many queries instead of one."""
    rng = np.random.RandomState(1234)
    data = rng.randn(100, m)
    x = rng.randn(200, m) + (10.0 if far else 0.0)
    index = index_type(data, leaf=2) if index_type is KDTreeIndex else index_type(data)
    for bound in (0.2, np.inf):
        _assert_brute_force(index, x, data, bound)
    dist, idx = index.query(x)
    np.testing.assert_allclose(dist ** 2, np.sum((x - data[idx]) ** 2, axis=1), rtol=1e-12)
    assert np.all(np.sum((data[None] - x[:, None]) ** 2, axis=2) > dist[:, None] ** 2 - 1e-8)  # scipy's eps


@pytest.mark.parametrize("leaf", [1, 24])
def test_scipy_small_and_small_nonleaf(leaf):
    """_Test_small / _Test_small_nonleaf (the unit cube's corners; leafsize default, and 1): the query
    (0, 0, 0.1) gives (0.1, 0); points near a normal query within 0.5. (Their k=2 case: see k refused below.)"""
    index = KDTreeIndex(CUBE, leaf=leaf)
    dist, idx = index.query((0, 0, 0.1), 1)
    assert (dist, idx) == (pytest.approx(0.1, rel=1e-15), 0)
    x = np.random.RandomState(1234).randn(50, 3)
    _assert_brute_force(index, x, CUBE, 0.5)
    _assert_brute_force(GridIndex(CUBE), x, CUBE, 0.5)


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_minkowski_norms_other_than_2_are_refused_and_eps_is_met(index_type):
    """test_points_near_l1 / test_points_near_linf and test_approx: pcreg searches Euclidean distances only,
    so p=1 and p=inf are refused (they were answered with Euclidean distances, unasked); eps=0.1 allows an answer
    up to 1.1 times the nearest, and the exact answer is given."""
    rng = np.random.RandomState(1234)
    data = rng.randn(100, 3)
    index = index_type(data)
    x = rng.randn(3)
    for p in (1, np.inf, 3):
        with pytest.raises(ValueError, match=r"Euclidean distances \(p=2\) only"):
            index.query(x, p=p, distance_upper_bound=0.2)
    assert index.query(x, p=2) == cKDTree(data).query(x, p=2)
    d_real, i_real = index.query(x)
    d, i = index.query(x, eps=0.1)
    assert d <= d_real * 1.1 and (d, i) == (d_real, i_real)
    with pytest.raises(TypeError):
        index.query(x, distance_upper_bond=0.2)  # a misspelt option is an error, not an unbounded search


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_vectorization_shapes_and_k(index_type):
    """Test_vectorization_cKDTree: a single query gives a float and an integer; queries (2, 4, 3) and k = n + 23
    are cKDTree's, refused here with what pcreg answers instead ((K, d) queries, k = 1); non-contiguous queries
    answer as one at a time. test_kdtree_list_k: k = [1] is refused too."""
    index = index_type(CUBE)
    d, i = index.query([0, 0, 0])
    assert isinstance(d, float) and isinstance(i, np.integer) and (d, i) == (0.0, 0)
    with pytest.raises(ValueError, match=r"queries must be \(K, 3\), got shape \(2, 4, 3\)"):
        index.query(np.zeros((2, 4, 3)))
    for k in (len(CUBE) + 23, 2, [1]):
        with pytest.raises(ValueError, match="k=1 queries only"):
            index.query([0, 0, 0], k=k)
    qs = np.random.RandomState(1234).randn(3, 1000).T
    assert not qs.flags.c_contiguous
    ds, i_s = index.query(qs)
    for q, d, i in zip(qs[:100], ds, i_s):
        assert index.query(q) == (d, i)
    want_d, want_i = cKDTree(CUBE).query(qs)
    np.testing.assert_array_equal(i_s, want_i)
    np.testing.assert_allclose(ds, want_d, rtol=1e-15)


def test_scipy_build_modes_give_the_same_answers():
    """test_kdtree_build_modes (balanced or not, compact or not: the same 5 neighbours): here every leaf size,
    one point a leaf to all in one, gives the brute-force answers (scipy's 5000 4-D normal points, in 3-D)."""
    rng = np.random.RandomState(0)
    points = rng.randn(5000, 3)
    q = np.concatenate([points[:300], rng.randn(300, 3)])
    want = brute_force(q, points)
    for leaf in (1, 2, 24, 5000):
        np.testing.assert_array_equal(KDTreeIndex(points, leaf=leaf).nearest(q)[1], want[1])


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_copy_data_an_index_ignores_later_changes_to_its_points(index_type):
    """test_kdtree_copy_data: the index answers the same after the caller overwrites the array it was built
    from. The searches kept their own sorted copy, but the ICP step's moments (:meth:`move_and_match`) read the
    caller's array: overwritten, they summed the new coordinates with the old neighbours."""
    rng = np.random.RandomState(0)
    points = rng.randn(500, 3)
    index = index_type(points)
    q = np.ascontiguousarray(points[:200] + 0.01)
    before_nn = index.nearest(q, 0.5)
    before = index.move_and_match(q.copy(), None, 0.5)
    points[...] = rng.randn(500, 3)
    np.testing.assert_array_equal(index.nearest(q, 0.5)[1], before_nn[1])
    after = index.move_and_match(q.copy(), None, 0.5)
    np.testing.assert_array_equal(after[1], before[1])
    for a, b in zip(after[2], before[2]):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("m", [2, 3])
def test_scipy_duplicated_inputs(m):
    """test_kdtree_duplicated_inputs: 1024 points, the first half all ones, the second all twos, leafsize 1:
    a root and two leaves. pcreg keeps each repeated point once, by its lowest index (0 and 512)."""
    n = 1024
    data = np.ones((n, m))
    data[n // 2:] = 2
    index = KDTreeIndex(data, leaf=1)
    assert len(index._nodes) == 3
    assert index.nearest(np.array([[1.1] * m, [1.9] * m, [1.5] * m]))[1].tolist() == [0, 512, 0]
    _assert_brute_force(GridIndex(data), np.random.default_rng(m).uniform(0, 3, (50, m)), data)


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_short_knn(index_type):
    """test_short_knn (gh-6425, six points two of them 0.01 from others, bound 0.2): each point's nearest is
    itself at 0; and 0.01 away points' nearest others within 0.2, found from just beside them."""
    xyz = np.array([[0., 0., 0.], [1.01, 0., 0.], [0., 1., 0.], [0., 1.01, 0.], [1., 0., 0.], [1., 1., 0.]])
    index = index_type(xyz)
    d, i = index.query(xyz, distance_upper_bound=0.2)
    np.testing.assert_array_equal(d, 0.0)
    np.testing.assert_array_equal(i, np.arange(6))
    _assert_brute_force(index, xyz + [0.004, 0.003, 0.0], xyz, 0.2)


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_empty_input_is_refused(index_type):
    """test_kdtree_empty_input (gh-5040: an empty tree answers inf): pcreg refuses an empty index, and its ICP
    an empty cloud, as bad input."""
    with pytest.raises(ValueError, match="M >= 1"):
        index_type(np.empty((0, 3)))
    with pytest.raises(InputError, match="target: the cloud is empty"):
        pcreg.icp(np.ones((2, 3)), np.empty((0, 3)))


@pytest.mark.parametrize("m", [1, 4, 7])
def test_scipy_and_nanoflann_other_dimensions_are_refused(m):
    """scipy's trees and nanoflann's take any dimension (test_kdtree_nan is 1-D, _Test_random 4-D, nanoflann's
    clouds 7-D): pcreg's indexes and its ICP take 2-D and 3-D points, and refuse others naming the shape."""
    points = np.random.default_rng(m).random((20, m))
    for index_type in INDEXES:
        with pytest.raises(ValueError, match=rf"needs an \(M, 2\|3\) array with M >= 1, got shape \(20, {m}\)"):
            index_type(points)
    with pytest.raises(InputError, match=rf"expected an \(N, 2\) or \(N, 3\) array of points, got shape \(20, {m}\)"):
        pcreg.icp(points, points)


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_complex_data_is_refused(index_type):
    """test_kdtree_complex_data (gh-9108): complex points and queries are refused; they were cut to their real
    parts with a ComplexWarning."""
    points = np.random.default_rng(0).random((10, 4)).view(complex)
    with pytest.raises(ValueError, match="points must be real coordinates, got complex"):
        index_type(points)
    index = index_type(points.real)
    for search in (index.query, index.nearest):
        with pytest.raises(ValueError, match="queries must be real coordinates, got complex"):
            search(points)
    with pytest.raises(InputError, match="not a numeric array"):
        pcreg.icp(points, points.real)


@pytest.mark.parametrize("index_type", INDEXES)
def test_scipy_nonfinite_points_are_refused_and_nonfinite_queries_have_no_neighbour(index_type):
    """test_kdtree_nan and test_nonfinite_inputs_gh_18223: a NaN among the points is refused (the grid took it
    silently, and put it in a cell of its own making); a NaN or inf query scipy refuses, pcreg answers "no
    neighbour" (the ICP refuses NaN and inf at its door)."""
    vals = [1, 5, -10, 7, -4, -16, -6, 6, 3, -11]
    data = np.column_stack([np.concatenate([vals, np.full(10, np.nan)]), np.zeros(20)])
    coords = np.random.default_rng(12345).uniform(size=(100, 3), low=0.0, high=0.1)
    index = index_type(coords)
    for bad in (np.nan, np.inf):
        broken = coords.copy()
        broken[0, :] = bad
        with pytest.raises(ValueError, match="needs finite points"):
            index_type(broken)
        with pytest.raises(ValueError, match="needs finite points"):
            index_type(data)
        d, i = index.query([bad] * 3)
        assert (d, i) == (np.inf, 100)
        with pytest.raises(InputError, match="NaN or inf"):
            pcreg.icp(broken, coords)


def test_scipy_gh_18800_array_likes():
    """test_gh_18800: points given as a list, queries as an ndarray subclass whose ``all`` is not callable (as
    pandas frames were)."""

    class ArrLike(np.ndarray):
        def __new__(cls, input_array):
            obj = np.asarray(input_array).view(cls)
            obj.all = None
            return obj

        def __array_finalize__(self, obj):
            if obj is not None:
                self.all = getattr(obj, "all", None)

    points = [[66.22, 32.54], [22.52, 22.39], [31.01, 81.21]]
    for index_type in INDEXES:
        index = index_type(points)
        np.testing.assert_array_equal(index.query(ArrLike(np.array(points)))[1], [0, 1, 2])
        assert index_type(ArrLike(np.array(points))).query([30.0, 80.0])[1] == 2


def test_scipy_large_and_tiny_coordinates_answer_as_cKDTree():
    """Coordinates whose squares leave float range: a finite query 1e155 and more away has every squared
    distance overflow to inf, and both trees answer "none" (inf, n); coordinates 1e-200 apart have squared
    distances that underflow to 0, a tie both give to the lowest index."""
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 1.0]])
    tiny = np.array([[1e-200, 0.0], [3e-200, 0.0]])
    for data, q in ((pts, [[1e155, 0.0], [1e200, 1e200], [-1e300, 5.0], [2e-160, 0.0], [2.5, 2.5]]),
                    (tiny, [[2.5e-200, 0.0], [0.0, 0.0]])):
        q = np.array(q)
        want_d, want_i = cKDTree(data).query(q)
        for index_type in INDEXES:
            got_d, got_i = index_type(data).query(q)
            np.testing.assert_array_equal(got_i, want_i)
            np.testing.assert_array_equal(got_d, want_d)



@pytest.mark.parametrize("scale", [1e300, 1e150, 5e-324, 1e-300, 1e12])
@pytest.mark.parametrize("d", [2, 3])
def test_points_spread_over_any_float_range_are_indexed(scale, d):
    """The same large- and small-coordinate cases over a cloud: points spread over 1e150 or 1e300 (their volume
    beyond float range) or over a few subnormal numbers (a volume of 0). The grid chose a cell of inf or 0 for them and
    refused its own choice ("cell size must be a positive number", a cell it was not given); it answers now.
    Points more than the largest float apart along an axis it refuses, saying so; the KD-tree takes them."""
    rng = np.random.default_rng(d)
    data = rng.integers(-50, 50, (300, d)) * scale
    q = np.concatenate([data[:50], rng.integers(-60, 60, (50, d)) * scale])
    for index_type in INDEXES:
        _assert_brute_force(index_type(data), q, data)
    far = np.array([[-1e308] + [0.0] * (d - 1), [1e308] + [0.0] * (d - 1), [0.0] * (d - 1) + [1.0]] * 20)
    with pytest.raises(ValueError, match="less than the largest float apart"):
        GridIndex(far)
    assert KDTreeIndex(far).nearest(far[:3])[1].tolist() == [0, 1, 2]


# --- nanoflann tests/test_kdtree_basic.cpp, tests/test_helpers.h ------------------------------------------------

def _nanoflann_cloud(rng, n: int, dim: int, dtype) -> np.ndarray:
    """generateRandomPointCloud: ``max_range * (rand() % 1000) / 1000`` per coordinate, max_range 20: points on
    a 0.02 lattice, so ties and repeats occur (float: the lattice rounded to float32, then searched in float64)."""
    return (20.0 * (rng.integers(0, 1000, (n, dim)) / 1000.0)).astype(dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n, dim", [(10, 2), (100, 2), (100, 3)])
def test_nanoflann_L2_vs_bruteforce(dtype, n, dim):
    """L2_vs_bruteforce (and L2_concurrent_build_vs_bruteforce's answers): 500 clouds each, a lattice query
    each; the nearest's squared distance as the brute force's (theirs within 1e-3, for float) and, on a tie, the
    lowest index. Their 7-D clouds and k = 4..19 do not apply (pcreg: 2-D, 3-D, k = 1)."""
    rng = np.random.default_rng(n * 10 + dim)
    for _ in range(50):
        cloud = _nanoflann_cloud(rng, n, dim, dtype)
        q = _nanoflann_cloud(rng, 10, dim, dtype).astype(np.float64)
        data = cloud.astype(np.float64)
        for index in (KDTreeIndex(cloud, leaf=10), GridIndex(cloud)):
            _assert_brute_force(index, q, data)


@pytest.mark.parametrize("n, dim", [(100, 2), (100, 3)])
def test_nanoflann_rknn_L2_vs_bruteforce_with_a_strict_bound(n, dim):
    """rknn_L2_vs_bruteforce: squared radii 9 r^2, r = 1..4, on the lattice clouds. nanoflann's radius counts
    d^2 <= r^2; pcreg's bound is strict (d^2 < r^2, as Open3D's hybrid search and cKDTree), which decides for
    a point exactly at the radius (none is the nearest in these clouds: the last case puts one there)."""
    rng = np.random.default_rng(dim)
    for _ in range(30):
        data = _nanoflann_cloud(rng, n, dim, np.float64)
        q = _nanoflann_cloud(rng, 10, dim, np.float64)
        for r in (1, 2, 3, 4):
            for index in (KDTreeIndex(data, leaf=10), GridIndex(data, max_distance=3.0 * r)):
                _assert_brute_force(index, q, data, 3.0 * r)
    edge = np.array([[0.0, 0.0], [3.0, 0.0]])
    for index_type in INDEXES:
        assert index_type(edge).nearest(np.array([[0.0, 3.0]]), 3.0)[1].tolist() == [-1]  # at the radius: none
        assert index_type(edge).nearest(np.array([[0.0, 3.0]]), np.nextafter(3.0, 4.0))[1].tolist() == [0]
    assert cKDTree(edge).query([0.0, 3.0], distance_upper_bound=3.0)[1] == 2


@pytest.mark.parametrize("n", [5, 100])
def test_nanoflann_L2_vs_L2_simple_two_searches_agree(n):
    """L2_vs_L2_simple_test (two adaptors on one cloud, the query (0.5, 0.5, 0.5)): here pcreg's two searches,
    the KD-tree and the grid, give the same index and the same squared distance, on nanoflann's cloud of
    coordinates in [0, 10) (PointCloud's generateRandomPointCloud), at every leaf size and cell size."""
    rng = np.random.default_rng(n)
    cloud = 10.0 * rng.integers(0, 1000, (n, 3)) / 1000.0
    q = np.vstack([[0.5, 0.5, 0.5], 10.0 * rng.random((50, 3))])
    want = KDTreeIndex(cloud).nearest(q)
    for index in (KDTreeIndex(cloud, leaf=1), KDTreeIndex(cloud, leaf=10), GridIndex(cloud),
                  GridIndex(cloud, cell=0.05), GridIndex(cloud, cell=20.0)):
        got = index.nearest(q)
        np.testing.assert_array_equal(got[1], want[1])
        np.testing.assert_array_equal(got[0], want[0])


def test_nanoflann_robust_empty_tree_and_same_points():
    """robust_empty_tree (a search on no points finds nothing): pcreg refuses the empty index instead.
    same_points (16 copies of (-1, 0, 1) build a tree): kept once, found by its lowest index."""
    for index_type in INDEXES:
        with pytest.raises(ValueError, match="M >= 1"):
            index_type(np.empty((0, 3)))
        index = index_type(np.tile([-1.0, 0.0, 1.0], (16, 1)))
        d2, idx = index.nearest(np.array([[0.5, 0.5, 0.5], [-1.0, 0.0, 1.0]]))
        assert idx.tolist() == [0, 0] and d2.tolist() == [2.25 + 0.25 + 0.25, 0.0]
    assert len(KDTreeIndex(np.tile([-1.0, 0.0, 1.0], (16, 1)))._nodes) == 1


def test_nanoflann_concurrent_build_vs_L2():
    """L2_concurrent_build_vs_L2 (a tree built on several threads answers as one built on one): here indexes
    built from four Python threads at once answer as one built alone (the compiled build holds the GIL)."""
    rng = np.random.default_rng(7)
    clouds = [_nanoflann_cloud(rng, 2000, d, np.float64) for d in (2, 3, 2, 3)]
    queries = [_nanoflann_cloud(rng, 500, c.shape[1], np.float64) for c in clouds]
    with ThreadPoolExecutor(4) as pool:
        built = list(pool.map(KDTreeIndex, clouds))
    for index, cloud, q in zip(built, clouds, queries):
        alone = KDTreeIndex(cloud).nearest(q)
        np.testing.assert_array_equal(index.nearest(q)[1], alone[1])
        np.testing.assert_array_equal(index.nearest(q)[1], brute_force(q, cloud)[1])


# --- pycpd testing/rigid_test.py -----------------------------------------------------------------------------------

def _fish(d: int) -> np.ndarray:
    fish = np.loadtxt(FISH)
    return fish if d == 2 else np.column_stack([fish, np.zeros(len(fish))])


@pytest.mark.parametrize("d", [2, 3])
def test_pycpd_rigid_fish_through_the_crosscheck(d):
    """rigid_test.py test_2D / test_3D: the fish (3-D: at z = 0) turned 30 degrees about z and shifted by
    (0.5, 1.0(, -2.0)), ``X = Y R + t`` (row vectors: the motion R^T, t); s = 1, R and t recovered to 6 decimals.
    The cross-check's pycpd row meets pycpd's test, and pcreg's reference ICP (the fish is about 2 across; pairs
    within 1, and in 3-D, shifted 2 along z, within 2.5) lands on the same motion."""
    pytest.importorskip("pycpd")
    reach = {2: 1.0, 3: 2.5}[d]
    theta = np.pi / 6.0
    R = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])[:d, :d]
    t = np.array([0.5, 1.0, -2.0])[:d]
    Y = _fish(d)
    X = Y @ R + t
    T = np.eye(d + 1)
    T[:d, :d] = R.T
    T[:d, d] = t
    report = crosscheck_implementations(Y, X, implementations=["pycpd"], options=ICPOptions(max_correspondence_distance=reach),
                                        truth=T)
    for name in ("pycpd", "reference"):
        row = report.rows[name]
        assert row["error"] is None and row["agrees"], (name, row["error"])
        np.testing.assert_array_almost_equal(row["matrix"], T)
        assert row["truth_rotation_deg"] < 1e-6 and row["truth_translation"] < 1e-6, name
    assert report.rows["pycpd"]["info"]["scale"] == pytest.approx(1.0, abs=1e-6)
