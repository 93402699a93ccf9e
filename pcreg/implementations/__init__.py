"""ICP implementations behind one interface, for cross-checks (:mod:`pcreg.implementations.crosscheck`).

``get(spec)`` returns an :class:`~pcreg.implementations.base.Implementation` for a built-in name
(:data:`BUILTIN`), ``py:MODULE:FUNCTION`` or ``cmd:"PROGRAM {source} {target} {init} {out} {params}"``;
``parse_list`` splits a ``--with`` value on commas outside quotes. Every implementation returns a
:class:`~pcreg.registration.result.RegistrationResult`, as :func:`pcreg.icp` does.
"""

from __future__ import annotations

from .base import (COMPARABILITY, FIXED_POINT, OBJECTIVE, STEP, ImplementationError, Implementation, MissingLibrary,
                   Pinned, reported, run_quietly, stdout_to_stderr)
from .builtin import BUILTIN
from .user import Command, PythonCallable

DEFAULT = ("reference", "open3d", "open3d-tensor", "small_gicp", "small_gicp-plane", "small_gicp-gicp", "kiss-icp",
           "pycpd", "probreg-cpd", "probreg-filterreg")


def get(spec: str, *, timeout: float | None = None) -> Implementation:
    spec = spec.strip()
    if spec.startswith("py:"):
        return PythonCallable(spec)
    if spec.startswith("cmd:"):
        return Command(spec) if timeout is None else Command(spec, timeout=timeout)
    if spec in BUILTIN:
        return BUILTIN[spec]()
    raise ImplementationError(f"unknown implementation {spec!r}; built in: {', '.join(BUILTIN)}; "
                              "or py:MODULE:FUNCTION, cmd:\"PROGRAM {source} {target} {init} {out} {params}\"")


def parse_list(text: str) -> list[str]:
    """Split on commas outside single or double quotes; 'all' expands to :data:`DEFAULT`."""
    items, cur, quote = [], [], None
    for ch in text:
        if quote:
            cur.append(ch)
            if ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
            cur.append(ch)
        elif ch == ",":
            items.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    items.append("".join(cur).strip())
    out: list[str] = []
    for it in items:
        if not it:
            continue
        out.extend(DEFAULT if it == "all" else [it])
    return list(dict.fromkeys(out))


__all__ = ["BUILTIN", "COMPARABILITY", "DEFAULT", "FIXED_POINT", "OBJECTIVE", "STEP", "Command", "Implementation",
           "ImplementationError", "MissingLibrary", "Pinned", "PythonCallable", "get",
           "parse_list", "reported", "run_quietly", "stdout_to_stderr"]
