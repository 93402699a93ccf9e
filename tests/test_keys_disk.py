"""What a stretch between two key frames keeps under ``OUT/.keys/`` for its backward pass: compressed without
loss (every bit back) when the disk needs it and kept as it is otherwise, the run's outputs the same either
way; read back from an earlier version's uncompressed files so that its interrupted run resumes, refused in one
line when damaged; and the note before a run whose longest stretch will not fit on OUT's disk."""

import io
import shutil

import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import OutputError
from pcreg.runs import disk, kept
from _runs import kill_at_commit
from test_keyframes_run import _keys, _outputs, _video, run_whole_and_stopped


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 6, 0, width=160, height=120)


def test_every_bit_comes_back():
    rng = np.random.default_rng(0)
    prior = rng.normal(0, 4, (30, 40, 9)).astype(np.float16)
    prior.reshape(-1)[:4] = [np.nan, -np.inf, np.inf, -0.0]
    prior.view(np.uint16).reshape(-1)[4] = 0x7E01  # a NaN with a payload of its own
    arrays = {"prior": prior, "weight": rng.random((30, 40)).astype(np.float16), "fallback": np.asarray(True),
              "image": rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), "column": np.ones((5, 1), np.float32),
              "empty": np.zeros((0, 4), np.float16), "ints": rng.integers(-9, 9, (6, 7), dtype=np.int32)}
    back = kept.unpack(kept.pack(arrays))
    assert list(back) == list(arrays)
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype and back[name].shape == a.shape, name
        assert back[name].tobytes() == a.tobytes(), name


def test_a_smooth_prior_and_frame_are_kept_smaller(tmp_path):
    y, x = np.mgrid[0:120, 0:160]
    prior = np.stack([np.sin(x / 9.0 + c) * y / 7 for c in range(10)], axis=-1).astype(np.float16)
    kept.write_prior(tmp_path, 3, prior, False, np.hypot(x, y).astype(np.float16) / 50)
    image = np.stack([x, y, x + y], axis=-1).astype(np.uint8)
    kept.write_frame(tmp_path, 3, image)
    assert (tmp_path / "prior-3.kept").stat().st_size < 0.5 * (prior.nbytes + 2 * 160 * 120)
    assert (tmp_path / "frame-3.kept").stat().st_size < 0.5 * image.nbytes
    p, fallback, w, cut = kept.read_prior(tmp_path, 3)
    assert p.tobytes() == prior.tobytes() and not fallback and w is not None and not cut
    kept.write_prior(tmp_path, 4, prior, False, cut=True)
    assert kept.read_prior(tmp_path, 4)[3] is True
    (tmp_path / "prior-5.kept").write_bytes(kept.pack({"prior": prior, "fallback": np.asarray(True)}))  # kept before
    assert kept.read_prior(tmp_path, 5)[1:] == (True, None, False)
    assert kept.read_frame(tmp_path, 3).tobytes() == image.tobytes()


@pytest.mark.parametrize("damage", [lambda b: b[:-7], lambda b: b[:20] + bytes(len(b) - 20), lambda b: b"PK" + b[2:]])
def test_a_damaged_kept_file_is_refused_in_one_line(tmp_path, damage):
    kept.write_prior(tmp_path, 2, np.ones((12, 16), np.float16), True)
    path = tmp_path / "prior-2.kept"
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(OutputError, match=r"prior-2.kept: missing or unreadable; use --force to start over$"):
        kept.read_prior(tmp_path, 2)
    with pytest.raises(OutputError, match=r"frame-5.kept: missing or unreadable"):
        kept.read_frame(tmp_path, 5)


def _as_before(folder) -> int:
    """What ``folder`` (a stretch's hidden folder) holds, rewritten as the previous version wrote it:
    ``prior-N.npz`` (numpy's uncompressed npz of the same members) and ``frame-N.npy``; how many files."""
    n = 0
    for path in sorted(folder.glob("*.kept")):
        kind, t = path.stem.split("-")
        arrays = kept.unpack(path.read_bytes())
        buf = io.BytesIO()
        if kind == "frame":
            np.save(buf, arrays["image"], allow_pickle=False)
        else:
            np.savez(buf, **arrays)
        (folder / f"{kind}-{t}.{'npy' if kind == 'frame' else 'npz'}").write_bytes(buf.getvalue())
        path.unlink()
        n += 1
    return n


@pytest.mark.parametrize("kill_at, phase", [(10, "store"), (15, "between"), (18, "backward")])
def test_a_run_stopped_by_the_previous_version_resumes_to_the_same_bytes(tmp_path, frames, monkeypatch, kill_at,
                                                                           phase):
    """A video with key frames 1 and 4 stopped while its stretch kept its frames, ran its forward pass or its
    backward pass, its kept files in the previous version's form: run again, the same outputs."""
    args = run_whole_and_stopped(tmp_path, frames, monkeypatch, kill_at, phase)
    (stretch,) = (tmp_path / "cut" / ".keys").iterdir()
    assert _as_before(stretch) > 0
    assert main(args + ["--out", str(tmp_path / "cut")]) == 0
    assert _outputs(tmp_path / "whole") == _outputs(tmp_path / "cut")
    assert (tmp_path / "whole" / "run.json").read_bytes() == (tmp_path / "cut" / "run.json").read_bytes()
    assert not (tmp_path / "cut" / ".keys").exists()


def test_not_compressing_keeps_every_bit_as_it_is():
    rng = np.random.default_rng(1)
    arrays = {"prior": rng.normal(0, 4, (30, 40, 9)).astype(np.float16), "fallback": np.asarray(False),
              "image": rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), "empty": np.zeros((0, 4), np.float16)}
    data = kept.pack(arrays, compress=False)
    assert len(data) - sum(a.nbytes for a in arrays.values()) < 600  # the header only
    back = kept.unpack(data)
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype and back[name].shape == a.shape, name
        assert back[name].tobytes() == a.tobytes(), name
    assert back["prior"].flags.writeable
    assert arrays["prior"].tobytes() in data  # as it is: no difference taken, no shuffle, no zlib


def _free(monkeypatch, free):
    """The free space :func:`pcreg.runs.disk.free_bytes` reports, for the runs that follow."""
    monkeypatch.setattr(disk, "free_bytes", lambda path: free)


@pytest.mark.parametrize("free, compressed", [(None, True), (0, True), (2**62, False)])
def test_a_stretch_keeps_its_files_compressed_only_when_the_disk_needs_it(tmp_path, frames, monkeypatch, free,
                                                                          compressed):
    """Free space unknown or scarce: compressed; plenty: the arrays' bytes as they are."""
    video = _video(tmp_path, frames)
    keys = _keys(tmp_path / "keys", frames, [0, 5], name="{:06d}")
    _free(monkeypatch, free)
    kill_at_commit(monkeypatch, 15, "backward")
    assert main(["run", str(video), "--labels", str(keys), "--out", str(tmp_path / "cut")]) == 130
    (stretch,) = (tmp_path / "cut" / ".keys").iterdir()
    priors, images = sorted(stretch.glob("prior-*.kept")), sorted(stretch.glob("frame-*.kept"))
    assert len(priors) == 4 and len(images) == 6
    for paths, nbytes in [(priors, 160 * 120 * 2 + 1), (images, 160 * 120 * 3)]:
        for p in paths:
            size = p.stat().st_size
            assert (size < 0.7 * nbytes) if compressed else (nbytes <= size < nbytes + 600), (p.name, size)


def test_a_run_kept_compressed_or_not_writes_the_same_bytes(tmp_path, frames, monkeypatch):
    """The same run with its stretch kept compressed, kept uncompressed, and stopped in its forward pass
    compressed then resumed uncompressed (a resumed run decides again; its stretch keeps files of both kinds):
    the same labels, confidence and run.json."""
    video = _video(tmp_path, frames)
    keys = _keys(tmp_path / "keys", frames, [1, 4], name="{:06d}")
    args = ["run", str(video), "--labels", str(keys), "--confidence", "--out"]
    _free(monkeypatch, 0)
    assert main(args + [str(tmp_path / "packed")]) == 0
    kill_at_commit(monkeypatch, 14, "between")
    assert main(args + [str(tmp_path / "mixed")]) == 130
    monkeypatch.undo()
    (stretch,) = (tmp_path / "mixed" / ".keys").iterdir()
    assert sorted(p.name for p in stretch.glob("prior-*.kept")) == ["prior-2.kept"]  # prior-3.kept written uncompressed
    assert b'"zlib": true' in (stretch / "prior-2.kept").read_bytes()[:400]
    _free(monkeypatch, 2**62)
    assert main(args + [str(tmp_path / "plain")]) == 0
    assert main(args + [str(tmp_path / "mixed")]) == 0
    whole = _outputs(tmp_path / "packed")
    assert any("conf" in name for name in whole)
    for other in ("plain", "mixed"):
        assert _outputs(tmp_path / other) == whole, other
        assert (tmp_path / other / "run.json").read_bytes() == (tmp_path / "packed" / "run.json").read_bytes()


GIB = 2**30


def test_the_longest_stretch_decides_what_a_run_keeps():
    frame, prior = disk.frame_bytes(1920, 1080), disk.prior_bytes(1920, 1080, 11)
    assert disk.prior_bytes(1920, 1080, 2) < prior
    assert disk.frame_bytes(1920, 1080, compressed=False) == 3 * 1920 * 1080 > frame
    assert disk.prior_bytes(1920, 1080, 11, compressed=False) == 2 * 11 * 1920 * 1080 > prior
    assert disk.prior_bytes(1920, 1080, 2, compressed=False) == 2 * 1920 * 1080
    assert disk.stretch_bytes(0, 801, video=True, frame=frame, prior=prior) == 800 * prior + 802 * frame
    assert disk.stretch_bytes(0, 801, video=False, frame=frame, prior=prior) == 800 * prior
    assert disk.stretch_bytes(None, 10, video=True, frame=frame, prior=prior) == 11 * frame  # before the first key
    assert disk.stretch_bytes(None, 10, video=False, frame=frame, prior=prior) == 0
    assert disk.stretch_bytes(40, None, video=True, frame=frame, prior=prior) == 0  # forwards to the end


def test_a_note_names_what_the_stretch_needs_and_what_is_free(tmp_path):
    assert disk.disk_note(5 * GIB, 6 * GIB, tmp_path) is None
    assert disk.disk_note(5 * GIB, None, tmp_path) is None
    note = disk.disk_note(5 * GIB, 2 * GIB, tmp_path / "out")
    assert note is not None and "about 5.0 GiB" in note and "2.0 GiB is free" in note and str(tmp_path / "out") in note
    assert disk.free_bytes(tmp_path / "not" / "yet") == shutil.disk_usage(tmp_path).free
    small = disk.disk_note(60 * 2**20, 40 * 2**20, tmp_path)  # both read "0.0 GiB"
    assert small is not None and "about 60.0 MiB" in small and "40.0 MiB is free" in small
    assert "about 700 kB" in disk.disk_note(700 * 1024, 100 * 1024, tmp_path)


def test_compressed_only_when_uncompressed_would_take_more_than_half_the_free_space():
    assert not disk.compress_kept(5 * GIB, 10 * GIB)
    assert disk.compress_kept(5 * GIB + 1, 10 * GIB)
    assert disk.compress_kept(1, None)  # unknown: compressed
    assert disk.compress_kept(1, 0)


def test_pcreg_run_notes_a_disk_too_small_and_nothing_when_it_fits(tmp_path, frames, monkeypatch, capsys):
    video = _video(tmp_path, frames)
    keys = _keys(tmp_path / "keys", frames, [0, 4], name="{:06d}")
    args = ["run", str(video), "--labels", str(keys)]
    assert main(args + ["--out", str(tmp_path / "fits")]) == 0
    assert "note" not in capsys.readouterr().err
    need = 3 * disk.prior_bytes(160, 120, 2) + 5 * disk.frame_bytes(160, 120)  # frames 0-4, priors of 1-3
    monkeypatch.setattr(disk, "free_bytes", lambda path: int(need) - 1)
    assert main(args + ["--out", str(tmp_path / "small")]) == 0
    err = capsys.readouterr().err
    assert err.count("pcreg: note: the longest stretch") == 1 and f"{disk._size(int(need) - 1)} is free" in err
    monkeypatch.setattr(disk, "free_bytes", lambda path: int(need))
    assert main(args + ["--out", str(tmp_path / "exact")]) == 0
    assert "note" not in capsys.readouterr().err


def test_a_key_frames_run_resumed_into_another_recording_says_where_it_starts(tmp_path, frames, monkeypatch, capsys):
    """A key-frames run with ``--record`` stopped, then resumed with another ``--record`` file: the second file holds
    the run from where it resumed, said on stderr, and run.json names both files in turn."""
    import json

    video = _video(tmp_path, frames)
    keys = _keys(tmp_path / "keys", frames, [1, 4], name="{:06d}")
    args = ["run", str(video), "--labels", str(keys), "--out", str(tmp_path / "cut"), "--record"]
    kill_at_commit(monkeypatch, 14, "between")
    assert main(args + [str(tmp_path / "a.rrd")]) == 130
    monkeypatch.undo()
    lines = json.loads((tmp_path / "cut" / "run.json").read_text())["lines"]
    assert lines > 0
    capsys.readouterr()
    assert main(args + [str(tmp_path / "b.rrd")]) == 0
    assert (f"pcreg: note: {tmp_path / 'b.rrd'} records this run from steps.jsonl line {lines + 1} on: what was labelled "
            "before it stopped is not in it") in capsys.readouterr().err
    state = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert state["recordings"] == [{"file": str(tmp_path / "a.rrd"), "from": "the start"},
                                   {"file": str(tmp_path / "b.rrd"), "from": f"steps.jsonl line {lines + 1} on"}]
