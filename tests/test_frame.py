"""A frame checked once (pcreg.frame.PreparedFrame): every function that takes an image takes it as it
is, nothing derived from it is computed twice, and the caller's array is never changed."""

from __future__ import annotations

import numpy as np
import pytest

import pcreg
from pcreg.classification.features import frame_features
from pcreg.errors import InputError
from pcreg.frame import PreparedFrame, as_rgb_uint8


def _image(h=48, w=64, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_a_prepared_frame_is_checked_once_read_only_and_the_callers_array_stays_writable():
    img = _image()
    frame = PreparedFrame.of(img)
    assert frame.shape == (48, 64) and np.shares_memory(frame.rgb, img)
    assert not frame.rgb.flags.writeable and img.flags.writeable
    with pytest.raises(ValueError):
        frame.rgb[0, 0, 0] = 1
    assert PreparedFrame.of(frame) is frame and as_rgb_uint8(frame) is frame.rgb
    grey = PreparedFrame.of(np.full((16, 16), 0.5))  # converted once, as every image is
    assert grey.rgb.dtype == np.uint8 and grey.rgb.shape == (16, 16, 3) and int(grey.rgb[0, 0, 0]) == 128
    with pytest.raises(InputError, match="frame of shape"):
        PreparedFrame.of(img, shape=(40, 64))
    with pytest.raises(InputError, match="NaN"):
        PreparedFrame.of(np.full((16, 16, 3), np.nan))


def test_what_is_derived_from_a_frame_is_made_once_and_is_the_same_as_from_the_array():
    img = _image(seed=1)
    frame = PreparedFrame.of(img)
    calls = []
    assert frame.derived("k", lambda rgb: calls.append(1) or rgb.sum()) == img.sum()
    assert frame.derived("k", lambda rgb: calls.append(1) or 0) == img.sum() and calls == [1]
    groups = frame_features(frame, ("rgb", "hsv", "row"))
    assert frame_features(frame, ("rgb", "hsv", "row")) is groups  # kept with the frame
    for (name, a), (name_b, b) in zip(groups, frame_features(img, ("rgb", "hsv", "row"))):
        assert name == name_b
        np.testing.assert_array_equal(a, b)
    frames = pcreg.synthetic("syn1a", 2, 0, width=64, height=48)
    clf = pcreg.fit_classifier([frames[0]])
    frame = PreparedFrame.of(frames[1].image)
    np.testing.assert_array_equal(clf.decision_function(frame), clf.decision_function(frames[1].image))
    np.testing.assert_array_equal(clf.predict(frame), clf.predict(frames[1].image))


def test_a_stream_learns_the_same_when_its_counts_wait_for_the_next_frame():
    # the learner counts a frame's sure pixels when the classifier is next wanted: the histogram read
    # between two steps (what `pcreg run` saves) is the one counted at once
    from pcreg.classification.bayes import class_histograms
    from pcreg.pipeline.learning import Learner, Learning

    frames = pcreg.synthetic("syn1a", 4, 0, width=64, height=48)
    clf = pcreg.fit_classifier([frames[0]])
    rule = Learning(sure=0.0, stride=2, decay=0.5)
    learner, direct = Learner(clf, rule), np.zeros_like(np.asarray(clf.counts_, np.float64))
    for f in frames[1:]:
        fused = np.where(f.labels == 1, 5.0, -5.0).astype(np.float32)
        learner.update(PreparedFrame.of(f.image), fused, fused)
        labels = np.where(f.labels[::2, ::2] == 1, 1, 0).astype(np.uint8)
        direct = 0.5 * direct + class_histograms(np.ascontiguousarray(f.image[::2, ::2]), labels, clf.features)
        np.testing.assert_array_equal(learner.stream, direct)


def test_a_prepared_frame_is_an_array_to_numpy_and_to_every_public_function():
    frames = pcreg.synthetic("syn1a", 2, 0, width=96, height=72)
    a, b = PreparedFrame.of(frames[0].image), PreparedFrame.of(frames[1].image)
    assert np.asarray(a) is a.rgb and np.array(a).flags.writeable  # a copy only when asked for
    assert np.asarray(a, dtype=np.float32).dtype == np.float32
    with pytest.raises(ValueError):
        np.asarray(a, dtype=np.float32, copy=False)
    np.testing.assert_array_equal(pcreg.warp(a, np.eye(3))[0], pcreg.warp(frames[0].image, np.eye(3))[0])
    clf = pcreg.fit_classifier([pcreg.Frame(a, frames[0].labels, "key")])
    np.testing.assert_array_equal(clf.predict(b), pcreg.fit_classifier([frames[0]]).predict(frames[1].image))
    r, r_array = pcreg.register(a, b), pcreg.register(frames[0].image, frames[1].image)
    np.testing.assert_array_equal(r.T_ref_mov, r_array.T_ref_mov)


@pytest.mark.parametrize("anchor", ["key", "previous"])
def test_a_stream_whose_frames_come_in_one_reused_buffer_labels_as_from_separate_arrays(anchor):
    # a camera driver or a decoder writes each frame into the same array: the key frame (and a chained
    # stream's previous frame) must be the propagator's own copy
    frames = pcreg.synthetic("syn1a", 4, 0, width=96, height=72)
    prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, anchor=anchor)
    want = [prop.step(f.image) for f in frames[1:]]
    buffer = frames[0].image.copy()
    prop = pcreg.Propagator.from_key_frame(buffer, frames[0].labels, anchor=anchor)
    for f, labels in zip(frames[1:], want):
        buffer[...] = f.image
        np.testing.assert_array_equal(prop.step(buffer), labels)
