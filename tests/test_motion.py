"""The one motion type: a 3x3 T_ref_mov, or a dense field with its confidence."""

import numpy as np
import pytest

import pcreg
from pcreg import transforms as tf
from pcreg.errors import InputError
from pcreg.registration.motion import Motion, field_from_matrix

from _images import moved, rigid_about_centre, shapes_image

SHAPE = (40, 60)


def test_of_takes_matrices_fields_and_results():
    T = tf.rigid2d(10.0, 3.0, -2.0)
    m = Motion.of(T)
    assert not m.is_field and np.array_equal(m.matrix, T) and m.confidence is None
    assert Motion.of(m) is m
    fld = field_from_matrix(T, SHAPE)
    f = Motion.of(fld)
    assert f.is_field and f.field.dtype == np.float32 and f.field.shape == SHAPE + (2,)
    ref = shapes_image()
    res = pcreg.register(ref, moved(ref, rigid_about_centre(ref.shape, 5.0, 3.0, -2.0)))
    assert np.array_equal(Motion.of(res).matrix, res.T_ref_mov)


def test_a_dense_result_brings_its_field_and_confidence():
    ref = shapes_image()
    res = pcreg.register_dense(ref, moved(ref, rigid_about_centre(ref.shape, 2.0, 3.0, -2.0)))
    m = Motion.of(res)
    assert m.is_field and np.array_equal(m.field, res.field) and np.array_equal(m.confidence, res.confidence)
    assert "mean_confidence=" in repr(m)


def test_arrays_are_read_only_copies():
    fld = field_from_matrix(np.eye(3), SHAPE)
    m = Motion(field=fld)
    fld[0, 0] = 99.0
    assert m.field[0, 0, 0] == 0.0
    with pytest.raises(ValueError, match="read-only"):
        m.field[0, 0, 0] = 1.0


@pytest.mark.parametrize("bad, match", [
    (np.eye(4), r"3x3 matrix or an \(H, W, 2\) field, got shape \(4, 4\)"),
    (np.full((3, 3), np.nan), "T_ref_mov must be finite: it has NaN or inf values"),
    (np.zeros((4, 5, 3)), r"got shape \(4, 5, 3\)"),
    ("identity", "a 3x3 matrix or a dense field, got str"),
    (object(), "must be a 3x3 matrix or a dense field, got object"),
])
def test_what_is_not_a_motion_is_refused(bad, match):
    with pytest.raises(InputError, match=match):
        Motion.of(bad)


def test_a_field_with_nan_or_a_misfit_confidence_is_refused():
    fld = field_from_matrix(np.eye(3), SHAPE)
    with pytest.raises(InputError, match="NaN or inf"):
        Motion(field=np.where(fld > 5, np.nan, fld))
    with pytest.raises(InputError, match=r"confidence must be \(H, W\)"):
        Motion(field=fld, confidence=np.ones((3, 3)))
    with pytest.raises(InputError, match="goes with a dense field"):
        Motion(matrix=np.eye(3), confidence=np.ones(SHAPE))
    with pytest.raises(InputError, match="exactly one"):
        Motion()


def test_after_composes_as_the_matrices_do():
    """b->a after c->b is c->a, whichever of the two is a field."""
    T_ab, T_bc = tf.rigid2d(4.0, 2.0, 1.0), tf.rigid2d(-3.0, -1.0, 2.5)
    both = Motion(matrix=T_ab).after(Motion(matrix=T_bc), SHAPE)
    assert not both.is_field and np.allclose(both.matrix, T_ab @ T_bc)
    truth = field_from_matrix(T_ab @ T_bc, SHAPE)
    f_bc = field_from_matrix(T_bc, SHAPE)
    h, w = SHAPE
    inside = (f_bc[..., 0] >= 0) & (f_bc[..., 0] <= w - 1) & (f_bc[..., 1] >= 0) & (f_bc[..., 1] <= h - 1)
    for a, b in [(Motion(matrix=T_ab), Motion(field=f_bc)),
                 (Motion(field=field_from_matrix(T_ab, SHAPE)), Motion(matrix=T_bc)),
                 (Motion(field=field_from_matrix(T_ab, SHAPE)), Motion(field=f_bc))]:
        c = a.after(b, SHAPE)
        assert c.is_field
        # OpenCV's remap reads a field at 1/32 px; a pixel that leaves frame b lands far outside frame a
        assert np.abs(c.field - truth)[inside].max() < 0.05
        assert (np.abs(c.field - truth)[~inside] < 0.05).all() or (c.field[~inside] < -1e5).any()


def test_warp_takes_a_motion_a_matrix_or_a_result_alike():
    img = shapes_image()
    T = rigid_about_centre(img.shape, 7.0, 4.0, -3.0)
    by_matrix, valid = pcreg.warp(img, T)
    by_motion, valid_m = pcreg.warp(img, Motion(matrix=T))
    assert np.array_equal(by_matrix, by_motion) and np.array_equal(valid, valid_m)
    with pytest.raises(InputError, match="^warp: "):
        pcreg.warp(img, np.eye(4))


def test_the_compiled_field_of_a_matrix_is_the_broadcast_formula_to_the_bit():
    from pcreg.registration.motion import _field_py, field_from_matrix

    rng = np.random.default_rng(0)
    h, w = 37, 53
    x = np.arange(w, dtype=np.float64)[None, :]
    y = np.arange(h, dtype=np.float64)[:, None]
    for k in range(6):
        M = np.eye(3) + rng.normal(0, 0.05, (3, 3))
        M[2] = [0, 0, 1] if k % 2 else [1e-3 * rng.normal(), 1e-3 * rng.normal(), 1.0]
        if k % 2:
            want = np.dstack([M[0, 0] * x + (M[0, 1] * y + M[0, 2]), M[1, 0] * x + (M[1, 1] * y + M[1, 2])])
        else:
            den = M[2, 0] * x + M[2, 1] * y + M[2, 2]
            want = np.dstack([(M[0, 0] * x + M[0, 1] * y + M[0, 2]) / den, (M[1, 0] * x + M[1, 1] * y + M[1, 2]) / den])
        got = field_from_matrix(M, (h, w))
        assert got.dtype == np.float32 and got.shape == (h, w, 2)
        np.testing.assert_array_equal(got, want.astype(np.float32))
        np.testing.assert_array_equal(_field_py(M, np.empty((h, w, 2), np.float32)), got)  # the fallback


def test_the_field_of_a_matrix_on_its_horizon_is_not_finite_and_a_wrong_shape_is_refused():
    from pcreg.registration.motion import field_from_matrix

    with np.errstate(divide="ignore", invalid="ignore"):
        f = field_from_matrix([[1, 0, 0], [0, 1, 0], [-0.5, 0, 1]], (4, 5))  # x = 2 divides by zero
    assert (~np.isfinite(f[:, 2])).any(axis=1).all() and np.isfinite(f[:, :2]).all()
    for bad in (np.eye(2), np.zeros((2, 3)), np.eye(4)):
        with pytest.raises(InputError, match="3x3"):
            field_from_matrix(bad, (4, 5))
