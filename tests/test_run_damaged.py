"""A `pcreg run` output folder damaged after the run, or left by a run a full disk stopped: the resume,
`pcreg export` and `pcreg view` each end in exit 0 with the run's own output, or in one line naming the
file and exit 2, and nothing already written is lost."""

from __future__ import annotations

import builtins
import json
import os
from pathlib import Path

import numpy as np
import pytest

import pcreg.runs.files as run_files
from pcreg.cli import main
from _runs import drifting_frames, one_line_errors


def _contents(out) -> dict:
    return {p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and not p.is_symlink()}


@pytest.mark.parametrize("odd", ["folder", "loop", "device"])
def test_a_run_json_that_is_not_a_file_is_refused_not_taken_for_a_fresh_folder(tmp_path, capsys, odd):
    """A run.json that is a folder, a loop of links or a link to a device is no folder without a run: the
    resume would start over, emptying steps.jsonl (or labelling every frame again without a word)."""
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    (out / "run.json").unlink()
    if odd == "folder":
        (out / "run.json").mkdir()
    else:
        os.symlink("run.json" if odd == "loop" else os.devnull, out / "run.json")
    before = _contents(out)
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "run.json: unreadable" in err[0] and "--force" in err[0], err
    assert _contents(out) == before


def test_a_carry_whose_learned_histogram_is_not_numbers_is_refused(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    state = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**state, "done": 3}))  # as a run stopped after frame 2
    with np.load(out / "carry-0.npz") as z:
        members = {k: z[k] for k in z.files}
    assert int(members["frame"]) == 2
    np.savez(out / "carry-0.npz", **{**members, "learned": np.array(["a", "b"])})
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "carry-0.npz: missing or unreadable" in err[0], err


def test_a_full_disk_while_a_step_is_appended_names_steps_jsonl(tmp_path, capsys, monkeypatch):
    """/dev/full refuses every write with ENOSPC, as a full disk does: the run's appends to steps.jsonl go there."""
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    folder, key = drifting_frames(tmp_path / "frames")
    whole = tmp_path / "whole"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(whole)]) == 0
    out = tmp_path / "out"

    def full(path, mode="r", *args, **kwargs):  # the appends, and only they, onto the full disk
        return builtins.open("/dev/full" if Path(path) == out / "steps.jsonl" and "a" in mode else path, mode, *args, **kwargs)

    monkeypatch.setattr(run_files, "open", full, raising=False)
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"cannot write {out / 'steps.jsonl'}: No space left on device" in err[0], err
    assert err[0].endswith("(the frames labelled are kept; free space there, then rerun the same command to resume)")
    # with space again, the resume writes what the whole run wrote
    monkeypatch.undo()
    assert main(run) == 0
    assert all(_contents(out)[f"f{i}.png"] == _contents(whole)[f"f{i}.png"] for i in range(4))


@pytest.mark.parametrize("odd", ["dangling", "link", "hard link", "pipe", "folder"])
def test_a_steps_jsonl_that_is_not_a_file_is_not_written_through(tmp_path, capsys, odd):
    """A steps.jsonl that is a link in a new --out was appended to where it led (outside --out; --force emptied its
    target; a hard link's other name likewise), and a named pipe held the run: refused naming it; --force removes the
    link or pipe, not what it names."""
    folder, key = drifting_frames(tmp_path / "frames")
    out, target = tmp_path / "out", tmp_path / "elsewhere.txt"
    out.mkdir()
    if odd in ("link", "hard link"):
        target.write_text("a person's\n")
    if odd in ("dangling", "link"):
        (out / "steps.jsonl").symlink_to(target)
    elif odd == "hard link":
        os.link(target, out / "steps.jsonl")
    elif odd == "pipe":
        os.mkfifo(out / "steps.jsonl")
    else:
        (out / "steps.jsonl").mkdir()
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    for force in ([], ["--force"]):
        capsys.readouterr()
        assert main(run + force) == (0 if force and odd != "folder" else 2)
        if not force or odd == "folder":
            err = one_line_errors(capsys)
            assert len(err) == 1 and f"{out / 'steps.jsonl'}: " in err[0] and "not a file of its own" in err[0], err
            assert ("--force" in err[0]) is (odd != "folder")
            assert not (out / "run.json").exists() and not list(out.glob("*.png"))
        assert (target.read_text() == "a person's\n") if odd in ("link", "hard link") else not target.exists()
    assert (out / "steps.jsonl").is_dir() if odd == "folder" else (out / "steps.jsonl").is_file()
    if odd != "folder":
        assert not (out / "steps.jsonl").is_symlink() and main(run) == 0  # the run's own now: resumed


def test_a_run_whose_steps_jsonl_is_a_link_resumes_and_force_over_it_keeps_it_on_bad_input(tmp_path, capsys):
    """A run's own folder whose files are links (``cp -rs``, git-annex, DVC): its rerun goes on as before, and a run
    started over with --force that stops on bad input puts the earlier run back whole, its link included (the check of
    a new --out's steps.jsonl is not made in a folder that holds a run)."""
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main([*run, "--stop", "3"]) == 0
    (out / "steps.jsonl").rename(tmp_path / "kept-steps.jsonl")
    (out / "steps.jsonl").symlink_to(tmp_path / "kept-steps.jsonl")
    before = _contents(out)
    capsys.readouterr()
    assert main([*run, "--stop", "3"]) == 0 and "already done" in capsys.readouterr().out
    (folder / "f3.png").write_bytes(b"not a png")
    assert main([*run, "--force"]) == 2
    assert "as it was" in capsys.readouterr().err
    assert _contents(out) == before and (out / "steps.jsonl").is_symlink()


def test_a_part_of_a_step_after_the_counted_ones_is_not_read_by_the_readers(tmp_path, capsys):
    """A run stopped by a full disk while it appended a step leaves part of a line after the steps run.json
    counts: the review, the export and the resume read only the counted ones."""
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]
    assert main(run) == 0
    whole = _contents(out)
    state = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**state, "done": 3}))
    lines = (out / "steps.jsonl").read_bytes().splitlines(keepends=True)
    (out / "steps.jsonl").write_bytes(b"".join(lines[:2]) + lines[2][:40])
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 0
    assert main(["export", str(out), "--to", str(tmp_path / "x.zip")]) == 0
    assert main(run) == 0
    assert _contents(out)["f3.png"] == whole["f3.png"]
    assert (out / "steps.jsonl").read_bytes().count(b"\n") == 3


@pytest.mark.parametrize("field", ["predicted_iou", "iou"])
@pytest.mark.parametrize("iou", [{"road": "high"}, {"1": float("nan")}, {"1": "nan"}, {"1": 1.5}, {"1": -0.5}])
def test_a_predicted_iou_pcreg_did_not_write_is_named_by_the_review(tmp_path, capsys, iou, field):
    # a NaN (json's NaN, or "nan") was read as a number: the review page's classes of that frame then failed on
    # json.dumps(allow_nan=False), the connection dropped with a traceback on the server's terminal; the same of the
    # IoU against the truth (pcreg run --truth), which the legend shows too
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    lines = (out / "steps.jsonl").read_text().splitlines(keepends=True)
    lines[0] = json.dumps({**json.loads(lines[0]), field: iou}) + "\n"
    (out / "steps.jsonl").write_text("".join(lines))
    capsys.readouterr()
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 2
    err = one_line_errors(capsys)
    said = "a predicted_iou" if field == "predicted_iou" else "an iou"
    assert len(err) == 1 and f"steps.jsonl: the step of f1.png has {said} pcreg run did not write" in err[0], err
    assert not (tmp_path / "o.mp4").exists()


def test_the_readers_take_steps_jsonl_a_line_at_a_time_and_no_further_than_a_line_past_run_json_s_count(tmp_path):
    """An hour's run at 30 frames/s holds about 108,000 steps (190 MB): readers that held the file and every
    step parsed took about 1 GB for it."""
    from pcreg.runs.files import STEPS, parse_steps, step_lines
    from pcreg.runs.state import read_state, run_frames

    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0

    def steps_then_more():
        yield from step_lines(out)
        raise AssertionError("read past the steps run.json counts")

    assert run_frames(read_state(out), out) == (["f0.png"], [f"f{i}.png" for i in range(4)])
    steps = parse_steps(out / STEPS, steps_then_more())
    assert next(steps)["name"] == "f1.png"  # given before the rest of the file is read


@pytest.mark.parametrize("damage", ["cut", "empty"])
def test_an_overlay_of_a_run_whose_run_json_is_damaged_names_the_run_json(tmp_path, capsys, damage):
    """Not "--overlay takes a run's folder (one with a run.json)" of a folder that holds one."""
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    state = (out / "run.json").read_bytes()
    (out / "run.json").write_bytes(state[: len(state) // 2] if damage == "cut" else b"")
    capsys.readouterr()
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {out / 'run.json'}: unreadable (not a run.json that pcreg run wrote)"]
    assert not (tmp_path / "o.mp4").exists()


def test_a_full_disk_at_the_start_names_the_lock_and_leaves_no_folder(tmp_path, capsys, monkeypatch):
    """The lock on the output folder is the first thing a run writes: on a full disk the file is made (an
    inode) and its first byte refused. The line said "No space left on device", naming no file, and left the
    folder it made behind."""
    import errno

    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "new" / "out"
    real = os.pwrite

    def full(fd, data, offset):
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")) == ".pcreg.lock":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data, offset)

    monkeypatch.setattr(os, "pwrite", full)
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"cannot write {out / '.pcreg.lock'}, the lock on the output folder: No space left on device" \
        in err[0], err
    assert not (tmp_path / "new").exists()
    monkeypatch.setattr(os, "pwrite", real)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0


@pytest.mark.parametrize("truth", [False, True])
def test_a_run_json_without_its_truth_counts_is_refused_on_resume(tmp_path, capsys, truth):
    """run.json's top-level "truth" (the running error counts, None without --truth) deleted, or None where a truth
    folder is named: the resume raised KeyError / TypeError (exit 1) when it wrote its next frame. Without --truth a
    run.json without the field resumes (it says nothing the run needs)."""
    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    if truth:  # the key frame's labels as every frame's truth
        (tmp_path / "truth").mkdir()
        for frame in folder.iterdir():
            (tmp_path / "truth" / frame.name).write_bytes(key.read_bytes())
        run += ["--truth", str(tmp_path / "truth")]
    assert main([*run, "--stop", "2"]) == 0
    state = json.loads((out / "run.json").read_text())
    for damaged in ({**state, "truth": None if state["truth"] is not None else {"frames": 1}},
                    {k: v for k, v in state.items() if k != "truth"}):
        (out / "run.json").write_text(json.dumps(damaged))
        capsys.readouterr()
        if not truth and "truth" not in damaged:
            assert main(run) == 0 and json.loads((out / "run.json").read_text())["done"] == 4
            continue
        assert main(run) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and "run.json" in err[0] and "'truth'" in err[0], err
