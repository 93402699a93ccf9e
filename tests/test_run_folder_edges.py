"""A run's folder at its edges: frames removed from the end of the folder since the run (the review and the export
said nothing, and the archive held masks of frames gone), a ``--record`` file there already when ``--out`` holds no
run (refused only once the key frame's labels were written), ``--force`` leaving the earlier run's export, and an
evaluation's units kept under a clip's name too long for a file's."""

from __future__ import annotations

import contextlib
import io

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.review import read_review


@pytest.fixture(scope="module")
def synthetic():
    return pcreg.synthetic("syn1a", 5, 0, width=96, height=72)


def _run(tmp_path, synthetic, keys: bool = False, *extra):
    folder = tmp_path / "frames"
    folder.mkdir(exist_ok=True)
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(folder / f"f{i}.png"), f.image[:, :, ::-1])
    (tmp_path / "keys").mkdir(exist_ok=True)
    for k in (0, 4) if keys else (0,):  # the last a key frame
        cv2.imwrite(str(tmp_path / "keys" / f"f{k}.png"), synthetic[k].labels)
    labels = tmp_path / "keys" if keys else tmp_path / "keys" / "f0.png"
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["run", str(folder), "--labels", str(labels), "--out", str(tmp_path / "out"), *map(str, extra)])
    return folder, tmp_path / "out", rc


@pytest.mark.parametrize("keys", [False, True], ids=["one label image", "a folder of key frames"])
def test_frames_removed_from_the_end_of_the_folder_are_named_by_the_review_and_the_export(tmp_path, synthetic, capsys, keys):
    folder, out, rc = _run(tmp_path, synthetic, keys)
    assert rc == 0
    (folder / "f4.png").unlink()  # with key frames, the last key frame alone: it has no step
    if not keys:
        (folder / "f3.png").unlink()
    with pytest.raises(InputError) as caught:
        read_review(out)
    said = (f"{folder}: no longer holds f4.png, a key frame of the run in {out}: frames were removed since the run"
            if keys else f"{folder}: holds 3 frames, the run in {out} labelled f3.png as frame 3: frames were removed since the run")
    assert str(caught.value).startswith(said) and "--force" in str(caught.value)
    capsys.readouterr()
    assert main(["export", str(out)]) == 2
    assert said in capsys.readouterr().err
    assert not (out / "export-cvat-mask.zip").exists()


def test_a_record_file_there_already_with_no_run_in_out_is_refused_before_anything_is_written(tmp_path, synthetic, capsys):
    other = tmp_path / "other.rrd"
    other.write_bytes(b"another run's recording")
    _, out, rc = _run(tmp_path, synthetic, False, "--record", other)
    assert rc == 2
    err = capsys.readouterr().err
    assert f"{other} exists, and {out} holds no run yet whose recording it could be" in err
    assert not out.exists() or not any(out.iterdir())  # nothing written
    assert other.read_bytes() == b"another run's recording"


def test_a_run_started_over_leaves_no_export_of_the_earlier_labels(tmp_path, synthetic):
    _, out, rc = _run(tmp_path, synthetic)
    assert rc == 0
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["export", str(out)]) == 0
    assert (out / "export-cvat-mask.zip").is_file()
    _, out, rc = _run(tmp_path, synthetic, False, "--force")
    assert rc == 0
    assert not (out / "export-cvat-mask.zip").exists()  # an archive of the labels replaced
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["export", str(out)]) == 0


def test_an_evaluation_of_a_clip_named_near_the_longest_name_finishes_and_resumes(tmp_path, capsys):
    """Its finished unit was kept as ``units/NAME_reference.json``, past the 255 bytes of a name: every run of the
    command stopped there (exit 2, "File name too long") and none could finish."""
    clip = tmp_path / "data" / ("c" * 250)
    for sub in ("images", "labels"):
        (clip / sub).mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(clip / "images" / f"f{i:02d}.png"), rng.integers(0, 256, (40, 48, 3), dtype=np.uint8))
        cv2.imwrite(str(clip / "labels" / f"f{i:02d}.png"), np.repeat(np.arange(12, dtype=np.uint8), 4)[None, :].repeat(40, 0))
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--data", f"camvid:{clip.parent}", "--classes", "camvid11", "--methods", "plain", "--out", str(out)]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(args) == 0, capsys.readouterr().err
        kept = sorted(p.name for p in (out / "units").iterdir())
        assert kept and all(len(name.encode()) <= 255 for name in kept)
        assert main(args) == 0  # resumed from the units kept
    assert sorted(p.name for p in (out / "units").iterdir()) == kept


def test_a_unit_keeps_the_name_it_had_wherever_that_fits_and_is_cut_at_a_character():
    from pcreg.experiments.units import unit_path

    fits = "c" * 240 + "_reference"  # 255 bytes with .json: the name kept before, which a resumed evaluation finds
    assert unit_path("o", fits).name == fits + ".json"
    assert unit_path("o", "clip" * 46 + "/frame12_reference").parts[-2:] == ("clip" * 46, "frame12_reference.json")
    cut = unit_path("o", "日" * 90 + "_reference").name  # 285 bytes: cut between two characters, with a digest
    assert len(cut.encode()) <= 255 and cut.startswith("日" * 70) and cut.endswith(".json")
    assert unit_path("o", "日" * 90 + "_reference") != unit_path("o", "日" * 90 + "_referencf")
