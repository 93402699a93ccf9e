"""Rounds of labelling, as a person labels a clip: run with ``--suggest``, label the frames suggested, run again.
The suggestions of an earlier round were left for the review to offer as current after a round that changed the
key frames (one of them a key frame now); a closed stdout (``| head -1``) stopped the command before it wrote
suggest.txt; the run's own label PNG of a ``--mapping camvid`` run was refused as a key frame's labels; and the review
of a run stopped between its stretches showed fewer frames than the export, without a word."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.export import read_labels, read_run
from pcreg.review import read_review
from test_keyframes_run import frames_folder, six_frames


@pytest.fixture()
def clip(tmp_path):
    """The six synthetic frames of the runs from key frames, and the folder they are written to."""
    frames = six_frames()
    return frames, frames_folder(tmp_path / "frames", frames)


def _keys(path, frames, which, lut=None):
    path.mkdir(exist_ok=True)
    for i in which:
        cv2.imwrite(str(path / f"f{i}.png"), frames[i].labels if lut is None else lut[frames[i].labels])
    return path


def test_a_round_that_changes_the_key_frames_leaves_no_suggestions_of_the_round_before(tmp_path, clip, capsys):
    frames, folder = clip
    keys, out = _keys(tmp_path / "keys", frames, [0]), tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main([*run, "--suggest", "2"]) == 0
    first = [line.split("\t")[0] for line in (out / "suggest.txt").read_text().splitlines()]
    assert len(first) == 2 and [t for t, _ in read_review(out).suggested]
    _keys(keys, frames, [int(first[0][1:])])  # the first frame suggested, labelled
    assert main(run) == 0  # no --suggest this round: the suggestions of the last are not this run's
    assert not (out / "suggest.txt").exists() and read_review(out).suggested == ()
    assert main([*run, "--suggest", "2"]) == 0
    now = [line.split("\t")[0] for line in (out / "suggest.txt").read_text().splitlines()]
    assert first[0] not in now and len(now) == 2
    # a suggest.txt that names a key frame (written by hand, or by an earlier pcreg): the review does not offer it
    (out / "suggest.txt").write_text(f"{first[0]}\t9.99\n{now[0]}\t1.00\n")
    review = read_review(out)
    assert [review.names[t] for t, _ in review.suggested] == [f"{now[0]}.png"]
    capsys.readouterr()


def test_suggest_txt_is_written_though_stdout_is_closed_before_the_run_ends(tmp_path, clip):
    frames, folder = clip
    keys, out = _keys(tmp_path / "keys", frames, [0, 3]), tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "pcreg", "run", str(folder), "--labels", str(keys), "--out", str(out),
                             "--suggest", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # as `| head -1` does once it has its line: every line the command prints meets a closed pipe
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=600) in (0, 141), err
    assert "Traceback" not in err, err
    lines = (out / "suggest.txt").read_text().splitlines()
    assert len(lines) == 2 and all(line.split("\t")[0] in {"f1", "f2", "f4", "f5"} for line in lines)


def test_a_frame_of_a_mapping_camvid_run_is_a_key_frame_of_the_next_round_as_it_is(tmp_path, clip):
    """`--mapping camvid` reads CamVid's ids as ground and obstacle, and writes its labels in ``lagr``'s palette: one
    of them, given as a key frame's labels (a person correcting the frame the run predicted), was read through
    ``camvid11``'s palette and refused ("another class table?")."""
    frames, folder = clip
    camvid = np.full(256, 11, np.uint8)
    camvid[[0, 1]] = [3, 1]  # ground as road, obstacle as building, unknown as void
    keys, out = _keys(tmp_path / "keys", frames, [0], camvid), tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out), "--mapping", "camvid"]
    assert main(run) == 0
    predicted = read_labels(out / "f3.png")
    (keys / "f3.png").write_bytes((out / "f3.png").read_bytes())  # taken as it is, as a person would correct it
    assert main(run) == 0
    np.testing.assert_array_equal(read_labels(out / "f3.png"), predicted)
    rgb = cv2.imread(str(out / "f4.png"), cv2.IMREAD_COLOR)  # another, saved again in RGB by an editor
    cv2.imwrite(str(keys / "f4.png"), rgb)
    predicted = read_labels(out / "f4.png")
    assert main(run) == 0
    np.testing.assert_array_equal(read_labels(out / "f4.png"), predicted)
    assert json.loads((out / "run.json").read_text())["run"]["mapping"] == "camvid"


def test_the_review_of_a_run_stopped_between_its_stretches_says_which_frames_it_does_not_show(tmp_path, clip, monkeypatch, capsys):
    frames, folder = clip
    from pcreg.runs.run import Run

    keys, out = _keys(tmp_path / "keys", frames, [0, 2, 5]), tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    corrected = frames[0].labels.copy()
    corrected[:10] = 1
    cv2.imwrite(str(keys / "f0.png"), corrected)  # the first key frame corrected: its stretch again, the other kept
    real, commits = Run.commit, []

    def stop(self):
        commits.append(1)
        if len(commits) == 2:
            raise KeyboardInterrupt
        real(self)

    monkeypatch.setattr(Run, "commit", stop)
    assert main(run) == 130
    monkeypatch.undo()
    shown, exported = len(read_review(out).names), len(read_run(out).names)
    assert shown < exported  # f1 labelled again is not yet; f2 to f5, kept, are
    capsys.readouterr()
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 0
    err = capsys.readouterr().err
    assert (f"the review shows the {shown} frame(s) labelled from the first frame on, up to the first not labelled yet, "
            f"not the {exported - shown} labelled after it (pcreg export has them all)") in err, err
    assert f"{out} holds {exported} of the 6 frames the run chose: it is unfinished" in err, err


def test_a_round_without_the_truth_of_the_last_is_refused_as_other_options_not_as_inputs_moved(tmp_path, clip, capsys):
    """Leaving ``--truth`` out of a round was refused as a run "over" the truth folder, "not over these inputs", its
    remedy said twice: the truth is an option left out, not an input moved."""
    frames, folder = clip
    keys, truth, out = _keys(tmp_path / "keys", frames, [0]), _keys(tmp_path / "truth", frames, range(6)), tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main([*run, "--truth", str(truth)]) == 0
    capsys.readouterr()
    assert main(run) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {out} holds a run with other options (truth: '"), err
    assert err[0].endswith(" then, None now); use --force to start over or another --out"), err
    moved = tmp_path / "moved"  # the frames moved, and an option changed: the remedy said once
    folder.rename(moved)
    assert main(["run", str(moved), "--labels", str(keys), "--out", str(out), "--truth", str(truth), "--weight", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].count("another --out") == 1 and "weight: 2.0 then, 3.0 now" in err[0], err


@pytest.mark.parametrize("labels", ["folder of keys", "one key frame"])
def test_a_first_run_with_suggest_does_not_write_over_a_persons_suggest_txt(tmp_path, clip, capsys, labels):
    """A folder of no run holding a suggest.txt of a person's: a first run with ``--suggest`` wrote over it (a first
    run without it keeps it). Refused, naming it, before anything is written; ``--force`` writes over it."""
    frames, folder = clip
    keys, out = _keys(tmp_path / "keys", frames, [0]), tmp_path / "out"
    out.mkdir()
    (out / "suggest.txt").write_text("mine\n")
    given = keys if labels == "folder of keys" else keys / "f0.png"
    run = ["run", str(folder), "--labels", str(given), "--out", str(out), "--suggest", "1"]
    capsys.readouterr()
    assert main(run) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {out / 'suggest.txt'}: this run would write over it"), err
    assert sorted(p.name for p in out.iterdir() if p.name != ".pcreg.lock") == ["suggest.txt"] and (out / "suggest.txt").read_text() == "mine\n"
    assert main(run[:-2]) == 0 and (out / "suggest.txt").read_text() == "mine\n"  # without --suggest: kept
    assert main([*run, "--force"]) == 0 and (out / "suggest.txt").read_text() != "mine\n"
