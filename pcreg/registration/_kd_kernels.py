"""The compiled kernels of the exact nearest-neighbour KD-tree (:mod:`pcreg.registration.kdtree`): its
build, one query's descent, the loops over queries (one thread and numba's threads) and one ICP
iteration's moves and matches. :class:`~pcreg.registration.kdtree.KDTreeIndex` holds their arrays; the
reference ICP's compiled loops (:mod:`pcreg.registration.reference`) inline the search.

The tree's nodes are one (K, 4) float64 array, in depth-first order (a node's first child is the next
node): an inner node is ``[low, high, axis, second child]``, where ``low`` is the largest coordinate
along ``axis`` of its first child's points and ``high`` the smallest of its second child's; a leaf is
``[first row, end row, -1, -1]`` of the points, which are stored in the leaves' order.

Where a loop is compiled twice (one thread, and ``parallel=True``), its body is a call of the same
inlined search: numba keys its on-disk cache by the function, not by its options.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit, prange
from ._nn_kernels import _move

#: Above this depth a node is split at its median instead of the middle of its widest side, so that no
#: input makes the tree deeper than this plus log2 of its points (the stacks below are sized by it).
MIDDLE_SPLIT_DEPTH = 48
#: Queries handed to a thread at a time by the threaded loops (each chunk allocates one search stack).
CHUNK = 256


# ---------------------------------------------------------------------------------------------------
# build
# ---------------------------------------------------------------------------------------------------

@njit(cache=True)
def _build(points, leaf):
    """The tree of (M, d) finite points, M >= 1: (nodes (K, 4), the points in the leaves' order, their
    original indices, the depth). A node of at most ``leaf`` points is a leaf; a node whose points are
    all the same point is a leaf of one row, that of the lowest index (a LiDAR scan can return
    thousands of copies of one point, and each would tie with the others in every search near it).

    A node is split across its widest side at the middle of its points' extent (a sliding midpoint: the
    cut moves to the nearest point, so neither side is empty), which adapts the cells to points on
    surfaces; below :data:`MIDDLE_SPLIT_DEPTH`, at the median."""
    m, d = points.shape
    wp = points.copy()
    widx = np.arange(m)
    nodes = np.empty((2 * m + 1, 4), np.float64)
    # a stack of nodes to make: (first row, end row, parent whose second child it is or -1, depth)
    todo = np.empty((MIDDLE_SPLIT_DEPTH + 130, 4), np.int64)
    todo[0, 0], todo[0, 1], todo[0, 2], todo[0, 3] = 0, m, -1, 0
    sp = 1
    n_nodes = 0
    depth = 0
    lo = np.empty(d)
    hi = np.empty(d)
    while sp > 0:
        sp -= 1
        s, e, parent, level = todo[sp, 0], todo[sp, 1], todo[sp, 2], todo[sp, 3]
        node = n_nodes
        n_nodes += 1
        if parent >= 0:
            nodes[parent, 3] = node
        depth = max(depth, level)
        axis, spread = _widest(wp, s, e, lo, hi)
        if e - s <= leaf or spread == 0.0:
            nodes[node, 0], nodes[node, 1], nodes[node, 2], nodes[node, 3] = s, e, -1.0, -1.0
            if spread == 0.0:  # one point, repeated: keep its lowest index, in the node's first row
                k = s
                for t in range(s + 1, e):
                    if widx[t] < widx[k]:
                        k = t
                widx[s] = widx[k]
                nodes[node, 1] = s + 1
            continue
        if level < MIDDLE_SPLIT_DEPTH:
            mid, low, high = _split_middle(wp, widx, s, e, axis, lo[axis], hi[axis])
        else:
            mid, low, high = _split_median(wp, widx, s, e, axis)
        nodes[node, 0], nodes[node, 1], nodes[node, 2] = low, high, axis
        todo[sp, 0], todo[sp, 1], todo[sp, 2], todo[sp, 3] = mid, e, node, level + 1
        todo[sp + 1, 0], todo[sp + 1, 1], todo[sp + 1, 2], todo[sp + 1, 3] = s, mid, -1, level + 1
        sp += 2  # the first child is made next, so it is node + 1
    return nodes[:n_nodes].copy(), wp, widx, depth


@njit(cache=True)
def _widest(wp, s, e, lo, hi):
    """The axis of the widest extent of rows ``s..e`` and that extent; ``lo`` / ``hi`` get the bounds."""
    d = wp.shape[1]
    for a in range(d):
        lo[a] = wp[s, a]
        hi[a] = wp[s, a]
    for t in range(s + 1, e):
        for a in range(d):
            v = wp[t, a]
            if v < lo[a]:
                lo[a] = v
            elif v > hi[a]:
                hi[a] = v
    axis = 0
    spread = hi[0] - lo[0]
    for a in range(1, d):
        if hi[a] - lo[a] > spread:
            spread = hi[a] - lo[a]
            axis = a
    return axis, spread


@njit(cache=True)
def _split_middle(wp, widx, s, e, axis, vmin, vmax):
    """Rows ``s..e`` partitioned in place: those below the middle of ``[vmin, vmax]`` (vmin < vmax)
    first. Returns (the first row of the second part, the largest coordinate of the first part, the
    smallest of the second)."""
    d = wp.shape[1]
    cut = 0.5 * (vmin + vmax)
    if not (vmin < cut < vmax):  # vmax is the next float after vmin
        cut = vmax
    i, j = s, e - 1
    low, high = -np.inf, np.inf
    while i <= j:
        v = wp[i, axis]
        if v < cut:
            low = max(low, v)
            i += 1
        else:
            high = min(high, v)
            for a in range(d):
                wp[i, a], wp[j, a] = wp[j, a], wp[i, a]
            widx[i], widx[j] = widx[j], widx[i]
            j -= 1
    return i, low, high


@njit(cache=True)
def _split_median(wp, widx, s, e, axis):
    """Rows ``s..e`` sorted along ``axis`` and cut in half (equal coordinates may fall on both sides)."""
    order = np.argsort(wp[s:e, axis], kind="mergesort") + s
    wp[s:e] = wp[order]
    widx[s:e] = widx[order]
    mid = (s + e) // 2
    return mid, wp[mid - 1, axis], wp[mid, axis]


# ---------------------------------------------------------------------------------------------------
# one query
# ---------------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _nearest(q, best_d2, best_i, nodes, spts, sidx, stack_node, stack_gap):
    """(squared distance, index) of the nearest point nearer than ``best_d2`` (or as near with an index
    below ``best_i``), else ``(best_d2, best_i)``: called with ``(r2, -1)`` it is the nearest point with
    d^2 < r2. Exact, ties to the lowest index.

    Depth first, the query's side of each cut first; the other side is stacked with its lower bound,
    the sum of the squared gaps along each axis to the nearest cut seen on the way (``stack_gap``: the
    three gaps and the bound; ``stack_node``: the node). Each gap is ``fl(cut - q)`` for a cut no farther
    than the points beyond it, so in floating point it is at most ``fl(p - q)`` for each of them, and the
    bound, summed in the search's order, at most their computed ``d^2``: a node is skipped only where
    none of its points can be nearer, or tie."""
    d = q.shape[0]
    sp = 0
    node = 0
    g0 = 0.0
    g1 = 0.0
    g2 = 0.0
    while True:
        while nodes[node, 2] >= 0.0:
            a = np.int64(nodes[node, 2])
            qa = q[a]
            low = nodes[node, 0]
            high = nodes[node, 1]
            if (qa - low) + (qa - high) < 0.0:
                near, far, gap = node + 1, np.int64(nodes[node, 3]), high - qa
            else:
                near, far, gap = np.int64(nodes[node, 3]), node + 1, qa - low
            f0 = max(g0, gap) if a == 0 else g0
            f1 = max(g1, gap) if a == 1 else g1
            f2 = max(g2, gap) if a == 2 else g2
            lb = f0 * f0 + f1 * f1
            if d == 3:
                lb += f2 * f2
            if lb < best_d2 or (lb == best_d2 and best_i >= 0):
                stack_node[sp] = far
                stack_gap[sp, 0], stack_gap[sp, 1], stack_gap[sp, 2], stack_gap[sp, 3] = f0, f1, f2, lb
                sp += 1
            node = near
        for j in range(np.int64(nodes[node, 0]), np.int64(nodes[node, 1])):
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
        while True:  # the next stacked node that may still hold a nearer (or tying) point
            if sp == 0:
                return best_d2, best_i
            sp -= 1
            lb = stack_gap[sp, 3]
            if lb < best_d2 or (lb == best_d2 and best_i >= 0):
                break
        node = stack_node[sp]
        g0, g1, g2 = stack_gap[sp, 0], stack_gap[sp, 1], stack_gap[sp, 2]


@njit(cache=True, inline="always")
def _stacks(depth):
    return np.empty(depth + 2, np.int64), np.empty((depth + 2, 4), np.float64)


@njit(cache=True)
def _query_serial(queries, r2, nodes, spts, sidx, depth, out_d2, out_i):
    stack_node, stack_gap = _stacks(depth)
    for t in range(queries.shape[0]):
        out_d2[t], out_i[t] = _nearest(queries[t], r2, np.int64(-1), nodes, spts, sidx, stack_node, stack_gap)


@njit(cache=True, parallel=True)
def _query_parallel(queries, r2, nodes, spts, sidx, depth, out_d2, out_i):
    n = queries.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        stack_node, stack_gap = _stacks(depth)
        for t in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            out_d2[t], out_i[t] = _nearest(queries[t], r2, np.int64(-1), nodes, spts, sidx, stack_node, stack_gap)


# ---------------------------------------------------------------------------------------------------
# one ICP iteration's correspondences (the moments: pcreg.registration._nn_kernels._moments)
# ---------------------------------------------------------------------------------------------------

@njit(cache=True)
def _move_query_serial(pts, M, move, r2, nodes, spts, sidx, depth, out_d2, out_i):
    """Move each of ``pts`` in place by ``M`` (where ``move``) and find its nearest target point."""
    stack_node, stack_gap = _stacks(depth)
    for t in range(pts.shape[0]):
        if move:
            _move(pts, t, M, pts.shape[1])
        out_d2[t], out_i[t] = _nearest(pts[t], r2, np.int64(-1), nodes, spts, sidx, stack_node, stack_gap)


@njit(cache=True, parallel=True)
def _move_query_parallel(pts, M, move, r2, nodes, spts, sidx, depth, out_d2, out_i):
    n = pts.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        stack_node, stack_gap = _stacks(depth)
        for t in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if move:
                _move(pts, t, M, pts.shape[1])
            out_d2[t], out_i[t] = _nearest(pts[t], r2, np.int64(-1), nodes, spts, sidx, stack_node, stack_gap)
