"""`pcreg export`: a real run's labels as CVAT's "Segmentation mask 1.1" zip, decoded back through its own
label map to exactly the run's labels; the confidence threshold; every bad input refused in one line with
exit code 2 and nothing written."""

from __future__ import annotations

import io
import json
import re
import shutil
import zipfile

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.export import read_labels, read_run
from _runs import in_a_terminal, killed_mid_write

NAMES = {"ground": 0, "obstacle": 1, "unknown": 2}  # the archive's names -> pcreg's class ids (LAGR's table)


@pytest.fixture(scope="module")
def run_out(tmp_path_factory):
    """A real `pcreg run` of four synthetic frames with --confidence (made once for the module)."""
    root = tmp_path_factory.mktemp("run")
    frames = pcreg.synthetic("syn1a", 4, 0, width=160, height=120)
    (root / "frames").mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(root / "frames" / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(root / "key.png"), frames[0].labels)
    assert 2 in frames[0].labels  # the key frame holds unknown pixels too
    out = root / "out"
    assert main(["run", str(root / "frames"), "--labels", str(root / "key.png"), "--out", str(out), "--confidence"]) == 0
    return out


@pytest.fixture
def run_copy(run_out, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(run_out, out)
    return out


def _labelmap(text: str) -> dict[tuple[int, int, int], str]:
    colours = {}
    for line in text.splitlines():
        if line.strip() and not line.startswith("#"):
            name, colour, parts, actions = line.split(":")
            colours[tuple(int(c) for c in colour.split(","))] = name
    return colours


def _decode(z: zipfile.ZipFile, member: str, colours: dict) -> np.ndarray:
    """A colour-coded PNG of the archive back to pcreg's class ids through ``colours`` (RGB -> id)."""
    rgb = cv2.imdecode(np.frombuffer(z.read(member), np.uint8), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    out = np.full(rgb.shape[:2], 255, np.uint8)
    for colour, k in colours.items():
        out[(rgb == colour).all(axis=2)] = k
    assert (out != 255).all(), f"{member}: a colour the label map does not declare"
    return out


def _run_frames(out):
    state = json.loads((out / "run.json").read_text())
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    return [state["key_frame"]] + [s["name"] for s in steps]


def _check_archive(path, out, expected: dict[str, np.ndarray]):
    names = _run_frames(out)
    stems = [n.rsplit(".", 1)[0] for n in names]
    with zipfile.ZipFile(path) as z:
        assert z.testzip() is None
        assert sorted(z.namelist()) == sorted(["labelmap.txt", "ImageSets/Segmentation/default.txt"]
                                              + [f"SegmentationClass/{s}.png" for s in stems]
                                              + [f"SegmentationObject/{s}.png" for s in stems])
        assert z.read("ImageSets/Segmentation/default.txt").decode().split("\n") == stems + [""]
        colours = _labelmap(z.read("labelmap.txt").decode())
        assert sorted(colours.values()) == ["ground", "obstacle", "unknown"]  # no extra background line
        assert {v: k for k, v in colours.items()}["unknown"] == (0, 0, 0)  # the importer's background: black
        from pcreg.classes import LAGR, parse_labelmap

        assert parse_labelmap(z.read("labelmap.txt").decode(), "labelmap.txt") == LAGR
        by_id = {c: NAMES[name] for c, name in colours.items()}
        # the VOC instance colour map: 0 black (no instance: unlabelled in the tool), 1 (128,0,0), 2 (0,128,0)
        instances = {(0, 0, 0): 0, (128, 0, 0): 1, (0, 128, 0): 2}
        for stem in stems:
            labels = _decode(z, f"SegmentationClass/{stem}.png", by_id)
            np.testing.assert_array_equal(labels, expected[stem])
            inst = _decode(z, f"SegmentationObject/{stem}.png", instances)
            np.testing.assert_array_equal(inst == 0, labels == 2)  # unknown: no instance, nothing imported
            for i in (1, 2):  # each instance holds one class: ground 1, obstacle 2
                assert len(np.unique(labels[inst == i])) <= 1
            np.testing.assert_array_equal(inst[labels == 0], 1)
            np.testing.assert_array_equal(inst[labels == 1], 2)


def _labels(out):
    return {p.stem: read_labels(p) for p in out.glob("*.png")}


def test_export_decodes_back_to_the_runs_labels(run_copy, capsys):
    out = run_copy
    assert main(["export", str(out), "--format", "cvat-mask"]) == 0
    said = capsys.readouterr().out
    assert "4 frame(s)" in said and "Segmentation mask 1.1" in said
    archive = out / "export-cvat-mask.zip"
    expected = _labels(out)
    assert len(expected) == 4 and (expected["frame_000"] == 2).any()  # the key frame's unknown pixels
    _check_archive(archive, out, expected)
    # the same labels give the same bytes; an existing archive is kept unless --force
    first = archive.read_bytes()
    assert main(["export", str(out)]) == 2
    assert "exists (use --force" in capsys.readouterr().err
    assert main(["export", str(out), "--force"]) == 0 and archive.read_bytes() == first
    assert not list(out.glob(".*.tmp"))



def test_what_a_killed_export_left_is_removed_and_one_being_written_kept(run_copy):
    """An export killed mid-archive (kill -9, power lost) leaves its temporary file, as large as the frames it
    held, beside the archive: the next export of that archive removes it, but not the temporary file of
    another export of it still under way, nor one of another file."""
    from pcreg.outputs import atomic_file

    archive = run_copy / "export-cvat-mask.zip"
    killed = killed_mid_write(archive)
    other = killed_mid_write(run_copy / "export-cvat-mask.zip.zip")  # another archive's, not this one's
    with atomic_file(archive) as fh:  # an export of the same archive under way
        fh.write(b"PK")
        [writing] = set(run_copy.glob(".export-cvat-mask.zip.*.tmp")) - {killed, other}
        assert main(["export", str(run_copy)]) == 0
        assert not killed.exists() and writing.is_file() and other.is_file()
        _check_archive(archive, run_copy, _labels(run_copy))
    assert archive.read_bytes() == b"PK" and not writing.exists()  # the one under way took its place once done

def test_a_refused_export_still_removes_what_a_killed_one_left(run_copy, capsys):
    """An export with ``--force`` killed mid-archive, then one without it: refused as the archive exists, it
    removed nothing, and the killed one's temporary file (as large as the frames it held) stayed until a
    ``--force``. Another archive's temporary file is left."""
    archive = run_copy / "export-cvat-mask.zip"
    assert main(["export", str(run_copy)]) == 0
    first = archive.read_bytes()
    killed = killed_mid_write(archive)
    other = killed_mid_write(run_copy / "other.zip")
    capsys.readouterr()
    assert main(["export", str(run_copy)]) == 2
    assert "exists (use --force" in capsys.readouterr().err
    assert not killed.exists() and other.is_file() and archive.read_bytes() == first


def test_export_to_a_file_elsewhere(run_copy, tmp_path):
    dest = tmp_path / "for" / "cvat.zip"
    assert main(["export", str(run_copy), "--to", str(dest)]) == 0
    _check_archive(dest, run_copy, _labels(run_copy))
    assert not (run_copy / "export-cvat-mask.zip").exists()


def test_min_confidence_leaves_unsure_pixels_unlabelled(run_copy, tmp_path):
    out = run_copy
    labels = _labels(out)
    conf = {p.stem: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in (out / "confidence").glob("*.png")}
    assert sorted(conf) == ["frame_001", "frame_002", "frame_003"]  # the key frame has none: a person's labels
    p = float(np.median(np.concatenate([c.ravel() for c in conf.values()]))) / 255.0 + 1e-3
    expected = dict(labels)
    for stem, c in conf.items():
        expected[stem] = np.where(c.astype(np.float64) / 255.0 < p, 2, labels[stem]).astype(np.uint8)
        assert (expected[stem] == 2).sum() > (labels[stem] == 2).sum()  # about half the pixels marked
    assert main(["export", str(out), "--min-confidence", f"{p!r}", "--to", str(tmp_path / "c.zip")]) == 0
    _check_archive(tmp_path / "c.zip", out, expected)
    # 0 changes nothing; 1 leaves every frame after the key frame unlabelled, bar labels known for sure
    assert main(["export", str(out), "--min-confidence", "0", "--to", str(tmp_path / "z.zip")]) == 0
    _check_archive(tmp_path / "z.zip", out, labels)
    assert main(["export", str(out), "--min-confidence", "1", "--to", str(tmp_path / "o.zip")]) == 0
    everything = {s: (np.where(conf[s] < 255, 2, labels[s]).astype(np.uint8) if s in conf else labels[s]) for s in labels}
    _check_archive(tmp_path / "o.zip", out, everything)


def test_an_edited_run_is_refused_naming_the_file_edited(run_copy, tmp_path, capsys):
    """A confidence map written over with JPEG bytes (its name still .png) was exported with --min-confidence, its
    values moved at every edge; a run.json with a key written twice (JSON keeps the last) was read, and the export
    then blamed steps.jsonl for what run.json's second value counted."""
    out = run_copy
    conf = out / "confidence" / "frame_002.png"
    grey = cv2.imread(str(conf), cv2.IMREAD_UNCHANGED)
    conf.write_bytes(cv2.imencode(".jpg", grey)[1].tobytes())
    _refused([str(out), "--min-confidence", "0.5", "--to", str(tmp_path / "c.zip")], capsys, str(conf), "not a PNG")
    assert main(["export", str(out), "--to", str(tmp_path / "plain.zip")]) == 0  # without it, no map is read
    text = (out / "run.json").read_text().rstrip()
    assert text.endswith("}")
    (out / "run.json").write_text(text[:-1] + ', "done": 2}')
    _refused([str(out), "--to", str(tmp_path / "d.zip")], capsys, str(out / "run.json"),
             "the key 'done' is written twice in one object")
    assert not (tmp_path / "c.zip").exists() and not (tmp_path / "d.zip").exists()


def test_a_step_that_names_a_frame_another_step_named_otherwise_blames_the_steps(run_copy, tmp_path, capsys):
    """steps.jsonl edited so that two steps say frame 1 (the second named frame_002.png): the export and the review
    said the frames folder had changed since the run (a frame added, removed or renamed); the folder is untouched."""
    from pcreg.errors import InputError
    from pcreg.review import read_review

    out = run_copy
    lines = (out / "steps.jsonl").read_text().splitlines()
    second = json.loads(lines[1])
    assert second["frame"] == 2 and second["name"] == "frame_002.png"
    lines[1] = json.dumps(dict(second, frame=1))
    (out / "steps.jsonl").write_text("\n".join(lines) + "\n")
    said = f"{out / 'steps.jsonl'}: frame 1 is frame_001.png on one line and frame_002.png on another"
    _refused([str(out), "--to", str(tmp_path / "d.zip")], capsys, said)
    with pytest.raises(InputError, match=re.escape(said)):
        read_review(out)
    first = json.loads(lines[0])  # a step that names the key frame's place: run.json named it first
    lines[0], lines[1] = json.dumps(dict(first, frame=0)), json.dumps(second)
    (out / "steps.jsonl").write_text("\n".join(lines) + "\n")
    _refused([str(out), "--to", str(tmp_path / "d.zip")], capsys,
             f"{out / 'steps.jsonl'}: frame 0 is frame_000.png in run.json (its key frame) and frame_001.png on a line")


def test_a_run_folder_that_is_not_there_is_said_to_be_missing(tmp_path, capsys):
    """``pcreg export MISSING`` said "MISSING: not a folder", as of a file given in its place."""
    _refused([str(tmp_path / "missing")], capsys, f"{tmp_path / 'missing'}: no such folder")
    (tmp_path / "file").write_text("x")
    _refused([str(tmp_path / "file")], capsys, f"{tmp_path / 'file'}: not a folder")


def _refused(args, capsys, *said):
    try:
        code = main(["export", *args])
    except SystemExit as exc:  # a bad option: the parser's one line
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pcreg"), err
    for s in said:
        assert s in err, err
    return err


def test_bad_input_one_line_exit_2_nothing_written(run_copy, tmp_path, capsys):
    out = run_copy
    before = sorted(p.name for p in out.rglob("*"))
    # a folder that is not a run's output; one that does not exist
    (tmp_path / "plain").mkdir()
    _refused([str(tmp_path / "plain")], capsys, "run.json", "not the output of pcreg run")
    _refused([str(tmp_path / "nowhere")], capsys, "nowhere")
    # an unknown format; a confidence threshold out of range
    _refused([str(out), "--format", "coco"], capsys, "--format", "coco")
    _refused([str(out), "--min-confidence", "1.5"], capsys, "--min-confidence")
    # an unwritable destination: a folder, a path under a file
    _refused([str(out), "--to", str(tmp_path)], capsys, str(tmp_path), "is a folder")
    _refused([str(out), "--to", ""], capsys, "argument --to: expected a value")
    _refused([str(out), "--to", str(out / "run.json" / "x.zip")], capsys, "run.json", "not a folder")
    assert sorted(p.name for p in out.rglob("*")) == before
    # --min-confidence on a run made without --confidence
    no_conf = tmp_path / "no_conf"
    shutil.copytree(out, no_conf)
    shutil.rmtree(no_conf / "confidence")
    state = json.loads((no_conf / "run.json").read_text())
    state["run"].pop("confidence", None)
    (no_conf / "run.json").write_text(json.dumps(state))
    _refused([str(no_conf), "--min-confidence", "0.5"], capsys, "--min-confidence", "--confidence")
    assert not (no_conf / "export-cvat-mask.zip").exists()
    # a label file that is missing, or holds a value that is not a label: named, nothing written
    (out / "frame_002.png").rename(tmp_path / "aside.png")
    _refused([str(out)], capsys, "frame_002.png", "missing")
    cv2.imwrite(str(out / "frame_002.png"), np.full((120, 160), 7, np.uint8))
    _refused([str(out)], capsys, "frame_002.png", "label value 7")
    cv2.imwrite(str(out / "frame_002.png"), np.zeros((120, 160, 3), np.uint8) + [0, 0, 9])
    _refused([str(out)], capsys, "frame_002.png")
    cv2.imwrite(str(out / "frame_002.png"), np.zeros((60, 80), np.uint8))  # labels, but of another size
    _refused([str(out)], capsys, "frame_002.png", "labels of 80x60, the key frame's are")
    assert not (out / "export-cvat-mask.zip").exists() and not list(out.glob(".*.tmp"))
    # a run with no label files; a run.json that pcreg run did not write
    for p in out.glob("*.png"):
        p.unlink()
    _refused([str(out)], capsys, "no label files")
    (out / "run.json").write_text("{not json")
    _refused([str(out)], capsys, "run.json", "unreadable")
    assert not (out / "export-cvat-mask.zip").exists()


def test_a_key_frame_edited_in_run_json_is_said_to_be_run_json_s(run_copy, capsys):
    """A key frame that run.json names and that has no label file: the file was removed or run.json edited,
    and the line says both, naming run.json, not only the label file."""
    state = json.loads((run_copy / "run.json").read_text())
    state["key_frame"] = "frame_099.png"
    (run_copy / "run.json").write_text(json.dumps(state))
    _refused([str(run_copy)], capsys, "frame_099.png: missing", str(run_copy / "run.json"), "run.json edited")
    assert not (run_copy / "export-cvat-mask.zip").exists()


def test_only_the_frames_the_run_counted(run_copy):
    """A step appended after run.json's last commit (a run killed there) is not exported."""
    out = run_copy
    state = json.loads((out / "run.json").read_text())
    state["done"] = 3
    (out / "run.json").write_text(json.dumps(state))
    assert main(["export", str(out)]) == 0
    with zipfile.ZipFile(io.BytesIO((out / "export-cvat-mask.zip").read_bytes())) as z:
        assert z.read("ImageSets/Segmentation/default.txt").decode().split() == ["frame_000", "frame_001", "frame_002"]


@pytest.mark.parametrize("name", ["a\nb.png", "a\rb.png", "a\u2028b.png"])
def test_a_frame_name_with_a_line_break_is_refused_not_split_in_default_txt(name):
    from pcreg.errors import InputError
    from pcreg.export import cvat_mask_archive

    labels = np.zeros((4, 6), np.uint8)
    with pytest.raises(InputError, match="a frame name with a line break"):
        cvat_mask_archive([("f0.png", labels), (name, labels)])
    data, _ = cvat_mask_archive([("f0.png", labels), ("a b é.png", labels)])
    listed = zipfile.ZipFile(io.BytesIO(data)).read("ImageSets/Segmentation/default.txt").decode()
    assert listed == "f0\na b é\n"


@pytest.mark.parametrize("name", ["#f1.png", " f1.png", "f1 .png", "f1\u00a0.png"])
def test_a_frame_name_default_txt_would_read_otherwise_is_refused(name):
    """Datumaro's VOC reader (CVAT's import) strips each line of default.txt and takes one starting with '#' for a
    comment: a frame '#f1.png' was dropped from the import and ' f1.png' looked up as f1.png, without a word,
    while the export said it wrote every frame. Such a name is refused, naming the frame."""
    from pcreg.errors import InputError
    from pcreg.export import cvat_mask_archive

    labels = np.zeros((4, 6), np.uint8)
    with pytest.raises(InputError, match=f"^{re.escape(repr(name))}: .*default.txt.*rename the frame"):
        cvat_mask_archive([("f0.png", labels), (name, labels)])
    data, _ = cvat_mask_archive([("f0.png", labels), ("a#b c.png", labels)])  # inside a name: read as it is
    assert zipfile.ZipFile(io.BytesIO(data)).read("ImageSets/Segmentation/default.txt").decode() == "f0\na#b c\n"


def test_a_summary_names_a_dozen_labels_and_counts_the_rest():
    from pcreg.validation import MOST_NAMED, listed

    assert listed([]) == "none" and listed(["road"]) == "road" and listed(["road", "car"]) == "road and car"
    many = [f"c{i}" for i in range(150)]
    assert listed(many) == ", ".join(many[:MOST_NAMED]) + f" and {150 - MOST_NAMED} more"


def test_class_names_that_hold_a_comma_or_a_list_word_are_quoted_in_the_summary(tmp_path, capsys):
    """CVAT names such as 'car, red' or 'rock and gravel' were listed bare: 'labels car, red in 5, rock and gravel in
    5 and road in 5' reads as five classes. A name holding a comma, a quote or a word of the list is quoted."""
    from pcreg.classes.table import listed_name as quoted
    from pcreg.validation import listed

    assert [quoted(n) for n in ("road", "car, red", "rock and gravel", "none", "it's", "Person In Car")] == \
        ["road", "'car, red'", "'rock and gravel'", "'none'", '"it\'s"', "'Person In Car'"]
    assert listed([quoted("car, red"), quoted("road")]) == "'car, red' and road"
    names = ["background", "car, red", "rock and gravel", "road"]
    (tmp_path / "labelmap.txt").write_text("\n".join(
        ["# label:color_rgb:parts:actions"] + [f"{n}:{i * 60},{i * 30},{255 - i * 60}::" for i, n in enumerate(names)]
    ).replace("background:0,0,255", "background:0,0,0"))
    frames = pcreg.synthetic("syn1a", 3, 0, width=96, height=64)
    (tmp_path / "frames").mkdir()
    for t, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / "frames" / f"f{t}.png"), f.image[:, :, ::-1])
    key = np.zeros((64, 96), np.uint8)  # ids in the labelmap's order, background (0, 0, 0) the unknown
    key[:, 32:64], key[:, 64:] = 1, 2
    cv2.imwrite(str(tmp_path / "key.png"), key)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "key.png"), "--classes",
                 str(tmp_path / "labelmap.txt"), "--out", str(out)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    assert main(["export", str(out)]) == 0
    wrote, cvat = capsys.readouterr().out.splitlines()[:2]
    assert "(labels 'car, red' in " in wrote and ", 'rock and gravel' in " in wrote and " and road in " in wrote, wrote
    assert "the 3 labels 'car, red', 'rock and gravel' and road of its labelmap.txt" in cvat, cvat
    cv2.imwrite(str(tmp_path / "one.png"), np.zeros((64, 96), np.uint8))
    assert main(["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "one.png"), "--classes",
                 str(tmp_path / "labelmap.txt"), "--out", str(tmp_path / "one")]) == 2
    assert "hold one class only ('car, red')" in capsys.readouterr().err


def test_a_table_of_150_classes_runs_and_exports(tmp_path, capsys):
    # more classes than OpenCV takes channels in one array (128): every map of the step is filtered in parts
    from pcreg.classes.files import voc_colormap

    k, h, w = 150, 96, 128
    colours = voc_colormap(256)
    (tmp_path / "labelmap.txt").write_text("\n".join(
        ["# label:color_rgb:parts:actions"] + [f"c{i}:{','.join(str(int(v)) for v in colours[i])}::" for i in range(k)]))
    rng = np.random.default_rng(3)
    scene = cv2.resize(rng.integers(0, 256, (24, 40, 3)).astype(np.uint8), (w + 20, h), interpolation=cv2.INTER_LINEAR)
    labels = cv2.resize(rng.integers(1, k, (8, 12)).astype(np.uint8), (w + 20, h), interpolation=cv2.INTER_NEAREST)
    (tmp_path / "frames").mkdir()
    (tmp_path / "keys").mkdir()
    for t in range(5):
        cv2.imwrite(str(tmp_path / "frames" / f"f{t}.png"), scene[:, 4 * t:4 * t + w])
    for t in (0, 4):
        cv2.imwrite(str(tmp_path / "keys" / f"f{t}.png"), labels[:, 4 * t:4 * t + w])
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "keys"), "--classes",
                 str(tmp_path / "labelmap.txt"), "--out", str(out), "--confidence"]) == 0
    got = read_labels(out / "f2.png", read_run(out).table)
    assert got.shape == (h, w) and np.mean(got == labels[:, 8:8 + w]) > 0.9
    capsys.readouterr()
    assert main(["export", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"the {k - 1} labels" in said and "more" in said and len(said.splitlines()[1]) < 300
    assert zipfile.ZipFile(out / "export-cvat-mask.zip").read("labelmap.txt").decode().count("\n") >= k - 1


def test_export_and_view_say_when_the_run_has_not_labelled_every_frame_it_chose(tmp_path, capsys):
    frames = pcreg.synthetic("syn1a", 5, 0, width=160, height=120)
    folder, out = tmp_path / "frames", tmp_path / "out"
    folder.mkdir()
    for i, f in enumerate(frames[:4]):
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    command = ["run", str(folder), "--labels", str(tmp_path / "key.png"), "--out", str(out)]
    assert main(command) == 0
    assert main(["export", str(out)]) == 0
    said = capsys.readouterr()
    assert "unfinished" not in said.out + said.err
    cv2.imwrite(str(folder / "frame_004.png"), frames[4].image[:, :, ::-1])  # a frame more to label
    assert main(["export", str(out), "--force"]) == 0
    said = capsys.readouterr()
    assert f"pcreg: note: {out} holds 4 of the 5 frames the run chose: it is unfinished" in said.err
    assert "frames the run chose" not in said.out  # stdout holds what was written, as every command's does
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 0
    assert f"pcreg: note: {out} holds 4 of the 5 frames" in capsys.readouterr().err  # the same note, on stderr
    assert main(command) == 0  # the same command labels the frame left
    assert main(["export", str(out), "--force"]) == 0
    said = capsys.readouterr()
    assert "5 frame(s)" in said.out and "unfinished" not in said.out + said.err


def test_export_and_view_say_when_a_video_run_is_unfinished_or_being_written(tmp_path, monkeypatch, capsys):
    """A video's frames are not counted ahead (its container's count is no fact), and the note that a run is unfinished
    or being written was said of a frames folder only: a video run stopped, or exported while it ran, gave a partial
    archive and review without a word. run.json says whether decoding found the end of the frames (from one label
    image) or a stretch is under way (from key frames); the lock, whether a run writes the folder now."""
    from pcreg.outputs import OutputLock
    from _runs import kill_at_commit, kill_before_commit, video_and_keys

    _, video, keys = video_and_keys(tmp_path, 6, (0, 3))
    one, stretches = tmp_path / "one", tmp_path / "stretches"
    command = {one: ["run", str(video), "--labels", str(keys / "000000.png"), "--out", str(one)],
               stretches: ["run", str(video), "--labels", str(keys), "--out", str(stretches)]}
    kill_before_commit(monkeypatch, 4)
    assert main(command[one]) == 130
    monkeypatch.undo()
    kill_at_commit(monkeypatch, 2, "store")  # the video's frames decoded for the stretch's passes
    assert main(command[stretches]) == 130
    monkeypatch.undo()
    for out in (one, stretches):
        capsys.readouterr()
        assert main(["export", str(out)]) == 0
        err = capsys.readouterr().err
        assert f"pcreg: note: {out} holds " in err and "of a video, which the run did not label to its end: it is " \
            "unfinished (the same pcreg run command goes on from where it stopped)" in err, err
        assert main(command[out]) == 0
        with OutputLock(out):  # as while a run writes it
            assert main(["view", str(out), "--overlay", str(tmp_path / f"{out.name}.mp4")]) == 0
        err = capsys.readouterr().err
        assert f"pcreg: note: {out} holds 6 frame(s) of a video: a pcreg run (pid " in err, err
        assert main(["export", str(out), "--force"]) == 0
        assert "pcreg: note" not in capsys.readouterr().err  # finished: no note


def test_a_video_run_of_an_earlier_pcreg_is_not_said_unfinished(tmp_path, capsys):
    """A run.json without ``video_file`` (every run names it first since; an earlier pcreg's, which kept no
    ``video_end``) does not say whether the run labelled the video to its end: a finished run of pcreg 0.2.0 was said
    unfinished by the export and the review. The note says it is not known; the same command says "all frames already
    done", and from then on run.json says it."""
    from _runs import video_and_keys

    _, video, keys = video_and_keys(tmp_path, 6, (0,))
    out = tmp_path / "out"
    command = ["run", str(video), "--labels", str(keys / "000000.png"), "--out", str(out)]
    assert main(command) == 0
    state = json.loads((out / "run.json").read_text())
    earlier = {k: v for k, v in state.items() if k not in ("video_file", "video_end", "format")}
    (out / "run.json").write_text(json.dumps(earlier))  # as pcreg 0.2.0 wrote it
    capsys.readouterr()
    assert main(["export", str(out)]) == 0
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 0
    err = capsys.readouterr().err
    assert "unfinished" not in err
    assert err.count(f"pcreg: note: {out} holds 6 frame(s) of a video; its run.json does not say whether the run "
                     "labelled the video to its end (a run of an earlier pcreg)") == 2, err
    assert main(command) == 0
    assert "all 6 frames already done" in capsys.readouterr().out
    assert json.loads((out / "run.json").read_text())["video_end"] == 6
    assert main(["export", str(out), "--force"]) == 0
    assert "pcreg: note" not in capsys.readouterr().err


def test_a_run_stopped_before_its_first_frame_is_said_so_by_every_reader(tmp_path, capsys):
    """A run stopped before its run.json was written (its steps.jsonl made, no frame labelled): export said "no
    run.json, so not the output of pcreg run", view --web "no results.json here (an evaluation's output folder)"."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "steps.jsonl").write_bytes(b"")
    for command in (["export", str(out)], ["view", str(out), "--web"], ["view", str(out), "--overlay", str(tmp_path / "o.mp4")]):
        assert main(command) == 2
        assert capsys.readouterr().err == (f"pcreg: error: {out}: a pcreg run stopped there before it labelled its first "
                                           "frame (no run.json yet): the same pcreg run command starts it\n"), command
    (out / "steps.jsonl").unlink()
    assert main(["export", str(out)]) == 2
    assert capsys.readouterr().err == f"pcreg: error: {out}: no run.json, so not the output of pcreg run\n"


def _frames_then(monkeypatch, then):
    """pcreg.export.labelled_frames, each frame passed on after ``then(index)`` is called."""
    import pcreg.export

    real = pcreg.export.labelled_frames

    def frames(*args, **kwargs):
        for t, item in enumerate(real(*args, **kwargs)):
            then(t)
            yield item

    monkeypatch.setattr(pcreg.export, "labelled_frames", frames)


def test_an_interrupted_export_says_nothing_was_written_not_to_resume(run_copy, monkeypatch, capsys):
    def stop_at_the_third(t):
        if t == 2:
            raise KeyboardInterrupt

    _frames_then(monkeypatch, stop_at_the_third)
    assert main(["export", str(run_copy)]) == 130
    assert capsys.readouterr().err == "pcreg: interrupted (nothing was written)\n"
    assert not (run_copy / "export-cvat-mask.zip").exists() and not list(run_copy.glob(".*.tmp"))


def test_a_signal_once_the_archive_is_written_does_not_say_nothing_was_written(run_copy, monkeypatch, capsys):
    """Ctrl-C while the export printed its summary, the archive already in place: exit 130 and "interrupted (nothing
    was written)", beside the archive it had written. The archive is whole: the summary is printed, exit 0."""
    import os
    import signal

    import pcreg.classes.table

    real = pcreg.classes.table.listed_name
    sent = []

    def signal_then(name):
        if not sent:
            sent.append(os.kill(os.getpid(), signal.SIGINT))  # as the first class name of the summary is written
        return real(name)

    monkeypatch.setattr(pcreg.classes.table, "listed_name", signal_then)
    assert main(["export", str(run_copy)]) == 0
    said = capsys.readouterr()
    assert sent and said.out.startswith(f"wrote {run_copy / 'export-cvat-mask.zip'}: ") and "interrupted" not in said.err
    assert zipfile.ZipFile(run_copy / "export-cvat-mask.zip").testzip() is None


def test_the_archive_is_written_as_the_frames_are_read_not_held_whole(run_copy, monkeypatch, tmp_path):
    """Each frame's masks reach the disk (the archive's temporary file, beside it) before the next frame is
    read: a run of thousands of frames is never held in memory whole; the archive appears once complete."""
    dest = tmp_path / "a.zip"
    sizes: list[int] = []

    def measure(t):
        tmp = list(tmp_path.glob(".a.zip.*.tmp"))
        assert not dest.exists() and len(tmp) == 1
        sizes.append(tmp[0].stat().st_size)

    _frames_then(monkeypatch, measure)
    assert main(["export", str(run_copy), "--to", str(dest)]) == 0
    assert len(sizes) == 4 and all(a < b for a, b in zip(sizes, sizes[1:]))  # grew with every frame
    assert dest.is_file() and not list(tmp_path.glob(".*.tmp"))
    _check_archive(dest, run_copy, _labels(run_copy))


def test_a_frame_name_an_archive_cannot_hold_is_named(run_copy, capsys):
    steps = run_copy / "steps.jsonl"
    lines = steps.read_text().splitlines()
    first = json.loads(lines[0])
    first["name"] = "x\\y.png"  # a legal Linux file name, a folder and a file to an annotation tool
    steps.write_text("\n".join([json.dumps(first), *lines[1:]]) + "\n")
    assert main(["export", str(run_copy)]) == 2
    assert "the frame name 'x\\\\y.png' is not a file name an archive can hold" in capsys.readouterr().err


def test_a_label_file_of_another_size_is_named_with_min_confidence_not_its_confidence_map(run_copy, capsys):
    """The confidence map is of the frame's size; the label file beside it was replaced."""
    out = run_copy
    cv2.imwrite(str(out / "frame_002.png"), np.zeros((60, 80), np.uint8))
    err = _refused([str(out), "--min-confidence", "0.5"], capsys, "labels of 80x60, the key frame's are")
    assert f"{out / 'frame_002.png'}:" in err and "confidence" not in err, err
    assert not (out / "export-cvat-mask.zip").exists()


@pytest.mark.parametrize("damage, line", [
    (lambda s: s + "garbage\n", 4),  # a whole line after the counted steps that is no step
    (lambda s: s + '{"note": 1}\n', 4),  # JSON, but no step
    (lambda s: s + s.splitlines(keepends=True)[-1] * 2, 5),  # two lines after them: a stopped run leaves one
    (lambda s: s.replace("\n", "\n[]\n", 1), 2),  # a line among them that is no step: not run.json's
])
def test_a_steps_jsonl_line_pcreg_run_did_not_write_is_named_by_export_and_view(run_copy, capsys, damage, line):
    from pcreg.review import read_review

    path = run_copy / "steps.jsonl"
    path.write_text(damage(path.read_text()))
    _refused([str(run_copy)], capsys, f"{path}: line {line}")
    with pytest.raises(pcreg.errors.InputError, match=f"steps.jsonl: line {line}"):
        read_review(run_copy)


def test_a_step_cut_off_by_a_kill_after_the_counted_steps_is_left_out(run_copy):
    """A run killed while it appended a step leaves it without its line break: not counted, not exported."""
    from pcreg.review import read_review

    with open(run_copy / "steps.jsonl", "a") as fh:
        fh.write('{"frame": 4, "na')
    assert main(["export", str(run_copy)]) == 0
    assert len(read_review(run_copy).names) == 4


@pytest.mark.parametrize("odd", ["device", "fifo", "folder"])
def test_a_label_file_that_is_no_regular_file_is_said_to_be_one_not_missing(run_copy, capsys, odd):
    import os

    path = run_copy / "frame_002.png"
    path.unlink()
    if odd == "device":
        path.symlink_to("/dev/zero")
    elif odd == "fifo":
        os.mkfifo(path)
    else:
        path.mkdir()
    said = "is a folder, not a file (label image)" if odd == "folder" else "not a regular file"
    err = _refused([str(run_copy)], capsys, f"{path}: {said}")
    assert "missing" not in err
    assert not (run_copy / "export-cvat-mask.zip").exists()


def test_an_export_shows_its_progress_on_a_terminal(run_copy):
    """An export reads and writes every frame the run labelled (minutes for hours of video): on a terminal it
    draws a frames bar, as `pcreg run` does, and says nothing more when its output is not one."""
    rc, seen = in_a_terminal(["export", str(run_copy), "--to", str(run_copy / "a.zip")])
    assert rc == 0 and "frames:" in seen and "/4 [" in seen, seen  # tqdm's "frames:   0%|...| 0/4 [00:00<?"
    piped = _piped_export(run_copy)
    assert "frames" not in piped.stderr and "%|" not in piped.stderr, piped.stderr


def _piped_export(run_copy):
    """``pcreg export`` with its stderr a pipe, as a script runs it."""
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "pcreg", "export", str(run_copy), "--to", str(run_copy / "b.zip")],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("absent", [("fence",), ("fence", "sign", "pole", "tree")])
def test_the_summary_names_the_classes_in_no_frame(tmp_path, capsys, absent):
    """The line after the archive names the classes no frame holds (up to three; more are counted)."""
    from _runs import ROAD_AND_CAR, colour_keys, drifting_frames

    folder, _ = drifting_frames(tmp_path / "frames", (48, 64), n=3)
    keys = colour_keys(tmp_path / "keys")
    colours = ["64,64,128", "192,192,128", "128,128,128", "128,128,0"]
    table = tmp_path / "labelmap.txt"
    table.write_text(ROAD_AND_CAR + "".join(f"{n}:{c}::\n" for n, c in zip(absent, colours)))
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(keys), "--classes", str(table), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["export", str(out)]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    said = "fence in none" if len(absent) == 1 else "4 others in none"
    assert "(labels road in 3 and car in 3; " + said + "; unknown left unlabelled in" in line, line


def test_each_frame_name_is_checked_once_not_against_every_name_before(monkeypatch):
    """A frame's name was looked for in the list of every name written before it, so an export's time grew with
    the square of the run's frames (10,000 frames of 4x4 took 3.0 s, 40,000 took 25 s; an hour at 30 frames a
    second is 108,000): counted here by the comparisons of names, one a frame now."""
    from pathlib import Path

    import pcreg.export

    compared = [0]

    class Name(str):
        __hash__ = str.__hash__

        def __eq__(self, other):
            compared[0] += 1
            return str.__eq__(self, other)

    class Counted(type(Path())):
        @property
        def stem(self):
            return Name(super().stem)

    monkeypatch.setattr(pcreg.export, "Path", Counted)
    n = 2000
    labels = np.zeros((2, 2), np.uint8)
    pcreg.export.write_cvat_mask(io.BytesIO(), ((f"{i:06d}.png", labels) for i in range(n)))
    assert compared[0] <= 2 * n  # one a frame where its name is told to be one line (2,001,000 before)
    with pytest.raises(pcreg.errors.InputError, match="two frames named 000001"):
        pcreg.export.write_cvat_mask(io.BytesIO(), ((f"{i:06d}.png", labels) for i in (0, 1, 2, 1)))


def test_the_archive_is_refused_over_an_input_of_the_run_force_or_not(tmp_path, capsys):
    """``--to`` the run's own key labels (or its CVAT export) with ``--force`` wrote the archive over them: the person's
    labels were lost, and the run, resumed, read the archive as new key labels."""
    frames = pcreg.synthetic("syn1a", 3, 0, width=96, height=72)
    (tmp_path / "frames").mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / "frames" / f"f{i}.png"), f.image[:, :, ::-1])
    key = tmp_path / "key.png"
    cv2.imwrite(str(key), frames[0].labels)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "frames"), "--labels", str(key), "--out", str(out), "--model", "flow"]) == 0
    before = key.read_bytes()
    capsys.readouterr()
    assert main(["export", str(out), "--to", str(key), "--force"]) == 2
    assert capsys.readouterr().err == (f"pcreg: error: {key} is the input {key}; the output would overwrite it (choose "
                                       "another file)\n")
    assert key.read_bytes() == before


def test_the_archive_is_refused_over_a_frame_of_the_run_force_or_not(tmp_path, capsys):
    """``--to FRAMES/f1.png --force`` (a file of the folder of frames the run read, not the folder itself) wrote the
    archive over the frame: the video's frame was lost, and the run, resumed or run again, refused the folder. A run's
    output folder inside its folder of frames is still exported over its own archive with --force."""
    frames = pcreg.synthetic("syn1a", 3, 0, width=96, height=72)
    src = tmp_path / "frames"
    src.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(src / f"f{i}.png"), f.image[:, :, ::-1])
    key = tmp_path / "key.png"
    cv2.imwrite(str(key), frames[0].labels)
    out = src / "labelled"  # a folder is no frame: the run's output may lie among its frames
    assert main(["run", str(src), "--labels", str(key), "--out", str(out), "--model", "flow"]) == 0
    before = (src / "f1.png").read_bytes()
    capsys.readouterr()
    assert main(["export", str(out), "--to", str(src / "f1.png"), "--force"]) == 2
    assert capsys.readouterr().err == (f"pcreg: error: --to {src / 'f1.png'}: a file of the folder {src} the run "
                                       "reads; the archive would replace it (choose another name or folder)\n")
    assert (src / "f1.png").read_bytes() == before
    assert main(["export", str(out)]) == 0
    assert main(["export", str(out), "--force"]) == 0  # its own archive, inside the folder of frames
    assert main(["export", str(out), "--to", str(src / "new.zip")]) == 0  # a new file there replaces nothing
    assert zipfile.is_zipfile(src / "new.zip")


def test_a_frame_name_that_is_not_utf8_is_refused():
    """Frames ``f\\xff.png`` and ``f\\xfe.png`` (names that are not UTF-8, as a Linux file system holds them) were both
    stored as ``f\\ufffd`` (one frame's masks taken for both); one alone was stored so, exit 0, its masks matching no
    frame where the archive was imported (pcreg run --labels of it refused "names no frame")."""
    labels = np.zeros((4, 6), np.uint8)
    frames = [("g.png", labels), ("f\udcff.png", labels), ("f\udcfe.png", labels + 1)]
    for given in (frames, frames[:2]):
        with pytest.raises(pcreg.errors.InputError, match=re.escape(
                "'f\\udcff.png': a frame name that is not UTF-8: a zip names its members in UTF-8, and as 'f\ufffd' its "
                "masks would match no frame in the tool (nor in pcreg run --labels); rename the frames to UTF-8")):
            pcreg.export.write_cvat_mask(io.BytesIO(), given)
    with pytest.raises(pcreg.errors.InputError, match="two frames named g"):
        pcreg.export.write_cvat_mask(io.BytesIO(), frames[:1] * 2)
