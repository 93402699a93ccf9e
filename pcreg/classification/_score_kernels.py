"""The compiled pass of many-class naive Bayes (:meth:`~pcreg.classification.bayes.NaiveBayesPixelClassifier.
class_scores`): every class's sum of table look-ups in one read of the pixel's features, where a look-up
table per class and feature group would read the image K times. Its rows are taken in blocks, ``first, first +
stride, ...``, so that a large frame's are shared with the helper thread, each pixel written by the same code."""

from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["class_sums"]


#: Rows per block of the pass (two threads take alternate blocks: :func:`pcreg._threads.interleave`).
BLOCK_ROWS = 16


def _class_sums_py(planes, tables, row, out, first, stride):
    h, w, f = planes.shape
    k = tables.shape[2]
    acc = np.empty(k, np.float32)  # a pixel's sums, in the order the features come
    for b in range(first * BLOCK_ROWS, h, stride * BLOCK_ROWS):
        for i in range(b, min(b + BLOCK_ROWS, h)):
            for j in range(w):
                for c in range(k):
                    acc[c] = row[i, c]
                for g in range(f):
                    v = planes[i, j, g]
                    for c in range(k):
                        acc[c] += tables[g, v, c]
                for c in range(k):
                    out[i, j, c] = acc[c]


_class_sums = njit(cache=True, nogil=True)(_class_sums_py)


def class_sums(groups, tables: np.ndarray, bias: np.ndarray, *, width: int | None = None) -> np.ndarray:
    """(H, W, K) float32: for each class ``k``, ``bias[k]`` plus the sum over the features of
    ``tables[k, f, x_f]`` (``tables`` (K, F, 256)), the features as :func:`~pcreg.classification.features.
    frame_features` gives them (``groups``: ``(name, planes)``, a ``row`` feature one value per row). ``width``:
    the image's, which the ``row`` feature alone does not give (each row's sums, the same along it)."""
    k = tables.shape[0]
    image_planes, image_tables = [], []
    row = None
    f = 0
    for name, planes in groups:
        if name == "row":
            term = np.ascontiguousarray(tables[:, f, :][:, planes].T, dtype=np.float32)  # (H, K)
            row = term if row is None else row + term
            f += 1
            continue
        c = planes.shape[-1] if planes.ndim == 3 else 1
        image_planes.append(planes.reshape(planes.shape[0], planes.shape[1], c))
        image_tables.append(tables[:, f:f + c, :])
        f += c
    if not image_planes:  # the row alone: one vector a row
        if row is None or width is None:
            raise ValueError("class_sums needs an image feature, or the row and the image's width")  # a caller's bug
        base = np.ascontiguousarray(row + np.asarray(bias, np.float32), dtype=np.float32)
        return np.ascontiguousarray(np.broadcast_to(base[:, None, :], (base.shape[0], width, k)))
    import cv2

    # cv2.merge, not np.concatenate: numpy copies a few bytes at a time along the last axis (4 ms at 640x480)
    planes = np.ascontiguousarray(cv2.merge(image_planes)).reshape(image_planes[0].shape[:2] + (-1,))
    lut = np.ascontiguousarray(np.concatenate(image_tables, axis=1).transpose(1, 2, 0), dtype=np.float32)  # (F, 256, K)
    h = planes.shape[0]
    base = np.broadcast_to(np.asarray(bias, np.float32), (h, k)) if row is None else row + np.asarray(bias, np.float32)
    out = np.empty(planes.shape[:2] + (k,), np.float32)
    base = np.ascontiguousarray(base, dtype=np.float32)
    from .._threads import MIN_PIXELS, interleave

    interleave(h * planes.shape[1], lambda first, stride: _class_sums(planes, lut, base, out, first, stride),
               min_items=MIN_PIXELS)  # rows shared with the helper thread when it is free
    return out
