"""A stream whose motion is DIS optical flow (``Propagator(model="flow")``, ``pcreg run --model flow``): the
trust rule, learning and the confidence on a flow, no second motion, refused where DIS cannot run."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.registration.flow import FlowResult
from _runs import frames_folder, one_line_errors
from pcreg.export import read_labels


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn1a", 7, 0, width=320, height=240)


def _errors(prop, frames):
    return [pcreg.error_rate(prop.step(f.image), f.labels) for f in frames[1:]]


@pytest.mark.parametrize("preset, scale", [("medium", 1.0), ("fast", 0.5), ("ultrafast", 1.0)])
def test_a_flow_stream_labels_better_than_naive_bayes_with_one_motion_and_a_confidence(frames, preset, scale):
    key = frames[0]
    clf = pcreg.fit_classifier([key])
    prop = pcreg.Propagator(clf, model=f"flow:{preset}", scale=scale)
    prop.reset(key.image, key.labels)
    errors, reports = [], []
    for f in frames[1:]:
        errors.append(pcreg.error_rate(prop.step(f.image), f.labels))
        reports.append(prop.last)
    plain = [pcreg.error_rate(clf.predict(f.image), f.labels) for f in frames[1:]]
    assert np.mean(errors) < 0.7 * np.mean(plain)
    for r in reports:
        assert isinstance(r.registration, FlowResult) and r.registration.preset == preset and r.start is None
        d = r.to_dict()["registration"]
        assert d["model"] == "flow" and d["preset"] == preset and d["median_displacement"] >= 0
        assert r.trust.second is None and r.trust.primary is not None  # the flow's prior alone: no second motion
        assert r.confidence.shape == (240, 320) and 0.5 <= float(r.confidence.min())
    assert prop.carry is None and not prop.warm_starts  # a flow starts from nothing: every step stands alone


def test_a_flow_stream_is_a_function_of_the_key_frame_and_the_frame(frames):
    # no state carried from step to step (learning aside): the same frame after other frames gives the same labels
    key = frames[0]
    clf = pcreg.fit_classifier([key])
    a = pcreg.Propagator(clf, model="flow", learning=None)
    a.reset(key.image, key.labels)
    b = pcreg.Propagator(clf, model="flow", learning=None)
    b.reset(key.image, key.labels)
    for f in frames[1:4]:
        a.step(f.image)
    np.testing.assert_array_equal(a.step(frames[4].image), b.step(frames[4].image))


def test_the_flow_model_on_camvid_beats_plain_and_the_unmoved_key_frame(shared_data):
    from pcreg.datasets import load_folder

    clip = load_folder(shared_data / "camvid" / "0016E5")[:12]
    key = clip[0]
    clf = pcreg.fit_classifier([key])
    prop = pcreg.Propagator(clf, model="flow:fast", scale=0.5)
    prop.reset(key.image, key.labels)
    ours = _errors(prop, clip)
    plain = [pcreg.error_rate(clf.predict(f.image), f.labels) for f in clip[1:]]
    unmoved_errors = [pcreg.error_rate(key.labels, f.labels) for f in clip[1:]]
    assert np.mean(ours) < 0.75 * np.mean(plain)
    assert np.mean(ours) < np.mean(unmoved_errors)


def test_bad_presets_and_frames_too_small_for_dis_are_refused(frames):
    clf = pcreg.fit_classifier([frames[0]])
    for bad in ("flow:slow", "flow:", "flows", None, 3):
        with pytest.raises(InputError, match="preset" if str(bad).startswith("flow:") else "unknown model"):
            pcreg.Propagator(clf, model=bad)
    assert pcreg.Propagator(clf, model="flow").preset == "medium" and pcreg.Propagator(clf).preset is None
    tiny = cv2.resize(frames[0].image, (40, 30))
    prop = pcreg.Propagator(clf, model="flow")
    with pytest.raises(InputError, match="40x30 are too small for the flow model"):
        prop.reset(tiny, np.zeros((30, 40), np.uint8))
    with pytest.raises(InputError, match=r"scale 0.1 works at 32x24 .* optical flow"):
        pcreg.Propagator(clf, model="flow", scale=0.1).reset(frames[0].image, frames[0].labels)
    # the dense model takes what DIS cannot: its second motion is left out instead
    dense = pcreg.Propagator(clf)
    dense.reset(cv2.resize(frames[0].image, (64, 30)), np.zeros((30, 64), np.uint8))


def test_the_flow_model_anchored_to_the_previous_frame(frames):
    key = frames[0]
    clf = pcreg.fit_classifier([key])
    prop = pcreg.Propagator(clf, model="flow", anchor="previous")
    prop.reset(key.image, key.labels)
    errors = _errors(prop, frames)
    plain = [pcreg.error_rate(clf.predict(f.image), f.labels) for f in frames[1:]]
    assert np.mean(errors) < np.mean(plain)
    assert prop.last.reference == len(frames) - 2


def test_run_with_the_flow_model_keeps_its_preset(tmp_path, frames, capsys):
    import json

    from pcreg.recording import entities as E
    from pcreg.recording.readback import image, read_recording

    folder, keys = frames_folder(tmp_path, frames)
    out, rrd = tmp_path / "out", tmp_path / "run.rrd"
    args = ["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(out), "--model", "flow"]
    assert main([*args, "--preset", "fast", "--scale", "0.5", "--record", str(rrd)]) == 0
    rec = read_recording(rrd)  # the flow's displacement logged at the frames' size, in their pixels
    assert image(rec.latest(E.DENSE_DISPLACEMENT, frame=2)).shape[:2] == (240, 320)
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert [s["registration"]["model"] for s in steps] == ["flow"] * 6 and steps[0]["registration"]["preset"] == "fast"
    assert steps[0]["trust"]["second"] is None and steps[0]["start"] is None
    capsys.readouterr()
    assert main([*args, "--scale", "0.5"]) == 2  # continued with another preset: refused, not mixed
    assert "model: 'flow:fast' then, 'flow:medium' now" in one_line_errors(capsys)[-1]
    assert main([*args, "--preset", "fast", "--scale", "0.5"]) == 0
    assert "all 7 frames already done" in capsys.readouterr().out
    for i in range(1, 7):
        labels = read_labels(out / f"f{i}.png")
        assert labels.shape == (240, 320) and pcreg.error_rate(labels, frames[i].labels) < 10
    # key frames at both ends of a stretch
    two = tmp_path / "two"
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(two), "--model", "flow"]) == 0
    for i in (1, 2, 3, 5, 6):
        assert pcreg.error_rate(read_labels(two / f"f{i}.png"), frames[i].labels) < 10
    capsys.readouterr()
    assert main(["run", str(folder), "--labels", str(keys / "f0.png"), "--out", str(tmp_path / "x"),
                 "--preset", "fast"]) == 2  # a preset without the flow model
    assert "--preset is DIS's, for --model flow" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_label_clip_takes_the_flow_model(frames):
    from pcreg.pipeline.keyframes import label_clip

    images = [f.image for f in frames]
    clip = label_clip(lambda t: images[t], 7, {0: frames[0].labels, 5: frames[5].labels}, model="flow:fast",
                      scale=0.5)
    between = [pcreg.error_rate(clip[t].labels, frames[t].labels) for t in range(1, 5)]
    clf = pcreg.fit_classifier([frames[0], frames[5]])
    plain = [pcreg.error_rate(clf.predict(frames[t].image), frames[t].labels) for t in range(1, 5)]
    assert np.mean(between) < np.mean(plain) and clip[3].confidence.shape == (240, 320)
    with pytest.raises(InputError, match="preset"):
        label_clip(lambda t: images[t], 7, {0: frames[0].labels}, model="flow:slow")


def test_a_flow_run_stopped_between_a_frames_files_and_its_count_resumes_exactly(tmp_path, frames, monkeypatch):
    import json

    from _runs import assert_same_run, kill_before_commit

    folder, keys = frames_folder(tmp_path, frames)
    base = ["run", str(folder), "--labels", str(keys / "f0.png"), "--model", "flow", "--scale", "0.5", "--confidence"]
    assert main([*base, "--out", str(tmp_path / "whole")]) == 0
    kill_before_commit(monkeypatch, 3)
    assert main([*base, "--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    assert json.loads((tmp_path / "cut" / "run.json").read_text())["done"] == 3
    assert main([*base, "--out", str(tmp_path / "cut")]) == 0  # frame 3 again, with what frame 2 had learned
    assert_same_run(tmp_path / "whole", tmp_path / "cut", 7)


def test_medium_without_refinement_is_dis_medium_with_no_variational_step_and_is_a_preset_everywhere(frames):
    from pcreg.pipeline.trust import CLASS_TRUST, TrustRule
    from pcreg.registration.flow import PRESETS, UNREFINED, dis_flow

    g0, g1 = (cv2.cvtColor(f.image, cv2.COLOR_RGB2GRAY) for f in frames[:2])
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setVariationalRefinementIterations(0)
    unrefined = dis_flow(g1, g0, "medium-norefine")
    np.testing.assert_array_equal(unrefined, dis.calc(g1, g0, None))
    assert not np.array_equal(unrefined, dis_flow(g1, g0, "medium"))  # the refinement moves the flow
    assert "medium-norefine" in PRESETS and UNREFINED <= set(PRESETS)
    assert CLASS_TRUST.preset == "medium-norefine" and TrustRule(preset="medium-norefine").preset == "medium-norefine"
    clf = pcreg.fit_classifier([frames[0]])
    prop = pcreg.Propagator(clf, model="flow:medium-norefine")
    prop.reset(frames[0].image, frames[0].labels)
    labels = prop.step(frames[1].image)
    assert prop.last.registration.preset == "medium-norefine" and labels.shape == frames[1].labels.shape


def test_a_motions_summary_is_the_same_to_the_bit_whatever_the_buffers():
    """The largest displacement a step's summary gives (steps.jsonl's ``max_displacement``) was cv2.magnitude's,
    whose last bit depends on where its arrays lie in memory: two runs of the same frames, or a run and its
    resumed copy, wrote 62.10468673706055 and 62.10469055175781 for the same field."""
    from pcreg.registration.dense import DenseRegistrationResult
    from pcreg.registration.result import RegistrationResult

    rng = np.random.default_rng(3)
    h, w = 481, 643
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    dx, dy = rng.uniform(-80, 80, (h, w)), rng.uniform(-80, 80, (h, w))
    # the largest displacement near the first pixel, where a vectorised loop may begin before its first aligned
    # block: one whose length rounds to another float32 when x * x + y * y is fused (133.7161 against 133.71611)
    dx[0, 2], dy[0, 2] = np.float32(96.36961), np.float32(92.69787)
    field = np.dstack([xs + dx, ys + dy]).astype(np.float32)
    sx, sy = field[..., 0] - xs, field[..., 1] - ys
    want = float(np.sqrt(sx * sx + sy * sy).max())  # in float32, each product and the sum rounded
    identity = RegistrationResult(matrix=np.eye(3), fitness=1.0, inlier_rmse=0.0, iterations=0, converged=True,
                                  backend="given", seconds=0.0)
    seen: dict[str, set] = {"flow": set(), "dense": set()}
    held = []
    for i in range(48):  # arrays of other sizes kept between the summaries: the next ones lie elsewhere
        held.append(np.ones(1 + 8 * i + (i % 5) * 100_000, np.uint8))
        at = np.empty(field.nbytes + 64, np.uint8)[4 * (i % 16):4 * (i % 16) + field.nbytes].view(np.float32)
        at = at.reshape(field.shape)
        at[...] = field
        seen["flow"].add(FlowResult(field=at, preset="medium", seconds=0.0).to_dict()["max_displacement"])
        dense = DenseRegistrationResult(matrix=np.eye(3), field=at, confidence=np.ones((h, w), np.float32),
                                        global_result=identity, fitness=1.0, inlier_rmse=0.0, iterations=1, seconds=0.0)
        seen["dense"].add(dense.to_dict()["max_displacement"])
    assert seen == {"flow": {want}, "dense": {want}}
