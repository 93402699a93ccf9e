"""``pcreg run`` from a folder of key frames, resumable: :class:`KeyRun`, the passes of
:mod:`pcreg.pipeline.key_passes` under their public name, which also takes 0.2.0's form
``KeyRun(frames, keys, out, options, *, identity, truth=None, confidence=False)`` (with a :class:`DeprecationWarning`,
until 0.4). A run itself (:class:`pcreg.runs.run.Run`) makes the passes' own class, so that it need not load this
module, which loads it for 0.2.0's form.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import TYPE_CHECKING

from . import key_passes
from .key_passes import HIDDEN
from .._moved import moved

__all__ = ["KeyRun", "HIDDEN"]

#: ``KeyRun(owner, keys, config)``, and 0.2.0's ``KeyRun(frames, keys, out, options, *, identity, truth=None,
#: confidence=False)``, ``options`` the :class:`pcreg.Propagator` keywords (a dict; a
#: :class:`~pcreg.pipeline.config.PropagatorConfig` is taken too, by position or as ``config=``), still taken until 0.4.
_FORM = inspect.Signature([inspect.Parameter(n, inspect.Parameter.POSITIONAL_OR_KEYWORD) for n in ("owner", "keys", "config")]
                          + [inspect.Parameter("reading", inspect.Parameter.KEYWORD_ONLY, default=None)])
_FORM_0_2 = inspect.Signature(
    [inspect.Parameter(n, inspect.Parameter.POSITIONAL_OR_KEYWORD) for n in ("frames", "keys", "out", "options")]
    + [inspect.Parameter("identity", inspect.Parameter.KEYWORD_ONLY),
       inspect.Parameter("truth", inspect.Parameter.KEYWORD_ONLY, default=None),
       inspect.Parameter("confidence", inspect.Parameter.KEYWORD_ONLY, default=False)])


class KeyRun(key_passes.KeyRun):
    """:class:`pcreg.pipeline.key_passes.KeyRun`: ``KeyRun(owner, keys, config)``, or 0.2.0's ``KeyRun(frames, keys,
    out, options, identity=, truth=, confidence=)`` (by position or keyword), its owner the
    :class:`~pcreg.runs.run.Run` that spells, with a :class:`DeprecationWarning` naming the new spelling."""

    def __init__(self, *args, **kwargs) -> None:
        named = set(kwargs) - {"reading"}  # the first chosen frame's reading (key_passes.KeyRun), keyword only
        if len(args) + len(named) > 3 or not named <= {"owner", "keys", "config"}:
            super().__init__(*_run_of_0_2(*args, **kwargs))
        else:
            owner, keys, config, reading = _bound(_FORM, args, kwargs)
            super().__init__(owner, keys, config, reading=reading)


def _bound(form: inspect.Signature, args: tuple, kwargs: dict) -> list:
    """The arguments of a call of ``KeyRun`` bound to ``form``, its defaults applied; Python's TypeError when they
    do not fit, naming ``KeyRun()``."""
    try:
        bound = form.bind(*args, **kwargs)
    except TypeError as exc:
        raise TypeError(f"KeyRun(): {exc}") from None
    bound.apply_defaults()
    return list(bound.arguments.values())


def _run_of_0_2(*args, **kwargs) -> tuple:
    """``(owner, keys, config)`` of a call in 0.2.0's form (:data:`_FORM_0_2`), with the warning."""
    import warnings

    from ..runs.run import Run

    if "config" in kwargs and "options" not in kwargs:  # the keyword a PropagatorConfig was given by
        kwargs["options"] = kwargs.pop("config")
    frames, keys, out, options, identity, truth, confidence = _bound(_FORM_0_2, args, kwargs)
    warnings.warn("KeyRun(frames, keys, out, options, identity=..., truth=..., confidence=...) is deprecated and will "
                  "be removed in 0.4.0; use KeyRun(pcreg.runs.run.Run(frames, out, identity, truth=..., confidence=...), "
                  "keys, config)", DeprecationWarning, stacklevel=3)
    return Run(frames, Path(out), identity, truth=truth, confidence=bool(confidence)), keys, _config(options)


def _config(options):
    """The :class:`~pcreg.pipeline.config.PropagatorConfig` of 0.2.0's ``options``: a dict of
    :class:`pcreg.Propagator`'s keywords as ``PropagatorConfig.options()`` gives them (a flow's preset in its
    model's name, ``"flow:medium"``), or a configuration already."""
    from .config import PropagatorConfig

    if isinstance(options, PropagatorConfig):
        return options
    if not isinstance(options, dict):
        raise TypeError(f"KeyRun(): options must be a dict of pcreg.Propagator's keywords or a PropagatorConfig, "
                        f"not {type(options).__name__}")
    given = dict(options)
    model = str(given.get("model", "dense"))
    if model.startswith("flow:"):
        given["model"], given["preset"] = "flow", model.split(":", 1)[1]
    return PropagatorConfig(**given)


if not TYPE_CHECKING:  # a module __getattr__ would be mypy's for every name: a misspelt one would pass
    __getattr__ = moved(__name__, {"Stretch": "pcreg.pipeline.engine", "stretches": "pcreg.pipeline.engine"})
