"""Progress finer than a unit: a unit of an evaluation says how much work it holds (its frames, say) and
counts each step of it as it goes, in whichever process runs it; the command's bar counts the steps.

A unit calls :func:`unit_work` once it knows its work (what is left of it: the steps it told before, choosing its
key frames say, count too) and :func:`unit_step` after each step. Both do nothing
unless the unit runs under :func:`~pcreg._runner.run_units` with a :class:`Tally` that estimates the work: in the
command's own process they reach its :class:`Counting` directly, in a local pool's worker through a pipe to it
(read as results land, and every quarter of a second), on a dask cluster nowhere (its bar moves as units land).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Callable

#: Where this process's unit tells its progress (a :meth:`Counting.tell`, or a pipe's ``put`` to one); None: nowhere.
_sink: Callable[[tuple], None] | None = None


@dataclass
class _Under:
    """The unit under way in this process: its ``call`` and ``index`` (:class:`Counting`'s) and the steps it told."""

    call: int
    index: int
    told: int = 0


#: The unit under way in this process, when its progress is counted.
_unit: _Under | None = None
#: Each :class:`Counting`'s number: a message of an earlier call's unit, still in a pool's pipe, is not counted.
_CALLS = itertools.count()


@dataclass(frozen=True)
class Tally:
    """What a bar of units counts: ``desc`` names it; without ``estimate`` the units, else their work in ``counts``
    (``"frame"``, say), each unit's ``estimate(unit)`` until the unit tells its own (:func:`unit_work`)."""

    desc: str = ""
    counts: str = "unit"
    estimate: Callable[[Any], int] | None = None


def unit_work(total: int) -> None:
    """The unit under way holds ``total`` steps of work besides those it told: the bar counts them in place of its
    estimate."""
    if _sink is not None and _unit is not None:
        _sink((_unit.call, _unit.index, "work", _unit.told + int(total)))


def unit_step(n: int = 1) -> None:
    """The unit under way did ``n`` more steps of its work."""
    if _sink is not None and _unit is not None:
        _unit.told += int(n)
        _sink((_unit.call, _unit.index, "step", int(n)))


def tell_through(put: Callable[[tuple], None]) -> None:
    """In a pool's worker: the units it runs tell their progress through ``put`` (the pool's pipe)."""
    global _sink
    _sink = put


def tracked(fn: Callable[[Any], Any], unit_id: tuple[int, int], unit: Any) -> Any:
    """``fn(unit)``, its progress told as the unit ``unit_id`` (``(call, index)``; what :class:`Counting` submits)."""
    global _unit
    before, _unit = _unit, _Under(*unit_id)
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


class Counting:
    """One :func:`~pcreg._runner.run_units` call's ``bar`` over ``units``: the units landed, or with ``tally``'s
    estimate their :class:`Work` as they tell it, from this process (``inline``) or through ``executor``'s pipe
    (a local pool's ``steps``). A context: while it lasts, a unit run in this process tells it."""

    #: The most messages read from the pipe at a time: workers that keep it full do not hold back results landed.
    READ_AT_MOST = 1000

    def __init__(self, bar, units, tally: Tally, executor, *, inline: bool) -> None:
        self.bar, self.call, self.inline = bar, next(_CALLS), inline
        self.work = None if tally.estimate is None else Work(bar, [tally.estimate(u) for u in units])
        self.steps = getattr(executor, "steps", None)
        self.told = self.work is not None and not getattr(executor, "remote", False)
        self._sink = _sink

    def __enter__(self) -> "Counting":
        global _sink
        if self.inline and self.work is not None:
            _sink = self.tell
        return self

    def __exit__(self, *exc) -> None:
        global _sink
        _sink = self._sink

    def tell(self, message: tuple) -> None:
        """A unit's message ``(call, index, kind, n)``; one of another call is left out."""
        call, *rest = message
        if call == self.call and self.work is not None:
            self.work.tell(tuple(rest))

    def submit(self, executor, fn: Callable[[Any], Any], i: int, unit: Any):
        """``fn(unit)`` submitted, its progress told as this call's unit ``i`` where it is counted."""
        return executor.submit(tracked, fn, (self.call, i), unit) if self.told else executor.submit(fn, unit)

    def read(self) -> None:
        """The messages in the pipe (at most :data:`READ_AT_MOST`)."""
        for _ in range(self.READ_AT_MOST):
            if self.steps is None or self.steps.empty():
                return
            self.tell(self.steps.get())

    def land(self, i: int) -> None:
        """Unit ``i`` finished."""
        if self.work is None:
            self.bar.update(1)
        else:
            self.work.land(i)
