"""The compiled carries of K class maps along a field: :func:`remap_classes` is OpenCV's bilinear ``remap`` to the
bit, and :func:`remap_labels`, which reads each neighbour's row of a table by its label, gives what
:func:`remap_classes` gives of the map ``table[labels]`` (two kernels share the rounding: a change to one shows)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pcreg.pipeline._class_kernels import remap_classes, remap_labels


def _field(h: int, w: int, seed: int) -> np.ndarray:
    """(h, w, 2) float32 positions: mostly inside a (h, w) map, some across its edges, far outside and NaN."""
    rng = np.random.default_rng(seed)
    f = np.dstack([rng.uniform(-3, w + 2, (h, w)), rng.uniform(-3, h + 2, (h, w))]).astype(np.float32)
    f[::7, ::5] = np.float32(np.nan)
    f[3, :, 0] = -1e6
    f[5, :, 1] = np.float32(h) - np.float32(1 / 64)  # half a 1/32 step under the last row
    return f


@pytest.mark.parametrize("k", [2, 5, 11, 70])
def test_the_class_maps_carried_are_opencvs_remap(k):
    h, w = 48, 64
    values = np.random.default_rng(k).normal(size=(h, w, k)).astype(np.float32)
    field = _field(h, w, k)
    ours = remap_classes(values, field)
    theirs = cv2.remap(values, field, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    np.testing.assert_array_equal(ours, theirs.reshape(ours.shape))


@pytest.mark.parametrize("k", [2, 5, 11, 70])
def test_labels_carried_by_their_table_are_the_table_carried(k):
    h, w = 48, 64
    rng = np.random.default_rng(100 + k)
    labels = rng.integers(0, 256, (h, w), dtype=np.uint8)
    table = rng.normal(size=(256, k)).astype(np.float32)
    field = _field(h, w, 100 + k)
    carried = remap_labels(labels, table, field)
    assert carried.dtype == np.float32 and carried.shape == (h, w, k)
    assert np.array_equal(carried.view(np.uint32), remap_classes(table[labels], field).view(np.uint32))
