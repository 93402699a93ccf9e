"""The ``pcreg`` command line: parse, build a config, call the library.

Known errors (:class:`pcreg.errors.PcregError`, bad options) become one line on stderr and exit code 2.
Each command lives in its own module under ``pcreg.commands`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports happen inside ``run``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# name -> (module, one-line help). "evaluate" has sub-commands of its own.
COMMANDS: dict[str, tuple[str, str]] = {
    "register": ("pcreg.commands.register", "register a moving image to a reference image"),
    "crosscheck": ("pcreg.commands.crosscheck", "run both ICP backends on the same input and compare them"),
    "demo": ("pcreg.commands.demo", "the whole story on the built-in synthetic data (what `make demo` runs)"),
    "run": ("pcreg.commands.run", "label a folder of frames from a labelled key frame (streaming propagation)"),
    "view": ("pcreg.commands.view", "open a rerun recording, or render a screenshot of it"),
}
EVALUATIONS: dict[str, tuple[str, str]] = {
    "classification": ("pcreg.commands.evaluate_classification", "thesis Ch. 4: naive Bayes cases I-III"),
    "rotation": ("pcreg.commands.evaluate_rotation", "thesis Ch. 5: classify rotated frames before/after registration"),
    "sequence": ("pcreg.commands.evaluate_sequence", "thesis Ch. 6-7: register frame i+k to i, classify, fuse labels"),
}


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (argparse's default prints usage too)
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _add(sub, name: str, module: str, help_: str) -> None:
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name != module:  # a missing dependency inside the module is a real error
            raise
        return
    p = sub.add_parser(name, help=help_, description=(mod.__doc__ or help_).strip().splitlines()[0])
    mod.add_arguments(p)
    p.set_defaults(_module=module)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pcreg", description="Register images as point clouds; classify terrain per pixel.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (module, help_) in COMMANDS.items():
        _add(sub, name, module, help_)
    ev = sub.add_parser("evaluate", help="run one of the thesis's experiments")
    ev_sub = ev.add_subparsers(dest="evaluation", metavar="EXPERIMENT", parser_class=_Parser)
    for name, (module, help_) in EVALUATIONS.items():
        _add(ev_sub, name, module, help_)
    return parser


def main(argv: list[str] | None = None) -> int:
    from .errors import PcregError

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_module", None):
        parser.print_help(sys.stderr)
        return 2
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except PcregError as exc:
        sys.stderr.write(f"pcreg: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("pcreg: interrupted (finished units are kept; rerun the same command to resume)\n")
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
