"""Run as ``python -m _interrupted_in_exec`` (from tests/): ``pcreg demo`` whose work is a string run by
``exec`` that SIGINT interrupts, as when Ctrl-C lands while a lazy import makes a dataclass. The
command line must still exit 130, not end by the signal."""

import sys

import pcreg.commands.demo as command
from pcreg import cli


def _work(args) -> int:
    exec("import os, signal\nos.kill(os.getpid(), signal.SIGINT)\nwhile True:\n    pass\n")  # noqa: S102
    return 0


command.run = _work
sys.argv = ["pcreg", "demo"]
raise SystemExit(cli.main())
