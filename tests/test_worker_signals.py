"""A ``--workers`` process ended by a signal the ``signal.Signals`` enumeration has no name for (a real-time
signal, as job schedulers and some supervisors send) is said in the pool's one line like any other signal: the
message's own ``signal.Signals(n)`` raised ValueError, and the command ended as a bug in pcreg."""

from __future__ import annotations

import os
import signal

import pytest

from pcreg._runner import make_executor, run_units
from pcreg.errors import PcregError

REAL_TIME = signal.SIGRTMIN + 6 if hasattr(signal, "SIGRTMIN") else None


def _ends_by_a_real_time_signal(unit: int) -> int:
    if unit == 0:
        os.kill(os.getpid(), REAL_TIME)
    return unit


@pytest.mark.skipif(REAL_TIME is None, reason="no real-time signals here")
def test_a_worker_ended_by_a_real_time_signal_is_one_line():
    with pytest.raises(PcregError, match=r"ended abruptly \(SIGRTMIN\+6[,)]") as caught:
        with make_executor(2) as executor:
            run_units(_ends_by_a_real_time_signal, [0, 1], executor=executor, show_progress=False)
    assert "\n" not in str(caught.value)
