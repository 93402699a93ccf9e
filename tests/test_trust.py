"""The trust rule, the labels' confidence, learning from the stream, and their outputs."""

import json

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.pipeline import trust as T
from pcreg.pipeline.learning import Learner, Learning


@pytest.fixture(scope="module")
def frames():
    return pcreg.synthetic("syn2a", 6, 0, width=320, height=240)


@pytest.fixture(scope="module")
def stepped(frames):
    prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels)
    reports = []
    for f in frames[1:]:
        labels = prop.step(f.image)
        reports.append((f, labels, prop.last))
    return prop, reports


def test_every_label_has_a_confidence_in_0_1_and_the_sure_ones_are_more_often_right(stepped):
    _, reports = stepped
    right, conf = [], []
    for f, labels, last in reports:
        c = last.confidence
        assert c.shape == labels.shape and c.dtype == np.float32
        assert np.all(np.isfinite(c)) and c.min() >= 0 and c.max() <= 1
        assert last.predicted_error == pytest.approx(100 * (1 - c.mean(dtype=np.float64)))
        assert json.loads(json.dumps(last.to_dict()))["predicted_error"] == pytest.approx(last.predicted_error)
        known = f.labels < 2
        right.append(((labels == 1) == (f.labels == 1))[known])
        conf.append(c[known])
    right, conf = np.concatenate(right), np.concatenate(conf)
    sure = conf >= np.quantile(conf, 0.5)
    assert right[sure].mean() > right[~sure].mean()  # the confidence ranks the labels


def test_the_trust_rule_labels_better_than_one_weight(frames, stepped):
    _, reports = stepped
    plain = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, trust=None, learning=None)
    err_trust = np.mean([pcreg.error_rate(labels, f.labels) for f, labels, _ in reports])
    err_plain = np.mean([pcreg.error_rate(plain.step(f.image), f.labels) for f, _, _ in reports])
    assert err_trust <= err_plain


def test_a_prior_wholly_outside_the_key_frame_leaves_naive_bayes_alone():
    rng = np.random.default_rng(0)
    d = rng.normal(0, 3, (40, 60)).astype(np.float32)
    prior = rng.normal(0, 5, (40, 60)).astype(np.float32)
    outside = np.full((40, 60), T.OUTSIDE, np.float32)
    maps = T.trust_maps(T.STREAM_TRUST, weight=2.0, primary_prior=prior, primary_residual=outside,
                        confidence=np.ones((40, 60), np.float32), second_prior=prior, second_residual=outside)
    np.testing.assert_array_equal(T.fused_log_odds(d, maps), d)
    near = T.trust_maps(T.STREAM_TRUST, weight=2.0, primary_prior=prior, primary_residual=np.zeros_like(d),
                        confidence=None, second_prior=None, second_residual=None)
    np.testing.assert_allclose(near.primary, 2.0 * T.STREAM_TRUST.dense)  # full trust at confidence 1/3
    assert near.second is None


def test_carried_residual_is_zero_along_the_true_motion_and_outside_beyond_the_frame():
    rng = np.random.default_rng(1)
    img = rng.integers(0, 255, (60, 80, 3)).astype(np.uint8)
    b = T.blurred(img)
    ys, xs = np.mgrid[0:60, 0:80].astype(np.float32)
    same = T.carried_residual(b, b, np.dstack([xs, ys]))
    assert same.max() < 1e-3
    away = T.carried_residual(b, b, np.dstack([xs + 500, ys]))
    np.testing.assert_allclose(away, T.OUTSIDE, rtol=1e-5)


def test_label_confidence_refuses_wrong_coefficients():
    z = np.zeros((8, 8), np.float32)
    with pytest.raises(InputError, match="coefficients"):
        T.label_confidence(z, z, z, coefficients=(1.0, 2.0))
    for bad in ({"dense": -1}, {"flow": "x"}, {"residual": 0}, {"preset": "slow"}):
        with pytest.raises(InputError):
            T.TrustRule(**bad)
    with pytest.raises(InputError, match="TrustRule"):
        pcreg.Propagator(pcreg.fit_classifier(pcreg.synthetic("syn1a", 1, 0, width=64, height=48)), trust=0.5)


def test_learning_never_lets_the_stream_outweigh_the_key_frame(frames):
    clf = pcreg.fit_classifier([frames[0]])
    rule = Learning(share=0.5, decay=1.0, sure=0.0, stride=2)
    learner = Learner(clf, rule)
    key_pixels = clf.counts_[:, 0].sum()
    for f in frames[1:] * 4:  # twenty frames, all taken as sure
        fused = np.where(f.labels == 1, 5.0, -5.0).astype(np.float32)
        learner.update(f.image, fused, fused)
    assert learner.stream[:, 0].sum() > key_pixels  # more stream pixels than key pixels were seen ...
    learned = learner.classifier.counts_[:, 0].sum()
    assert learned <= key_pixels * (1 + rule.share) + 3  # ... but they weigh at most half the key frame's
    assert not np.array_equal(learner.classifier.theta_, clf.theta_)
    again = Learner(clf, rule)
    again.restore(learner.stream)
    np.testing.assert_array_equal(again.classifier.theta_, learner.classifier.theta_)
    for bad in (np.zeros((2, 2)), np.full(learner.stream.shape, np.nan), -np.ones(learner.stream.shape)):
        with pytest.raises(InputError, match="learned"):
            again.restore(bad)
    with pytest.raises(InputError):
        Learning(share=2)


def test_calibration_summary_matches_a_direct_count():
    from pcreg.experiments.stream import calibration, calibration_counts

    rng = np.random.default_rng(2)
    conf = rng.uniform(0.5, 1.0, (50, 40)).astype(np.float32)
    truth = rng.integers(0, 3, (50, 40)).astype(np.uint8)
    labels = np.where(rng.uniform(size=(50, 40)) < conf, truth, 1 - np.minimum(truth, 1)).astype(np.uint8)
    labels[truth == 2] = 0
    counts = calibration_counts(conf, labels, truth)
    cal = calibration(counts)
    known = truth < 2
    wrong = (labels[known] == 1) != (truth[known] == 1)
    assert cal["pixels"] == known.sum()
    assert cal["error"] == pytest.approx(100 * wrong.mean())
    level = np.rint(conf[known] * 255) / 255
    order = np.argsort(-level, kind="stable")
    n = int(0.8 * known.sum())
    assert cal["error_top80"] == pytest.approx(100 * wrong[order[:n]].mean(), abs=2.0)
    assert 0 <= cal["ece"] < 0.2
    assert calibration(np.zeros((2, 256))) == {"pixels": 0}


def _folder(tmp_path, frames):
    import cv2

    src = tmp_path / "frames"
    src.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(src / f"f{i:03d}.png"), cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(tmp_path / "key.png"), frames[0].labels)
    return src


def test_run_writes_confidence_maps_and_refuses_to_resume_without_them(tmp_path, frames, capsys):
    import cv2

    src = _folder(tmp_path, frames[:4])
    out = tmp_path / "out"
    args = ["run", str(src), "--labels", str(tmp_path / "key.png"), "--out", str(out)]
    assert main(args + ["--confidence"]) == 0
    for i in range(1, 4):
        c = cv2.imread(str(out / "confidence" / f"f{i:03d}.png"), cv2.IMREAD_UNCHANGED)
        assert c.dtype == np.uint8 and c.shape == frames[0].labels.shape and c.max() > 128
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert len(steps) == 3 and all(0 <= s["predicted_error"] <= 100 for s in steps)
    before = sorted(p.name for p in out.rglob("*"))
    assert main(args) == 2  # the same run without --confidence: another run's options
    assert "other options" in capsys.readouterr().err
    assert sorted(p.name for p in out.rglob("*")) == before  # nothing lost


def test_a_confidence_outside_0_1_is_never_written():
    from pcreg.runs.files import confidence_png

    np.testing.assert_array_equal(confidence_png(np.array([[0.0, 0.5, 1.0]])), [[0, 128, 255]])
    for bad in (np.array([[np.nan]]), np.array([[1.5]]), np.array([[-0.1]])):
        with pytest.raises(AssertionError):
            confidence_png(bad)


def test_two_key_frames_label_the_frames_between_better_than_one(frames):
    from pcreg.pipeline.engine import Stretch, stretches
    from pcreg.pipeline.keyframes import label_clip

    n = len(frames)
    plan = stretches([4, 2], n)
    assert plan == [Stretch(None, 2, 2), Stretch(2, 4, 4), Stretch(4, None, n)]
    assert [s.frames for s in plan] == [range(0, 2), range(3, 4), range(5, 6)]
    assert [s.keys for s in plan] == [(2,), (2, 4), (4,)]
    assert stretches([3], None) == [Stretch(None, 3, 3), Stretch(3, None, None)]  # a video of unknown length
    with pytest.raises(InputError, match="outside"):
        stretches([0, n], n)
    one = label_clip(lambda t: frames[t].image, n, {0: frames[0].labels})
    two = label_clip(lambda t: frames[t].image, n, {0: frames[0].labels, n - 1: frames[n - 1].labels})
    between = range(1, n - 1)
    err1 = np.mean([pcreg.error_rate(one[t].labels, frames[t].labels) for t in between])
    err2 = np.mean([pcreg.error_rate(two[t].labels, frames[t].labels) for t in between])
    assert err2 < err1
    for f in two:
        assert (f.confidence is None) == (f.index in (0, n - 1))
        assert f.keys == ((f.index,) if f.index in (0, n - 1) else (0, n - 1))
    back = label_clip(lambda t: frames[t].image, n, {n - 1: frames[n - 1].labels})  # backwards only
    assert all(f.keys == (n - 1,) for f in back)


def test_a_key_frame_added_relabels_only_the_stretch_it_splits(frames):
    """Each stretch's classifier is fitted on its own key frames (fit="stretch"): the frames outside the
    split stretch keep their labels; fitted on all of them (fit="all"), every frame may change."""
    from pcreg.pipeline.keyframes import label_clip

    n, image = len(frames), (lambda t: frames[t].image)
    keys = {1: frames[1].labels, 3: frames[3].labels}
    before = label_clip(image, n, keys)
    after = label_clip(image, n, {**keys, 5: frames[5].labels})
    for t in range(4):  # before 1, and between 1 and 3: untouched by a key frame at 5
        np.testing.assert_array_equal(after[t].labels, before[t].labels)
        assert after[t].predicted_error == before[t].predicted_error
    assert after[4].keys == (3, 5) and before[4].keys == (3,)
    everywhere = label_clip(image, n, {**keys, 5: frames[5].labels}, fit="all")
    assert [f.keys for f in everywhere] == [f.keys for f in after]
    with pytest.raises(InputError, match="fit"):
        label_clip(image, n, keys, fit="some")


def test_suggest_picks_far_frames_predicted_wrong_without_truth():
    from pcreg.pipeline.keyframes import suggest

    predicted = {t: 1.0 + 0.1 * t for t in range(1, 30)}
    assert suggest(predicted, [0], 1, 30) == [29]  # the far end of a stretch labelled from one side
    picks = suggest(predicted, [0], 3, 30)
    assert picks[0] == 29 and len(set(picks)) == 3 and 0 not in picks
    bumped = {**predicted, 10: 50.0}
    assert suggest(bumped, [0, 29], 1, 30) == [10]  # between two key frames: where the error is predicted
    with pytest.raises(InputError, match="only"):
        suggest({1: 1.0}, [0], 2, 3)



def _suggest_as_stated(predicted, keys, count):
    """:func:`~pcreg.pipeline.keyframes.suggest`'s rule written as its docstring states it, one frame at a time."""
    taken, chosen = set(keys), []
    candidates = [t for t in predicted if t not in taken]
    for _ in range(count):
        near = {t: min(abs(t - k) for k in taken | set(chosen)) for t in candidates if t not in chosen}
        ends = [t for t in (min(candidates), max(candidates)) if t in near and not min(taken) <= t <= max(taken)]
        if ends:
            pick = max(ends, key=lambda t: (near[t], -t))
        else:
            pick = max(near, key=lambda t: (predicted[t] * near[t], -t))
        chosen.append(pick)
        taken.add(pick)
    return chosen


def test_suggest_follows_its_rule_on_random_clips_ties_included():
    """The suggestions keep each candidate's distance to the nearest labelled frame as they go (a clip of 100,000
    frames with 200 key frames took 14.7 s, every candidate measured against every labelled frame each pick):
    the same frames as the rule stated one frame at a time, ties (equal errors, a whole clip predicted
    right) to the earliest frame."""
    from pcreg.pipeline.keyframes import suggest

    rng = np.random.default_rng(3)
    for trial in range(200):
        n = int(rng.integers(2, 60))
        keys = sorted(set(rng.choice(n, size=int(rng.integers(1, min(n, 5) + 1)), replace=False).tolist()))
        frames = [t for t in range(n) if t not in keys]
        if not frames:
            continue
        levels = rng.choice([0.0, 1.0, 2.5], size=len(frames)) if trial % 3 == 0 else rng.random(len(frames)) * 10
        predicted = dict(zip(frames, levels.tolist()))
        count = int(rng.integers(1, len(frames) + 1))
        assert suggest(predicted, keys, count, n) == _suggest_as_stated(predicted, keys, count), (predicted, keys)


def test_suggest_never_names_a_frame_outside_the_clip_nor_takes_an_error_that_is_no_number():
    """``suggest(predicted, keys, count, n)`` took ``n`` and never read it: a predicted error of frame 9 in a clip
    of 3 frames made it suggest frame 9, and a NaN predicted error (no number) was suggested before every
    finite one. Both are refused, as a key frame outside the clip is."""
    from pcreg.pipeline.keyframes import suggest

    with pytest.raises(InputError, match="frame 9 .* 3 frames"):
        suggest({1: 5.0, 9: 3.0}, [0], 2, 3)
    with pytest.raises(InputError, match="key frame 7 .* 3 frames"):
        suggest({1: 5.0, 2: 3.0}, [7], 1, 3)
    with pytest.raises(InputError, match="frame 1 .* nan"):
        suggest({1: float("nan"), 2: 3.0, 3: 1.0}, [0], 3, 4)
    assert suggest({1: 5.0, 2: 3.0}, [0], 2, 3) == [2, 1]

def test_evaluate_stream_with_key_frames_anywhere(tmp_path, capsys):
    from pcreg.experiments.stream_keys import check_key_spec, key_indices

    assert key_indices("first,last", 10) == [0, 9] and key_indices("every:4", 10) == [0, 4, 8]
    assert key_indices("spaced:3", 9) == [0, 3, 6] and key_indices("2,5", 10) == [2, 5]
    for bad in ("every:0", "suggest:x", "0,12", "spaced:0", "a,b"):
        with pytest.raises(InputError, match="--keys"):
            key_indices(bad, 10)
    # as typed by hand: spaces around the commas and colons read; 1_0 and other digits Python's int takes do not
    assert key_indices(" first, last ", 10) == [0, 9] and key_indices("spaced: 3", 9) == [0, 3, 6]
    assert key_indices("2 , 5", 10) == [2, 5] and key_indices("every : 4", 10) == [0, 4, 8]
    for bad in ("1_0", "every:1_0", "\u0662,5", "spaced:\u0663"):
        with pytest.raises(InputError, match="whole number|spaced:N, suggest:N or frame indices"):
            key_indices(bad, 12)
    for bad in ("suggest: 1_0", "suggest:x"):
        with pytest.raises(InputError, match="suggest:N takes a whole number"):
            check_key_spec(bad, 12)
    check_key_spec("suggest : 3", 12)
    huge = "9" * 5000  # past what int() reads from a string (4300 digits): its ValueError ended in exit 1
    for bad, said in ((f"spaced:{huge}", "spaced:N needs 1 <= N <= 10"), (f"2,{huge}", "must lie in 0..9"),
                      (f"-{huge}", "must lie in 0..9"), (f"suggest:{huge}", "suggest:N needs 1 <= N <= 10")):
        with pytest.raises(InputError, match=said):
            key_indices(bad, 10)
    with pytest.raises(InputError, match="suggest:N needs 1 <= N <= 10"):
        check_key_spec(f"suggest:{huge}", 10)
    assert key_indices(f"every:{huge}", 10) == [0] and key_indices("every:0009", 10) == [0, 9]
    zeros = "0" * 5000  # leading zeros count in int()'s limit too
    assert key_indices(f"spaced:{zeros}3", 9) == [0, 3, 6] and key_indices(f"2,{zeros}5", 10) == [2, 5]
    with pytest.raises(InputError) as said:  # the reason is not cut off by the spec it echoes
        key_indices(f"spaced:{huge}", 10)
    assert str(said.value) == "--keys spaced:999...999 (5000 digits): spaced:N needs 1 <= N <= 10 (the clip's frames)"
    for every in ("every:1", "spaced:10", "0,1,2,3,4,5,6,7,8,9"):  # scored nothing: a table of NaN, "met"
        with pytest.raises(InputError, match="every one of the clip's 10 frames is a key frame"):
            key_indices(every, 10)
    out = tmp_path / "o"
    args = ["evaluate", "stream", "--frames", "5", "--size", "160x120", "--data", "synthetic:syn1a", "--out", str(out)]
    assert main(args + ["--keys", "suggest:2"]) == 0
    res = json.loads((out / "results.json").read_text())
    c = res["datasets"]["syn1a"]
    assert c["key_frames"][0] == 0 and len(c["key_frames"]) == 2 and c["scored"] == 3
    assert res["methods"] == ["plain", "unregistered", "pcreg", "pcreg_half", "pcreg_flow", "flow_key", "flowultrafast_key"]
    assert res["calibration"]["pixels"] > 0
    assert c["means"]["pcreg_flow"] < c["means"]["plain"] and c["means"]["pcreg_half"] < c["means"]["plain"]
    capsys.readouterr()
    assert main(args + ["--keys", "first", "--key-every", "2", "--force"]) == 2
    assert "give one" in capsys.readouterr().err
    assert main(args + ["--keys", "first", "--methods", "dense_key", "--force"]) == 2


def test_label_confidence_is_the_logistic_model_over_its_features():
    # the neighbourhoods' part summed at half size and resized once is the model over the features
    rng = np.random.default_rng(3)
    d = cv2.GaussianBlur(rng.normal(0, 4, (96, 128)).astype(np.float32), (0, 0), 3)
    prior = cv2.GaussianBlur(rng.normal(0, 6, (96, 128)).astype(np.float32), (0, 0), 5)
    F = d + prior
    feats = T.confidence_features(F, d, prior)
    a = T.CONFIDENCE_COEFFICIENTS
    z = a[0] + sum(np.float64(c) * f for c, f in zip(a[1:], feats))
    want = np.maximum(1.0 / (1.0 + np.exp(-z)), T.MIN_CONFIDENCE)
    got = T.label_confidence(F, d, prior)
    assert got.dtype == np.float32 and got.shape == F.shape
    np.testing.assert_allclose(got, want, atol=2e-5)
    assert 0.5 < got.mean() < 1.0 and got.min() == np.float32(0.5) and got.max() > 0.9


def test_the_compiled_trusted_fusion_is_the_numpy_rule():
    # the stream's one pass (trusted_fusion) against trust_maps, prior_term and the fusion written in numpy,
    # with and without the field's confidence and the second motion, residuals outside the key frame included
    rng = np.random.default_rng(5)
    h, w = 300, 260  # over the helper's row split
    d, ld, lf = (rng.normal(0, 3, (h, w)).astype(np.float32) for _ in range(3))
    rd, rf = (rng.uniform(0, 120, (h, w)).astype(np.float32) for _ in range(2))
    rd[:10], rf[-10:] = T.OUTSIDE, T.OUTSIDE
    conf = rng.uniform(-0.2, 1.2, (h, w)).astype(np.float32)
    conf[5, 5] = np.nan
    for c in (conf, None):
        for flow in ((lf, rf), None):
            maps, prior, fused = T.trusted_fusion(T.STREAM_TRUST, 2.0, d, ld, rd, c, flow)
            want = T.trust_maps(T.STREAM_TRUST, weight=2.0, primary_prior=ld, primary_residual=rd, confidence=c,
                                second_prior=None if flow is None else lf, second_residual=None if flow is None else rf)
            np.testing.assert_allclose(maps.primary, want.primary, rtol=1e-6, atol=1e-7)
            assert (maps.second is None) == (flow is None)
            if flow is not None:
                np.testing.assert_allclose(maps.second, want.second, rtol=1e-6, atol=1e-7)
            np.testing.assert_allclose(prior, want.prior_term((h, w)), rtol=1e-5, atol=1e-5)
            numpy_fused = T.fused_log_odds(d, want)
            np.testing.assert_allclose(fused, numpy_fused, rtol=1e-5, atol=1e-5)


def test_the_labels_are_the_sign_of_the_fused_log_odds_blurred_by_the_rule(frames):
    """The rule's ``smooth``: a Gaussian of that many px at 480 wide (here 320: 2/3 of it) over the fused
    log-odds, whose sign is the label and which the confidence reads; 0 reads each pixel alone."""
    from dataclasses import replace

    key, clf = frames[0], pcreg.fit_classifier([frames[0]])
    w = key.image.shape[1]
    seen = {}
    for smooth in (0.0, 3.0):
        prop = pcreg.Propagator(clf, trust=replace(T.STREAM_TRUST, smooth=smooth), learning=None)
        prop.reset(key.image, key.labels)
        labels = prop.step(frames[2].image)
        last = prop.last
        prior = last.trust.prior_term(labels.shape)
        fused = (last.log_odds + prior).astype(np.float32)
        shown = fused if smooth == 0 else cv2.GaussianBlur(fused, (0, 0), smooth * w / 480.0)
        clear = np.abs(shown) > 1e-3  # the kernel's exponential may differ from numpy's in its last bit
        assert np.array_equal(labels[clear], (shown > 0)[clear])
        np.testing.assert_allclose(last.confidence, T.label_confidence(shown, last.log_odds, prior), atol=1e-4)
        seen[smooth] = labels
    assert np.count_nonzero(seen[0.0] != seen[3.0]) > 0.001 * seen[0.0].size  # the blur changed some labels
    with pytest.raises(InputError, match="trust smooth"):
        T.TrustRule(smooth=-1.0)


def test_the_trust_maps_names_of_before_0_2_still_read_with_a_warning():
    """TrustMaps names its motions by their role (primary, second); dense/flow/... still read, warning."""
    a, b = np.ones((2, 2), np.float32), np.zeros((2, 2), np.float32)
    maps = T.TrustMaps(a, b, None, None, a * 3, None)
    for old, new in (("dense", "primary"), ("dense_prior", "primary_prior"), ("dense_residual", "primary_residual"),
                     ("flow", "second"), ("flow_prior", "second_prior"), ("flow_residual", "second_residual")):
        with pytest.warns(DeprecationWarning, match=f"use TrustMaps.{new}"):
            assert getattr(maps, old) is getattr(maps, new)
    with pytest.raises(AttributeError):
        maps.nothing_of_the_kind
    assert set(maps.summary(T.STREAM_TRUST, 2.0)) == {"primary", "second"}
