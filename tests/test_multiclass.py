"""The stream with more than two classes (pcreg.pipeline.multiclass): CamVid's eleven classes on a real clip."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from pcreg.classes import CAMVID11, LAGR
from pcreg.errors import InputError
from pcreg.pipeline import multiclass
from pcreg.pipeline.stream import Propagator


def _clip(shared_data, n=4):
    import cv2

    folder = shared_data / "camvid" / "0001TP"
    names = sorted(p.name for p in (folder / "images").iterdir())[:n]
    images = [cv2.imread(str(folder / "images" / m))[:, :, ::-1].copy() for m in names]
    labels = [cv2.imread(str(folder / "labels" / m), cv2.IMREAD_UNCHANGED) for m in names]
    return images, labels


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_eleven_classes_follow_the_clip(shared_data, scale):
    """Every label is one of the key frame's classes, each confidence in [1/K, 1], and the propagated
    labels are nearer the truth than the key frame's labels left where they are."""
    images, labels = _clip(shared_data)
    prop = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, scale=scale)
    trained = set(np.unique(labels[0]).tolist()) - {CAMVID11.unknown}
    errors, unmoved = [], []
    for image, truth in zip(images[1:], labels[1:]):
        out = prop.step(image)
        assert out.shape == truth.shape and out.dtype == np.uint8
        assert set(np.unique(out).tolist()) <= trained
        conf = prop.last.confidence
        k = len(trained)
        assert conf.shape == truth.shape and conf.min() >= max(1.0 / k, multiclass.CLASS_MIN_CONFIDENCE) - 1e-6
        assert conf.max() <= 1.0
        assert prop.last.log_odds.shape[2] == k
        maps = prop.last.trust  # the fusion's priors' part, kept: what summing the maps again gives
        assert maps.term is not None
        assert np.array_equal(maps.prior_term(maps.term.shape), replace(maps, term=None).prior_term(maps.term.shape))
        iou = prop.last.predicted_iou
        assert iou and all(0.0 <= v <= 1.0 for v in iou.values()) and set(iou) <= trained
        known = truth != CAMVID11.unknown
        errors.append(np.mean(out[known] != truth[known]))
        unmoved.append(np.mean(labels[0][known] != truth[known]))
    assert np.mean(errors) < np.mean(unmoved)


def test_two_classes_stay_log_odds_and_predict_each_class_iou_with_the_other_as_runner_up(shared_data):
    """A LAGR key frame keeps the two-class step: (H, W) log-odds. Each class's predicted IoU is that of the
    confidence with the other class as every pixel's runner-up: ground's expected hits are the confidence
    summed over its pixels, its false alarms one minus it there, its misses one minus it over obstacle's."""
    images, labels = _clip(shared_data, 2)
    lut = np.array([2, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 2] + [2] * 244, np.uint8)
    prop = Propagator.from_key_frame(images[0], lut[labels[0]], classes=LAGR)
    out = prop.step(images[1])
    assert prop.last.log_odds.ndim == 2
    c = prop.last.confidence.astype(np.float64)
    for k in (0, 1):
        tp, fp, fn = c[out == k].sum(), (1 - c[out == k]).sum(), (1 - c[out == 1 - k]).sum()
        assert prop.last.predicted_iou[k] == pytest.approx(tp / (tp + fp + fn), rel=1e-6)
    assert prop.last.to_dict()["predicted_iou"] == {str(k): v for k, v in prop.last.predicted_iou.items()}


def test_a_label_outside_the_table_is_refused(shared_data):
    images, labels = _clip(shared_data, 1)
    bad = labels[0].copy()
    bad[0, 0] = 40
    with pytest.raises(InputError, match="label value 40"):
        Propagator.from_key_frame(images[0], bad, classes=CAMVID11)


def test_the_prior_is_the_two_class_prior_class_by_class():
    """At two classes the evidence of class 1 over class 0 is the two-class prior's log-odds."""
    from pcreg.classification.fusion import label_prior, prior_log_odds

    rng = np.random.default_rng(0)
    lab = rng.integers(0, 3, (40, 64)).astype(np.uint8)
    pi = np.array([0.3, 0.7])
    lp = multiclass.prior_log_probs(multiclass.class_prior_maps(lab, np.array([0, 1]), pi), pi)
    two = prior_log_odds(label_prior(lab, pi=0.7), pi=0.7)
    assert np.allclose(lp[:, :, 1] - lp[:, :, 0], two, atol=1e-4)


def test_predicted_iou_counts_misses_by_the_runner_up():
    labels = np.array([[0, 0, 1, 1]], np.uint8)
    conf = np.array([[1.0, 0.5, 1.0, 1.0]], np.float32)
    second = np.array([[1, 1, 0, 0]], np.uint8)
    iou = multiclass.predicted_iou(labels, conf, second, [0, 1])
    assert iou[0] == pytest.approx(1.5 / 2.0)  # tp 1.5, fp 0.5, no miss
    assert iou[1] == pytest.approx(2.0 / 2.5)  # tp 2, a miss of 0.5


@pytest.mark.parametrize("bad", [np.nan, 1.5, -0.25, np.inf])
def test_predicted_iou_refuses_a_confidence_that_is_no_probability(bad):
    # a NaN gave {} (every class left out), 1.5 an IoU above 1: figures that say nothing, returned as if they did
    labels = np.array([[0, 0, 1, 1]], np.uint8)
    second = np.array([[1, 1, 0, 0]], np.uint8)
    conf = np.array([[1.0, bad, 1.0, 1.0]], np.float32)
    with pytest.raises(InputError, match="confidence"):
        multiclass.predicted_iou(labels, conf, second, [0, 1])
    with pytest.raises(InputError, match="differ in shape"):
        multiclass.predicted_iou(labels, np.ones((1, 3), np.float32), second, [0, 1])


def _camvid_folder(shared_data, tmp_path, n=5, keys=(0,)):
    import shutil

    src = shared_data / "camvid" / "0001TP"
    names = sorted(p.name for p in (src / "images").iterdir())[:n]
    for sub in ("frames", "keys", "truth"):
        (tmp_path / sub).mkdir()
    for m in names:
        shutil.copy(src / "images" / m, tmp_path / "frames" / m)
        shutil.copy(src / "labels" / m, tmp_path / "truth" / m)
    for k in keys:
        shutil.copy(src / "labels" / names[k], tmp_path / "keys" / names[k])
    return names


@pytest.mark.parametrize("keys", [(0,), (0, 4)])
def test_pcreg_run_labels_eleven_classes(shared_data, tmp_path, keys):
    """``pcreg run --classes camvid11`` from one key frame or a folder of two: palette PNGs of CamVid's ids,
    the error against the truth counted over the classes, each step's predicted IoU per class."""
    import json

    from pcreg.cli import main
    from pcreg.export import read_labels

    names = _camvid_folder(shared_data, tmp_path, keys=keys)
    labels = tmp_path / "keys" if len(keys) > 1 else tmp_path / "keys" / names[0]
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "frames"), "--labels", str(labels), "--classes", "camvid11",
                 "--truth", str(tmp_path / "truth"), "--confidence", "--out", str(out)]) == 0
    import cv2

    truth = [cv2.imread(str(tmp_path / "truth" / m), cv2.IMREAD_UNCHANGED) for m in names]
    trained = set(np.unique(truth[0]).tolist()) - {CAMVID11.unknown}
    errors = []
    for m, t in zip(names[1:4], truth[1:4]):
        lab = read_labels(out / m, CAMVID11)
        assert set(np.unique(lab).tolist()) <= trained | set(np.unique(truth[4]).tolist())
        known = t != CAMVID11.unknown
        errors.append(100.0 * np.mean(lab[known] != t[known]))
    state = json.loads((out / "run.json").read_text())
    assert state["truth"]["error"] == pytest.approx(np.mean(errors), abs=15)  # pooled against per-frame means
    assert state["truth"]["error"] < state["truth"]["plain_error"]
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert any("predicted_iou" in s for s in steps)
    from pcreg.review import class_figures, read_review

    figures = class_figures(read_review(out), 2)  # what the review's legend shows beside each class
    assert [f["id"] for f in figures] == list(range(11))
    assert sum(f["share"] for f in figures) <= 100.0 + 1e-6
    assert any(f["iou"] is not None and 0 <= f["iou"] <= 1 for f in figures)
    assert main(["run", str(tmp_path / "frames"), "--labels", str(labels), "--classes", "camvid11",
                 "--truth", str(tmp_path / "truth"), "--confidence", "--out", str(out)]) == 0  # all done: resumes


def test_evaluate_stream_scores_every_class(shared_data, tmp_path):
    """``evaluate stream --classes camvid11``: every method's mIoU per clip and IoU per class, and the checks
    against each baseline."""
    import json

    from pcreg.cli import main
    from pcreg.experiments.stream_classes import CLASS_METHODS

    out = tmp_path / "ev"
    assert main(["evaluate", "stream", "--data", f"camvid:{shared_data / 'camvid' / '0001TP'}", "--frames", "4",
                 "--keys", "first,last", "--classes", "camvid11", "--out", str(out)]) == 0
    doc = json.loads((out / "results.json").read_text())
    clip = doc["datasets"]["0001TP"]
    assert set(clip["miou"]) == set(CLASS_METHODS) and all(0 <= v <= 100 for v in clip["miou"].values())
    assert clip["means"]["pcreg"] < clip["means"]["plain"]
    assert "sky" in (out / "stream_iou.md").read_text()
    assert "mIoU at least 3 points" in (out / "checks.md").read_text()


def test_a_class_table_file_edited_since_is_another_configuration(shared_data, tmp_path, capsys):
    """``evaluate stream --classes FILE`` run again after FILE changed (sky no longer scored) resumed the units of
    the table as it was (mIoU 38.78 where a fresh run gives 31.77), and named the classes by the file as it is."""
    import json

    from pcreg.classes import CAMVID11, table_json
    from pcreg.cli import main

    table = tmp_path / "table.json"
    table.write_text(table_json(CAMVID11))
    args = ["evaluate", "stream", "--data", f"camvid:{shared_data / 'camvid' / '0001TP'}", "--frames", "3",
            "--methods", "plain", "--classes", str(table), "--out", str(tmp_path / "ev")]
    assert main(args) == 0
    doc = json.loads(table.read_text())
    doc["unknown"] = 0  # sky is not scored
    table.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different configuration" in err[0], err
    config = json.loads((tmp_path / "ev" / "config.json").read_text())
    assert config["class_table"]["unknown"] == CAMVID11.unknown  # the table the units were scored in
    table.unlink()  # the report of the table as it was scored, without its file
    from pcreg.experiments.reports.stream_classes import classes_tables

    names = [r[0] for r in classes_tables(json.loads((tmp_path / "ev" / "results.json").read_text()))["stream_iou"][2]]
    assert "sky" in names


@pytest.mark.parametrize("model", ["dense", "similarity"])
def test_eleven_classes_without_a_trust_rule(shared_data, model):
    """With no trust rule the key frame's evidence per class is carried along the motion (a field or a
    global transform) at the weight, and the best class read: no confidence, labels of the trained classes."""
    from pcreg.classification.bayes import fit_classifier
    from pcreg.datasets import Frame

    images, labels = _clip(shared_data, 3)
    clf = fit_classifier([Frame(images[0], labels[0], "key")], classes=CAMVID11)
    prop = Propagator(clf, trust=None, model=model)
    prop.reset(images[0], labels[0])
    for image in images[1:]:
        out = prop.step(image)
        assert set(np.unique(out).tolist()) <= set(clf.classes_.tolist())
        assert prop.last.confidence is None and prop.last.predicted_iou is None


def test_a_chained_eleven_class_stream_resumes_exactly_from_its_saved_carry(shared_data, tmp_path):
    """With more than two classes the stream registers each frame to the previous one; what a step hands to
    the next (the frame and its motion to the key frame) goes through the carry file, and a propagator
    resumed from it labels the next frames exactly as the uninterrupted one."""
    from pcreg.pipeline.estimators import ChainCarry
    from pcreg.runs.files import read_carry, write_carry

    images, labels = _clip(shared_data, 6)
    whole = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, scale=0.5)
    assert whole.anchor == multiclass.CLASS_ANCHOR == "previous"
    saved, expected = {}, {}
    for t in range(1, 6):
        expected[t] = (whole.step(images[t]).copy(), whole.last.confidence.copy())
        saved[t] = (whole.carry, whole.learned)
        assert whole.last.reference == t - 1  # registered to the frame before
    carry = saved[3][0]
    assert isinstance(carry, ChainCarry) and carry.frame == 3 and carry.rgb.shape == (180, 240, 3)
    write_carry(tmp_path / "carry.npz", 3, *saved[3])
    back, learned = read_carry(tmp_path / "carry.npz", 3, "")
    resumed = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, scale=0.5)
    resumed.resume(3, back, learned)
    for t in (4, 5):
        np.testing.assert_array_equal(resumed.step(images[t]), expected[t][0])
        np.testing.assert_array_equal(resumed.last.confidence, expected[t][1])
    with pytest.raises(InputError, match="ChainCarry"):
        Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, scale=0.5).resume(3, None)
    after_key = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, scale=0.5)
    after_key.resume(0, None)  # after the key frame itself: its chain is the key frame, no carry needed
    np.testing.assert_array_equal(after_key.step(images[1]), expected[1][0])
    np.testing.assert_array_equal(after_key.last.confidence, expected[1][1])
    with pytest.raises(InputError, match="another stream"):  # a carried frame of another size
        Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11).resume(3, back)
    keyed = Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11, anchor="key")
    assert keyed.anchor == "key" and not isinstance(keyed.carry, ChainCarry)


def test_an_interrupted_eleven_class_run_resumes_as_the_whole_one(shared_data, tmp_path, monkeypatch):
    from _runs import kill_before_commit

    from pcreg.cli import main

    names = _camvid_folder(shared_data, tmp_path, n=5)
    base = ["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "keys" / names[0]), "--classes", "camvid11",
            "--scale", "0.5", "--confidence"]
    assert main([*base, "--out", str(tmp_path / "whole")]) == 0
    kill_before_commit(monkeypatch, 3)
    assert main([*base, "--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    assert main([*base, "--out", str(tmp_path / "cut")]) == 0
    for m in names[1:]:
        for name in (m, f"confidence/{m}"):
            assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "cut" / name).read_bytes(), name


@pytest.mark.parametrize("k", [2, 3, 5, 11])
def test_the_carried_evidence_is_opencvs_remap_to_the_bit(k):
    import cv2

    rng = np.random.default_rng(0)
    h, w = 240, 320  # enough pixels for the rows to be shared with the helper thread
    values = rng.normal(0.0, 3.0, (h, w, k)).astype(np.float32)
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).astype(np.float32)
    field = (grid + rng.normal(0.0, 4.0, (h, w, 2))).astype(np.float32)
    field[::7, ::5] = np.nan  # no position: outside
    field[0, :, 0] = np.linspace(-3.0, 2.0, w)  # across the left border
    field[1, :, 1] = np.linspace(h - 2.0, h + 1.0, w)  # across the bottom one
    field[2, :, 0] = np.arange(w) / 64.0  # positions half-way between two of OpenCV's 1/32 px steps
    expected = cv2.remap(values, field, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    assert np.array_equal(multiclass.carried_log_probs(values, field), expected.reshape(h, w, k), equal_nan=True)


@pytest.mark.parametrize("second", [True, False])
def test_the_fusion_marks_what_the_window_and_the_confidence_read_as_they_would(second):
    from pcreg.pipeline._class_kernels import best_agreement, carried_best

    rng = np.random.default_rng(1)
    h, w, k = 240, 320, 6
    d, l1, l2 = (rng.normal(0.0, 3.0, (h, w, k)).astype(np.float32) for _ in range(3))
    w1, w2 = (rng.uniform(0.0, 2.0, (h, w)).astype(np.float32) for _ in range(2))
    w1[:10] = 0.0  # no trust at all: every class allowed, the carried label read at the least weight
    pairs = [(w1, l1), (w2, l2) if second else (None, None)]
    total = w1 + w2 if second else w1
    log_pi = np.log(rng.dirichlet(np.ones(k))).astype(np.float32)
    fused, prior, (carried, agree) = multiclass.fused_and_marked(d, pairs, total, log_pi)
    f0, p0 = multiclass.fused_scores(d, pairs)
    assert np.array_equal(fused, f0) and np.array_equal(prior, p0)
    assert np.array_equal(carried, carried_best(p0, total, log_pi))
    assert np.array_equal(carried, np.argmax(p0 / np.maximum(total, np.float32(1e-6))[..., None] + log_pi, axis=2))
    assert np.array_equal(agree, best_agreement(d, p0))
    assert np.array_equal(multiclass.windowed(f0, p0, total, log_pi, carried=carried),
                          multiclass.windowed(f0, p0, total, log_pi))


@pytest.mark.parametrize("h, w, k, side", [(480, 640, 11, 129), (7, 5, 3, 3), (1, 1, 2, 1), (50, 33, 70, 9),
                                        (40, 60, 130, 97), (64, 80, 256, 11), (30, 20, 5, 201)])
def test_the_class_window_holds_the_classes_a_dilation_of_each_class_would(h, w, k, side):
    from pcreg.pipeline._class_kernels import class_window

    rng = np.random.default_rng(h * w + k)
    carried = cv2.resize(rng.integers(0, k, (max(1, h // 8), max(1, w // 8))).astype(np.uint8), (w, h),
                         interpolation=cv2.INTER_NEAREST)
    bits = class_window(carried, k, side)
    assert bits.shape == (h, w, (k + 63) // 64) and bits.dtype == np.uint64
    one_hot = (carried[..., None] == np.arange(k)).astype(np.uint8)
    kernel = np.ones((side, side), np.uint8)  # OpenCV dilates at most 128 channels at once: 64 at a time
    expected = np.concatenate([cv2.dilate(np.ascontiguousarray(one_hot[..., i:i + 64]), kernel).reshape(h, w, -1)
                               for i in range(0, k, 64)], axis=2)
    found = np.stack([(bits[..., c // 64] >> np.uint64(c % 64)) & np.uint64(1) for c in range(k)], axis=2)
    assert np.array_equal(found, expected)


@pytest.mark.parametrize("h, w, k, sides", [(480, 640, 11, (13, 29)), (7, 5, 3, (3, 9)), (1, 1, 2, (1, 3)),
                                         (51, 33, 70, (5, 23)), (40, 60, 150, (15, 45)), (2, 3, 4, (7,))])
def test_the_purities_are_what_blurring_each_class_at_half_size_reads(h, w, k, sides):
    from pcreg.pipeline._class_kernels import purities

    rng = np.random.default_rng(h + w + k)
    best = cv2.resize(rng.integers(0, k, (max(1, h // 6), max(1, w // 6))).astype(np.uint8), (w, h),
                      interpolation=cv2.INTER_NEAREST).astype(np.intp)
    best[rng.random((h, w)) < 0.1] = rng.integers(0, k)  # ties within blocks, and classes in specks
    own, shares = purities(best, k, sides)
    hh, hw = max(1, h // 2), max(1, w // 2)
    blocks = np.zeros((hh, hw, k), np.float32)  # each 2x2 block's share of each class
    for di in range(2):
        for dj in range(2):
            part = best[di::2, dj::2][:hh, :hw]
            np.add.at(blocks, (*np.indices(part.shape), part), np.float32(0.25))
    assert np.array_equal(own, np.argmax(blocks, axis=2))
    for n, side in enumerate(sides):
        m = np.concatenate([cv2.blur(np.ascontiguousarray(blocks[..., i:i + 64]), (side, side),
                                     borderType=cv2.BORDER_REFLECT).reshape(hh, hw, -1) for i in range(0, k, 64)], axis=2)
        assert np.array_equal(shares[n], np.take_along_axis(m, own[..., None], axis=2)[..., 0])


def test_the_confidence_kernels_give_numpys_numbers():
    from pcreg.pipeline._class_kernels import log_margins, logistic_confidence

    rng = np.random.default_rng(7)
    h, w = 300, 400  # large enough to be shared with the helper thread
    margin = (rng.standard_exponential((h, w)) * rng.choice([0.01, 1.0, 30.0, 1e4], (h, w))).astype(np.float32)
    margin[:3] = np.array([-1.0, 0.0, np.nan], np.float32)[:, None]
    with np.errstate(invalid="ignore"):
        expected_lm = np.log1p(np.maximum(margin, np.float32(0)))
    lm = log_margins(margin)
    # numpy's float32 log1p is its own SIMD routine where the CPU has AVX-512, and it differs from the C
    # library's, which the compiled kernel calls, by one or two units in the last place (6% of these values there)
    assert np.array_equal(np.isnan(lm), np.isnan(expected_lm))
    np.testing.assert_array_max_ulp(np.nan_to_num(lm), np.nan_to_num(expected_lm), maxulp=2)
    lm = np.nan_to_num(lm)
    z0, piece = (rng.normal(0.0, 20.0, (h, w)).astype(np.float32) for _ in range(2))
    a, b, c, least = -1.131, -1.38, 0.834, 0.25
    for p in (piece, None):
        z = z0.copy()
        if p is not None:
            z += np.float32(c) * p * lm
        z += np.float32(a) * lm + np.float32(b)
        expected = np.maximum(np.float32(1) / (np.float32(1) + np.exp(-np.clip(z, -60.0, 60.0))), np.float32(least))
        got = logistic_confidence(z0.copy(), lm, a, b, least, piece=p, c=c)
        assert np.array_equal(got, expected)


def test_a_class_outside_the_window_is_lowered_where_the_priors_are_trusted():
    rng = np.random.default_rng(5)
    h, w, k = 120, 160, 4
    fused = rng.normal(0.0, 2.0, (h, w, k)).astype(np.float32)
    prior = np.zeros((h, w, k), np.float32)
    prior[..., 0] = 5.0
    prior[:, 150:, 0], prior[:, 150:, 2] = 0.0, 5.0  # class 2 carried at the right edge only
    weight = np.ones((h, w), np.float32)
    weight[:10] = 0.0  # untrusted rows: every class allowed
    out = multiclass.windowed(fused, prior, weight, np.zeros(k, np.float32))
    from pcreg.pipeline.readout import odd

    side = odd(multiclass.CLASS_WINDOW, w)
    near = np.zeros(w, bool)
    near[max(0, 150 - side // 2):] = True
    lowered = fused - np.float32(multiclass.CLASS_PENALTY)
    assert np.array_equal(out[:10], fused[:10])
    assert np.array_equal(out[10:, :, 0], fused[10:, :, 0])  # shown everywhere
    assert np.array_equal(out[10:, :, 1], lowered[10:, :, 1]) and np.array_equal(out[10:, :, 3], lowered[10:, :, 3])
    assert np.array_equal(out[10:, near, 2], fused[10:, near, 2])
    assert np.array_equal(out[10:, ~near, 2], lowered[10:, ~near, 2])


def test_evidence_of_one_vector_a_label_is_carried_from_the_labels_to_the_bit():
    rng = np.random.default_rng(2)
    h, w, k = 240, 320, 11
    labels = rng.integers(0, 12, (h, w)).astype(np.uint8)
    labels[:, :40] = 255  # a value no class has: the class prior alone
    table = rng.normal(0.0, 3.0, (256, k)).astype(np.float32)
    values = table[labels]
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).astype(np.float32)
    field = (grid + rng.normal(0.0, 6.0, (h, w, 2))).astype(np.float32)
    field[::9, ::4] = np.nan
    field[0, :, 0] = np.linspace(-3.0, 2.0, w)
    by_label = multiclass.label_evidence(labels, values)
    assert by_label is not None
    assert np.array_equal(multiclass.carried_log_probs(values, field, labels=by_label),
                          multiclass.carried_log_probs(values, field))
    values[5, 5, 0] += 1.0  # no longer one vector a label
    assert multiclass.label_evidence(labels, values) is None
    assert multiclass.label_evidence(labels, values[:, :, :3]) is None  # three classes: OpenCV's own remap


def test_region_means_follow_connected_pieces():
    """Each pixel gets the mean over its 4-connected piece of one label: two pieces of the same label apart
    (here touching only at a corner) are two pieces."""
    from pcreg.pipeline._class_regions import region_means

    labels = np.array([[0, 0, 1, 2],
                       [1, 1, 0, 2],
                       [1, 1, 0, 2]], np.uint8)
    values = np.arange(12, dtype=np.float32).reshape(3, 4)
    want = np.array([[0.5, 0.5, 2.0, 7.0],
                     [6.5, 6.5, 8.0, 7.0],
                     [6.5, 6.5, 8.0, 7.0]], np.float32)
    assert np.allclose(region_means(labels, values), want)


def test_a_label_in_a_piece_read_with_small_margins_is_less_sure():
    """Two pixels with the same margin, deep in pieces that are pure and agree with the carried prior: the
    one whose piece was read with small margins elsewhere gets the lower confidence (the region's terms of
    CLASS_CONFIDENCE_COEFFICIENTS); and the coefficients are eight."""
    h, w, k = 64, 128, 3
    best = np.zeros((h, w), np.intp)
    best[:, 64:] = 1
    margin = np.full((h, w), 5.0, np.float32)
    margin[:, 64:] = 0.2
    margin[24:40, 16:48] = margin[24:40, 80:112] = 3.0  # the same margin at the two pixels compared
    scores = np.zeros((h, w, k), np.float32)
    scores[..., 0] = best == 0
    scores[..., 1] = best == 1
    conf = multiclass.class_confidence(margin, best, scores, scores, multiclass.CLASS_CONFIDENCE_COEFFICIENTS)
    assert conf[32, 32] > conf[32, 96] + 0.05
    with pytest.raises(InputError, match="8 coefficients"):
        multiclass.class_confidence(margin, best, scores, scores, multiclass.CLASS_CONFIDENCE_COEFFICIENTS[:5])


def test_a_frame_read_with_small_margins_overall_is_less_sure_everywhere():
    """The same pixel, its piece and its neighbourhood alike, in two frames: in the one whose other pieces were
    read with small margins it gets the lower confidence (the frame's term of CLASS_CONFIDENCE_COEFFICIENTS),
    by the logistic model's intercept moved by 1.2 times the change of the frame's mean log1p(margin)."""
    h, w, k = 64, 128, 3
    best = np.zeros((h, w), np.intp)
    best[:, 64:] = 1
    scores = np.zeros((h, w, k), np.float32)
    scores[..., 0] = best == 0
    scores[..., 1] = best == 1
    sure, unsure = np.full((h, w), 5.0, np.float32), np.full((h, w), 5.0, np.float32)
    unsure[:, 64:] = 0.1  # the other piece read with small margins
    coefficients = multiclass.CLASS_CONFIDENCE_COEFFICIENTS
    a, b = (multiclass.class_confidence(m, best, scores, scores, coefficients)[32, 32] for m in (sure, unsure))
    assert a > b > multiclass.CLASS_MIN_CONFIDENCE
    logit = lambda p: np.log(p / (1.0 - p))  # noqa: E731
    frame_change = float(np.mean(np.log1p(unsure)) - np.mean(np.log1p(sure)))
    assert logit(b) - logit(a) == pytest.approx(coefficients[7] * frame_change, rel=1e-3)


@pytest.mark.parametrize("kill_at, phase", [(6, "between"), (9, "backward"), (13, "forward")])
def test_an_interrupted_eleven_class_run_from_a_key_folder_resumes_to_the_same_bytes(shared_data, tmp_path, monkeypatch,
                                                                                   kill_at, phase):
    """Key frames 1 and 4 of seven CamVid frames, the stream chained frame to frame: killed at a commit of the
    stretch between the key frames (its forward pass kept, its backward pass) or of the one after, then run
    again: every label and confidence PNG, run.json and the steps are those of the uninterrupted run."""
    from _runs import kill_at_commit, timeless

    from pcreg.cli import main

    names = _camvid_folder(shared_data, tmp_path, n=7, keys=(1, 4))
    base = ["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "keys"), "--classes", "camvid11",
            "--scale", "0.5", "--confidence"]
    assert main([*base, "--out", str(tmp_path / "whole")]) == 0
    kill_at_commit(monkeypatch, kill_at, phase)
    assert main([*base, "--out", str(tmp_path / "cut")]) == 130
    monkeypatch.undo()
    assert main([*base, "--out", str(tmp_path / "cut")]) == 0
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    written = sorted(p.relative_to(whole).as_posix() for p in whole.rglob("*.png"))
    assert len(written) == 2 * 7 - 2  # every frame's labels, and the confidence of the five that are not key frames
    for name in written:
        assert (whole / name).read_bytes() == (cut / name).read_bytes(), name
    assert (whole / "run.json").read_bytes() == (cut / "run.json").read_bytes()
    assert ([timeless(x) for x in (whole / "steps.jsonl").read_text().splitlines()]
            == [timeless(x) for x in (cut / "steps.jsonl").read_text().splitlines()])
    assert names[1] in {p.name for p in whole.glob("*.png")}


def test_evaluate_stream_prints_the_miou_table(shared_data, tmp_path, capsys):
    """With ``--classes`` the command prints the mIoU table (its headline) after the error table, as written to
    OUT/stream_miou.md (three frames of a clip, two key frames)."""
    import shutil

    from pcreg.cli import main

    clip = tmp_path / "data" / "0001TP"
    source = shared_data / "camvid" / "0001TP"
    for part in ("images", "labels"):
        (clip / part).mkdir(parents=True)
        for p in sorted((source / part).iterdir())[:3]:
            shutil.copy(p, clip / part / p.name)
    out = tmp_path / "ev"
    assert main(["evaluate", "stream", "--data", f"camvid:{clip.parent}", "--frames", "3", "--keys", "spaced:2",
                 "--classes", "camvid11", "--methods", "plain", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    errors, miou = (out / "stream_reference.md").read_text(), (out / "stream_miou.md").read_text()
    assert "mIoU" in miou and "0001TP" in miou
    assert errors in printed and miou in printed
    assert printed.index(errors) < printed.index(miou) < printed.index((out / "checks.md").read_text())
