"""The DAVIS benchmark's J and F (pcreg.classification.davis_measures): cases checked by hand, and the
official evaluation's own figures on the shared DAVIS masks."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from pcreg.classification.davis_measures import (benchmark_mean, boundary_f, boundary_map, boundary_tolerance, jaccard,
                                                 scored_frames, sequence_mean)
from pcreg.errors import InputError


def _band(rows: int, shape=(10, 10)) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[:rows] = True
    return m


def test_jaccard_is_the_intersection_over_the_union_and_one_when_both_are_empty():
    a = np.zeros((4, 4), np.uint8)
    a[1:3, 1:3] = 1
    b = np.roll(a, 1, axis=1)  # 2 pixels shared, 6 in the union
    assert jaccard(a, b) == pytest.approx(1 / 3)
    assert jaccard(a, a) == 1.0
    assert jaccard(a, np.zeros_like(a)) == 0.0
    assert jaccard(np.zeros_like(a), np.zeros_like(a)) == 1.0
    assert jaccard(a * 255, b.astype(bool)) == pytest.approx(1 / 3)  # nonzero is the object
    with pytest.raises(InputError, match="one shape"):
        jaccard(a, a[:3])


def test_the_boundary_map_is_drawn_half_a_pixel_towards_the_origin_as_seg2bmap_draws_it():
    m = np.zeros((4, 4), bool)
    m[1:3, 1:3] = True
    expected = np.array([[1, 1, 1, 0],
                         [1, 0, 1, 0],
                         [1, 1, 1, 0],
                         [0, 0, 0, 0]], bool)
    np.testing.assert_array_equal(boundary_map(m), expected)
    # an object touching the right and bottom edges: the last column compares south only, the last row
    # east only, the corner never
    full = np.ones((3, 3), bool)
    assert not boundary_map(full).any()
    corner = np.zeros((3, 3), bool)
    corner[1:, 1:] = True
    np.testing.assert_array_equal(boundary_map(corner), [[1, 1, 1], [1, 0, 0], [1, 0, 0]])


def test_the_tolerance_is_the_ceiling_of_0_008_of_the_diagonal():
    assert boundary_tolerance((480, 854)) == math.ceil(0.008 * math.hypot(480, 854)) == 8
    assert boundary_tolerance((10, 10)) == 1
    assert boundary_tolerance((10, 10), 3) == 3 == boundary_tolerance((10, 10), 3.0)
    assert boundary_tolerance((10, 10), 0) == 0  # exact matches only, as the reference takes it
    for bad in (2.5, -0.008, float("nan"), float("inf")):  # 2.5: the benchmark's disk would be an even square
        with pytest.raises(InputError, match="boundary tolerance"):
            boundary_f(_band(5), _band(5), bound_th=bad)
    for flag in (True, np.True_):  # a flag given where a tolerance goes was taken as 1 px
        with pytest.raises(InputError, match="boundary tolerance"):
            boundary_f(_band(5), _band(5), bound_th=flag)


def test_boundary_f_matches_within_the_tolerance_and_counts_by_hand():
    truth = _band(5)  # its boundary: row 4, 10 px; the tolerance at 10x10 is 1 px
    assert boundary_f(truth, truth) == 1.0
    assert boundary_f(_band(6), truth) == 1.0  # one row off: within 1 px
    assert boundary_f(_band(7), truth) == 0.0  # two rows off: nothing matched
    # rows 0-4 on the left half, 0-6 on the right: 12 boundary pixels, 6 within 1 px of the truth's
    # (P = 1/2); 6 of the truth's 10 within 1 px of them (R = 3/5): F = 2PR / (P + R) = 6/11
    mixed = _band(5)
    mixed[5:7, 5:] = True
    assert boundary_map(mixed).sum() == 12
    assert boundary_f(mixed, truth) == pytest.approx(6 / 11)
    assert boundary_f(truth, mixed) == pytest.approx(6 / 11)  # symmetric: P and R swap
    empty = np.zeros((10, 10), bool)
    assert boundary_f(empty, empty) == 1.0
    assert boundary_f(empty, truth) == 0.0 and boundary_f(truth, empty) == 0.0


def test_frames_1_to_n_minus_2_are_scored_per_sequence_then_over_sequences():
    assert list(scored_frames(5)) == [1, 2, 3]
    assert list(scored_frames(2)) == [] and list(scored_frames(3)) == [1]
    values = {0: 0.0, 1: 0.5, 2: 1.0, 3: 0.0, 4: 0.0}  # frames 0 and 4 left out
    assert sequence_mean(values, 5) == pytest.approx(0.5)
    assert math.isnan(sequence_mean({0: 1.0}, 5))
    # per sequence first: a long sequence weighs as much as a short one
    assert benchmark_mean([sequence_mean({1: 1.0}, 3), sequence_mean(dict.fromkeys(range(1, 9), 0.0), 10)]) == 0.5
    assert benchmark_mean([0.2, float("nan"), 0.4]) == pytest.approx(0.3)
    assert math.isnan(benchmark_mean([]))


# J and F of the official evaluations on the shared masks (prediction, truth): fperazzi/davis (commit aaee12c,
# python/lib/davis/measures) and davisvideochallenge/davis2017-evaluation (commit ac7c43f, davis2017/metrics.py),
# run on these masks; both gave these figures.
OFFICIAL = [(("goat", 10), ("goat", 20), (0, 0), 0.28599982988857703, 0.11507072597410928),
            (("blackswan", 1), ("blackswan", 2), (0, 0), 0.9182932787381057, 1.0),
            (("kite-surf", 5), ("kite-surf", 40), (0, 0), 0.0017624056837583302, 0.021488935264582516),
            (("breakdance", 3), ("breakdance", 3), (7, -4), 0.8408701971540428, 0.9859573041854485)]


@pytest.mark.data
@pytest.mark.parametrize("pred, truth, shift, j, f", OFFICIAL)
def test_j_and_f_equal_the_official_evaluations_on_the_shared_masks(shared_data, pred, truth, shift, j, f):
    def mask(seq, i):
        path = shared_data / "davis" / seq / "labels" / f"{i:05d}.png"
        if not path.is_file():
            pytest.skip(f"{path} is absent")
        return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)

    p = np.roll(mask(*pred), shift, axis=(0, 1))
    t = mask(*truth)
    assert jaccard(p, t) == pytest.approx(j, abs=1e-12)
    assert boundary_f(p, t) == pytest.approx(f, abs=1e-12)


def test_a_tolerance_past_the_diagonal_matches_every_boundary_pixel():
    """A tolerance in px wider than the image: each boundary pixel is within it of every other (F 1), as with
    a tolerance of the diagonal itself; 10**6 px asked numpy for a 29 TiB disk (MemoryError)."""
    mixed = _band(5)
    mixed[5:7, 5:] = True
    reach = math.ceil(math.hypot(9, 9))  # 13 px: from corner to corner of a 10x10 image
    assert boundary_f(mixed, _band(2), bound_th=reach) == 1.0
    assert boundary_f(mixed, _band(2), bound_th=3) < 1.0
    for wide in (reach + 1, 10**6, 10.0**12):
        assert boundary_f(mixed, _band(2), bound_th=wide) == 1.0


def test_void_truth_is_scored_as_background_as_davis2017_evaluations_figures_are():
    """davis2017-evaluation (commit 30b698a) takes its void mask from masks already cast to bool: no pixel is void,
    so a prediction over a void pixel counts against it, in J and in F. The DAVIS scores of the stream evaluation
    read void (label 2) the same way."""
    from pcreg.datasets import Frame
    from pcreg.experiments.stream_davis import DavisScores

    labels = np.zeros((20, 30), np.uint8)
    labels[5:12, 8:20] = 1
    labels[12:15, 8:20] = 2  # a void band under the object
    over_void = (labels > 0).astype(np.uint8)  # the object and the void band
    hook = DavisScores(3)
    hook.on_frame(1, Frame(np.zeros((20, 30, 3), np.uint8), labels, "1"), {"m": over_void})
    assert hook.values["J"]["m"] == [pytest.approx(7 / 10)]  # 84 of 120 px: the void band is in the union only
    assert hook.values["F"]["m"] == [boundary_f(over_void, labels == 1)] and hook.values["F"]["m"][0] < 1
