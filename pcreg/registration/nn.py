"""Exact nearest-neighbour search on a uniform grid, compiled with numba: the correspondence search of
the reference ICP.

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

Why a grid rather than a compiled KD-tree: the ICP's queries are bounded (``max_correspondence_distance``)
and arrive in spatially coherent order, so a query touches 3^d cells of about the correspondence
distance, with no tree descent; building it is one counting sort (linear), against a KD-tree's
O(M log M). A compiled KD-tree with the same tie rule (median splits, leaves of 4-16 points) was no
faster per query on 1k-30k points of the LiDAR pair. Per query against scipy's cKDTree:
``python -m pcreg.registration.nn --bench``; the ICP against Open3D's and small_gicp's:
``tools/bench_icp.py`` (README, Benchmarks).

Compilation is cached on disk (``cache=True``); ``python -m pcreg.kernels`` compiles every
kernel once (the Makefile's ``setup`` runs it), so no command compiles after installation; a new
process only loads numba and the cached machine code, on its first registration.
"""

from __future__ import annotations

import math
import os

import numba
import numpy as np

from .._jit import njit, prange
from .._threads import others_busy, usable_cpus


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


#: True in a process forked after its parent's OpenMP threads started (:func:`can_thread`).
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


#: A cell holding more points than this is kept sorted by the first coordinate, and a query reads only
#: its points within reach along that axis: from the first within reach of its x (a binary search)
#: until the next point is farther in x alone than the best so far. LiDAR scans crowd some cells of a
#: uniform grid (on the LiDAR pair the largest holds 1,856 distinct points, and 5,032 copies of one
#: point before :func:`_build` keeps it once). 64: image clouds (edge points on the pixel lattice)
#: have cells of up to about 40 points, where the sorted path measured slower than a plain scan.
SORTED_CELL_MIN = 64
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
_EPS_CELLS = 1e-7  # slack (in cell units) on every geometric lower bound: rounding down is never trusted


# ---------------------------------------------------------------------------------------------------
# build
# ---------------------------------------------------------------------------------------------------

@njit(cache=True)
def _bounds(pts):
    """Per-dimension minimum and maximum of (M, d) points, M >= 1, in one pass (the values of
    ``pts.min(axis=0)`` and ``pts.max(axis=0)``, which numpy reduces slowly along a short axis)."""
    lo = pts[0].copy()
    hi = pts[0].copy()
    for t in range(1, pts.shape[0]):
        for a in range(pts.shape[1]):
            v = pts[t, a]
            if v < lo[a]:
                lo[a] = v
            if v > hi[a]:
                hi[a] = v
    return lo, hi


@njit(cache=True)
def _hash_slot(key, mask):
    # Fibonacci hashing of a non-negative int64 key
    return ((key * np.int64(-7046029254386353131)) >> np.int64(17)) & mask


@njit(cache=True)
def _build(points, origin, h, dims, hashed):
    """Counting sort of the points into cells. Returns (sorted points, their original indices, cell
    start offsets (n_cells + 1), hash keys, hash cell ids).

    Within a cell the points keep ascending indices, except in a crowded cell (more than
    :data:`SORTED_CELL_MIN` points), which is sorted by its first coordinate (stably) and keeps each
    repeated point once, by its lowest index (:func:`_mark_repeats`): a query's answer is the same (the
    lowest index wins a tie), and the cell no longer holds copies (a LiDAR scan can return thousands of
    points at one place: 5,032 in one cell of the LiDAR pair, which every query near it read).

    One pass over the cells (the running sum of their counts), and a second only where repeats are
    dropped: a small cloud's dense table can have 30 cells a point, and each pass over it cost about as
    much as the points themselves."""
    m, d = points.shape
    tkeys, tcell, cell_of, n_cells = _cells_of(points, origin, h, dims, hashed)
    # start[c] counts cell c's points, then (running sum) ends it; the fill, backwards, leaves it at the
    # cell's first row, and start[n_cells] = m
    start = np.zeros(n_cells + 1, np.int64)
    crowded = np.empty(m // (SORTED_CELL_MIN + 1) + 1, np.int64)
    n_crowded = 0
    for i in range(m):
        c = cell_of[i]
        start[c] += 1
        if start[c] == SORTED_CELL_MIN + 1:
            crowded[n_crowded] = c
            n_crowded += 1
    for c in range(1, n_cells):
        start[c] += start[c - 1]
    start[n_cells] = m
    spts = np.empty((m, d), np.float64)
    sidx = np.empty(m, np.int64)
    for i in range(m - 1, -1, -1):  # backwards: within a cell, points keep ascending indices
        c = cell_of[i]
        start[c] -= 1
        j = start[c]
        for a in range(d):
            spts[j, a] = points[i, a]
        sidx[j] = i
    if n_crowded == 0:
        return spts, sidx, start, tkeys, tcell
    drop = np.zeros(m, np.bool_)
    n_drop = 0
    for t in range(n_crowded):  # a crowded cell by its first coordinate (see SORTED_CELL_MIN), then its repeats
        s0, s1 = start[crowded[t]], start[crowded[t] + 1]
        order = np.argsort(spts[s0:s1, 0], kind="mergesort")
        spts[s0:s1] = spts[s0:s1][order]
        sidx[s0:s1] = sidx[s0:s1][order]
        n_drop += _mark_repeats(spts, s0, s1, drop)
    if n_drop == 0:
        return spts, sidx, start, tkeys, tcell
    w = 0
    s0 = start[0]
    for c in range(n_cells):
        s1 = start[c + 1]
        start[c] = w
        for j in range(s0, s1):
            if not drop[j]:
                for a in range(d):
                    spts[w, a] = spts[j, a]
                sidx[w] = sidx[j]
                w += 1
        s0 = s1
    start[n_cells] = w
    return spts[:w], sidx[:w], start, tkeys, tcell


@njit(cache=True)
def _cells_of(points, origin, h, dims, hashed):
    """Each point's cell: (hash keys, hash cell ids, the cell of each point, number of cells). A dense
    table numbers the cells by their linear key; a hash numbers the occupied cells as it meets them."""
    m, d = points.shape
    keys = np.empty(m, np.int64)
    for i in range(m):
        key = np.int64(0)
        stride = np.int64(1)
        for a in range(d):
            c = np.int64(math.floor((points[i, a] - origin[a]) / h))
            if c < 0:
                c = 0
            elif c >= dims[a]:
                c = dims[a] - 1
            key += c * stride
            stride *= dims[a]
        keys[i] = key
    if not hashed:
        n_cells = 1
        for a in range(d):
            n_cells *= dims[a]
        return np.empty(0, np.int64), np.empty(0, np.int64), keys, n_cells
    size = 1
    while size < 2 * m:
        size *= 2
    mask = np.int64(size - 1)
    tkeys = np.full(size, -1, np.int64)
    tcell = np.full(size, -1, np.int64)
    n_cells = 0
    cell_of = np.empty(m, np.int64)
    for i in range(m):
        s = _hash_slot(keys[i], mask)
        while True:
            if tkeys[s] == keys[i]:
                break
            if tkeys[s] == -1:
                tkeys[s] = keys[i]
                tcell[s] = n_cells
                n_cells += 1
                break
            s = (s + 1) & mask
        cell_of[i] = tcell[s]
    return tkeys, tcell, cell_of, n_cells


@njit(cache=True)
def _mark_repeats(spts, s0, s1, drop):
    """Marks in ``drop`` the rows of ``s0..s1`` (a cell sorted by its first coordinate, stably, so in
    ascending index within equal x) that repeat a row before them, and returns how many. Equal points lie
    in one run of equal x; each row of a run is compared with the run's distinct rows before it (a run is
    one row long unless x repeats)."""
    n_drop = 0
    r0 = s0
    while r0 < s1:
        r1 = r0 + 1
        while r1 < s1 and spts[r1, 0] == spts[r0, 0]:
            r1 += 1
        if r1 - r0 > 1:
            firsts = np.empty(r1 - r0, np.int64)  # the run's distinct rows so far
            n = 0
            for j in range(r0, r1):
                if _seen(spts, j, firsts, n):
                    drop[j] = True
                    n_drop += 1
                else:
                    firsts[n] = j
                    n += 1
        r0 = r1
    return n_drop


@njit(cache=True, inline="always")
def _seen(spts, j, firsts, n):
    """Whether point ``j`` equals one of ``firsts[:n]`` in every coordinate after the first (the run
    already shares its x)."""
    for t in range(n):
        f = firsts[t]
        same = True
        for a in range(1, spts.shape[1]):
            if spts[j, a] != spts[f, a]:
                same = False
                break
        if same:
            return True
    return False


# ---------------------------------------------------------------------------------------------------
# one query
# ---------------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _cell_range(key, hashed, start, tkeys, tcell):
    if hashed:
        mask = np.int64(tkeys.shape[0] - 1)
        s = _hash_slot(key, mask)
        while True:
            k = tkeys[s]
            if k == key:
                c = tcell[s]
                return start[c], start[c + 1]
            if k == -1:
                return 0, 0
            s = (s + 1) & mask
    return start[key], start[key + 1]


@njit(cache=True, inline="always")
def _gap2(i, u):
    """Squared lower bound (cell units) on the distance from coordinate ``u`` to cell ``i``."""
    g = max(0.0, i - u, u - (i + 1))
    g = max(g - _EPS_CELLS, 0.0)
    return g * g


@njit(cache=True)
def _scan_all(q, best_d2, best_i, spts, sidx):
    d = q.shape[0]
    for j in range(spts.shape[0]):
        d2 = 0.0
        for a in range(d):
            diff = q[a] - spts[j, a]
            d2 += diff * diff
        i = sidx[j]
        if d2 < best_d2 or (d2 == best_d2 and best_i >= 0 and i < best_i):
            best_d2 = d2
            best_i = i
    return best_d2, best_i


@njit(cache=True, inline="always")
def _nearest(q, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed):
    """(squared distance, index) of the nearest point with d^2 < r2, or (r2, -1).

    Inlined into each loop over queries: as a call, each query passes its eleven arguments (the arrays
    as several fields each) and reloads what the loop keeps in registers. Inlined, a loop of 1,000 or
    10,000 queries on the bench's 2-D and 3-D clouds took 0.94-0.95 of the time, with the same answers
    (both forms compiled in one process, alternating, median of 41 runs)."""
    d = q.shape[0]
    best_d2 = r2
    best_i = np.int64(-1)
    n0 = dims[0]
    n1 = dims[1]
    n2 = dims[2] if d == 3 else np.int64(1)
    u0 = (q[0] - origin[0]) / h
    u1 = (q[1] - origin[1]) / h
    u2 = (q[2] - origin[2]) / h if d == 3 else 0.5
    # Far outside the grid (by more than its size) or NaN: the rings would be mostly empty; scan every point.
    if not (-2.0 * n0 - 2.0 < u0 < 3.0 * n0 + 2.0 and -2.0 * n1 - 2.0 < u1 < 3.0 * n1 + 2.0
            and -2.0 * n2 - 2.0 < u2 < 3.0 * n2 + 2.0):
        return _scan_all(q, best_d2, best_i, spts, sidx)
    c0 = np.int64(math.floor(u0))
    c1 = np.int64(math.floor(u1))
    c2 = np.int64(math.floor(u2))
    # rings closer than the grid are empty; beyond kmax they are outside it
    k0 = max(np.int64(0), -c0, c0 - (n0 - 1), -c1, c1 - (n1 - 1), -c2, c2 - (n2 - 1))
    kmax = max(c0, n0 - 1 - c0, c1, n1 - 1 - c1, c2, n2 - 1 - c2)
    h2 = h * h
    k = k0
    while k <= kmax:
        if k > 0:
            # every point of ring k (and beyond) lies outside the block of rings 0..k-1
            lb = min(u0 - (c0 - k + 1), (c0 + k) - u0, u1 - (c1 - k + 1), (c1 + k) - u1)
            if d == 3:
                lb = min(lb, u2 - (c2 - k + 1), (c2 + k) - u2)
            lb = max(lb - _EPS_CELLS, 0.0)
            lb2 = lb * lb * h2
            if lb2 > best_d2 or (best_i < 0 and lb2 >= best_d2):
                break
        zlo = c2 - k if d == 3 else np.int64(0)
        zhi = c2 + k if d == 3 else np.int64(0)
        for iz in range(max(zlo, 0), min(zhi, n2 - 1) + 1):
            zface = d == 3 and (iz == zlo or iz == zhi)
            bz = _gap2(iz, u2) if d == 3 else 0.0
            for iy in range(max(c1 - k, 0), min(c1 + k, n1 - 1) + 1):
                yface = zface or iy == c1 - k or iy == c1 + k
                by = bz + _gap2(iy, u1)
                if by * h2 > best_d2:
                    continue
                step = 1 if (yface or k == 0) else 2 * k
                for ix in range(c0 - k, c0 + k + 1, step):
                    if ix < 0 or ix >= n0:
                        continue
                    if (by + _gap2(ix, u0)) * h2 > best_d2:
                        continue
                    key = ix + n0 * (iy + n1 * iz)
                    s0, s1 = _cell_range(key, hashed, start, tkeys, tcell)
                    # the plain scan written out here, as _scan_sorted's: calling one scan function per
                    # cell for both measured 1.5x slower on 2-D image clouds
                    if s1 - s0 <= SORTED_CELL_MIN:
                        for j in range(s0, s1):
                            diff = q[0] - spts[j, 0]
                            d2 = diff * diff
                            diff = q[1] - spts[j, 1]
                            d2 += diff * diff
                            if d == 3:
                                diff = q[2] - spts[j, 2]
                                d2 += diff * diff
                            if d2 <= best_d2:
                                i = sidx[j]
                                if d2 < best_d2 or (best_i >= 0 and i < best_i):
                                    best_d2 = d2
                                    best_i = i
                        continue
                    best_d2, best_i = _scan_sorted(q, spts, sidx, s0, s1, best_d2, best_i)
        k += 1
    return best_d2, best_i


@njit(cache=True)
def _scan_sorted(q, spts, sidx, s0, s1, best_d2, best_i):
    """:func:`_nearest`'s scan of a crowded cell ``s0..s1``, sorted by x: from the first point within
    reach of ``q[0]`` until the next is farther in x alone than the best so far (the same sums and tie
    rule as the plain scan). Returns the new ``(best_d2, best_i)``."""
    d = q.shape[0]
    reach = _reach(best_d2)
    for j in range(_first_at_least(spts, s0, s1, q[0] - reach), s1):
        if spts[j, 0] - q[0] > reach:
            break
        diff = q[0] - spts[j, 0]
        d2 = diff * diff
        diff = q[1] - spts[j, 1]
        d2 += diff * diff
        if d == 3:
            diff = q[2] - spts[j, 2]
            d2 += diff * diff
        if d2 <= best_d2:
            i = sidx[j]
            if d2 < best_d2 or (best_i >= 0 and i < best_i):
                best_d2 = d2
                best_i = i
                reach = _reach(best_d2)
    return best_d2, best_i


@njit(cache=True, inline="always")
def _reach(best_d2):
    """How far along x a point may lie from the query and still be at most ``best_d2`` away: a little
    more than ``sqrt(best_d2)`` (relative 1e-9 and absolute 1e-150 to spare), so that any point skipped
    beyond it has ``diff * diff > best_d2`` as the search computes it, rounding and underflow included,
    and can neither be nearer nor tie."""
    return math.sqrt(best_d2) * (1.0 + 1e-9) + 1e-150


@njit(cache=True, inline="always")
def _first_at_least(spts, lo, hi, x):
    """The first row in ``lo..hi`` (sorted by the first coordinate) whose first coordinate is >= ``x``
    (``hi`` if none): a binary search."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if spts[mid, 0] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _query_serial(queries, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed, out_d2, out_i):
    for t in range(queries.shape[0]):
        out_d2[t], out_i[t] = _nearest(queries[t], r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed)


@njit(cache=True, parallel=True)
def _query_parallel(queries, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed, out_d2, out_i):
    for t in prange(queries.shape[0]):
        out_d2[t], out_i[t] = _nearest(queries[t], r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed)


# ---------------------------------------------------------------------------------------------------
# one ICP iteration's correspondences and their moments
# ---------------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _move(pts, t, M, d):
    if d == 2:
        x, y = pts[t, 0], pts[t, 1]
        pts[t, 0] = M[0, 0] * x + M[0, 1] * y + M[0, 2]
        pts[t, 1] = M[1, 0] * x + M[1, 1] * y + M[1, 2]
    else:
        x, y, z = pts[t, 0], pts[t, 1], pts[t, 2]
        pts[t, 0] = M[0, 0] * x + M[0, 1] * y + M[0, 2] * z + M[0, 3]
        pts[t, 1] = M[1, 0] * x + M[1, 1] * y + M[1, 2] * z + M[1, 3]
        pts[t, 2] = M[2, 0] * x + M[2, 1] * y + M[2, 2] * z + M[2, 3]


@njit(cache=True)
def _move_query_serial(pts, M, move, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed, out_d2, out_i):
    for t in range(pts.shape[0]):
        if move:
            _move(pts, t, M, pts.shape[1])
        out_d2[t], out_i[t] = _nearest(pts[t], r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed)


@njit(cache=True, parallel=True)
def _move_query_parallel(pts, M, move, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed, out_d2, out_i):
    for t in prange(pts.shape[0]):
        if move:
            _move(pts, t, M, pts.shape[1])
        out_d2[t], out_i[t] = _nearest(pts[t], r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed)


@njit(cache=True)
def _moments(pts, target, out_d2, out_i, center):
    """Over the matched pairs (p = moved source point, q = its target), relative to ``center``:
    count, sum of d^2, sum p, sum q, sum |p|^2, sum q p^T."""
    d = pts.shape[1]
    k = 0
    sd2 = 0.0
    sp = np.zeros(d)
    sq = np.zeros(d)
    spp = 0.0
    sqp = np.zeros((d, d))
    for t in range(pts.shape[0]):
        j = out_i[t]
        if j < 0:
            continue
        k += 1
        sd2 += out_d2[t]
        for a in range(d):
            pa = pts[t, a] - center[a]
            sp[a] += pa
            spp += pa * pa
            qa = target[j, a] - center[a]
            sq[a] += qa
            for b in range(d):
                sqp[a, b] += qa * (pts[t, b] - center[b])
    return k, sd2, sp, sq, spp, sqp


@njit(cache=True)
def _move_match_moments_serial(pts, M, move, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed, out_d2,
                               out_i, target, center):
    """:func:`_move_query_serial` then :func:`_moments`, in one call (one dispatch from Python)."""
    _move_query_serial(pts, M, move, r2, spts, sidx, start, tkeys, tcell, origin, h, dims, hashed, out_d2, out_i)
    return _moments(pts, target, out_d2, out_i, center)


# ---------------------------------------------------------------------------------------------------
# the index
# ---------------------------------------------------------------------------------------------------

def squared_bound(max_distance: float) -> float:
    """The squared distance bound of a search: ``max_distance ** 2``, or inf where the distance is not
    finite (inf or NaN: no bound) or its square is beyond float range."""
    r = float(max_distance)
    return r * r if np.isfinite(r) else np.inf


class GridIndex:
    """Exact nearest-neighbour index of (M, 2|3) points on a uniform grid.

    points : (M, d) finite float64, d = 2 or 3, M >= 1.
    cell : cell side in the points' units. None: from the density, about :data:`POINTS_PER_CELL`
        points per cell of the bounding box, but at most ``max_distance`` when that is given (queries
        bounded by it then visit at most 3^d cells), and no less than :data:`MIN_CELL_OF_DENSITY` of it.
    max_distance : the distance bound the queries will mostly use (a hint for ``cell``).

    :meth:`query` answers like ``scipy.spatial.cKDTree.query`` with ``k=1``.
    """

    def __init__(self, points: np.ndarray, *, cell: float | None = None, max_distance: float | None = None) -> None:
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3) or pts.shape[0] < 1:
            raise ValueError(f"GridIndex needs an (M, 2|3) array with M >= 1, got shape {pts.shape}")
        m, d = pts.shape
        lo, hi = _bounds(pts)
        extent = hi - lo
        if cell is None:
            span = np.maximum(extent, 0.0)
            pos = span[span > 0]
            if pos.size == 0:
                cell = 1.0
            else:
                # cells of the occupied dimensions' volume shared among the points
                cell = float((np.prod(pos) * POINTS_PER_CELL / m) ** (1.0 / pos.size))
                cell = max(cell, float(pos.max()) / 2**20)
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
        :func:`_nearest` after the query and its bound, for kernels that search inside their own loop."""
        return (self._spts, self._sidx, self._start, self._tkeys, self._tcell, self.origin, self.cell, self.dims,
                self.hashed)

    def __repr__(self) -> str:
        return (f"GridIndex(n={self.n}, dim={self.dim}, cell={self.cell:.4g}, cells={'x'.join(map(str, self.dims))}, "
                f"{'hashed' if self.hashed else 'dense'})")

    def nearest(self, queries: np.ndarray, max_distance: float = np.inf, *, workers: int | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """Squared distance (K,) float64 and index (K,) int64 of each query's nearest point with
        ``d^2 < max_distance^2``; ``(max_distance^2, -1)`` where there is none.

        workers : threads (None: all of numba's where :func:`threaded` says so, else 1; 1 where
            :func:`can_thread` says no).
        """
        q = np.ascontiguousarray(queries, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != self.dim:
            raise ValueError(f"queries must be (K, {self.dim}), got shape {q.shape}")
        r2 = squared_bound(max_distance)
        out_d2 = np.empty(q.shape[0], np.float64)
        out_i = np.empty(q.shape[0], np.int64)
        args = (q, r2, *self.search_arrays, out_d2, out_i)
        parallel = (threaded(q.shape[0]) if workers is None else workers != 1) and can_thread()
        if parallel:
            _query_parallel(*args)
        else:
            _query_serial(*args)
        return out_d2, out_i

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

    def query(self, x: np.ndarray, k: int = 1, *, distance_upper_bound: float = np.inf, workers: int = 1, **_ignored
              ) -> tuple[np.ndarray, np.ndarray]:
        """As ``cKDTree.query(x, k=1, distance_upper_bound=...)``: (distances, indices), ``inf`` and ``n``
        where no point is closer than the bound."""
        if k != 1:
            raise ValueError("GridIndex answers k=1 queries only")
        x = np.asarray(x, dtype=np.float64)
        single = x.ndim == 1
        d2, idx = self.nearest(x[None] if single else x, distance_upper_bound,
                               workers=None if workers in (-1, None) else workers)
        miss = idx < 0
        dist = np.sqrt(d2)
        dist[miss] = np.inf
        idx[miss] = self.n
        return (dist[0], idx[0]) if single else (dist, idx)


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


def _bench(n: int = 20000, repeats: int = 7) -> None:  # pragma: no cover - a measurement, not a test
    import time

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
        s = build()
        run(s)
        tb, tq = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            s = build()
            t1 = time.perf_counter()
            run(s)
            t2 = time.perf_counter()
            tb.append(t1 - t0)
            tq.append(t2 - t1)
        rows[name] = (np.median(tb) * 1e3, np.median(tq) / n * 1e6)
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
