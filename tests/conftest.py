"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = (REPO_ROOT.parent / "shared" / "data").resolve()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` relative to the repository root (real data nobody on the project made).

    Skips the test with a clear reason when the folder is absent (a user's own clone has no ``../shared``).
    """
    if not SHARED_DATA.is_dir():
        pytest.skip(f"../shared/data is absent: {SHARED_DATA} not found (real-data tests need it)")
    return SHARED_DATA


@pytest.fixture
def on_path(tmp_path, monkeypatch):
    """tmp_path on sys.path (the modules written there importable), as the working directory."""
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    return tmp_path
