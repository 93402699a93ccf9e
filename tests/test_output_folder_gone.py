"""An output folder removed, moved or replaced while a command writes into it: refused at the next write, not made
again behind the command's back (a run that ended "labelled" in a new folder without its key frame or its lock)."""

from __future__ import annotations

import os
import shutil

import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import OutputError
from pcreg.outputs import OutputLock, atomic_write_bytes
from _runs import frames_folder, one_line_errors


def _gone(folder, how: str) -> None:
    if how == "removed":
        shutil.rmtree(folder)
    elif how == "moved":
        os.rename(folder, folder.with_name(folder.name + "-moved"))
    else:  # another folder, with a lock file of its own, in its place
        shutil.rmtree(folder)
        folder.mkdir()
        (folder / OutputLock.NAME).write_text("")


@pytest.mark.parametrize("how", ["removed", "moved", "replaced"])
def test_a_write_into_a_held_folder_that_is_gone_is_refused_not_made_again(tmp_path, how):
    folder = tmp_path / "out"
    with OutputLock(folder):
        atomic_write_bytes(folder / "a.txt", b"1")
        _gone(folder, how)
        with pytest.raises(OutputError, match=f"{folder}: the output folder was removed, moved or replaced while pcreg"):
            atomic_write_bytes(folder / "sub" / "b.txt", b"2")
        assert not (folder / "sub").exists() and (how == "replaced") == folder.exists()
    with OutputLock(folder):  # held again: written as before
        atomic_write_bytes(folder / "sub" / "c.txt", b"3")
    atomic_write_bytes(tmp_path / "free" / "d.txt", b"4")  # a folder no lock holds is made as before


@pytest.mark.parametrize("how", ["removed", "moved"])
def test_a_run_whose_folder_goes_while_it_labels_stops_saying_so(tmp_path, capsys, monkeypatch, how):
    """The run went on into a folder made again, ended with exit 0 and "labelled", and left a run without its key
    frame's labels or lock (export and the same command then refused it): exit 2 naming the folder; moved back, the
    same command goes on from where it was."""
    from pcreg.runs.run import Run

    frames = pcreg.synthetic("syn1a", 6, 0, width=160, height=120)
    folder, keys = frames_folder(tmp_path, frames, keys=(0,))
    out = tmp_path / "out"
    real = Run.write_frame

    def write_frame(self, t, *a, **k):
        if t == 3 and out.exists():
            _gone(out, how)
        return real(self, t, *a, **k)

    monkeypatch.setattr(Run, "write_frame", write_frame)
    args = ["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(out)]
    assert main(args) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{out}: the output folder was removed, moved or replaced while pcreg wrote into it" in err[0]
    assert not out.exists()
    monkeypatch.undo()
    if how == "moved":
        os.rename(out.with_name("out-moved"), out)
    assert main(args) == 0
    assert all((out / f"f{i}.png").is_file() for i in range(6))


def test_a_lock_is_let_go_after_the_working_folder_changes_and_other_threads_take_locks(tmp_path, monkeypatch):
    """A lock taken by a relative name and released after a change of working folder stayed held in the check's
    table (a later write there, not locked, would have been refused); threads taking and releasing locks while a
    write is checked changed the table under the check (a RuntimeError, said as a bug)."""
    import threading

    from pcreg import outputs

    monkeypatch.chdir(tmp_path)
    lock = OutputLock("rel").__enter__()
    monkeypatch.chdir(tmp_path / "rel")
    lock.__exit__()
    assert outputs._HELD == {}
    stop = threading.Event()

    def churn():
        while not stop.is_set():
            with OutputLock(tmp_path / "churn"):
                pass

    locks = [OutputLock(tmp_path / f"held{i}").__enter__() for i in range(50)]
    worker = threading.Thread(target=churn)
    worker.start()
    try:
        for i in range(500):
            atomic_write_bytes(tmp_path / "held0" / f"{i % 3}.txt", b"1")
    finally:
        stop.set()
        worker.join()
        for lock in locks:
            lock.__exit__()
    assert outputs._HELD == {}


def test_an_out_through_a_link_and_dotdot_is_the_folder_the_system_makes(tmp_path):
    """``--out LINK/../x`` is the folder beside LINK's target, as the system resolves it: the check reads that
    folder's lock, not a folder beside LINK that does not exist (it said the folder was removed)."""
    (tmp_path / "real" / "inner").mkdir(parents=True)
    (tmp_path / "link").symlink_to(tmp_path / "real" / "inner")
    out = tmp_path / "link" / ".." / "x"
    with OutputLock(out):
        atomic_write_bytes(out / "a.txt", b"1")
    assert (tmp_path / "real" / "x" / "a.txt").read_bytes() == b"1"
