"""Names a module of pcreg 0.2.0 held that another holds now: still read from the old module, with a
:class:`DeprecationWarning` naming the new spelling, until 0.4 (:func:`moved`)."""

from __future__ import annotations

import importlib
import warnings
from typing import Any, Callable

#: 0.2.0's ``pcreg.export.LABELMAP`` and ``INSTANCE_COLOURS``, the two-class export's VOC colours: pcreg's class id
#: -> (name, RGB) and -> the RGB of its instance. The export writes the run's class table's now.
LABELMAP_0_2: dict[int, tuple[str, tuple[int, int, int]]] = {2: ("background", (0, 0, 0)), 0: ("ground", (0, 128, 0)),
                                                            1: ("obstacle", (128, 0, 0))}
INSTANCE_COLOURS_0_2: dict[int, tuple[int, int, int]] = {0: (128, 0, 0), 1: (0, 128, 0), 2: (0, 0, 0)}


def moved(module: str, names: dict[str, str], *, fallback: Callable[[str], Any] | None = None) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``module`` (its ``__name__``) that reads each of ``names`` ({old name: where it is
    now, ``"package.module"`` when the name is the same, ``"package.module:name"`` when it is not, then, after a
    space, what to use instead where that is not the same thing}) from where it is now, warning once a read; any
    other name goes to ``fallback``, or is Python's AttributeError."""

    def __getattr__(name: str) -> Any:
        where = names.get(name)
        if where is None:
            if fallback is not None:
                return fallback(name)
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        path, _, instead = where.partition(" ")
        new_module, _, new_name = path.partition(":")
        new_name = new_name or name
        warnings.warn(f"{module}.{name} is deprecated and will be removed in 0.4.0; use "
                      f"{instead or f'{new_module}.{new_name}'}", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(new_module), new_name)

    return __getattr__

