"""``pcreg run --labels EXPORT.zip``: key frames drawn in CVAT and exported as "Segmentation mask 1.1", and
the run's export read back by Datumaro's VOC reader (the reader CVAT's import uses).

The exports are written here in CVAT's documented layout (docs.cvat.ai, "Segmentation Mask": labelmap.txt,
ImageSets/Segmentation/default.txt, SegmentationClass/NAME.png in the label map's colours,
SegmentationObject/NAME.png) from the shared CamVid clip 0001TP, whose ids 0..10 and 11 void are the
``camvid11`` table. Bad exports end in one line naming the file, exit 2.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import shutil
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.classes import CAMVID11, ClassTable, LabelClass, labelmap_text, table_json
from pcreg.errors import InputError
from pcreg.cli import main
from pcreg.export import read_labels
from _runs import one_line_errors

CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "camvid" / "0001TP"
N = 5
#: CamVid's ids -> a two-class table: road and pavement "drivable", sky and void unlabelled, the rest "other"
TWO = ClassTable((LabelClass(0, "drivable", (128, 64, 128)), LabelClass(1, "other", (64, 0, 128)),
                  LabelClass(2, "background", (0, 0, 0))), 2, "two")
TWO_LUT = np.array([2, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 2], np.uint8)


def _needs_clip():
    if not (CLIP / "images").is_dir():
        pytest.skip(f"the shared CamVid clip is absent ({CLIP})")


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """The first N frames of CamVid 0001TP in a folder, and their CamVid ids by stem."""
    _needs_clip()
    root = tmp_path_factory.mktemp("clip")
    frames = root / "frames"
    frames.mkdir()
    names = sorted(p.name for p in (CLIP / "images").iterdir())[:N]
    ids = {}
    for n in names:
        shutil.copy(CLIP / "images" / n, frames / n)
        ids[Path(n).stem] = cv2.imread(str(CLIP / "labels" / n), cv2.IMREAD_UNCHANGED)
    return frames, ids


def cvat_export(path: Path, table: ClassTable, masks: dict[str, np.ndarray], *, as_zip: bool = True) -> Path:
    """A CVAT "Segmentation mask 1.1" export of ``masks`` (stem -> class ids of ``table``) at ``path``
    (a .zip, or an unpacked folder), in the documented layout."""
    files: dict[str, bytes] = {"labelmap.txt": labelmap_text(table).encode(),
                               "ImageSets/Segmentation/default.txt": "".join(f"{s}\n" for s in masks).encode()}
    lut = np.zeros((256, 3), np.uint8)
    lut[: table.n_values] = table.palette()
    for stem, ids in masks.items():
        rgb = lut[ids]
        files[f"SegmentationClass/{stem}.png"] = cv2.imencode(".png", rgb[:, :, ::-1])[1].tobytes()
        files[f"SegmentationObject/{stem}.png"] = cv2.imencode(".png", rgb[:, :, ::-1])[1].tobytes()
    if as_zip:
        with zipfile.ZipFile(path, "w") as z:
            for name, data in files.items():
                z.writestr(name, data)
    else:
        for name, data in files.items():
            (path / name).parent.mkdir(parents=True, exist_ok=True)
            (path / name).write_bytes(data)
    return path


def _run(args, capsys) -> tuple[int, list[str]]:
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main([str(a) for a in args])
    return rc, one_line_errors(capsys)


def test_camvid11_export_reads_back_as_camvid_ids(clip, tmp_path):
    """The eleven classes of a CVAT export come back as CamVid's own ids, by name and as frame_NNNNNN."""
    from pcreg.classes.cvat import read_cvat_keys
    from pcreg.datasets.sources import Selection, open_frames

    frames, ids = clip
    stems = list(ids)
    source = open_frames(frames, Selection())
    by_name = cvat_export(tmp_path / "a.zip", CAMVID11, {stems[0]: ids[stems[0]], stems[3]: ids[stems[3]]})
    table, keys = read_cvat_keys(by_name, source, ids[stems[0]].shape)
    assert table.agrees(CAMVID11) and sorted(keys) == [0, 3]
    np.testing.assert_array_equal(keys[3], ids[stems[3]])
    (tmp_path / "b").mkdir()
    wrapped = tmp_path / "wrapped.zip"  # the same export zipped with its folder around it
    with zipfile.ZipFile(by_name) as z, zipfile.ZipFile(wrapped, "w") as w:
        for name in z.namelist():
            w.writestr(f"task_1/{name}", z.read(name))
    table, again = read_cvat_keys(wrapped, source, ids[stems[0]].shape)
    assert table.agrees(CAMVID11) and sorted(again) == [0, 3]
    np.testing.assert_array_equal(again[3], keys[3])
    with zipfile.ZipFile(wrapped, "a") as w:
        w.writestr("task_1/SegmentationClass/x.png", b"")
    with pytest.raises(InputError, match="wrapped.zip:task_1/SegmentationClass/x.png"):  # errors name the member
        read_cvat_keys(wrapped, source, ids[stems[0]].shape)
    by_index = cvat_export(tmp_path / "b", CAMVID11, {"frame_000000": ids[stems[0]], "frame_000004": ids[stems[4]],
                                                      "frame_000002": np.full_like(ids[stems[2]], 11)}, as_zip=False)
    table, keys = read_cvat_keys(by_index, source, ids[stems[0]].shape)
    assert sorted(keys) == [0, 4]  # frame 2 all background: nobody drew on it
    np.testing.assert_array_equal(keys[4], ids[stems[4]])
    _, keys = read_cvat_keys(by_index, open_frames(frames, Selection(0, None, 2)), ids[stems[0]].shape)
    assert sorted(keys) == [0, 2]  # --every 2: the source's frame 4 is the run's third


def test_run_from_a_cvat_export_and_back(clip, tmp_path, capsys):
    """Two key frames drawn in CVAT (its zip and the unpacked folder alike) label the clip; the run's
    labels are palette PNGs in the export's colours; pcreg's export of it reads back through Datumaro's
    VOC reader with the same classes and the same labels."""
    frames, ids = clip
    stems = list(ids)
    keys = {stems[0]: TWO_LUT[ids[stems[0]]], f"frame_{N - 1:06d}": TWO_LUT[ids[stems[-1]]]}
    export = cvat_export(tmp_path / "task.zip", TWO, keys)
    out = tmp_path / "out"
    rc, err = _run(["run", frames, "--labels", export, "--out", out, "--model", "flow", "--scale", "0.5"], capsys)
    assert rc == 0, err
    run = json.loads((out / "run.json").read_text())["run"]
    assert [c["name"] for c in run["classes"]["classes"]] == ["drivable", "other", "background"]
    from PIL import Image

    with Image.open(out / f"{stems[2]}.png") as im:
        assert im.mode == "P" and tuple(im.getpalette()[:9]) == (128, 64, 128, 64, 0, 128, 0, 0, 0)
    np.testing.assert_array_equal(read_labels(out / f"{stems[0]}.png", TWO), keys[stems[0]])
    (tmp_path / "unpacked").mkdir()
    with zipfile.ZipFile(export) as z:
        z.extractall(tmp_path / "unpacked")
    rc, err = _run(["run", frames, "--labels", tmp_path / "unpacked", "--out", tmp_path / "out2", "--model", "flow",
                    "--scale", "0.5"], capsys)
    assert rc == 0, err
    for s in stems:
        assert (out / f"{s}.png").read_bytes() == (tmp_path / "out2" / f"{s}.png").read_bytes()
    rc, err = _run(["export", out, "--to", tmp_path / "back.zip"], capsys)
    assert rc == 0, err
    with zipfile.ZipFile(tmp_path / "back.zip") as z:
        assert z.read("labelmap.txt").decode().splitlines()[1:] == ["background:0,0,0::", "drivable:128,64,128::",
                                                                    "other:64,0,128::"]
    _datumaro_reads(tmp_path / "back.zip", tmp_path / "dm", {s: read_labels(out / f"{s}.png", TWO) for s in stems})


#: The Python that reads with Datumaro: ``make test`` installs it in a venv of its own, since it pins opencv<5 and
#: pillow 12, below pcreg's; this one's when it has Datumaro.
DATUMARO_PYTHON = Path(__file__).resolve().parents[1] / ".venv-datumaro" / "bin" / "python"


def _datumaro_python() -> str:
    if DATUMARO_PYTHON.exists():
        return str(DATUMARO_PYTHON)
    pytest.importorskip("datumaro", reason="Datumaro is not installed (its VOC reader is CVAT's import; `make test` "
                        "installs it in .venv-datumaro, or pip install datumaro, which pins opencv<5 and pillow 12)")
    return sys.executable


def _datumaro_reads(archive: Path, where: Path, labels: dict[str, np.ndarray]) -> None:
    """Datumaro's VOC segmentation reader (CVAT's "Segmentation mask 1.1" import) finds every frame, the
    table's classes, and each class's mask where the run's labels have it."""
    python = _datumaro_python()
    with zipfile.ZipFile(archive) as z:
        z.extractall(where)
    found = where.with_suffix(".npz")
    subprocess.run([python, str(Path(__file__).with_name("_datumaro_read.py")), str(where), str(found)], check=True,
                   capture_output=True)
    with np.load(found) as got:
        names = list(got["names"])
        assert {"drivable", "other"} <= set(names) and names.count("background") == 1
        assert sorted(got["items"]) == sorted(labels)
        for item, want in labels.items():
            for name, k in (("drivable", 0), ("other", 1)):
                key = f"mask/{item}/{name}"
                mask = got[key] if key in got else np.zeros(want.shape, bool)
                np.testing.assert_array_equal(mask, want == k, err_msg=f"{item} {name}")


@pytest.mark.parametrize("how", ["names match no frame", "a member climbs out", "not a zip", "a colour not in labelmap",
                                 "labelmap with two names", "--classes disagrees", "all background", "a huge labelmap",
                                 "two members of one name", "a transparent mask", "a JPEG mask"])
def test_bad_cvat_exports_end_in_one_line(clip, tmp_path, capsys, how):
    frames, ids = clip
    stems = list(ids)
    good = {stems[0]: TWO_LUT[ids[stems[0]]]}
    export, args, said = tmp_path / "task.zip", [], ""
    if how == "names match no frame":
        cvat_export(export, TWO, {"frame_000100": good[stems[0]], "frame_000200": good[stems[0]]})
        said = f"named frame_000100 ... frame_000200, the frames of {frames} {stems[0]} ... {stems[-1]}"
    elif how == "a member climbs out":
        cvat_export(export, TWO, good)
        with zipfile.ZipFile(export, "a") as z:
            z.writestr("../evil.png", b"x")
        said = "'../evil.png' names a path outside the archive"
    elif how == "not a zip":
        export.write_bytes(b"PK\x03\x04 this is no archive")
        said = "not a readable zip archive"
    elif how == "a colour not in labelmap":
        cvat_export(export, TWO, good)
        bad = np.zeros((*good[stems[0]].shape, 3), np.uint8)
        bad[5, 7] = (1, 2, 3)
        with zipfile.ZipFile(export, "a") as z:
            z.writestr(f"SegmentationClass/{stems[1]}.png", cv2.imencode(".png", bad)[1].tobytes())
        said = f"SegmentationClass/{stems[1]}.png: colour (3, 2, 1) (at x=7, y=5) is no class's colour"
    elif how == "labelmap with two names":
        with zipfile.ZipFile(export, "w") as z:
            z.writestr("labelmap.txt", "background:0,0,0::\nroad:1,1,1::\nroad:2,2,2::\n")
            z.writestr(f"SegmentationClass/{stems[0]}.png", b"")
        said = "labelmap.txt: two classes named 'road'"
    elif how == "a huge labelmap":  # 64 MiB of comments in a few hundred kB: read no further than a table's limit
        with zipfile.ZipFile(export, "w", compression=zipfile.ZIP_DEFLATED) as z:
            z.writestr("labelmap.txt", "background:0,0,0::\nroad:1,1,1::\nsky:2,2,2::\n" + "#\n" * (32 << 20))
            z.writestr(f"SegmentationClass/{stems[0]}.png", b"")
        said = "labelmap.txt: 67108908 bytes, more than the 1048576 a class table may have"
    elif how == "two members of one name":
        cvat_export(export, TWO, good)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # zipfile warns of the duplicate name it is asked to write
            with zipfile.ZipFile(export, "a") as z:
                z.writestr(f"SegmentationClass/{stems[0]}.png", b"")
        said = f"two members named 'SegmentationClass/{stems[0]}.png'"
    elif how == "a transparent mask":
        cvat_export(export, TWO, good)
        rgba = np.zeros((*good[stems[0]].shape, 4), np.uint8)  # black, but nothing drawn: alpha 0
        with zipfile.ZipFile(export, "a") as z:
            z.writestr(f"SegmentationClass/{stems[1]}.png", cv2.imencode(".png", rgba)[1].tobytes())
        said = f"SegmentationClass/{stems[1]}.png: a class mask with transparent pixels"
    elif how == "a JPEG mask":  # saved as .png by an editor: its colours at every edge are no class's
        cvat_export(export, TWO, good)
        with zipfile.ZipFile(export, "a") as z:
            z.writestr(f"SegmentationClass/{stems[1]}.png", cv2.imencode(".jpg", TWO.paint(good[stems[0]]))[1].tobytes())
        said = f"SegmentationClass/{stems[1]}.png: a JPEG, which changes the values at every edge"
    elif how == "--classes disagrees":
        cvat_export(export, TWO, good)
        args, said = ["--classes", "lagr"], "its class table disagrees with --classes lagr's"
    elif how == "all background":
        cvat_export(export, TWO, {stems[0]: np.full_like(good[stems[0]], 2)})
        said = "every mask is background only"
    out = tmp_path / "out"
    out.mkdir()
    (out / "kept.txt").write_text("written before")
    rc, err = _run(["run", frames, "--labels", export, "--out", out, *args], capsys)
    assert rc == 2 and len(err) == 1 and said in err[0] and str(export) in err[0], err
    assert sorted(p.name for p in out.iterdir()) == ["kept.txt"]


@pytest.mark.parametrize("stored", ["palette", "colours", "ids"])
def test_a_folder_of_labels_reads_through_the_table(clip, tmp_path, stored):
    """load_folder reads CamVid's labels stored as ids, a palette PNG or camvid11's colours alike (mapped to
    lagr's three labels), and a folder of labels of another table through that table (classes=)."""
    import pcreg
    from pcreg.classes import write_label_png
    from pcreg.datasets.folder import load_folder, mapping_lut

    frames, ids = clip
    lut = mapping_lut("camvid")
    for table, lab_of, kw, want in ((CAMVID11, ids, {}, {s: lut[v] for s, v in ids.items()}),
                                    (TWO, {s: TWO_LUT[v] for s, v in ids.items()}, {"mapping": None, "classes": TWO},
                                     {s: TWO_LUT[v] for s, v in ids.items()})):
        root = tmp_path / table.source
        (root / "labels").mkdir(parents=True)
        shutil.copytree(frames, root / "images")
        for stem, lab in lab_of.items():
            path = root / "labels" / f"{stem}.png"
            if stored == "palette":
                write_label_png(path, lab, table)
            elif stored == "colours":
                cv2.imwrite(str(path), table.paint(lab)[:, :, ::-1])
            else:
                cv2.imwrite(str(path), lab)
        got = load_folder(root, **kw)
        assert [f.name for f in got] == list(ids)
        for f in got:
            np.testing.assert_array_equal(f.labels, want[f.name])
    if stored != "ids":  # lagr's table: the other table's palette and colours are not its classes
        with pytest.raises(pcreg.errors.DatasetError, match="palette colours" if stored == "palette" else "colour"):
            load_folder(tmp_path / "two", mapping=None)


def test_masks_in_sub_folders_are_read_and_masks_that_name_frames_two_ways_refused(clip, tmp_path, capsys):
    """A task made from nested folders puts masks in ``SegmentationClass/SUB/``: one there was left out without
    a word. Frames numbered from 1 (``frame_000001.png``) with masks named by CVAT's frame number (from 0):
    one mask matched a file by name, another by number, a key frame one frame off."""
    frames, ids = clip
    stems = list(ids)
    keys = {stems[0]: TWO_LUT[ids[stems[0]]], f"seq/{stems[-1]}": TWO_LUT[ids[stems[-1]]]}
    export = cvat_export(tmp_path / "nested.zip", TWO, keys)
    rc, err = _run(["run", frames, "--labels", export, "--out", tmp_path / "out", "--model", "flow", "--scale", "0.5"], capsys)
    assert rc == 0, err
    assert sorted(json.loads((tmp_path / "out" / "run.json").read_text())["keys"]) == [f"{stems[0]}.png", f"{stems[-1]}.png"]
    numbered = tmp_path / "numbered"
    numbered.mkdir()
    for i, s in enumerate(stems):
        shutil.copy(frames / f"{s}.png", numbered / f"frame_{i + 1:06d}.png")  # as ffmpeg numbers them
    export = cvat_export(tmp_path / "video.zip", TWO, {"frame_000000": TWO_LUT[ids[stems[0]]],
                                                       "frame_000003": TWO_LUT[ids[stems[3]]]})
    rc, err = _run(["run", numbered, "--labels", export, "--out", tmp_path / "out2"], capsys)
    assert rc == 2 and "name frames two ways: frame_000003 the frame file of that name, frame_000000 CVAT's frame" in err[0], err


def test_an_export_zipped_by_macos_finder_is_read_inside_its_folder(clip, tmp_path):
    """Finder zips a folder with its ``__MACOSX/FOLDER/._NAME`` metadata beside it: the export inside the folder
    is read, the metadata left out (it was "labelmap.txt: missing")."""
    from pcreg.classes.cvat import read_cvat_keys
    from pcreg.datasets.sources import Selection, open_frames

    frames, ids = clip
    stems = list(ids)
    export = cvat_export(tmp_path / "task.zip", CAMVID11, {stems[1]: ids[stems[1]]})
    finder = tmp_path / "finder.zip"
    with zipfile.ZipFile(export) as z, zipfile.ZipFile(finder, "w") as w:
        for name in z.namelist():
            w.writestr(f"task_7/{name}", z.read(name))
            folder, _, base = name.rpartition("/")
            w.writestr(f"__MACOSX/task_7/{folder + '/' if folder else ''}._{base}", b"\0\5\26\7 AppleDouble")
    table, keys = read_cvat_keys(finder, open_frames(frames, Selection()), ids[stems[0]].shape)
    assert table.agrees(CAMVID11) and sorted(keys) == [1]
    np.testing.assert_array_equal(keys[1], ids[stems[1]])
    with zipfile.ZipFile(finder, "a") as w:  # a file beside the folder: named with the folder ("labelmap.txt: missing")
        w.writestr("README.txt", "the task's notes\n")
    with pytest.raises(InputError) as exc:
        read_cvat_keys(finder, open_frames(frames, Selection()), ids[stems[0]].shape)
    assert "finder.zip:labelmap.txt: missing" in str(exc.value) and "the export lies in task_7/, beside README.txt" in str(exc.value)


def test_an_export_beside_other_files_deeper_in_an_archive_or_folder_is_named(clip, tmp_path, capsys):
    """An export zipped two folders down beside a file of the top folder (home/me/task_7/ beside home/README.txt)
    was refused as "labelmap.txt: missing" naming no export, and an unpacked export beside a file (task_7/ beside
    README.txt) as a folder of no label PNG: each refusal names where the export lies, to give --labels."""
    frames, ids = clip
    stem = list(ids)[0]
    export = cvat_export(tmp_path / "task.zip", CAMVID11, {stem: ids[stem]})
    nested = tmp_path / "nested.zip"
    with zipfile.ZipFile(export) as z, zipfile.ZipFile(nested, "w") as w:
        for name in z.namelist():
            w.writestr(f"home/me/task_7/{name}", z.read(name))
        w.writestr("home/README.txt", "the task's notes\n")
    rc, err = _run(["run", frames, "--labels", nested, "--out", tmp_path / "out"], capsys)
    assert rc == 2 and "the export lies in home/me/task_7/, beside home/README.txt" in err[0], err
    unpacked = tmp_path / "unpacked"
    (unpacked / "task_7").mkdir(parents=True)
    cvat_export(unpacked / "task_7", CAMVID11, {stem: ids[stem]}, as_zip=False)
    (unpacked / "README.txt").write_text("the task's notes\n")
    rc, err = _run(["run", frames, "--labels", unpacked, "--out", tmp_path / "out"], capsys)
    assert rc == 2 and f"a CVAT export lies in {unpacked / 'task_7'}: give --labels {unpacked / 'task_7'}" in err[0], err
    rc, err = _run(["run", frames, "--labels", unpacked / "task_7", "--out", tmp_path / "out"], capsys)
    assert rc == 0, err  # where it says


def test_the_export_of_a_run_whose_unknown_is_not_black_writes_it_black(clip, tmp_path, capsys):
    """A task whose ``background`` label is not black labels a run; its export back was refused after the run was
    labelled (CVAT would take another class for the unlabelled pixels). The archive now writes the unknown black,
    CVAT's background, in labelmap.txt and the masks alike, and says so; read back, the labels are the run's."""
    from pcreg.classes.cvat import read_cvat_keys
    from pcreg.datasets.sources import Selection, open_frames

    frames, ids = clip
    stems = list(ids)
    grey = ClassTable((*TWO.known, LabelClass(2, "background", (10, 10, 10))), 2, "grey")
    export = tmp_path / "task.zip"
    with zipfile.ZipFile(export, "w") as z:
        z.writestr("labelmap.txt", "background:10,10,10::\ndrivable:128,64,128::\nother:64,0,128::\n")
        z.writestr(f"SegmentationClass/{stems[0]}.png", cv2.imencode(".png", grey.paint(TWO_LUT[ids[stems[0]]])[:, :, ::-1])[1])
    out = tmp_path / "out"
    rc, err = _run(["run", frames, "--labels", export, "--out", out, "--model", "flow", "--scale", "0.5", "--confidence"],
                   capsys)
    assert rc == 0, err
    rc, err = _run(["export", out, "--min-confidence", "0.9"], capsys)  # some pixels left unknown
    assert rc == 0 and any("unknown class background is (10, 10, 10) in the run's table and black in the archive" in e for e in err), err
    archive = out / "export-cvat-mask.zip"
    with zipfile.ZipFile(archive) as z:
        assert "background:0,0,0::" in z.read("labelmap.txt").decode().splitlines()
        masks = [cv2.imdecode(np.frombuffer(z.read(n), np.uint8), cv2.IMREAD_COLOR) for n in z.namelist()
                 if n.startswith("SegmentationClass/")]
    assert not any(((m == 10).all(axis=2)).any() for m in masks)  # no pixel in the run table's grey
    source = open_frames(frames, Selection())
    table, keys = read_cvat_keys(archive, source, ids[stems[0]].shape)
    assert table.unknown_class.name == "background" and len(keys) > 1
    for t, labels in keys.items():  # each frame read back as the export wrote it: the run's labels, or unknown
        run = read_labels(out / f"{Path(stems[t]).stem}.png", grey)
        assert ((labels == run) | (labels == table.unknown)).all(), t
    assert sum(int((k == table.unknown).sum()) for k in keys.values()) > 0
    # under the run's own table (--classes): its ids and colours, the masks read in the colours the export wrote
    (tmp_path / "grey.json").write_text(table_json(grey))
    mine, again = read_cvat_keys(archive, source, ids[stems[0]].shape, str(tmp_path / "grey.json"))
    assert mine == grey and set(again) == set(keys)
    assert all((again[t] == keys[t]).all() for t in keys)


def test_an_archive_of_a_table_whose_unknown_is_not_black_reads_back_in_datumaro(clip, tmp_path):
    """The unknown of a table in another colour is written black, Datumaro's background: its reader (CVAT's import)
    finds one background and each class's masks where the labels have them, nothing for the unknown."""
    from pcreg.export import write_cvat_mask_archive

    frames, ids = clip
    grey = ClassTable((*TWO.known, LabelClass(2, "background", (10, 10, 10))), 2, "grey")
    labels = {s: TWO_LUT[ids[s]] for s in list(ids)[:2]}
    assert all((lab == grey.unknown).any() for lab in labels.values())
    write_cvat_mask_archive(tmp_path / "grey.zip", [(f"{s}.png", lab) for s, lab in labels.items()], grey)
    _datumaro_reads(tmp_path / "grey.zip", tmp_path / "dm", labels)


def test_a_known_class_in_black_is_exported_in_a_colour_of_its_own(clip, tmp_path, capsys):
    """VOC palette masks (labelme's, DAVIS's) hold their background as class 0 in black, void 255: a run read them
    under a table saying so, and its export was refused after the whole video was labelled ("label the run again with
    a --classes table that gives that class another colour", which the palette masks then refused). The class is
    written in the first colour of VOC's colour map that no class has, and said; Datumaro (CVAT's import) finds its
    masks under its name, and the void pixels left unlabelled."""
    from pcreg.classes import write_label_png
    from pcreg.export import write_cvat_mask_archive

    frames, ids = clip
    voc = ClassTable((LabelClass(0, "background", (0, 0, 0)), LabelClass(1, "car", (128, 0, 0)),
                      LabelClass(2, "truck", (0, 128, 0)), LabelClass(255, "void", (224, 224, 192))), 255, "voc.json")
    labels = {}
    for s in list(ids)[:2]:
        lab = TWO_LUT[ids[s]].copy()  # 0 drivable, 1 other, 2 unknown: here background, car and void
        lab[lab == 2] = 255
        lab[:8, :8] = 2
        labels[s] = lab
    write_cvat_mask_archive(tmp_path / "voc.zip", [(f"{s}.png", lab) for s, lab in labels.items()], voc)
    with zipfile.ZipFile(tmp_path / "voc.zip") as z:
        assert z.read("labelmap.txt").decode().splitlines()[1:] == ["void:0,0,0::", "background:128,128,0::",
                                                                    "car:128,0,0::", "truck:0,128,0::"]
    python = _datumaro_python()
    with zipfile.ZipFile(tmp_path / "voc.zip") as z:
        z.extractall(tmp_path / "dm")
    subprocess.run([python, str(Path(__file__).with_name("_datumaro_read.py")), str(tmp_path / "dm"),
                    str(tmp_path / "dm.npz")], check=True, capture_output=True)
    with np.load(tmp_path / "dm.npz") as got:
        assert list(got["names"]) == ["void", "background", "car", "truck"]
        for item, want in labels.items():
            for name, k in (("background", 0), ("car", 1), ("truck", 2)):
                np.testing.assert_array_equal(got[f"mask/{item}/{name}"], want == k, err_msg=f"{item} {name}")
            assert f"mask/{item}/void" not in got.files
    out = tmp_path / "out"
    (tmp_path / "voc.json").write_text(json.dumps({"classes": [{"id": c.id, "name": c.name, "colour": list(c.colour)}
                                                               for c in voc.classes], "unknown": 255}))
    key = tmp_path / "key.png"
    write_label_png(key, labels[list(ids)[0]], voc)
    rc, err = _run(["run", frames, "--labels", key, "--out", out, "--model", "flow", "--scale", "0.5",
                    "--classes", tmp_path / "voc.json"], capsys)
    assert rc == 0, err
    rc, err = _run(["export", out], capsys)
    assert rc == 0 and any("the class background is black in the run's table, CVAT's background, and (128, 128, 0) in "
                           "the archive: its pixels go to the task's label background" in e for e in err), err
    # read back under the run's own table: the archive's colours are that table's as the export writes it (refused
    # before: "class 'background' (0, 0, 0) is in --classes ... only", where only its colour had changed)
    back = tmp_path / "back"
    rc, err = _run(["run", frames, "--labels", out / "export-cvat-mask.zip", "--out", back, "--model", "flow",
                    "--scale", "0.5", "--classes", tmp_path / "voc.json"], capsys)
    assert rc == 0, err
    first = f"{Path(list(ids)[0]).stem}.png"
    np.testing.assert_array_equal(read_labels(back / first, voc), read_labels(out / first, voc))


def test_tables_of_every_voc_colour_export(tmp_path):
    """Looking for a free colour for a black known class raised StopIteration (exit 1) on tables that take every
    colour of VOC's map, even with no black known class (a table of 256 exported before); the full VOC palette as a
    table (0 background black, 255 void the unknown) frees the void's colour as the unknown goes black. Ids are 0-255,
    one the unknown's: black and at most 254 other known colours leave one of VOC's 255 free."""
    from pcreg.classes import voc_colormap
    from pcreg.export import cvat_table, write_cvat_mask_archive

    cmap = [tuple(int(v) for v in c) for c in voc_colormap(256)]
    grey = ClassTable((LabelClass(0, "unknown", (10, 10, 10)), *(LabelClass(k, f"c{k}", cmap[k]) for k in range(1, 256))),
                      0, "many.json")
    assert cvat_table(grey).unknown_class.colour == (0, 0, 0)
    write_cvat_mask_archive(tmp_path / "many.zip", [("a.png", np.arange(16, dtype=np.uint8).reshape(4, 4))], grey)
    voc = ClassTable((LabelClass(0, "background", (0, 0, 0)), *(LabelClass(k, f"o{k}", cmap[k]) for k in range(1, 255)),
                      LabelClass(255, "void", cmap[255])), 255, "voc.json")
    assert cvat_table(voc).classes[0].colour == cmap[255] == (224, 224, 192)
    packed = ClassTable((LabelClass(0, "background", (0, 0, 0)), *(LabelClass(k, f"o{k}", cmap[k + 1]) for k in range(1, 255)),
                         LabelClass(255, "void", (10, 10, 10))), 255, "packed.json")  # 2-255 taken, 1 left
    assert cvat_table(packed).classes[0].colour == cmap[1]


def test_a_one_channel_mask_of_16_bits_holds_labelmap_lines_as_one_of_8(clip, tmp_path):
    """A one-channel class mask holds each pixel's line of labelmap.txt, in 8 bits or 16 (a 16-bit one was
    refused as "not a class mask (... or one channel)"); a value past the last line is refused, naming it."""
    from pcreg.classes.cvat import read_cvat_keys
    from pcreg.datasets.sources import Selection, open_frames

    frames, ids = clip
    stems = list(ids)
    lines = np.array([1, 2, 0], np.uint16)[TWO_LUT[ids[stems[0]]]]  # the line of each id: background, drivable, other
    source = open_frames(frames, Selection())
    for value, said in ((None, ""), (300, "value 300 is no line of the labelmap.txt (3 classes)")):
        mask = lines.copy()
        if value is not None:
            mask[4, 6] = value
        export = tmp_path / f"grey{value}.zip"
        with zipfile.ZipFile(export, "w") as z:
            z.writestr("labelmap.txt", labelmap_text(TWO))
            z.writestr(f"SegmentationClass/{stems[0]}.png", cv2.imencode(".png", mask)[1].tobytes())
        if value is None:
            table, keys = read_cvat_keys(export, source, mask.shape)
            np.testing.assert_array_equal(keys[0], TWO_LUT[ids[stems[0]]])
        else:
            with pytest.raises(InputError, match=re.escape(said)):
                read_cvat_keys(export, source, mask.shape)


def test_an_export_saved_without_its_suffix_is_read_as_its_zip(clip, tmp_path, capsys):
    """A CVAT export downloaded or renamed without ``.zip`` was "not an image pcreg reads": a file that starts as a
    zip does is read as the export, to the same labels; a PNG is still a key frame's labels."""
    from pcreg.classes.cvat import is_cvat_export

    frames, ids = clip
    stems = list(ids)
    named = cvat_export(tmp_path / "task_7.zip", TWO, {stems[0]: TWO_LUT[ids[stems[0]]]})
    bare = tmp_path / "task_7_annotations"
    bare.write_bytes(named.read_bytes())
    assert is_cvat_export(bare) and not is_cvat_export(CLIP / "labels" / f"{stems[0]}.png")
    for labels, out in ((named, "a"), (bare, "b")):
        rc, err = _run(["run", frames, "--labels", labels, "--out", tmp_path / out, "--model", "flow", "--scale", "0.5"],
                       capsys)
        assert rc == 0, err
    for stem in stems:
        assert (tmp_path / "a" / f"{stem}.png").read_bytes() == (tmp_path / "b" / f"{stem}.png").read_bytes()


def test_an_unpacked_export_in_its_folder_is_read_as_its_zip(clip, tmp_path, capsys):
    """An export unzipped with its folder around it (``FOLDER/task_7/labelmap.txt``, Finder's ``__MACOSX/`` and a
    ``.DS_Store`` beside it) is read inside that folder, as its zip is (it was "holds no label PNG"); errors name
    the file where it lies."""
    from pcreg.classes.cvat import is_cvat_export, read_cvat_keys
    from pcreg.datasets.sources import Selection, open_frames

    frames, ids = clip
    stems = list(ids)
    folder = tmp_path / "unzipped"
    (folder / "task_7").mkdir(parents=True)
    cvat_export(folder / "task_7", TWO, {stems[0]: TWO_LUT[ids[stems[0]]]}, as_zip=False)
    (folder / "__MACOSX" / "task_7").mkdir(parents=True)
    (folder / "__MACOSX" / "task_7" / "._labelmap.txt").write_bytes(b"\0\5\26\7 AppleDouble")
    (folder / ".DS_Store").write_bytes(b"\0\0\0\1Bud1")
    assert is_cvat_export(folder)
    rc, err = _run(["run", frames, "--labels", folder, "--out", tmp_path / "out", "--model", "flow", "--scale", "0.5"],
                   capsys)
    assert rc == 0, err
    run = json.loads((tmp_path / "out" / "run.json").read_text())["run"]
    assert [c["name"] for c in run["classes"]["classes"]] == ["drivable", "other", "background"]
    (folder / "task_7" / "SegmentationClass" / "x.png").write_bytes(b"")
    with pytest.raises(InputError, match=re.escape(str(folder / "task_7" / "SegmentationClass" / "x.png"))):
        read_cvat_keys(folder, open_frames(frames, Selection()), ids[stems[0]].shape)
    (folder / "notes.txt").write_text("two things in the folder: not an export wrapped in it\n")
    assert not is_cvat_export(folder)


def test_an_export_read_with_classes_whose_unknown_is_0_and_ids_have_gaps_keeps_their_ids(clip, tmp_path, capsys):
    """A label map holds no ids: an export of a table whose unknown is 0 (as ADE20K's) and whose ids have gaps,
    read with that table as --classes, gives its ids back, whatever the label map's order; pcreg export of
    the run writes the same label map. A class the two do not share is still refused, naming it."""
    from pcreg.classes import table_json
    from pcreg.classes.cvat import read_cvat_keys
    from pcreg.datasets.sources import Selection, open_frames

    gaps = ClassTable((LabelClass(0, "void", (0, 0, 0)), LabelClass(5, "road", (128, 64, 128)),
                       LabelClass(7, "sky", (128, 128, 128)), LabelClass(200, "other", (64, 0, 128))), 0, "gaps")
    lut = np.array([7, 200, 200, 5, 5, 200, 200, 200, 200, 200, 200, 0], np.uint8)
    frames, ids = clip
    masks = {s: lut[v] for s, v in ids.items()}
    spec = tmp_path / "gaps.json"
    spec.write_text(table_json(gaps))
    export = cvat_export(tmp_path / "task.zip", gaps, masks)
    table, keys = read_cvat_keys(export, open_frames(frames, Selection()), lut[ids[next(iter(ids))]].shape, str(spec))
    assert table.agrees(gaps) and sorted(keys) == list(range(N))
    for t, s in enumerate(masks):
        np.testing.assert_array_equal(keys[t], masks[s])
    with zipfile.ZipFile(export) as z, zipfile.ZipFile(tmp_path / "shuffled.zip", "w") as w:
        for name in z.namelist():
            data = z.read(name)
            if name == "labelmap.txt":  # its lines in another order
                data = b"\n".join(reversed(data.splitlines()))
            w.writestr(name, data)
    _, again = read_cvat_keys(tmp_path / "shuffled.zip", open_frames(frames, Selection()), keys[0].shape, str(spec))
    np.testing.assert_array_equal(again[2], keys[2])
    out = tmp_path / "out"
    rc, err = _run(["run", frames, "--labels", export, "--classes", spec, "--out", out], capsys)
    assert rc == 0, err
    np.testing.assert_array_equal(read_labels(out / f"{next(iter(ids))}.png", gaps), keys[0])
    rc, err = _run(["export", out, "--to", tmp_path / "back.zip"], capsys)
    assert rc == 0, err
    with zipfile.ZipFile(tmp_path / "back.zip") as back, zipfile.ZipFile(export) as z:
        assert back.read("labelmap.txt") == z.read("labelmap.txt")
    other = ClassTable((*gaps.classes[:3], LabelClass(200, "car", (64, 0, 128))), 0, "other")
    spec.write_text(table_json(other))
    rc, err = _run(["run", frames, "--labels", export, "--classes", spec, "--out", tmp_path / "out2"], capsys)
    assert rc == 2 and "its class table disagrees with --classes" in err[0] and "'car' (64, 0, 128)" in err[0], err


def test_classes_davis_reads_an_export_of_its_classes_and_names_itself_refusing_others(clip, tmp_path, capsys):
    """`--classes davis` (read as `--mapping davis` reads object masks) refused every CVAT export, naming `--mapping
    davis`, an option not given; the export's labelmap.txt is checked against the davis table now."""
    from pcreg.classes import DAVIS

    frames, ids = clip
    stems = list(ids)
    car = {stems[0]: np.where(ids[stems[0]] == 8, 1, 0).astype(np.uint8)}  # CamVid's car as the object
    rc, err = _run(["run", frames, "--labels", cvat_export(tmp_path / "davis.zip", DAVIS, car), "--classes", "davis",
                    "--out", tmp_path / "out", "--stop", "3"], capsys)
    assert rc == 0, err
    np.testing.assert_array_equal(read_labels(tmp_path / "out" / f"{stems[0]}.png", DAVIS), car[stems[0]])
    rc, err = _run(["run", frames, "--labels", cvat_export(tmp_path / "two.zip", TWO, {stems[0]: TWO_LUT[ids[stems[0]]]}),
                    "--classes", "davis", "--out", tmp_path / "out2"], capsys)
    assert rc == 2 and len(err) == 1 and "disagrees with --classes davis's" in err[0] and "--mapping" not in err[0], err
