"""An initial guess (or a cross-check's truth) given as what is not a matrix of real numbers is refused as
bad input, as a cloud of the same values is: a Python int beyond float64's range raised Python's own
OverflowError, a complex matrix had its imaginary parts dropped with a warning, and a masked array with masked
entries was read by the values stored under its mask."""

from __future__ import annotations

import numpy as np
import pytest

import pcreg
from pcreg.errors import InputError
from pcreg.registration.icp_options import ICPOptions
from pcreg.registration.reference import icp_reference

HUGE = [[10**400, 0, 0], [0, 1, 0], [0, 0, 1]]
TURNED = np.eye(3) * (1 + 1j)
MASKED = np.ma.masked_array(np.eye(3), mask=np.eye(3, dtype=bool))  # the identity stored under the mask


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(0)
    source = rng.random((60, 2))
    return source, source + 0.01


@pytest.mark.parametrize("init, said", [(HUGE, "matrix of numbers"), (TURNED, "complex"), (MASKED, "masked")])
def test_icp_and_register_refuse_an_init_that_is_no_real_matrix(clouds, init, said):
    with pytest.raises(InputError, match=said):
        pcreg.icp(*clouds, init=init)
    with pytest.raises(InputError, match=said):
        icp_reference(*clouds, ICPOptions(max_correspondence_distance=1.0), init=init)
    image = np.zeros((64, 64, 3), np.uint8)
    with pytest.raises(InputError, match=said):
        pcreg.register(image, image, init=init)


def test_a_complex_matrix_without_imaginary_parts_is_refused_as_a_complex_cloud_is(clouds):
    with pytest.raises(InputError, match="init: complex"):
        pcreg.icp(*clouds, init=np.eye(3, dtype=complex))
    with pytest.raises(InputError, match="source: not a numeric array"):
        pcreg.icp(clouds[0].astype(complex), clouds[1])
