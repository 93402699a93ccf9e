"""The compiled grid search answers exactly as a KD-tree (scipy's cKDTree), ties by the lowest index."""

import os

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pcreg.registration.nn import OPENMP_SPIN_COUNT, GridIndex
from pcreg import ICPOptions
from pcreg.registration.reference import build_tree, icp_reference


def clouds(kind: str, d: int, rng):
    if kind == "uniform":
        tgt = rng.uniform(0, 10, (3000, d))
    elif kind == "clustered":  # dense blobs and empty space, as edges and a LiDAR's near field
        centres = rng.uniform(0, 100, (20, d))
        tgt = centres[rng.integers(20, size=3000)] + rng.normal(0, 0.3, (3000, d))
    else:  # a thin curve (or surface strip) far from the origin, as georeferenced scans
        t = rng.uniform(0, 2 * np.pi, 3000)
        tgt = np.column_stack([np.cos(t), np.sin(t)] + ([rng.uniform(0, 0.01, 3000)] if d == 3 else [])) * 50 + 1e5
    q = np.concatenate([tgt[:1500] + rng.normal(0, 0.5, (1500, d)),
                        rng.uniform(tgt.min(0) - 5, tgt.max(0) + 5, (1500, d))])
    return tgt, q


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("kind", ["uniform", "clustered", "curve"])
@pytest.mark.parametrize("cell", [None, "small", "large"])
def test_same_answers_as_a_kd_tree(d, kind, cell):
    rng = np.random.default_rng(d * 10 + len(kind))
    tgt, q = clouds(kind, d, rng)
    q[:3] = q[:3] * 1e6  # far outside the grid
    spacing = float(np.ptp(tgt, axis=0).max())
    size = {None: None, "small": spacing / 100, "large": spacing / 3}[cell]
    index = GridIndex(tgt, cell=size)
    tree = cKDTree(tgt)
    for bound in (0.2, 1.0, np.inf):
        want_d, want_i = tree.query(q, k=1, distance_upper_bound=bound)
        got_d, got_i = index.query(q, k=1, distance_upper_bound=bound)
        np.testing.assert_array_equal(got_i, want_i)
        np.testing.assert_allclose(got_d, want_d, rtol=1e-12)
        for workers in (1, 2):
            d2, idx = index.nearest(q, bound, workers=workers)
            np.testing.assert_array_equal(np.where(idx < 0, len(tgt), idx), want_i)


def test_ties_go_to_the_lowest_index_and_the_bound_is_strict():
    lattice = np.array([[x, y] for y in range(6) for x in range(6)], dtype=float)
    order = np.random.default_rng(0).permutation(len(lattice))
    tgt = lattice[order]
    index = GridIndex(tgt)
    q = np.array([[2.5, 2.5], [2.0, 2.5], [0.5, 0.0]])
    d2, idx = index.nearest(q)
    for p, i, dd in zip(q, idx, d2):
        dist = ((tgt - p) ** 2).sum(axis=1)
        assert dd == dist.min() and i == np.flatnonzero(dist == dist.min()).min()
    # d^2 < r^2, strictly (as Open3D and cKDTree): a point exactly at the bound is no neighbour
    d2, idx = index.nearest(np.array([[0.0, 0.5]]), 0.5)
    assert idx[0] == -1 and d2[0] == 0.25


@pytest.mark.parametrize("d", [2, 3])
def test_crowded_cells_with_repeated_points_answer_as_a_brute_force_search(d):
    """Cells of more than SORTED_CELL_MIN points are sorted by x and read within reach of the query, and
    points repeated there are indexed once: the answers are a brute-force search's, ties (repeats, and
    points on a lattice equidistant from the query) to the lowest index."""
    from pcreg.registration import nn

    rng = np.random.default_rng(d)
    crowd = np.round(rng.normal(0, 0.05, (3000, d)), 2)  # one crowded spot on a 0.01 lattice: many ties
    repeats = np.repeat(rng.uniform(-0.1, 0.1, (5, d)), 200, axis=0)  # 5 points, 200 copies each
    tgt = np.concatenate([crowd, repeats, rng.uniform(-5, 5, (500, d))])[rng.permutation(4500)]
    index = GridIndex(tgt, cell=0.5)
    counts = np.diff(index._start)
    assert counts.max() > nn.SORTED_CELL_MIN  # the sorted path is taken
    assert index._spts.shape[0] < len(tgt)  # and repeats were dropped
    q = np.concatenate([np.round(rng.normal(0, 0.06, (400, d)), 3), tgt[:100], rng.uniform(-6, 6, (100, d))])
    for bound in (0.004, 0.05, np.inf):
        d2, idx = index.nearest(q, bound)
        dist = ((q[:, None, :] - tgt[None, :, :]) ** 2).sum(axis=2)
        best = dist.min(axis=1)
        inside = best < bound * bound
        want = np.where(inside, np.argmax(dist == best[:, None], axis=1), -1)  # the lowest index at the minimum
        np.testing.assert_array_equal(idx, want)
        np.testing.assert_array_equal(d2[inside], best[inside])


def test_nan_queries_and_a_single_point():
    index = GridIndex(np.array([[1.0, 2.0]]))
    d2, idx = index.nearest(np.array([[np.nan, 0.0], [1.0, 2.5], [1e300, 0.0]]), 1.0)
    assert idx.tolist() == [-1, 0, -1]
    with pytest.raises(ValueError, match="M >= 1"):
        GridIndex(np.empty((0, 2)))


def test_icp_with_the_grid_equals_icp_with_a_kd_tree():
    """Same correspondences at every iteration; the compiled moments path sums in another order."""
    rng = np.random.default_rng(3)
    target = rng.uniform(-10, 10, (2000, 3))
    c, s = np.cos(0.05), np.sin(0.05)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    source = (target - 0.2) @ R + rng.normal(0, 0.01, target.shape)
    seen = {}
    for name, tree in (("grid", build_tree(target, max_distance=1.0)), ("kdtree", cKDTree(target))):
        seen[name] = []
        icp_reference(source, target, ICPOptions(max_correspondence_distance=1.0, max_iteration=20), tree=tree,
                      callback=seen[name].append)
    assert len(seen["grid"]) == len(seen["kdtree"]) > 3
    for a, b in zip(seen["grid"], seen["kdtree"]):
        np.testing.assert_array_equal(a.target_indices, b.target_indices)
        np.testing.assert_allclose(a.matrix, b.matrix, rtol=0, atol=1e-12)
        assert a.fitness == b.fitness and a.inlier_rmse == pytest.approx(b.inlier_rmse, rel=1e-12)


PARALLEL_AFTER_OPEN3D = """
import os
import open3d  # loads Open3D's own libtbb, which numba's TBB probe used to warn about
import numpy as np
import numba
from pcreg.registration.nn import PARALLEL_MIN_QUERIES, GridIndex
rng = np.random.default_rng(0)
index = GridIndex(rng.uniform(0, 100, (PARALLEL_MIN_QUERIES, 2)))
index.nearest(rng.uniform(0, 100, (PARALLEL_MIN_QUERIES, 2)))
print(numba.threading_layer(), os.environ.get("GOMP_SPINCOUNT"))
"""


def _openmp_loads() -> bool:
    try:
        from numba.np.ufunc import omppool  # noqa: F401  (needs libgomp)
    except ImportError:
        return False
    return True


def _clean_env(**extra: str) -> dict:
    names = ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY")
    return {**{k: v for k, v in os.environ.items() if k not in names}, **extra}


@pytest.mark.parametrize("extra, layer, spin", [
    ({}, "omp", str(OPENMP_SPIN_COUNT)),  # OpenMP first, its threads' spinning shortened
    ({"OMP_WAIT_POLICY": "passive"}, "omp", None),  # a user's OpenMP wait policy is left alone
    ({"NUMBA_THREADING_LAYER": "workqueue", "GOMP_SPINCOUNT": "5"}, "workqueue", "5"),  # so is a named layer
])
@pytest.mark.slow
def test_the_parallel_kernels_choose_their_threading_layer_quietly(extra, layer, spin):
    import subprocess
    import sys

    if layer == "omp" and not _openmp_loads():
        layer = "workqueue"  # no libgomp: the fork-safe layer, as quietly
    p = subprocess.run([sys.executable, "-c", PARALLEL_AFTER_OPEN3D], capture_output=True, text=True, timeout=300,
                       env=_clean_env(**extra))
    assert p.returncode == 0, p.stderr
    assert p.stderr == "", p.stderr
    assert p.stdout.split() == [layer, str(spin)], p.stdout


FORK_AFTER_PARALLEL = """
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
import numba
import numpy as np
from pcreg.registration.nn import PARALLEL_MIN_QUERIES, GridIndex, can_thread

def query(seed):
    rng = np.random.default_rng(seed)
    index = GridIndex(rng.uniform(0, 100, (PARALLEL_MIN_QUERIES, 2)))
    return index.nearest(rng.uniform(0, 100, (PARALLEL_MIN_QUERIES, 2)))[1], can_thread()

here, _ = query(0)  # the parent starts the threading layer's threads before the pool forks
with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork")) as pool:
    there = list(pool.map(query, [0, 0]))
print(numba.threading_layer(), all(np.array_equal(here, t) for t, _ in there), [c for _, c in there])
"""


@pytest.mark.parametrize("layer", ["default", "workqueue"])
def test_a_forked_worker_runs_the_parallel_kernels_after_its_parent(layer):
    """``--workers`` pools fork a parent that may have run a parallel kernel already: numba ends such a
    child when it runs one under GNU OpenMP, so the child runs the one-thread kernels, with the same
    answers (under workqueue, fork-safe, it still runs them threaded)."""
    import subprocess
    import sys

    extra = {} if layer == "default" else {"NUMBA_THREADING_LAYER": layer}
    p = subprocess.run([sys.executable, "-c", FORK_AFTER_PARALLEL], capture_output=True, text=True, timeout=300,
                       env=_clean_env(**extra))
    assert p.returncode == 0, (p.stdout, p.stderr)
    assert p.stderr == "", p.stderr
    started = p.stdout.split()[0]
    assert started == ("omp" if layer == "default" and _openmp_loads() else "workqueue"), p.stdout
    threads_in_child = "False" if started == "omp" else "True"
    assert p.stdout.split()[1:] == ["True", f"[{threads_in_child},", f"{threads_in_child}]"], p.stdout


def test_small_batches_use_the_threads_only_while_a_core_is_spare(monkeypatch):
    from pcreg.registration import nn

    monkeypatch.setattr(nn, "usable_cpus", lambda: 2)
    monkeypatch.setattr(nn.numba, "get_num_threads", lambda: 2)
    idle = nn.PARALLEL_MIN_QUERIES_IDLE
    # the CPUs the rest of the machine keeps busy (this process's own threads do not count)
    for others, small in ((0.0, True), (0.45, True), (0.5, False), (1.2, False)):
        monkeypatch.setattr(nn, "others_busy", lambda others=others: others)
        monkeypatch.setattr(nn.os, "getloadavg", lambda: (2.0, 2.0, 2.0))  # not read when others_busy knows
        assert nn.threaded(idle) is small, others
        assert nn.threaded(idle - 1) is False
        assert nn.threaded(nn.PARALLEL_MIN_QUERIES) is True  # large batches: always
    # before the first measure, or with no /proc/stat: the load average, this process included
    monkeypatch.setattr(nn, "others_busy", lambda: None)
    for load, small in ((0.4, True), (1.4, True), (1.5, False), (2.2, False)):
        monkeypatch.setattr(nn.os, "getloadavg", lambda load=load: (load, load, load))
        assert nn.threaded(idle) is small, load
        assert nn.threaded(nn.PARALLEL_MIN_QUERIES) is True
    monkeypatch.setattr(nn.os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setattr(nn.numba, "get_num_threads", lambda: 1)
    assert nn.threaded(5000) is False  # one thread: nothing to share
