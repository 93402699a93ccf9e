"""Compiled passes of the many-class read-out (:mod:`pcreg.pipeline.multiclass`): each reads an (H, W, K)
map once, where numpy's ``argmax``, ``take_along_axis`` and one-hot arrays would read and write it
several times (an eleven-class frame at 640x480 is 13.5 MB a map). Each pass takes blocks of rows,
``first, first + stride, ...`` (:data:`BLOCK_ROWS` rows a block), and writes each pixel's output in its own
place, so that a large frame's rows are shared with the helper thread (:func:`pcreg._threads.interleave`)
with the same result to the bit."""

from __future__ import annotations

import numpy as np

from .._jit import njit
from .readout import Scratch, empty

__all__ = ["top_two", "purities", "best_agreement", "fuse_classes", "fuse_and_mark", "carried_best", "class_window",
           "penalised", "remap_classes", "remap_labels", "log_margins", "logistic_confidence", "iou_sums", "BLOCK_ROWS"]

#: Rows per block of the passes (two threads take alternate blocks).
BLOCK_ROWS = 16

def _top_two_py(S, best, second, margin, first, stride):
    h, w, k = S.shape
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for j in range(w):
                vb = S[i, j, 0]
                bb = 0
                s = 0
                vs = vb
                if k > 1:  # the runner-up starts as the other of the first two
                    v = S[i, j, 1]
                    if v > vb:
                        bb, vb, s, vs = 1, v, 0, vb
                    else:
                        s, vs = 1, v
                for c in range(2, k):
                    v = S[i, j, c]
                    if v > vb:
                        s, vs = bb, vb
                        bb, vb = c, v
                    elif v > vs:
                        s, vs = c, v
                best[i, j] = bb
                second[i, j] = s
                margin[i, j] = vb - vs


def _carried_best_py(prior, weight, log_pi, least, carried, first, stride):
    h, w, k = prior.shape
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for j in range(w):
                inv = np.float32(1.0) / max(weight[i, j], least)
                bb = 0
                vb = prior[i, j, 0] * inv + log_pi[0]
                for c in range(1, k):
                    v = prior[i, j, c] * inv + log_pi[c]
                    if v > vb:
                        bb, vb = c, v
                carried[i, j] = bb


def _window_rows_py(carried, r, bits, first, stride):
    """Each row's classes within ``r`` px of each pixel along the row: ``bits`` (H, W, words) uint64, bit
    ``c % 64`` of word ``c // 64`` set when class index ``c`` of ``carried`` (H, W) is in the row's window
    (van Herk's running OR over blocks of ``2 r + 1``, the row padded with no class), a word at a time."""
    h, w = carried.shape
    words = bits.shape[2]
    s = 2 * r + 1
    n = w + 2 * r
    one, zero = np.uint64(1), np.uint64(0)
    pre = np.zeros(n, np.uint64)
    suf = np.zeros(n, np.uint64)
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for q in range(words):
                at = 0  # x % s
                for x in range(n):  # the padded row's class bit, ORed from each block's start
                    j = x - r
                    v = zero
                    if 0 <= j < w:
                        c = carried[i, j]
                        if c >> 6 == q:
                            v = one << np.uint64(c & 63)
                    suf[x] = v
                    pre[x] = v if at == 0 else pre[x - 1] | v
                    at = 0 if at == s - 1 else at + 1
                for start in range(0, n, s):  # ORed from each block's end
                    for x in range(min(start + s, n) - 2, start - 1, -1):
                        suf[x] |= suf[x + 1]
                for j in range(w):  # the window [j - r, j + r] is [j, j + s - 1] padded
                    bits[i, j, q] = suf[j] | pre[j + s - 1]


def _window_cols_py(rows, r, bits, pre, suf, first, stride):
    """:func:`_window_rows_py` down the columns of its output ``rows`` (H, W x words, flattened): ``bits``
    the classes within the square of side ``2 r + 1`` around each pixel. ``pre``, ``suf``: (H + 2 r,
    W x words) scratch. The columns are shared in ``stride`` contiguous parts (``first`` this call's)."""
    h, m = rows.shape
    s = 2 * r + 1
    n = h + 2 * r
    part = (m + stride - 1) // stride
    b, e = first * part, min(m, (first + 1) * part)
    zero = np.uint64(0)
    for y in range(n):
        i = y - r
        if 0 <= i < h:
            if y % s == 0:
                for j in range(b, e):
                    pre[y, j] = rows[i, j]
                    suf[y, j] = rows[i, j]
            else:
                for j in range(b, e):
                    pre[y, j] = pre[y - 1, j] | rows[i, j]
                    suf[y, j] = rows[i, j]
        else:
            for j in range(b, e):
                pre[y, j] = zero if y % s == 0 else pre[y - 1, j]
                suf[y, j] = zero
    for start in range(0, n, s):
        for y in range(min(start + s, n) - 2, start - 1, -1):
            for j in range(b, e):
                suf[y, j] |= suf[y + 1, j]
    for i in range(h):
        for j in range(b, e):
            bits[i, j] = suf[i, j] | pre[i + s - 1, j]


def _penalised_py(fused, allowed, weight, untrusted, penalty, out, first, stride):
    h, w, k = fused.shape
    one = np.uint64(1)
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for j in range(w):
                if weight[i, j] <= untrusted:  # every class allowed
                    for c in range(k):
                        out[i, j, c] = fused[i, j, c]
                elif k <= 64:  # one word of bits, read once (a third less time than a word a class)
                    m = allowed[i, j, 0]
                    for c in range(k):
                        v = fused[i, j, c]
                        out[i, j, c] = v if (m >> np.uint64(c)) & one else v - penalty
                else:
                    for c in range(k):
                        v = fused[i, j, c]
                        shown = (allowed[i, j, c >> 6] >> np.uint64(c & 63)) & one
                        out[i, j, c] = v if shown else v - penalty


def _reflected_py(p, n):
    """OpenCV's ``BORDER_REFLECT`` position (``fedcba|abcdefgh|hgfedcb``) of ``p`` in ``n`` items."""
    if n == 1:
        return 0
    while p < 0 or p >= n:
        p = -p - 1 if p < 0 else 2 * n - p - 1
    return p


def _purities_py(best, k, sides, own, out):
    """The share of each half-size pixel's neighbourhood with its own label, for each box of ``sides``
    (odd): ``own`` (h/2, w/2) the plurality of each 2x2 block of ``best`` (H, W) (the first of equals), and
    ``out[s]`` (h/2, w/2) float32 the mean over the box of the blocks' shares of it, borders reflected: what
    OpenCV's ``blur`` of the blocks' K shares gives at the own class (its sums in float64, exact for
    quarters, times 1 / side^2), from one table of sums per class."""
    h, w = best.shape
    hh, hw = own.shape
    counts = np.zeros(k, np.int32)
    for i in range(hh):  # each block's plurality
        for j in range(hw):
            for di in range(2):
                for dj in range(2):
                    y, x = 2 * i + di, 2 * j + dj
                    if y < h and x < w:
                        counts[best[y, x]] += 1
            bb, vb = 0, counts[0]
            for c in range(1, k):
                if counts[c] > vb:
                    bb, vb = c, counts[c]
            own[i, j] = bb
            for di in range(2):
                for dj in range(2):
                    y, x = 2 * i + di, 2 * j + dj
                    if y < h and x < w:
                        counts[best[y, x]] = 0
    r = 0
    for kk in sides:
        r = max(r, kk // 2)
    ph, pw = hh + 2 * r, hw + 2 * r
    rows = np.empty(ph, np.int64)
    cols = np.empty(pw, np.int64)
    for y in range(ph):
        rows[y] = _reflected(y - r, hh)
    for x in range(pw):
        cols[x] = _reflected(x - r, hw)
    table = np.empty((ph + 1, pw + 1, k), np.int32)  # the reflected blocks' counts over [0, y) x [0, x)
    table[0] = 0
    for y in range(ph):
        for c in range(k):
            counts[c] = 0  # the row's running counts
            table[y + 1, 0, c] = 0
        by = 2 * rows[y]
        for x in range(pw):
            bx = 2 * cols[x]
            for di in range(2):
                for dj in range(2):
                    if by + di < h and bx + dj < w:
                        counts[best[by + di, bx + dj]] += 1
            for c in range(k):
                table[y + 1, x + 1, c] = table[y, x + 1, c] + counts[c]
    for n in range(len(sides)):
        q = sides[n] // 2
        scale = 1.0 / (sides[n] * sides[n])
        for i in range(hh):
            y0, y1 = i - q + r, i + q + r + 1
            for j in range(hw):
                x0, x1 = j - q + r, j + q + r + 1
                c = own[i, j]
                total = table[y1, x1, c] - table[y0, x1, c] - table[y1, x0, c] + table[y0, x0, c]
                out[n, i, j] = np.float32(np.float64(total) * 0.25 * scale)


def _best_agreement_py(d, p, out, first, stride):
    h, w, k = d.shape
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for j in range(w):
                bd, bp = 0, 0
                vd, vp = d[i, j, 0], p[i, j, 0]
                for c in range(1, k):
                    if d[i, j, c] > vd:
                        bd, vd = c, d[i, j, c]
                    if p[i, j, c] > vp:
                        bp, vp = c, p[i, j, c]
                out[i, j] = 1.0 if bd == bp else 0.0


def _fuse_classes_py(d, w1, l1, w2, l2, ws, log_pi, least, fused, prior, carried, agree, first, stride):
    """``prior = w1 l1 + w2 l2`` and ``fused = d + prior`` per class; with ``carried`` (else None, as ``ws``,
    ``log_pi``, ``agree``) also, from the same values, what :func:`_carried_best_py` and
    :func:`_best_agreement_py` write of ``prior`` and ``d``."""
    h, w, k = d.shape
    zero, one = np.float32(0.0), np.float32(1.0)
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for j in range(w):
                a = w1[i, j]
                bw = zero if w2 is None else w2[i, j]
                inv = one if carried is None else one / max(ws[i, j], least)
                bc, bp, bd = 0, 0, 0
                vc, vp, vd = zero, zero, zero
                for c in range(k):
                    p = a * l1[i, j, c]
                    if w2 is not None:
                        p += bw * l2[i, j, c]
                    prior[i, j, c] = p
                    dc = d[i, j, c]
                    fused[i, j, c] = dc + p
                    if carried is None:
                        pass
                    else:
                        v = p * inv + log_pi[c]
                        if c == 0:
                            vc, vp, vd = v, p, dc
                        else:
                            if v > vc:
                                bc, vc = c, v
                            if p > vp:
                                bp, vp = c, p
                            if dc > vd:
                                bd, vd = c, dc
                if carried is None:
                    pass
                else:
                    carried[i, j] = bc
                    agree[i, j] = 1.0 if bd == bp else 0.0


def _taps_py(fx, fy, h, w):
    """Where OpenCV's bilinear ``remap`` reads the position (fx, fy) of an (h, w) map, to the bit: the top-left
    neighbour (sx, sy) of the position rounded to 1/32 px (half to even), the four weights (products of ``1 - t``
    and ``t``, t = k/32) and which of the four neighbours lie inside the map (bits 1, 2, 4, 8 in OpenCV's order);
    a position far outside, or NaN, has none inside and weights 0."""
    one, zero, scale, inv = np.float32(1.0), np.float32(0.0), np.float32(32.0), np.float32(1.0 / 32.0)
    if not (fx > -2.0 and fx < w + 1.0 and fy > -2.0 and fy < h + 1.0):
        return 0, 0, zero, zero, zero, zero, 0
    X, Y = int(np.rint(fx * scale)), int(np.rint(fy * scale))
    sx, sy = X >> 5, Y >> 5
    ax, ay = np.float32(X & 31) * inv, np.float32(Y & 31) * inv
    inside = 15
    if not (0 <= sy and sy + 1 < h and 0 <= sx and sx + 1 < w):  # at the map's edge
        in0, in1, inl, inr = 0 <= sy < h, 0 <= sy + 1 < h, 0 <= sx < w, 0 <= sx + 1 < w
        inside = (in0 and inl) * 1 + (in0 and inr) * 2 + (in1 and inl) * 4 + (in1 and inr) * 8
    return sx, sy, (one - ay) * (one - ax), (one - ay) * ax, ay * (one - ax), ay * ax, inside


def _remap_classes_py(src, fld, out, first, stride):
    """OpenCV's bilinear ``remap`` of a float32 map of K channels (K not 1, 3 or 4) with a float32 field and
    a constant border of 0, to the bit (:func:`_taps_py`): the four neighbours summed in OpenCV's order, a
    neighbour outside the map counted as 0."""
    k, h, w, zero = src.shape[2], src.shape[0], src.shape[1], np.float32(0.0)
    for b in range(first * BLOCK_ROWS, fld.shape[0], stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, fld.shape[0])):
            for j in range(fld.shape[1]):
                sx, sy, w0, w1, w2, w3, inside = _taps(fld[i, j, 0], fld[i, j, 1], h, w)
                if inside == 15:
                    for c in range(k):
                        out[i, j, c] = (src[sy, sx, c] * w0 + src[sy, sx + 1, c] * w1 + src[sy + 1, sx, c] * w2
                                        + src[sy + 1, sx + 1, c] * w3)
                    continue
                for c in range(k):
                    v0 = src[sy, sx, c] if inside & 1 else zero
                    v1 = src[sy, sx + 1, c] if inside & 2 else zero
                    v2 = src[sy + 1, sx, c] if inside & 4 else zero
                    v3 = src[sy + 1, sx + 1, c] if inside & 8 else zero
                    out[i, j, c] = v0 * w0 + v1 * w1 + v2 * w2 + v3 * w3


def _remap_labels_py(table, lab, fld, out, first, stride):
    """:func:`_remap_classes_py` of the map ``table[lab]`` (``lab`` (H, W) uint8, ``table`` (257, K) float32
    whose last row is 0), the same numbers: each neighbour's values read from its label's row, a neighbour
    outside the map from the row of zeros (``0 * weight`` is the 0 the map's border adds, so no test a
    class: about 0.6 of the time)."""
    k, h, w = table.shape[1], lab.shape[0], lab.shape[1]
    for b in range(first * BLOCK_ROWS, fld.shape[0], stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, fld.shape[0])):
            for j in range(fld.shape[1]):
                sx, sy, w0, w1, w2, w3, inside = _taps(fld[i, j, 0], fld[i, j, 1], h, w)
                l0 = lab[sy, sx] if inside & 1 else 256  # 256: outside, the table's row of zeros
                l1 = lab[sy, sx + 1] if inside & 2 else 256
                l2 = lab[sy + 1, sx] if inside & 4 else 256
                l3 = lab[sy + 1, sx + 1] if inside & 8 else 256
                for c in range(k):
                    out[i, j, c] = table[l0, c] * w0 + table[l1, c] * w1 + table[l2, c] * w2 + table[l3, c] * w3


def _log_margin_py(margin, out, first, stride):
    """``out = log1p(max(margin, 0))`` (float32; a NaN stays NaN, as numpy's ``maximum`` and ``log1p``)."""
    h, w = margin.shape
    zero = np.float32(0.0)
    for r in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(r, min(r + BLOCK_ROWS, h)):
            for j in range(w):
                v = margin[i, j]
                out[i, j] = np.log1p(zero if v < zero else v)


def _negative_logit_py(z, log_margin, piece, c, a, b, first, stride):
    """In place, ``z = -clip(z + (c piece) log_margin + (a log_margin + b), -60, 60)`` (float32, in numpy's
    order: ``z += c * piece * log_margin`` first; no ``piece`` term when it is None; a NaN stays NaN)."""
    h, w = z.shape
    lo, hi = np.float32(-60.0), np.float32(60.0)
    for r in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(r, min(r + BLOCK_ROWS, h)):
            for j in range(w):
                v = z[i, j]
                if piece is not None:
                    v = v + c * piece[i, j] * log_margin[i, j]
                t = a * log_margin[i, j] + b
                v = v + t
                v = lo if v < lo else (hi if v > hi else v)
                z[i, j] = -v


def _logistic_py(e, least, first, stride):
    """In place, ``e = max(1 / (e + 1), least)`` (float32; a NaN stays NaN)."""
    h, w = e.shape
    one = np.float32(1.0)
    for r in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(r, min(r + BLOCK_ROWS, h)):
            for j in range(w):
                c = one / (e[i, j] + one)
                e[i, j] = least if c < least else c


def _iou_sums_py(labels, confidence, second, tp, fp, fn):
    """Per class id, in float64 and pixel order (as ``np.bincount`` with weights sums): the confidence over
    the pixels labelled with it (``tp``), one minus it there (``fp``) and over the pixels whose runner-up it
    is (``fn``)."""
    one = 1.0
    for i in range(labels.size):
        c = np.float64(confidence[i])
        tp[labels[i]] += c
        fp[labels[i]] += one - c
        fn[second[i]] += one - c


_top_two = njit(cache=True, nogil=True)(_top_two_py)
_iou_sums = njit(cache=True, nogil=True)(_iou_sums_py)
_negative_logit = njit(cache=True, nogil=True)(_negative_logit_py)
_log_margin = njit(cache=True, nogil=True)(_log_margin_py)
_logistic = njit(cache=True, nogil=True)(_logistic_py)
_reflected = njit(cache=True, nogil=True)(_reflected_py)
_purities = njit(cache=True, nogil=True)(_purities_py)
_best_agreement = njit(cache=True, nogil=True)(_best_agreement_py)
_carried_best = njit(cache=True, nogil=True)(_carried_best_py)
_window_rows = njit(cache=True, nogil=True)(_window_rows_py)
_window_cols = njit(cache=True, nogil=True)(_window_cols_py)
_penalised = njit(cache=True, nogil=True)(_penalised_py)
_fuse_classes = njit(cache=True, nogil=True)(_fuse_classes_py)
_taps = njit(cache=True, nogil=True, inline="always")(_taps_py)
_remap_classes = njit(cache=True, nogil=True)(_remap_classes_py)
_remap_labels = njit(cache=True, nogil=True)(_remap_labels_py)


def _rows(kernel, shape: tuple[int, ...], *args) -> None:
    """``kernel(*args, first, stride)`` over the rows of a map of ``shape``, shared with the helper thread on
    large maps (:func:`pcreg._threads.interleave`)."""
    from .._threads import MIN_PIXELS, interleave

    interleave(shape[0] * shape[1], lambda first, stride: kernel(*args, first, stride), min_items=MIN_PIXELS)


def top_two(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(best, second, margin)`` per pixel of (H, W, K) float32 scores: the best class's index (the first
    of equals), the runner-up's, and the best score minus the runner-up's."""
    S = np.ascontiguousarray(S, dtype=np.float32)
    h, w = S.shape[:2]
    best, second = np.empty((h, w), np.intp), np.empty((h, w), np.intp)
    margin = np.empty((h, w), np.float32)
    _rows(_top_two, S.shape, S, best, second, margin)
    return best, second, margin


def purities(best: np.ndarray, k: int, sides: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(own, shares)``: each 2x2 block's plurality class index of ``best`` (H, W) (the first of equals),
    (H/2, W/2) intp, and for each odd box side of ``sides`` the share of the box around each block held by
    the block's own class, (len(sides), H/2, W/2) float32: what OpenCV's ``blur`` (borders reflected) of the
    K one-hot maps at half size (each block's share of each class) reads at the own class, to the bit,
    without the K maps."""
    h, w = best.shape
    if not 1 <= k <= 256 or any(s < 1 or s % 2 == 0 for s in sides):
        raise ValueError("purities takes 1 to 256 classes and odd sides")  # a caller's bug
    own = np.empty((max(1, h // 2), max(1, w // 2)), np.intp)
    out = np.empty((len(sides),) + own.shape, np.float32)
    _purities(np.ascontiguousarray(best, np.intp), k, np.asarray(sides, np.int64), own, out)
    return own, out


def best_agreement(d: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(H, W) float32: 1 where the best class of ``d`` is the best class of ``p`` ((H, W, K) each), else 0."""
    out = np.empty(d.shape[:2], np.float32)
    _rows(_best_agreement, d.shape, np.ascontiguousarray(d, np.float32), np.ascontiguousarray(p, np.float32), out)
    return out


def fuse_classes(d: np.ndarray, w1: np.ndarray, l1: np.ndarray, w2: np.ndarray | None,
                 l2: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(fused, prior)``, (H, W, K) float32: ``prior = w1 l1 + w2 l2`` per class (weights (H, W); the second
    pair may be None) and ``fused = d + prior``."""
    d = np.ascontiguousarray(d, np.float32)
    fused, prior = np.empty_like(d), np.empty_like(d)
    c = np.ascontiguousarray
    _rows(_fuse_classes, d.shape, d, c(w1, np.float32), c(l1, np.float32), None if w2 is None else c(w2, np.float32),
          None if l2 is None else c(l2, np.float32), None, None, None, fused, prior, None, None)
    return fused, prior


def fuse_and_mark(d: np.ndarray, w1: np.ndarray, l1: np.ndarray, w2: np.ndarray | None, l2: np.ndarray | None,
                  weight: np.ndarray, log_pi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(fused, prior, carried, agree)``: :func:`fuse_classes`, with in the same pass :func:`carried_best`
    of ``prior`` (``weight`` the (H, W) summed trust weight, ``log_pi`` (K,)) and :func:`best_agreement` of
    ``d`` and ``prior``, the same numbers as each apart."""
    d = np.ascontiguousarray(d, np.float32)
    fused, prior = np.empty_like(d), np.empty_like(d)
    carried, agree = np.empty(d.shape[:2], np.uint8), np.empty(d.shape[:2], np.float32)
    c = np.ascontiguousarray
    _rows(_fuse_classes, d.shape, d, c(w1, np.float32), c(l1, np.float32), None if w2 is None else c(w2, np.float32),
          None if l2 is None else c(l2, np.float32), c(weight, np.float32), c(log_pi, np.float32), np.float32(1e-6),
          fused, prior, carried, agree)
    return fused, prior, carried, agree


def carried_best(prior: np.ndarray, weight: np.ndarray, log_pi: np.ndarray) -> np.ndarray:
    """(H, W) uint8: the index of the best class of ``prior / weight + log_pi`` ((H, W, K) evidence, K at
    most 256; (H, W) summed trust weight, at least 1e-6; (K,) log class priors): the carried priors' own
    label, the first of equals."""
    carried = np.empty(prior.shape[:2], np.uint8)
    _rows(_carried_best, prior.shape, np.ascontiguousarray(prior, np.float32), np.ascontiguousarray(weight, np.float32),
          np.ascontiguousarray(log_pi, np.float32), np.float32(1e-6), carried)
    return carried


def class_window(carried: np.ndarray, k: int, side: int, *, scratch: Scratch | None = None) -> np.ndarray:
    """(H, W, ceil(K / 64)) uint64: the class indices of ``carried`` (H, W) uint8, each below ``k``, found
    within the square of ``side`` px (odd) centred on each pixel, as bits (class ``c``: bit ``c % 64`` of
    word ``c // 64``); what OpenCV's ``dilate`` of the K one-hot maps by that square gives, one bit a class
    (the area outside the map holds no class), in two passes of van Herk's running OR (rows, then columns),
    each shared with the helper thread. ``scratch``: where its arrays are kept between calls (the bits returned
    among them: read them before the next call)."""
    from .._threads import MIN_PIXELS, interleave

    lab = np.ascontiguousarray(carried, np.uint8)
    if side < 1 or side % 2 == 0 or not 1 <= k <= 256:
        raise ValueError("class_window takes an odd side and 1 to 256 classes")  # a caller's bug
    h, w = lab.shape
    r, words = side // 2, (k + 63) // 64
    rows = empty(scratch, "window rows", (h, w, words), np.uint64)
    _rows(_window_rows, lab.shape, lab, r, rows)
    flat, bits = rows.reshape(h, w * words), empty(scratch, "window bits", (h, w * words), np.uint64)
    pre = empty(scratch, "window pre", (h + 2 * r, w * words), np.uint64)
    suf = empty(scratch, "window suf", (h + 2 * r, w * words), np.uint64)
    interleave(h * w, lambda first, stride: _window_cols(flat, r, bits, pre, suf, first, stride), min_items=MIN_PIXELS)
    return bits.reshape(h, w, words)


def penalised(fused: np.ndarray, allowed: np.ndarray, weight: np.ndarray, untrusted: float,
              penalty: float, *, scratch: Scratch | None = None) -> np.ndarray:
    """(H, W, K) float32: ``fused`` lowered by ``penalty`` where a class is not ``allowed`` (its bit unset
    in the (H, W, words) uint64 of :func:`class_window`) and the pixel's summed trust ``weight`` is above
    ``untrusted``. ``scratch``: where the result is kept between calls (read it before the next call)."""
    out = empty(scratch, "penalised", fused.shape, np.float32)
    _rows(_penalised, fused.shape, np.ascontiguousarray(fused, np.float32), np.ascontiguousarray(allowed, np.uint64),
          np.ascontiguousarray(weight, np.float32), np.float32(untrusted), np.float32(penalty), out)
    return out


def remap_classes(values: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(h, w, K) float32: ``values`` (H, W, K) read at ``field`` (h, w, 2) float32 positions, bilinearly, 0
    outside: ``cv2.remap(values, field, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)`` to the
    bit, in one pass shared with the helper thread. OpenCV reads 1, 3 or 4 channels another way (its
    weights are not rounded to 1/32 px there): for those it is called itself."""
    src = np.ascontiguousarray(values, np.float32)
    fld = np.ascontiguousarray(field, np.float32)
    k = src.shape[2]
    if k in (1, 3, 4):
        import cv2

        out = cv2.remap(src, fld, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out.reshape(fld.shape[:2] + (k,))
    out = np.empty(fld.shape[:2] + (k,), np.float32)
    _rows(_remap_classes, fld.shape, src, fld, out)
    return out


def remap_labels(labels: np.ndarray, table: np.ndarray, field: np.ndarray) -> np.ndarray:
    """:func:`remap_classes` of ``table[labels]`` ((H, W) uint8 labels, (256, K) float32 table, K not 1, 3 or
    4), the same numbers, each neighbour's values read from its label's row of the table."""
    lab = np.ascontiguousarray(labels, np.uint8)
    tab = np.ascontiguousarray(table, np.float32)
    fld = np.ascontiguousarray(field, np.float32)
    if tab.shape[0] != 256 or tab.shape[1] in (1, 3, 4):
        raise ValueError("remap_labels takes a (256, K) table, K not 1, 3 or 4")  # a caller's bug
    out = np.empty(fld.shape[:2] + (tab.shape[1],), np.float32)
    table = np.zeros((257, tab.shape[1]), np.float32)  # row 256: a neighbour outside the map
    table[:256] = tab
    _rows(_remap_labels, fld.shape, table, lab, fld, out)
    return out


def iou_sums(labels: np.ndarray, confidence: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(tp, fp, fn)``, (256,) float64 each, by class id: the sums of ``confidence`` over each label's pixels,
    of one minus it there, and of one minus it over the pixels whose runner-up (``second``) is the class; the
    numbers ``np.bincount`` with weights gives, in one pass without its float64 copies."""
    lab = np.ascontiguousarray(labels, np.uint8).ravel()
    sec = np.ascontiguousarray(second, np.uint8).ravel()
    conf = np.ascontiguousarray(confidence, np.float32).ravel()
    if not lab.size == sec.size == conf.size:
        raise ValueError("iou_sums takes maps of one size")  # a caller's bug
    tp, fp, fn = np.zeros(256), np.zeros(256), np.zeros(256)
    _iou_sums(lab, conf, sec, tp, fp, fn)
    return tp, fp, fn


def log_margins(margin: np.ndarray) -> np.ndarray:
    """(H, W) float32 ``log1p(max(margin, 0))`` in one compiled pass shared with the helper thread: numpy's
    numbers, or within two units in the last place of them where numpy uses its own AVX-512 routine."""
    m = np.ascontiguousarray(margin, np.float32)
    out = np.empty(m.shape, np.float32)
    _rows(_log_margin, m.shape, m, out)
    return out


def logistic_confidence(z: np.ndarray, log_margin: np.ndarray, a: float, b: float, least: float, *,
                        piece: np.ndarray | None = None, c: float = 0.0) -> np.ndarray:
    """(H, W) float32, in ``z`` itself: ``max(1 / (1 + exp(-clip(z + c piece log_margin + (a log_margin + b),
    -60, 60))), least)`` (``log_margin``: log1p of the margin between the two best classes, at least 0, as the
    caller made it for its own features; ``piece``: a map multiplied by ``c`` and the log-margin, or None),
    numpy's float32 operations in the same order (its ``exp`` between two compiled passes shared with the
    helper thread, in place of a dozen passes of numpy over the map)."""
    m = np.ascontiguousarray(log_margin, np.float32)
    if z.dtype != np.float32 or not z.flags.c_contiguous or z.shape != m.shape:
        raise ValueError("logistic_confidence works in place on a C-contiguous float32 map of the margin's shape")
    p = None if piece is None else np.ascontiguousarray(piece, np.float32)
    if p is not None and p.shape != m.shape:
        raise ValueError("logistic_confidence takes a piece map of the margin's shape")
    _rows(_negative_logit, z.shape, z, m, p, np.float32(c), np.float32(a), np.float32(b))
    np.exp(z, out=z)
    _rows(_logistic, z.shape, z, np.float32(least))
    return z
