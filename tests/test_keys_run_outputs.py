"""A run from a folder of key frames, as a person labelling hours of video meets it: the files of theirs in
``--out`` that pcreg did not write are left alone, and a video's frames past its millionth (a seventh digit in
their names) are exported in frame order."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 6, 0, width=96, height=72)


def _folder(path, frames):
    path.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(path / f"f{i}.png"), f.image[:, :, ::-1])
    return path


def _keys(path, frames, which, name="f{}"):
    path.mkdir()
    for i in which:
        cv2.imwrite(str(path / f"{name.format(i)}.png"), frames[i].labels)
    return path


def test_a_users_hidden_tmp_files_in_out_are_left_alone(tmp_path, frames):
    """open_keys removed every ``.*.tmp`` in --out, not only the temporary files of pcreg's own writes: an
    editor's or a script's hidden file there was deleted at every start and resume."""
    folder, keys, out = _folder(tmp_path / "frames", frames), _keys(tmp_path / "keys", frames, [0, 3]), tmp_path / "out"
    out.mkdir()
    mine = [out / ".notes.tmp", out / ".corrections.csv.tmp"]
    for f in mine:
        f.write_text("a person's file")
    stale = out / ".steps.jsonl.k1ll3d_1.tmp"  # what a kill while steps.jsonl was rewritten leaves
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(out)]) == 0
    stale.write_bytes(b"{")
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(out)]) == 0  # resumed: all done
    assert [f.read_text() for f in mine] == ["a person's file"] * 2
    assert not stale.exists()


def _video(path, frames):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, frames[0].image.shape[1::-1])
    for f in frames:
        writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    writer.release()
    return path


def test_a_videos_frames_past_its_millionth_are_exported_in_frame_order(tmp_path, frames, monkeypatch):
    """run_frames sorted a key-frames run's names as text, so frame 1000000 came before 999997 in the export's
    default.txt (the order CVAT lists the frames in) and in every reader's list. The video's frames are named
    from 999997 on here (the names a video of more than a million frames gives them), its key frames by CVAT's
    frame numbers."""
    from pcreg.datasets.sources import VideoFrames
    from pcreg.export import read_run

    first = 999_997

    def name(self, position):
        return f"{self.selection.index(position) + first:06d}"

    monkeypatch.setattr(VideoFrames, "name", name)
    monkeypatch.setattr(VideoFrames, "stem", name)
    video, out = _video(tmp_path / "clip.avi", frames), tmp_path / "out"
    keys = _keys(tmp_path / "keys", frames, [1, 4], name="frame_{:06d}")
    assert main(["run", str(video), "--labels", str(keys), "--out", str(out)]) == 0
    in_order = [str(first + i) for i in range(6)]
    assert [n for n in read_run(out).names] == in_order
    assert main(["export", str(out)]) == 0
    with zipfile.ZipFile(out / "export-cvat-mask.zip") as z:
        assert z.read("ImageSets/Segmentation/default.txt").decode().split() == in_order


def test_a_folder_that_holds_no_run_keeps_its_own_hidden_keys_folder(tmp_path, frames):
    """A fresh run removed every folder under ``--out/.keys`` (where a run keeps its stretches' passes) though
    ``--out`` held no run: a folder that was no run's output keeps every file in it."""
    folder, keys, out = _folder(tmp_path / "frames", frames), _keys(tmp_path / "keys", frames, [0, 3]), tmp_path / "out"
    theirs = out / ".keys" / "gpg"
    theirs.mkdir(parents=True)
    (theirs / "key.txt").write_text("a person's file")
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(out)]) == 0
    assert (theirs / "key.txt").read_text() == "a person's file"
    assert [p.name for p in (out / ".keys").iterdir()] == ["gpg"]  # the run's own passes removed when done


def test_frames_added_after_the_last_key_frame_are_labelled_when_the_run_goes_on(tmp_path):
    """The stretch after the last key frame was kept as done when the frames folder gained frames at its end (its
    fingerprint names its key frame and the options, not where it stops): the same command said "all frames already
    done" and never labelled them, while the export said the run was unfinished. It is labelled again to the new
    end, as a run over the larger folder labels it; a folder that lost frames there the same."""
    import json

    from _runs import timeless

    more = pcreg.synthetic("syn1a", 8, 0, width=96, height=72)
    folder, keys = tmp_path / "frames", _keys(tmp_path / "keys", more, [0, 3])
    _folder(folder, more[:6])
    grown, whole = tmp_path / "grown", tmp_path / "whole"
    args = ["run", str(folder), "--labels", str(keys), "--confidence"]
    assert main([*args, "--out", str(grown)]) == 0
    for i in (6, 7):
        cv2.imwrite(str(folder / f"f{i}.png"), more[i].image[:, :, ::-1])
    assert main([*args, "--out", str(grown)]) == 0
    assert main([*args, "--out", str(whole)]) == 0
    for name in [f"f{i}.png" for i in range(8)] + [f"confidence/f{i}.png" for i in (1, 2, 4, 5, 6, 7)]:
        assert (grown / name).read_bytes() == (whole / name).read_bytes(), name
    assert [timeless(line) for line in (grown / "steps.jsonl").read_text().splitlines()] == \
        [timeless(line) for line in (whole / "steps.jsonl").read_text().splitlines()]
    assert json.loads((grown / "run.json").read_text()) == json.loads((whole / "run.json").read_text())
    for i in (6, 7):
        (folder / f"f{i}.png").unlink()
    assert main([*args, "--out", str(grown)]) == 0
    assert [json.loads(line)["name"] for line in (grown / "steps.jsonl").read_text().splitlines()] == \
        ["f2.png", "f1.png", "f4.png", "f5.png"]


@pytest.mark.parametrize("gone", ["f3", "f6"])  # between two key frames; after the last
def test_a_frame_removed_from_the_folder_takes_its_labels_with_it(tmp_path, gone):
    """A key-frames run goes on without a frame removed from the folder since (its stretch labelled again), but its
    label PNG and confidence map stayed in --out, beside labels of the frames that are the run's; and --force, which
    removes what the run's steps name, no longer found them. Removed with the steps that named them."""
    from _runs import drifting_frames, key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", n=7)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 4))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out), "--confidence"]
    assert main(run) == 0
    assert (out / f"{gone}.png").is_file() and (out / "confidence" / f"{gone}.png").is_file()
    (folder / f"{gone}.png").unlink()
    assert main(run) == 0
    assert not (out / f"{gone}.png").exists() and not (out / "confidence" / f"{gone}.png").exists()
    assert sorted(p.stem for p in out.glob("*.png")) == sorted(p.stem for p in folder.glob("*.png"))
    assert main([*run, "--force"]) == 0
    assert sorted(p.stem for p in out.glob("*.png")) == sorted(p.stem for p in folder.glob("*.png"))


def test_a_run_refused_after_a_frame_was_removed_removes_nothing(tmp_path, capsys):
    """A frame removed and another labelled frame written again: the run is refused, and the removed frame's labels,
    which run.json still counts, were already gone; put back as they were, the frames were refused again ("missing,
    though run.json counts that frame labelled"). Nothing is removed before the run is taken."""
    from _runs import drifting_frames, key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", n=7)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 4))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    kept = {p: p.read_bytes() for p in (folder / "f2.png", folder / "f6.png")}
    (folder / "f6.png").unlink()
    f2 = cv2.imread(str(folder / "f2.png"))
    f2[0, 0] = 255 - f2[0, 0]
    cv2.imwrite(str(folder / "f2.png"), f2)
    capsys.readouterr()
    assert main(run) == 2
    assert "f2.png: changed since the run" in capsys.readouterr().err
    assert (out / "f6.png").is_file()
    for p, data in kept.items():
        p.write_bytes(data)
    assert main(run) == 0
