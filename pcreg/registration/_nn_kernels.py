"""The compiled kernels of the exact nearest-neighbour grid (:mod:`pcreg.registration.nn`): the counting
sort that builds it, one query's ring search, the loops over queries (one thread and numba's threads)
and one ICP iteration's moves, matches and moments. :class:`~pcreg.registration.nn.GridIndex` holds
their arrays; the reference ICP's compiled loop (:mod:`pcreg.registration.reference`) inlines the search.

Where a loop is compiled twice, once on one thread and once with ``parallel=True`` (``_query_serial`` /
``_query_parallel``, ``_move_query_serial`` / ``_move_query_parallel``), its body is one line calling the
same inlined search: numba keys its on-disk cache by the function, not by its options, so one Python
function compiled both ways would share (and overwrite) one cache entry.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit, prange

#: A cell holding more points than this is kept sorted by the first coordinate, and a query reads only
#: its points within reach along that axis: from the first within reach of its x (a binary search)
#: until the next point is farther in x alone than the best so far. LiDAR scans crowd some cells of a
#: uniform grid (on the LiDAR pair the largest holds 1,856 distinct points, and 5,032 copies of one
#: point before :func:`_build` keeps it once). 64: image clouds (edge points on the pixel lattice)
#: have cells of up to about 40 points, where the sorted path measured slower than a plain scan.
SORTED_CELL_MIN = 64

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
                    # the plain scan written out here, each point through the inlined _closer: calling one
                    # scan function per cell for both measured 1.5x slower on 2-D image clouds
                    if s1 - s0 <= SORTED_CELL_MIN:
                        for j in range(s0, s1):
                            best_d2, best_i = _closer(q, spts, sidx, j, best_d2, best_i)
                        continue
                    best_d2, best_i = _scan_sorted(q, spts, sidx, s0, s1, best_d2, best_i)
        k += 1
    return best_d2, best_i


@njit(cache=True)
def _scan_sorted(q, spts, sidx, s0, s1, best_d2, best_i):
    """:func:`_nearest`'s scan of a crowded cell ``s0..s1``, sorted by x: from the first point within
    reach of ``q[0]`` until the next is farther in x alone than the best so far (the same sums and tie
    rule as the plain scan). Returns the new ``(best_d2, best_i)``."""
    reach = _reach(best_d2)
    for j in range(_first_at_least(spts, s0, s1, q[0] - reach), s1):
        if spts[j, 0] - q[0] > reach:
            break
        d2, i = _closer(q, spts, sidx, j, best_d2, best_i)
        if i != best_i:  # a nearer point, or as near with a lower index (indices in a cell are distinct)
            best_d2 = d2
            best_i = i
            reach = _reach(best_d2)
    return best_d2, best_i


@njit(cache=True, inline="always")
def _closer(q, spts, sidx, j, best_d2, best_i):
    """Row ``j`` of the sorted points against the best so far: its squared distance to ``q``,
    ``dx*dx + dy*dy (+ dz*dz)`` in that order, and the new ``(best_d2, best_i)``: row ``j``'s where it is
    nearer, or as near with a lower index (the tie rule), else the old. Inlined into both scans of
    :func:`_nearest` (the plain and the sorted)."""
    diff = q[0] - spts[j, 0]
    d2 = diff * diff
    diff = q[1] - spts[j, 1]
    d2 += diff * diff
    if q.shape[0] == 3:
        diff = q[2] - spts[j, 2]
        d2 += diff * diff
    if d2 <= best_d2:
        i = sidx[j]
        if d2 < best_d2 or (best_i >= 0 and i < best_i):
            return d2, i
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

