"""A scene cut under ``pcreg run --follow object``: the previous frame's labels are not carried across it
(the object is lost, its confidence the colours' alone), continuous frames never read as one, and the
carry that the cut test reads (the previous frame's colour histogram) round-trips through a run's files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pcreg.pipeline.follow import BINS, FollowCarry, ObjectFollower


def _cut(shared_data, a: str, b: str, n: int):
    """``n`` frames of DAVIS sequence ``a`` then ``n`` of ``b`` at ``a``'s size, with their masks."""
    from pcreg.datasets.davis import load_sequence

    seqs = []
    for name in (a, b):
        root = shared_data / "davis" / name
        if not root.is_dir():
            pytest.skip(f"{root} is absent (the shared DAVIS sequences)")
        seqs.append(load_sequence(root / "images", root / "labels", n_frames=n))
    h, w = seqs[0][0].image.shape[:2]
    images = [f.image for f in seqs[0]] + [cv2.resize(f.image, (w, h), interpolation=cv2.INTER_AREA) for f in seqs[1]]
    truth = [f.labels for f in seqs[0]] + [cv2.resize(f.labels, (w, h), interpolation=cv2.INTER_NEAREST)
                                           for f in seqs[1]]
    return images, truth


def test_labels_carried_across_a_cut_are_not_trusted(shared_data):
    images, truth = _cut(shared_data, "goat", "blackswan", 4)
    follower = ObjectFollower.from_key_frame(images[0], truth[0])
    cuts, sure_wrong = [], []
    for image, t in zip(images[1:], truth[1:]):
        labels = follower.step(image)
        cuts.append(follower.last.trust_summary["cut"])
        sure_wrong.append(float(((labels != t) & (t < 2) & (follower.last.confidence > 0.9)).mean()))
    # without the cut test the goat's labels flowed onto the swan's lake: 7-8% of each frame wrong and
    # sure (> 0.9); lost, nothing is labelled the object and the colours alone are its confidence
    assert max(sure_wrong[3:]) < 0.01, sure_wrong
    assert cuts == [False, False, False, True, False, False, False], cuts
    assert not follower.carry.labels.any()


def test_a_cut_is_both_a_poor_flow_and_new_colours(shared_data):
    images, truth = _cut(shared_data, "blackswan", "car-roundabout", 2)
    follower = ObjectFollower.from_key_frame(images[0], truth[0])
    follower.step(images[1])
    same = follower.last.trust_summary
    follower.step(images[2])
    cut = follower.last.trust_summary
    assert same["residual"] < 0.3 and same["colour_change"] < 0.45 and not same["cut"]
    assert cut["residual"] > 0.3 and cut["colour_change"] > 0.45 and cut["cut"]


def test_a_followers_colour_histogram_round_trips_and_an_older_carry_reads_without_it(tmp_path):
    from pcreg.errors import InputError, OutputError
    from pcreg.runs.files import read_carry, write_carry

    colours = np.full(BINS ** 3, 1.0 / BINS ** 3, np.float32)
    carry = FollowCarry(np.eye(6, 8, dtype=np.uint8), np.full((6, 8), 7, np.uint8), colours)
    write_carry(tmp_path / "c.npz", 3, carry, None)
    back, _ = read_carry(tmp_path / "c.npz", 3, "")
    assert np.array_equal(back.colours, colours)
    write_carry(tmp_path / "old.npz", 3, FollowCarry(carry.labels, carry.grey), None)
    assert read_carry(tmp_path / "old.npz", 3, "")[0].colours is None
    np.savez(tmp_path / "bad.npz", frame=np.int64(3), grid=np.zeros((0, 0, 2), np.float32),
             evidence=np.float64("nan"), learned=np.zeros(0), follow=np.stack([carry.labels, carry.grey]),
             follow_colours=np.zeros(7, np.float32))
    with pytest.raises(OutputError, match="use --force"):
        read_carry(tmp_path / "bad.npz", 3, "")
    with pytest.raises(InputError, match="colour histogram"):
        FollowCarry(carry.labels, carry.grey, np.zeros(BINS ** 3))
