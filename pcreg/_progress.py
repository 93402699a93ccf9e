"""Progress finer than a unit: a unit of an evaluation says how much work it holds (its frames, say) and
counts each step of it as it goes, in whichever process runs it; the command's bar counts the steps.

A unit calls :func:`unit_work` once it knows its work and :func:`unit_step` after each step. Both do nothing
unless the unit runs under :func:`~pcreg._runner.run_units` with a bar of work (``work=``): in the command's
own process they reach its :class:`Work` directly, in a local pool's worker through a pipe to it (read
as results land, and every quarter of a second), on a dask cluster nowhere (its bar moves as units land).
"""

from __future__ import annotations

from typing import Any, Callable

#: Where this process's unit tells its progress (the bar's :meth:`Work.tell`, or a pipe's ``put`` to it); None: nowhere.
_sink: Callable[[tuple], None] | None = None
#: The index of the unit under way in this process, when its progress is counted.
_unit: int | None = None


def unit_work(total: int) -> None:
    """The unit under way holds ``total`` steps of work: the bar counts them in place of its estimate."""
    if _sink is not None and _unit is not None:
        _sink((_unit, "work", int(total)))


def unit_step(n: int = 1) -> None:
    """The unit under way did ``n`` more steps of its work."""
    if _sink is not None and _unit is not None:
        _sink((_unit, "step", int(n)))


def tracked(fn: Callable[[Any], Any], index: int, unit: Any) -> Any:
    """``fn(unit)``, its progress told as the unit at ``index`` (what :func:`~pcreg._runner.run_units` submits)."""
    global _unit
    before, _unit = _unit, index
    try:
        return fn(unit)
    finally:
        _unit = before


class Work:
    """One bar's count of the work of every unit: a unit's estimate until it says its own (:func:`unit_work`),
    its steps (never past its work), and all of it once it lands (:meth:`land`, whatever it told)."""

    def __init__(self, bar, estimates: list[int]) -> None:
        self.bar = bar
        self.total = [max(0, int(e)) for e in estimates]
        self.done = [0] * len(self.total)
        self.landed = [False] * len(self.total)
        bar.total = sum(self.total)
        bar.refresh()

    def tell(self, message: tuple) -> None:
        """A unit's :func:`unit_work` or :func:`unit_step`, ``(index, "work" | "step", n)``; one of a unit landed
        already, or of no unit of this bar, is left out."""
        i, kind, n = message
        if not (isinstance(i, int) and 0 <= i < len(self.total)) or self.landed[i]:
            return
        if kind == "work":
            n = max(int(n), self.done[i])
            self.bar.total += n - self.total[i]
            self.total[i] = n
            self.bar.refresh()
        elif kind == "step":
            n = max(0, min(int(n), self.total[i] - self.done[i]))
            self.done[i] += n
            self.bar.update(n)

    def land(self, i: int) -> None:
        """Unit ``i`` finished: whatever it did not count is counted now."""
        if not self.landed[i]:
            self.bar.update(self.total[i] - self.done[i])
            self.done[i], self.landed[i] = self.total[i], True
