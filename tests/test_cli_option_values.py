"""Option values a careless or hostile user types: refused by the parser in one line naming the option, exit 2,
before anything is read or run."""

from __future__ import annotations

import pytest

from pcreg.cli import main


@pytest.mark.parametrize("argv, option", [
    (["register", "a.png", "b.png", "--levels", "100"], "--levels"),
    (["register", "a.png", "b.png", "--max-distance", "1e7"], "--max-distance"),
])
def test_an_option_value_out_of_range_is_refused_naming_the_option(tmp_path, monkeypatch, capsys, argv, option):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {option}" in err[0]
