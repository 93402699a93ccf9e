"""Property-based fuzzing of the files of classes: CVAT's ``labelmap.txt`` and pcreg's JSON class table (damaged as
bytes and as text: a field dropped, a colon added, odd characters, a number made huge or negative), a CVAT
"Segmentation mask 1.1" export as a zip (its bytes damaged, or a valid archive whose labelmap.txt, masks, lists or
names are), and key label PNGs read through a class table (palette, class ids, colours; a DAVIS object mask). Each
reader returns a valid result or raises PcregError in one line naming the file; nothing else, and never hangs.
Every seed is made here."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pcreg.classes import CAMVID11, DAVIS, LAGR, ClassTable, encode_label_png, labelmap_text, table_json
from _fuzz import FUZZ, FUZZ_MORE, ODD_NUMBERS, header_then_random, held_to_contract, mutated_bytes, mutated_json, mutated_text

ROAD_CAR = "# label:color_rgb:parts:actions\nbackground:0,0,0::\nroad:128,64,128::\ncar:0,0,192::\n"

#: Label maps as CVAT writes them, and as others do: without the background, without colours, with parts and
#: actions, in Windows's line breaks behind a BOM.
LABELMAPS = {
    "cvat": ROAD_CAR,
    "no_background": "road:128,64,128::\ncar:0,0,192::\nsky:128,128,128::\n",
    "no_colours": "# label:color_rgb:parts:actions\nbackground:::\nroad:::\ncar:::\n",
    "parts": "background:0,0,0::\nperson:192,128,128:head,hand,foot:jumping,running\nhorse:192,0,128::\n",
    "windows": "\ufeff" + ROAD_CAR.replace("\n", "\r\n"),
    "camvid11": labelmap_text(CAMVID11),
}
#: JSON tables as pcreg writes them, one whose unknown is named and one whose ids have a gap.
TABLES = {
    "lagr": json.loads(table_json(LAGR)),
    "camvid11": json.loads(table_json(CAMVID11)),
    "named_unknown": {"classes": [{"name": "sky", "colour": [128, 128, 128]}, {"name": "road", "colour": [128, 64, 128]},
                                  {"name": "void", "colour": [0, 0, 0]}], "unknown": "void"},
    "gap": {"classes": [{"id": 0, "name": "void", "colour": [0, 0, 0]}, {"id": 3, "name": "a", "colour": [1, 2, 3]},
                        {"id": 7, "name": "b", "colour": [4, 5, 6]}], "unknown": 0},
}


def _write(folder: Path, name: str, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        if old.is_file():
            old.unlink()
    path = folder / name
    path.write_bytes(data)
    return path


def _check_table(table: ClassTable, from_labelmap: bool) -> None:
    """A table read is one: two known classes or more, and its JSON and (its unknown black, read from a label map)
    its labelmap.txt read back as itself."""
    from pcreg.classes import parse_labelmap, parse_table_json

    assert isinstance(table, ClassTable) and table.n_known >= 2
    again = parse_table_json(table_json(table), "again")
    assert again.agrees(table) and again.unknown_class.name == table.unknown_class.name
    if from_labelmap and table.unknown_class.colour == (0, 0, 0):
        assert parse_labelmap(labelmap_text(table), "again").agrees(table)


def _read_table(data: bytes, folder: Path, name: str) -> None:
    """The table of ``data`` saved as ``name`` (``labelmap.txt``, ``classes.json`` or a name of neither kind),
    read as ``--classes`` reads it; ``labelmap.txt`` also as a folder holding it (an unpacked export)."""
    from pcreg.classes import class_table

    path = _write(folder, name, data)
    labelmap = name != "classes.json" and not data.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{")
    with held_to_contract(str(path)):
        _check_table(class_table(str(path)), labelmap)
    if name == "labelmap.txt":
        with held_to_contract(str(path)):
            _check_table(class_table(str(folder)), labelmap)


@pytest.mark.parametrize("seed", sorted(LABELMAPS))
@FUZZ
@given(data=st.data())
def test_mutated_labelmaps(tmp_path_factory, seed, data):
    text = data.draw(mutated_text(LABELMAPS[seed]))
    name = data.draw(st.sampled_from(["labelmap.txt", "classes"]))
    _read_table(text.encode("utf-8", "surrogatepass"), tmp_path_factory.getbasetemp() / f"lm_{seed}", name)


@pytest.mark.parametrize("seed", sorted(TABLES))
@FUZZ
@given(data=st.data())
def test_mutated_json_tables(tmp_path_factory, seed, data):
    doc = data.draw(mutated_json(TABLES[seed]))
    text = json.dumps(doc, indent=data.draw(st.sampled_from([None, 1])))
    if data.draw(st.booleans()):
        text = data.draw(mutated_text(text, sep=","))
    name = data.draw(st.sampled_from(["classes.json", "classes", "labelmap.txt"]))
    _read_table(text.encode("utf-8", "surrogatepass"), tmp_path_factory.getbasetemp() / f"js_{seed}", name)


@pytest.mark.parametrize("seed", ["cvat", "parts", "camvid11"])
@FUZZ
@given(data=st.data())
def test_table_bytes(tmp_path_factory, seed, data):
    """Damaged as bytes (half a UTF-8 character, a NUL), random bytes, the start of a table then random bytes."""
    text = LABELMAPS[seed] if seed != "camvid11" else table_json(CAMVID11)
    how = data.draw(st.sampled_from(["mutated", "random", "head"]))
    raw = text.encode()
    blob = data.draw(mutated_bytes(raw) if how == "mutated" else st.binary(max_size=512) if how == "random"
                     else header_then_random(raw))
    name = "classes.json" if seed == "camvid11" else "labelmap.txt"
    _read_table(blob, tmp_path_factory.getbasetemp() / f"tb_{seed}", name)


@st.composite
def damaged_table(draw) -> tuple[bytes, str]:
    """Any of the tables above damaged any of the ways above, and the name it is saved under."""
    how = draw(st.sampled_from(["labelmap", "json", "bytes"]))
    if how == "labelmap":
        text = draw(mutated_text(LABELMAPS[draw(st.sampled_from(sorted(LABELMAPS)))]))
    elif how == "json":
        text = json.dumps(draw(mutated_json(TABLES[draw(st.sampled_from(sorted(TABLES)))])))
        text = draw(mutated_text(text, sep=",")) if draw(st.booleans()) else text
    else:
        raw = draw(st.sampled_from([*LABELMAPS.values(), table_json(CAMVID11)])).encode()
        return draw(mutated_bytes(raw) | header_then_random(raw) | st.binary(max_size=512)), \
            draw(st.sampled_from(["labelmap.txt", "classes.json", "classes"]))
    return text.encode("utf-8", "surrogatepass"), draw(st.sampled_from(["labelmap.txt", "classes.json", "classes"]))


@pytest.mark.slow
@FUZZ_MORE
@given(table=damaged_table())
def test_damaged_tables_more(tmp_path_factory, table):
    _read_table(table[0], tmp_path_factory.getbasetemp() / "tables_more", table[1])


# -- a CVAT export, zipped -------------------------------------------------------------------------------------

SHAPE = (24, 32)


def _mask(kind: str) -> bytes:
    """A class mask of road over car (CVAT's colours: RGB; or a palette PNG; or one channel of labelmap lines)."""
    from PIL import Image

    h, w = SHAPE
    lines = np.zeros(SHAPE, np.uint8)
    lines[2: h // 2], lines[h // 2:] = 1, 2
    lines[:, :3] = 0  # a strip nobody labelled
    colours = np.array([(0, 0, 0), (128, 64, 128), (0, 0, 192)], np.uint8)
    if kind == "rgb":
        return cv2.imencode(".png", np.ascontiguousarray(colours[lines][:, :, ::-1]))[1].tobytes()
    if kind == "grey":
        return cv2.imencode(".png", lines)[1].tobytes()
    im = Image.frombytes("P", (w, h), lines.tobytes())
    im.putpalette(colours.tobytes(), rawmode="RGB")
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    return buf.getvalue()


def _members(mask: str = "rgb", names: tuple[str, str] = ("f0", "f1")) -> dict[str, bytes]:
    """The members of an export of two frames, the first drawn on and the second not."""
    blank = cv2.imencode(".png", np.zeros((*SHAPE, 3), np.uint8))[1].tobytes()
    return {"labelmap.txt": ROAD_CAR.encode(), "ImageSets/Segmentation/default.txt": "".join(f"{n}\n" for n in names).encode(),
            f"SegmentationClass/{names[0]}.png": _mask(mask), f"SegmentationClass/{names[1]}.png": blank,
            f"SegmentationObject/{names[0]}.png": _mask("rgb")}


def _names(frames) -> tuple[str, str]:
    return ("f0", "f1") if frames.kind == "folder" else ("frame_000000", "000001")


def _zipped(members: dict[str, bytes], compression: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


@pytest.fixture(scope="module", params=["folder", "video"])
def frames(request, tmp_path_factory):
    """The frames the export labels, opened as a run opens them: ``f0.png`` and ``f1.png``, or a video of two
    frames (whose masks are named ``frame_000000``, CVAT's name, and ``000001``, the frame's number)."""
    from pcreg.datasets.sources import open_frames

    folder = tmp_path_factory.mktemp("cvat_frames")
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (*SHAPE, 3), dtype=np.uint8) for _ in range(2)]
    if request.param == "folder":
        for i, image in enumerate(images):
            cv2.imwrite(str(folder / f"f{i}.png"), image)
        return open_frames(folder)
    av = pytest.importorskip("av")
    from _videos import mux_all

    with av.open(str(folder / "two.mp4"), "w") as c:
        s = c.add_stream("mpeg4", rate=10)
        s.width, s.height, s.pix_fmt = SHAPE[1], SHAPE[0], "yuv420p"
        mux_all(c, s, images)
    return open_frames(folder / "two.mp4")


def _read_export(frames, data: bytes, folder: Path) -> None:
    """``data`` as ``--labels EXPORT.zip``: its table and key frames (:func:`pcreg.classes.cvat.read_cvat_keys`)."""
    from pcreg.classes.cvat import read_cvat_keys

    path = _write(folder, "export.zip", data)
    with held_to_contract(str(path)):
        table, keys = read_cvat_keys(path, frames, SHAPE)
        _check_table(table, True)
        assert keys and set(keys) <= {0, 1}
        for labels in keys.values():
            assert labels.shape == SHAPE and labels.dtype == np.uint8 and table.valid()[labels].all()


def test_the_seed_export_reads(frames, tmp_path):
    """The unmutated export is valid: its labelmap's classes, the first frame drawn on, in every kind of mask."""
    from pcreg.classes.cvat import read_cvat_keys

    for kind in ("rgb", "grey", "palette"):
        path = tmp_path / "export.zip"
        path.write_bytes(_zipped(_members(kind, _names(frames))))
        table, keys = read_cvat_keys(path, frames, SHAPE)
        assert [c.name for c in table.known] == ["road", "car"] and list(keys) == [0]
        assert (keys[0][:, :3] == 2).all() and keys[0][5, 10] == 0 and keys[0][20, 10] == 1, kind


@st.composite
def damaged_export(draw, names: tuple[str, str]) -> bytes:
    """An export's archive damaged as bytes, random bytes, a zip's first bytes then random ones; or a valid archive
    whose labelmap.txt, a mask, a list or the members' names are damaged, a member dropped or one added."""
    members = _members(draw(st.sampled_from(["rgb", "grey", "palette"])), names)
    how = draw(st.sampled_from(["bytes", "random", "head", "labelmap", "mask", "list", "names", "renumber", "drop",
                                "add"]))
    compression = draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED]))
    masks = [f"SegmentationClass/{n}.png" for n in names]
    if how == "bytes":
        return draw(mutated_bytes(_zipped(members, compression)))
    if how == "random":
        return draw(st.binary(max_size=512))
    if how == "head":
        return draw(header_then_random(_zipped(members, compression), head=256))
    if how == "labelmap":
        text = draw(mutated_text(ROAD_CAR))
        members["labelmap.txt"] = text.encode("utf-8", "surrogatepass")
    elif how == "mask":
        name = draw(st.sampled_from(masks))
        members[name] = draw(mutated_bytes(members[name]))
    elif how == "list":
        list_name = "ImageSets/Segmentation/default.txt"
        members[list_name] = draw(mutated_text(members[list_name].decode())).encode("utf-8", "surrogatepass")
    elif how == "names":
        old = draw(st.sampled_from(sorted(members)))
        new = draw(mutated_text(old, sep="/")) or "x"
        members = {new if n == old else n: d for n, d in members.items()}
    elif how == "renumber":  # a mask named by a frame's number, as CVAT names a video's frames
        old = draw(st.sampled_from(masks))
        number = draw(st.sampled_from(ODD_NUMBERS) | st.integers(0, 10**12).map(str))
        members[f"SegmentationClass/{number}.png"] = members.pop(old)
    elif how == "drop":
        members.pop(draw(st.sampled_from(sorted(members))))
    else:
        members[draw(st.sampled_from([masks[1], "SegmentationClass/f2.png", "SegmentationClass/000007.png",
                                      "labelmap.txt/x", f"SegmentationClass/sub/{names[0]}.png", "a.zip",
                                      f"__MACOSX/._{names[0]}.png"]))] = \
            draw(st.binary(max_size=64) | st.just(members[masks[0]]))
    try:
        return _zipped(members, compression)
    except (ValueError, UnicodeEncodeError):  # a name zipfile cannot write (a NUL, half a surrogate pair)
        return _zipped(_members(names=names), compression)


@FUZZ
@given(data=st.data())
def test_damaged_cvat_exports(tmp_path_factory, frames, data):
    blob = data.draw(damaged_export(_names(frames)))
    _read_export(frames, blob, tmp_path_factory.getbasetemp() / f"cvat_{frames.kind}")


@pytest.mark.slow
@FUZZ_MORE
@given(data=st.data())
def test_damaged_cvat_exports_more(tmp_path_factory, frames, data):
    blob = data.draw(damaged_export(_names(frames)))
    _read_export(frames, blob, tmp_path_factory.getbasetemp() / f"cvat_more_{frames.kind}")


# -- key label PNGs through a class table ----------------------------------------------------------------------

def _key_seeds() -> dict[str, tuple[bytes, ClassTable, str]]:
    """Label images as pcreg reads key frames: ``(data, table, mapping)``."""
    from PIL import Image

    h, w = SHAPE
    ids = np.zeros(SHAPE, np.uint8)
    ids[h // 2:], ids[:, :4] = 1, 2
    camvid = (np.arange(h * w).reshape(SHAPE) % 12).astype(np.uint8)
    rgb = CAMVID11.palette()[camvid]
    out = {"lagr_ids": (cv2.imencode(".png", ids)[1].tobytes(), LAGR, "none"),
           "lagr_palette": (encode_label_png(ids, LAGR), LAGR, "none"),
           "lagr_colours": (cv2.imencode(".png", np.ascontiguousarray(LAGR.palette()[ids][:, :, ::-1]))[1].tobytes(), LAGR,
                            "none"),
           "lagr_ids16": (cv2.imencode(".png", ids.astype(np.uint16))[1].tobytes(), LAGR, "none"),
           "camvid11_palette": (encode_label_png(camvid, CAMVID11), CAMVID11, "none"),
           "camvid11_rgba": (cv2.imencode(".png", np.dstack([rgb[:, :, ::-1], np.full(SHAPE, 255, np.uint8)]))[1].tobytes(),
                             CAMVID11, "none"),
           "camvid_mapping": (cv2.imencode(".png", camvid)[1].tobytes(), LAGR, "camvid"),
           "davis_grey": (cv2.imencode(".png", ids * 255 // 2)[1].tobytes(), DAVIS, "davis")}
    im = Image.frombytes("P", (w, h), (ids == 1).astype(np.uint8).tobytes())
    im.putpalette(bytes([0, 0, 0, 128, 0, 0, 0, 128, 0]), rawmode="RGB")
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    out["davis_palette"] = (buf.getvalue(), DAVIS, "davis")
    return out


KEYS = _key_seeds()


def _read_key(kind: str, data: bytes, folder: Path) -> None:
    """``data`` as a key frame's label image, read as ``pcreg run --labels FILE`` reads it."""
    from pcreg.runs.inputs import read_labels

    _, table, mapping = KEYS[kind]
    path = _write(folder, "key.png", data)
    with held_to_contract(str(path)):
        labels = read_labels(path, mapping, table)
        assert labels.ndim == 2 and labels.dtype == np.uint8 and labels.size
        assert table.valid()[labels].all()


def test_the_key_seeds_read():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        for kind, (data, table, mapping) in KEYS.items():
            from pcreg.runs.inputs import read_labels

            path = _write(Path(d) / kind, "key.png", data)
            assert read_labels(path, mapping, table).shape == SHAPE, kind


@pytest.mark.parametrize("kind", sorted(KEYS))
@FUZZ
@given(data=st.data())
def test_mutated_key_labels(tmp_path_factory, kind, data):
    _read_key(kind, data.draw(mutated_bytes(KEYS[kind][0])), tmp_path_factory.getbasetemp() / f"key_{kind}")


@pytest.mark.parametrize("kind", ["lagr_palette", "lagr_ids", "davis_palette"])
@FUZZ
@given(data=st.data())
def test_key_labels_of_random_bytes(tmp_path_factory, kind, data):
    seed = KEYS[kind][0]
    blob = data.draw(st.binary(max_size=512) | header_then_random(seed, head=64))
    _read_key(kind, blob, tmp_path_factory.getbasetemp() / f"keyr_{kind}")


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(KEYS))
@FUZZ_MORE
@given(data=st.data())
def test_mutated_key_labels_more(tmp_path_factory, kind, data):
    _read_key(kind, data.draw(mutated_bytes(KEYS[kind][0])), tmp_path_factory.getbasetemp() / f"keym_{kind}")


# -- what the fuzzing found --------------------------------------------------------------------------------------

def test_a_labelmap_colour_of_thousands_of_digits_is_refused_in_a_line(tmp_path):
    """Python's int() refuses a number of more than 4300 digits with a ValueError: it came out of the label map's
    reader as a bug (exit 1) instead of the file named."""
    from pcreg.classes import class_table
    from _fuzz import refused_in_a_line

    path = tmp_path / "labelmap.txt"
    path.write_text("road:" + "9" * 5000 + ",64,128::\ncar:0,0,192::\n")
    with pytest.raises(Exception) as caught:
        class_table(str(path))
    refused_in_a_line(caught.value, str(path))
    assert "not R,G,B in 0..255" in str(caught.value) and len(str(caught.value)) < 300


def test_a_cvat_mask_named_by_a_number_of_thousands_of_digits_names_no_frame(frames, tmp_path):
    """A video's masks may be named by the frame's number: one of more than 4300 digits made int() raise a
    ValueError, a bug (exit 1), instead of the mask being one that names no frame."""
    from pcreg.classes.cvat import read_cvat_keys
    from _fuzz import refused_in_a_line

    members = _members("rgb", (_names(frames)[0], "9" * 5000))
    path = tmp_path / "export.zip"
    path.write_bytes(_zipped(members))
    assert list(read_cvat_keys(path, frames, SHAPE)[1]) == [0]  # the mask of no frame is blank: passed over
    members = _members("rgb", ("9" * 5000, _names(frames)[1]))
    path.write_bytes(_zipped(members))
    with pytest.raises(Exception) as caught:
        read_cvat_keys(path, frames, SHAPE)
    refused_in_a_line(caught.value, str(path))
