"""pcreg's compiled kernels (numba, cached on disk), compiled all at once so that no command pauses for it.

    python -m pcreg.kernels      # what `make setup` runs after installing

The kernels: the exact correspondence search (:mod:`pcreg.registration.kdtree`; the grid of
:mod:`pcreg.registration.nn`), the reference ICP's
point-to-point and projective loops (:mod:`pcreg.registration.reference`), the sub-pixel edges of the image pyramids
(:mod:`pcreg.registration.clouds`), the dense registration's window search, assembly, solver and
full-size field (:mod:`pcreg.registration.dense`), the field of a transform
(:mod:`pcreg.registration.motion`) and the stream's one-pass fusions (:mod:`pcreg.pipeline.prior`,
:mod:`pcreg.pipeline.trust`).
Their cache is keyed to all of their sources together (:mod:`pcreg._jit`).
"""

from __future__ import annotations

import time

import numpy as np


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every compiled kernel of pcreg, on small inputs."""
    from .pipeline.prior import fused_labels
    from .pipeline.trust import STREAM_TRUST, trusted_fusion
    from .registration import kdtree, nn, reference
    from .registration.api import register_dense
    from .registration.clouds import image_pyramid

    nn.warm_up()
    kdtree.warm_up()
    reference.warm_up()
    img = np.zeros((64, 64, 3), np.uint8)
    img[16:48, 20:40] = 200
    image_pyramid(img, levels=2).clouds(max_points=100)
    a, b = _textured_pair()
    result = register_dense(a, b)
    shape = result.confidence.shape
    fused_labels(np.zeros(shape, np.float32), np.full(shape, 0.5, np.float32), result.confidence, weight=1.0, pi=0.5)
    zeros = np.zeros(shape, np.float32)
    for confidence in (result.confidence, None):  # the one fusion kernel, compiled for each case a stream meets
        for flow in ((zeros, zeros), None):
            trusted_fusion(STREAM_TRUST, 1.0, zeros, zeros, zeros, confidence, flow)
    _warm_classes(shape)
    _warm_read_only()


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only copy of ``a``: numba compiles a kernel apart for read-only arrays."""
    a = a.copy()
    a.setflags(write=False)
    return a


def _warm_read_only() -> None:
    """The kernels a stream calls with read-only arrays (a key frame's features and field, kept, the weights of a
    carried prior, a motion's matrix), compiled for those too: each is a signature of its own, which a ``pcreg run``
    after ``python -m pcreg.kernels`` compiled at its first step."""
    from .pipeline import _class_kernels as k
    from .registration.dense.window import match_window
    from .registration.motion import field_from_matrix

    field_from_matrix(_read_only(np.eye(3)), (4, 4))
    level = np.zeros((8, 8, 3), np.float32)
    samples = np.full((2, 2), 4.0)
    match_window(_read_only(level), level, samples, samples, np.zeros((2, 3), np.float32), radius=1, lam=1.0)
    scores, w = np.zeros((4, 4, 3), np.float32), np.ones((4, 4), np.float32)
    ro = _read_only(w)
    for w2, l2 in ((ro, scores), (None, None)):
        k.fuse_classes(scores, ro, scores, w2, l2)
        k.fuse_and_mark(scores, ro, scores, w2, l2, w, np.zeros(3, np.float32))
    k.remap_labels(np.zeros((4, 4), np.uint8), np.zeros((256, 5), np.float32), _read_only(np.zeros((4, 4, 2), np.float32)))


def _warm_classes(shape: tuple[int, int]) -> None:
    """The many-class step's kernels (:mod:`pcreg.pipeline._class_kernels`, the confidence's piece means,
    naive Bayes' class sums)."""
    from .classification._score_kernels import class_sums
    from .pipeline import _class_kernels as k
    from .pipeline._class_regions import region_means

    scores = np.zeros(shape + (3,), np.float32)
    w = np.ones(shape, np.float32)
    k.top_two(scores)
    k.purities(np.zeros(shape, np.intp), 3, (3, 5))
    k.best_agreement(scores, scores)
    for w2, l2 in ((w, scores), (None, None)):
        k.fuse_classes(scores, w, scores, w2, l2)
        k.fuse_and_mark(scores, w, scores, w2, l2, w, np.zeros(3, np.float32))
    k.class_window(k.carried_best(scores, w, np.zeros(3, np.float32)), 3, 3)
    k.remap_classes(np.zeros(shape + (5,), np.float32), np.zeros(shape + (2,), np.float32))
    k.remap_labels(np.zeros(shape, np.uint8), np.zeros((256, 5), np.float32), np.zeros(shape + (2,), np.float32))
    k.penalised(scores, np.ones(shape + (1,), np.uint64), w, 1e-3, 15.0)
    k.log_margins(w)
    for piece in (w, None):
        k.logistic_confidence(np.zeros(shape, np.float32), w, 1.0, 0.0, 0.5, piece=piece, c=1.0)
    k.iou_sums(np.zeros(shape, np.uint8), w, np.zeros(shape, np.uint8))
    region_means(np.zeros(shape, np.intp), w)
    class_sums([("rgb", np.zeros(shape + (3,), np.uint8)), ("row", np.zeros(shape[0], np.uint8))],
               np.zeros((3, 4, 256), np.float32), np.zeros(3, np.float32))


def _textured_pair(size: int = 96, shift: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Two (size, size, 3) uint8 views of one smooth random texture, ``shift`` px apart: enough texture
    at every level for the dense registration's kernels to run."""
    import cv2

    rng = np.random.default_rng(0)
    cells = rng.integers(0, 256, (size // 4 + shift, size // 4 + shift, 3), dtype=np.uint8)
    texture = cv2.resize(cells, ((size + 4 * shift),) * 2, interpolation=cv2.INTER_CUBIC)
    return (np.ascontiguousarray(texture[:size, :size]),
            np.ascontiguousarray(texture[shift:size + shift, shift:size + shift]))


def main() -> int:  # pragma: no cover - run by the Makefile
    """Compile every kernel; Ctrl-C or SIGTERM (a ``make`` stopped) ends it with one line and exit 130, the kernels
    compiled so far kept in the cache (a kernel being compiled is finished first, :mod:`pcreg._jit`)."""
    import sys

    from ._signals import check_interrupted, ignore_signals, interrupt_on_signals, restore_signals

    previous = interrupt_on_signals()
    t0 = time.perf_counter()
    try:
        warm_up()
        check_interrupted()  # one noted while a kernel was compiled
    except KeyboardInterrupt:
        restore_signals(previous)
        ignore_signals()  # a second Ctrl-C while the line is said
        print("pcreg: interrupted while compiling the kernels (those compiled are kept; python -m pcreg.kernels, or "
              "make, goes on)", file=sys.stderr)
        return 130
    restore_signals(previous)
    from ._jit import _UNCACHED

    where = ("not cached: no folder was writable, so each process compiles them again; set NUMBA_CACHE_DIR"
             if _UNCACHED else "cache: the __pycache__ folders beside pcreg's modules, or NUMBA_CACHE_DIR")
    print(f"pcreg: compiled kernels ready in {time.perf_counter() - t0:.1f} s ({where})")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
