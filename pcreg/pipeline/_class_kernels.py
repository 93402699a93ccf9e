"""Compiled passes of the many-class read-out (:mod:`pcreg.pipeline.multiclass`): each reads an (H, W, K)
map once, where numpy's ``argmax``, ``take_along_axis`` and one-hot arrays would read and write it
several times (an eleven-class frame at 640x480 is 13.5 MB a map)."""

from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["top_two", "block_shares", "best_agreement", "fuse_classes", "carried_best", "penalised"]


def _top_two_py(S, best, second, margin):
    h, w, k = S.shape
    for i in range(h):
        for j in range(w):
            vb = S[i, j, 0]
            b = 0
            s = 0
            vs = vb
            if k > 1:  # the runner-up starts as the other of the first two
                v = S[i, j, 1]
                if v > vb:
                    b, vb, s, vs = 1, v, 0, vb
                else:
                    s, vs = 1, v
            for c in range(2, k):
                v = S[i, j, c]
                if v > vb:
                    s, vs = b, vb
                    b, vb = c, v
                elif v > vs:
                    s, vs = c, v
            best[i, j] = b
            second[i, j] = s
            margin[i, j] = vb - vs


def _carried_best_py(prior, weight, log_pi, least, out):
    h, w, k = prior.shape
    for i in range(h):
        for j in range(w):
            inv = np.float32(1.0) / max(weight[i, j], least)
            b = 0
            vb = prior[i, j, 0] * inv + log_pi[0]
            for c in range(1, k):
                v = prior[i, j, c] * inv + log_pi[c]
                if v > vb:
                    b, vb = c, v
            out[i, j] = b


def _penalised_py(fused, allowed, weight, untrusted, penalty, out):
    h, w, k = fused.shape
    for i in range(h):
        for j in range(w):
            free = weight[i, j] <= untrusted
            for c in range(k):
                v = fused[i, j, c]
                out[i, j, c] = v if free or allowed[i, j, c] else v - penalty


def _block_shares_py(best, k, out):
    h, w = best.shape
    hh, hw = out.shape[0], out.shape[1]
    for i in range(hh):
        for j in range(hw):
            for c in range(k):
                out[i, j, c] = 0.0
            for di in range(2):
                for dj in range(2):
                    y, x = 2 * i + di, 2 * j + dj
                    if y < h and x < w:
                        out[i, j, best[y, x]] += 0.25


def _best_agreement_py(d, p, out):
    h, w, k = d.shape
    for i in range(h):
        for j in range(w):
            bd, bp = 0, 0
            vd, vp = d[i, j, 0], p[i, j, 0]
            for c in range(1, k):
                if d[i, j, c] > vd:
                    bd, vd = c, d[i, j, c]
                if p[i, j, c] > vp:
                    bp, vp = c, p[i, j, c]
            out[i, j] = 1.0 if bd == bp else 0.0


def _fuse_classes_py(d, w1, l1, w2, l2, fused, prior):
    h, w, k = d.shape
    for i in range(h):
        for j in range(w):
            a = w1[i, j]
            b = np.float32(0.0) if w2 is None else w2[i, j]
            for c in range(k):
                p = a * l1[i, j, c]
                if w2 is not None:
                    p += b * l2[i, j, c]
                prior[i, j, c] = p
                fused[i, j, c] = d[i, j, c] + p


_top_two = njit(cache=True, nogil=True)(_top_two_py)
_block_shares = njit(cache=True, nogil=True)(_block_shares_py)
_best_agreement = njit(cache=True, nogil=True)(_best_agreement_py)
_carried_best = njit(cache=True, nogil=True)(_carried_best_py)
_penalised = njit(cache=True, nogil=True)(_penalised_py)
_fuse_classes = njit(cache=True, nogil=True)(_fuse_classes_py)


def top_two(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(best, second, margin)`` per pixel of (H, W, K) float32 scores: the best class's index (the first
    of equals), the runner-up's, and the best score minus the runner-up's."""
    S = np.ascontiguousarray(S, dtype=np.float32)
    h, w = S.shape[:2]
    best, second = np.empty((h, w), np.intp), np.empty((h, w), np.intp)
    margin = np.empty((h, w), np.float32)
    _top_two(S, best, second, margin)
    return best, second, margin


def block_shares(best: np.ndarray, k: int) -> np.ndarray:
    """(H/2, W/2, K) float32: each 2x2 block's share of each class index of ``best`` (H, W) (the one-hot
    labels at half size, as an area resize of them gives)."""
    h, w = best.shape
    out = np.empty((max(1, h // 2), max(1, w // 2), k), np.float32)
    _block_shares(np.ascontiguousarray(best), k, out)
    return out


def best_agreement(d: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(H, W) float32: 1 where the best class of ``d`` is the best class of ``p`` ((H, W, K) each), else 0."""
    out = np.empty(d.shape[:2], np.float32)
    _best_agreement(np.ascontiguousarray(d, np.float32), np.ascontiguousarray(p, np.float32), out)
    return out


def fuse_classes(d: np.ndarray, w1: np.ndarray, l1: np.ndarray, w2: np.ndarray | None,
                 l2: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(fused, prior)``, (H, W, K) float32: ``prior = w1 l1 + w2 l2`` per class (weights (H, W); the second
    pair may be None) and ``fused = d + prior``."""
    d = np.ascontiguousarray(d, np.float32)
    fused, prior = np.empty_like(d), np.empty_like(d)
    c = np.ascontiguousarray
    _fuse_classes(d, c(w1, np.float32), c(l1, np.float32), None if w2 is None else c(w2, np.float32),
                  None if l2 is None else c(l2, np.float32), fused, prior)
    return fused, prior


def carried_best(prior: np.ndarray, weight: np.ndarray, log_pi: np.ndarray) -> np.ndarray:
    """(H, W) uint8: the best class index of ``prior / weight + log_pi`` ((H, W, K) evidence, (H, W) summed
    trust weight, at least 1e-6; (K,) log class priors): the carried priors' own label."""
    out = np.empty(prior.shape[:2], np.uint8)
    _carried_best(np.ascontiguousarray(prior, np.float32), np.ascontiguousarray(weight, np.float32),
                  np.ascontiguousarray(log_pi, np.float32), np.float32(1e-6), out)
    return out


def penalised(fused: np.ndarray, allowed: np.ndarray, weight: np.ndarray, untrusted: float,
              penalty: float) -> np.ndarray:
    """(H, W, K) float32: ``fused`` lowered by ``penalty`` where a class is not ``allowed`` ((H, W, K) uint8)
    and the pixel's summed trust ``weight`` is above ``untrusted``."""
    out = np.empty(fused.shape, np.float32)
    _penalised(np.ascontiguousarray(fused, np.float32), np.ascontiguousarray(allowed),
               np.ascontiguousarray(weight, np.float32), np.float32(untrusted), np.float32(penalty), out)
    return out
