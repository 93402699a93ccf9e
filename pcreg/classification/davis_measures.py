"""The DAVIS benchmark's measures of a video object's mask: region similarity J and boundary accuracy F.

Ported from the benchmark's official evaluation, and faithful to it (Perazzi et al., "A Benchmark Dataset
and Evaluation Methodology for Video Object Segmentation", CVPR 2016):

- J (:func:`jaccard`): ``db_eval_iou`` of fperazzi/davis ``python/lib/davis/measures/jaccard.py`` (and of
  davisvideochallenge/davis2017-evaluation ``davis2017/metrics.py``): the intersection over the union of
  the two object masks, 1 when both are empty.
- F (:func:`boundary_f`): ``db_eval_boundary`` of ``f_boundary.py`` (``f_measure`` in davis2017-evaluation):
  each mask's boundary drawn by :func:`boundary_map` (``seg2bmap``, D. Martin's Berkeley code), each
  boundary dilated by a disk of radius ``ceil(0.008 * the image's diagonal)`` px (scikit-image's
  ``disk``: the offsets with dx² + dy² <= r²), precision the share of the predicted boundary within the
  dilated true one, recall the converse, F their harmonic mean. A missing boundary on one side gives F 0,
  on both sides 1.
- The protocol (:func:`scored_frames`, :func:`sequence_mean`, :func:`benchmark_mean`): frames 1 to n-2 of
  a sequence of n frames are scored (the first frame's mask is given, the last is left out as in
  ``DAVISAnnotationLoader._eval``); each measure is averaged over a sequence's frames first (``db_statistics``'
  mean), then over sequences (``db_eval_view``'s average).

Masks are any (H, W) arrays; nonzero is the object (the benchmark reads its annotations as grey and
casts them to bool). pcreg's labels qualify as ``labels == 1``: as they are, their 2 (unknown, or a DAVIS 2017
void pixel) would be read as the object. Void is background here, as in davis2017-evaluation's figures: its
``_evaluate_semisupervised`` passes ``void_pixels`` of ``mask == 255`` taken from masks already cast to bool
(``get_all_masks``), which hold no pixel, so no pixel is left out of J or F (checked at its commit 30b698a).
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

import numpy as np

from ..errors import InputError

__all__ = ["BOUNDARY_TOLERANCE", "jaccard", "boundary_map", "boundary_tolerance", "boundary_f", "scored_frames",
           "sequence_mean", "benchmark_mean"]

#: The boundary's matching tolerance as a share of the image's diagonal (the benchmark's ``bound_th``).
BOUNDARY_TOLERANCE = 0.008


def _pair(predicted, truth) -> tuple[np.ndarray, np.ndarray]:
    p, t = np.asarray(predicted), np.asarray(truth)
    if p.ndim != 2 or p.shape != t.shape:
        raise InputError(f"the predicted mask {p.shape} and the true mask {t.shape} must be two (H, W) arrays of one shape")
    return p.astype(bool), t.astype(bool)


def jaccard(predicted: np.ndarray, truth: np.ndarray) -> float:
    """J, the object's intersection over union: |P ∩ T| / |P ∪ T|, 1 when both masks are empty.

    predicted, truth : (H, W) masks, nonzero the object. Returns a float in [0, 1].
    """
    p, t = _pair(predicted, truth)
    union = np.count_nonzero(p | t)
    if union == 0:
        return 1.0
    return float(np.count_nonzero(p & t) / union)


def boundary_map(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the mask's boundary one pixel wide, as the benchmark's ``seg2bmap`` draws it.

    A pixel is on the boundary when it differs from its east, south or south-east neighbour (those past
    the image's edge count as background); in the last row only the east neighbour counts, in the last
    column only the south one, and the bottom-right pixel never. The boundary thus lies half a pixel
    towards the origin from the mask's edge. (D. Martin, Berkeley, 2003, as ported in the DAVIS code.)
    """
    seg = np.asarray(mask).astype(bool)
    if seg.ndim != 2:
        raise InputError(f"a mask must be an (H, W) array, got shape {seg.shape}")
    east, south, south_east = np.zeros_like(seg), np.zeros_like(seg), np.zeros_like(seg)
    east[:, :-1] = seg[:, 1:]
    south[:-1, :] = seg[1:, :]
    south_east[:-1, :-1] = seg[1:, 1:]
    b = (seg ^ east) | (seg ^ south) | (seg ^ south_east)
    b[-1, :] = seg[-1, :] ^ east[-1, :]
    b[:, -1] = seg[:, -1] ^ south[:, -1]
    b[-1, -1] = False
    return b


def boundary_tolerance(shape: tuple[int, ...], bound_th: float = BOUNDARY_TOLERANCE) -> int:
    """The matching distance in px: ``bound_th`` itself when it is 1 or more (a whole number of px: the
    benchmark's disk of a radius like 2.5 is an even square, centred between pixels, which a dilation here
    would not reproduce, so it is refused), else ``ceil(bound_th * sqrt(H² + W²))`` (8 px at 854x480)."""
    if not (isinstance(bound_th, (int, float, np.integer, np.floating)) and not isinstance(bound_th, (bool, np.bool_))
            and math.isfinite(bound_th) and bound_th >= 0):
        raise InputError(f"the boundary tolerance must be a number of 0 or more, got {bound_th!r}")
    if bound_th >= 1:
        if bound_th != int(bound_th):
            raise InputError(f"a boundary tolerance of 1 or more is in whole px, got {bound_th}")
        return int(bound_th)
    return int(math.ceil(bound_th * math.hypot(shape[0], shape[1])))


def _disk(radius: int) -> np.ndarray:
    """(2r+1, 2r+1) uint8: 1 where dx² + dy² <= r² (``skimage.morphology.disk``)."""
    d = np.arange(-radius, radius + 1)
    return (d[:, None] ** 2 + d[None, :] ** 2 <= radius ** 2).astype(np.uint8)


def boundary_f(predicted: np.ndarray, truth: np.ndarray, *, bound_th: float = BOUNDARY_TOLERANCE) -> float:
    """F, the boundary F-measure of the predicted mask against the true one.

    predicted, truth : (H, W) masks, nonzero the object. bound_th : the tolerance, a share of the
    diagonal (below 1) or px (:func:`boundary_tolerance`). Each boundary (:func:`boundary_map`) is dilated
    by a disk of that radius; precision = |B_P ∩ dilated B_T| / |B_P|, recall = |B_T ∩ dilated B_P| / |B_T|,
    F = 2PR / (P + R) (0 when P + R is 0). No predicted boundary: P 1, R 0; no true one: P 0, R 1; neither:
    F 1. A tolerance of the image's diagonal or more matches every boundary pixel: F 1. Returns a float in [0, 1].
    """
    import cv2

    p, t = _pair(predicted, truth)
    bp, bt = boundary_map(p), boundary_map(t)
    n_p, n_t = int(np.count_nonzero(bp)), int(np.count_nonzero(bt))
    if n_p == 0 or n_t == 0:
        return 1.0 if n_p == n_t else 0.0
    radius = boundary_tolerance(p.shape, bound_th)
    (h, w) = p.shape
    if radius ** 2 >= (h - 1) ** 2 + (w - 1) ** 2:  # the diagonal or more: every pixel within reach of every other
        return 1.0  # its disk not built (one of 10**6 px would take 29 TiB)
    disk = _disk(radius)
    p_dil = cv2.dilate(bp.view(np.uint8), disk).view(bool)
    t_dil = cv2.dilate(bt.view(np.uint8), disk).view(bool)
    precision = np.count_nonzero(bp & t_dil) / n_p
    recall = np.count_nonzero(bt & p_dil) / n_t
    if precision + recall == 0:
        return 0.0
    return float(2 * precision * recall / (precision + recall))


def scored_frames(n: int) -> range:
    """The frames of an ``n``-frame sequence the benchmark scores: 1 to n-2 (none below 3 frames)."""
    return range(1, max(1, n - 1))


def sequence_mean(values: Mapping[int, float], n: int) -> float:
    """A measure's mean over one sequence: its values ``{frame index: value}`` on :func:`scored_frames` of
    ``n`` averaged (other frames ignored; NaN when none of them has a value)."""
    kept = [float(values[t]) for t in scored_frames(n) if t in values]
    return float(np.mean(kept)) if kept else float("nan")


def benchmark_mean(per_sequence: Iterable[float]) -> float:
    """The benchmark's figure: the mean over sequences of each sequence's mean (NaN ones left out, as
    ``np.nanmean``; NaN when none)."""
    v = np.asarray([float(x) for x in per_sequence], dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")
