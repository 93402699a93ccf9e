"""Exact nearest-neighbour search on a uniform grid, compiled with numba, and when a batch of queries runs
on numba's threads (:func:`threaded`, for the grid and the KD-tree alike). The grid was the reference
ICP's correspondence search until the KD-tree of :mod:`pcreg.registration.kdtree` replaced it; it is
kept as the tree's measured baseline (``python -m pcreg.registration.kdtree``).

The target points are bucketed into cubic cells of side ``h`` (a counting sort: a dense cell table when
the bounding box holds at most 16 cells a point or 2^18 cells, else an open-addressing hash of the
occupied cells). A query visits the cells in rings of growing Chebyshev distance around its own cell and stops
as soon as the nearest face of the rings already searched is farther than the best point found (or than
the distance bound), so the answer is exact for any cell size; the cell size only sets the speed.
Cells whose box lies farther than the best distance so far are skipped without reading their points.

Agreement with KD-trees (Open3D's nanoflann, scipy's cKDTree):

- distances are compared squared, ``dx*dx + dy*dy (+ dz*dz)`` summed in that order (as nanoflann's L2
  adaptor), and a neighbour counts when ``d^2 < r^2`` (strictly, as Open3D's hybrid search and
  cKDTree's ``distance_upper_bound``);
- among points at exactly the same squared distance the lowest index wins, whatever the cell size. A
  KD-tree returns whichever of them its traversal meets first, which depends on how it was split
  (Open3D's often returns a higher index). Generic coordinates never tie; clouds on a common lattice
  can (pixel clouds compared at the identity), and there the two may pick different, equally near points.

Why it gave way to a tree: a bounded query touches 3^d cells of about the correspondence distance, with
no tree descent, which suits image edge points; but the points of a LiDAR scan lie on surfaces, at
densities that vary a hundredfold with the range, and no one cell size suits them (crowded cells near
the sensor, hundreds of empty ones for a query elsewhere). A KD-tree with sliding-midpoint splits
answered the LiDAR pair's queries in a quarter of the grid's time or less, one thread each, and 2-D
edge points in 0.3-0.9 of it (:mod:`pcreg.registration.kdtree`). Per query against scipy's cKDTree:
``python -m pcreg.registration.nn --bench``; the ICP against Open3D's and small_gicp's:
``tools/bench_icp.py`` (README, Benchmarks).

The compiled kernels are in :mod:`pcreg.registration._nn_kernels`; this module holds the index, the
choice of numba's threading layer and when a batch of queries runs on its threads.

Compilation is cached on disk (``cache=True``); ``python -m pcreg.kernels`` compiles every
kernel once (the Makefile's ``setup`` runs it), so no command compiles after installation; a new
process only loads numba and the cached machine code, on its first registration.
"""

from __future__ import annotations

import os

import numba
import numpy as np

from .._threads import others_busy, usable_cpus
from ._nn_kernels import SORTED_CELL_MIN  # noqa: F401  (the crowded cells' threshold, named here with the grid's)
from ._nn_kernels import (_bounds, _build, _move_match_moments_serial, _move_query_parallel, _moments, _query_parallel,
                          _query_serial)


#: libgomp's spin count (``GOMP_SPINCOUNT``) where neither it nor ``OMP_WAIT_POLICY`` is set: how long
#: an OpenMP thread waits, spinning, for the next parallel region before it sleeps. An ICP runs one
#: region an iteration, back to back, apart by the moments' sum on one thread (tens of microseconds at
#: 1k points). libgomp's default (300,000) kept a core busy 6.5 ms after every region on the Intel
#: machine; 10,000 kept it 0.4 ms, and the 1k / 3k-point 3-D ICP took 0.81 / 0.67 of Open3D's time with
#: it against 0.76 / 0.69 with the default and 0.97 / 0.71 with 1,000 (one process each, 61 calls).
OPENMP_SPIN_COUNT = 10000


def _choose_threading_layer() -> None:
    """Name numba's threading layers instead of letting it probe: this module and the reference ICP's
    threaded loop (:mod:`pcreg.registration.reference`, which imports this module first) hold pcreg's
    only ``parallel=True`` kernels, and the layer is picked when the first of them runs (after this).

    - **OpenMP first** (GNU libgomp; ``make setup`` installs it): its threads wait for the next region
      spinning a while (:data:`OPENMP_SPIN_COUNT`), so the ICP's back-to-back regions find them awake.
      With ``workqueue``, whose threads sleep between regions and must be woken for each, the 1k / 3k
      3-D ICP took 1.40-1.43 / 0.96-1.04 of Open3D's time, against 0.74-0.77 / 0.68-0.70 with OpenMP
      (alternating processes, 61 calls each). libgomp is not fork-safe: numba ends a forked child that
      runs a parallel kernel once its parent's OpenMP threads started, so such a child runs the one-thread
      kernels (:func:`can_thread`), which give the same answers.
    - **workqueue** where OpenMP cannot be loaded (no libgomp): fork-safe; not thread-safe, but these
      kernels hold the GIL while they run (no ``nogil``), so two Python threads never enter it at once.
    - **TBB never**: Open3D ships its own ``libtbb.so.12``, older than numba accepts, and once Open3D is
      imported numba's probe finds it and prints a ``NumbaWarning``. (numba wants all three named: it is
      last, after workqueue, which always loads.)

    ``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY`` set in the environment still win,
    and so do ``GOMP_SPINCOUNT`` and ``OMP_WAIT_POLICY``.
    """
    if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
        numba.config.THREADING_LAYER = "default"
        numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]
    if "GOMP_SPINCOUNT" not in os.environ and "OMP_WAIT_POLICY" not in os.environ:
        os.environ["GOMP_SPINCOUNT"] = str(OPENMP_SPIN_COUNT)  # read when libgomp loads, at the first region


#: The values numba takes for ``NUMBA_THREADING_LAYER`` (its layers, and the choices among them).
THREADING_LAYERS = ("default", "safe", "forksafe", "threadsafe", "omp", "tbb", "workqueue")

def check_threading_layer() -> None:
    """Refuse a ``NUMBA_THREADING_LAYER`` numba does not know (an :class:`~pcreg.errors.InputError` now,
    rather than numba's error at the first parallel kernel)."""
    from ..errors import InputError

    given = os.environ.get("NUMBA_THREADING_LAYER")
    if given is not None and given not in THREADING_LAYERS:
        raise InputError(f"NUMBA_THREADING_LAYER={given!r} is not a numba threading layer; choose one of "
                         f"{', '.join(THREADING_LAYERS)} or unset it")
    why = _layer_missing(given)
    if why is not None:
        raise InputError(f"NUMBA_THREADING_LAYER={given!r}: numba cannot load it on this machine ({why}); "
                         "unset it, or choose workqueue")


#: The libraries of numba's threading layers that a ``NUMBA_THREADING_LAYER`` needs, one of them (numba's
#: ``safe`` is TBB alone, ``threadsafe`` TBB or OpenMP; ``forksafe`` and ``default`` take numba's own workqueue too).
_LAYER_NEEDS = {"tbb": ("tbbpool",), "safe": ("tbbpool",), "threadsafe": ("tbbpool", "omppool"), "omp": ("omppool",)}


def _layer_missing(given: str | None) -> str | None:
    """Why numba cannot load the threading layer ``given`` names (TBB's library not installed: its ImportError), or
    None: it can, or needs none. The library is loaded, not started (no thread before a fork)."""
    import importlib
    import warnings

    from numba.np.ufunc import parallel

    said = None
    for module in _LAYER_NEEDS.get(given or "", ()):
        try:
            if module == "tbbpool" and hasattr(parallel, "_check_tbb_version_compatible"):
                with warnings.catch_warnings():  # numba's own refusal of a TBB too old, without its warning
                    warnings.simplefilter("ignore")
                    parallel._check_tbb_version_compatible()
            importlib.import_module(f"numba.np.ufunc.{module}")
        except ImportError as exc:
            said = said or str(exc)
        else:
            return None
    return said


#: True in a process forked after its parent's OpenMP threads started (:func:`can_thread`): a fact about
#: this process and numba's threading layer in it, set by the fork hook, so held at module level.
_FORKED_AFTER_OPENMP = False


def _started_layer() -> str | None:
    """The threading layer numba started in this process, or None before its first parallel kernel."""
    try:
        return numba.threading_layer()
    except ValueError:
        return None


def _note_fork() -> None:
    global _FORKED_AFTER_OPENMP
    if _started_layer() == "omp":
        _FORKED_AFTER_OPENMP = True


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_note_fork)


def can_thread() -> bool:
    """Whether this process may run a ``parallel=True`` kernel: not in a child forked after its parent
    started GNU OpenMP's threads (numba ends such a child when it runs one; see
    :func:`_choose_threading_layer`). Where it may not, the one-thread kernels give the same answers."""
    return not _FORKED_AFTER_OPENMP


_choose_threading_layer()

#: Queries at or above this count use the multi-threaded kernel: below it, on a loaded machine,
#: starting the threads and waiting for a core costs more than it saves.
PARALLEL_MIN_QUERIES = 20000
#: ... and from this count while the machine has a core to spare (:func:`threaded`). On an idle 2-CPU
#: machine the threads paid from about 1,000 points: a 15-iteration ICP of 1k / 3k / 10k points took
#: 0.5-0.6 of the one-thread time in 2-D and 0.6-0.75 in 3-D, while at 300 points they cost as much as
#: they saved and at 100 more. On a loaded machine (load average 1.6-2.3 on 2 CPUs, this process
#: included) the same change made 1k-point ICPs slower, hence the test of a spare core.
PARALLEL_MIN_QUERIES_IDLE = 1000


def threaded(n: int) -> bool:
    """Whether a batch of ``n`` queries runs on numba's threads: from :data:`PARALLEL_MIN_QUERIES`
    always, from :data:`PARALLEL_MIN_QUERIES_IDLE` while the rest of the machine keeps busy fewer than
    the CPUs this process may use less one and a half: on 2 CPUs, less than half a core
    (:func:`~pcreg._threads.others_busy`; before its first measure, and where the machine's CPU time is
    not known, the 1-minute load average, this process included, under the CPUs less half a CPU). Both
    ways give the same answers, to the bit."""
    if not can_thread():
        return False
    if n >= PARALLEL_MIN_QUERIES:
        return True
    if n < PARALLEL_MIN_QUERIES_IDLE or numba.get_num_threads() < 2:
        return False
    others = others_busy()
    if others is not None:
        return others < usable_cpus() - 1.5
    try:
        load = os.getloadavg()[0]
    except OSError:  # pragma: no cover - no load average on this system
        return False
    return load < usable_cpus() - 0.5


#: Target points per cell when the cell size is chosen from the point density.
POINTS_PER_CELL = 2.0
#: ... but a bounded query's cell is no smaller than this fraction of that: below the correspondence
#: distance, the cells a query visits outnumber the points they hold. The density is taken over the
#: bounding box's volume, which is too low for points on surfaces (LiDAR scans) and their cells are far
#: apart. Half against a quarter, build and 15 searches on one thread, medians of 21 alternating runs:
#: 0.83 / 0.82 / 0.89 of the time on 1k / 3k / 10k points of the LiDAR pair, 0.80 on 1k uniform in a cube,
#: 0.79 on 1k on a sphere, 0.92-0.97 at 10k, 0.93 on 1k image edge points (0.97-0.98 where both fractions
#: give the same cell). Whole density cells (fraction 1) were slower from 10k 3-D points (1.13-1.42).
MIN_CELL_OF_DENSITY = 0.5
#: A dense cell table (8 bytes a cell) is used while it holds at most this many cells per point, or
#: at most :data:`DENSE_MIN_CELLS`; beyond, a hash of the occupied cells (slower lookups, memory ~ points).
DENSE_CELLS_PER_POINT = 16
DENSE_MIN_CELLS = 1 << 18


# ---------------------------------------------------------------------------------------------------
# the index
# ---------------------------------------------------------------------------------------------------

def squared_bound(max_distance: float) -> float:
    """The squared distance bound of a search: ``max_distance ** 2``, or inf where the distance is not
    finite (inf or NaN: no bound) or its square is beyond float range."""
    r = float(max_distance)
    return r * r if np.isfinite(r) else np.inf


def _real_array(a, what: str) -> np.ndarray:
    """``a`` as float64; complex numbers are refused rather than cut to their real parts."""
    if np.iscomplexobj(a):
        raise ValueError(f"{what} must be real coordinates, got complex numbers")
    return np.asarray(a, dtype=np.float64)


def index_points(points, name: str) -> np.ndarray:
    """The points of an index: a C-contiguous float64 copy of (M, 2|3) finite real coordinates, M >= 1 (a copy:
    the index answers the same after its caller changes ``points``)."""
    pts = np.array(_real_array(points, f"{name}'s points"), dtype=np.float64, order="C")
    if pts.ndim != 2 or pts.shape[1] not in (2, 3) or pts.shape[0] < 1:
        raise ValueError(f"{name} needs an (M, 2|3) array with M >= 1, got shape {pts.shape}")
    if not np.isfinite(pts).all():  # a NaN has no side of a cut, nor a cell
        raise ValueError(f"{name} needs finite points")
    return pts


class NearestIndex:
    """What the reference ICP's searches share: :meth:`nearest` over the search's own compiled kernels
    (``_query_kernels``: serial, parallel; each takes the queries, the squared bound, the search's
    ``search_arrays`` and the two outputs) and :meth:`query` in scipy's ``cKDTree`` form."""

    n: int
    dim: int
    _query_kernels: tuple

    @property
    def search_arrays(self) -> tuple:
        """The arrays the compiled kernels search, after the queries and the bound."""
        raise NotImplementedError  # each search's own

    def nearest(self, queries: np.ndarray, max_distance: float = np.inf, *, workers: int | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """Squared distance (K,) float64 and index (K,) int64 of each query's nearest point with
        ``d^2 < max_distance^2``; ``(max_distance^2, -1)`` where there is none.

        workers : threads (None: all of numba's where :func:`threaded` says so, else 1; 1 where
            :func:`can_thread` says no).
        """
        q = np.ascontiguousarray(_real_array(queries, "queries"))
        if q.ndim != 2 or q.shape[1] != self.dim:
            raise ValueError(f"queries must be (K, {self.dim}), got shape {q.shape}")
        out_d2 = np.empty(q.shape[0], np.float64)
        out_i = np.empty(q.shape[0], np.int64)
        serial, parallel = self._query_kernels
        search = parallel if (threaded(q.shape[0]) if workers is None else workers != 1) and can_thread() else serial
        search(q, squared_bound(max_distance), *self.search_arrays, out_d2, out_i)
        return out_d2, out_i

    def query(self, x: np.ndarray, k: int = 1, *, eps: float = 0.0, p: float = 2.0,
              distance_upper_bound: float = np.inf, workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """As ``cKDTree.query(x, k=1, distance_upper_bound=...)``: (distances, indices), ``inf`` and ``n``
        where no point is closer than the bound. ``x`` is one point (d,) or (K, d) points.

        eps : accepted for cKDTree's interface; the answer is exact, so within any ``1 + eps``.
        p : the Minkowski norm; only 2 (Euclidean) is searched, any other is refused.
        """
        if k != 1:
            raise ValueError(f"{type(self).__name__} answers k=1 queries only")
        if p != 2:
            raise ValueError(f"{type(self).__name__} searches Euclidean distances (p=2) only, got p={p}")
        x = _real_array(x, "queries")
        single = x.ndim == 1
        d2, idx = self.nearest(x[None] if single else x, distance_upper_bound,
                               workers=None if workers in (-1, None) else workers)
        miss = idx < 0
        dist = np.sqrt(d2)
        dist[miss] = np.inf
        idx[miss] = self.n
        return (dist[0], idx[0]) if single else (dist, idx)


def _density_cell(extent: np.ndarray, m: int) -> float:
    """The side of cubic cells that share the occupied dimensions' volume among ``m`` points,
    :data:`POINTS_PER_CELL` a cell (1 where all points are one; summed in logarithms where the volume leaves
    float range: extents of 1e300, or of a few subnormal numbers)."""
    pos = extent[extent > 0]
    if pos.size == 0:
        return 1.0
    with np.errstate(over="ignore", under="ignore"):
        cell = float((np.prod(pos) * POINTS_PER_CELL / m) ** (1.0 / pos.size))
    if not 0.0 < cell < np.inf:
        cell = float(np.exp((np.log(pos).sum() + np.log(POINTS_PER_CELL / m)) / pos.size))
    return max(cell, float(pos.max()) / 2**20)


class GridIndex(NearestIndex):
    """Exact nearest-neighbour index of (M, 2|3) points on a uniform grid.

    points : (M, d) finite float64, d = 2 or 3, M >= 1.
    cell : cell side in the points' units. None: from the density, about :data:`POINTS_PER_CELL`
        points per cell of the bounding box, but at most ``max_distance`` when that is given (queries
        bounded by it then visit at most 3^d cells), and no less than :data:`MIN_CELL_OF_DENSITY` of it.
    max_distance : the distance bound the queries will mostly use (a hint for ``cell``).

    :meth:`query` answers like ``scipy.spatial.cKDTree.query`` with ``k=1``.
    """

    _query_kernels = (_query_serial, _query_parallel)

    def __init__(self, points: np.ndarray, *, cell: float | None = None, max_distance: float | None = None) -> None:
        pts = index_points(points, "GridIndex")
        m, d = pts.shape
        lo, hi = _bounds(pts)
        with np.errstate(over="ignore"):
            extent = hi - lo
        if not np.isfinite(extent).all():
            raise ValueError("GridIndex needs points less than the largest float apart along each axis "
                             "(KDTreeIndex takes any finite points)")
        if cell is None:
            cell = _density_cell(extent, m)
            if max_distance is not None and np.isfinite(max_distance) and max_distance > 0:
                cell = max(min(cell, float(max_distance)), cell * MIN_CELL_OF_DENSITY)
        cell = float(cell)
        if not (cell > 0 and np.isfinite(cell)):
            raise ValueError(f"cell size must be a positive number, got {cell}")
        scale = max(float(np.abs(lo).max()), float(extent.max()), 1.0)
        cell = max(cell, scale * 1e-9)  # keeps cell coordinates well inside float precision
        dims = np.floor(extent / cell).astype(np.int64) + 1
        while np.prod(dims.astype(np.float64)) > 2.0**62 / 8:  # linear keys must fit in int64
            cell *= 2.0
            dims = np.floor(extent / cell).astype(np.int64) + 1
        hashed = bool(np.prod(dims.astype(np.float64)) > max(DENSE_CELLS_PER_POINT * m, DENSE_MIN_CELLS))
        self.dim = d
        self.n = m
        self.cell = cell
        self.origin = lo.astype(np.float64)
        self.dims = dims
        self.hashed = hashed
        self.data = pts
        self.center = (lo + hi) / 2.0
        self._spts, self._sidx, self._start, self._tkeys, self._tcell = _build(pts, self.origin, cell, dims, hashed)

    def __len__(self) -> int:
        return self.n

    @property
    def search_arrays(self) -> tuple:
        """The index as the compiled search takes it: (sorted points, their indices, cell starts, hash
        keys, hash cells, origin, cell size, cells per dimension, hashed), the arguments of
        :func:`~pcreg.registration._nn_kernels._nearest` after the query and its bound, for kernels that search inside their own loop."""
        return (self._spts, self._sidx, self._start, self._tkeys, self._tcell, self.origin, self.cell, self.dims,
                self.hashed)

    def __repr__(self) -> str:
        return (f"GridIndex(n={self.n}, dim={self.dim}, cell={self.cell:.4g}, cells={'x'.join(map(str, self.dims))}, "
                f"{'hashed' if self.hashed else 'dense'})")

    def move_and_match(self, points: np.ndarray, update: np.ndarray | None, max_distance: float):
        """One point-to-point ICP iteration's correspondence step, compiled: move ``points`` (N, d),
        C-contiguous float64, **in place** by the affine ``update`` ((d+1, d+1); None: do not move),
        find each one's nearest point within ``max_distance``, and sum the moments of the matched pairs
        (relative to the centre of the points' bounding box, for precision).

        Returns (squared distances (N,), indices (N,) with -1 for none, (count, sum d^2, sum p,
        sum q, sum |p|^2, sum q p^T, centre))."""
        n = points.shape[0]
        r2 = squared_bound(max_distance)
        out_d2 = np.empty(n, np.float64)
        out_i = np.empty(n, np.int64)
        M = np.eye(self.dim + 1) if update is None else np.ascontiguousarray(update, dtype=np.float64)
        args = (points, M, update is not None, r2, *self.search_arrays, out_d2, out_i)
        if threaded(n):
            _move_query_parallel(*args)
            mom = _moments(points, self.data, out_d2, out_i, self.center)
        else:
            mom = _move_match_moments_serial(*args, self.data, self.center)
        return out_d2, out_i, (*mom, self.center)



def warm_up() -> None:
    """Compile (or load from the on-disk cache) the search's kernels: 2-D and 3-D, dense and hashed, serial
    and parallel, bounded and unbounded (:mod:`pcreg.kernels` warms every kernel of pcreg)."""
    rng = np.random.default_rng(0)
    for d in (2, 3):
        pts = rng.uniform(0, 10, (64, d))
        for hashed_cell in (None, 1e-3):
            idx = GridIndex(pts, cell=hashed_cell)
            for workers in (1, 2) if can_thread() else (1,):
                idx.nearest(pts[:8] + 0.01, 0.5, workers=workers)
                idx.nearest(pts[:8] + 100.0, workers=workers)


def time_search(build, run, repeats: int) -> tuple[float, float]:
    """Median seconds of ``build()`` and of ``run(index)`` over ``repeats`` rounds, after one round not
    counted (compilation, caches): what this module's and the KD-tree's measurements print."""
    import time

    run(build())
    tb, tq = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        index = build()
        t1 = time.perf_counter()
        run(index)
        tb.append(t1 - t0)
        tq.append(time.perf_counter() - t1)
    return float(np.median(tb)), float(np.median(tq))


def _bench(n: int = 20000, repeats: int = 7) -> None:  # pragma: no cover - a measurement, not a test

    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tgt = np.column_stack([320 + 250 * np.cos(3 * t) * np.cos(t), 240 + 200 * np.sin(5 * t)]) + rng.normal(0, 2, (n, 2))
    src = tgt + rng.normal(0, 1.0, tgt.shape)
    rows = {}
    for name, build, run in (
        ("cKDTree", lambda: cKDTree(tgt), lambda s: s.query(src, k=1, distance_upper_bound=2.5)),
        ("grid 1 thread", lambda: GridIndex(tgt, max_distance=2.5), lambda s: s.nearest(src, 2.5, workers=1)),
        ("grid 2 threads", lambda: GridIndex(tgt, max_distance=2.5), lambda s: s.nearest(src, 2.5, workers=2)),
    ):
        tb, tq = time_search(build, run, repeats)
        rows[name] = (tb * 1e3, tq / n * 1e6)
    for name, (b, q) in rows.items():
        print(f"{name:16s} build {b:7.2f} ms   query {q:6.3f} us/point")


def main(argv: list[str] | None = None) -> int:  # pragma: no cover - exercised by the Makefile
    import argparse
    import time

    p = argparse.ArgumentParser(prog="python -m pcreg.registration.nn",
                                description="compile the correspondence search (cached on disk), or time it")
    p.add_argument("--warm", action="store_true", help="compile the search's kernels now")
    p.add_argument("--bench", action="store_true", help="time queries against scipy's cKDTree")
    args = p.parse_args(argv)
    if not (args.warm or args.bench):
        p.print_help()
        return 2
    if args.warm:
        t0 = time.perf_counter()
        warm_up()
        print(f"pcreg: compiled kernels ready in {time.perf_counter() - t0:.1f} s "
              f"(cache: {os.path.dirname(__file__)}/__pycache__ or NUMBA_CACHE_DIR)")
    if args.bench:
        _bench()
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
