"""A stream's state is its own: it keeps no array its caller may write into afterwards (the key labels, a
frame, a resumed carry), and what it gives out to be saved (its scene, a follower's carry) cannot be written
into to change the steps that follow."""

from __future__ import annotations

import numpy as np
import pytest

import pcreg
from pcreg.classes import CAMVID11


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 4, 0, width=160, height=120)


def _eleven(labels: np.ndarray) -> np.ndarray:
    """The synthetic ground, obstacle and unknown as camvid11's road, sidewalk and void."""
    return np.array([3, 4, CAMVID11.unknown], np.uint8)[labels]


def test_many_class_key_labels_written_after_reset_leave_the_stream_as_it_was(frames):
    """With more than two classes the stream kept the caller's label array itself (the class table's check
    returns a uint8 array as it is): a caller who reused it (the next clip's key labels read into the same
    buffer) changed every later step's labels, and ``key_labels``, without a word."""
    def labels_after(write: bool) -> list[np.ndarray]:
        labels = _eleven(frames[0].labels)
        prop = pcreg.Propagator.from_key_frame(frames[0].image, labels, classes=CAMVID11)
        if write:
            labels[:] = 3
        return [prop.step(f.image) for f in frames[1:]] + [prop.key_labels]

    for kept, written in zip(labels_after(False), labels_after(True)):
        assert np.array_equal(kept, written)


def _steps(prop, frames) -> list:
    out = []
    for f in frames:
        out += [prop.step(f.image), prop.last.confidence, prop.last.trust_summary.get("cut")]
    return out


def _same(a: list, b: list) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def _zeroed(scene) -> None:
    for a in (scene.grey, scene.colours):
        if a.flags.writeable:
            a[...] = 0


def test_the_scene_a_stream_gives_or_resumes_from_is_not_written_through(frames):
    """``Propagator.scene`` gave the cut test's own arrays, and ``resume`` kept the caller's: a caller who wrote
    into them (a buffer reused for saving) made every later frame a cut, its confidence the least the stream
    gives."""
    def steps(write) -> list:
        prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
        out = []
        for f in frames[1:]:
            out += _steps(prop, [f])
            write(prop)
        return out

    def resumed(prop) -> None:  # resumed from a scene of the caller's, then the caller's array written
        scene = prop.scene
        own = type(scene)(scene.grey.copy(), scene.colours.copy())
        prop.resume(prop.last.frame, prop.carry, prop.learned, own)
        _zeroed(own)

    untouched = steps(lambda prop: None)
    assert not any(untouched[2::3])
    assert _same(untouched, steps(lambda prop: _zeroed(prop.scene)))
    assert _same(untouched, steps(resumed))


def _zero_carry(carry) -> None:
    for a in (carry.labels, carry.grey):
        if a.flags.writeable:
            a[...] = 0


def test_the_carry_a_follower_gives_or_resumes_from_is_not_written_through():
    """``ObjectFollower.carry`` gave the follower's own labels and grey levels, and ``resume`` kept the caller's: a
    caller who wrote into them lost the object (every later frame read against 'nowhere') without a word."""
    from pcreg.pipeline.follow import FollowCarry, ObjectFollower
    from test_follow_objects import moving_object

    pairs = moving_object(5)

    def steps(write) -> list:
        follower = ObjectFollower.from_key_frame(*pairs[0])
        out = []
        for image, _ in pairs[1:]:
            out += [follower.step(image), follower.last.confidence]
            write(follower)
        return out

    def resumed(follower) -> None:  # resumed from a carry of the caller's, then the caller's arrays written
        c = follower.carry
        own = FollowCarry(c.labels.copy(), c.grey.copy(), c.colours.copy())
        follower.resume(follower.last.frame, own)
        _zero_carry(own)

    untouched = steps(lambda follower: None)
    assert untouched[-2].any()  # the object followed to the last frame
    assert _same(untouched, steps(lambda follower: _zero_carry(follower.carry)))
    assert _same(untouched, steps(resumed))


@pytest.mark.parametrize("stride", [1, 3])
def test_a_frame_written_after_its_step_is_not_learned_from(frames, stride):
    """With ``Learning(stride=1)`` the learner kept the frame itself (a one-in-one sample of it is a view) until the
    next step counted it: a caller who decodes every frame into one buffer taught naive Bayes the next frame's
    colours with this frame's labels."""
    from pcreg.pipeline.learning import Learning

    def steps(buffered: bool) -> list:
        prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, learning=Learning(stride=stride))
        buffer = np.empty_like(frames[0].image)
        out = []
        for f in frames[1:]:
            buffer[...] = f.image
            out.append(prop.step(buffer if buffered else f.image.copy()))
            buffer[...] = 0
        return out + [prop.learned]

    learned = steps(False)
    assert learned[-1].any()
    assert _same(learned, steps(True))


def test_a_chained_stream_resumed_from_a_callers_frame_keeps_its_own(frames):
    """A chained stream (``anchor="previous"``) resumed from a :class:`ChainCarry` of the caller's registered the next
    frame to the caller's array itself: written afterwards (the buffer it was read into), the next step's reference
    was whatever the caller wrote there."""
    from pcreg.pipeline.estimators import ChainCarry

    def steps(write: bool) -> list:
        prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, anchor="previous")
        prop.step(frames[1].image)
        c = prop.carry
        own = ChainCarry(c.rgb.copy(), c.motion, c.frame)
        prop.resume(prop.last.frame, own, prop.learned, prop.scene)
        if write:
            own.rgb[...] = 0
        return _steps(prop, frames[2:])

    assert _same(steps(False), steps(True))


class _FailsOnce:
    """A caller's classifier that fails on its ``fail_at``-th frame (out of memory on a GPU, say), else pcreg's."""

    def __init__(self, nb, fail_at: int | None) -> None:
        self.nb, self.calls, self.fail_at = nb, 0, fail_at
        self.classes_, self.class_prior_ = nb.classes_, nb.class_prior_

    def decision_function(self, image):
        self.calls += 1
        if self.calls == self.fail_at:
            raise MemoryError("out of memory")
        return self.nb.decision_function(image)


@pytest.mark.parametrize("anchor", ["key", "previous"])
def test_a_step_that_raises_leaves_the_stream_as_it_was(anchor):
    """A step that raised after its frame was checked had counted the frame and kept its warm start and its cut
    test's frame: the steps after it were numbered one on, and their labels and confidence were not those of the
    stream that was never given that frame."""
    frames = pcreg.synthetic("syn1a", 5, 0, width=160, height=120)
    nb = pcreg.fit_classifier([frames[0]])

    def steps(fail: bool) -> list:
        prop = pcreg.Propagator(_FailsOnce(nb, 2 if fail else None), anchor=anchor)
        prop.reset(frames[0].image, frames[0].labels)
        prop.step(frames[1].image)
        if fail:
            with pytest.raises(MemoryError):
                prop.step(frames[2].image)
        out = []
        for f in frames[3:]:
            out += [prop.step(f.image), prop.last.confidence, prop.last.frame]
        return out

    never_given = steps(False)
    assert never_given[2::3] == [2, 3]
    assert _same(never_given, steps(True))
