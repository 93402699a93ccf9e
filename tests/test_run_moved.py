"""A run whose project folder was moved or copied (its frames, key labels and --out together) resumes from the new
place, its inputs checked by what they hold, not by their paths; a run kept without those checks is refused as
before."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from _runs import drifting_frames, one_line_errors


def _run_json(out) -> dict:
    return json.loads((out / "run.json").read_text())


def _pngs(out) -> dict:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*.png"))}


def test_a_moved_one_key_run_resumes_and_names_its_new_places(tmp_path, capsys):
    """A run stopped at --stop 2 and moved goes on to every frame from the new place, as a run left in place does;
    a finished run run again after a move names the new places in run.json (for the review and the export)."""
    here, there, whole = tmp_path / "a", tmp_path / "b", tmp_path / "whole"
    here.mkdir()
    folder, key = drifting_frames(here / "frames", n=5)
    run = ["run", "frames", "--labels", "key.png", "--out", "out", "--confidence"]
    assert main([*[str(here / a) if a in ("frames", "key.png", "out") else a for a in run], "--stop", "2"]) == 0
    shutil.copytree(here, whole)  # the same run, left in place, goes on there
    assert main([*[str(whole / a) if a in ("frames", "key.png", "out") else a for a in run]]) == 0
    here.rename(there)
    assert main([*[str(there / a) if a in ("frames", "key.png", "out") else a for a in run]]) == 0
    assert _pngs(there / "out") == _pngs(whole / "out")
    state = _run_json(there / "out")
    assert state["done"] == 5
    assert state["run"]["folder"] == str((there / "frames").resolve()) and state["run"]["labels"] == str((there / "key.png").resolve())
    moved = tmp_path / "c"
    there.rename(moved)
    capsys.readouterr()
    assert main(["view", str(moved / "out"), "--overlay", str(tmp_path / "early.mp4")]) == 2  # not run again yet
    said = capsys.readouterr().err
    assert f"the run's folder {(there / 'frames').resolve()} is gone" in said
    assert f"the same pcreg run with the folder's new path and --out {moved / 'out'} names the new places" in said
    assert main([*[str(moved / a) if a in ("frames", "key.png", "out") else a for a in run]]) == 0
    assert "all 5 frames already done" in capsys.readouterr().out
    assert _run_json(moved / "out")["run"]["folder"] == str((moved / "frames").resolve())
    assert main(["export", str(moved / "out"), "--to", str(tmp_path / "export.zip")]) == 0


def test_a_copied_run_whose_frame_changed_or_that_kept_no_digest_of_its_labels_is_refused(tmp_path, capsys):
    """Moved, the inputs are checked by what they hold: a frame written again since is named. A run that kept no
    digest of its key labels (begun before it was kept) cannot be checked so: its new places are other options."""
    here = tmp_path / "a"
    here.mkdir()
    folder, key = drifting_frames(here / "frames", n=4)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(here / "out"), "--stop", "2"]) == 0
    changed = tmp_path / "b"
    shutil.copytree(here, changed)
    img = cv2.imread(str(changed / "frames" / "f1.png"))
    cv2.imwrite(str(changed / "frames" / "f1.png"), 255 - img)
    capsys.readouterr()
    assert main(["run", str(changed / "frames"), "--labels", str(changed / "key.png"), "--out", str(changed / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"holds a run over {(here / 'frames').resolve()}, not over these inputs: give another --out" in err[0], err
    assert "(what is here is not what it read: " in err[0] and "f1.png: changed since the run" in err[0], err
    older = tmp_path / "c"
    shutil.copytree(here, older)
    state = _run_json(older / "out")
    del state["key_labels"]
    (older / "out" / "run.json").write_text(json.dumps(state))
    assert main(["run", str(older / "frames"), "--labels", str(older / "key.png"), "--out", str(older / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "holds a run with other options (folder:" in err[0], err
    here.rename(tmp_path / "gone")  # the review of that run said a run from the new place would go on: refused so
    assert main(["view", str(older / "out"), "--overlay", str(tmp_path / "o.mp4")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"the run's folder {(here / 'frames').resolve()} is gone" in err[0], err
    assert "put it back there: this run was begun by an earlier pcreg" in err[0] and "new path" not in err[0], err


def test_a_moved_key_frames_run_resumes_from_its_new_place(tmp_path, capsys):
    """A run from a folder of key frames, moved with its frames and key labels: done, and named in its new places."""
    frames = pcreg.synthetic("syn1a", 5, 0, width=96, height=72)
    here = tmp_path / "a"
    (here / "frames").mkdir(parents=True)
    (here / "keys").mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(here / "frames" / f"f{i}.png"), np.ascontiguousarray(f.image[:, :, ::-1]))
    for i in (0, 4):
        cv2.imwrite(str(here / "keys" / f"f{i}.png"), frames[i].labels)
    assert main(["run", str(here / "frames"), "--labels", str(here / "keys"), "--out", str(here / "out")]) == 0
    before = _pngs(here / "out")
    there = tmp_path / "b"
    here.rename(there)
    capsys.readouterr()
    assert main(["run", str(there / "frames"), "--labels", str(there / "keys"), "--out", str(there / "out")]) == 0
    assert "already done" in capsys.readouterr().out
    assert _pngs(there / "out") == before
    assert _run_json(there / "out")["run"]["labels"] == str((there / "keys").resolve())


@pytest.mark.parametrize("kind", ["folder", "video"])
def test_an_input_of_another_kind_in_the_same_place_is_still_other_options(tmp_path, capsys, kind):
    """Only the places of the same inputs move: frames read from a video where a folder was (or the other way) are
    other options, named."""
    frames = pcreg.synthetic("syn1a", 4, 0, width=96, height=72)
    (tmp_path / "frames").mkdir()
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (96, 72))
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / "frames" / f"{i:06d}.png"), np.ascontiguousarray(f.image[:, :, ::-1]))
        writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    writer.release()
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    first, second = (tmp_path / "frames", video) if kind == "folder" else (video, tmp_path / "frames")
    out = tmp_path / "out"
    assert main(["run", str(first), "--labels", str(tmp_path / "key.png"), "--out", str(out), "--stop", "2"]) == 0
    capsys.readouterr()
    assert main(["run", str(second), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "holds a run with other options" in err[0], err


def test_another_projects_inputs_with_this_out_name_both_places_and_another_out(tmp_path, capsys):
    """Two projects laid out alike (frames/, key.png), the second's inputs given with the first's --out by mistake:
    taken for a move, the checks found the key labels and frames not the run's, and said they had "changed since the
    run began", --force the only way named (which removes the first project's labels). The places then and now come
    first, and another --out beside --force."""
    first, second = tmp_path / "a", tmp_path / "b"
    first.mkdir()
    second.mkdir()
    drifting_frames(first / "frames", n=4, seed=0)
    drifting_frames(second / "frames", n=4, seed=1)
    cv2.imwrite(str(second / "key.png"), 1 - cv2.imread(str(second / "key.png"), cv2.IMREAD_UNCHANGED))
    out = first / "out"
    assert main(["run", str(first / "frames"), "--labels", str(first / "key.png"), "--out", str(out), "--stop", "2"]) == 0
    before = _pngs(out)
    capsys.readouterr()
    for labels in (second / "key.png", first / "key.png"):  # other key labels; the same key labels, other frames
        assert main(["run", str(second / "frames"), "--labels", str(labels), "--out", str(out)]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{out} holds a run over {first.resolve()}/" in err[0], err
        assert ", not over these inputs: give another --out, or --force to start over (what is here is not what it read: " in err[0]
    assert _pngs(out) == before
