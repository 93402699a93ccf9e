"""A letterboxed or pillarboxed video: its black bars keep the key frame's labels (pcreg.pipeline.bars)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pcreg.classes import CAMVID11, LAGR
from pcreg.pipeline.bars import BLACK, Bars
from pcreg.pipeline.stream import Propagator
from pcreg.pipeline.trust import predicted_error

PAD = 40  # rows of black above and below the picture


def _frames(shared_data, n: int = 4):
    folder = shared_data / "camvid" / "0001TP"
    names = sorted(p.name for p in (folder / "images").iterdir())[:n]
    images = [cv2.cvtColor(cv2.imread(str(folder / "images" / f)), cv2.COLOR_BGR2RGB) for f in names]
    labels = cv2.imread(str(folder / "labels" / names[0]), cv2.IMREAD_UNCHANGED)
    return images, labels


def _letterboxed(image: np.ndarray, noise: int = 0) -> np.ndarray:
    out = cv2.copyMakeBorder(image, PAD, PAD, 0, 0, cv2.BORDER_CONSTANT, value=(0, 0, 0))
    if noise:  # a codec's black: 0 to ``noise``
        rng = np.random.default_rng(0)
        bars = np.zeros(out.shape[:2], bool)
        bars[:PAD], bars[-PAD:] = True, True
        out[bars] = rng.integers(0, noise + 1, size=(int(bars.sum()), 3), dtype=np.uint8)
    return out


def test_bars_found_at_each_edge_and_not_in_a_picture_or_a_black_frame():
    rgb = np.full((60, 80, 3), 120, np.uint8)
    assert Bars.of(rgb, np.zeros((60, 80), np.uint8)) is None
    rgb[:5], rgb[-7:], rgb[:, :3], rgb[:, -2:] = BLACK, 0, 9, 3
    bars = Bars.of(rgb, np.zeros((60, 80), np.uint8))
    assert bars is not None and bars.edges == (5, 7, 3, 2)
    assert bars.picture == (slice(5, 53), slice(3, 78)) and int(bars.mask.sum()) == 60 * 80 - 48 * 75
    rgb[:5, 40, 1] = BLACK + 1  # one pixel brighter than black ends the top bar, and the bottom one has no pair
    assert Bars.of(rgb, np.zeros((60, 80), np.uint8)).edges == (0, 0, 3, 2)


def test_a_dark_scene_black_at_one_edge_or_more_at_one_than_the_other_has_no_bars():
    """A night frame whose sky is black for 40 rows kept the key frame's labels there at confidence 1, the rows
    left out of its predicted error: bars come in pairs at opposite edges, about as wide (a centred picture)."""
    rgb = np.full((120, 160, 3), 90, np.uint8)
    rgb[:40] = 5
    assert Bars.of(rgb, np.zeros((120, 160), np.uint8)) is None
    rgb[-10:] = 3  # dark road at the bottom too, of another width
    assert Bars.of(rgb, np.zeros((120, 160), np.uint8)) is None
    rgb[-38:] = 3  # as wide, within a tenth: letterbox bars
    assert Bars.of(rgb, np.zeros((120, 160), np.uint8)).edges == (40, 38, 0, 0)
    assert Bars.of(np.zeros((60, 80, 3), np.uint8), np.zeros((60, 80), np.uint8)) is None


def test_a_frame_holds_its_bars_with_subtitles_on_them_but_not_once_the_picture_fills_it():
    rgb = np.full((100, 100, 3), 120, np.uint8)
    rgb[:20], rgb[-20:] = 0, 0
    bars = Bars.of(rgb, np.zeros((100, 100), np.uint8))
    frame = rgb.copy()
    frame[-15:-5, 20:80] = 255  # a line of subtitles on the lower bar
    assert bars.held(frame)
    assert not bars.held(np.full((100, 100, 3), 120, np.uint8))


@pytest.mark.parametrize("table", [CAMVID11, LAGR], ids=["eleven classes", "two classes"])
def test_a_letterboxed_clip_keeps_the_key_frames_labels_on_its_bars(shared_data, table):
    images, camvid = _frames(shared_data)
    key_labels = camvid if table is CAMVID11 else np.select([camvid == 3, camvid == 11], [0, 2], 1).astype(np.uint8)
    unknown = table.unknown
    padded = cv2.copyMakeBorder(key_labels, PAD, PAD, 0, 0, cv2.BORDER_CONSTANT, value=int(unknown))
    prop = Propagator.from_key_frame(_letterboxed(images[0]), padded, classes=table)
    for image in images[1:]:
        labels = prop.step(_letterboxed(image, noise=12))
        conf = prop.last.confidence
        bars = np.zeros(labels.shape, bool)
        bars[:PAD], bars[-PAD:] = True, True
        assert (labels[bars] == unknown).all()  # not the class of black the classifier knows
        assert (conf[bars] == 1.0).all()
        # the frame's predicted error is the picture's, not lowered by the bars
        assert prop.last.predicted_error == pytest.approx(predicted_error(conf[PAD:-PAD]))
        assert prop.last.predicted_error > predicted_error(conf) + 1.0
        assert str(int(unknown)) not in {str(k) for k in prop.last.trust_summary["predicted_iou"]}


def test_an_object_followed_in_a_letterboxed_clip_is_scored_on_the_picture(shared_data):
    from pcreg.pipeline.follow import ObjectFollower

    folder = shared_data / "davis" / "blackswan"
    names = sorted(p.name for p in (folder / "images").iterdir())[:3]
    images = [_letterboxed(cv2.cvtColor(cv2.imread(str(folder / "images" / n)), cv2.COLOR_BGR2RGB)) for n in names]
    mask = cv2.imread(str(sorted((folder / "labels").iterdir())[0]), cv2.IMREAD_UNCHANGED)
    key = cv2.copyMakeBorder((mask > 0).astype(np.uint8), PAD, PAD, 0, 0, cv2.BORDER_CONSTANT, value=0)
    follower = ObjectFollower.from_key_frame(images[0], key)
    for image in images[1:]:
        labels = follower.step(image)
        conf = follower.last.confidence
        assert (labels[:PAD] == 0).all() and (labels[-PAD:] == 0).all() and (conf[:PAD] == 1.0).all()
        assert follower.last.predicted_error == pytest.approx(predicted_error(conf[PAD:-PAD]))


def test_the_frames_between_two_key_frames_keep_the_bars_too(shared_data, tmp_path):
    """Between two key frames each frame is read again from both passes' priors: the bars were labelled obstacle
    there (38,200 of 38,400 bar pixels), at confidence down to a half, and counted in the predicted error."""
    import json

    from PIL import Image

    from pcreg.cli import main

    images, camvid = _frames(shared_data, 5)
    frames, keys, out = tmp_path / "frames", tmp_path / "keys", tmp_path / "out"
    frames.mkdir()
    keys.mkdir()
    lagr = np.select([camvid == 3, camvid == 11], [0, 2], 1).astype(np.uint8)
    for i, image in enumerate(images):
        cv2.imwrite(str(frames / f"f{i}.png"), _letterboxed(image)[:, :, ::-1])
    for i in (0, 4):
        cv2.imwrite(str(keys / f"f{i}.png"), cv2.copyMakeBorder(lagr, PAD, PAD, 0, 0, cv2.BORDER_CONSTANT, value=2))
    assert main(["run", str(frames), "--labels", str(keys), "--out", str(out), "--confidence"]) == 0
    for i in (1, 2, 3):
        labels = np.array(Image.open(out / f"f{i}.png"))
        conf = np.array(Image.open(out / "confidence" / f"f{i}.png"))
        assert (labels[:PAD] == 2).all() and (labels[-PAD:] == 2).all()
        assert (conf[:PAD] == 255).all() and (conf[-PAD:] == 255).all()
    steps = {s["name"]: s for s in map(json.loads, (out / "steps.jsonl").read_text().splitlines())}
    for i in (1, 2, 3):
        conf = np.array(Image.open(out / "confidence" / f"f{i}.png")).astype(np.float64) / 255
        assert steps[f"f{i}.png"]["predicted_error"] == pytest.approx(100 * (1 - conf[PAD:-PAD].mean()), abs=0.3)


@pytest.mark.parametrize("keys", [(0,), (0, 4)], ids=["one key frame", "two key frames"])
def test_label_clip_keeps_the_bars_and_scores_the_picture(shared_data, keys):
    from pcreg.pipeline.keyframes import label_clip

    images, camvid = _frames(shared_data, 5)
    folder = shared_data / "camvid" / "0001TP"
    names = sorted(p.name for p in (folder / "images").iterdir())[:5]
    padded = [_letterboxed(image) for image in images]

    def key(i):
        lab = cv2.imread(str(folder / "labels" / names[i]), cv2.IMREAD_UNCHANGED)
        lagr = np.select([lab == 3, lab == 11], [0, 2], 1).astype(np.uint8)
        return cv2.copyMakeBorder(lagr, PAD, PAD, 0, 0, cv2.BORDER_CONSTANT, value=2)

    out = label_clip(lambda t: padded[t], 5, {k: key(k) for k in keys})
    for f in out[1:4]:
        assert (f.labels[:PAD] == 2).all() and (f.labels[-PAD:] == 2).all() and (f.confidence[:PAD] == 1.0).all()
        assert f.predicted_error == pytest.approx(predicted_error(f.confidence[PAD:-PAD]))
