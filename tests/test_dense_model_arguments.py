"""pcreg.register(model="dense") and the arguments of register it is given: the callback and the images'
pyramids go to its global similarity, as register gives them to any other model's search; none is taken and
left unused."""

from __future__ import annotations

import numpy as np
import pytest

from pcreg import RegisterConfig, register
from pcreg.errors import InputError
from pcreg.registration.clouds import image_pyramid

from _images import shapes_image


@pytest.fixture(scope="module")
def pair():
    ref = shapes_image(120, 160, 0)
    return ref, np.roll(ref, (2, 3), axis=(0, 1))


def test_the_dense_models_callback_sees_its_global_similaritys_iterations(pair):
    ref, mov = pair
    dense, similarity = [], []
    res = register(ref, mov, model="dense", callback=dense.append)
    register(ref, mov, config=RegisterConfig.of(model="similarity", model_check=False), callback=similarity.append)
    assert dense and len(dense) == len(similarity)
    assert res.global_result.evidence.generator == "fourier_mellin"
    assert [it.fitness for it in dense] == [it.fitness for it in similarity]


def test_the_dense_model_refuses_what_register_refuses_of_a_callback_and_pyramids(pair):
    ref, mov = pair
    with pytest.raises(InputError, match="callback"):
        register(ref, mov, model="dense", callback=42)
    with pytest.raises(InputError):
        register(ref, mov, model="dense", reference_pyramid="not a pyramid")


def test_the_dense_model_uses_the_pyramids_it_is_given(pair):
    ref, mov = pair
    kept = image_pyramid(ref, levels=4), image_pyramid(mov, levels=4)
    given = register(ref, mov, model="dense", reference_pyramid=kept[0], moving_pyramid=kept[1])
    built = register(ref, mov, model="dense")
    np.testing.assert_allclose(given.matrix, built.matrix, atol=1e-6)
    with pytest.raises(InputError):  # another image's pyramid is refused, as any model's
        register(ref, mov, model="dense", reference_pyramid=kept[1])


def test_the_dense_model_checks_its_masks_as_register_does(pair):
    ref, mov = pair
    with pytest.raises(InputError, match="reference_mask"):
        register(ref, mov, model="dense", reference_mask="junk")
    with pytest.raises(InputError, match="moving_mask"):
        register(ref, mov, model="dense", moving_mask="everything")
