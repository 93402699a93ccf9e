"""An object lost at a scene cut under ``pcreg run --follow object`` is found again when a later frame is back
in its shot (shot, another shot, the first shot again), never in the other shot, and a run stopped while it is
lost resumes exactly (the last frame that held it is saved with every frame)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.pipeline.follow import BINS, FollowCarry, ObjectFollower
from _runs import assert_same_run, kill_before_commit

SIZE = (427, 240)  # half DAVIS's 854x480: the steps run at 213x120


def _frames(shared_data, name: str, first: int, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """DAVIS sequence ``name``'s frames ``first`` .. ``first + n - 1`` at :data:`SIZE`, with their masks."""
    from pcreg.datasets.davis import load_sequence

    root = shared_data / "davis" / name
    if not root.is_dir():
        pytest.skip(f"{root} is absent (the shared DAVIS sequences)")
    frames = load_sequence(root / "images", root / "labels", n_frames=first + n)[first:]
    return [(cv2.resize(f.image, SIZE, interpolation=cv2.INTER_AREA),
             cv2.resize(f.labels, SIZE, interpolation=cv2.INTER_NEAREST)) for f in frames]


def _shots(shared_data, back: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """goat's frames 0-4, blackswan's 0-2 (no goat: all background), then goat's 5-7 when ``back``."""
    swan = [(image, np.zeros_like(labels)) for image, labels in _frames(shared_data, "blackswan", 0, 3)]
    return _frames(shared_data, "goat", 0, 5) + swan + (_frames(shared_data, "goat", 5, 3) if back else [])


def _follow(frames) -> tuple[list[np.ndarray], list[dict], ObjectFollower]:
    follower = ObjectFollower.from_key_frame(*frames[0])
    labels, summaries = [], []
    for image, _ in frames[1:]:
        labels.append(follower.step(image))
        summaries.append(follower.last.trust_summary)
    return labels, summaries, follower


def test_an_object_lost_at_a_cut_is_found_again_where_its_shot_returns(shared_data):
    labels, summaries, _ = _follow(_shots(shared_data, back=True))
    unbroken, _, _ = _follow(_frames(shared_data, "goat", 0, 8))
    assert [s["cut"] for s in summaries] == [False] * 4 + [True, False, False, True, False, False]
    assert [s["back"] for s in summaries] == [False] * 7 + [True, False, False]
    assert not any(frame.any() for frame in labels[4:7])  # the swan's frames: no goat
    # back in goat's shot, the frame before the cut's labels are carried as if the swan had not been there
    for returned, whole in zip(labels[7:], unbroken[4:]):
        assert np.array_equal(returned, whole)
        assert returned.any()


def test_an_object_never_back_is_not_found_in_the_other_shot(shared_data):
    frames = _shots(shared_data, back=False) + [(image, 0 * labels) for image, labels in
                                                _frames(shared_data, "blackswan", 3, 3)]
    labels, summaries, follower = _follow(frames)
    assert not any(s["back"] for s in summaries)
    assert not any(frame.any() for frame in labels[4:])
    assert follower.carry.held is not None and follower.carry.held.labels.any()  # still searched for


def test_a_run_stopped_while_the_object_is_lost_resumes_exactly(shared_data, tmp_path, monkeypatch):
    frames = _shots(shared_data, back=True)[:10]  # f0 .. f9: one width
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, (image, _) in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i}.png"), image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "key.png"), frames[0][1])
    base = ["run", str(folder), "--labels", str(tmp_path / "key.png"), "--follow", "object", "--confidence"]
    assert main([*base, "--out", str(tmp_path / "whole")]) == 0
    kill_before_commit(monkeypatch, 7)  # the swan's last frame, resumed from the one before it
    assert main([*base, "--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    assert main([*base, "--out", str(tmp_path / "cut")]) == 0
    assert_same_run(tmp_path / "whole", tmp_path / "cut", len(frames))


def test_the_frame_before_a_cut_round_trips_in_a_runs_carry(tmp_path):
    from pcreg.errors import InputError, OutputError
    from pcreg.runs.files import read_carry, write_carry

    colours = np.full(BINS ** 3, 1.0 / BINS ** 3, np.float32)
    held = FollowCarry(np.eye(6, 8, dtype=np.uint8), np.full((6, 8), 9, np.uint8), colours)
    carry = FollowCarry(np.zeros((6, 8), np.uint8), np.full((6, 8), 7, np.uint8), colours, held)
    write_carry(tmp_path / "c.npz", 3, carry, None)
    back, _ = read_carry(tmp_path / "c.npz", 3, "")
    assert np.array_equal(back.held.labels, held.labels) and np.array_equal(back.held.grey, held.grey)
    assert np.array_equal(back.held.colours, colours)
    np.savez(tmp_path / "bad.npz", frame=np.int64(3), grid=np.zeros((0, 0, 2), np.float32),
             evidence=np.float64("nan"), learned=np.zeros(0), follow=np.stack([carry.labels, carry.grey]),
             follow_colours=colours, follow_held=np.stack([held.labels, held.grey]))
    with pytest.raises(OutputError, match="use --force"):
        read_carry(tmp_path / "bad.npz", 3, "")
    with pytest.raises(InputError, match="before a cut"):
        FollowCarry(carry.labels, carry.grey, colours, FollowCarry(held.labels, held.grey))
