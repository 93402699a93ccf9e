"""How pcreg's public calls behave towards their caller's program: a Ctrl-C is a ``KeyboardInterrupt``, and a stream
is stepped by one thread at a time.

- **A Ctrl-C landing in a compiled kernel** (numba) comes out of it as a ``SystemError`` ("returned a result with an
  exception set") whose cause is the ``KeyboardInterrupt``: a caller's ``except KeyboardInterrupt`` missed it, and a
  ``SystemError`` reads as a bug. :func:`interruptible` raises the ``KeyboardInterrupt`` itself.
- **One stream, one caller at a time.** A :class:`pcreg.Propagator` is one stream whose steps follow each other: two
  threads stepping (or resetting) it at once interleaved its steps and raised whatever the other thread's half-made
  state gave (an ``AttributeError``, or an :class:`~pcreg.errors.InputError` of two sizes blaming the frames).
  :func:`one_caller` refuses a call made while another thread's call on the same object runs, in one line.
"""

from __future__ import annotations

import contextlib
import functools
import threading
from typing import Callable, Iterator, TypeVar

from .errors import InputError

__all__ = ["OneStream", "interruptible", "one_caller", "state_without_caller"]

F = TypeVar("F", bound=Callable)

#: The attribute of an object that holds the mark of a call running on it, (thread id, token) (only while one runs:
#: never copied or pickled).
CALLER = "_pcreg_caller"


@contextlib.contextmanager
def interrupts_unwrapped() -> Iterator[None]:
    """Raise the ``KeyboardInterrupt`` that a compiled kernel wrapped in a ``SystemError`` (or in one wrapped in
    another: a kernel loaded from numba's cache while Ctrl-C lands) within the block; any other error as it is."""
    try:
        yield
    except SystemError as exc:
        cause: BaseException | None = exc
        for _ in range(8):  # the chain of SystemErrors down to what was raised in the kernel
            if not isinstance(cause, SystemError):
                break
            cause = cause.__cause__ if cause.__cause__ is not None else cause.__context__
        if isinstance(cause, KeyboardInterrupt):
            raise cause.with_traceback(None) from None
        raise


def interruptible(fn: F) -> F:
    """``fn`` within :func:`interrupts_unwrapped`."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        with interrupts_unwrapped():
            return fn(*args, **kwargs)

    return call  # type: ignore[return-value]


def one_caller(method: F) -> F:
    """``method`` of an object, :func:`interruptible`, refused while another thread runs a call so guarded on the same
    object (the same thread may call one inside another)."""
    run = interruptible(method)

    @functools.wraps(method)
    def call(self, *args, **kwargs):
        me = threading.get_ident()
        token = (me, object())  # this call's own: whether it put the mark in is told by the mark itself
        holder = self.__dict__.setdefault(CALLER, token)  # atomic under the GIL: the first call in holds it
        if holder is not token and holder[0] != me:
            raise InputError(f"{type(self).__name__}.{method.__name__} called while another thread's call on the same "
                             f"{type(self).__name__} runs: a stream's steps follow each other; use one per thread, "
                             "or call it from one thread (or under a lock)")
        try:
            return run(self, *args, **kwargs)
        finally:
            if holder is token and self.__dict__.get(CALLER) is token:  # the object's dict now (a refused reset puts its old one back)
                del self.__dict__[CALLER]

    return call  # type: ignore[return-value]


def state_without_caller(obj) -> dict:
    """``obj``'s attributes to copy or pickle (its ``__getstate__``), without the mark of a call running on it; refused
    while another thread's call runs on it (a copy of a stream half-way through a step)."""
    state = dict(obj.__dict__)
    holder = state.pop(CALLER, None)
    if holder is not None and holder[0] != threading.get_ident():
        raise InputError(f"a {type(obj).__name__} copied or pickled while another thread's call on it runs: copy it "
                         "between its steps")
    return state


class OneStream:
    """What a stream (:class:`pcreg.Propagator`, :class:`~pcreg.pipeline.follow.ObjectFollower`) is copied and pickled
    as: every attribute but the mark of a call running (:func:`state_without_caller`), and ``copy.copy`` a fork,
    a deep copy (a shallow one shared the state its steps change in place: stepping the copy changed the original's
    labels)."""

    def __getstate__(self) -> dict:
        return state_without_caller(self)

    def __copy__(self):
        import copy

        return copy.deepcopy(self)
