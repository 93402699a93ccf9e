"""`pcreg run` on hostile frames and on output folders that are not as it left them: every case ends in
exit 0 (frames it can label) or one line and exit 2, never an internal error."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from pcreg.classes import LAGR, encode_label_png
from pcreg.cli import main
from pcreg.errors import InputError
from _runs import drifting_frames, key_frames_of, one_line_errors
from pcreg.export import read_labels


@pytest.mark.parametrize("shape", [(8, 8), (8, 1000), (20, 1200), (12, 16)])
def test_frames_too_small_for_dis_are_labelled_without_the_second_motion(tmp_path, shape, capsys):
    folder, key = drifting_frames(tmp_path / "frames", shape)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]) == 0
    for i in range(1, 4):
        assert read_labels(out / f"f{i}.png").shape == shape
    # DIS itself refuses them in one line, where OpenCV raises or crashes the process
    from pcreg.registration.flow import DIS_MIN_SIDE, dis_field

    img = np.zeros((*shape, 3), np.uint8)
    with pytest.raises(InputError, match=f"too small for DIS optical flow \\(at least {DIS_MIN_SIDE} px"):
        dis_field(img, img, preset="ultrafast")


@pytest.mark.parametrize("held", ["steps.jsonl"])
def test_a_persons_steps_jsonl_in_a_folder_of_no_run_is_refused_not_written_over(tmp_path, capsys, held):
    """A file named steps.jsonl of a person's in a new --out was replaced by the run's steps without a word. No run
    leaves it with lines and no run.json (it writes it empty, then its state), so it is refused, kept; --force
    writes over it."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    out.mkdir()
    (out / held).write_text('{"my": "notes"}\n')
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{out / held}: this run would write over it" in err[0] and "--force" in err[0], err
    assert (out / held).read_text() == '{"my": "notes"}\n' and [p.name for p in out.iterdir() if p.name != ".pcreg.lock"] == [held]
    assert main([*run, "--force"]) == 0
    assert not (out / held).exists() or '"my"' not in (out / held).read_text()
    assert (out / "run.json").is_file()


def test_an_output_folder_whose_files_are_in_the_way_is_refused_in_one_line(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    out.mkdir()
    (out / "confidence").write_text("a file where the confidence folder goes")
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "File exists" in err[0] and "confidence" in err[0]
    assert (out / "confidence").read_text().startswith("a file")  # left as it was


@pytest.mark.parametrize("where", ["f2.png", "confidence/f3.png"])
def test_a_folder_of_no_run_holding_a_file_the_run_would_write_is_refused(tmp_path, capsys, where):
    """A person's own corrected label map f2.png (or a confidence map) in a folder given as --out, with no run of
    pcreg's there, was written over without a word. Refused naming it, the file kept; --force writes over it, and a
    run killed at its start (steps.jsonl written first) resumes."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    (out / "confidence").mkdir(parents=True)
    (out / "notes.png").write_bytes(b"a picture of no frame's name")  # no frame's: left alone, not in the way
    (out / where).write_bytes(b"a person's own")
    run = ["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{out / where}: this run would write over it" in err[0] and "--force" in err[0], err
    assert (out / where).read_bytes() == b"a person's own" and not (out / "run.json").exists()
    (out / "steps.jsonl").write_text('{"frame": 1}\n')  # steps of a run whose run.json is gone: no run killed at its start
    assert main(run) == 2 and (out / where).read_bytes() == b"a person's own"
    assert f"{out / where}: this run would write over it" in one_line_errors(capsys)[0]
    (out / "steps.jsonl").unlink()
    assert main([*run, "--force"]) == 0
    assert (out / where).read_bytes() != b"a person's own" and (out / "notes.png").exists()
    (out / "run.json").unlink()  # as a run killed after its first writes, before its state
    (out / "steps.jsonl").write_bytes(b"")
    capsys.readouterr()
    assert main(run) == 0


CORRUPT_STATES = {
    "a list": lambda s: [s], "null": lambda s: None, "a string": lambda s: "run",
    "no done": lambda s: {k: v for k, v in s.items() if k != "done"}, "done text": lambda s: {**s, "done": "abc"},
    "done infinite": lambda s: {**s, "done": float("inf")}, "done a list": lambda s: {**s, "done": [2]},
    "done zero": lambda s: {**s, "done": 0}, "fallbacks negative": lambda s: {**s, "fallbacks": -1},
    "truth not counts": lambda s: {**s, "truth": {"frames": "x"}}, "key_labels a number": lambda s: {**s, "key_labels": 3},
    "an empty object": lambda s: {}, "no run": lambda s: {k: v for k, v in s.items() if k != "run"},
    "run a list": lambda s: {**s, "run": [s["run"]]},  # said as not pcreg's, not as a run of other options
}


@pytest.mark.parametrize("change", sorted(CORRUPT_STATES))
def test_a_run_json_pcreg_did_not_write_is_refused_by_name(tmp_path, capsys, change):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    state = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps(CORRUPT_STATES[change](state)))
    capsys.readouterr()
    assert main([*run, "--suggest", "1"]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "run.json" in err[0] and "--force" in err[0]
    assert main([*run, "--force"]) == 0  # and --force starts over


@pytest.mark.parametrize("line", [b"garbage", b"\xff\xfe", b"null", b"[1, 2]", b'{"frame": "3"}',
                                  b'{"frame": 1, "predicted_error": "high"}', b'{"frame": 1, "predicted_error": 1e999}',
                                  b"[" * 100_000 + b"]" * 100_000])
def test_a_steps_line_pcreg_did_not_write_is_refused_by_line(tmp_path, capsys, line):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out), "--suggest", "1"]
    assert main(run) == 0
    lines = (out / "steps.jsonl").read_bytes().splitlines(keepends=True)
    (out / "steps.jsonl").write_bytes(b"".join(lines[:1]) + line + b"\n" + b"".join(lines[2:]))
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "steps.jsonl: line 2 is not a step pcreg run wrote" in err[0]


def test_json_nested_beyond_the_recursion_limit_is_bad_input(tmp_path, capsys):
    """json raises RecursionError for a document nested deeper than Python's recursion limit: a class table,
    a run.json resumed and a run.json exported are each refused in one line, exit 2, not a bug."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    nested = "[" * 100_000 + "]" * 100_000
    (tmp_path / "table.json").write_text(nested)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main([*run, "--classes", str(tmp_path / "table.json")]) == 2
    assert "table.json" in one_line_errors(capsys)[-1]
    assert main(run) == 0
    (out / "run.json").write_text(nested)
    capsys.readouterr()
    for args in ([*run, "--suggest", "1"], ["export", str(out)]):
        assert main(args) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and "run.json" in err[0], err


def test_a_key_frames_run_with_a_damaged_state_or_step_is_refused(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    keys = key_frames_of(key, tmp_path / "keys")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    good = (out / "run.json").read_text()
    for change in ({"stretches": {}}, {"cursor": 3}, {"lines": -2}, {"keys": []}):
        (out / "run.json").write_text(json.dumps({**json.loads(good), **change}))
        capsys.readouterr()
        assert main(run) == 2
        assert f"its {next(iter(change))!r} is not as pcreg run writes it" in one_line_errors(capsys)[-1]
    (out / "run.json").write_text(good)
    steps = (out / "steps.jsonl").read_bytes().splitlines(keepends=True)
    (out / "steps.jsonl").write_bytes(b"[]\n" + b"".join(steps[1:]))
    capsys.readouterr()
    assert main(run) == 2
    assert "steps.jsonl: line 1 is not a step pcreg run wrote" in one_line_errors(capsys)[-1]


def test_a_full_disk_or_a_folder_in_the_way_is_bad_input_not_a_bug(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    out.mkdir()
    (out / "steps.jsonl").mkdir()  # a folder where the run writes its steps
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "steps.jsonl" in err[0] and "internal error" not in err[0]


def test_the_program_runs_with_an_ascii_terminal_and_a_closed_stdout(tmp_path):
    import os
    import subprocess
    import sys

    folder, key = drifting_frames(tmp_path / "кадры", (96, 128), n=2)
    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    out = tmp_path / "выход"
    p = subprocess.run([sys.executable, "-m", "pcreg", "run", str(folder), "--labels", str(key), "--out", str(out)],
                       capture_output=True, env=env)
    assert p.returncode == 0, p.stderr
    assert b"\\u0432\\u044b" in p.stdout and (out / "f1.png").is_file()  # the path escaped, not a failure
    # stdout closed by the caller: a command that prints only progress succeeds; --json, whose result would go
    # nowhere (it exited 0 with the result lost), is refused before any work
    command = [sys.executable, "-m", "pcreg", "register", str(folder / "f0.png"), str(folder / "f1.png")]
    p = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=lambda: os.close(1))
    assert p.returncode in (0, 3) and b"internal error" not in p.stderr, p.stderr
    p = subprocess.run([*command, "--json"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                       preexec_fn=lambda: os.close(1))
    assert p.returncode == 2 and p.stderr.decode().startswith(
        "pcreg: error: --json prints to standard output, which is closed"), p.stderr
    out = tmp_path / "result.json"
    p = subprocess.run([*command, "--json"], stdout=out.open("w"), stderr=subprocess.PIPE)
    assert p.returncode in (0, 3) and json.loads(out.read_text())["ok"] is (p.returncode == 0), p.stderr
    if os.path.exists("/dev/full"):  # a stdout on a full disk: the line said "No space left on device", naming nothing
        with open("/dev/full", "w") as full:
            p = subprocess.run([*command, "--json"], stdout=full, stderr=subprocess.PIPE)
        assert p.returncode == 2 and p.stderr.decode().splitlines() == [
            "pcreg: error: No space left on device: standard output"], p.stderr
        with open("/dev/full", "w") as full:  # the table, not --json: the same line (it named nothing)
            p = subprocess.run(command, stdout=full, stderr=subprocess.PIPE)
        assert p.returncode in (2, 3) and p.stderr.decode().splitlines()[-1] == (
            "pcreg: error: No space left on device: standard output"), p.stderr
        for asked in (["--help"], ["run", "--help"], ["--version"]):  # argparse dropped the failed write: exit 0
            with open("/dev/full", "w") as full:
                p = subprocess.run([sys.executable, "-m", "pcreg", *asked], stdout=full, stderr=subprocess.PIPE)
            assert p.returncode == 2 and p.stderr.decode().splitlines() == [
                "pcreg: error: No space left on device: standard output"], (asked, p.stderr)
        cv2.imwrite(str(tmp_path / "flat.png"), np.full((96, 128, 3), 128, np.uint8))  # nothing to register on
        with open("/dev/full", "w") as full:  # refused, its JSON to a full disk: it ended in a traceback
            p = subprocess.run([*command[:-1], str(tmp_path / "flat.png"), "--json"], stdout=full,
                               stderr=subprocess.PIPE)
        said = p.stderr.decode().splitlines()
        assert p.returncode == 3 and len(said) == 2 and said[0].startswith("pcreg: registration refused: "), said
        assert said[1] == "pcreg: error: No space left on device: standard output"
        # stderr on a full disk: the line is lost, the exit status still says how the command ended (a bad input's 2
        # was 1, a bug, as Python reported the failed write of its line)
        for args, code in ((["run", str(folder), "--labels", str(tmp_path / "no such key.png"), "--out", str(tmp_path / "o")], 2),
                           ([*command[3:-1], str(tmp_path / "flat.png")], 3), ([*command[3:], "--json"], 0)):
            with open("/dev/full", "w") as full:
                p = subprocess.run([sys.executable, "-m", "pcreg", *args], stdout=subprocess.PIPE, stderr=full)
            assert p.returncode == code, (args, p.returncode)


def test_a_rerun_with_other_key_labels_or_fewer_frames_is_refused_and_force_starts_clean(tmp_path, capsys):
    """A run from one label image is not continued from key labels edited since it began, nor over a frames
    folder that lost frames (it was an internal error); ``--force`` starts over without the confidence maps
    and suggestions the earlier run wrote (the review and the export read them)."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence", "--suggest", "1"]) == 0
    assert (out / "confidence").is_dir() and (out / "suggest.txt").is_file()
    written = {p.name: p.read_bytes() for p in out.glob("*.png")}
    cv2.imwrite(str(key), 1 - cv2.imread(str(key), cv2.IMREAD_UNCHANGED))
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence", "--suggest", "1"]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "key.png: the key frame's labels changed since the run" in err[0], err
    assert {p.name: p.read_bytes() for p in out.glob("*.png")} == written
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--force"]) == 0
    assert not (out / "confidence").exists() and not (out / "suggest.txt").exists()
    assert read_labels(out / "f0.png")[0, 0] == 1  # the new key labels
    (folder / "f4.png").unlink()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "counts 5 frames labelled" in err[0] and "holds 4" in err[0], err


def test_a_run_started_over_over_fewer_frames_leaves_no_label_png_of_the_earlier_run(tmp_path):
    """``--force`` over fewer frames (``--every 2``, ``--stop``) left the earlier run's label PNGs of the frames it no
    longer labels beside its own: ``OUT/*.png`` mixed two runs. The label PNGs the earlier run's run.json and
    steps.jsonl name are removed, from one label image and from key frames alike; a file it did not write is kept,
    and so are the key labels when they sit in --out."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 4))
    for labels, out, fewer, left in ((key, tmp_path / "one", ["--every", "2"], {"f0", "f2", "f4"}),
                                     (keys, tmp_path / "keyed", ["--stop", "3"], {"f0", "f1", "f2"})):
        assert main(["run", str(folder), "--labels", str(labels), "--out", str(out)]) == 0
        assert {p.stem for p in out.glob("*.png")} == {f"f{i}" for i in range(6)}
        (out / "mine.png").write_bytes(b"not a run's")
        assert main(["run", str(folder), "--labels", str(labels), "--out", str(out), *fewer, "--force"]) == 0
        assert {p.stem for p in out.glob("*.png")} == left | {"mine"}
    inside = folder / "run"  # --out in the frames' folder (or the truth's): every file in it is below an input
    assert main(["run", str(folder), "--labels", str(key), "--out", str(inside)]) == 0
    assert main(["run", str(folder), "--labels", str(key), "--out", str(inside), "--every", "2", "--force"]) == 0
    assert {p.stem for p in inside.glob("*.png")} == {"f0", "f2", "f4"}
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "one"), "--force"]) == 0
    shutil.copy(key, tmp_path / "one" / "f5.png")  # the key labels in --out, named as a frame the run labelled
    assert main(["run", str(folder), "--labels", str(tmp_path / "one" / "f5.png"), "--out", str(tmp_path / "one"),
                 "--every", "2", "--force"]) == 0
    assert (tmp_path / "one" / "f5.png").read_bytes() == key.read_bytes()


def test_options_a_run_would_not_use_are_refused_and_advice_is_in_its_own_options(tmp_path, capsys):
    """``--backend`` and ``--init`` are the global registration's: ``--model dense`` and ``flow`` took them without
    effect (the same labels) and then refused a run again without them as "other options". Refused, named; the
    open3d backend's refusal of an affine model names ``--backend reference``; a scale too small for a global model
    names no ``--levels``, which pcreg run does not take."""
    folder, key = drifting_frames(tmp_path / "frames", (120, 160), n=3)
    for model, given, said in (("dense", ["--backend", "open3d"], "--backend open3d: "),
                               ("flow", ["--init", "auto", "--backend", "open3d"], "--backend open3d, --init auto: "),
                               ("affine", ["--backend", "open3d"], "(--backend reference)"),
                               ("rigid", ["--scale", "0.1"], "scale 0.1 works at 16x12")):
        out = tmp_path / model
        assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--model", model, *given]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and said in err[0] and "--levels" not in err[0] and not out.exists(), err
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "s"), "--model", "similarity",
                 "--backend", "open3d", "--init", "auto"]) == 0
    # a run begun when dense took them (its run.json names them) goes on without them, and gains the defaults
    out = tmp_path / "begun"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--stop", "2"]) == 0
    state = json.loads((out / "run.json").read_text())
    state["run"].update(backend="open3d", init="auto")
    (out / "run.json").write_text(json.dumps(state))
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["run"]["backend"] == "reference"
    assert {p.stem for p in out.glob("*.png")} == {"f0", "f1", "f2"}


def test_a_frame_added_among_those_a_run_labelled_is_named_not_taken_for_a_lost_label(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    written = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    shutil.copy(folder / "f1.png", folder / "f1a.png")  # between f1 and f2 in name order
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "labelled f2.png as frame 2" in err[0] and "now holds as f1a.png" in err[0], err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == written


def test_output_paths_that_are_loops_of_symbolic_links_are_bad_input(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(loop)]) == 2
    assert "loop: a loop of symbolic links" in one_line_errors(capsys)[0]
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    assert main(["export", str(out), "--to", str(loop)]) == 2
    assert "a symbolic link to nothing" in one_line_errors(capsys)[0]
    assert main(["export", str(out), "--to", str(loop / "x.zip")]) == 2
    assert "a loop of symbolic links" in one_line_errors(capsys)[0]
    dangling = tmp_path / "gone.zip"
    dangling.symlink_to(tmp_path / "nowhere.zip")
    assert main(["export", str(out), "--to", str(dangling)]) == 2 and not (tmp_path / "nowhere.zip").exists()
    assert main(["export", str(out), "--to", str(dangling), "--force"]) == 0


def test_an_interrupted_recorded_run_says_how_to_resume_and_that_resumes(tmp_path, capsys, monkeypatch):
    """Rerunning the very command of a run interrupted while recording is refused (the recording exists),
    so the interrupt says to give another recording file; that rerun finishes the run."""
    from _runs import kill_before_commit

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    out = tmp_path / "out"
    kill_before_commit(monkeypatch, 2)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--record", str(tmp_path / "a.rrd")]) == 130
    said = capsys.readouterr().err
    assert "(the frames labelled are kept; rerun the same command with another --record file" in said, said
    monkeypatch.undo()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--record", str(tmp_path / "b.rrd")]) == 0
    assert json.loads((out / "run.json").read_text())["done"] == 5


@pytest.mark.parametrize("where", ["frames", "keys"])
@pytest.mark.parametrize("odd", ["link to nothing", "folder"])
def test_an_entry_named_as_a_frame_or_key_that_is_not_a_file_is_refused_not_skipped(tmp_path, capsys, where, odd):
    """A dangling link or a folder named like a frame (or key labels) was left out without a word: the
    run labelled a frame fewer (or had a key frame fewer)."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    keys = tmp_path / "keys"
    keys.mkdir()
    (keys / "f0.png").write_bytes(key.read_bytes())
    entry = keys / "f2.png" if where == "keys" else folder / "f9.png"
    if odd == "folder":
        entry.mkdir()
    else:
        entry.symlink_to(tmp_path / "nowhere.png")
    labels = keys if where == "keys" else key
    assert main(["run", str(folder), "--labels", str(labels), "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{entry.name}: named as" in err[0] and "not a file that can be read" in err[0], err


def test_a_new_run_keeps_what_it_did_not_write_and_never_removes_its_own_inputs(tmp_path, capsys):
    """A first run into a folder that holds a ``confidence/`` and a ``suggest.txt`` of the user's removed them (a
    run started over forgets those of an earlier run); and a run whose frames lie in ``OUT/confidence/``
    removed its own frames when started over."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    out = tmp_path / "out"
    (out / "confidence").mkdir(parents=True)
    (out / "confidence" / "notes.txt").write_text("mine")
    (out / "suggest.txt").write_text("mine too")
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    assert (out / "confidence" / "notes.txt").read_text() == "mine" and (out / "suggest.txt").read_text() == "mine too"
    inside = tmp_path / "inside"
    shutil.copytree(folder, inside / "confidence")
    assert main(["run", str(inside / "confidence"), "--labels", str(key), "--out", str(inside)]) == 0
    assert main(["run", str(inside / "confidence"), "--labels", str(key), "--out", str(inside), "--force"]) == 2
    assert "an input of this run" in one_line_errors(capsys)[0]
    assert sorted(p.name for p in (inside / "confidence").iterdir()) == sorted(p.name for p in folder.iterdir())


def test_key_labels_in_the_folder_the_run_writes_its_confidence_maps_in_are_refused(tmp_path, capsys):
    """``--labels OUT/confidence --confidence``: the confidence maps were written among the key labels, and every
    later run (``--force`` too) refused them as labels until removed by hand."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    (tmp_path / "out").mkdir()
    keys = key_frames_of(key, tmp_path / "out" / "confidence", positions=(0, 3))
    before = sorted(p.name for p in keys.iterdir())
    assert main(["run", str(folder), "--labels", str(keys), "--confidence", "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"lies in {tmp_path / 'out' / 'confidence'}, where this run writes its confidence maps" in err[0]
    assert sorted(p.name for p in keys.iterdir()) == before and sorted(p.name for p in (tmp_path / "out").iterdir()) == ["confidence"]
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out")]) == 0  # no maps: no clash


def test_hidden_files_are_no_frames_and_numbers_of_different_widths_are_refused(tmp_path, capsys):
    """A hidden thumbnail (``.thumb.png``) sorted first and became the key frame; ``f8 ... f13`` were read as
    ``f10 f11 f12 f13 f8 f9``, the labels drawn on f8 given to f10."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    shutil.copy(folder / "f3.png", folder / ".thumb.png")
    (folder / "._f0.png").write_bytes(b"\0\5\26\7")  # what macOS leaves beside a file on a foreign disk
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["key_frame"] == "f0.png"
    wide = tmp_path / "wide"
    wide.mkdir()
    for i in range(4):
        shutil.copy(folder / f"f{i}.png", wide / f"f{i + 8}.png")
    assert main(["run", str(wide), "--labels", str(key), "--out", str(tmp_path / "out2")]) == 2
    assert "numbered with different widths (f11.png sorts before f8.png" in one_line_errors(capsys)[0]
    stamps = tmp_path / "stamps"  # time stamps whose fractions differ in width are in order by name
    stamps.mkdir()
    for i, name in enumerate(["1612345678.15", "1612345678.2", "1612345678.25", "1612345679.1"]):
        shutil.copy(folder / f"f{i}.png", stamps / f"{name}.png")
    assert main(["run", str(stamps), "--labels", str(key), "--out", str(tmp_path / "out3")]) == 0


def test_out_in_the_images_folder_frames_would_be_read_from_is_refused_before_anything_is_written(tmp_path, capsys):
    """``--out FRAMES/images`` for frames read from FRAMES itself: the run wrote its label PNGs there, and the next
    run read them as the frames (a folder's ``images/`` sub-folder is read in its place once there is one)."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    out = folder / "images"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "images/ sub-folder of the frames' folder" in err[0], err
    assert not out.exists()
    for keys in (key, key_frames_of(key, tmp_path / "keys", (0, 3))):  # a folder of key frames' labels too
        assert main(["run", str(folder), "--labels", str(keys), "--out", str(out / ".")]) == 2
        assert "images/ sub-folder" in one_line_errors(capsys)[0]
        assert not out.exists()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(folder / "labelled")]) == 0


def test_a_key_frame_of_one_class_is_named_before_anything_is_written(tmp_path, capsys):
    """The classifier's "training labels hold only one class" named no file, and in a run from a folder of key
    frames came after the first stretch was labelled (a stretch's classifier is fitted on its key frames: f4
    alone for the frame after it)."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    cv2.imwrite(str(tmp_path / "ground.png"), np.zeros((48, 64), np.uint8))
    assert main(["run", str(folder), "--labels", str(tmp_path / "ground.png"), "--out", str(tmp_path / "a")]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {tmp_path / 'ground.png'}: the labels hold one class only "
                                       "(ground); the classifier of the frames it labels needs pixels of at least two classes"]
    cv2.imwrite(str(tmp_path / "unknown.png"), np.full((48, 64), 2, np.uint8))  # no class at all: not "one class (none)"
    assert main(["run", str(folder), "--labels", str(tmp_path / "unknown.png"), "--out", str(tmp_path / "u")]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {tmp_path / 'unknown.png'}: the labels are all unknown (2): "
                                       "nothing to fit or propagate"]
    assert not (tmp_path / "u").exists()
    keys = tmp_path / "keys"
    keys.mkdir()
    shutil.copy(key, keys / "f0.png")
    shutil.copy(tmp_path / "ground.png", keys / "f4.png")
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "b")]) == 2
    assert "the labels of f4.png hold one class only (ground)" in one_line_errors(capsys)[0]
    assert not (tmp_path / "b").exists()
    shutil.copy(key, keys / "f5.png")  # key frames side by side fit no classifier together: f4 beside f5 is fine
    shutil.copy(tmp_path / "ground.png", keys / "f3.png")
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "c")]) == 0


def test_frames_with_names_near_the_file_systems_limit_are_labelled(tmp_path):
    """A frame's stem of 249 bytes is a legal name; its label PNG's temporary file, 14 bytes longer, was not."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=3)
    long = "é" * 100 + "x" * 49  # 249 bytes in UTF-8
    for i in range(3):
        (folder / f"f{i}.png").rename(folder / f"{long}{i}.png")
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]) == 0
    assert sorted(p.name for p in out.glob("*.png")) == [f"{long}{i}.png" for i in range(3)]


def test_suggest_refuses_frame_names_that_its_lines_cannot_hold(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=3)
    (folder / "f1.png").rename(folder / "f1\ta.png")
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "o"), "--suggest", "1"]) == 2
    assert "the frame name 'f1\\ta.png' holds a tab or a line break" in one_line_errors(capsys)[0]
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "o")]) == 0


def test_a_runs_recording_draws_each_frame_over_its_key_frame(tmp_path):
    """The Registration view of a ``pcreg run`` recording was empty: only the moving frames were logged. The key
    frame is now the reference of every frame registered to it."""
    from pcreg.recording.readback import image, read_recording

    folder, key = drifting_frames(tmp_path / "frames", (96, 128), n=4)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out"),
                 "--record", str(tmp_path / "run.rrd"), "--record-raw"]) == 0
    rec = read_recording(tmp_path / "run.rrd")
    first = cv2.imread(str(folder / "f0.png"))[:, :, ::-1]
    for frame in (1, 3):
        np.testing.assert_array_equal(image(rec.reference(frame)), first)
        np.testing.assert_array_equal(image(rec.moving(frame)), cv2.imread(str(folder / f"f{frame}.png"))[:, :, ::-1])


def test_a_recording_of_a_run_from_two_key_frames_draws_each_frame_over_its_reference(tmp_path):
    """Each pass registers its frames to its key frame (the later one between two key frames, the last one after
    it; a chained step to the frame before in the pass): the Registration view of such runs was empty."""
    from pcreg.recording.readback import image, read_recording

    folder, key = drifting_frames(tmp_path / "frames", (96, 128), n=6)
    keys = tmp_path / "keys"
    keys.mkdir()
    for name in ("f0.png", "f3.png"):
        (keys / name).write_bytes(key.read_bytes())
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out"),
                 "--record", str(tmp_path / "run.rrd"), "--record-raw"]) == 0
    rec = read_recording(tmp_path / "run.rrd")
    frame = {i: cv2.imread(str(folder / f"f{i}.png"))[:, :, ::-1] for i in range(6)}
    for t in (1, 2, 4, 5):
        np.testing.assert_array_equal(image(rec.reference(t)), frame[3])
        np.testing.assert_array_equal(image(rec.moving(t)), frame[t])


def test_a_finished_run_from_key_frames_run_again_with_its_recording_says_it_is_done(tmp_path, capsys):
    """As a finished run from one label image does: the same command again is "all frames already done", exit 0,
    and the recording is left as it is (it was refused as "exists (use --force to overwrite)")."""
    folder, key = drifting_frames(tmp_path / "frames", (96, 128), n=5)
    keys = tmp_path / "keys"
    keys.mkdir()
    for name in ("f0.png", "f3.png"):
        (keys / name).write_bytes(key.read_bytes())
    args = ["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out"), "--record", str(tmp_path / "run.rrd")]
    assert main(args) == 0
    recorded = (tmp_path / "run.rrd").read_bytes()
    capsys.readouterr()
    assert main(args) == 0
    assert "all frames already done" in capsys.readouterr().out
    assert (tmp_path / "run.rrd").read_bytes() == recorded
    # another recording file for the finished run: not written empty without a word (it held no frame)
    assert main([*args[:-1], str(tmp_path / "again.rrd")]) == 0
    said = capsys.readouterr()
    assert "all frames already done" in said.out and not (tmp_path / "again.rrd").exists()
    assert f"nothing is recorded and {tmp_path / 'again.rrd'} is not written (--force" in said.err


def test_a_finished_run_from_one_key_frame_with_a_new_recording_says_none_is_written(tmp_path, capsys):
    folder, key = drifting_frames(tmp_path / "frames", (96, 128), n=4)
    args = ["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out")]
    assert main(args) == 0
    capsys.readouterr()
    assert main([*args, "--record", str(tmp_path / "late.rrd")]) == 0
    said = capsys.readouterr()
    assert "already done" in said.out and not (tmp_path / "late.rrd").exists()
    assert "nothing is recorded" in said.err
    assert main([*args, "--record", str(tmp_path / "late.rrd"), "--force"]) == 0  # the way to a recording
    assert (tmp_path / "late.rrd").stat().st_size > 0


def test_a_resumed_chained_run_records_the_reference_of_its_first_step(tmp_path, capsys):
    """A run with many classes registers each frame to the one before; resumed, its first step's reference
    (the frame the stopped run labelled last) was not at hand and the Registration view had none there. The
    propagator's carry holds it."""
    from pcreg.recording.readback import image, read_recording

    folder, _ = drifting_frames(tmp_path / "frames", (96, 128), n=6)
    labels = np.repeat(np.array([1, 3, 4], np.uint8), 32)[:, None] * np.ones((1, 128), np.uint8)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    bad = folder / "f4.png"
    good = bad.read_bytes()
    bad.write_bytes(good[:100])
    args = ["run", str(folder), "--labels", str(tmp_path / "key.png"), "--classes", "camvid11",
            "--out", str(tmp_path / "out"), "--record-raw"]
    assert main([*args, "--record", str(tmp_path / "first.rrd")]) == 2  # stops at the broken frame
    capsys.readouterr()
    bad.write_bytes(good)
    assert main([*args, "--record", str(tmp_path / "again.rrd")]) == 0
    rec = read_recording(tmp_path / "again.rrd")
    frame = {i: cv2.imread(str(folder / f"f{i}.png"))[:, :, ::-1] for i in range(6)}
    for t in (4, 5):
        np.testing.assert_array_equal(image(rec.reference(t)), frame[t - 1])
        np.testing.assert_array_equal(image(rec.moving(t)), frame[t])


def test_a_resume_after_a_class_of_the_table_was_renamed_says_which_class(tmp_path, capsys):
    """A class table's file edited between a run and its resume: refused, naming the class that differs (the
    line said only "other options" when the difference lay past the first 60 characters of the table)."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    labels = cv2.imread(str(key), cv2.IMREAD_UNCHANGED)
    labels[:, 40:] = 2
    cv2.imwrite(str(key), labels)
    labelmap = tmp_path / "labelmap.txt"
    labelmap.write_text("background:0,0,0::\nroad:128,64,128::\nsky:128,128,128::\ncar:64,0,128::\n")
    out = tmp_path / "out"
    args = ["run", str(folder), "--labels", str(key), "--classes", str(labelmap), "--out", str(out)]
    assert main(args) == 0
    written = {p.name: p.read_bytes() for p in out.iterdir()}
    labelmap.write_text("background:0,0,0::\nroad:128,64,128::\nsky:128,128,128::\nvehicle:64,0,128::\n")
    assert main(args) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "classes.classes[2]: {'id': 2, 'name': 'car', 'colour': [64, 0, 128]} then, " \
        "{'id': 2, 'name': 'vehicle', 'colour': [64, 0, 128]} now" in err[0], err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == written


def test_a_run_interrupted_inside_a_compiled_kernel_says_its_frames_are_kept(tmp_path, capsys, monkeypatch):
    """Ctrl-C landing inside a numba kernel surfaces as a SystemError ("returned a result with an exception
    set"), not a KeyboardInterrupt: the run said the evaluations' "finished units are kept"."""
    import signal

    from pcreg.pipeline.stream import Propagator

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    real = Propagator.step
    steps = []

    def kernel_interrupted(self, image, *args, **kwargs):
        steps.append(1)
        if len(steps) == 2:
            try:
                signal.raise_signal(signal.SIGINT)  # the command line's own handler notes it and raises
            except KeyboardInterrupt as exc:
                raise SystemError("CPUDispatcher(...) returned a result with an exception set") from exc
        return real(self, image, *args, **kwargs)

    monkeypatch.setattr(Propagator, "step", kernel_interrupted)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 130
    said = capsys.readouterr().err
    assert "pcreg: interrupted (the frames labelled are kept; rerun the same command to resume)" in said, said
    monkeypatch.undo()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["done"] == 5


def test_images_among_the_frames_in_a_format_pcreg_does_not_read_are_named_in_a_note(tmp_path, capsys):
    """A GIF or a phone's HEIC among the frames was passed over without a word: the run had a frame fewer."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    (folder / "f1b.gif").write_bytes(b"GIF89a")
    (folder / "IMG_0001.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic")
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out")]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "does not read" in ln]
    assert notes == [f"pcreg: note: {folder}: 2 images in a format pcreg does not read, not labelled (IMG_0001.HEIC "
                     "and f1b.gif); convert them to PNG to label them with the others"], notes
    assert sorted(p.name for p in (tmp_path / "out").glob("*.png")) == [f"f{i}.png" for i in range(4)]


@pytest.mark.parametrize("damage", ["garbage", "cut before IEND", "colours", "another size", "confidence garbage",
                                    "confidence gone"])
def test_a_label_png_damaged_since_the_run_is_named_on_resume_not_taken_as_done(tmp_path, capsys, damage):
    """A label PNG (or a confidence PNG) of a counted frame overwritten, cut short or removed: the rerun said "all 5
    frames already done" (exit 0) and the export failed on it later; it names the file, its damage and --force, and
    leaves the folder as it was."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]
    assert main(run) == 0
    good = (out / "f2.png").read_bytes()
    labels = read_labels(out / "f2.png")
    damaged = {"garbage": b"not a PNG", "cut before IEND": good[:-12],
               "colours": cv2.imencode(".png", LAGR.paint(labels)[:, :, ::-1])[1].tobytes(),
               "another size": encode_label_png(labels[:, :32], LAGR),
               "confidence garbage": b"not a PNG"}
    if damage == "confidence gone":
        shutil.rmtree(out / "confidence")
    else:
        (out / ("confidence/" if damage.startswith("confidence") else "") / "f2.png").write_bytes(damaged[damage])
    written = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    said = {"garbage": "f2.png: not a PNG,", "cut before IEND": "f2.png: the file ends before its IEND chunk",
            "colours": "f2.png: not a label PNG pcreg run writes", "another size": "f2.png: labels of 32x48, the frames 64x48",
            "confidence garbage": "confidence/f2.png: not a PNG,", "confidence gone": "confidence/f1.png is missing"}[damage]
    assert len(err) == 1 and said in err[0] and "counts that frame labelled" in err[0] and "--force" in err[0], err
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == written


def test_a_label_png_of_grey_ids_as_pcreg_0_2_wrote_is_resumed_over(tmp_path, capsys):
    """pcreg 0.2 wrote label PNGs as 8-bit grey ids: a run of its frames is not taken for a damaged one."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    cv2.imwrite(str(out / "f2.png"), read_labels(out / "f2.png"))
    capsys.readouterr()
    assert main(run) == 0
    assert "all 4 frames already done" in capsys.readouterr().out


def test_a_key_frames_label_png_damaged_since_the_run_is_written_again_and_another_named(tmp_path, capsys):
    """A run from a folder of key frames: a key frame's own label PNG overwritten is written again from its key
    labels (it was left damaged); a carried frame's is named, as in a run from one label image."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    keys = tmp_path / "keys"
    keys.mkdir()
    for i in (0, 4):
        shutil.copy(key, keys / f"f{i}.png")
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    good = (out / "f4.png").read_bytes()
    (out / "f4.png").write_bytes(b"not a PNG")
    assert main(run) == 0
    assert (out / "f4.png").read_bytes() == good
    (out / "f2.png").write_bytes((out / "f2.png").read_bytes()[:-12])
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "f2.png: the file ends before its IEND chunk" in err[0], err


def test_a_review_video_refused_for_a_damaged_label_says_one_line(tmp_path, capsys):
    """pcreg view --overlay of frames too small for their legend, one label PNG damaged: the note on the legend came
    before the refusal, two lines for a video not written; the refusal alone now, the note once a video is written."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=4)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    video = tmp_path / "review.mp4"
    capsys.readouterr()
    assert main(["view", str(out), "--overlay", str(video)]) == 0
    assert "too small for the legend" in capsys.readouterr().err
    (out / "f2.png").write_bytes(b"not a PNG")
    assert main(["view", str(out), "--overlay", str(video), "--force"]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "f2.png" in err[0] and "error" in err[0], err
    assert video.is_file()  # the earlier video, kept


@pytest.mark.parametrize("phase", ["bogus", "store"])
def test_a_key_frames_run_whose_cursor_names_no_phase_of_its_stretch_is_refused(tmp_path, capsys, monkeypatch, phase):
    """A run.json whose stretch under way is in a phase that is none of pcreg's (or one a folder's stretch has not: a
    video's ``store``) ended as a bug (ValueError: 'bogus' is not in list), where any other field not as pcreg run
    writes it is one line, exit 2."""
    from _runs import kill_at_commit

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    run = ["run", str(folder), "--labels", str(key_frames_of(key, tmp_path / "keys")), "--out", str(tmp_path / "out")]
    kill_at_commit(monkeypatch, 7, "backward")
    assert main(run) == 130
    monkeypatch.undo()
    state = json.loads((tmp_path / "out" / "run.json").read_text())
    state["cursor"]["phase"] = phase
    (tmp_path / "out" / "run.json").write_text(json.dumps(state))
    capsys.readouterr()
    assert main(run) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {tmp_path / 'out' / 'run.json'}: its 'cursor' is not as pcreg run "
                                       "writes it; use --force to start over"]


def test_a_runs_recording_plots_each_frames_predicted_error(tmp_path):
    """A ``pcreg run`` recording held the frames, labels and motions but not how well the run expected to do: each
    step's predicted error (its ``steps.jsonl`` figure) is now a series of the Errors view, on the frame timeline."""
    import json

    from pcreg.recording.readback import read_recording

    folder, key = drifting_frames(tmp_path / "frames", (96, 128), n=4)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out"),
                 "--record", str(tmp_path / "run.rrd")]) == 0
    rec = read_recording(tmp_path / "run.rrd")
    steps = [json.loads(line) for line in (tmp_path / "out" / "steps.jsonl").read_text().splitlines()]
    series = rec.series("/errors/predicted")
    assert series == pytest.approx({s["frame"]: s["predicted_error"] for s in steps}, rel=1e-6)


def test_running_out_of_memory_names_the_run_s_way_down(tmp_path, monkeypatch, capsys):
    """"out of memory (use smaller inputs or a lower --max-pixels)": for a run of frames far below the pixel limit
    whose key frames show 254 classes, the one way down that helps, --scale, went unsaid."""
    import pcreg.runs.run

    def exhausted(request):
        raise MemoryError

    monkeypatch.setattr(pcreg.runs.run.Run, "label", staticmethod(exhausted))
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=3)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "out of memory" in err[0] and "--scale 0.5" in err[0], err


@pytest.mark.parametrize("record, said", [("r\udcc3\udca9c.rrd", "a recording's path must be valid UTF-8"),
                                          ("run.txt", "a recording's name must end in .rrd")])
def test_a_recording_path_rerun_cannot_take_is_refused_before_any_label_is_written(tmp_path, capsys, record, said):
    """In the C locale without Python's UTF-8 mode a non-ASCII --record path comes as the file system's escapes,
    which rerun cannot take: it was refused after the key frame's labels, run.json and steps.jsonl were written,
    a run begun in --out. Refused before, --out left as it was."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64))
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--record", str(tmp_path / record)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and said in err[0], err
    assert not out.exists()


def test_the_closing_command_to_review_a_run_whose_folder_begins_with_a_dash_can_be_pasted(tmp_path, monkeypatch, capsys):
    """``--out=-o2``: the closing line said ``pcreg view -o2 --web``, which pasted reads -o2 as an option (exit 2)."""
    folder, key = drifting_frames(tmp_path / "frames")
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(key), "--out=-o2"]) == 0
    hint = capsys.readouterr().out.splitlines()[-1]
    assert hint == "to review the labels on the frames: pcreg view ./-o2 --web", hint
    assert main(["view", "./-o2", "--overlay", "o2.mp4"]) == 0  # the folder as the line gives it (--web serves it)


def test_an_output_folder_that_is_a_dangling_symbolic_link_is_refused_saying_so(tmp_path, capsys):
    """It said "cannot write to OUT: File exists" (mkdir's word for a link to nothing)."""
    import os

    folder, key = drifting_frames(tmp_path / "frames")
    out = tmp_path / "out"
    os.symlink(tmp_path / "elsewhere", out)
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {out} is a symbolic link to {os.path.realpath(tmp_path / 'elsewhere')}, which does not "
                                       "exist: make that folder, or choose another --out"]
    (tmp_path / "elsewhere").mkdir()
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out)]) == 0
    assert (tmp_path / "elsewhere" / "f1.png").is_file()


def test_a_run_without_record_does_not_load_rerun(tmp_path):
    """rerun took a third of a second to load in every run, and under a low limit of open files (ulimit -n 12) its
    runtime panicked with a 40-line backtrace (exit 134) in a run that records nothing."""
    import subprocess
    import sys

    folder, key = drifting_frames(tmp_path / "frames")

    def loaded(*record: str) -> str:
        args = ["run", str(folder), "--labels", str(key), *record, "--out", str(tmp_path / f"o{len(record)}")]
        code = (f"import sys; from pcreg.cli import main; assert main({args!r}) == 0; "
                "print(','.join(m for m in sys.modules if m.split('.')[0] in ('rerun', 'rerun_bindings')))")
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr[-2000:]
        return p.stdout.splitlines()[-1]

    assert loaded() == ""
    assert "rerun" in loaded("--record", str(tmp_path / "r.rrd"))
