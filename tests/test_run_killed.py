"""`pcreg run` killed outright (SIGKILL: the system out of memory, a power cut) at an event, then the same
command run again: it finishes (exit 0) and leaves what an uninterrupted run leaves."""

from __future__ import annotations

import os
import signal

from _events import until
from _interrupting import start
from _runs import assert_same_run, drifting_frames

from pcreg.cli import main

# Frames after the kill: with 10 of 180x240 the last frame was written 0.16-0.28 s after the kill's event and the
# run ended 0.95-1.1 s after it, less than a loaded machine may let pass before the kill (the run then finished
# whole, unkilled); with 40 of 270x360, 1.1-1.4 s and 1.5-1.9 s.
N = 40


def _killed_at(args: list, out, pngs: int) -> None:
    """Run ``pcreg run ARGS`` in a process and SIGKILL it once ``out`` holds ``pngs`` label PNGs."""
    p = start(["run", *args])
    try:
        until(lambda: len(list(out.glob("f*.png"))) >= pngs, what=f"{pngs} label PNGs", alive=p)
    finally:
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.communicate()
    assert p.returncode == -signal.SIGKILL, f"the run ended (exit {p.returncode}) before it was killed"


def _frames(tmp_path):
    return drifting_frames(tmp_path / "frames", (270, 360), n=N)


def test_a_confidence_map_half_written_when_killed_is_removed_by_the_rerun(tmp_path):
    """A kill while ``confidence/NAME.png`` was written left its temporary file there for good: the rerun
    cleaned up the top folder's, not the confidence folder's."""
    folder, key = _frames(tmp_path)
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(whole), "--confidence"]) == 0
    _killed_at([folder, "--labels", key, "--out", cut, "--confidence"], cut, 4)
    (cut / "confidence").mkdir(exist_ok=True)
    (cut / "confidence" / ".f05.png.k1ll3d.tmp").write_bytes(b"\x89PNG\r\n")  # what a kill mid-write leaves
    assert main(["run", str(folder), "--labels", str(key), "--out", str(cut), "--confidence"]) == 0
    assert sorted(p.name for p in (cut / "confidence").iterdir()) == sorted(p.name for p in (whole / "confidence").iterdir())
    assert_same_run(whole, cut, N)


def test_a_recorded_run_killed_says_how_to_go_on_and_force_records_every_frame(tmp_path, capsys):
    """The same command after a kill of a run with ``--record`` was refused (the recording exists) with
    advice (--force) that seemed to throw the labels away and did not say that another recording resumes.
    Now the refusal names both ways on, loses nothing, and ``--force`` records every frame, with the same
    labels as an uninterrupted run and no temporary file of the killed run left."""
    from pcreg.recording.readback import read_recording, unfinished_files_allowed

    folder, key = _frames(tmp_path)
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(whole), "--record", str(tmp_path / "w.rrd"),
                 "--confidence"]) == 0
    args = [folder, "--labels", key, "--out", cut, "--record", tmp_path / "c.rrd", "--confidence"]
    _killed_at(args, cut, 5)
    (cut / ".carry-1.npz.k1ll3d.tmp").write_bytes(b"PK")  # a carry half written when it was killed
    labelled = sorted(p.name for p in cut.glob("f*.png"))
    assert main(["run", *map(str, args)]) == 2
    err = capsys.readouterr().err
    assert "cut short when the run was killed" in err and "another --record file" in err and "--force" in err
    assert "up to about a second before" in err  # rerun writes a second at a time: the last second is not in it
    assert sorted(p.name for p in cut.glob("f*.png")) == labelled  # nothing lost
    assert main(["run", *map(str, args), "--force"]) == 0
    assert_same_run(whole, cut, N)
    assert not list(cut.glob(".*.tmp"))
    with unfinished_files_allowed():
        frames = [{r.times.get("frame") for r in read_recording(p).get("labels/predicted")}
                  for p in (tmp_path / "w.rrd", tmp_path / "c.rrd")]
    assert frames[0] == frames[1] and set(range(1, N)) <= frames[1]


def test_a_recorded_run_stopped_by_ctrl_c_says_how_to_go_on_too(tmp_path, monkeypatch, capsys):
    """A run with ``--record`` stopped cleanly (Ctrl-C: the recording closed): the same command was refused as
    "c.rrd exists (use --force to overwrite)", naming only the way that labels every frame again. It names both
    ways on, as after a kill, and another --record file resumes to the same labels."""
    from _runs import kill_before_commit

    folder, key = _frames(tmp_path)
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(whole), "--confidence"]) == 0
    args = [str(folder), "--labels", str(key), "--out", str(cut), "--confidence"]
    kill_before_commit(monkeypatch, 6)
    assert main(["run", *args, "--record", str(tmp_path / "c.rrd")]) == 130
    monkeypatch.undo()
    capsys.readouterr()
    assert main(["run", *args, "--record", str(tmp_path / "c.rrd")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"pcreg: error: {tmp_path / 'c.rrd'} exists (the recording of this run as it stopped, or another "
                   "file); to go on from there, give another --record file (it holds the frames from there on); to "
                   "record every frame in this one, add --force (the run starts over from the key frame, same labels)"]
    assert main(["run", *args, "--record", str(tmp_path / "c2.rrd")]) == 0
    assert_same_run(whole, cut, N)
    _assert_recordings(cut, capsys, [("c.rrd", "the start"), ("c2.rrd", "f06.png on")], tmp_path)


def _assert_recordings(out, capsys, files: list, folder) -> None:
    """The resumed run said that its recording starts where it resumed, and run.json names each file in turn."""
    import json

    last, start = files[-1]
    said = capsys.readouterr().err
    assert (f"pcreg: note: {folder / last} records this run from {start}: what was labelled before it stopped is not in "
            "it (--force labels and records every frame)") in said, said
    state = json.loads((out / "run.json").read_text())
    assert state["recordings"] == [{"file": str(folder / f), "from": s} for f, s in files]
    assert state["recording"] == str(folder / last)


def test_a_recording_removed_after_a_stop_is_written_again_saying_what_it_holds(tmp_path, monkeypatch, capsys):
    """A run with ``--record`` stopped by Ctrl-C, its recording removed, and the same command run again: it
    resumed into a new file of the same name holding only the frames from there on, and said nothing, so that the
    file looked like the whole run's recording."""
    from _runs import kill_before_commit

    from pcreg.recording.readback import read_recording

    folder, key = _frames(tmp_path)
    args = [str(folder), "--labels", str(key), "--out", str(tmp_path / "cut"), "--record", str(tmp_path / "c.rrd")]
    kill_before_commit(monkeypatch, 6)
    assert main(["run", *args]) == 130
    monkeypatch.undo()
    (tmp_path / "c.rrd").unlink()
    capsys.readouterr()
    assert main(["run", *args]) == 0
    _assert_recordings(tmp_path / "cut", capsys, [("c.rrd", "the start"), ("c.rrd", "f06.png on")], tmp_path)
    assert min(r.times.get("frame") for r in read_recording(tmp_path / "c.rrd").get("labels/predicted")) == 6
