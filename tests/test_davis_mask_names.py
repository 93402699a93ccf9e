"""The refusal of a sequence of several objects by ``load_sequence`` names the mask file read, also where it is
saved with an upper-case suffix (``00000.PNG``, as the reader takes it): it named ``00000.png``, no such file."""

from __future__ import annotations

import pytest

from pcreg.datasets.davis import load_sequence
from pcreg.errors import DatasetError
from _davis import frames_and_masks
from test_davis_objects import two_object_sequence


def test_several_objects_in_upper_case_masks_name_the_mask(tmp_path):
    pairs = frames_and_masks(3)
    seq = tmp_path / "disc"
    two_object_sequence(seq, [p[0] for p in pairs], [p[1] for p in pairs])
    for p in (seq / "labels").iterdir():
        p.rename(p.with_suffix(".PNG"))
    with pytest.raises(DatasetError) as err:
        load_sequence(seq / "images", seq / "labels")
    assert str(err.value).startswith(f"{seq / 'labels' / '00000.PNG'}: a mask of 2 objects"), str(err.value)
