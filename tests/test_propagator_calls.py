"""`pcreg.Propagator` as a caller's program meets it: Ctrl-C in a compiled kernel is a KeyboardInterrupt, a second
thread's call while one runs is refused, a copy is a fork, and a weight the confidence was not calibrated at warns."""

from __future__ import annotations

import copy
import pickle
import threading
import warnings

import numpy as np
import pytest

from pcreg import Propagator
from pcreg._calls import interruptible
from pcreg.errors import InputError, UncalibratedWarning
from _runs import drifting_frames


def _stream(tmp_path, n=6, **options):
    """``(key frame, its labels, the frames after it)`` of a drifting textured scene, and a Propagator reset to it."""
    import cv2

    tmp_path.mkdir(parents=True, exist_ok=True)
    folder, key = drifting_frames(tmp_path / "frames", shape=(96, 128), n=n)
    frames = [cv2.imread(str(p))[:, :, ::-1].copy() for p in sorted(folder.iterdir())]
    labels = cv2.imread(str(key), cv2.IMREAD_UNCHANGED)
    return frames, labels, Propagator.from_key_frame(frames[0], labels, **options)


def _interrupted_kernel(*args, **kwargs):
    """What numba's dispatcher gives when a Ctrl-C lands while its kernel runs: a SystemError from the interrupt."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:
        raise SystemError("CPUDispatcher(<function _match_window_py>) returned a result with an exception set") from exc


def test_a_ctrl_c_in_a_compiled_kernel_is_a_keyboard_interrupt_and_the_stream_goes_on(tmp_path, monkeypatch):
    """It came out of step as a SystemError, which a caller's `except KeyboardInterrupt` misses and reads as a bug."""
    import pcreg.registration.dense.window as window

    frames, labels, prop = _stream(tmp_path)
    _, _, reference = _stream(tmp_path / "b")
    for f in frames[1:3]:
        prop.step(f)
        reference.step(f)
    monkeypatch.setattr(window, "_match_window_jit", _interrupted_kernel)
    with pytest.raises(KeyboardInterrupt):
        prop.step(frames[3])
    monkeypatch.undo()
    for f in frames[3:]:  # the step that was interrupted left the stream as it was
        assert np.array_equal(prop.step(f), reference.step(f))


def test_interruptible_lets_every_other_error_through():
    with pytest.raises(KeyboardInterrupt):
        interruptible(_interrupted_kernel)()

    def other():
        raise SystemError("a bug")

    with pytest.raises(SystemError, match="a bug"):
        interruptible(other)()
    assert interruptible(lambda x: x + 1)(1) == 2


def test_a_second_thread_stepping_a_stream_while_it_steps_is_refused(tmp_path, monkeypatch):
    """Two threads stepping and resetting one Propagator interleaved its steps and raised AttributeErrors, or an
    InputError of two frame sizes that blamed the frames."""
    frames, labels, prop = _stream(tmp_path)
    inside, go = threading.Event(), threading.Event()
    real = prop._classify

    def held(frame):  # the first thread's step, held inside until the second thread has tried
        inside.set()
        assert go.wait(60)
        return real(frame)

    monkeypatch.setattr(prop, "_classify", held)
    done: list = []
    first = threading.Thread(target=lambda: done.append(prop.step(frames[1])))
    first.start()
    assert inside.wait(60)
    for call in (lambda: prop.step(frames[2]), lambda: prop.reset(frames[0], labels)):
        with pytest.raises(InputError, match=r"called while another thread's call on the same Propagator runs"):
            call()
    for fork in (copy.copy, pickle.dumps):  # a fork of half a step, which also carried the running call's mark
        with pytest.raises(InputError, match=r"copied or pickled while another thread's call on it runs"):
            fork(prop)
    go.set()
    first.join()
    monkeypatch.undo()
    assert len(done) == 1 and prop.last.frame == 1 and "_pcreg_caller" not in prop.__dict__
    prop.step(frames[2])  # the stream's own thread goes on
    assert prop.last.frame == 2


def test_a_copy_of_a_stream_is_a_fork(tmp_path):
    """copy.copy shared the state a step changes in place: stepping the copy changed the original's next labels."""
    frames, _, prop = _stream(tmp_path)
    _, _, reference = _stream(tmp_path / "b")
    for f in frames[1:3]:
        prop.step(f)
        reference.step(f)
    fork = copy.copy(prop)
    for f in frames[3:]:
        fork.step(f)
    kept = pickle.loads(pickle.dumps(prop))  # and pickled: a key-anchored stream's prepared key frame failed both
    labels = reference.step(frames[3])
    assert np.array_equal(prop.step(frames[3]), labels) and np.array_equal(kept.step(frames[3]), labels)


def test_a_weight_the_confidence_was_not_calibrated_at_warns(tmp_path):
    with pytest.warns(UncalibratedWarning, match=r"weight=20\): the confidence and the predicted error are calibrated at weight 2"):
        _stream(tmp_path / "a", weight=20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UncalibratedWarning)
        _stream(tmp_path / "b")  # the default weight
        _stream(tmp_path / "c", weight=20.0, trust=None)  # no confidence


def test_pcreg_run_with_another_weight_says_so_once(tmp_path, capsys):
    from pcreg.cli import main

    folder, key = drifting_frames(tmp_path / "frames", n=4)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out"), "--weight", "20"]) == 0
    said = capsys.readouterr()
    assert said.out.count("(the confidence is calibrated at the default --weight 2: at 20 it and the predicted error") == 1, said
    assert "UncalibratedWarning" not in said.err and "UncalibratedWarning" not in said.out
    # the command's silence is its own: it left the process's filters set, and a later Propagator warned nothing
    assert not any(f[2] is UncalibratedWarning for f in warnings.filters)


def test_two_refusals_say_what_they_mean(tmp_path):
    """``frame must be in >= 0``; float labels of CamVid's classes refused naming ground and obstacle."""
    from pcreg.classes import CAMVID11

    frames, labels, prop = _stream(tmp_path)
    with pytest.raises(InputError, match=r"^frame must be >= 0, got -1$"):
        prop.resume(-1, None)
    with pytest.raises(InputError, match=r"^labels must be integers \(the ids of camvid11\), got float32$"):
        Propagator.from_key_frame(frames[0], labels.astype(np.float32), classes=CAMVID11)


@pytest.mark.parametrize("where", ["its report", "a reset"])
def test_an_object_follower_interrupted_late_in_a_step_or_a_reset_is_left_as_it_was(shared_data, monkeypatch, where):
    """Ctrl-C while the follower made its step's report came after it had taken the step's carry and counted the
    frame: the frame given again was stepped twice (its report numbered 6 for the fifth frame, and the labels after
    it differed from an uninterrupted stream's). A reset interrupted while it made the key frame's colour table
    left the new key's object share beside the old key's colours."""
    import cv2

    import pcreg.pipeline.follow as follow
    import pcreg.pipeline.trust as trust
    from pcreg.pipeline.follow import ObjectFollower

    seq = shared_data / "davis" / "blackswan"
    frames = [cv2.imread(str(seq / "images" / f"{i:05d}.jpg"))[:, :, ::-1].copy() for i in range(6)]
    mask = (cv2.imread(str(seq / "labels" / "00000.png"), cv2.IMREAD_GRAYSCALE) > 0).astype(np.uint8)
    clean = ObjectFollower.from_key_frame(frames[0], mask)
    expected = [clean.step(f) for f in frames[1:]]
    f = ObjectFollower.from_key_frame(frames[0], mask)
    f.step(frames[1])
    f.step(frames[2])
    real = trust.class_predicted_iou if where == "its report" else follow._colour_table

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(trust if where == "its report" else follow, real.__name__, ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        f.step(frames[3]) if where == "its report" else f.reset(frames[4], 1 - mask)
    monkeypatch.undo()
    got = [f.step(x) for x in frames[3:]]
    assert f.last.frame == clean.last.frame == 5
    assert all(np.array_equal(a, b) for a, b in zip(got, expected[2:]))


def test_a_part_of_the_key_object_far_from_its_largest_is_followed(shared_data):
    """The blackswan's key mask with a second part drawn 90x200 px far from the swan: the follower kept only the
    largest part and those within 32 px of it, so the drawn part was dropped from frame 1 on, confidently."""
    import cv2

    from pcreg.pipeline.follow import ObjectFollower

    seq = shared_data / "davis" / "blackswan"
    frames = [cv2.imread(str(seq / "images" / f"{i:05d}.jpg"))[:, :, ::-1].copy() for i in range(3)]
    mask = (cv2.imread(str(seq / "labels" / "00000.png"), cv2.IMREAD_GRAYSCALE) > 0).astype(np.uint8)
    mask[380:470, 640:840] = 1
    f = ObjectFollower.from_key_frame(frames[0], mask)
    for frame in frames[1:]:
        labels = f.step(frame)
        assert (labels[380:470, 640:840] == 1).mean() > 0.8


@pytest.mark.parametrize("keys", [False, True], ids=["one label image", "a folder of key frames"])
def test_a_key_frame_of_one_colour_is_refused_naming_it(tmp_path, capsys, keys):
    """A black key frame (a video's first frame before the picture starts): it was taken, and every frame after it
    labelled from nothing (the object lost from frame 1 at a predicted error of about 54%), exit 0."""
    import cv2

    from pcreg.cli import main
    from pcreg.pipeline.follow import ObjectFollower
    from _runs import key_frames_of, one_line_errors

    folder, key = drifting_frames(tmp_path / "frames", shape=(96, 128), n=6)
    black = folder / ("f5.png" if keys else "f0.png")
    cv2.imwrite(str(black), np.zeros_like(cv2.imread(str(black))))
    labels = key_frames_of(key, tmp_path / "keys", (0, 5)) if keys else key
    assert main(["run", str(folder), "--labels", str(labels), "--out", str(tmp_path / "out")]) == 2
    assert one_line_errors(capsys) == [f"pcreg: error: {black} is one colour everywhere (0, 0, 0): as a key frame it "
                                       "holds nothing to tell its classes apart by, or to follow; choose one that "
                                       "shows the scene"]
    if keys:  # a fade to black labelled all one class says what it holds: taken
        cv2.imwrite(str(labels / "f5.png"), np.zeros_like(cv2.imread(str(labels / "f5.png"), cv2.IMREAD_UNCHANGED)))
        assert main(["run", str(folder), "--labels", str(labels), "--out", str(tmp_path / "out")]) == 0
    mask = cv2.imread(str(key), cv2.IMREAD_UNCHANGED)
    grey = np.full(mask.shape + (3,), 128, np.uint8)
    for make in (lambda: Propagator.from_key_frame(grey, mask), lambda: ObjectFollower.from_key_frame(grey, mask % 2)):
        with pytest.raises(InputError, match=r"^the key frame is one colour everywhere \(128, 128, 128\)"):
            make()


def _interrupted_twice(*args, **kwargs):
    """What a kernel loaded from numba's cache while Ctrl-C lands gives: a SystemError from a SystemError from it."""
    try:
        _interrupted_kernel()
    except SystemError as exc:
        raise SystemError("<function _numba_unpickle> returned a result with an exception set") from exc


@pytest.mark.parametrize("kernel", [_interrupted_kernel, _interrupted_twice])
def test_a_ctrl_c_in_a_kernel_of_the_public_functions_is_a_keyboard_interrupt(monkeypatch, kernel):
    """pcreg.register_dense (13 of 40 interrupts), register(model="dense") and icp raised the SystemError, and one
    wrapped twice was not unwrapped by the streams either."""
    import pcreg
    import pcreg.registration.dense.window as window

    frames = pcreg.synthetic("syn1a", 2, 0, width=160, height=120)
    monkeypatch.setattr(window, "_match_window_jit", kernel)
    for call in (lambda: pcreg.register_dense(frames[0].image, frames[1].image),
                 lambda: pcreg.register(frames[0].image, frames[1].image, model="dense")):
        with pytest.raises(KeyboardInterrupt):
            call()
    with pytest.raises(KeyboardInterrupt):
        interruptible(kernel)()


def test_a_step_interrupted_after_its_report_leaves_the_last_report_as_it_was(tmp_path, monkeypatch):
    """A Ctrl-C late in a step (after its report was made) rewound the stream but left ``last`` the report of the step
    that did not happen."""
    frames, labels, prop = _stream(tmp_path)
    prop.step(frames[1])
    before = prop.last

    def late(self, labels):
        raise KeyboardInterrupt

    monkeypatch.setattr(Propagator, "table_labels", late)
    with pytest.raises(KeyboardInterrupt):
        prop.step(frames[2])
    monkeypatch.undo()
    assert prop.last is before and prop.last.frame == 1
    assert prop.step(frames[2]) is not None and prop.last.frame == 2


def test_a_report_and_a_dense_result_equal_their_copies():
    """``==`` of a StepReport or a DenseRegistrationResult and its copy raised numpy's "truth value of an array is
    ambiguous": the arrays are compared by their values."""
    import cv2

    import pcreg

    frames = pcreg.synthetic("syn1a", 2, 0, width=128, height=96)
    result = pcreg.register_dense(frames[0].image, frames[1].image)
    assert result == copy.deepcopy(result) and result == pickle.loads(pickle.dumps(result))
    assert hash(result) == hash(copy.deepcopy(result))
    other = copy.deepcopy(result)
    object.__setattr__(other, "field", other.field + 1)
    assert result != other
    prop = Propagator.from_key_frame(frames[0].image, frames[0].labels)
    prop.step(cv2.GaussianBlur(frames[1].image, (3, 3), 0))
    report = prop.last
    assert report == copy.deepcopy(report) and report == pickle.loads(pickle.dumps(report)) and report != 1
