"""What ``classes=`` and a table's own checks are given that is not what they take: a table's text, a name no file
can have, labels that are not (H, W)."""

import re

import numpy as np
import pytest

from pcreg.classes import CAMVID11, class_table, labelmap_text, parse_labelmap, table_json
from pcreg.errors import InputError


@pytest.mark.parametrize("text", [labelmap_text(CAMVID11), table_json(CAMVID11)])
def test_a_tables_text_given_as_classes_is_named_as_text(text):
    """Past 255 bytes it raised OSError ("File name too long"), shorter a message of several lines."""
    with pytest.raises(InputError, match=r"^classes: the text of a class table \('.{10,60}\), not a table's name or "
                                         r"file; read it with pcreg\.classes\.parse_labelmap") as caught:
        class_table(text)
    assert "\n" not in str(caught.value)
    assert parse_labelmap(labelmap_text(CAMVID11), "text").agrees(CAMVID11)


@pytest.mark.parametrize("name", ["x" * 300, "a\0b", "missing.txt"])
def test_a_name_no_file_has_is_neither_a_table_nor_a_file(name, tmp_path):
    with pytest.raises(InputError, match="neither a built-in class table .* nor a file$") as caught:
        class_table(name)
    assert len(str(caught.value)) < 200


@pytest.mark.parametrize("shape", [(4, 5, 3), (5,), (2, 4, 5)])
def test_labels_that_are_not_one_id_a_pixel_are_refused(shape):
    """``paint`` of a colour image's three channels gave a (4, 5, 3, 3) picture; a row of ids was taken."""
    labels = np.zeros(shape, np.uint8)
    with pytest.raises(InputError, match=r"^f: labels must be \(H, W\), one class id a pixel, got shape " + re.escape(str(shape))):
        CAMVID11.check_labels(labels, "f")
    with pytest.raises(InputError, match=r"labels must be \(H, W\)"):
        CAMVID11.paint(labels)
    assert CAMVID11.paint(np.zeros((4, 5), np.uint8)).shape == (4, 5, 3)


@pytest.mark.parametrize("value, said", [(1.0000001, "got 1.0000001"), (1.5, "got 1.5"), (2.0, "got 2")])
def test_a_number_just_past_its_limit_is_shown_apart_from_it(value, said):
    """``scale=1.0000001`` was refused as "must be <= 1, got 1"."""
    from pcreg.validation import check_float

    with pytest.raises(InputError, match=rf"^scale must be <= 1, {said}$"):
        check_float(value, "scale", hi=1)


@pytest.mark.parametrize("second", ["Road", "ROAD", "ro\u200bad", "ro\u00adad"])
def test_two_names_a_person_reads_as_one_are_refused(second):
    """'road' beside 'Road', a zero-width space or a full-width letter: two classes of one name to whoever draws
    them (in CVAT's label list too), taken as two."""
    import unicodedata

    from pcreg.classes.table import ClassTable, LabelClass

    for a, b in (("road", second), ("caf\u00e9", unicodedata.normalize("NFD", "caf\u00e9")), ("road", "\uff52\uff4f\uff41\uff44"),
                 ("sign symbol", "sign\u00a0symbol"), ("sign symbol", "sign  symbol"),
                 ("\u30ac\u30fc\u30c9\u30ec\u30fc\u30eb", "\uff76\uff9e\uff70\uff84\uff9e\uff9a\uff70\uff99"),  # half-width kana
                 ("\u30d1\u30f3", "\uff8a\uff9f\uff9d")):  # full width, a no-break space, two
        with pytest.raises(InputError, match=r"differ only in case, in Unicode form or by an invisible character"):
            ClassTable((LabelClass(0, a, (1, 1, 1)), LabelClass(1, b, (2, 2, 2)), LabelClass(2, "void", (0, 0, 0))), 2, "t")
    for a, b in (("road", "roads"), ("x2", "x\u00b2"), ("\uac00", "\uffa1\uffc2"),  # a syllable, two half-width jamo ("\U0001f468\u200d\U0001f469", "\U0001f468\U0001f469"),
                 ("\u0645\u06cc\u200c\u0634\u0648\u062f", "\u0645\u06cc\u0634\u0648\u062f")):  # a joiner shows
        assert ClassTable((LabelClass(0, a, (1, 1, 1)), LabelClass(1, b, (2, 2, 2)),
                           LabelClass(2, "void", (0, 0, 0))), 2, "t").n_known == 2


def test_a_table_file_whose_name_opens_as_json_is_read(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "{labels}.txt").write_text(labelmap_text(CAMVID11))
    assert class_table("{labels}.txt").agrees(CAMVID11)
