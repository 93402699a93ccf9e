"""Clouds far under one unit across: the stopping rule's default threshold on the inlier RMSE shrinks with them.

Open3D's absolute 1e-6 is met by every step of a cloud a thousandth of a unit across, so both backends stopped
after their first step: a cloud 2e-3 across turned 10 degrees was returned turned 0.37 degrees, converged.
"""

import numpy as np
import pytest

import pcreg
from pcreg.registration import transforms as tf
from pcreg.registration.icp_options import RMSE_TOLERANCE
from pcreg.registration.open3d_icp import icp_open3d
from pcreg.registration.reference import icp_reference


def _clouds(scale: float, dim: int = 2):
    rng = np.random.default_rng(0)
    source = rng.uniform(-1, 1, (400, dim)) * scale
    if dim == 2:
        T = tf.rigid2d(10.0, 0.05 * scale, -0.03 * scale)
    else:
        T = tf.lift_to_3d(tf.rigid2d(10.0, 0.05 * scale, -0.03 * scale))
        T[2, 3] = 0.02 * scale
    return source, tf.apply(T, source), T


@pytest.mark.parametrize("backend", ["reference", "open3d"])
@pytest.mark.parametrize("scale", [1e-3, 1e-6, 1e-30])
@pytest.mark.parametrize("dim", [2, 3])
def test_a_small_cloud_registers_with_the_defaults(backend, scale, dim):
    source, target, T = _clouds(scale, dim)
    r = pcreg.icp(source, target, pcreg.ICPOptions(backend=backend))
    assert r.converged and r.iterations > 1
    assert tf.rotation_disagreement_deg(r.matrix, T) < 1e-3
    assert np.abs(tf.apply(r.matrix, source) - target).max() < 1e-4 * scale


@pytest.mark.parametrize("backend", [icp_reference, icp_open3d])
def test_each_backend_scales_the_default_too(backend):
    source, target, T = _clouds(1e-4)
    r = backend(source, target, options=pcreg.ICPOptions(max_correspondence_distance=1.0))
    assert tf.rotation_disagreement_deg(r.matrix, T) < 1e-3


def test_a_threshold_given_is_kept():
    """The user's own threshold is Open3D's absolute rule, as before: 1e-6 stops a cloud 2e-3 across at once."""
    source, target, T = _clouds(1e-3)
    r = pcreg.icp(source, target, pcreg.ICPOptions(relative_rmse=1e-6))
    assert r.iterations == 1 and tf.rotation_disagreement_deg(r.matrix, T) > 5


def test_the_default_threshold():
    options = pcreg.ICPOptions()
    assert options.relative_rmse is None
    unit = np.array([[0.0, 0.0], [3.0, 4.0]])
    assert options.stopping_rmse(unit) == RMSE_TOLERANCE == 1e-6  # 5 across: Open3D's, unchanged
    assert options.stopping_rmse(unit * 1e-3, unit * 1e-4) == pytest.approx(5e-9)  # the larger cloud's extent
    assert pcreg.ICPOptions(relative_rmse=0.5).stopping_rmse(unit * 1e-3) == 0.5
    with pytest.raises(pcreg.errors.InputError, match="relative_rmse"):
        pcreg.ICPOptions(relative_rmse=-1.0)


def test_clouds_one_unit_across_or_more_are_unchanged():
    source, target, _ = _clouds(200.0)
    scaled = pcreg.icp(source, target)
    given = pcreg.icp(source, target, pcreg.ICPOptions(relative_rmse=1e-6))
    assert np.array_equal(scaled.matrix, given.matrix) and scaled.iterations == given.iterations


def test_the_cross_check_pins_the_scaled_threshold_on_every_implementation():
    from pcreg.implementations.crosscheck import crosscheck_implementations

    source, target, _ = _clouds(1e-3, dim=3)
    report = crosscheck_implementations(source, target, implementations=("reference", "open3d"),
                                        options=pcreg.ICPOptions(max_correspondence_distance=1.0))
    extent = max(np.linalg.norm(np.ptp(c, axis=0)) for c in (source, target))
    assert [row["settings"]["relative_rmse"] for row in report.rows.values()] == pytest.approx([1e-6 * extent] * 2)
