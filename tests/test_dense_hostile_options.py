"""pcreg.register_dense given what its arithmetic cannot hold: a global transform that sends moving pixels
through infinity, a membrane weight beyond float64's range. Each is refused as bad input, never returned as a
field of NaN nor raised as numpy's, scipy's or Python's own error."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import pcreg

from pcreg import DenseOptions, register_dense
from pcreg.errors import InputError
from pcreg.registration.dense import Membrane


def _pair(h=120, w=160, seed=0):
    rng = np.random.default_rng(seed)
    ref = cv2.GaussianBlur(rng.integers(0, 255, (h, w, 3)).astype(np.uint8), (0, 0), 1.5)
    mov = np.roll(ref, 2, axis=1)
    return ref, mov


@pytest.mark.parametrize("T", [
    [[1, 0, 0], [0, 1, 0], [0.01, 0, -1.0]],  # the horizon x = 100 crosses a 160 px wide image
    [[1, 0, 0], [0, 1, 0], [-0.01, 0, 1.0]],
])
def test_a_global_transform_through_infinity_is_refused(T):
    ref, mov = _pair()
    with pytest.raises(InputError, match="global_result.*infinity"):
        register_dense(ref, mov, global_result=np.array(T))


def test_a_projective_global_transform_short_of_its_horizon_gives_a_finite_field():
    ref, mov = _pair()
    T = np.array([[1, 0, 0], [0, 1, 0], [-0.001, 0, 1.0]])  # horizon at x = 1000, beyond the image
    res = register_dense(ref, mov, global_result=T)
    assert np.all(np.isfinite(res.field))


@pytest.mark.parametrize("membrane", [
    dict(strain=1e-300),  # (spacing x strain)^2 underflows to 0
    dict(strain=1e-160),  # the weight overflows
    dict(strain=1e-10, stiffness=(1e300,)),
    dict(strain=100.0, stiffness=(1e-320,)),  # the weight's pull towards the global transform underflows
])
def test_a_membrane_weight_beyond_float64_is_refused(membrane):
    with pytest.raises(InputError, match="membrane weight"):
        Membrane(**membrane)


@pytest.mark.parametrize("membrane", [dict(stiffness=(1e300,)), dict(stiffness=(1e-300,)), dict(strain=1e-150)])
def test_extreme_membrane_weights_within_float64_give_a_finite_field(membrane):
    ref, mov = _pair()
    for cg in (30, 0):
        res = register_dense(ref, mov, global_result=np.eye(3),
                             options=DenseOptions(membrane=Membrane(cg_iterations=cg, **membrane)))
        assert np.all(np.isfinite(res.field))


def test_a_three_dimensional_registration_as_the_global_step_is_refused():
    ref, mov = _pair()
    rng = np.random.default_rng(0)
    cloud = rng.random((50, 3))
    with pytest.raises(InputError, match="global_result.*3x3"):
        register_dense(ref, mov, global_result=pcreg.icp(cloud, cloud + 0.01))


@pytest.mark.parametrize("shape, spacing", [((64, 64), 64.0), ((9, 9), 8.0), ((120, 160), 159.0)])
def test_an_exact_solve_on_a_grid_two_nodes_wide(shape, spacing):
    """Two nodes a row: the diagonal of the next row's first node (gw - 1) is the diagonal of the right
    neighbour (1), which the sparse LU's matrix must hold once."""
    ref, mov = _pair(*shape)
    runs = {cg: register_dense(ref, mov, global_result=np.eye(3),
                               options=DenseOptions(levels=1, finest_level=0,
                                                    membrane=Membrane(grid_spacing=spacing, cg_iterations=cg)))
            for cg in (0, 1000)}
    assert runs[0].grid.shape[1] == 2
    np.testing.assert_allclose(runs[0].grid, runs[1000].grid, atol=0.01)  # CG stops at a relative residual of 1e-4
