"""The streaming propagator, cached pyramids, and the `pcreg run` command."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.registration.clouds import cloud_pyramid, image_pyramid
from _runs import kill_before_commit
from pcreg.export import read_labels


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 8, 0, width=320, height=240)


def test_pyramid_clouds_equal_cloud_pyramid(frames):
    img = frames[0].image
    pyr = image_pyramid(img, levels=4)
    for max_points, seed in (((600, 400, 300, 200), 1), (5000, 0), (None, 0)):
        a = cloud_pyramid(img, levels=4, max_points=max_points, seed=seed)
        b = pyr.clouds(max_points=max_points, seed=seed)
        for x, y in zip(a, b):  # the same points; OpenCV's float32 gradient magnitude may differ by an ulp
            np.testing.assert_array_equal(x.colors, y.colors)
            np.testing.assert_allclose(x.normals, y.normals, atol=1e-6)
            np.testing.assert_allclose(x.points, y.points, atol=1e-6)


def test_register_with_prebuilt_pyramids_gives_the_same_result(frames):
    a, b = frames[0].image, frames[2].image
    kw = dict(model="similarity", init="identity")
    plain = pcreg.register(a, b, **kw)
    cached = pcreg.register(a, b, reference_pyramid=image_pyramid(a), moving_pyramid=image_pyramid(b), **kw)
    np.testing.assert_allclose(plain.matrix, cached.matrix, atol=1e-6)
    with pytest.raises(InputError, match="built for"):
        pcreg.register(a, b, reference_pyramid=image_pyramid(a[:120, :160]), **kw)
    with pytest.raises(InputError, match="other options"):
        pcreg.register(a, b, moving_pyramid=image_pyramid(b, canny_percentile=70.0), **kw)


def test_propagator_streams_labels_better_than_naive_bayes(frames):
    prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    clf = prop.classifier
    fused_err, plain_err = [], []
    for f in frames[1:]:
        labels = prop.step(f.image)
        assert labels.shape == f.labels.shape and labels.dtype == np.uint8 and labels.max() <= 1
        last = prop.last
        assert last.registered and not last.fallback and last.reason is None
        assert last.reference == 0  # anchored to the key frame
        assert last.registration.field.shape == f.labels.shape + (2,)  # the dense model by default
        stream = pcreg.pipeline.stream
        assert stream.STEP_PARTS["register"] == ("global",) + pcreg.registration.dense.DENSE_STAGES
        parts = {f"{stage}.{part}" for stage, names in stream.STEP_PARTS.items() for part in names}
        assert set(last.times) == set(stream.STEP_STAGES) | parts and last.times["total"] > 0
        for stage in ("classify", "fuse"):  # the parts add up to their stage
            assert sum(last.times[f"{stage}.{p}"] for p in stream.STEP_PARTS[stage]) == pytest.approx(
                last.times[stage], rel=1e-6, abs=1e-9)
        assert last.times["register.search"] > 0 and last.times["register.field"] > 0
        assert sum(last.times[f"register.{p}"] for p in stream.STEP_PARTS["register"]) <= last.times["register"]
        fused_err.append(pcreg.error_rate(labels, f.labels))
        plain_err.append(pcreg.error_rate(clf.predict(f.image), f.labels))
    assert np.mean(fused_err) < np.mean(plain_err)


def test_chained_propagation_registers_to_the_previous_frame(frames):
    prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, model="similarity", anchor="previous")
    for i, f in enumerate(frames[1:4], start=1):
        prop.step(f.image)
        assert prop.last.registered and prop.last.reference == i - 1
        assert prop.last.registration.matrix.shape == (3, 3)


def _unwarped(prop, image):
    """What the fallback must give: the key frame's prior fused unwarped at the propagator's weight."""
    from pcreg.classification.fusion import fuse, label_prior, prior_log_odds

    pi = float(prop.classifier.class_prior_[1])
    prior = prior_log_odds(label_prior(prop.key_labels, pi=pi, fusion=prop.fusion), pi=pi)
    return (fuse(prop.classifier.decision_function(image), prior, weight=prop.weight) > 0).astype(np.uint8)


def test_a_failed_registration_falls_back_to_the_key_frames_labels(frames):
    for options in ({}, {"model": "similarity", "anchor": "previous"}):  # without the trust rule: one weight
        prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, trust=None, learning=None,
                                               **options)
        prop.step(frames[1].image)
        flat = np.full_like(frames[2].image, 128)
        labels = prop.step(flat)
        assert prop.last.fallback and not prop.last.registered and prop.last.reason
        # the dense step tried warm, then cold again, before it gave up; a global model has no start
        assert prop.last.start == ("restarted" if not options else None)
        np.testing.assert_array_equal(labels, _unwarped(prop, flat))
        assert not np.array_equal(labels, (prop.classifier.decision_function(flat) > 0).astype(np.uint8))
        prop.step(frames[3].image)  # registered again, to the key frame or to frame 1, the last that registered
        assert prop.last.registered and prop.last.reference == (0 if not options else 1)


def test_dense_steps_start_from_the_previous_grid_and_restart_cold_after_a_jump(frames):
    from pcreg.pipeline.stream import STREAM_DENSE, DenseStep

    key = frames[0]
    prop = pcreg.Propagator.from_key_frame(key.image, key.labels)
    cold = pcreg.Propagator.from_key_frame(key.image, key.labels, dense=DenseStep(warm=False))
    for f in frames[1:4]:
        prop.step(f.image)
        cold.step(f.image)
        assert cold.last.start == "cold" and cold.carry is None
    assert prop.carry.grid.shape == prop.last.registration.grid.shape
    # a jump of 60 px, five times the warm gate (3 px at level 2): the warm field's evidence collapses,
    # the step runs again cold and keeps the cold field
    h, w = key.image.shape[:2]
    jumped = cv2.warpAffine(frames[4].image, np.float32([[1, 0, 60], [0, 1, 0]]), (w, h),
                            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    prop.step(jumped)
    assert prop.last.start == "restarted"
    fresh = pcreg.register_dense(key.image, jumped, global_result=np.eye(3), options=STREAM_DENSE.options())
    np.testing.assert_array_equal(prop.last.registration.field, fresh.field)
    assert prop.carry.reference_evidence == fresh.info["evidence"]
    prop.step(jumped)  # from the restarted field: warm again
    assert prop.last.start == "warm"


def test_a_resumed_propagator_continues_exactly_as_the_uninterrupted_one(frames):
    from pcreg.pipeline.stream import Carry

    whole = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    for f in frames[1:4]:
        whole.step(f.image)
    saved = Carry(whole.carry.grid.copy(), whole.carry.reference_evidence)
    learned = whole.learned
    assert learned is not None and learned.sum() > 0  # naive Bayes has learned from three frames
    expected = whole.step(frames[4].image)
    resumed = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    resumed.resume(3, saved, learned)
    np.testing.assert_array_equal(resumed.step(frames[4].image), expected)
    np.testing.assert_array_equal(resumed.last.confidence, whole.last.confidence)
    forgetful = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    forgetful.resume(3, saved)  # without what was learned, the classifier is the key frame's again
    assert forgetful.learned.sum() == 0
    assert resumed.last.frame == 4 and resumed.last.start == whole.last.start == "warm"
    np.testing.assert_array_equal(resumed.last.registration.field, whole.last.registration.field)
    with pytest.raises(InputError, match="ChainCarry"):  # a chained stream needs the frame it registers to
        pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, anchor="previous").resume(3, saved)
    with pytest.raises(InputError, match="Carry"):
        resumed.resume(3, saved.grid)
    with pytest.raises(InputError, match="before reset"):
        pcreg.Propagator(resumed.classifier).resume(3, saved)
    for grid, evidence in ((np.zeros((4, 4)), 1.0), (np.full((4, 4, 2), np.nan), 1.0), (np.zeros((4, 4, 2)), np.inf),
                           ("abc", 1.0), (object(), 1.0), (np.full((4, 4, 2), "a"), 1.0), (np.zeros((0, 0, 2)), 1.0),
                           (np.zeros((4, 4, 2), complex), 1.0), (np.zeros((4, 4, 2)), None), (np.zeros((4, 4, 2)), "3"),
                           (np.zeros((4, 4, 2)), 1 + 1j), (np.zeros((4, 4, 2)), 10**400), (np.zeros((4, 4, 2)), True),
                           (np.zeros((4, 4, 2)), -1.0), (np.full((4, 4, 2), 1e300), 1.0)):
        with pytest.raises(InputError, match="carried"):
            Carry(grid, evidence)
    for frame in ("x", None, -3, 2.7, True):
        with pytest.raises(InputError, match="frame"):
            resumed.resume(frame, saved)
    with pytest.raises(InputError, match="another stream"):
        resumed.resume(3, Carry(np.zeros((5, 6, 2), np.float32), 1.0))
    assert resumed.last.frame == 4 and resumed.carry is not None  # a refused resume changes nothing
    global_model = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, model="similarity")
    global_model.resume(3, saved)
    assert global_model.carry is None  # nothing to carry between global registrations


def test_dense_step_options_are_checked():
    from pcreg.pipeline.stream import DenseStep

    for bad in ({"warm": 1}, {"warm_level": -1}, {"warm_level": 0}, {"warm_level": 8}, {"warm_iterations": 0},
                {"warm_iterations": 2.0}, {"warm_iterations": 200_000}, {"restart_ratio": 1.5},
                {"restart_ratio": "half"}, {"restart_ratio": True}, {"iterations": True}):
        with pytest.raises(InputError):
            DenseStep(**bad)
    ok = DenseStep(warm=np.True_, restart_ratio=np.float32(0.5), warm_level=np.int64(3))
    assert ok.warm is True and type(ok.restart_ratio) is float and type(ok.warm_level) is int
    assert DenseStep().options(warm=True) == pcreg.DenseOptions(texture=None, iterations=4, max_points=5000,
                                                                initial_level=2)
    from pcreg.registration.dense import GlobalStep

    base = pcreg.DenseOptions(seed=3, global_step=GlobalStep(backend="open3d"))
    assert DenseStep().options(base) == replace(base, texture=None, iterations=8, max_points=5000)
    with pytest.raises(InputError, match="max_points"):  # the dense options are checked when the stream is made
        image = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
        pcreg.Propagator.from_key_frame(image, np.repeat([[0], [1]], 32, axis=0) * np.ones(64, np.uint8),
                                        dense=DenseStep(max_points=3))


def test_propagator_input_errors(frames):
    clf = pcreg.fit_classifier([frames[0]])
    prop = pcreg.Propagator(clf)
    with pytest.raises(InputError, match="before reset"):
        prop.step(frames[1].image)
    with pytest.raises(InputError, match="0 \\(ground\\)"):
        prop.reset(frames[0].image, np.full(frames[0].labels.shape, 7, np.uint8))
    with pytest.raises(InputError, match="shape"):
        prop.reset(frames[0].image, frames[0].labels[:10])
    prop.reset(frames[0].image, frames[0].labels)
    with pytest.raises(InputError, match="stream of"):
        prop.step(frames[1].image[:100])
    with pytest.raises(InputError, match="no decision_function"):
        pcreg.Propagator(object())
    with pytest.raises(InputError, match="unknown anchor"):
        pcreg.Propagator(clf, anchor="both")
    with pytest.raises(InputError, match="unknown model"):
        pcreg.Propagator(clf, model="warp")
    with pytest.raises(InputError, match="all unknown"):
        pcreg.Propagator.from_key_frame(frames[0].image, np.full(frames[0].labels.shape, 2, np.uint8))


def _write_frames(folder, frames):
    folder.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), f.image[:, :, ::-1])


def test_a_resume_refused_for_what_was_learned_leaves_the_stream_as_it_was(frames):
    """A learned histogram of another shape, or one that counts unknown pixels (which the classifier refuses), was
    refused after the frame, the carry (and the learner's stream) were taken: the next step was numbered after the
    refused frame and warm-started from the refused carry."""
    from pcreg.pipeline.stream import Carry

    whole = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    for f in frames[1:4]:
        whole.step(f.image)
    saved, learned = Carry(whole.carry.grid.copy(), whole.carry.reference_evidence), whole.learned
    unknown = learned.copy()
    unknown[2, :, 10] = 5  # the unknown class's row: no learner writes it
    fresh = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    expected = fresh.step(frames[1].image)
    for bad in (learned[:, :, :100], unknown):
        stream = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
        with pytest.raises(InputError):
            stream.resume(3, saved, bad)
        assert stream.carry is None and stream.learned.sum() == 0
        np.testing.assert_array_equal(stream.step(frames[1].image), expected)
        assert stream.last.frame == 1 and stream.last.start == fresh.last.start


def test_run_command_writes_labels_and_resumes(tmp_path, frames, capsys):
    src = tmp_path / "frames"
    _write_frames(src, frames[:4])
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    out = tmp_path / "out"
    args = ["run", str(src), "--labels", str(tmp_path / "key.png"), "--out", str(out)]
    assert main(args) == 0
    state = json.loads((out / "run.json").read_text())
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert state["done"] == 4 and [s["name"] for s in steps] == ["f001.png", "f002.png", "f003.png"]
    assert all(s["registered"] for s in steps) and state["fallbacks"] == 0
    first = read_labels(out / "f003.png")
    assert first.shape == frames[3].labels.shape and first.max() <= 1
    # two more frames arrive: the run resumes from the state it kept, as an uninterrupted run would
    for i in (4, 5):
        cv2.imwrite(str(src / f"f{i:03d}.png"), frames[i].image[:, :, ::-1])
    stale = [out / ".f004.png.k1ll3d_1.tmp", out / ".run.json.k1ll3d_2.tmp"]  # what a kill mid-write leaves
    for f in stale:
        f.write_bytes(b"half")
    assert main(args) == 0
    assert not any(f.exists() for f in stale)
    state = json.loads((out / "run.json").read_text())
    assert state["done"] == 6 and len((out / "steps.jsonl").read_text().splitlines()) == 5
    whole = tmp_path / "whole"
    assert main(["run", str(src), "--labels", str(tmp_path / "key.png"), "--out", str(whole)]) == 0
    for i in range(6):
        np.testing.assert_array_equal(read_labels(out / f"f{i:03d}.png"),
                                      read_labels(whole / f"f{i:03d}.png"))
    assert main(args) == 0 and "already done" in capsys.readouterr().out
    # a label PNG the run counts done, gone since: refused, not called done
    moved = (out / "f002.png").rename(tmp_path / "f002.png")
    assert main(args) == 2
    assert "f002.png is missing, though" in capsys.readouterr().err
    moved.rename(out / "f002.png")
    # a resume needs the last counted frame's carry
    state["done"] = 5
    (out / "run.json").write_text(json.dumps(state))
    (out / "carry-0.npz").unlink()
    assert main(args) == 2
    assert "carry-0.npz: missing or unreadable" in capsys.readouterr().err
    (out / "carry-0.npz").write_bytes((out / "carry-1.npz").read_bytes())  # frame 5's, not frame 4's
    assert main(args) == 2
    assert "holds frame 5's carry, not frame 4's" in capsys.readouterr().err
    for junk in (b"PK\x03\x04" + b"\0" * 40, (out / "carry-1.npz").read_bytes()[:300], b"not a carry"):
        (out / "carry-0.npz").write_bytes(junk)  # a damaged file: bad input, exit 2, not a bug
        assert main(args) == 2
        assert "carry-0.npz: missing or unreadable" in capsys.readouterr().err
    good = dict(np.load(out / "carry-1.npz"))
    for change, said in (({"frame": np.array("4")}, "missing or unreadable"), ({"frame": np.float64(4.0)}, "missing"),
                         ({"frame": np.int64(4), "grid": np.full((3, 3, 2), "a")}, "carried grid"),
                         ({"frame": np.int64(4), "evidence": np.float64(-1)}, "carried evidence"),
                         ({"frame": np.int64(4), "grid": np.zeros((0, 5))}, "carried grid"),
                         ({"frame": np.int64(4), "grid": np.zeros((3, 3, 2), np.float32)}, "another stream")):
        np.savez(out / "carry-0.npz", **{**good, **change})
        assert main(args) == 2
        assert said in capsys.readouterr().err, change
    broken = bytearray((out / "carry-1.npz").read_bytes())
    np.savez_compressed(out / "carry-0.npz", **{**good, "frame": np.int64(4)})
    data = bytearray((out / "carry-0.npz").read_bytes())
    data[60:90] = b"\xff" * 30  # a corrupt deflate stream
    (out / "carry-0.npz").write_bytes(bytes(data))
    assert main(args) == 2 and "missing or unreadable" in capsys.readouterr().err
    del broken
    state["done"] = 6
    (out / "run.json").write_text(json.dumps(state))
    # other options over the same folder: refused, unless --force; the message names what differs
    assert main(args + ["--weight", "3"]) == 2
    assert "other options (weight: 2.0 then, 3.0 now)" in capsys.readouterr().err
    assert main(args + ["--stop", "9", "--every", "2"]) == 2  # the frames chosen, in the options' own words
    assert "other options (frames: every frame then, --stop 9 --every 2 now)" in capsys.readouterr().err
    # a run begun when the labels were read pixel by pixel is not continued with blurred ones
    (out / "run.json").write_text(json.dumps({**state, "run": {k: v for k, v in state["run"].items() if k != "smooth"}}))
    assert main(args) == 2
    assert "other options (smooth: not set then, 3.0 now)" in capsys.readouterr().err


def test_run_command_bad_input(tmp_path, frames, capsys):
    src = tmp_path / "frames"
    _write_frames(src, frames[:2])
    cv2.imwrite(str(tmp_path / "key.png"), np.full(frames[0].labels.shape, 9, np.uint8))
    assert main(["run", str(src), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "o")]) == 2
    assert "label value 9" in capsys.readouterr().err
    cv2.imwrite(str(tmp_path / "small.png"), frames[0].labels[:50])
    assert main(["run", str(src), "--labels", str(tmp_path / "small.png"), "--out", str(tmp_path / "o")]) == 2
    assert main(["run", str(tmp_path / "nowhere"), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "o")]) == 2


def test_run_scores_against_truth_and_resumes_exactly_after_a_crash(tmp_path, frames, capsys, monkeypatch):

    src, truth = tmp_path / "frames", tmp_path / "truth"
    _write_frames(src, frames[:6])
    truth.mkdir()
    for i, f in enumerate(frames[:6]):
        cv2.imwrite(str(truth / f"f{i:03d}.png"), f.labels)
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    base = ["run", str(src), "--labels", str(tmp_path / "key.png"), "--truth", str(truth)]
    assert main(base + ["--out", str(tmp_path / "whole")]) == 0
    state = json.loads((tmp_path / "whole" / "run.json").read_text())
    assert state["truth"]["frames"] == 5 and state["truth"]["error"] < state["truth"]["plain_error"]
    assert "error against the truth" in capsys.readouterr().out

    # a crash after frame 3's PNG and step line were written, before run.json counted it
    kill_before_commit(monkeypatch, 3)
    assert main(base + ["--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    assert json.loads((tmp_path / "cut" / "run.json").read_text())["done"] == 3
    assert len((tmp_path / "cut" / "steps.jsonl").read_text().splitlines()) == 3  # frame 3's line, uncommitted
    assert main(base + ["--out", str(tmp_path / "cut")]) == 0
    # the steps after the first start from the one before (the resumed frame 3 from frame 2's carry)
    starts = [json.loads(line)["start"] for line in (tmp_path / "cut" / "steps.jsonl").read_text().splitlines()]
    assert starts[0] == "cold" and set(starts[1:]) <= {"warm", "restarted"} and "warm" in starts[1:], starts
    for name in ["run.json", "steps.jsonl", "carry-0.npz", "carry-1.npz"] + [f"f{i:03d}.png" for i in range(6)]:
        a, b = (tmp_path / "whole" / name).read_bytes(), (tmp_path / "cut" / name).read_bytes()
        if name == "steps.jsonl":  # times differ from run to run; everything else is the same
            a, b = ([_timeless(json.loads(line)) for line in x.splitlines()] for x in (a, b))
        if name == "run.json":
            a, b = (json.loads(x)["truth"] for x in (a, b))
        assert a == b, name


def _timeless(step: dict) -> dict:
    step.pop("times")
    step["registration"].pop("seconds")
    return step


def test_run_truth_bad_input(tmp_path, frames, capsys):
    src, truth = tmp_path / "frames", tmp_path / "truth"
    _write_frames(src, frames[:3])
    truth.mkdir()
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    cv2.imwrite(str(truth / "f000.png"), frames[0].labels)
    cv2.imwrite(str(truth / "f001.png"), frames[1].labels)
    args = ["run", str(src), "--labels", str(tmp_path / "key.png"), "--truth", str(truth), "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert f"{truth / 'f002.png'}: no truth labels for frame f002.png" in capsys.readouterr().err
    cv2.imwrite(str(truth / "f002.png"), frames[2].labels[:100])
    assert main(args) == 2
    err = capsys.readouterr().err  # the file named, as every other input check names it (it named the frame alone)
    assert err.count("\n") == 1 and f"{truth / 'f002.png'}: truth labels of {frames[2].labels.shape[1]}x100" in err, err
    assert not (tmp_path / "o").exists()  # nothing written before the input was checked


def test_a_truth_all_unknown_says_it_measured_nothing(tmp_path, frames, capsys):
    """--truth whose maps are all unknown: the run ended with no word of the error it was asked for."""
    src, truth = tmp_path / "frames", tmp_path / "truth"
    _write_frames(src, frames[:3])
    truth.mkdir()
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    for i in range(3):
        cv2.imwrite(str(truth / f"f{i:03d}.png"), np.full(frames[0].labels.shape, 2, np.uint8))
    assert main(["run", str(src), "--labels", str(tmp_path / "key.png"), "--truth", str(truth), "--model", "flow",
                 "--out", str(tmp_path / "o")]) == 0
    assert "error against the truth: none, the truth labels of the frames labelled are all unknown" \
        in capsys.readouterr().out
