"""pcreg.outputs.WriteBehind (pcreg run's writer beside the step) and what it writes of the learner: the
calls run in order, an error reaches the caller and stops the writing, leaving the block lets what was
submitted finish; a histogram taken for later is the one the learner had when it was taken."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import pcreg
from pcreg.outputs import WriteBehind


def test_calls_run_in_order_beside_the_caller_and_all_finish_at_the_end():
    done, release = [], threading.Event()

    def write(i):
        release.wait(10)
        done.append(i)

    with WriteBehind(depth=2) as writer:
        writer.submit(write, 0)
        assert done == []  # the caller goes on while the writer waits
        release.set()
        for i in range(1, 6):
            writer.submit(write, i)
    assert done == list(range(6))


def test_an_error_reaches_the_caller_and_nothing_after_it_is_written():
    done = []

    def write(i):
        if i == 1:
            raise OSError("disk full")
        done.append(i)

    writer = WriteBehind(depth=1)
    writer.submit(write, 0)
    writer.submit(write, 1)
    with pytest.raises(OSError, match="disk full"):
        for i in range(2, 50):  # raised at a later submit ...
            writer.submit(write, i)
    writer.close()
    assert done == [0]
    def fail():
        raise OSError("at the end")

    with pytest.raises(OSError, match="at the end"):  # ... or when the block ends
        with WriteBehind() as w:
            w.submit(fail)


def test_leaving_on_an_interrupt_lets_the_submitted_writes_finish_first():
    done, started = [], threading.Event()

    def write(i):
        started.set()
        done.append(i)

    with pytest.raises(KeyboardInterrupt):
        with WriteBehind(depth=4) as writer:
            for i in range(3):
                writer.submit(write, i)
            started.wait(10)
            raise KeyboardInterrupt
    assert done == [0, 1, 2]


def test_the_learned_histogram_taken_for_later_is_the_one_of_that_moment():
    frames = pcreg.synthetic("syn1a", 5, 0, width=96, height=72)
    prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    prop.step(frames[1].image)
    prop.step(frames[2].image)
    later = prop.learned_later()  # frame 2's pixels not counted yet: counted when it is called
    now = prop.learned  # counted here
    prop.step(frames[3].image)  # the learner moves on
    np.testing.assert_array_equal(later(), now)
    assert not np.array_equal(prop.learned, now)
    assert pcreg.Propagator(prop.classifier, learning=None).learned_later()() is None
