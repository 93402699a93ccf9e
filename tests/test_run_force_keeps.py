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
    assert len(err) == 1 and "f3.png" in err[0], err
    assert _contents(out) == earlier
    assert not (out / EARLIER).exists()


def test_a_run_started_over_that_finishes_deletes_the_earlier_run(tmp_path):
    folder, key = drifting_frames(tmp_path / "frames", n=6)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--confidence"]) == 0
    assert main(["run", str(folder), "--labels", str(key), "--out", str(out), "--force", "--stop", "4"]) == 0
    assert not (out / EARLIER).exists() and not (out / "confidence").exists()
    assert sorted(p.name for p in out.glob("f*.png")) == ["f0.png", "f1.png", "f2.png", "f3.png"]


def test_a_run_started_over_and_interrupted_keeps_both_until_the_new_one_finishes(tmp_path, monkeypatch):
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
