"""`pcreg evaluate stream`'s bar counts frames: each unit tells its frames and each one labelled, in the command's own
process and from a pool's workers, before its result lands."""

import pytest

from pcreg import _progress
from pcreg._runner import make_executor, progress
from pcreg.experiments.stream import StreamConfig, evaluate


class _Seen(_progress.Work):
    """The bar's count as run_units keeps it, each message noted in order."""

    log: list[tuple] = []

    def tell(self, message: tuple) -> None:
        _Seen.log.append(("tell", *message))
        super().tell(message)

    def land(self, i: int) -> None:
        _Seen.log.append(("land", i))
        super().land(i)


def _per_unit(log: list[tuple], units: int) -> list[list[tuple]]:
    out: list[list[tuple]] = [[] for _ in range(units)]
    for entry in log:
        out[entry[1]].append(entry)
    return out


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("protocol", [{}, {"keys": "spaced:2"}, {"key_every": 3}])
def test_each_frame_of_each_method_is_a_step_told_before_its_unit_lands(monkeypatch, workers, protocol):
    monkeypatch.setattr(_progress, "Work", _Seen)
    _Seen.log = []
    config = StreamConfig(data="synthetic:syn1a,syn2b", frames=6, size=(96, 72), methods=("plain", "unregistered"), **protocol)
    with make_executor(workers) as ex:
        evaluate(config, executor=ex, show_progress=False)
    keys = {"keys": 2, "key_every": 2}.get(next(iter(protocol), ""), 1)  # spaced:2 and every 3rd of 6: 2 key frames
    frames = (6 - keys) * 2
    for unit in _per_unit(_Seen.log, 2):
        assert unit[0] == ("tell", unit[0][1], "work", frames)
        assert unit[1:-1] == [("tell", unit[0][1], "step", 1)] * frames
        assert unit[-1] == ("land", unit[0][1])


@pytest.mark.parametrize("workers", [1, 2])
def test_the_pass_that_suggests_the_key_frames_is_counted_too(monkeypatch, workers):
    """``--keys suggest:2`` runs pcreg over the clip to choose its key frames: its frames are steps of the unit (they
    counted nothing, the bar still for a whole pass), and the unit's work then says them beside the methods'."""
    monkeypatch.setattr(_progress, "Work", _Seen)
    _Seen.log = []
    config = StreamConfig(data="synthetic:syn1a,syn2b", frames=6, size=(96, 72), methods=("plain", "unregistered"),
                          keys="suggest:2")
    with make_executor(workers) as ex:
        evaluate(config, executor=ex, show_progress=False)
    for unit in _per_unit(_Seen.log, 2):
        i = unit[0][1]
        assert unit == [*[("tell", i, "step", 1)] * 5, ("tell", i, "work", 5 + 4 * 2), *[("tell", i, "step", 1)] * 8,
                        ("land", i)]


def test_many_classes_count_pcreg_s_frames_and_the_baselines(monkeypatch, shared_data):
    monkeypatch.setattr(_progress, "Work", _Seen)
    _Seen.log = []
    config = StreamConfig(data=f"camvid:{shared_data / 'camvid' / '0001TP_b'}", frames=5, classes="camvid11",
                          keys="spaced:2", methods=("plain", "pcreg"))
    evaluate(config, show_progress=False)
    (unit,) = _per_unit(_Seen.log, 1)
    assert unit == [("tell", 0, "work", 6), *[("tell", 0, "step", 1)] * 6, ("land", 0)]


def test_a_unit_s_steps_never_take_the_bar_past_its_work():
    with progress(total=0, disable=True) as bar:
        work = _progress.Work(bar, [5, 7])
        assert bar.total == 12
        work.tell((0, "work", 3))
        work.tell((0, "step", 2))
        work.tell((0, "step", 5))  # one more than it said: counted up to its work only
        assert (bar.total, work.done) == (10, [3, 0])
        work.tell((1, "step", 4))
        work.tell((0, "work", 1))  # less than it did already: its work is what it did
        work.land(1)
        work.tell((1, "step", 1))  # landed: no more
        work.tell((5, "step", 1))  # of no unit of this bar
        work.land(0)
        assert (bar.total, work.done) == (10, [3, 7])


def test_a_message_of_an_earlier_call_s_unit_is_not_counted():
    from pcreg._runner import InlineExecutor

    with progress(total=0, disable=True) as bar:
        first = _progress.Counting(bar, [0, 1], _progress.Tally("x", "frame", lambda u: 4), InlineExecutor(), inline=True)
        second = _progress.Counting(bar, [0, 1], _progress.Tally("x", "frame", lambda u: 4), InlineExecutor(), inline=True)
        second.tell((first.call, 1, "step", 3))  # still in a pool's pipe from the call before, whose unit raised
        second.tell((second.call, 1, "step", 2))
        assert second.work.done == [0, 2] and first.work.done == [0, 0]


def test_workers_that_keep_the_pipe_full_do_not_hold_back_a_landed_result():
    import multiprocessing

    class Pool:  # a pool's pipe, filled beyond what one read takes
        steps = multiprocessing.SimpleQueue()

    with progress(total=0, disable=True) as bar:
        counting = _progress.Counting(bar, [0], _progress.Tally("x", "frame", lambda u: 10**6), Pool(), inline=False)
        for _ in range(counting.READ_AT_MOST + 5):
            Pool.steps.put((counting.call, 0, "step", 1))
        counting.read()
        assert counting.work.done == [counting.READ_AT_MOST] and not Pool.steps.empty()
        counting.land(0)
        counting.read()
        assert counting.work.done == [10**6] and Pool.steps.empty()
