"""`pcreg run SOURCE --labels FOLDER`: key frames anywhere, every frame labelled from those around it, both
ways; resumed exactly after an interrupt; a key frame added relabels only its stretch; --suggest N; bad
labels folders and options refused in one line (exit 2), nothing already written lost."""

import json
import os
import zipfile

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.classification.metrics import error_rate
from _runs import in_a_terminal, kill_at_commit, one_line_errors, timeless
from pcreg.export import read_labels


def six_frames() -> list:
    """The six synthetic frames these runs label (f0 to f5)."""
    return pcreg.synthetic("syn1a", 6, 0, width=160, height=120)


def frames_folder(d, frames):
    """``frames`` written to the new folder ``d`` as f0.png, f1.png, ..."""
    d.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(d / f"f{i}.png"), f.image[:, :, ::-1])
    return d


@pytest.fixture(scope="module")
def frames():
    return six_frames()


@pytest.fixture()
def folder(tmp_path, frames):
    return frames_folder(tmp_path / "frames", frames)


def _video(tmp_path, frames):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (160, 120))
    for f in frames:
        writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    writer.release()
    return path


def _keys(path, frames, which, name="f{}"):
    path.mkdir(exist_ok=True)
    for i in which:
        cv2.imwrite(str(path / f"{name.format(i)}.png"), frames[i].labels)
    return path


def _labels(out, name):
    return read_labels(out / f"{name}.png")


_err, _timeless = one_line_errors, timeless


def _outputs(out) -> dict:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*.png"))}


def test_two_key_frames_label_the_frames_between_better_than_one_as_label_clip_does(tmp_path, frames, folder):
    from pcreg.pipeline.keyframes import label_clip
    from pcreg.registration.clouds import load_image

    one, two = tmp_path / "one", tmp_path / "two"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "k1", frames, [0])), "--out", str(one)]) == 0
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "k2", frames, [0, 4])), "--out", str(two)]) == 0
    between = range(1, 4)
    e1 = np.mean([error_rate(_labels(one, f"f{t}"), frames[t].labels) for t in between])
    e2 = np.mean([error_rate(_labels(two, f"f{t}"), frames[t].labels) for t in between])
    assert e2 < e1
    np.testing.assert_array_equal(_labels(two, "f4"), frames[4].labels)  # a key frame's labels as given
    # the run labels each frame as label_clip does (each stretch's classifier on its own key frames)
    images = [load_image(folder / f"f{t}.png") for t in range(6)]
    clip = label_clip(lambda t: images[t], 6, {0: frames[0].labels, 4: frames[4].labels})
    for f in clip:
        np.testing.assert_array_equal(_labels(two, f"f{f.index}"), f.labels)
    steps = [json.loads(line) for line in (two / "steps.jsonl").read_text().splitlines()]
    assert sorted((s["frame"], tuple(s["keys"])) for s in steps) == [
        (1, ("f0.png", "f4.png")), (2, ("f0.png", "f4.png")), (3, ("f0.png", "f4.png")), (5, ("f4.png",))]
    assert not (two / ".keys").exists()


def test_one_key_frame_at_the_first_frame_labels_as_a_single_label_image(tmp_path, frames, folder):
    _keys(tmp_path / "k", frames, [0])
    more = ["--confidence", "--suggest", "2"]
    assert main(["run", str(folder), "--labels", str(tmp_path / "k"), "--out", str(tmp_path / "a"), *more]) == 0
    assert main(["run", str(folder), "--labels", str(tmp_path / "k" / "f0.png"), "--out", str(tmp_path / "b"), *more]) == 0
    assert _outputs(tmp_path / "a") == _outputs(tmp_path / "b")
    suggested = (tmp_path / "b" / "suggest.txt").read_text()
    assert suggested == (tmp_path / "a" / "suggest.txt").read_text() and len(suggested.splitlines()) == 2


def run_whole_and_stopped(tmp_path, frames, monkeypatch, kill_at: int, phase: str) -> list[str]:
    """A video with key frames 1 and 4 run whole into ``tmp_path/whole``, and into ``tmp_path/cut`` stopped at
    commit ``kill_at`` of ``phase`` (:func:`kill_at_commit`): the command's arguments but ``--out``."""
    video = _video(tmp_path, frames)
    keys = _keys(tmp_path / "keys", frames, [1, 4], name="{:06d}")
    args = ["run", str(video), "--labels", str(keys), "--confidence"]
    assert main(args + ["--out", str(tmp_path / "whole")]) == 0
    kill_at_commit(monkeypatch, kill_at, phase)
    assert main(args + ["--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    return args


@pytest.mark.parametrize("kill_at, phase", [(10, "store"), (15, "between"), (18, "backward"), (21, "forward")])
def test_an_interrupted_run_resumes_to_the_same_bytes(tmp_path, frames, monkeypatch, capsys, kill_at, phase):
    """A video with key frames 1 and 4, killed at a commit of the stretch between them (its frames being
    kept, its forward pass, its backward pass) or of the one after, then run again."""
    args = run_whole_and_stopped(tmp_path, frames, monkeypatch, kill_at, phase)
    assert any((tmp_path / "cut" / ".keys").iterdir())  # what the stretch's passes hand on, in the hidden folder
    if phase == "backward":  # what the forward pass kept, lost: refused in one line, --force starts over
        import shutil

        lost = shutil.copytree(tmp_path / "cut", tmp_path / "lost")
        capsys.readouterr()
        for f in lost.glob(".keys/*/prior-*.kept"):
            f.unlink()
        assert main(args + ["--out", str(lost)]) == 2
        assert _err(capsys) == [f"pcreg: error: {next(lost.glob('.keys/*'))}/prior-2.kept: missing or unreadable; use "
                                "--force to start over"]
        assert main(args + ["--out", str(lost), "--force"]) == 0
        assert _outputs(tmp_path / "whole") == _outputs(lost)
    assert main(args + ["--out", str(tmp_path / "cut")]) == 0
    assert _outputs(tmp_path / "whole") == _outputs(tmp_path / "cut")
    assert (tmp_path / "whole" / "run.json").read_bytes() == (tmp_path / "cut" / "run.json").read_bytes()
    assert ([_timeless(x) for x in (tmp_path / "whole" / "steps.jsonl").read_text().splitlines()]
            == [_timeless(x) for x in (tmp_path / "cut" / "steps.jsonl").read_text().splitlines()])
    assert sorted(_outputs(tmp_path / "cut")) == ([f"{i:06d}.png" for i in range(6)]
                                                  + [f"confidence/{i:06d}.png" for i in (0, 2, 3, 5)])
    state = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert state["cursor"] is None and [s["keys"] for s in state["stretches"]] == [["000001"], ["000001", "000004"],
                                                                                    ["000004"]]
    assert not (tmp_path / "cut" / ".keys").exists()


def test_a_key_frame_added_relabels_only_its_stretch_and_suggest_names_the_frames(tmp_path, frames, folder, capsys):
    keys, out = _keys(tmp_path / "keys", frames, [0, 3]), tmp_path / "out"
    args = ["run", str(folder), "--labels", str(keys), "--out", str(out), "--suggest", "2"]
    assert main(args) == 0
    lines = (out / "suggest.txt").read_text().splitlines()
    steps = {s["name"]: s["predicted_error"] for s in map(json.loads, (out / "steps.jsonl").read_text().splitlines())}
    assert len(lines) == 2 and len({ln.split()[0] for ln in lines}) == 2
    for ln in lines:
        name, err = ln.split()
        assert name in {"f1", "f2", "f4", "f5"} and float(err) == pytest.approx(steps[f"{name}.png"], abs=0.005)
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("f*.png")}
    _keys(keys, frames, [5])  # splits the last stretch (f4, f5 from f3) into f4 between f3 and f5
    os.utime(out / "f1.png", ns=(1, 1))  # a frame of an unchanged stretch: never written again
    assert main(args) == 0
    after = {p.name: p.stat().st_mtime_ns for p in out.glob("f*.png")}
    assert after["f1.png"] == 1 and all(after[n] == before[n] for n in ("f0.png", "f2.png", "f3.png"))
    assert after["f4.png"] != before["f4.png"] and after["f5.png"] != before["f5.png"]
    np.testing.assert_array_equal(_labels(out, "f5"), frames[5].labels)
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert sorted(s["name"] for s in steps) == ["f1.png", "f2.png", "f4.png"]
    assert main(args) == 0 and "already done" in capsys.readouterr().out
    # a frame's labels the run counts done, gone since: refused, not called done
    moved = (out / "f2.png").rename(tmp_path / "f2.png")
    assert main(args) == 2 and _err(capsys)[0].startswith(f"pcreg: error: {out / 'f2.png'} is missing, though")
    moved.rename(out / "f2.png")
    # another option is refused; --suggest asks for more frames than are left
    assert main(args + ["--weight", "1"]) == 2 and "other options" in _err(capsys)[0]
    assert main(args[:-1] + ["4"]) == 2
    assert _err(capsys) == ["pcreg: error: --suggest 4: only 3 frame(s) are not key frames"]


def test_a_frame_made_a_key_frame_keeps_no_confidence_map_of_when_it_was_labelled(tmp_path, frames, folder):
    """With --confidence, a key frame added since holds its key labels and no confidence map, as a run from those key
    frames at once has it: its map from when it was labelled stayed (the review and the export read it)."""
    keys = _keys(tmp_path / "keys", frames, [0, 5])
    args = ["run", str(folder), "--labels", str(keys), "--confidence", "--out"]
    assert main(args + [str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "confidence" / "f3.png").is_file()
    _keys(keys, frames, [3])
    assert main(args + [str(tmp_path / "out")]) == 0
    assert main(args + [str(tmp_path / "at_once")]) == 0
    assert not (tmp_path / "out" / "confidence" / "f3.png").exists()
    assert _outputs(tmp_path / "out") == _outputs(tmp_path / "at_once")


def test_bad_labels_folders_and_options_are_refused(tmp_path, frames, folder, capsys):
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "k", frames, [0])), "--out", str(out)]) == 0
    written = _outputs(out)

    def refused(keys, *more):
        assert main(["run", str(folder), "--labels", str(keys), "--out", str(out), *more]) == 2
        err = _err(capsys)
        assert len(err) == 1 and _outputs(out) == written
        return err[0]

    said = refused(_keys(tmp_path / "nameless", frames, [0, 2], name="g{}"))
    assert "g0.png: names no frame" in said and f"(f0 ... f{len(frames) - 1})" in said, said
    twice = _keys(tmp_path / "twice", frames, [0, 2])
    cv2.imwrite(str(twice / "f2.PNG"), frames[2].labels)
    if len(list(twice.iterdir())) == 3:  # a file system that tells case apart
        assert "a second label for the frame f2.png" in refused(twice)
    small = _keys(tmp_path / "small", frames, [0])
    cv2.imwrite(str(small / "f3.png"), frames[3].labels[:60])
    msg = refused(small)
    assert msg.startswith("pcreg: error: ") and "f3.png: labels are 160x60, the frames 160x120" in msg
    ground = tmp_path / "ground"  # two key frames that show ground alone: which ones is said
    ground.mkdir()
    for i in (0, 2):
        cv2.imwrite(str(ground / f"f{i}.png"), np.zeros_like(frames[i].labels))
    assert main(["run", str(folder), "--labels", str(ground), "--out", str(tmp_path / "o_ground")]) == 2
    err = _err(capsys)
    assert len(err) == 1 and "the labels of f0.png and f2.png hold one class only (ground)" in err[0]
    with pytest.raises(SystemExit) as exit_:  # argparse's own refusal, one line too
        main(["run", str(folder), "--labels", str(tmp_path / "k"), "--out", str(out), "--suggest", "0"])
    assert exit_.value.code == 2 and _err(capsys) == ["pcreg run: error: argument --suggest: expected an integer >= 1, got 0"]
    assert "only 5 frame(s)" in refused(tmp_path / "k", "--suggest", "6")
    assert main(["run", str(folder), "--labels", str(tmp_path / "k"), "--out", str(tmp_path / "k")]) == 2
    assert "would overwrite the key frames' labels" in _err(capsys)[0]
    # a video's frames are named by index: two names of one frame, a frame past the end
    video = _video(tmp_path, frames)
    vkeys = _keys(tmp_path / "vk", frames, [1], name="{:06d}")
    cv2.imwrite(str(vkeys / "0000001.png"), frames[1].labels)
    assert main(["run", str(video), "--labels", str(vkeys), "--out", str(out)]) == 2
    assert "a second label for the frame 000001" in _err(capsys)[0]
    late = _keys(tmp_path / "late", frames, [1], name="{:06d}")
    cv2.imwrite(str(late / "000009.png"), frames[1].labels)
    assert main(["run", str(video), "--labels", str(late), "--out", str(out)]) == 2
    assert "000009.png: names no frame" in _err(capsys)[0] and _outputs(out) == written
    unchosen = _keys(tmp_path / "unchosen", frames, [2], name="{:06d}")  # --start 1 --every 2 chooses 1, 3, 5
    assert main(["run", str(video), "--labels", str(unchosen), "--out", str(out), "--start", "1", "--every", "2"]) == 2
    assert "(000001 ... 000005) among those chosen" in _err(capsys)[0]


def test_key_labels_named_as_cvat_names_frames_label_those_frames(tmp_path, frames, folder):
    """A key folder's frame_NNNNNN.png labels the source frame NNNNNN (CVAT's names, for a folder and a
    video alike): the run is the one its NAME.png keys give; a second name of one frame is refused."""
    by_name, by_cvat = tmp_path / "o_name", tmp_path / "o_cvat"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "kn", frames, [0, 4])), "--out", str(by_name)]) == 0
    cvat = _keys(tmp_path / "kc", frames, [0, 4], name="frame_{:06d}")
    assert main(["run", str(folder), "--labels", str(cvat), "--out", str(by_cvat)]) == 0
    assert _outputs(by_name) == _outputs(by_cvat)
    cv2.imwrite(str(cvat / "f4.png"), frames[4].labels)
    assert main(["run", str(folder), "--labels", str(cvat), "--out", str(tmp_path / "o_twice")]) == 2
    video = _video(tmp_path, frames)
    vkeys = _keys(tmp_path / "vc", frames, [2], name="frame_{:06d}")
    assert main(["run", str(video), "--labels", str(vkeys), "--out", str(tmp_path / "o_video")]) == 0
    assert (tmp_path / "o_video" / "000002.png").is_file()


def test_a_key_frames_run_is_exported_and_reviewed_like_a_one_key_run(tmp_path, folder, frames):
    """export and the review read a run from a folder of key frames: every frame, the key frames among
    them, in frame order."""
    import zipfile

    from pcreg.export import read_run
    from pcreg.review import read_review

    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "keys", frames, (0, 5))),
                 "--out", str(out), "--confidence"]) == 0
    run = read_run(out)
    assert run.names == tuple(f"f{i}.png" for i in range(6))
    assert run.confidence[0] is None and run.confidence[5] is None and run.confidence[2] is not None
    assert main(["export", str(out), "--format", "cvat-mask"]) == 0
    with zipfile.ZipFile(out / "export-cvat-mask.zip") as z:
        assert sum(n.startswith("SegmentationClass/") for n in z.namelist()) == 6
    r = read_review(out)
    assert r.names == tuple(f"f{i}.png" for i in range(6)) and r.keys == frozenset({0, 5})
    assert all((e is None) == (t in (0, 5)) for t, e in enumerate(r.errors))


def test_min_confidence_keeps_every_key_frames_labels_and_thresholds_the_first_frame_when_not_a_key(
        tmp_path, folder, frames):
    """export --min-confidence of a run from a folder of key frames: each key frame's labels (a person's) are
    kept, wherever it lies, and every other frame, the first one included when it is not a key frame, is
    thresholded on its own confidence map."""
    from pcreg.export import read_run

    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "keys", frames, (1, 4))),
                 "--out", str(out), "--confidence"]) == 0
    assert read_run(out).names[0] == "f0.png"  # the first frame is labelled backwards from f1, not a key frame
    archive = tmp_path / "sure.zip"
    assert main(["export", str(out), "--min-confidence", "1", "--to", str(archive)]) == 0
    unknown = 2  # lagr's
    with zipfile.ZipFile(archive) as z:
        for i in range(6):
            inst = cv2.imdecode(np.frombuffer(z.read(f"SegmentationObject/f{i}.png"), np.uint8), cv2.IMREAD_COLOR)
            unlabelled = (inst == 0).all(axis=2)
            labels = _labels(out, f"f{i}")
            if i in (1, 4):  # a key frame: its labels as they are
                np.testing.assert_array_equal(unlabelled, labels == unknown)
            else:
                conf = cv2.imread(str(out / "confidence" / f"f{i}.png"), cv2.IMREAD_UNCHANGED)
                assert ((conf < 255) & (labels != unknown)).any()  # a frame the threshold changes
                np.testing.assert_array_equal(unlabelled, (labels == unknown) | (conf < 255))


def test_the_old_stream_run_name_warns_and_still_opens_a_run(tmp_path, frames):
    """`pcreg.pipeline.stream_run.StreamRun` is `pcreg.runs.run.Run` for a run from one label image, with a
    DeprecationWarning naming the new spelling."""
    from pcreg.datasets.sources import open_frames
    from pcreg.pipeline import stream_run
    from pcreg.runs.run import Run

    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(frames[:2]):
        cv2.imwrite(str(folder / f"f{i}.png"), f.image[:, :, ::-1])
    with pytest.warns(DeprecationWarning, match="pcreg.runs.run.Run"):
        old = stream_run.StreamRun
    run = old(open_frames(folder), frames[0].labels, tmp_path / "out", None, identity={"x": 1})
    assert isinstance(run, Run) and run.start() == 1
    assert run.carry_after(0) == (None, None)  # 0.2.0's pair (Run's gives a third, the scene)
    assert run.learned_after(0) is None  # apart, as before 0.2.0
    assert (tmp_path / "out" / "f0.png").is_file() and json.loads((tmp_path / "out" / "run.json").read_text())["done"] == 1


def test_a_run_whose_every_frame_is_a_key_frame_says_so(tmp_path, frames, folder, capsys):
    """Every frame given labels (a CVAT export of a fully drawn task): the run wrote their labels and said "all
    frames already done", as if an earlier run had labelled them."""
    keys = _keys(tmp_path / "keys", frames, range(len(frames)))
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(out)]) == 0
    assert f"every frame is a key frame ({len(frames)})" in capsys.readouterr().out
    np.testing.assert_array_equal(_labels(out, "f3"), frames[3].labels)


def test_the_bar_counts_the_forward_pass_between_two_key_frames(folder, frames, tmp_path):
    """Between two key frames a forward pass keeps each frame's prior before the backward pass labels any: the
    bar sat at 0 through it (half the run: 5.6 s of 10.6 over 146 frames of CamVid) and then guessed 13 minutes
    left. It counts the forward steps too: 4 frames between key frames 0 and 5, 8 steps."""
    keys = tmp_path / "keys"
    keys.mkdir()
    for k in (0, 5):
        cv2.imwrite(str(keys / f"f{k}.png"), frames[k].labels)
    rc, seen = in_a_terminal(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out")])
    assert rc == 0 and "steps:" in seen and "/8 [" in seen and "/4 [" not in seen, seen


def test_a_stretch_carry_of_another_stream_is_refused_in_one_line(tmp_path, frames, monkeypatch, capsys):
    """A carry in the hidden folder whose cut-test frame is of another size (another stream's) is refused as
    the one-key run refuses it: one line, --force to start over, not a bare message naming no file."""
    args = run_whole_and_stopped(tmp_path, frames, monkeypatch, 18, "backward")  # resumed after a step: its carry
    edited = 0
    for f in (tmp_path / "cut").glob(".keys/*/carry-*.npz"):
        with np.load(f) as z:
            members = {k: z[k] for k in z.files}
        if "scene_grey" in members:
            np.savez(f, **{**members, "scene_grey": np.zeros((5, 7), np.uint8)})
            edited += 1
    assert edited
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "cut")]) == 2
    err = _err(capsys)
    assert len(err) == 1 and "another stream" in err[0] and err[0].endswith("use --force to start over"), err
    assert str(tmp_path / "cut") in err[0] and "carry-" in err[0]


def test_a_key_label_of_a_frame_file_not_chosen_is_refused_not_moved_to_the_next(tmp_path, frames, capsys):
    """Frames named frame_000001.png, ... (as ffmpeg numbers the files it writes, from 1) and a key label named as
    one of them that --start/--every leave out: it names that file, not CVAT's frame number (the file after it), so
    it is refused as a frame not chosen; before, frame_000003.png's labels became frame_000004.png's."""
    d = tmp_path / "frames"
    d.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(d / f"frame_{i + 1:06d}.png"), f.image[:, :, ::-1])
    keys = tmp_path / "keys"  # --start 1 --every 2 chooses frame_000002.png, frame_000004.png, frame_000006.png
    keys.mkdir()
    cv2.imwrite(str(keys / "frame_000003.png"), frames[2].labels)  # frames[2]'s file, not chosen
    out = tmp_path / "out"
    assert main(["run", str(d), "--labels", str(keys), "--out", str(out), "--every", "2", "--start", "1"]) == 2
    err = _err(capsys)[0]
    assert "frame_000003.png: names no frame" in err and "among those chosen" in err
    assert not (out / "run.json").exists()
    # a CVAT export of such a task names its masks so too
    export = tmp_path / "export"
    (export / "SegmentationClass").mkdir(parents=True)
    (export / "labelmap.txt").write_text("background:0,0,0::\nground:34,197,94::\nobstacle:255,40,40::\n")
    colours = np.array([[34, 197, 94], [255, 40, 40], [0, 0, 0]], np.uint8)
    cv2.imwrite(str(export / "SegmentationClass" / "frame_000003.png"), colours[frames[2].labels][:, :, ::-1])
    assert main(["run", str(d), "--labels", str(export), "--out", str(out), "--every", "2", "--start", "1"]) == 2
    err = _err(capsys)[0]  # as the folder's: the file it names is not chosen, and which are around it
    assert "frame_000003.png: names no frame" in err and "--every 2 chooses frame_000002 and frame_000004 around it" \
        in err and not (out / "run.json").exists()
    # labels named by CVAT's numbers of a video task over these files (frame 1 the second file) and by the files'
    # names alike, one of them a file left out: read two ways, refused as when every file is chosen
    cv2.imwrite(str(keys / "frame_000001.png"), frames[1].labels)  # CVAT's frame 1: frame_000002.png, chosen
    assert main(["run", str(d), "--labels", str(keys), "--out", str(out), "--start", "1"]) == 2
    assert "name frames two ways" in _err(capsys)[0] and not (out / "run.json").exists()


def test_a_key_label_saved_as_a_jpeg_or_tiff_is_said_not_passed_over(tmp_path, frames, folder, capsys):
    """A labels folder holding a key frame's labels saved as a JPEG or a TIFF (no NAME.png beside it): the run says, on
    stderr before the first frame, that those files are not read, naming them (before, they were passed over without
    a word and their frames labelled as if nobody had drawn them); a folder with no PNG at all names them in its
    refusal. A JPEG with its PNG beside it, or one that names no frame, is not mentioned."""
    keys = _keys(tmp_path / "keys", frames, [0])
    cv2.imwrite(str(keys / "f3.jpg"), frames[3].labels)
    cv2.imwrite(str(keys / "f4.tif"), frames[4].labels)
    cv2.imwrite(str(keys / "f0.jpg"), frames[0].labels)
    cv2.imwrite(str(keys / "thumbnail.jpg"), frames[0].labels)
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "not read as key labels" in line]
    assert len(notes) == 1 and "2 images named as frames but not PNG" in notes[0] and "(f3.jpg and f4.tif)" in notes[0], notes
    (keys / "f0.png").unlink()
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out2")]) == 2
    err = _err(capsys)
    assert len(err) == 1 and "holds no label PNG" in err[0] and "(f0.jpg, f3.jpg and f4.tif)" in err[0], err


def test_key_labels_of_frames_outside_start_and_stop_are_left_out_with_a_note(tmp_path, frames, folder, capsys):
    """One folder of key labels (or one CVAT export) for a whole video, run a stretch at a time: the labels of frames
    before --start or from --stop on are left out, said in one note, and the run is the one the labels inside the
    stretch give; a frame --every steps over inside the stretch is still refused (its labels would be lost)."""
    stretch = ["--start", "1", "--stop", "5"]  # f1 .. f4
    whole = _keys(tmp_path / "whole", frames, [0, 2, 5])
    inside = _keys(tmp_path / "inside", frames, [2])
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["run", str(folder), "--labels", str(inside), "--out", str(a), *stretch]) == 0
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(whole), "--out", str(b), *stretch]) == 0
    err = capsys.readouterr().err
    assert err.count("pcreg: note:") == 1
    assert f"--labels {whole}: 2 key labels of frames outside those chosen left out (--start 1 --stop 5): f0.png and " \
           "f5.png" in err
    assert _outputs(a) == _outputs(b) and sorted(_outputs(b)) == ["f1.png", "f2.png", "f3.png", "f4.png"]
    assert [_timeless(line) for line in (a / "steps.jsonl").read_text().splitlines()] == [
        _timeless(line) for line in (b / "steps.jsonl").read_text().splitlines()]
    # every label outside the stretch: refused in one line, nothing written
    out = tmp_path / "none"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "ends", frames, [0, 5])), "--out", str(out),
                 *stretch]) == 2
    assert "every key label names a frame outside those chosen (--start 1 --stop 5): f0.png and f5.png" \
        in _err(capsys)[0] and not out.exists()
    # inside the stretch but not chosen (--every 2 chooses f1, f3): refused as before
    assert main(["run", str(folder), "--labels", str(whole), "--out", str(out), *stretch, "--every", "2"]) == 2
    err = _err(capsys)[0]
    assert "f2.png: names no frame" in err and "--every 2 chooses f1 and f3 around it" in err and not out.exists()
    # a CVAT export of the whole task: its masks of frames outside the stretch drawn on, left out alike
    export = tmp_path / "export"
    (export / "SegmentationClass").mkdir(parents=True)
    (export / "labelmap.txt").write_text("background:0,0,0::\nground:34,197,94::\nobstacle:255,40,40::\n")
    colours = np.array([[34, 197, 94], [255, 40, 40], [0, 0, 0]], np.uint8)
    for i, f in enumerate(frames):
        drawn = f.labels if i in (0, 2) else np.full_like(f.labels, 2)  # f0 and f2 drawn on, the rest background
        cv2.imwrite(str(export / "SegmentationClass" / f"f{i}.png"), colours[drawn][:, :, ::-1])
    c = tmp_path / "c"
    assert main(["run", str(folder), "--labels", str(export), "--out", str(c), *stretch]) == 0
    err = capsys.readouterr().err
    assert f"--labels {export}: 1 key label of frames outside those chosen left out (--start 1 --stop 5): f0.png" in err
    assert _outputs(c).keys() == _outputs(a).keys()
    # the same export run on a stretch none of its drawn masks is in: refused saying so, not that no mask names a frame
    assert main(["run", str(folder), "--labels", str(export), "--out", str(out), "--start", "3", "--stop", "5"]) == 2
    assert f"{export}: every mask drawn on names a frame outside those chosen (--start 3 --stop 5): f0.png and " \
           "f2.png" in _err(capsys)[0] and not out.exists()
    # labels named as CamVid's download names them (NAME_L.png): left out, and stepped over, alike
    camvid = _keys(tmp_path / "camvid", frames, [0, 2, 5], name="f{}_L")
    d = tmp_path / "d"
    assert main(["run", str(folder), "--labels", str(camvid), "--out", str(d), *stretch]) == 0
    assert "2 key labels of frames outside those chosen left out (--start 1 --stop 5): f0_L.png and f5_L.png" \
        in capsys.readouterr().err
    assert _outputs(d) == _outputs(a)
    assert main(["run", str(folder), "--labels", str(camvid), "--out", str(out), *stretch, "--every", "2"]) == 2
    err = _err(capsys)[0]
    assert "f2_L.png: names no frame" in err and "--every 2 chooses f1 and f3 around it" in err and not out.exists()
    # a video's frames named by index: the key label of frame 0 left out of a run from frame 2
    video = _video(tmp_path, frames)
    vkeys = _keys(tmp_path / "vk", frames, [0, 3], name="{:06d}")
    v = tmp_path / "v"
    assert main(["run", str(video), "--labels", str(vkeys), "--out", str(v), "--start", "2"]) == 0
    assert "1 key label of frames outside those chosen left out (--start 2): 000000.png" in capsys.readouterr().err
    steps = [json.loads(line) for line in (v / "steps.jsonl").read_text().splitlines()]
    assert {k for s in steps for k in s["keys"]} == {"000003"}


def test_a_key_frames_run_json_counting_more_steps_than_written_is_refused_by_export_and_view(
        tmp_path, folder, frames, capsys):
    """run.json of a run from key frames counting more steps than steps.jsonl holds: ``pcreg run`` refused it, while
    ``export`` and ``view --overlay`` read the steps there were and said nothing (a run from one label image was
    refused by all three)."""
    import json

    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(_keys(tmp_path / "keys", frames, (1, 4))), "--out", str(out)]) == 0
    state = json.loads((out / "run.json").read_text())
    state["lines"] += 100
    (out / "run.json").write_text(json.dumps(state))
    capsys.readouterr()
    said = f"pcreg: error: {out / 'steps.jsonl'}: missing or unreadable (4 steps for {state['lines']} finished frames)"
    both = (["export", str(out), "--to", str(tmp_path / "a.zip")], ["view", str(out), "--overlay", str(tmp_path / "o.mp4")])
    for args in both:  # view named run.json, which is as pcreg run wrote it
        assert main(args) == 2
        assert capsys.readouterr().err.splitlines() == [said]
    (out / "steps.jsonl").unlink()
    for args in both:
        assert main(args) == 2
        assert capsys.readouterr().err.splitlines() == [said.replace("(4 steps", "(0 steps")]
    assert not (tmp_path / "a.zip").exists() and not (tmp_path / "o.mp4").exists()
