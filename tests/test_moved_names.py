"""Names of pcreg 0.2.0's modules that moved since (a run's file names to ``pcreg.runs.files``, the stretches to
``pcreg.pipeline.engine``, the cloud files' checks to ``pcreg.cloud_files``, ...): each still reads from its old
module with a DeprecationWarning naming the new spelling, as the same object; they were AttributeErrors."""

from __future__ import annotations

import importlib

import pytest

MOVED = [("pcreg.pipeline.stream_run", n, "pcreg.runs.files", n) for n in ("STATE", "STEPS", "CARRY", "CONFIDENCE", "confidence_png")] + [
    ("pcreg.review", "SUGGEST", "pcreg.runs.files", "SUGGEST"),
    ("pcreg.pipeline.keys_run", "Stretch", "pcreg.pipeline.engine", "Stretch"),
    ("pcreg.pipeline.keys_run", "stretches", "pcreg.pipeline.engine", "stretches"),
    ("pcreg.formats", "check_cloud_file", "pcreg.cloud_files", "check_cloud_file"),
    ("pcreg.formats", "check_npy_file", "pcreg.cloud_files", "check_npy_file"),
    ("pcreg.formats", "read_text_matrix", "pcreg.text_files", "read_text_matrix")]


@pytest.mark.parametrize(("old", "name", "new", "new_name"), MOVED)
def test_a_moved_name_reads_from_its_old_module_with_a_warning_naming_the_new(old, name, new, new_name):
    with pytest.warns(DeprecationWarning, match=rf"^{old}\.{name} is deprecated .*; use {new}\.{new_name}$") as said:
        got = getattr(importlib.import_module(old), name)
    assert said[0].filename == __file__  # the warning points at the reader's line
    assert got is getattr(importlib.import_module(new), new_name)


def test_the_export_s_colours_of_0_2_and_the_stretches_as_0_2_gave_them():
    import pcreg.export
    import pcreg.pipeline.keyframes

    with pytest.warns(DeprecationWarning, match="the run's class table"):
        assert pcreg.export.LABELMAP == {2: ("background", (0, 0, 0)), 0: ("ground", (0, 128, 0)), 1: ("obstacle", (128, 0, 0))}
    with pytest.warns(DeprecationWarning, match="pcreg.export.instance_colours"):
        assert pcreg.export.INSTANCE_COLOURS == {0: (128, 0, 0), 1: (0, 128, 0), 2: (0, 0, 0)}
    with pytest.warns(DeprecationWarning, match="pcreg.pipeline.engine.stretches"):
        segments = pcreg.pipeline.keyframes.segments
    assert segments(10, [0, 4, 5, 9]) == [(0, 4, range(1, 4)), (5, 9, range(6, 9))]
    assert segments(6, [2]) == [(None, 2, range(0, 2)), (2, None, range(3, 6))]
    with pytest.raises(pcreg.InputError, match="outside"):
        segments(4, [4])
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        pcreg.export.nothing  # noqa: B018


def test_icp_settings_made_by_position_keep_stepwise_where_0_2_had_it():
    from pcreg.registration.steps import IcpSettings

    s = IcpSettings("rigid", 1e-6, "none", 0.9, "point_to_point", "svd", True)
    assert s.stepwise is True and s.dlt == "svd"
