"""Exact nearest-neighbour search on a KD-tree, compiled with numba: the correspondence search of the
reference ICP.

The tree splits each node across its widest side at the middle of its points' extent (a sliding
midpoint; at the median below :data:`~pcreg.registration._kd_kernels.MIDDLE_SPLIT_DEPTH` levels) down
to leaves of :data:`LEAF_SIZE` points, stored in the leaves' order. A query descends to its own leaf,
then visits the other sides of the cuts on its way whose lower bound (the squared gaps to the cuts)
is below the best distance so far. A point repeated many times is kept once, by its lowest index.

Agreement with other KD-trees (Open3D's nanoflann, scipy's cKDTree), as the grid
(:class:`pcreg.registration.nn.GridIndex`) before it:

- distances are compared squared, ``dx*dx + dy*dy (+ dz*dz)`` summed in that order (as nanoflann's L2
  adaptor), and a neighbour counts when ``d^2 < r^2`` (strictly, as Open3D's hybrid search and
  cKDTree's ``distance_upper_bound``);
- among points at exactly the same squared distance the lowest index wins (the bounds that skip a
  node are exact in floating point, so a tying point is never skipped). Another tree returns whichever
  of them its traversal meets first; generic coordinates never tie, clouds on a common lattice can.

Why a tree rather than the uniform grid it replaced in the ICP: the points of a LiDAR scan lie on
surfaces, at densities that vary a hundredfold with the range. No one cell size suits them: cells of
about the correspondence distance held 28-196 points on average (a query near the sensor read hundreds),
smaller ones left a bounded query hundreds of empty cells to visit. The tree's cells follow the points.
On the LiDAR pair's subsets of 1k-70k points it answered the same queries in a quarter to a ninth of
the grid's time, one thread each, and on 2-D image edge points in 0.3-0.9 of it (``docs/benchmarks.md``,
ICP, per thread). Per query against scipy's cKDTree and the grid: ``python -m pcreg.registration.kdtree``.

Compilation is cached on disk (:mod:`pcreg._jit`); ``python -m pcreg.kernels`` compiles every kernel.
"""

from __future__ import annotations

import numpy as np

from ._kd_kernels import _build, _move_query_parallel, _move_query_serial, _query_parallel, _query_serial
from ._nn_kernels import _bounds, _moments
from .nn import NearestIndex, can_thread, index_points, squared_bound, threaded

#: Points a leaf holds at most: a leaf's points are read in a row, faster than the nodes above them. The
#: index built and searched 15 times (the bench's ICP clouds, one thread, medians of 7 alternating
#: rounds, time relative to the fastest leaf; the machine was loaded, load average 7):
#:
#: | leaf | 12 | 16 | 24 | 32 | 48 | 64 |
#: |---|---|---|---|---|---|---|
#: | 3-D 1k / 10k / 70k | 1.76 / 1.17 / 1.31 | 1.06 / 1.19 / 1.32 | 1.07 / 1.00 / 1.00 | 1.06 / 1.07 / 1.11 | 1.00 / 1.10 / 1.18 | 1.33 / 1.29 / 1.28 |
#: | 2-D 1k / 10k / 100k | 1.23 / 1.32 / 1.51 | 1.43 / 1.41 / 1.08 | 1.00 / 1.58 / 1.07 | 1.02 / 1.33 / 1.19 | 1.59 / 1.00 / 1.00 | 1.45 / 1.33 / 1.16 |
#:
#: and in a round of 3 searches a build, leaves of 6 / 8 / 12 / 16 / 24 points took 1.11-1.57 / 1.08-1.46 /
#: 1.04-1.25 / 1.03-1.12 / 1.00 of the fastest's time at every size.
LEAF_SIZE = 24


class KDTreeIndex(NearestIndex):
    """Exact nearest-neighbour index of (M, 2|3) finite points on a KD-tree.

    points : (M, d) finite float64, d = 2 or 3, M >= 1.
    leaf : points a leaf holds at most (:data:`LEAF_SIZE`).
    max_distance : accepted for the grid's interface (a tree's shape does not depend on it).

    :meth:`query` answers like ``scipy.spatial.cKDTree.query`` with ``k=1``.
    """

    _query_kernels = (_query_serial, _query_parallel)

    def __init__(self, points: np.ndarray, *, leaf: int = LEAF_SIZE, max_distance: float | None = None) -> None:
        pts = index_points(points, "KDTreeIndex")
        if int(leaf) < 1:
            raise ValueError(f"leaf must hold at least one point, got {leaf}")
        lo, hi = _bounds(pts)
        self.dim = pts.shape[1]
        self.n = pts.shape[0]
        self.data = pts
        self.center = (lo + hi) / 2.0
        self._nodes, self._spts, self._sidx, self.depth = _build(pts, int(leaf))

    def __len__(self) -> int:
        return self.n

    @property
    def search_arrays(self) -> tuple:
        """The index as the compiled search takes it: (nodes, the points in the leaves' order, their
        indices, the depth), the arguments of :func:`~pcreg.registration._kd_kernels._nearest`'s loops
        after the query's bound."""
        return self._nodes, self._spts, self._sidx, self.depth

    def __repr__(self) -> str:
        leaves = int(np.count_nonzero(self._nodes[:, 2] < 0))
        return f"KDTreeIndex(n={self.n}, dim={self.dim}, nodes={len(self._nodes)}, leaves={leaves}, depth={self.depth})"

    def move_and_match(self, points: np.ndarray, update: np.ndarray | None, max_distance: float):
        """One point-to-point ICP iteration's correspondence step, compiled: move ``points`` (N, d),
        C-contiguous float64, **in place** by the affine ``update`` ((d+1, d+1); None: do not move),
        find each one's nearest point within ``max_distance``, and sum the moments of the matched pairs
        (relative to the centre of the target's bounding box, for precision).

        Returns (squared distances (N,), indices (N,) with -1 for none, (count, sum d^2, sum p,
        sum q, sum |p|^2, sum q p^T, centre))."""
        n = points.shape[0]
        out_d2 = np.empty(n, np.float64)
        out_i = np.empty(n, np.int64)
        M = np.eye(self.dim + 1) if update is None else np.ascontiguousarray(update, dtype=np.float64)
        args = (points, M, update is not None, squared_bound(max_distance), *self.search_arrays, out_d2, out_i)
        (_move_query_parallel if threaded(n) else _move_query_serial)(*args)
        mom = _moments(points, self.data, out_d2, out_i, self.center)
        return out_d2, out_i, (*mom, self.center)



def warm_up() -> None:
    """Compile (or load from the on-disk cache) the tree's kernels: 2-D and 3-D, serial and parallel,
    bounded and unbounded, a repeated point and a deep (median-split) tree."""
    rng = np.random.default_rng(0)
    for d in (2, 3):
        pts = np.concatenate([rng.uniform(0, 10, (64, d)), np.zeros((20, d)), 2.0 ** -np.arange(70)[:, None] * np.ones(d)])
        index = KDTreeIndex(pts)
        for workers in (1, 2) if can_thread() else (1,):
            index.nearest(pts[:8] + 0.01, 0.5, workers=workers)
            index.nearest(pts[:8] + 100.0, workers=workers)
        moved = np.ascontiguousarray(pts[:8] + 0.01)
        index.move_and_match(moved, np.eye(d + 1), 0.5)
        index.move_and_match(moved, None, 0.5)


def _bench(repeats: int = 7) -> None:  # pragma: no cover - a measurement, not a test
    from pathlib import Path

    from scipy.spatial import cKDTree

    from .nn import GridIndex, time_search

    rng = np.random.default_rng(0)
    scans = Path(__file__).resolve().parents[3] / "shared" / "data" / "scans"
    clouds = []
    if (scans / "target.ply").is_file():
        import open3d as o3d

        tgt = np.asarray(o3d.io.read_point_cloud(str(scans / "target.ply")).points, dtype=np.float64)
        src = np.asarray(o3d.io.read_point_cloud(str(scans / "source.ply")).points, dtype=np.float64)
        clouds.append(("LiDAR pair, 3-D", tgt, src, 0.5))
    n = 20000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tgt2 = np.column_stack([320 + 250 * np.cos(3 * t) * np.cos(t), 240 + 200 * np.sin(5 * t)]) + rng.normal(0, 2, (n, 2))
    clouds.append(("20k 2-D curve", tgt2, tgt2 + rng.normal(0, 1.0, tgt2.shape), 2.5))
    for label, tgt, src, dist in clouds:
        print(f"{label}: {len(tgt)} target, {len(src)} query points, bound {dist:g}, one thread")
        for name, build, run in (
            ("cKDTree", lambda: cKDTree(tgt), lambda s: s.query(src, k=1, distance_upper_bound=dist)),
            ("grid", lambda: GridIndex(tgt, max_distance=dist), lambda s: s.nearest(src, dist, workers=1)),
            ("KD-tree", lambda: KDTreeIndex(tgt), lambda s: s.nearest(src, dist, workers=1)),
        ):
            tb, tq = time_search(build, run, repeats)
            print(f"  {name:8s} build {tb * 1e3:7.2f} ms   query {tq / len(src) * 1e9:6.0f} ns/point")


if __name__ == "__main__":  # pragma: no cover
    _bench()
