"""The helper thread (pcreg._threads): work shared with it gives the same results, to the bit, as work
done on one thread; a busy helper never holds the caller up; errors reach the caller."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import pcreg
from pcreg import _threads
from pcreg.registration.dense import match_window


def _with_helper(on: bool, fn):
    before = _threads._STATE["enabled"]
    _threads.set_enabled(on)
    try:
        return fn()
    finally:
        _threads.set_enabled(before)


def _two_cpus():
    if _threads.usable_cpus() < 2:
        pytest.skip("this process may use one CPU: the helper thread is never used")


def test_interleave_covers_every_block_once_with_and_without_the_helper():
    _two_cpus()
    for on in (False, True):
        for n in (0, 1, 31, 32, 33, 1000, 4097):
            seen = np.zeros(n, int)

            def blocks(first, stride, seen=seen, n=n):
                for b in range(first * 32, n, stride * 32):
                    seen[b:b + 32] += 1

            _with_helper(on, lambda: _threads.interleave(n, blocks, min_items=1))
            assert np.all(seen == 1), (on, n)


def test_work_offered_on_the_helper_runs_there_whole():
    """The helper never offers work to itself (it could only take it back): on it, interleave runs
    every block in one share and beside runs in place, both on the helper."""
    _two_cpus()
    pool = _threads.helper()
    assert pool is not None

    def on_helper():
        shares: list[tuple[int, int, str]] = []
        _threads.interleave(10, lambda first, stride: shares.append((first, stride, threading.current_thread().name)),
                            min_items=1)
        offered = _threads.beside(lambda: threading.current_thread().name)
        return threading.current_thread().name, _threads.helper(), shares, offered()

    name, inner, shares, offered = pool.submit(on_helper).result(timeout=60)
    assert name != threading.current_thread().name
    assert inner is None
    assert shares == [(0, 1, name)] and offered == name
    assert _threads.helper() is pool  # the caller's own thread still has it


def test_a_busy_helper_leaves_the_other_share_and_the_offered_work_to_the_caller():
    _two_cpus()
    release = threading.Event()
    started = threading.Event()
    pool = _threads.helper()
    assert pool is not None
    busy = pool.submit(lambda: (started.set(), release.wait(30)))
    started.wait(30)
    try:
        who: list[tuple[int, str]] = []
        _threads.interleave(10, lambda first, stride: who.append((first, threading.current_thread().name)),
                            min_items=1)
        assert sorted(f for f, _ in who) == [0, 1]
        assert all(name == threading.current_thread().name for _, name in who)  # nobody waited for the helper
        result = _threads.beside(lambda: threading.current_thread().name)
        assert result() == threading.current_thread().name
    finally:
        release.set()
        busy.result(30)


def test_work_offered_to_the_helper_runs_once_and_its_error_reaches_the_caller():
    _two_cpus()
    calls = []

    def work():
        calls.append(1)
        raise KeyError("from the helper")

    wait = _threads.beside(work)
    with pytest.raises(KeyError, match="from the helper"):
        wait()
    assert calls == [1]

    def failing(first, stride):
        if first == 0:
            raise ZeroDivisionError("share 0")

    with pytest.raises(ZeroDivisionError, match="share 0"):
        _threads.interleave(100, failing, min_items=1)


def test_the_helper_is_off_with_one_cpu_or_when_disabled(monkeypatch):
    monkeypatch.setattr(_threads, "usable_cpus", lambda: 1)
    assert _threads.helper() is None
    ran = []
    assert _threads.beside(lambda: ran.append(1) or 7)() == 7 and ran == [1]
    monkeypatch.undo()
    _with_helper(False, lambda: pytest.fail("helper given") if _threads.helper() is not None else None)


def test_the_split_window_search_gives_the_one_thread_answers_to_the_bit():
    _two_cpus()
    rng = np.random.default_rng(3)
    ref = rng.random((60, 80, 3), dtype=np.float32)
    mov = np.roll(ref, (2, -3), axis=(0, 1)) + rng.normal(0, 0.01, ref.shape).astype(np.float32)
    n = 3001  # not a whole number of blocks
    src = np.column_stack([rng.uniform(0, 79, n), rng.uniform(0, 59, n)])
    pos = src + rng.normal(0, 2, (n, 2))
    cols = mov[src[:, 1].astype(int), src[:, 0].astype(int)]
    args = (ref, mov, src, pos, cols)
    one = _with_helper(False, lambda: match_window(*args, radius=3, lam=4.0))
    two = _with_helper(True, lambda: match_window(*args, radius=3, lam=4.0))
    assert np.array_equal(one, two, equal_nan=True)
    assert np.isfinite(one[:, 0]).mean() > 0.9


def test_a_stream_gives_the_same_fields_and_labels_with_and_without_the_helper():
    _two_cpus()
    from pcreg.datasets import synthetic

    frames = synthetic("syn2a", 5, 0, width=320, height=240)
    runs = {}
    for on in (False, True):
        def stream():
            prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
            out = []
            for f in frames[1:]:
                labels = prop.step(f.image)
                r = prop.last.registration
                out.append((labels, r.field, r.confidence, r.info["evidence"], prop.last.start))
            return out
        runs[on] = _with_helper(on, stream)
    for a, b in zip(runs[False], runs[True]):
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
        assert a[3] == b[3] and a[4] == b[4]
    assert [r[4] for r in runs[True]] == ["cold", "warm", "warm", "warm"]


def test_close_ends_the_helper_after_its_work_and_a_later_use_makes_a_new_one():
    _two_cpus()
    started, release = threading.Event(), threading.Event()
    done = []
    pool = _threads.helper()
    pool.submit(lambda: (started.set(), release.wait(30), done.append(1)))
    started.wait(30)
    closer = threading.Thread(target=_threads.close)
    closer.start()
    assert not done  # close waits for the work the helper holds ...
    release.set()
    closer.join(30)
    assert not closer.is_alive() and done == [1]  # ... which was finished first
    assert not any(t.name.startswith("pcreg-helper") and t.is_alive() for t in threading.enumerate())
    again = _threads.helper()
    assert again is not None and again is not pool
    assert _threads.beside(lambda: 41 + 1)() == 42


def test_close_with_a_grace_gives_up_on_a_helper_that_waits_on_a_lock_left_held():
    """An interrupt can land while the main thread holds a lock the helper waits on (numba's, while a compiled
    kernel loads): closing without a bound waited for ever; with a grace it says the helper did not end."""
    _two_cpus()
    held, started = threading.Lock(), threading.Event()
    held.acquire()
    pool = _threads.helper()
    pool.submit(lambda: (started.set(), held.acquire(), held.release()))
    started.wait(30)
    assert _threads.close(timeout=0.01) is False
    held.release()  # the helper ends now; a later use makes a new one
    assert _threads.helper() is not pool and _threads.close(timeout=30) is True


def test_others_busy_is_the_machines_busy_time_less_this_processs(monkeypatch):
    """The CPUs the rest of the machine kept busy between two readings: this process's own threads (a
    threaded ICP, Open3D's) do not count, as they do in the load average."""
    from types import SimpleNamespace

    clock = {"now": 100.0, "busy": 1000.0, "own": 5.0}
    monkeypatch.setattr(_threads, "_machine_busy_seconds", lambda: clock["busy"])
    monkeypatch.setattr(_threads, "time", SimpleNamespace(monotonic=lambda: clock["now"],
                                                          process_time=lambda: clock["own"]))
    monkeypatch.setattr(_threads, "_OTHERS", {"at": None, "busy": 0.0, "own": 0.0, "value": None})
    assert _threads.others_busy() is None  # one reading: nothing to measure yet
    clock.update(now=101.0, busy=1002.0, own=6.9)  # 2 CPU-seconds busy in a second, 1.9 of them this process's
    assert _threads.others_busy() == pytest.approx(0.1)
    clock.update(now=101.0 + _threads.OTHERS_INTERVAL / 2, busy=1003.0)  # too soon to read again
    assert _threads.others_busy() == pytest.approx(0.1)
    clock.update(now=102.0, busy=1003.5, own=6.9)  # another process busy, this one idle
    assert _threads.others_busy() == pytest.approx(1.5)
    clock.update(now=103.0, busy=1004.0, own=8.0)  # the machine's ticks behind this process's own clock
    assert _threads.others_busy() == 0.0


def test_the_machines_busy_time_is_read_where_the_system_has_it():
    import os

    if not os.path.exists("/proc/stat"):
        pytest.skip("no /proc/stat on this system: the load average is used instead")
    first = _threads._machine_busy_seconds()
    assert first is not None and first > 0
    assert _threads._machine_busy_seconds() >= first


def test_both_gives_both_results_and_an_error_here_waits_for_the_side_first():
    _two_cpus()
    assert _threads.both(lambda: 1, lambda: 2) == (1, 2)
    started, release, finished = threading.Event(), threading.Event(), []

    def side():
        started.set()
        release.wait(10)
        finished.append(1)
        return "side"

    def here():
        started.wait(10)  # the helper holds the side's work
        release.set()
        raise ValueError("here")

    with pytest.raises(ValueError, match="here"):
        _threads.both(side, here)
    assert finished == [1]  # the side's work had ended when the error reached the caller


def test_alongside_leaves_the_sides_the_helper_has_not_reached_to_the_caller():
    _two_cpus()
    assert _threads.alongside(lambda: 0, lambda: 1, lambda: 2) == (0, [1, 2])
    started, release = threading.Event(), threading.Event()

    def first():
        started.set()
        release.wait(10)
        return threading.current_thread().name

    def second():  # the helper still holds the first side: the caller runs this one
        release.set()
        return threading.current_thread().name

    def here():
        started.wait(10)
        return "here"

    mine, (a, b) = _threads.alongside(here, first, second)
    assert mine == "here" and b == threading.current_thread().name and a != b


def test_alongside_waits_for_the_sides_before_an_error_goes_on():
    _two_cpus()
    started, release, finished = threading.Event(), threading.Event(), []

    def side():
        started.set()
        release.wait(10)
        finished.append(1)

    def here():
        started.wait(10)
        release.set()
        raise ValueError("here")

    with pytest.raises(ValueError, match="here"):
        _threads.alongside(here, side, lambda: None)
    assert finished == [1]


def test_an_image_cloud_is_the_same_on_one_opencv_thread_as_on_two(shared_data):
    """On one OpenCV thread (a one-CPU machine, ``taskset``, ``cv2.setNumThreads(1)``) cv::Canny hands the edge cloud's
    Canny to IPP, which leaves out the pixels exactly at a threshold: this frame had 17,483 edge points against 17,626,
    and ``pcreg register`` refused (exit 3) a pair it trusted on two CPUs. The call runs without IPP, in its thread
    alone: the same points on any thread count, and IPP left as it was for the rest."""
    import cv2

    image = cv2.imread(str(shared_data / "camvid" / "0001TP" / "images" / "0001TP_006690.png"))[:, :, ::-1].copy()
    threads, ipp = cv2.getNumThreads(), cv2.ipp.useIPP()
    clouds = []
    try:
        for n in (1, 2, 3):
            cv2.setNumThreads(n)
            clouds.append(pcreg.image_cloud(image))
            assert cv2.ipp.useIPP() == ipp
    finally:
        cv2.setNumThreads(threads)
    assert len(clouds[0].points) == 17626
    for cloud in clouds[1:]:
        assert np.array_equal(cloud.points, clouds[0].points)
