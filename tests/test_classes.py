"""Class tables: the built-ins, labelmap.txt and JSON read and written, label PNGs (palette, ids, colour)
written and read back to the same ids, and every bad input refused in one line naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from pcreg.classes import (CAMVID11, DAVIS, LAGR, TABLES, ClassTable, LabelClass, check_tables_agree, class_table,
                           encode_label_png, is_palette_png, labelmap_text, parse_labelmap,
                           parse_table_json, read_label_png, read_labelmap, table_json, voc_colormap, write_label_png,
                           write_labelmap)
from pcreg.errors import InputError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CAMVID = DATA / "camvid" / "0001TP"
DAVIS_SEQ = DATA / "davis" / "blackswan"

# CVAT's own "Segmentation mask 1.1" label map of a task with the labels road and car (its format:
# cvat/apps/dataset_manager/formats/utils.py make_colormap adds background first; Datumaro dumps it)
CVAT_LABELMAP = "# label:color_rgb:parts:actions\nbackground:0,0,0::\nroad:128,64,128::\ncar:64,0,128::\n"


def _one_line(exc: pytest.ExceptionInfo, *needles: str) -> None:
    msg = str(exc.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, msg


def test_builtins():
    assert LAGR.known_ids == (0, 1) and LAGR.unknown == 2 and LAGR.n_known == 2
    assert [c.name for c in LAGR.classes] == ["ground", "obstacle", "unknown"]
    from pcreg.review import COLOURS

    assert {c.id: c.colour for c in LAGR.known} == COLOURS  # the review's colours
    assert CAMVID11.known_ids == tuple(range(11)) and CAMVID11.unknown == 11
    assert CAMVID11.name_of(0) == "sky" and CAMVID11.name_of(10) == "bicyclist" and CAMVID11.id_of("road") == 3
    assert DAVIS.known_ids == (0, 1) and DAVIS.name_of(1) == "object"
    assert set(TABLES) == {"lagr", "camvid11", "davis"}
    for t in TABLES.values():
        assert t.unknown_class.colour == (0, 0, 0)
        assert class_table(t.source) is t
    assert class_table(None) is LAGR
    assert "ground" in repr(LAGR) and "0 ground, 1 obstacle, 2 unknown" == LAGR.describe()


def test_camvid_mapping_agrees_with_the_table():
    """The data's mapping of CamVid ids to LAGR labels names the same classes in the same ids."""
    from pcreg.datasets.folder import CAMVID_MAPPING

    assert set(CAMVID_MAPPING) == set(CAMVID11.ids)
    assert CAMVID_MAPPING[CAMVID11.id_of("road")] == 0 and CAMVID_MAPPING[CAMVID11.unknown] == 2


def test_a_class_name_holding_colour_words_leaves_a_grey_labels_refusal_one_line():
    # the colour image's refusal was told apart by its words, "colour (": a grey label image's refusal that named
    # a class "kerb colour (red)" was taken for a colour image's and read as one (IndexError, exit 1)
    from pcreg.classes.keys import decode_key_labels

    table = ClassTable((LabelClass(0, "kerb colour (red)", (1, 2, 3)), LabelClass(1, "road", (4, 5, 6)),
                        LabelClass(2, "void", (0, 0, 0))), 2)
    grey = np.zeros((4, 4), np.uint8)
    assert decode_key_labels(cv2.imencode(".png", grey)[1].tobytes(), "k.png", table).max() == 0
    grey[0, 0] = 7
    with pytest.raises(InputError, match="k.png: label value 7 is not a class id"):
        decode_key_labels(cv2.imencode(".png", grey)[1].tobytes(), "k.png", table)
    rgb = np.zeros((4, 4, 3), np.uint8)  # a colour of no class, still read as grey when its channels agree
    rgb[0, 0] = (9, 9, 8)
    with pytest.raises(InputError, match=r"colour \(8, 9, 9\) \(at x=0, y=0\) is no class's colour"):
        decode_key_labels(cv2.imencode(".png", rgb)[1].tobytes(), "k.png", table)


def test_a_label_mapping_takes_whole_ids_each_once():
    from pcreg.classes.mappings import mapping_lut

    lut = mapping_lut({7: 0, "9": 1, 11.0: 2, np.uint8(12): 1})  # a JSON object's keys are text
    assert lut[[7, 9, 11, 12, 13]].tolist() == [0, 1, 2, 1, 255]
    # 1.7 was read as raw id 1, and True as 1 again, the last of the two winning without a word
    for bad, needle in (({1.7: 1}, "1.7"), ({0: 0.5}, "0.5"), ({True: 0}, "True"), ({1: 0, "1": 1}, "twice")):
        with pytest.raises(InputError, match=needle):
            mapping_lut(bad)


@pytest.mark.parametrize("bad, needle", [
    (((0, "a", (1, 2, 3)), (1, "b", (4, 5, 6))), "1 known class"),  # fewer than two known
    (((0, "a", (1, 2, 3)), (0, "b", (4, 5, 6)), (2, "c", (0, 0, 0))), "share the id"),
    (((0, "a", (1, 2, 3)), (1, "a", (4, 5, 6)), (2, "c", (0, 0, 0))), "share the name"),
    (((0, "a", (1, 2, 3)), (1, "b", (1, 2, 3)), (2, "c", (0, 0, 0))), "share the colour"),
    (((0, "a", (1, 2, 3)), (1, "b", (4, 5, 6)), (256, "c", (0, 0, 0))), "0..255"),
    (((0, "a", (1, 2, 3)), (1, "b", (4, 5, 256)), (2, "c", (0, 0, 0))), "three integers"),
    (((0, "a:b", (1, 2, 3)), (1, "b", (4, 5, 6)), (2, "c", (0, 0, 0))), "holds ':'"),
    (((0, "#a", (1, 2, 3)), (1, "b", (4, 5, 6)), (2, "c", (0, 0, 0))), "starts with '#'"),  # a comment line
    # what would break a labelmap.txt line or cannot be written as UTF-8: every line break str.splitlines
    # knows, a control character, half of a surrogate pair
    *[(((0, f"a{ch}b", (1, 2, 3)), (1, "b", (4, 5, 6)), (2, "c", (0, 0, 0))), "a line break or a control")
      for ch in ("\n", "\r", "\x0b", "\x0c", "\x1c", "\x85", "\u2028", "\u2029", "\x00", "\t", "\ud800",
                 "\x7f", "\x9b",  # DEL, and C1's CSI: a terminal showing the name may act on it ("\x9b2J" clears it)
                 "\u202e", "\u2066", "\u200f")],  # bidirectional controls: a summary line shown after them is turned
    # a name no reader sees: a zero-width space, Hangul's filler, a combining accent alone, a blank Braille pattern
    *[(((0, name, (1, 2, 3)), (1, "b", (4, 5, 6)), (2, "c", (0, 0, 0))), "has no name")
      for name in ("\u200b", "\u3164", "\u0301", "\u2800", "\u200b\u3164")],
])
def test_table_validation(bad, needle):
    unknown = bad[-1][0]
    with pytest.raises(InputError) as exc:
        ClassTable(tuple(LabelClass(*c) for c in bad), unknown, "my.json")
    _one_line(exc, "my.json", needle)
    with pytest.raises(InputError, match="unknown id 7"):
        ClassTable(LAGR.classes, 7, "t")
    for unknown in (True, 2.0, "2", None):  # JSON's true is no id, nor a float or a string of digits
        with pytest.raises(InputError, match="unknown id"):
            ClassTable(LAGR.classes, unknown, "t")


def test_labelmap_round_trips_and_reads_cvats(tmp_path):
    for t in TABLES.values():
        p = write_labelmap(tmp_path / t.source / "labelmap.txt", t)
        back = read_labelmap(p)
        assert back == t and back.agrees(t)
        assert class_table(str(p)) == t and class_table(p.parent) == t  # a file, or an unpacked export's folder
    text = labelmap_text(CAMVID11)
    assert text.count("0,0,0") == 1 and "background" not in text  # no extra background beside void
    assert text.splitlines()[:2] == ["# label:color_rgb:parts:actions", "void:0,0,0::"]
    cvat = parse_labelmap(CVAT_LABELMAP, "labelmap.txt")
    assert cvat.known_ids == (0, 1) and [c.name for c in cvat.known] == ["road", "car"]
    assert cvat.unknown == 2 and cvat.unknown_class.name == "background"
    assert labelmap_text(cvat) == CVAT_LABELMAP  # written back as CVAT wrote it
    # a '#' past a name's first character is part of the name to CVAT and Datumaro (a leading one starts a comment)
    hashed = parse_labelmap("background:0,0,0::\nlane #1:10,20,30::\nC#:40,50,60::\n", "labelmap.txt")
    assert [c.name for c in hashed.known] == ["lane #1", "C#"]
    assert parse_labelmap(labelmap_text(hashed), "back") == hashed
    # LAGR's table from CVAT (its unknown called background) agrees with the built-in
    assert parse_labelmap("background:0,0,0::\nground:34,197,94::\nobstacle:255,40,40::\n", "x").agrees(LAGR)


def test_labelmap_forms_datumaro_accepts():
    # comments, blank lines, spaces, parts and actions (ignored), the background named but not first
    t = parse_labelmap("# c\n\n  sky:1,2,3:head,hand:jumping  \nbackground:0,0,0::\ncar: 4, 5 ,6::\n", "f")
    assert [c.name for c in t.known] == ["sky", "car"] and t.unknown_class.name == "background"
    # no colours at all: VOC's colour map in order (its first, black, the background)
    t = parse_labelmap("background:::\nroad:::\ncar:::\n", "f")
    assert t.unknown_class.colour == (0, 0, 0) and t.known[0].colour == (128, 0, 0) and t.known[1].colour == (0, 128, 0)
    np.testing.assert_array_equal(voc_colormap(4), [[0, 0, 0], [128, 0, 0], [0, 128, 0], [128, 128, 0]])
    # no background line: one added, black, as Datumaro's exporter adds it
    t = parse_labelmap("road:128,64,128::\ncar:64,0,128::\n", "f")
    assert t.unknown == 2 and t.unknown_class == LabelClass(2, "background", (0, 0, 0))
    # a class named background that is not black is the background when nothing is black
    t = parse_labelmap("background:9,9,9::\nroad:128,64,128::\ncar:64,0,128::\n", "f")
    assert t.unknown_class.colour == (9, 9, 9)


@pytest.mark.parametrize("text, needle", [
    ("background:0,0,0::\nroad:1,2,3::\nroad:4,5,6::\n", "two classes named 'road'"),
    ("background:0,0,0::\nroad:1,2,3::\ncar:1,2,3::\n", "share the colour (1, 2, 3)"),
    ("background:0,0,0::\nroad:1,2::\ncar:4,5,6::\n", "not R,G,B"),
    ("background:0,0,0::\nroad:1,2,300::\n", "not R,G,B"),
    ("background:0,0,0::\nroad:1,2,3::\n", "1 class(es) besides 'background'"),
    ("background:0,0,0::\nroad:1,2,3::\ncar:::\n", "has no colour"),
    ("background:0,0,0::\nroad:1,2,3::x:y\n", "fields"),
    ("# nothing\n", "no class"),
    ("background:0,0,0::\nroad:1_0,2,3::\ncar:4,5,6::\n", "not R,G,B"),  # int() would read 10
    ("background:0,0,0::\nroad:\u0661,2,3::\ncar:4,5,6::\n", "not R,G,B"),  # an Arabic-Indic 1
    # a line break str.splitlines takes and a text file does not: the name named, not "class 'ro' has no colour"
    ("background:0,0,0::\nro\u2028ad:1,2,3::\ncar:4,5,6::\n", "line 2: the class name 'ro\\u2028ad' holds U+2028"),
    ("background:0,0,0::\nro\u2029ad:1,2,3::\ncar:4,5,6::\n", "line 2: the class name 'ro\\u2029ad' holds U+2029"),
    ("background:0,0,0::\r\nro\x85ad:1,2,3::\r\ncar:4,5,6::\r\n", "line 2: the class name 'ro\\x85ad' holds U+0085"),
    ("".join(f"c{i}:{i},{255 - i},1::\n" for i in range(256)), "257 classes (its background among them); a class "
     "table holds at most 256"),  # a background added: no line holds an id to name
    # colours written without the ':' before them: read as Datumaro reads a table of names, the class named
    # 'road 128 64 128' and coloured by the VOC colour map
    ("road 128 64 128\ncar 64 0 128\n", "the line 'road 128 64 128' reads as a class named so, with no colour: a "
     "labelmap.txt line is name:R,G,B:parts:actions ('road:128,64,128::')"),
    ("road,128,64,128\nsky,70,130,180\n", "('road:128,64,128::')"),
    # a file of one line that is no label map: its only name took black, the background's colour
    ("hello world\n", "no line gives a colour, so its first class, 'hello world', took the VOC colour map's first, "
     "black, the background's"),
])
def test_bad_labelmaps(tmp_path, text, needle):
    p = tmp_path / "labelmap.txt"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        read_labelmap(p)
    _one_line(exc, str(p), needle)


def test_labelmap_needs_a_black_unknown():
    t = ClassTable((LabelClass(0, "a", (1, 1, 1)), LabelClass(1, "b", (2, 2, 2)), LabelClass(2, "u", (3, 3, 3))), 2, "t.json")
    with pytest.raises(InputError, match="needs it black"):
        labelmap_text(t)


def test_json_round_trip_and_errors(tmp_path):
    for t in TABLES.values():
        p = tmp_path / f"{t.source}.json"
        p.write_text(table_json(t))
        assert class_table(str(p)) == t
    t = parse_table_json('{"classes": [{"name": "a", "colour": [1,2,3]}, {"name": "b", "colour": [4,5,6]},'
                         '{"name": "u", "colour": [0,0,0]}], "unknown": "u"}', "x")
    assert t.known_ids == (0, 1) and t.unknown == 2
    for text, needle in [("[", "not JSON"), ('{"classes": []}', '"unknown"'),
                         ('{"classes": [{"name": "a"}], "unknown": 0}', "class 0"),
                         ('{"classes": [{"name": "a", "colour": "red"}], "unknown": 0}', "colour 'red'")]:
        with pytest.raises(InputError) as exc:
            parse_table_json(text, "t.json")
        _one_line(exc, "t.json", needle)
    named_txt = tmp_path / "classes.txt"  # a JSON table under another name reads as JSON, a labelmap as one
    named_txt.write_text(table_json(CAMVID11))
    assert class_table(str(named_txt)) == CAMVID11  # the source is not compared
    braced = tmp_path / "labelmap.txt"
    braced.write_text("{odd}:1,2,3::\nb:4,5,6::\n")
    assert [c.name for c in class_table(str(braced)).classes[:2]] == ["{odd}", "b"]
    with pytest.raises(InputError, match="neither a built-in"):
        class_table("nope")
    with pytest.raises(InputError, match="--classes '': empty"):
        class_table("")


def test_a_json_table_with_a_key_written_twice_is_refused_naming_the_key(tmp_path):
    """json keeps the last of a key written twice, silently: a table whose "unknown" (or a class's "name") is
    written twice was read as the last one. Refused, naming the key, as .json and under another name."""
    three = '[{"name": "a", "colour": [1,2,3]}, {"name": "b", "colour": [4,5,6]}, {"name": "u", "colour": [0,0,0]}]'
    for text, key in [(f'{{"classes": {three}, "unknown": "u", "unknown": "a"}}', "unknown"),
                      ('{"classes": [{"name": "a", "name": "z", "colour": [1,2,3]}], "unknown": 0}', "name")]:
        for name in ("t.json", "classes.txt"):
            (tmp_path / name).write_text(text)
            with pytest.raises(InputError) as exc:
                class_table(str(tmp_path / name))
            _one_line(exc, str(tmp_path / name), f"the key {key!r} is written twice in one object")


def test_a_json_table_cut_short_under_another_name_is_refused_as_json(tmp_path):
    """A JSON table not named .json, cut short or mistyped, was read as a label map and refused for "line 1 has 5
    ':'-separated fields"; the refusal says it is not JSON, and where. A label map whose first class is named in
    braces still reads as one."""
    cut = tmp_path / "classes.txt"
    cut.write_text(table_json(CAMVID11)[:200])
    with pytest.raises(InputError) as exc:
        class_table(str(cut))
    _one_line(exc, str(cut), "neither a label map nor a JSON table (not JSON: ")
    braced = tmp_path / "labelmap.txt"
    braced.write_text("{odd:1,2,3::\nb:4,5,6::\n")
    assert [c.name for c in class_table(str(braced)).classes[:2]] == ["{odd", "b"]


def test_a_zip_or_an_image_given_as_a_class_table_is_named_as_what_it_is(tmp_path):
    """--classes EXPORT.zip (or a label PNG) was refused as "not UTF-8 text (label map)" alone."""
    import zipfile

    export = tmp_path / "task.zip"
    with zipfile.ZipFile(export, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("labelmap.txt", labelmap_text(CAMVID11))
    image = tmp_path / "key.png"
    cv2.imwrite(str(image), np.zeros((48, 64), np.uint8))
    for path, said in ((export, "it is a zip archive (a CVAT export? its labelmap.txt is the table"),
                       (image, "it is an image, not a class table")):
        with pytest.raises(InputError) as exc:
            class_table(str(path))
        _one_line(exc, str(path), said)


def test_a_huge_number_in_a_json_table_is_refused_short():
    """An id, unknown or colour of 10**400 in a JSON table is refused in one short line, not all 401 digits echoed:
    read as JSON, an integer longer than any pcreg writes is refused; one of 20 digits is echoed by its first."""
    big, long = str(10**400), str(10**19)
    three = [{"name": "a", "colour": [1, 2, 3]}, {"name": "b", "colour": [4, 5, 6]}, {"name": "u", "colour": [0, 0, 0]}]
    for n, needle in ((big, "an integer of 401 digits, longer than any pcreg writes"), (long, "1000")):
        for text, where in [(f'{{"classes": [{{"id": {n}, "name": "a", "colour": [1,2,3]}}], "unknown": 0}}', "class id "),
                            (json.dumps({"classes": three, "unknown": 0}).replace(': 0}', f': {n}}}'), "the unknown id "),
                            (json.dumps({"classes": three, "unknown": "u"}).replace("[1, 2, 3]", f"[{n}, 2, 3]"),
                             "class 'a' has colour (")]:
            with pytest.raises(InputError) as exc:
                parse_table_json(text, "t.json")
            _one_line(exc, "t.json", needle if n == big else where + needle)
            assert len(str(exc.value)) < 160, str(exc.value)


def test_tables_agree():
    assert check_tables_agree([("a.png", LAGR), ("b.png", LAGR)]) is LAGR
    with pytest.raises(InputError) as exc:
        check_tables_agree([("a/labelmap.txt", LAGR), ("b/labelmap.txt", LAGR), ("c/labelmap.txt", DAVIS)])
    _one_line(exc, "c/labelmap.txt", "a/labelmap.txt", "class 0 is")


@pytest.mark.parametrize("table", list(TABLES.values()), ids=list(TABLES))
def test_label_png_round_trip(tmp_path, table):
    rng = np.random.default_rng(0)
    labels = rng.choice(np.array(table.ids, np.uint8), size=(37, 53))
    p = write_label_png(tmp_path / "x.png", labels, table)
    data = p.read_bytes()
    assert is_palette_png(data) and not list(tmp_path.glob(".*.tmp"))
    back = read_label_png(p, table)
    assert back.dtype == np.uint8 and back.shape == labels.shape
    np.testing.assert_array_equal(back, labels)
    with Image.open(p) as im:  # any viewer: the table's colours
        assert im.mode == "P"
        np.testing.assert_array_equal(np.asarray(im.convert("RGB")), table.paint(labels))
    # OpenCV expands the palette to colour: the colours read back through the table are the same ids
    bgr = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    assert bgr.ndim == 3
    np.testing.assert_array_equal(table.ids_from_colours(bgr[:, :, ::-1], "x"), labels)
    assert encode_label_png(labels, table) == data  # the same labels, the same bytes


def test_label_png_ids_and_colour_forms(tmp_path):
    labels = np.array([[0, 1, 2], [2, 1, 0]], np.uint8)
    cv2.imwrite(str(tmp_path / "ids.png"), labels)
    np.testing.assert_array_equal(read_label_png(tmp_path / "ids.png", LAGR), labels)
    cv2.imwrite(str(tmp_path / "ids16.png"), labels.astype(np.uint16))
    np.testing.assert_array_equal(read_label_png(tmp_path / "ids16.png", LAGR), labels)
    cv2.imwrite(str(tmp_path / "rgb.png"), LAGR.paint(labels)[:, :, ::-1])
    np.testing.assert_array_equal(read_label_png(tmp_path / "rgb.png", LAGR), labels)
    bgra = np.dstack([LAGR.paint(labels)[:, :, ::-1], np.full(labels.shape, 255, np.uint8)])
    cv2.imwrite(str(tmp_path / "rgba.png"), bgra)
    np.testing.assert_array_equal(read_label_png(tmp_path / "rgba.png", LAGR), labels)
    bgra[0, 0, 3] = 0
    cv2.imwrite(str(tmp_path / "rgba.png"), bgra)
    with pytest.raises(InputError, match="colour labels with transparent"):
        read_label_png(tmp_path / "rgba.png", LAGR)
    grey = Image.fromarray(np.dstack([labels, np.where(labels == 2, 0, 255).astype(np.uint8)]), "LA")
    grey.save(tmp_path / "la.png")  # grey and alpha: named as grey, not as colours
    with pytest.raises(InputError, match="la.png: grey labels with transparent"):
        read_label_png(tmp_path / "la.png", LAGR)
    # a VOC-style palette PNG (VOC's colour map) read through a table in those colours
    voc = ClassTable(tuple(LabelClass(i, n, tuple(int(v) for v in voc_colormap(3)[i]))
                           for i, n in enumerate(["background", "aeroplane", "bicycle"])), 0, "voc")
    im = Image.frombytes("P", (3, 2), np.array([[0, 1, 2], [2, 2, 0]], np.uint8).tobytes())
    im.putpalette(voc_colormap(256).tobytes())
    im.save(tmp_path / "voc.png")
    np.testing.assert_array_equal(read_label_png(tmp_path / "voc.png", voc), [[0, 1, 2], [2, 2, 0]])


def test_bad_label_pngs(tmp_path):
    p = tmp_path / "k.png"
    cv2.imwrite(str(p), np.array([[0, 1, 7]], np.uint8))
    with pytest.raises(InputError) as exc:
        read_label_png(p, LAGR)
    _one_line(exc, str(p), "label value 7 is not a class id", "0 ground, 1 obstacle, 2 unknown")
    rgb = LAGR.paint(np.array([[0, 1, 2]], np.uint8))
    rgb[0, 1] = (1, 2, 3)
    cv2.imwrite(str(p), rgb[:, :, ::-1])
    with pytest.raises(InputError) as exc:
        read_label_png(p, LAGR)
    _one_line(exc, str(p), "colour (1, 2, 3)", "x=1, y=0")
    write_label_png(p, np.array([[0, 1, 2]], np.uint8), LAGR)  # LAGR's palette read as DAVIS's ids
    with pytest.raises(InputError) as exc:
        read_label_png(p, DAVIS)
    _one_line(exc, str(p), "palette", "'background'")
    write_label_png(p, np.array([[0, 11]], np.uint8), CAMVID11)
    with pytest.raises(InputError, match="label value 11"):
        read_label_png(p, LAGR)
    with pytest.raises(InputError, match="label value 5"):
        write_label_png(tmp_path / "w.png", np.array([[0, 5]], np.uint8), LAGR)
    assert not (tmp_path / "w.png").exists()
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 30)
    with pytest.raises(InputError, match=str(p)):
        read_label_png(p, LAGR)
    with pytest.raises(InputError, match="no such file"):
        read_label_png(tmp_path / "none.png", LAGR)
    # a palette PNG with a pixel beyond its palette (three colours, index 5): no viewer can show it, and a
    # conversion to RGB makes it black; refused where a key frame is read and where a CVAT mask is
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    short = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 1, 8, 3, 0, 0, 0))
             + chunk(b"PLTE", bytes(CAMVID11.palette()[:3].ravel())) + chunk(b"IDAT", zlib.compress(b"\0\0\1\2\5"))
             + chunk(b"IEND", b""))
    p.write_bytes(short)
    with pytest.raises(InputError) as exc:
        read_label_png(p, CAMVID11)
    _one_line(exc, str(p), "index 5, beyond its palette of 3 colours")
    from pcreg.classes.cvat import _decode_mask

    with pytest.raises(InputError, match="m.png: a pixel of index 5, beyond its palette"):
        _decode_mask(short, "m.png", CAMVID11, [], None)
    # a JPEG, whatever its name says: its values are changed at every edge (a class table of 150 classes would
    # read most of them as some class), so it is no label image
    ids = (np.arange(48 * 64).reshape(48, 64) // 300 % 11).astype(np.uint8)
    p.write_bytes(cv2.imencode(".jpg", ids * 12)[1].tobytes())
    with pytest.raises(InputError) as exc:
        read_label_png(p, CAMVID11)
    _one_line(exc, str(p), "a JPEG", "lossless")


@pytest.mark.data
@pytest.mark.skipif(not CAMVID.is_dir(), reason="needs ../shared/data/camvid (the shared CamVid clips)")
def test_camvid_labels_read_and_written_in_camvid11(tmp_path):
    files = sorted((CAMVID / "labels").glob("*.png"))[:3]
    for f in files:
        raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        ids = read_label_png(f, CAMVID11)  # 8-bit class ids
        np.testing.assert_array_equal(ids, raw)
        out = write_label_png(tmp_path / f.name, ids, CAMVID11)
        np.testing.assert_array_equal(read_label_png(out, CAMVID11), raw)


@pytest.mark.data
@pytest.mark.skipif(not DAVIS_SEQ.is_dir(), reason="needs ../shared/data/davis (the shared DAVIS sequences)")
def test_davis_masks_through_the_mapping_then_the_table(tmp_path):
    from pcreg.datasets.folder import mapping_lut

    f = sorted((DAVIS_SEQ / "labels").glob("*.png"))[0]
    raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    with pytest.raises(InputError, match="label value 255"):
        read_label_png(f, DAVIS)  # a 0/255 mask: DAVIS_MAPPING reads it
    ids = mapping_lut("davis")[raw]
    out = write_label_png(tmp_path / "m.png", ids, DAVIS)
    np.testing.assert_array_equal(read_label_png(out, DAVIS), (raw != 0).astype(np.uint8))


def test_runs_label_files_and_palette_pngs_read_back_the_same(tmp_path):
    """What ``pcreg run`` writes today (pcreg.runs.files.write_labels, one grey channel) and the palette PNG
    that replaces it read back through read_label_png as identical arrays."""
    from pcreg.datasets import synthetic
    from pcreg.runs.files import write_labels

    labels = synthetic("syn1a", 1, 0, width=160, height=120)[0].labels
    assert set(np.unique(labels)) == {0, 1, 2}
    write_labels(tmp_path / "today.png", labels)
    write_label_png(tmp_path / "palette.png", labels, LAGR)
    today, palette = read_label_png(tmp_path / "today.png", LAGR), read_label_png(tmp_path / "palette.png", LAGR)
    np.testing.assert_array_equal(today, labels)
    np.testing.assert_array_equal(palette, labels)
    assert today.dtype == palette.dtype == np.uint8


def test_the_hint_for_values_beyond_the_table_follows_what_they_look_like():
    """A soft-edged object mask (resized, or saved as JPEG) holds values between 0 and 255: its hint was
    CamVid's table, which refuses it too; it is the object mask's mapping."""
    from pcreg.classes.mappings import mask_hint

    soft = np.array([[0, 4, 128, 255]], np.uint8)
    assert "--mapping davis" in mask_hint(soft) and "camvid11" not in mask_hint(soft)
    assert "--mapping davis" in mask_hint(np.array([[0, 255]], np.uint8))
    assert "--classes camvid11" in mask_hint(np.array([[0, 3, 11]], np.uint8))
    assert mask_hint(np.array([[0, 1, 2]], np.uint8)) == ""
    # under a table of two known classes of its own, a DAVIS mask's 255 had no word of what the file is; under the
    # default table the same hint, once
    from pcreg.classes.keys import decode_key_labels

    mine = ClassTable((LabelClass(0, "bg", (1, 2, 3)), LabelClass(1, "goat", (200, 0, 0)), LabelClass(2, "void", (0, 0, 0))),
                      2, "mine.json")
    png = cv2.imencode(".png", np.array([[0, 255], [255, 0]], np.uint8))[1].tobytes()
    for table, named in ((mine, "0 bg, 1 goat, 2 void"), (LAGR, "0 ground, 1 obstacle, 2 unknown")):
        with pytest.raises(InputError) as exc:
            decode_key_labels(png, "key.png", table)
        said = str(exc.value)
        assert said.startswith(f"key.png: label value 255 is not a class id ({named}); it is a 0/255 object mask (DAVIS): "
                               "pcreg run's --mapping davis reads it"), said
        assert said.count("0/255 object mask") == 1, said
    # 8-bit ids scaled to 16 bits (k x 257), as some converters save a label PNG: said, as a dark frame is
    with pytest.raises(InputError, match=r"label value 2827 is not a class id .*; every value is a multiple of 257 "
                                         r"\(2827 = 11 x 257\): 8-bit class ids scaled to 16 bits"):
        CAMVID11.check_labels(np.array([[0, 257, 2827]], np.uint16), "key.png")


def _damaged_png(tmp_path, how: str) -> Path:
    """A palette PNG of two classes with its image data's CRC flipped, cut inside its image data, or cut before its
    IEND chunk."""
    labels = np.zeros((48, 64), np.uint8)
    labels[10:30, 10:40] = 1
    im = Image.fromarray(labels, "P")
    im.putpalette([0, 0, 0, 128, 0, 0] + [0] * 762)
    path = tmp_path / f"{how}.png"
    im.save(path)
    data = bytearray(path.read_bytes())
    at = data.find(b"IDAT")
    end = at + 4 + int.from_bytes(data[at - 4:at], "big")  # the chunk's CRC
    if how == "crc":
        data[end] ^= 0xFF
    elif how == "cut":
        data = data[:end - 5]
    else:  # cut before its IEND chunk: the image data whole, read as labels by Pillow
        data = data[:data.find(b"IEND") - 4]
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("how", ["crc", "cut", "no end"])
def test_a_damaged_palette_png_is_refused_as_key_labels_and_as_an_object_mask(tmp_path, how):
    """Pillow, which reads palette PNGs, does not check the image data's CRC: a key mask whose IDAT CRC was damaged,
    or cut before its IEND chunk, was read as labels (OpenCV's libpng refuses the same file)."""
    from pcreg.classes.keys import read_key_labels, read_object_mask

    path = _damaged_png(tmp_path, how)
    said = {"crc": "a CRC error in its 'IDAT' chunk", "cut": "its 'IDAT' chunk runs past the end of the file",
            "no end": "the file ends before its IEND chunk"}[how]
    with pytest.raises(InputError, match=f"{path.name}: {said}"):
        read_key_labels(path, DAVIS)
    with pytest.raises(InputError, match=f"{path.name}: {said}"):
        read_object_mask(path)


_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))


def _palette_png(labels: np.ndarray, rows: int | None = None, *, interlaced: bool = False) -> bytes:
    """A palette PNG of ``labels`` written by hand, every chunk whole and its CRC right, its compressed image data
    ending cleanly after ``rows`` of its rows (None: all; interlaced: of the rows of all seven passes)."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    h, w = labels.shape
    parts = [labels[y0::dy, x0::dx] for x0, y0, dx, dy in _ADAM7] if interlaced else [labels]
    lines = [b"\0" + bytes(r) for part in parts if part.size for r in part]
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, int(interlaced)))
            + chunk(b"PLTE", DAVIS.palette()[:2].tobytes()) + chunk(b"IDAT", zlib.compress(b"".join(lines[:rows])))
            + chunk(b"IEND", b""))


@pytest.mark.parametrize("interlaced", [False, True])
def test_a_palette_png_whose_image_data_ends_early_is_refused_not_filled_with_the_first_class(tmp_path, interlaced):
    """A palette PNG whose compressed image data ends cleanly after 10 of its 48 rows, each chunk's CRC right: Pillow
    filled the missing rows with index 0 and pcreg read them as the first class, as key labels, truth and an object
    mask alike (libpng refuses the same file, "Not enough image data"). A whole one, interlaced too, reads as drawn."""
    from pcreg.classes.keys import read_key_labels, read_object_mask

    labels = np.zeros((48, 64), np.uint8)
    labels[10:30, 10:40] = 1
    whole, cut = tmp_path / "whole.png", tmp_path / "cut.png"
    whole.write_bytes(_palette_png(labels, interlaced=interlaced))
    cut.write_bytes(_palette_png(labels, 10, interlaced=interlaced))
    assert cv2.imdecode(np.frombuffer(whole.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED) is not None  # libpng's word
    assert np.array_equal(read_key_labels(whole, DAVIS), labels)
    assert np.array_equal(read_object_mask(whole)[0], labels)
    said = f"{cut.name}: its image data ends before the 48 rows of 64 px its header declares"
    with pytest.raises(InputError, match=said):
        read_key_labels(cut, DAVIS)
    with pytest.raises(InputError, match=said):
        read_object_mask(cut)


def test_a_palette_png_with_a_damaged_text_chunk_is_refused_naming_the_chunk(tmp_path):
    """A tEXt chunk's CRC error (a faulty tool): Pillow refused the file as "cannot identify image file
    <_io.BytesIO object at 0x...>"; the refusal names the chunk."""
    from PIL import PngImagePlugin

    from pcreg.classes.keys import read_key_labels

    im = Image.fromarray(np.zeros((48, 64), np.uint8), "P")
    im.putpalette([0, 0, 0, 128, 0, 0] + [0] * 762)
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", "a tool")
    path = tmp_path / "text.png"
    im.save(path, pnginfo=info)
    data = bytearray(path.read_bytes())
    at = data.find(b"tEXt")
    data[at + 4 + int.from_bytes(data[at - 4:at], "big")] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="text.png: a CRC error in its 'tEXt' chunk: the file is damaged"):
        read_key_labels(path, DAVIS)


def test_lossy_label_images_behind_other_headers_are_refused(tmp_path):
    """A TIFF compressed as JPEG and a lossy WebP after a VP8X header (metadata or alpha) were read as labels, 1.7%
    and 10% of a key frame's pixels in the wrong class, without a word: only a JPEG's and a plain VP8 WebP's first
    bytes were recognised. Lossless ones (LZW TIFF, VP8L WebP behind VP8X) still read exactly."""
    ids = (np.arange(48 * 64).reshape(48, 64) // 300 % 11).astype(np.uint8)
    exif = Image.Exif()
    exif[0x0131] = "an editor"  # Software: metadata brings the extended header
    grey, colours = Image.fromarray(ids), Image.fromarray(CAMVID11.paint(ids))
    cases = {"jpeg.tif": (grey, {"compression": "jpeg"}, "a TIFF compressed as JPEG"),
             "lzw.tif": (grey, {"compression": "tiff_lzw"}, None),
             "vp8x.webp": (colours, {"quality": 90, "exif": exif.tobytes()}, "a lossy WebP"),
             "vp8l.webp": (colours, {"lossless": True, "exif": exif.tobytes()}, None)}
    for name, (im, options, said) in cases.items():
        p = tmp_path / name
        im.save(p, **options)
        if name.endswith(".webp"):
            assert p.read_bytes()[12:16] == b"VP8X", name  # behind the extended header
        if said is None:
            np.testing.assert_array_equal(read_label_png(p, CAMVID11), ids)
        else:
            with pytest.raises(InputError) as exc:
                read_label_png(p, CAMVID11)
            _one_line(exc, str(p), said, "lossless")


def test_lossy_label_images_pillow_misjudged_are_refused(tmp_path):
    """A lossy WebP animation of one frame (its image inside an ANMF chunk) passed as lossless: it was refused for
    a smeared edge's colour of no class, where the file's kind is the cause. A TIFF's compression is read from its
    tag, not from Pillow's opening of it: libtiff's own JPEG TIFF is refused as before."""
    ids = (np.arange(48 * 64).reshape(48, 64) // 300 % 11).astype(np.uint8)
    colours = CAMVID11.paint(ids)
    anim = tmp_path / "anim.webp"
    Image.fromarray(colours).save(anim, save_all=True, append_images=[Image.fromarray(colours[::-1])], quality=90)
    data = anim.read_bytes()
    second = data.index(b"ANMF", data.index(b"ANMF") + 4)
    one = data[:second] + data[second + 8 + int.from_bytes(data[second + 4:second + 8], "little"):]  # its first frame
    anim.write_bytes(one[:4] + (len(one) - 8).to_bytes(4, "little") + one[8:])
    assert one[12:16] == b"VP8X" and one.count(b"ANMF") == 1
    ok, buf = cv2.imencode(".tif", colours[:, :, ::-1], [cv2.IMWRITE_TIFF_COMPRESSION, 7, cv2.IMWRITE_TIFF_ROWSPERSTRIP, 8])
    assert ok
    (tmp_path / "libtiff.tif").write_bytes(buf.tobytes())
    for name, said in (("anim.webp", "a lossy WebP"), ("libtiff.tif", "a TIFF compressed as JPEG")):
        with pytest.raises(InputError) as exc:
            read_label_png(tmp_path / name, CAMVID11)
        _one_line(exc, str(tmp_path / name), said, "lossless")


def test_class_ids_saved_as_colour_with_a_stray_pixel_name_that_pixel(tmp_path):
    """Class ids saved as grey RGB with one stray colour at (5, 5) were refused naming the colour of pixel (0, 0), a
    correct id: the stray pixel is named. A colour image of the table's colours is read as before."""
    from pcreg.classes.keys import read_key_labels

    ids = (np.arange(48 * 64).reshape(48, 64) // 300 % 11).astype(np.uint8)
    grey = np.dstack([ids] * 3)
    grey[5, 5] = (1, 2, 3)
    p = tmp_path / "stray.png"
    cv2.imwrite(str(p), grey)
    with pytest.raises(InputError, match=r"stray.png: grey \(class ids saved as colour\) but for 1 pixel\(s\), the "
                                         r"first at x=5, y=5 \(3, 2, 1\)"):
        read_key_labels(p, CAMVID11, "none")
    cv2.imwrite(str(p), CAMVID11.paint(ids)[:, :, ::-1])
    np.testing.assert_array_equal(read_key_labels(p, CAMVID11, "none"), ids)


def test_a_colour_png_with_one_colour_marked_transparent_reads_as_its_colours(tmp_path):
    """An RGB label PNG whose void colour a tool marked transparent (a tRNS chunk: one colour, every pixel's colour
    still stored) was refused as "transparent pixels", where a palette's or a grey PNG's tRNS was read. It reads as
    its colours, as a key label and as a CVAT mask; an alpha channel below 255 is still refused."""
    from pcreg.classes.cvat import _decode_mask

    ids = (np.arange(48 * 64).reshape(48, 64) // 250 % 12).astype(np.uint8)
    colours = CAMVID11.paint(ids)
    p = tmp_path / "trns.png"
    Image.fromarray(colours).save(p, transparency=tuple(int(v) for v in CAMVID11.palette()[CAMVID11.unknown]))
    assert b"tRNS" in p.read_bytes() and p.read_bytes()[25] == 2 and (ids == CAMVID11.unknown).any()
    np.testing.assert_array_equal(read_label_png(p, CAMVID11), ids)
    order = [CAMVID11.unknown, *CAMVID11.known_ids]
    np.testing.assert_array_equal(_decode_mask(p.read_bytes(), "m.png", CAMVID11, order, None), ids)
    rgba = np.dstack([colours, np.where(ids == CAMVID11.unknown, 0, 255).astype(np.uint8)])
    Image.fromarray(rgba).save(p)
    with pytest.raises(InputError, match="transparent pixels"):
        read_label_png(p, CAMVID11)


def test_a_grey_png_of_fewer_than_8_bits_is_read_as_it_stores_its_values(tmp_path):
    """A grey PNG of 4 bits holding ids 0..11 was refused as "label value 17" (libpng widens 1 to 17), and a 1-bit
    mask of 0 and 1 read as 0 and 255. The values are read as the file stores them: as labels, as a CVAT
    one-channel mask, and as an object mask."""
    from pcreg.classes.cvat import _decode_mask
    from pcreg.classes.keys import object_values

    ids = (np.arange(48 * 64).reshape(48, 64) // 300 % 12).astype(np.uint8)
    p = tmp_path / "ids4.png"
    Image.fromarray(ids).save(p, bits=4)
    assert p.read_bytes()[24] == 4  # the IHDR's bit depth
    np.testing.assert_array_equal(read_label_png(p, CAMVID11), ids)
    order = [CAMVID11.unknown, *CAMVID11.known_ids]
    np.testing.assert_array_equal(_decode_mask(p.read_bytes(), "m.png", CAMVID11, order, None),
                                  np.asarray(order)[ids])
    one = tmp_path / "one.png"
    Image.fromarray((ids % 2).astype(bool)).save(one)  # mode '1': one bit a pixel
    assert one.read_bytes()[24] == 1
    np.testing.assert_array_equal(read_label_png(one, LAGR), ids % 2)
    values, several = object_values(one.read_bytes(), "one.png")
    assert not several and set(np.unique(values)) == {0, 1}
