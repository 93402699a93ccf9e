"""What the view tests share: ``pcreg view`` in-process, and its one-line errors."""

from __future__ import annotations


def pcreg_view(argv: list[str]) -> int:
    """``pcreg view ARGV`` in-process, through the command line's own entry point."""
    from pcreg import cli

    return cli.main(["view", *argv])


def one_line_error(capsys) -> str:
    """The one stderr line of a refused command (``pcreg: error: ...``)."""
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pcreg: error: "), err
    return err
