"""A stream run below its frames' size (``Propagator(scale=...)``, ``pcreg run --scale``): the step at the
working size, the labels and confidence back at the frames' own, resumed and recorded as at full size."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.pipeline.working import WorkingSize
from _runs import frames_folder, one_line_errors
from pcreg.export import read_labels


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 7, 0, width=320, height=240)


def test_working_size_shapes_and_conversions_keep_pixel_centres():
    size = WorkingSize((240, 320), 0.5)
    assert size.shape == (120, 160) and size.scaled
    assert WorkingSize((240, 320)).shape == (240, 320) and not WorkingSize((240, 320)).scaled
    assert WorkingSize((3, 5), 0.01).shape == (1, 1)  # never below a pixel
    for bad in (0, -0.5, 1.5, float("nan"), "half", None, True):
        with pytest.raises(InputError, match="scale"):
            WorkingSize((240, 320), bad)
    # a shift of one working pixel is two of the frames'; the pixel centres map onto each other
    shift = np.array([[1.0, 0, 1], [0, 1, -1], [0, 0, 1]])
    np.testing.assert_allclose(size.frame_matrix(shift), [[1, 0, 2], [0, 1, -2], [0, 0, 1]], atol=1e-12)
    ys, xs = np.mgrid[0:120, 0:160].astype(np.float32)
    field = size.frame_field(np.dstack([xs + 1, ys]))
    assert field.shape == (240, 320, 2)
    Y, X = np.mgrid[0:240, 0:320].astype(np.float32)
    inner = (slice(2, -2), slice(2, -2))  # bilinear resizing holds the outermost half pixel
    np.testing.assert_allclose(field[..., 0][inner], X[inner] + 2, atol=1e-4)
    np.testing.assert_allclose(field[..., 1][inner], Y[inner], atol=1e-4)
    # the key frame's labels shrink over the same areas as its image: discs keep their place (the nearest
    # pixel, each block's top-left one, would move them (1/scale - 1) / 2 px down and right)
    rng = np.random.default_rng(0)
    discs = np.zeros((480, 640), np.uint8)
    for _ in range(30):
        cv2.circle(discs, (int(rng.integers(40, 600)), int(rng.integers(40, 440))), int(rng.integers(10, 40)), 1, -1)
    ys, xs = np.nonzero(discs == 1)
    for scale in (0.5, 0.25):
        yw, xw = np.nonzero(WorkingSize((480, 640), scale).labels(discs) == 1)
        assert abs((xw + 0.5).mean() / scale - 0.5 - xs.mean()) < 0.4
        assert abs((yw + 0.5).mean() / scale - 0.5 - ys.mean()) < 0.4
    grown = size.grow(np.full((120, 160), 0.7, np.float32))
    assert grown.shape == (240, 320) and np.allclose(grown, 0.7)
    with pytest.raises(ValueError, match="working at"):
        size.grow(np.zeros((100, 100), np.float32))


def test_a_stream_at_half_size_labels_the_full_frames_better_than_naive_bayes_and_resumes(frames):
    from pcreg.pipeline.stream import Carry

    key = frames[0]
    half = pcreg.Propagator.from_key_frame(key.image, key.labels, scale=0.5)
    plain_err, half_err = [], []
    for f in frames[1:4]:
        labels = half.step(f.image)
        r = half.last
        assert labels.shape == f.labels.shape and labels.dtype == np.uint8 and labels.max() <= 1
        assert r.confidence.shape == f.labels.shape and 0.5 <= r.confidence.min() and r.confidence.max() <= 1
        assert r.log_odds.shape == (120, 160) and r.registration.field.shape == (120, 160, 2)
        half_err.append(pcreg.error_rate(labels, f.labels))
        plain_err.append(pcreg.error_rate(half.classifier.predict(f.image), f.labels))
    assert np.mean(half_err) < 0.5 * np.mean(plain_err)
    assert half.working_size.shape == (120, 160) and half.key_labels.shape == key.labels.shape
    # the carry is the working size's grid, and a resumed stream continues exactly
    saved, learned = Carry(half.carry.grid.copy(), half.carry.reference_evidence), half.learned
    expected = half.step(frames[4].image)
    resumed = pcreg.Propagator.from_key_frame(key.image, key.labels, scale=0.5)
    resumed.resume(3, saved, learned)
    np.testing.assert_array_equal(resumed.step(frames[4].image), expected)
    np.testing.assert_array_equal(resumed.last.confidence, half.last.confidence)
    with pytest.raises(InputError, match="another stream"):  # a full-size stream's carry is not this one's
        full = pcreg.Propagator.from_key_frame(key.image, key.labels)
        full.step(frames[1].image)
        resumed.resume(3, full.carry)
    # without a trust rule the fused log-odds are brought back, then read
    bare = pcreg.Propagator.from_key_frame(key.image, key.labels, scale=0.5, trust=None)
    labels = bare.step(frames[1].image)
    assert labels.shape == key.labels.shape and bare.last.confidence is None
    assert pcreg.error_rate(labels, frames[1].labels) < pcreg.error_rate(bare.classifier.predict(frames[1].image),
                                                                         frames[1].labels)
    for bad in (0, 2, -1, "x"):
        with pytest.raises(InputError, match="scale"):
            pcreg.Propagator(half.classifier, scale=bad)
    with pytest.raises(InputError, match="works at 3x2 for frames of 320x240: too small"):  # at reset, not at a step
        pcreg.Propagator(half.classifier, scale=0.01).reset(key.image, key.labels)
    with pytest.raises(InputError, match="works at 64x48 .* too small for the similarity registration"):
        pcreg.Propagator(half.classifier, model="similarity", scale=0.2).reset(key.image, key.labels)
    # a global model on frames too small for its pyramid at their own size: each step raised, blaming the frame
    with pytest.raises(InputError, match="frames of 64x48 are too small for the similarity model") as refused:
        pcreg.Propagator(half.classifier, model="similarity").reset(key.image[::5, ::5], key.labels[::5, ::5])
    assert "levels=3)" in str(refused.value) and "--levels" not in str(refused.value)  # register=, not pcreg run
    # pcreg run has no levels to set: it said only levels=3; the models that take such frames are named
    assert str(refused.value).endswith("the dense model (the default) and the flow model take smaller frames")
    similar = pcreg.Propagator(half.classifier, model="similarity", scale=0.5)  # a global model at half size
    similar.reset(key.image, key.labels)
    assert similar.step(frames[1].image).shape == key.labels.shape and similar.last.registered
    with pytest.raises(InputError, match="shape"):  # frames of another size than the key frame's, as at full size
        half.step(frames[1].image[:200])


def test_label_clip_at_half_size_gives_full_size_labels(frames):
    from pcreg.pipeline.keyframes import label_clip

    images = [f.image for f in frames]
    keys = {0: frames[0].labels, 5: frames[5].labels}
    clip = label_clip(lambda t: images[t], 7, keys, scale=0.5)
    assert [f.index for f in clip] == list(range(7))
    for f in clip[1:5]:
        assert f.labels.shape == (240, 320) and f.confidence.shape == (240, 320)
    between = [pcreg.error_rate(clip[t].labels, frames[t].labels) for t in range(1, 5)]
    clf = pcreg.fit_classifier([frames[0], frames[5]])
    plain = [pcreg.error_rate(clf.predict(frames[t].image), frames[t].labels) for t in range(1, 5)]
    assert np.mean(between) < np.mean(plain)
    assert clip[6].labels.shape == (240, 320)  # after the last key frame, one-sided
    with pytest.raises(InputError, match="scale"):
        label_clip(lambda t: images[t], 7, keys, scale=0)


def test_run_at_half_size_writes_full_size_labels_records_and_keeps_its_scale(tmp_path, frames, capsys):
    from pcreg.recording import entities as E
    from pcreg.recording.readback import image, read_recording

    folder, keys = frames_folder(tmp_path, frames)
    out, rrd = tmp_path / "out", tmp_path / "run.rrd"
    assert main(["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(out), "--scale", "0.5",
                 "--confidence", "--record", str(rrd)]) == 0
    for i in range(1, 7):
        labels = read_labels(out / f"f{i}.png")
        assert labels.shape == (240, 320) and pcreg.error_rate(labels, frames[i].labels) < 10
    rec = read_recording(rrd)  # the frames and the field's maps at the frames' size, in their pixels
    assert image(rec.moving(1)).shape[:2] == (240, 320)
    assert image(rec.latest(E.DENSE_CONFIDENCE, frame=1)).shape[:2] == (240, 320)
    # the run remembers its scale: resumed without it, it is refused rather than continued otherwise
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(out)]) == 2
    assert "scale: 0.5 then, not set now" in one_line_errors(capsys)[-1]
    again = ["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(out), "--scale", "0.5", "--confidence"]
    assert main(again) == 0 and "all 7 frames already done" in capsys.readouterr().out
    # key frames at both ends of a stretch, at half size
    two = tmp_path / "two"
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(two), "--scale", "0.5"]) == 0
    for i in (1, 2, 3, 5, 6):
        labels = read_labels(two / f"f{i}.png")
        assert labels.shape == (240, 320) and pcreg.error_rate(labels, frames[i].labels) < 10
    bad_run = ["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(tmp_path / "bad"), "--scale"]
    for bad in ("0", "1.5", "nan"):
        capsys.readouterr()
        assert main([*bad_run, bad]) == 2
        assert "scale" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="2"):  # not a number: the parser's own one-line refusal
        main([*bad_run, "x"])
    assert not (tmp_path / "bad").exists()


def test_a_key_frame_brought_up_in_size_is_said_with_the_scale_it_holds_detail_for(shared_data, tmp_path, capsys):
    """CamVid frames (480x360) brought up to 640x480 and 960x720 keep their fine detail through a round trip to 0.75
    and 0.5 of their size, where the step labelled the shared clips better; the frames at their own size, or
    shrunk, do not. A run from such a key frame at full size says so once, before the first frame; at the scale
    said, with --follow object or with the flow model it says nothing of it."""
    from pcreg.datasets.detail import KEPT_DETAIL, detail_kept, detail_scale, scale_note
    from pcreg.pipeline.config import PropagatorConfig

    clip = shared_data / "camvid" / "0001TP"
    names = sorted(p.name for p in (clip / "images").iterdir())[:3]
    own = [cv2.imread(str(clip / "images" / n))[:, :, ::-1] for n in names]
    for size, scale in (((480, 360), 1.0), ((240, 180), 1.0), ((640, 480), 0.75), ((960, 720), 0.5)):
        image = cv2.resize(own[0], size, interpolation=cv2.INTER_CUBIC if size[0] > 480 else cv2.INTER_AREA)
        assert detail_scale(image) == scale, size
    assert detail_kept(own[0], 0.75) < KEPT_DETAIL and detail_scale(np.zeros((40, 40, 3), np.uint8)) == 0.5
    smooth = cv2.resize(own[0], (320, 240), interpolation=cv2.INTER_AREA)
    smooth = cv2.resize(cv2.resize(smooth, (160, 120), interpolation=cv2.INTER_AREA), (320, 240))  # brought up twice
    assert detail_scale(smooth) == 0.5 and detail_scale(smooth, longer_side=480) == 1.0  # not below 480 px
    assert scale_note(smooth, "small", PropagatorConfig()) is None
    frames, key = tmp_path / "frames", tmp_path / "key.png"
    frames.mkdir()
    for n, image in zip(names, own):
        cv2.imwrite(str(frames / n), cv2.resize(image, (640, 480), interpolation=cv2.INTER_CUBIC)[:, :, ::-1])
    labels = np.zeros((480, 640), np.uint8)
    labels[240:] = 1
    cv2.imwrite(str(key), labels)

    def said(*options: str) -> list[str]:
        assert main(["run", str(frames), "--labels", str(key), "--out", str(tmp_path / "out"), "--force", *options]) == 0
        return [ln for ln in capsys.readouterr().err.splitlines() if "holds no more detail" in ln]

    [line] = said()
    assert line.startswith(f"pcreg: note: {frames}: the key frame {names[0]} holds no more detail than at 0.75 of its "
                           "size (480x360: a round trip there keeps 8") and "`--scale 0.75`" in line
    assert said("--scale", "0.75") == [] and said("--model", "flow") == [] and said("--follow", "object") == []
