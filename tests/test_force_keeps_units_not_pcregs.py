"""``--force`` over an evaluation's folder removes its units (``OUT/units``): only when that folder holds only what an
evaluation writes there. A person's own files in a folder of that name went with it, the folder never an evaluation's."""

import pytest

from pcreg.cli import main


def _args(out):
    return ["evaluate", "sequence", "--data", "synthetic:syn1a", "--size", "160x120", "--frames", "4", "--increments",
            "1", "--levels", "2", "--out", str(out)]


@pytest.mark.parametrize("theirs", ["units/measurements/m1.csv", "units/notes.txt"])
def test_force_keeps_a_persons_files_in_a_folder_named_units(tmp_path, capsys, theirs):
    out = tmp_path / "proj"
    mine = out / theirs
    mine.parent.mkdir(parents=True)
    mine.write_text("data")
    capsys.readouterr()
    assert main([*_args(out), "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"pcreg: error: {mine}: not a file an evaluation writes, in the folder of its units that --force "
                   "removes; move it out of the folder, or give another --out"]
    assert mine.read_text() == "data"
    mine.unlink()
    assert main([*_args(out), "--force"]) == 0 and (out / "results.json").is_file()
    assert main([*_args(out), "--force"]) == 0  # its own units: removed and made again


def test_force_does_not_follow_a_link_named_units(tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "a.json").write_text("{}")
    out = tmp_path / "proj"
    out.mkdir()
    (out / "units").symlink_to(elsewhere)
    capsys.readouterr()
    assert main([*_args(out), "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {out / 'units'}: a link"), err
    assert (elsewhere / "a.json").read_text() == "{}"


def test_force_removes_what_a_file_browser_left(tmp_path, capsys):
    """A folder a file browser showed gains .DS_Store or Thumbs.db: --force was refused over them."""
    out = tmp_path / "proj"
    assert main(_args(out)) == 0
    for name in (".DS_Store", "Thumbs.db"):
        (out / "units" / name).write_bytes(b"\0")
    assert main([*_args(out), "--force"]) == 0 and not (out / "units" / ".DS_Store").exists()
