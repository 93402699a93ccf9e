"""pcreg.transforms given what is not the transform or the points it takes: refused in one line, never a confident
wrong answer (a 4x4 transform applied to 2-D points used to drop its translation) or another library's error."""

from __future__ import annotations

import numpy as np
import pytest

from pcreg import transforms as tf
from pcreg.errors import InputError

NAN3 = np.full((3, 3), np.nan)
T4 = np.eye(4)
T4[:3, 3] = (5.0, 6.0, 7.0)


@pytest.mark.parametrize("call", [
    lambda: tf.apply(T4, np.zeros((2, 2))),  # a 3-D result applied to 2-D points: its translation was dropped
    lambda: tf.apply(np.eye(3), np.zeros((2, 3))),
    lambda: tf.apply(np.eye(3), np.zeros(2)),
    lambda: tf.apply("abc", np.zeros((2, 2))),
    lambda: tf.apply(np.eye(3), [["a", "b"]]),
    lambda: tf.max_corner_error(np.eye(4), np.eye(3), (10, 10)),
    lambda: tf.rotation_disagreement_deg(np.eye(3), np.eye(4)),
    lambda: tf.rotation_disagreement_deg(NAN3, np.eye(3)),
    lambda: tf.lift_to_3d(np.eye(5)),
    lambda: tf.lift_to_3d(np.eye(2)),
    lambda: tf.project_to_2d(np.eye(3)),
    lambda: tf.nearest_rigid(np.zeros((3, 3))),
    lambda: tf.nearest_rigid(NAN3),
    lambda: tf.rotation_part(NAN3[:2, :2]),
    lambda: tf.rotation_angle_deg(np.diag([-1.0, 1.0])),  # a reflection, once called a half turn
    lambda: tf.rotation_angle_deg(np.diag([1.0, 1.0, -1.0])),
    lambda: tf.rotation_angle_deg("abc"),
    lambda: tf.scale_transform(np.eye(3), 0),
    lambda: tf.scale_transform(np.eye(3), "x"),
    lambda: tf.rigid2d(float("nan")),
    lambda: tf.rigid2d("a"),
    lambda: tf.about_point(np.eye(3), (np.nan, 0.0)),
    lambda: tf.about_point(np.eye(3), (1.0, 2.0, 3.0)),
    lambda: tf.rigid_problem(np.zeros((2, 3))),
    lambda: tf.image_center((5,)),
    lambda: tf.degeneracy(np.eye(3), (5,)),
    lambda: tf.corners((0, 4)),
], ids=lambda _: "")
def test_refused_in_one_line(call):
    with pytest.raises(InputError) as info:
        call()
    assert "\n" not in str(info.value)


def test_a_matrix_of_nan_is_not_rigid():
    assert "NaN" in tf.rigid_problem(NAN3)


def test_what_they_take_still_gives_the_same_numbers():
    points = np.array([[1.0, 2.0], [3.0, -4.0]])
    T = tf.rigid2d(30.0, 5.0, -2.0)
    assert np.allclose(tf.apply(T, points), points @ T[:2, :2].T + T[:2, 2])
    assert np.allclose(tf.apply(T4, np.zeros((1, 3))), [[5.0, 6.0, 7.0]])
    assert tf.rotation_angle_deg(T) == pytest.approx(30.0)
    assert tf.rotation_disagreement_deg(T, np.eye(3)) == pytest.approx(30.0)
    assert np.allclose(tf.about_point(T, (0.0, 0.0)), T)
    assert np.allclose(tf.nearest_rigid(T), T) and tf.rigid_problem(T) is None
    assert tf.max_corner_error(T, T, (10, 10)) == 0.0
    assert np.allclose(tf.project_to_2d(tf.lift_to_3d(T)), T)
    assert np.allclose(tf.rigid2d(np.array(30.0), np.float32(5.0), -2, scale=np.array(1)), T)
    assert np.allclose(tf.scale_transform(T, np.array(1.0)), T)


@pytest.mark.parametrize("n", [-1, 2.5, "3"])
def test_voc_colormap_of_no_count_is_refused(n):
    from pcreg.classes import voc_colormap

    with pytest.raises(InputError):
        voc_colormap(n)


def test_warp_marks_what_it_could_not_interpolate_as_not_valid():
    from pcreg import warp

    M = tf.rigid2d(3.0, 0.5, 0.5)
    a = np.ones((20, 20), np.float32)
    a[5, 5] = np.inf
    out, valid = warp(a, M)
    assert (~np.isfinite(out)).any() and not (valid & ~np.isfinite(out)).any()
    big = np.full((20, 20, 2), 3e38, np.float32)  # finite, but a cubic's overshoot is not
    out, valid = warp(big, M, interpolation="cubic")
    assert not (valid & ~np.isfinite(out).all(axis=2)).any() and valid.any()


@pytest.mark.parametrize("bad", ["negative", "nan", "inf", "complex"])
def test_histograms_that_are_no_counts_are_refused_as_such(bad):
    from pcreg.classification.bayes import NaiveBayesPixelClassifier

    counts = np.ones((3, len(NaiveBayesPixelClassifier().feature_names_), 256))
    counts[2] = 0
    counts = counts.astype(complex) if bad == "complex" else counts
    if bad != "complex":
        counts[0, 0, 0] = {"negative": -5.0, "nan": np.nan, "inf": np.inf}[bad]
    with pytest.raises(InputError, match="counts of pixels"):
        NaiveBayesPixelClassifier().fit_histograms(counts)


def test_crosscheck_names_an_open3d_cloud_as_icp_does():
    import open3d as o3d

    import pcreg

    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.random.default_rng(0).random((50, 3)))
    with pytest.raises(InputError, match="Open3D PointCloud, not an array"):
        pcreg.crosscheck(cloud, cloud)
