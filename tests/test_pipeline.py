"""pcreg.pipeline: one pair and a sequence, on small synthetic frames with exact poses."""

from __future__ import annotations

import time

import numpy as np
import pytest

from pcreg.classification.bayes import NaiveBayesPixelClassifier
from pcreg.datasets import Frame, synthetic
from pcreg.errors import InputError
from pcreg.classification.fusion import FusionConfig
from pcreg.registration.config import RegisterConfig
from pcreg.pipeline import (METHODS, PIPELINE_REGISTRATION, STAGES, PipelineConfig, TemporalFusion, log_odds, pair_indices, process_pair,
                            register_pair, resolve_fusion_frames, run_sequence, temporal_update)


@pytest.fixture(scope="module")
def frames():
    return synthetic("syn2a", 10, 0, width=160, height=120)


@pytest.fixture(scope="module")
def clf(frames):
    return NaiveBayesPixelClassifier(("rgb", "hsv", "row")).fit(frames[0].image, frames[0].labels)


def test_log_odds_agrees_with_predict(frames, clf):
    d = log_odds(clf, frames[3].image)
    assert d.shape == frames[3].shape and d.dtype == np.float32
    assert np.array_equal((d > 0).astype(np.uint8), clf.predict(frames[3].image))
    jll = clf.joint_log_likelihood(frames[3].image)
    assert np.allclose(d, jll[..., 1] - jll[..., 0], atol=1e-3)


def test_log_odds_needs_ground_and_obstacle(frames):
    three = NaiveBayesPixelClassifier(("rgb",), exclude_unknown=False).fit(frames[0].image, frames[0].labels)
    with pytest.raises(InputError):
        log_odds(three, frames[0].image)


def test_process_pair_scores_every_method(frames, clf):
    chain = TemporalFusion(frames[0].labels, weight=3.0)
    done = process_pair(frames[0], frames[3], clf, weight=3.0, indices=(0, 3), keep_arrays=True, temporal=chain)
    res, arrays = done.result, done.arrays
    assert set(res.errors) == set(METHODS) and set(res.times) == set(STAGES)
    assert res.registered and res.reason is None and res.corner_error < 1.0
    assert all(0 <= v <= 100 for v in res.errors.values())
    assert res.errors["augmented"] < res.errors["plain"]
    assert arrays.warped.shape == frames[0].image.shape and arrays.valid.dtype == bool
    assert chain.labels.dtype == np.uint8 and not chain.labels.flags.writeable
    # the first step of a chain is the one-step fusion
    assert res.errors["augmented_temporal"] == pytest.approx(res.errors["augmented"])
    # the inputs are never modified (frames are read-only views)
    assert not frames[0].image.flags.writeable


def test_weight_zero_is_plain_naive_bayes(frames, clf):
    res = process_pair(frames[0], frames[2], clf, weight=0.0).result
    assert res.errors["augmented"] == res.errors["plain"] == res.errors["augmented_unregistered"]


def test_failed_registration_is_recorded_and_the_pair_still_scored(frames, clf):
    flat = Frame(np.full_like(frames[2].image, 90), frames[2].labels, "flat")
    res = process_pair(frames[0], flat, clf, weight=3.0).result
    assert not res.registered and "edges" in res.reason
    assert res.registration is None and res.corner_error is None
    assert res.errors["augmented"] == res.errors["plain"]
    assert res.errors["thesis_after"] == res.errors["thesis_before"]
    t0 = time.perf_counter()
    got = register_pair(frames[0].image, flat.image)
    elapsed = time.perf_counter() - t0
    assert got.result is None and got.matrix is None and "no usable edges" in got.reason
    assert 0 < got.seconds <= elapsed  # the refused attempt's own wall time


def test_temporal_update_passes_on_only_what_labels_reached(frames):
    from pcreg.registration.warp import warp_to_moving

    T = np.array([[1.0, 0, 20.0], [0, 1.0, 0], [0, 0, 1.0]])  # the reference lies 20 px to the right
    # a classifier that sees the moving frame's true content (so the registration is supported)
    moved_labels, _ = warp_to_moving(frames[0].labels, T, shape=frames[0].shape, interpolation="nearest", fill=0)
    d = np.where(moved_labels == 1, 0.1, -0.1).astype(np.float32)
    fused, labels = temporal_update(d, frames[0].labels, T, pi=0.3, weight=4.0)
    assert np.all(labels[:, -20:] == 2)  # content new to the view carries no label
    known = labels < 2
    assert known.any()
    fused_none, labels_none = temporal_update(d, frames[0].labels, None, pi=0.3, weight=4.0)
    assert np.all(labels_none == 2) and np.array_equal(fused_none, d)
    # a registration the new frame contradicts (the labels moved the wrong way) carries nothing
    fused_bad, labels_bad = temporal_update(d, frames[0].labels, np.linalg.inv(T), pi=0.3, weight=4.0)
    assert np.all(labels_bad == 2) and np.array_equal(fused_bad, d)
    chain = TemporalFusion(frames[0].labels, pi=0.3, weight=4.0)
    out = chain.step(d, T)
    with pytest.raises(AttributeError):
        chain.labels = labels  # the state changes only through step
    assert np.array_equal(out, fused) and np.array_equal(chain.labels, labels)


def test_run_sequence_walks_pairs_and_chooses_the_weight_on_the_first_frames(frames):
    res = run_sequence(frames, k=2, config=PipelineConfig(), fusion_frames=4)
    assert res.fusion_frames == 4
    assert [(p.reference, p.moving) for p in res.pairs] == [(i, i + 2) for i in range(2, 8)]
    assert res.weight.pairs == 2 and res.weight.weight in res.weight.grid  # pairs (0, 2), (1, 3)
    assert res.temporal_weight is not None
    assert set(res.means) == set(METHODS)
    assert res.means["augmented"] < res.means["plain"]
    assert res.to_dict()["pairs"][0]["moving"] == 4
    assert not res.failures


def test_run_sequence_with_a_fixed_weight_and_first_k_training(frames):
    cfg = PipelineConfig(fusion=FusionConfig(weight=2.0))
    res = run_sequence(frames, k=1, config=cfg, train="first:3")
    assert res.fusion_frames == 3 and res.weight.weight == 2.0 and res.weight.pairs == 0
    assert [p.moving for p in res.pairs] == list(range(3, 10))


def test_short_sequences_give_notes_not_errors(frames):
    one = run_sequence(frames[:1], k=1)
    assert not one.pairs and "no pairs" in one.notes[0]
    long = run_sequence(frames[:4], k=4)
    assert not long.pairs and "not shorter" in long.notes[0]
    assert np.isnan(long.means["plain"])


@pytest.mark.parametrize("kwargs", [{"k": 0}, {"k": 1, "train": "first:x"}, {"k": 1, "train": "first:10"},
                                    {"k": 1, "train": "everything"}])
def test_run_sequence_rejects_bad_options(frames, kwargs):
    with pytest.raises(InputError):
        run_sequence(frames, **kwargs)


def test_unlabelled_frames_are_rejected(frames):
    bare = [Frame(f.image, None, f.name) for f in frames[:3]]
    with pytest.raises(InputError):
        run_sequence(bare, k=1)


def test_helpers():
    assert pair_indices(5, 2) == [(0, 2), (1, 3), (2, 4)]
    assert pair_indices(2, 3) == []
    assert resolve_fusion_frames(100, fusion_frames=None, train="reference") == 10
    assert resolve_fusion_frames(5, fusion_frames=None, train="reference") == 2
    assert resolve_fusion_frames(100, fusion_frames=None, train="first:7") == 7
    assert resolve_fusion_frames(100, fusion_frames=3, train="first:7") == 3
    with pytest.raises(InputError):
        RegisterConfig.of(backend="nope")
    open3d = PipelineConfig(registration=PIPELINE_REGISTRATION.replace(backend="open3d"))
    assert open3d.backend == "open3d" and open3d.registration.model == "similarity"
    assert PipelineConfig().registration.model == "similarity" and PipelineConfig().registration.search.init == "identity"


def test_a_refused_pair_is_recorded_with_its_reason(frames, clf):
    """With the plausibility test on (the pipeline's default has it off), a noise frame is refused."""
    noise = np.random.default_rng(3).integers(0, 256, frames[2].image.shape, dtype=np.uint8)
    strict = PipelineConfig(registration=PIPELINE_REGISTRATION.replace(min_inlier_ratio=0.15))
    res = process_pair(frames[0], Frame(noise, frames[2].labels, "noise"), clf, weight=3.0, config=strict).result
    assert not res.registered and "refused" in res.reason
    assert res.registration is None and res.errors["augmented"] == res.errors["plain"]


def test_a_sequence_goes_on_past_a_failed_registration(frames):
    seq = list(frames[:6])
    seq[3] = Frame(np.full_like(frames[3].image, 90), frames[3].labels, "flat")
    res = run_sequence(seq, k=1, fusion_frames=2)
    failed = {(f["reference"], f["moving"]) for f in res.failures}
    assert failed == {(2, 3), (3, 4)}
    assert all(f["reason"] for f in res.failures)
    assert [p.moving for p in res.pairs] == [2, 3, 4, 5]
    for p in res.pairs:
        assert np.isfinite(p.errors["plain"])
        if not p.registered:
            assert p.errors["augmented"] == p.errors["plain"]


def test_a_dense_fields_prior_is_weighted_per_pixel_by_its_confidence(frames):
    """The pair's fusion trusts a dense field's prior where the field has evidence (confidence 1: twice
    the weight) and distrusts it where it was interpolated (confidence 0: half), as the stream does."""
    from pcreg.pipeline.pair import _fuse_methods
    from pcreg.pipeline.prior import CONFIDENCE_SPAN
    from pcreg.registration.motion import Motion, field_from_matrix

    ref = mov = frames[0]  # the same image: the reference carried along the field matches it, full trust
    h, w = mov.labels.shape
    field = field_from_matrix(np.eye(3), (h, w))
    d = np.zeros((h, w), np.float32)  # no evidence of its own: the fused log-odds are the weighted prior
    conf = np.zeros((h, w), np.float32)
    conf[:, w // 2:] = 1.0
    kw = dict(pi=0.3, fusion=FusionConfig(), weight=2.0, flow_weight=2.0, temporal=None, flow=np.zeros((h, w, 2)))
    weighted = _fuse_methods(ref, mov, d, Motion(field=field, confidence=conf), **kw).registered
    one = _fuse_methods(ref, mov, d, Motion(matrix=np.eye(3)), **kw).registered  # a matrix: the one weight
    lo, hi = CONFIDENCE_SPAN
    known = np.abs(one) > 1e-3
    left, right = known.copy(), known.copy()
    left[:, w // 2:] = False
    right[:, :w // 2] = False
    np.testing.assert_allclose(weighted[left], lo * one[left], rtol=1e-5)
    np.testing.assert_allclose(weighted[right], hi * one[right], rtol=1e-5)


def test_a_dense_fields_prior_fades_where_the_carried_reference_does_not_match(frames):
    """The pair's trust, as the stream's: where the reference carried along the field differs from the
    moving frame, the prior's weight falls (exp(-r / 40) of the residual r); where it matches, it stays."""
    from pcreg.pipeline.pair import _fuse_methods
    from pcreg.pipeline.trust import residual_trust
    from pcreg.registration.motion import Motion, field_from_matrix

    ref = frames[0]
    h, w = ref.labels.shape
    field = field_from_matrix(np.eye(3), (h, w))
    changed = ref.image.copy()
    changed[:, w // 2:] = 255 - changed[:, w // 2:]  # the right half no longer the reference's
    mov = type(ref)(changed, ref.labels, "changed")
    trust = residual_trust(ref.image, changed, field)
    assert trust[:, : w // 4].mean() > 0.9 and trust[:, 3 * w // 4:].mean() < 0.2
    d = np.zeros((h, w), np.float32)
    kw = dict(pi=0.3, fusion=FusionConfig(), weight=2.0, flow_weight=2.0, temporal=None, flow=np.zeros((h, w, 2)))
    same = _fuse_methods(ref, ref, d, Motion(field=field), **kw).registered
    faded = _fuse_methods(ref, mov, d, Motion(field=field), **kw).registered
    np.testing.assert_allclose(faded, same * trust, rtol=1e-5, atol=1e-6)
