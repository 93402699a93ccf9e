"""`pcreg run --force` over an earlier run: the earlier run is moved aside as the new one starts, put back as it was
when bad input partway stops the new one (exit 2), and deleted once the new one finishes."""

from __future__ import annotations

import hashlib

import pytest

from pcreg.cli import main
from pcreg.runs.earlier import EARLIER
from _runs import drifting_frames, key_frames_of, one_line_errors


def _contents(out) -> dict[str, str]:
    """Every file under ``out`` (but the lock) and its SHA-256."""
    return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and p.name != ".pcreg.lock"}


@pytest.mark.parametrize("keys", [False, True])
def test_a_run_started_over_that_meets_bad_input_partway_leaves_the_earlier_run_as_it_was(tmp_path, capsys, keys):
    """The earlier run (over six frames, with confidence maps) was deleted as the run started over began, so a frame
    partway that did not read left three frames of six and an error: the earlier run was lost to bad input."""
    folder, key = drifting_frames(tmp_path / "frames", n=6)
    labels = key_frames_of(key, tmp_path / "keys", (0, 5)) if keys else key
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(labels), "--out", str(out), "--confidence"]) == 0
    earlier = _contents(out)
    assert "f5.png" in earlier and "confidence/f4.png" in earlier
    (folder / "f3.png").write_bytes(b"not a picture")
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(labels), "--out", str(out), "--force"]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "f3.png" in err[0] and f"{out} holds the earlier run again, as it was" in err[0], err
    assert _contents(out) == earlier
    assert not (out / EARLIER).exists()


def test_a_run_started_over_that_finishes_deletes_the_earlier_run(tmp_path):
    folder, key = drifting_frames(tmp_path / "frames", n=6)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]) == 0
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--force", "--stop", "4"]) == 0
    assert not (out / EARLIER).exists() and not (out / "confidence").exists()
    assert sorted(p.name for p in out.glob("f*.png")) == ["f0.png", "f1.png", "f2.png", "f3.png"]


def test_a_run_started_over_and_interrupted_keeps_both_until_the_new_one_finishes(tmp_path, monkeypatch, capsys):
    """Ctrl-C is not bad input: the new run stays to be resumed (without --force), the earlier one aside until then."""
    folder, key = drifting_frames(tmp_path / "frames", n=6)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]) == 0
    earlier = _contents(out)
    from pcreg.runs.run import Run

    real, count = Run.commit, [0]

    def stopped(self):
        count[0] += 1
        if count[0] == 3:
            raise KeyboardInterrupt
        real(self)

    monkeypatch.setattr(Run, "commit", stopped)
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main([*run, "--force"]) == 130
    assert "rerun the same command without --force to resume" in capsys.readouterr().err
    monkeypatch.undo()
    aside = {name: digest for name, digest in _contents(out).items() if name.startswith(EARLIER + "/")}
    assert aside == {f"{EARLIER}/{name}": digest for name, digest in earlier.items() if "/" not in name} | {
        f"{EARLIER}/confidence/{name.split('/')[1]}": digest for name, digest in earlier.items() if name.startswith("confidence/")}
    assert main(run) == 0  # resumed
    assert not (out / EARLIER).exists() and not (out / "confidence").exists() and (out / "f5.png").is_file()


def test_the_recording_of_a_run_started_over_is_put_back_with_it(tmp_path, capsys):
    """The earlier recording was written over (or removed, bad input at the first frame) by the run started over."""
    from pcreg.recording.readback import ended

    folder, key = drifting_frames(tmp_path / "frames", n=6)
    out, record = tmp_path / "out", tmp_path / "run.rrd"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out), "--record", str(record)]
    assert main(run) == 0
    earlier, good = record.read_bytes(), (folder / "f3.png").read_bytes()
    for bad in ("f3.png", "f1.png"):
        (folder / bad).write_bytes(b"not a picture")
        assert main([*run, "--force"]) == 2
        assert record.read_bytes() == earlier and [p.name for p in tmp_path.iterdir() if "rrd" in p.name] == ["run.rrd"]
        (folder / bad).write_bytes(good)
    assert main([*run, "--force", "--stop", "3"]) == 0
    assert record.read_bytes() != earlier and ended(record)
    assert [p.name for p in tmp_path.iterdir() if "rrd" in p.name] == ["run.rrd"]


def _finished_run(tmp_path, *extra):
    """A finished run of six frames (with confidence maps) in ``tmp_path/out``: its command, out and contents."""
    folder, key = drifting_frames(tmp_path / "frames", n=6)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out), *extra]
    assert main([*run, "--confidence"]) == 0
    return run, folder, out, _contents(out)


def _failing(monkeypatch, name: str, error: BaseException) -> None:
    """Make moving a file named ``name`` (os.replace) raise ``error``, as a file system or Ctrl-C would."""
    import os

    real = os.replace

    def replace(src, dst, *args, **kwargs):
        if os.path.basename(src) == name:
            raise error
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)


@pytest.mark.parametrize("error", [PermissionError(13, "Permission denied"), KeyboardInterrupt()])
def test_a_file_that_will_not_move_aside_leaves_the_earlier_run_as_it_was(tmp_path, capsys, monkeypatch, error):
    """The files moved before it were deleted with the new run's as the earlier run was put back (run.json among
    them): the folder was no run any more."""
    run, _, out, earlier = _finished_run(tmp_path)
    _failing(monkeypatch, "steps.jsonl", error)
    code = main([*run, "--force"])
    monkeypatch.undo()
    if isinstance(error, KeyboardInterrupt):
        assert code == 130
    else:
        assert code == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and "steps.jsonl aside" in err[0] and "left as it was" in err[0], err
    assert _contents(out) == earlier and not (out / EARLIER).exists()


def test_a_run_started_over_stopped_by_the_file_system_puts_the_earlier_run_and_recording_back(tmp_path, monkeypatch):
    """An OSError (exit 2, as a failing disk gives) deleted the recording set aside and left the earlier run aside."""
    import errno

    from pcreg.runs.run import Run

    record = tmp_path / "run.rrd"
    run, _, out, earlier = _finished_run(tmp_path, "--record", str(record))
    recorded = record.read_bytes()
    real, count = Run.commit, [0]

    def failing(self):
        count[0] += 1
        if count[0] == 3:
            raise OSError(errno.EIO, "Input/output error", str(out / "run.json"))
        real(self)

    monkeypatch.setattr(Run, "commit", failing)
    assert main([*run, "--force"]) == 2
    monkeypatch.undo()
    assert _contents(out) == earlier and not (out / EARLIER).exists()
    assert record.read_bytes() == recorded and sorted(p.name for p in tmp_path.iterdir() if "rrd" in p.name) == ["run.rrd"]


def test_an_earlier_run_folder_that_is_a_link_or_a_file_is_refused_not_followed(tmp_path, capsys):
    """A link there was followed: the earlier run's files moved into the folder it named, and one of its files, named
    as a frame's labels, was written over when the run was put back."""
    run, folder, out, earlier = _finished_run(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / "f1.png").write_bytes(b"precious")
    (out / EARLIER).symlink_to(other)
    (folder / "f3.png").write_bytes(b"not a picture")
    for _ in range(2):
        assert main([*run, "--force"]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{out / EARLIER}: not the folder" in err[0], err
        assert (other / "f1.png").read_bytes() == b"precious" and [p.name for p in other.iterdir()] == ["f1.png"]
        assert {k: v for k, v in _contents(out).items() if not k.startswith(EARLIER)} == earlier
        (out / EARLIER).unlink()
        (out / EARLIER).write_text("a file")


def test_a_run_killed_while_it_moved_the_earlier_run_aside_is_put_back_whole_by_the_next(tmp_path, capsys):
    """A run started over and killed (SIGKILL) after moving some of the earlier run's labels aside: the next run
    started over deleted them with the folder, before moving the rest."""
    run, folder, out, earlier = _finished_run(tmp_path)
    (out / EARLIER).mkdir()
    for name in ("f1.png", "f2.png"):  # what a kill between two moves leaves
        (out / name).rename(out / EARLIER / name)
    (folder / "f3.png").write_bytes(b"not a picture")
    assert main([*run, "--force"]) == 2
    assert _contents(out) == earlier and not (out / EARLIER).exists()


def test_a_run_killed_while_it_moved_the_earlier_run_aside_then_resumed_names_where_its_labels_are(tmp_path, capsys):
    """Resumed without --force after such a kill, the run was refused as "f1.png is missing", and no word of
    .earlier-run, where f1.png was."""
    run, folder, out, earlier = _finished_run(tmp_path)
    (out / EARLIER).mkdir()
    (out / "f1.png").rename(out / EARLIER / "f1.png")
    assert main([*run, "--confidence"]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{out / 'f1.png'} is missing (it is in {out / EARLIER}, " in err[0], err
    assert main([*run, "--force"]) == 0 and not (out / EARLIER).exists()


def test_a_label_png_written_before_its_step_line_goes_with_the_run_that_stopped(tmp_path, monkeypatch, capsys):
    """A run started over that stopped between a frame's label PNG and its step line (its confidence map could not be
    written) left that PNG beside the earlier run put back, which never had the frame, and said "as it was"."""
    import pcreg.runs.run as run_module
    from pcreg.errors import OutputError

    folder, key = drifting_frames(tmp_path / "frames", n=6)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main([*run, "--stop", "3"]) == 0
    earlier = _contents(out)
    real = run_module.write_confidence

    def full(path, confidence):
        if path.name == "f4.png":
            raise OutputError(f"cannot write {path}: No space left on device")
        real(path, confidence)

    monkeypatch.setattr(run_module, "write_confidence", full)
    assert main([*run, "--force", "--confidence"]) == 2
    assert f"{out} holds the earlier run again, as it was" in one_line_errors(capsys)[-1]
    assert _contents(out) == earlier and not (out / EARLIER).exists()


def test_a_recording_onto_an_input_is_refused_force_or_not(tmp_path, capsys):
    """`pcreg register REF.rrd MOV --record REF.rrd --force` replaced the reference image with the recording, exit 0;
    `pcreg run --record` onto the key labels would have too. Refused, as `--out` and `--screenshot` are."""
    import shutil

    folder, png = drifting_frames(tmp_path / "frames", shape=(96, 128), n=4)
    ref, key = tmp_path / "ref.rrd", tmp_path / "key.rrd"  # a PNG by its contents, whatever its name
    shutil.copy(folder / "f0.png", ref)
    shutil.copy(png, key)
    before = ref.read_bytes()
    for args in (["register", str(ref), str(folder / "f1.png"), "--record", str(ref), "--force"],
                 ["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out"), "--record", str(key),
                  "--force"]):
        capsys.readouterr()
        assert main(args) == 2
        said = one_line_errors(capsys)
        assert len(said) == 1 and "the output would overwrite it" in said[0], said
    assert ref.read_bytes() == before and key.is_file() and key.stat().st_size > 100
