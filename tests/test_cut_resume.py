"""A stream resumed after a scene cut goes on as the uninterrupted one: the cut test's last frame of the key
frame's scene is handed on with the carry (:mod:`pcreg.pipeline.cuts`), so the frames after the cut are still
found in another scene, and their confidence and steps are those of the whole run."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from _runs import assert_same_run, stopped_and_resumed


def _spliced(shared_data, n: int = 4) -> list[np.ndarray]:
    """``n`` CamVid frames of 0001TP, then ``n`` of 0016E5 at the same size: a scene cut after frame ``n - 1``."""
    clips = []
    for clip in ("0001TP", "0016E5"):
        folder = shared_data / "camvid" / clip / "images"
        if not folder.is_dir():
            pytest.skip(f"{folder} is absent (the shared CamVid clips)")
        clips.append([cv2.imread(str(p))[:, :, ::-1].copy() for p in sorted(folder.iterdir())[:n]])
    h, w = clips[0][0].shape[:2]
    return clips[0] + [cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA) for im in clips[1]]


def _key_labels(shared_data) -> np.ndarray:
    from pcreg.classes.mappings import mapping_lut

    folder = shared_data / "camvid" / "0001TP" / "labels"
    return mapping_lut("camvid")[cv2.imread(str(sorted(folder.iterdir())[0]), cv2.IMREAD_UNCHANGED)]


def test_a_propagator_resumed_after_a_cut_still_finds_the_other_scene(shared_data, tmp_path):
    from pcreg.pipeline.stream import Propagator
    from pcreg.runs.files import read_carry, write_carry

    images, key = _spliced(shared_data), _key_labels(shared_data)
    whole = Propagator.from_key_frame(images[0], key)
    saved, expected = {}, {}
    for t, image in enumerate(images[1:], 1):
        whole.step(image)
        expected[t] = (whole.last.trust_summary["cut"], whole.last.confidence.copy())
        saved[t] = (whole.carry, whole.learned, whole.scene)
    assert [expected[t][0] for t in range(1, 8)] == [False, False, False, True, True, True, True]
    write_carry(tmp_path / "carry.npz", 5, *saved[5])
    carry, learned, scene = read_carry(tmp_path / "carry.npz", 5, "", with_scene=True)
    resumed = Propagator.from_key_frame(images[0], key)
    resumed.resume(5, carry, learned, scene)
    for t in (6, 7):  # still tested against the last frame before the cut: found in the other scene
        resumed.step(images[t])
        assert resumed.last.trust_summary["cut"] == expected[t][0], t
        np.testing.assert_array_equal(resumed.last.confidence, expected[t][1])
    np.testing.assert_array_equal(scene.grey, saved[3][2].grey)  # the last frame before the cut, kept since
    forgetful = Propagator.from_key_frame(images[0], key)
    forgetful.resume(5, carry, learned)  # a carry saved before the scene was kept: frame 6 starts a scene
    forgetful.step(images[6])
    assert not forgetful.last.trust_summary["cut"]


def test_a_carry_without_its_scene_reads_as_none_and_a_damaged_one_is_refused(tmp_path):
    from pcreg.errors import InputError, OutputError
    from pcreg.pipeline.cuts import Scene
    from pcreg.pipeline.follow import BINS
    from pcreg.pipeline.stream import Propagator
    from pcreg.runs.files import read_carry, write_carry

    scene = Scene(np.full((6, 8), 7, np.uint8), np.full(BINS ** 3, 1.0 / BINS ** 3, np.float32))
    write_carry(tmp_path / "c.npz", 3, None, None, scene)
    assert read_carry(tmp_path / "c.npz", 3, "") == (None, None)
    back = read_carry(tmp_path / "c.npz", 3, "", with_scene=True)[2]
    assert np.array_equal(back.grey, scene.grey) and np.array_equal(back.colours, scene.colours)
    write_carry(tmp_path / "old.npz", 3, None, None)  # as a run saved it before the scene was kept
    assert read_carry(tmp_path / "old.npz", 3, "", with_scene=True) == (None, None, None)
    for members in ({"scene_grey": scene.grey}, {"scene_grey": scene.grey, "scene_colours": np.zeros(7, np.float32)},
                    {"scene_grey": scene.grey.astype(np.float32), "scene_colours": scene.colours}):
        np.savez(tmp_path / "bad.npz", frame=np.int64(3), grid=np.zeros((0, 0, 2), np.float32),
                 evidence=np.float64("nan"), learned=np.zeros(0), **members)
        with pytest.raises(OutputError, match="use --force"):
            read_carry(tmp_path / "bad.npz", 3, "", with_scene=True)
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)
    prop = Propagator.from_key_frame(image, (np.arange(96)[:, None] > 48).repeat(128, axis=1).astype(np.uint8))
    with pytest.raises(InputError, match="Scene"):
        prop.resume(2, None, None, scene.grey)
    prop.resume(2, None, None, Scene(np.full((48, 64), 7, np.uint8), scene.colours))  # half the key frame's size
    with pytest.raises(InputError, match="scene frame is 8x6, a stream of these frames keeps 64x48"):
        prop.resume(3, None, None, scene)  # another stream's: refused, and nothing changed
    assert prop.scene.grey.shape == (48, 64) and prop.scene.grey[0, 0] == 7


def test_a_run_stopped_after_a_cut_resumes_as_the_whole_one(shared_data, tmp_path, monkeypatch):
    from pcreg.classes import DEFAULT_TABLE, write_label_png

    images = _spliced(shared_data)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"f{i}.png"), image[:, :, ::-1])
    write_label_png(tmp_path / "key.png", _key_labels(shared_data), DEFAULT_TABLE)
    args = ["run", str(folder), "--labels", str(tmp_path / "key.png"), "--confidence"]
    whole, cut = stopped_and_resumed(monkeypatch, args, tmp_path, 6)
    assert_same_run(whole, cut, len(images))


def test_a_key_folder_run_stopped_after_a_cut_resumes_as_the_whole_one(shared_data, tmp_path, monkeypatch):
    import json

    from _runs import kill_at_commit, timeless

    from pcreg.classes import DEFAULT_TABLE, write_label_png
    from pcreg.cli import main

    images = _spliced(shared_data)
    folder, keys = tmp_path / "frames", tmp_path / "keys"
    folder.mkdir()
    keys.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"f{i}.png"), image[:, :, ::-1])
    write_label_png(keys / "f0.png", _key_labels(shared_data), DEFAULT_TABLE)
    args = ["run", str(folder), "--labels", str(keys), "--confidence"]
    assert main([*args, "--out", str(tmp_path / "whole")]) == 0
    kill_at_commit(monkeypatch, 9, "forward")  # after frame 6's, the cut after frame 3
    assert main([*args, "--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    assert json.loads((tmp_path / "cut" / "run.json").read_text())["cursor"]["steps"] == 6
    assert main([*args, "--out", str(tmp_path / "cut")]) == 0
    for i in range(1, len(images)):
        for name in (f"f{i}.png", f"confidence/f{i}.png"):
            assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "cut" / name).read_bytes(), name
    steps = [[timeless(line) for line in (run / "steps.jsonl").read_text().splitlines()]
             for run in (tmp_path / "whole", tmp_path / "cut")]
    assert steps[0] == steps[1] and [s["trust"]["cut"] for s in steps[0]] == [False] * 3 + [True] * 4


def _camvid11_labels(shared_data, clip: str, t: int, shape) -> np.ndarray:
    folder = shared_data / "camvid" / clip / "labels"
    labels = cv2.imread(str(sorted(folder.iterdir())[t]), cv2.IMREAD_UNCHANGED)
    return cv2.resize(labels, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


@pytest.mark.parametrize("classes", ["camvid11", "lagr"])
def test_frames_between_key_frames_of_two_shots_report_the_labels_written(shared_data, tmp_path, classes):
    """Key frames on each side of a scene cut (0001TP's frame 0, 0016E5's frame 2 of 4 spliced after it): each frame
    between them said in ``steps.jsonl`` the backward pass's cut test (frames of the first shot "cut": true, those past
    the cut false) and its predicted IoU, of classes the labels written did not hold. The line says the forward pass's
    cut beside its fallback, ``cut`` true only where neither key frame's scene holds the frame, and the predicted IoU
    of the labels written."""
    import json

    from PIL import Image

    from pcreg.cli import main

    images = _spliced(shared_data)
    frames, keys = tmp_path / "frames", tmp_path / "keys"
    frames.mkdir()
    keys.mkdir()
    for t, image in enumerate(images):
        cv2.imwrite(str(frames / f"f{t}.png"), cv2.resize(image, (240, 180), interpolation=cv2.INTER_AREA)[:, :, ::-1])
    for t, (clip, at) in {0: ("0001TP", 0), 6: ("0016E5", 2)}.items():
        labels = _camvid11_labels(shared_data, clip, at, (180, 240))
        if classes == "lagr":
            from pcreg.classes.mappings import mapping_lut

            labels = mapping_lut("camvid")[labels]
        cv2.imwrite(str(keys / f"f{t}.png"), labels)
    out = tmp_path / "out"
    assert main(["run", str(frames), "--labels", str(keys), "--classes", classes, "--out", str(out)]) == 0
    steps = {s["name"]: s for s in map(json.loads, (out / "steps.jsonl").read_text().splitlines())}
    unknown = 11 if classes == "camvid11" else 2
    for t in range(1, 6):
        step = steps[f"f{t}.png"]
        assert step["forward"]["cut"] == (t >= 4) and step["trust"]["cut"] is False, (t, step["trust"], step["forward"])
        held = {int(c) for c in np.unique(np.asarray(Image.open(out / f"f{t}.png")))} - {unknown}  # a palette PNG's ids
        assert {int(k) for k in step["predicted_iou"]} == held, t


def test_a_frame_between_key_frames_in_neither_scene_is_marked_as_a_cut_is():
    """A frame both passes' cut tests found outside their key frame's scene (a third shot between the key frames'):
    its confidence is the least, as a stream's after a cut (the labels are read as before); found by one pass only,
    the confidence is read as it was."""
    from pcreg.pipeline.engine import two_sided
    from pcreg.pipeline.trust import STREAM_TRUST, least_confidence

    rng = np.random.default_rng(1)
    d, earlier, later = (rng.normal(0, 2, (60, 80)).astype(np.float32) for _ in range(3))
    plain = two_sided(d, earlier, later, STREAM_TRUST)
    one = two_sided(d, earlier, later, STREAM_TRUST, cuts=(True, False))
    both = two_sided(d, earlier, later, STREAM_TRUST, cuts=(True, True))
    for read in (one, both):
        np.testing.assert_array_equal(read[0], plain[0])
    np.testing.assert_array_equal(one[1], plain[1])
    assert plain[1].min() < 0.9 < plain[1].max() and np.all(both[1] == least_confidence(2)) and least_confidence(2) == 0.5
