"""``pcreg view RUN --overlay FILE.mp4`` onto a full disk: FFmpeg wrote through a Python file, whose ENOSPC came back as
PyAV's "Error in PyAV callback" and an internal error (exit 1), or was printed whole as an exception "being dropped"
above the error's line. A real full disk: a small tmpfs."""

from __future__ import annotations

import os
import subprocess

import pytest

from _runs import video_run
from pcreg.cli import main



@pytest.fixture
def full_disk(tmp_path):
    """A folder on a tmpfs of 40 KiB (skipped where this process may not mount one)."""
    where = tmp_path / "tiny"
    where.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=40k", "tmpfs", str(where)],
                                           capture_output=True).returncode != 0:
        pytest.skip("mounting a small tmpfs needs root and a mount this system allows")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def test_an_overlay_video_onto_a_full_disk_is_refused_in_one_line_naming_it_and_leaves_nothing(tmp_path, full_disk, capfd):
    _, out = video_run(tmp_path, frames=90)  # an overlay of about 43 kB: FFmpeg's first 32 kB are written, then no more
    capfd.readouterr()
    assert main(["view", str(out), "--overlay", str(full_disk / "overlay.mp4")]) == 2
    assert capfd.readouterr().err.splitlines() == [
        f"pcreg: error: cannot write {full_disk / 'overlay.mp4'}: No space left on device"]
    assert os.listdir(full_disk) == []
    assert main(["view", str(out), "--overlay", str(tmp_path / "overlay.mp4")]) == 0  # with space, written
    assert (tmp_path / "overlay.mp4").stat().st_size > 40 * 1024
