"""The compiled KD-tree answers as a brute-force search: the nearest point with d^2 < r^2, ties (repeated
points, points on a lattice equidistant from the query) to the lowest index, on one thread and two."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pcreg.registration import _kd_kernels
from pcreg.registration.kdtree import KDTreeIndex


def brute_force(q: np.ndarray, tgt: np.ndarray, bound: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lowest index at the minimum or -1, squared distance, inside) by the search's own sums."""
    dist = np.zeros((len(q), len(tgt)))
    with np.errstate(invalid="ignore", over="ignore"):
        for a in range(q.shape[1]):
            diff = q[:, None, a] - tgt[None, :, a]
            dist = dist + diff * diff
        best = np.min(np.where(np.isnan(dist), np.inf, dist), axis=1)
        inside = best < bound * bound
    return np.where(inside, np.argmax(dist == best[:, None], axis=1), -1), best, inside


def targets(kind: str, d: int, rng) -> np.ndarray:
    if kind == "uniform":
        return rng.uniform(0, 10, (3000, d))
    if kind == "crowded lattice":  # one crowded spot on a 0.01 lattice: many ties
        return np.round(rng.normal(0, 0.05, (3000, d)), 2)
    if kind == "repeats":  # 5 points, 200 copies each (a LiDAR's returns at one place), among others
        return np.concatenate([np.repeat(rng.uniform(-0.1, 0.1, (5, d)), 200, axis=0),
                               rng.uniform(-1, 1, (500, d))])[rng.permutation(1500)]
    if kind == "surface":  # a thin strip far from the origin, as georeferenced scans
        t = rng.uniform(0, 2 * np.pi, 3000)
        cols = [np.cos(t), np.sin(t)] + ([rng.uniform(0, 0.01, 3000)] if d == 3 else [])
        return np.column_stack(cols) * 50 + 1e5
    # "deep": coordinates halving towards 0 make a sliding-midpoint tree deep: the median split bounds it
    return np.concatenate([2.0 ** -np.arange(200)[:, None] * np.ones(d), rng.uniform(0, 1, (50, d))])


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("kind", ["uniform", "crowded lattice", "repeats", "surface", "deep"])
def test_same_answers_as_a_brute_force_search(d, kind):
    rng = np.random.default_rng(d * 7 + len(kind))
    tgt = targets(kind, d, rng)
    near = tgt[rng.integers(len(tgt), size=300)] + np.round(rng.normal(0, 0.06, (300, d)), 3)
    lo, hi = tgt.min(0), tgt.max(0)
    q = np.concatenate([near, tgt[:100], rng.uniform(lo - 5, hi + 5, (100, d)), [[np.nan] * d, [1e300] * d]])
    index = KDTreeIndex(tgt)
    assert index.depth <= _kd_kernels.MIDDLE_SPLIT_DEPTH + np.log2(len(tgt)) + 1
    for bound in (0.004, 0.05, 0.5, np.inf):
        want, best, inside = brute_force(q, tgt, bound)
        for workers in (1, 2):
            d2, idx = index.nearest(q, bound, workers=workers)
            np.testing.assert_array_equal(idx, want)
            np.testing.assert_array_equal(d2[inside], best[inside])
            assert np.all(d2[~inside] == bound * bound)


def test_repeated_points_are_indexed_once():
    tgt = np.concatenate([np.zeros((500, 3)), np.ones((3, 3))])
    index = KDTreeIndex(tgt)
    leaves = index._nodes[index._nodes[:, 2] < 0]
    assert (leaves[:, 1] - leaves[:, 0]).sum() == 2  # a leaf of 500 copies reads one row, of 3 copies one
    d2, idx = index.nearest(np.array([[0.1, 0.0, 0.0], [0.9, 1.0, 1.0]]), 1.0)
    assert idx.tolist() == [0, 500]


def test_the_bound_is_strict_and_answers_as_cKDTree():
    lattice = np.array([[x, y] for y in range(6) for x in range(6)], dtype=float)
    index = KDTreeIndex(lattice)
    d2, idx = index.nearest(np.array([[0.0, 0.5]]), 0.5)  # a point exactly at the bound is no neighbour
    assert idx[0] == -1 and d2[0] == 0.25
    rng = np.random.default_rng(1)
    tgt = rng.uniform(0, 10, (2000, 3))
    q = rng.uniform(-1, 11, (500, 3))
    want_d, want_i = cKDTree(tgt).query(q, k=1, distance_upper_bound=0.4)
    got_d, got_i = KDTreeIndex(tgt).query(q, distance_upper_bound=0.4)
    np.testing.assert_array_equal(got_i, want_i)
    np.testing.assert_allclose(got_d, want_d, rtol=1e-12)


def test_a_single_point_and_bad_input():
    index = KDTreeIndex(np.array([[1.0, 2.0]]))
    d2, idx = index.nearest(np.array([[np.nan, 0.0], [1.0, 2.5], [1e300, 0.0]]), 1.0)
    assert idx.tolist() == [-1, 0, -1]
    with pytest.raises(ValueError, match="M >= 1"):
        KDTreeIndex(np.empty((0, 2)))
    with pytest.raises(ValueError, match="queries must be"):
        index.nearest(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        KDTreeIndex(np.array([[0.0, 1.0], [np.nan, 2.0], [3.0, 4.0]]))
    far = KDTreeIndex(np.array([[-1e308, 0.0], [1e308, 0.0], [0.0, 1.0]] * 20))  # extents beyond float range
    assert far.nearest(np.array([[1e308, 0.0]]))[1].tolist() == [1]
