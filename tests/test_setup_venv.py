"""The set-up's check of ``.venv`` (tools/setup_venv.sh, which ``make`` asks before anything else): a venv stopped
before pip was in it, one made in another folder (a copied or moved checkout, whose scripts name the other folder),
or one whose Python is gone is not whole, and ``make`` makes it again; this checkout's own is whole."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "setup_venv.sh"


def _check(folder: Path) -> str:
    return subprocess.run(["bash", str(SCRIPT), "check"], cwd=folder, capture_output=True, text=True, check=True).stdout.strip()


def test_a_venv_half_made_copied_or_without_its_python_is_made_again(tmp_path):
    assert _check(tmp_path) == "FORCE"  # none
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp_path / ".venv")], check=True)
    (tmp_path / ".venv" / ".pcreg-venv").write_text(f"{tmp_path.resolve() / '.venv'}\n")
    assert _check(tmp_path) == "FORCE"  # stopped before pip was in it
    copy = tmp_path / "copy"
    shutil.copytree(ROOT / ".venv", copy / ".venv", symlinks=True,
                    ignore=lambda d, names: [n for n in names if n in ("lib", "lib64", "include", "share")])
    assert _check(copy) == "FORCE"  # its note names this checkout's folder, not the copy's
    (copy / ".venv" / ".pcreg-venv").write_text(f"{copy.resolve() / '.venv'}\n")
    (copy / ".venv" / "bin" / "python").unlink()
    os.symlink(tmp_path / "gone" / "python3", copy / ".venv" / "bin" / "python")
    assert _check(copy) == "FORCE"  # its Python gone


def test_this_checkouts_venv_is_whole():
    if not (ROOT / ".venv" / ".pcreg-venv").is_file():
        pytest.skip("this checkout's .venv was not made by its Makefile's set-up")
    assert Path(sys.prefix).resolve() == (ROOT / ".venv").resolve() or pytest.skip("the tests run in another venv")
    assert _check(ROOT) == ""
