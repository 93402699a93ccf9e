"""pcreg installed without the extra that brings Open3D (``pip install pcreg``, not ``pcreg[cpu]``): a command that
needs it said "internal error, a bug in pcreg: ModuleNotFoundError" (exit 1). It says which library is missing and how
to install it, in one line, exit 2; a command that does not need it runs as before."""

from __future__ import annotations

import contextlib
import io
import sys

import cv2
import pytest

import pcreg
from pcreg.cli import main


@pytest.fixture
def pair(tmp_path):
    frames = pcreg.synthetic("syn1a", 2, 0, width=160, height=120)
    paths = []
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), f.image[:, :, ::-1])
        paths.append(str(tmp_path / f"f{i}.png"))
    return paths


def test_a_command_that_needs_open3d_without_it_says_how_to_install_it(pair, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "open3d", None)  # as absent: ``import open3d`` raises ModuleNotFoundError
    assert main(["register", *pair, "--backend", "open3d"]) == 2
    err = capsys.readouterr().err.splitlines()  # (a note that the kernels compile may come first)
    assert err[-1] == ("pcreg: error: this command needs open3d, which is not installed: pip install 'pcreg[cpu]' "
                       "(or 'pcreg[cuda]' for Open3D's CUDA build)"), err
    assert sum("error" in line for line in err) == 1, err


def test_a_command_that_needs_no_open3d_runs_without_it(pair, monkeypatch):
    monkeypatch.setitem(sys.modules, "open3d", None)
    with contextlib.redirect_stdout(io.StringIO()) as out:
        assert main(["register", *pair, "--backend", "reference"]) in (0, 3)
    assert "motion" in out.getvalue() or out.getvalue() == ""


def test_another_missing_module_is_still_a_bug(pair, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "open3d", None)
    monkeypatch.setattr("pcreg.cli.EXTRAS", {})
    assert main(["register", *pair, "--backend", "open3d"]) == 1
    assert "a bug in pcreg: ModuleNotFoundError" in capsys.readouterr().err
