"""pcreg.registration.dense: non-rigid ICP of colour clouds, fields in warp, the dense pipeline."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from pcreg import DenseOptions, register_dense, warp
from pcreg.registration.warp import warp_to_moving
from pcreg.errors import InputError
from pcreg.registration.dense import DenseRegistrationResult, GlobalStep, Membrane, field_from_matrix, match_window
from pcreg.registration.warp import invert_field

from _images import rigid_about_centre, shapes_image


def _textured(h=240, w=320, seed=0):
    """Shapes on a gradient plus fine random texture (texture everywhere, as the dense step wants)."""
    img = shapes_image(h, w, seed).astype(np.float32)
    noise = cv2.GaussianBlur(np.random.default_rng(seed).normal(0, 30, (h, w, 3)).astype(np.float32), (0, 0), 1.5)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def _smooth_field(h, w):
    """A known smooth non-rigid field: shift, zoom and two sinusoidal bends (reference coordinates)."""
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    dx = 3.0 + 0.02 * (xs - w / 2) + 4.0 * np.sin(2 * np.pi * ys / 180.0)
    dy = -2.0 + 0.02 * (ys - h / 2) + 3.0 * np.cos(2 * np.pi * xs / 220.0)
    return np.dstack([xs + dx, ys + dy]).astype(np.float32)


@pytest.fixture(scope="module")
def warped_pair():
    ref = _textured()
    F = _smooth_field(*ref.shape[:2])
    mov = cv2.remap(ref, F[..., 0], F[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return ref, mov, F


def test_recovers_a_known_smooth_field(warped_pair):
    ref, mov, F = warped_pair
    res = register_dense(ref, mov, options=DenseOptions(levels=4))
    assert isinstance(res, DenseRegistrationResult)
    assert res.field.shape == ref.shape[:2] + (2,) and res.field.dtype == np.float32
    assert res.confidence.shape == ref.shape[:2] and 0 <= res.confidence.min() <= res.confidence.max() <= 1
    inner = (slice(16, -16), slice(16, -16))
    err = np.linalg.norm(res.field - F, axis=2)[inner]
    global_err = np.linalg.norm(field_from_matrix(res.matrix, ref.shape[:2]) - F, axis=2)[inner]
    assert np.median(err) < 0.6, np.median(err)
    assert np.median(err) < 0.3 * np.median(global_err)
    assert np.percentile(err, 90) < 1.5
    d = res.to_dict()
    json.dumps(d)
    assert d["model"] == "dense" and len(d["matrix"]) == 3
    assert not res.field.flags.writeable
    assert "DenseRegistrationResult(field=320x240" in repr(res)


def test_no_motion_gives_the_identity_field():
    img = _textured(seed=3)
    res = register_dense(img, img, global_result=np.eye(3), options=DenseOptions(levels=3))
    ident = field_from_matrix(np.eye(3), img.shape[:2])
    assert np.median(np.linalg.norm(res.field - ident, axis=2)) < 0.15


def test_flat_areas_get_lower_confidence_and_the_global_motion():
    img = _textured(seed=5)
    img[:, 160:] = (120, 140, 90)  # right half flat
    T = rigid_about_centre(img.shape, 0.0, 4.0, -3.0)
    mov = cv2.warpAffine(img, T[:2], (320, 240), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_REFLECT)
    res = register_dense(img, mov, global_result=T, options=DenseOptions(levels=3))
    assert res.confidence[20:-20, 20:140].mean() > 2 * res.confidence[20:-20, 200:-20].mean()
    # where there is nothing to match, the field stays with the global transform
    flat = np.linalg.norm(res.field - field_from_matrix(T, img.shape[:2]), axis=2)[20:-20, 220:-20]
    assert np.median(flat) < 0.5


def test_window_search_is_the_exact_nearest_neighbour_in_position_and_colour():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(1)
    ref = rng.random((30, 40, 3)).astype(np.float32)
    mov = rng.random((30, 40, 3)).astype(np.float32)
    n, radius, lam = 300, 3, 4.0
    src = np.column_stack([rng.integers(5, 35, n), rng.integers(5, 25, n)]).astype(np.float64)
    pos = src + rng.uniform(-2, 2, (n, 2))
    cols = rng.random((n, 3)).astype(np.float32)
    fast = match_window(ref, mov, src, pos, cols, radius=radius, lam=lam)
    slow = match_window(ref, mov, src, pos, cols, radius=radius, lam=lam, compiled=False)
    np.testing.assert_allclose(fast, slow, rtol=1e-6, atol=1e-6)
    # without the mutual test (what the evidence needs): the same matches and distances, no flags
    alone = match_window(ref, mov, src, pos, cols, radius=radius, lam=lam, mutual=False)
    np.testing.assert_array_equal(alone[:, :3], fast[:, :3])
    assert not alone[:, 3].any() and fast[:, 3].any()
    ys, xs = np.mgrid[0:30, 0:40]
    feats = np.column_stack([xs.ravel(), ys.ravel(), lam * ref.reshape(-1, 3)])
    tree = cKDTree(feats)
    for i in range(n):
        cx, cy = np.floor(pos[i] + 0.5).astype(int)
        inside = (np.abs(xs.ravel() - cx) <= radius) & (np.abs(ys.ravel() - cy) <= radius)
        q = np.concatenate([pos[i], lam * cols[i]])
        d = np.linalg.norm(feats[inside] - q, axis=1)
        best = feats[inside][np.argmin(d)]
        # the search answers the windowed nearest neighbour (sub-pixel refined by at most half a pixel)
        assert abs(fast[i, 0] - best[0]) <= 0.5 + 1e-9 and abs(fast[i, 1] - best[1]) <= 0.5 + 1e-9
        dd, _ = tree.query(q)
        assert dd <= d.min() + 1e-9  # the global nearest neighbour is never farther than the gated one


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_window_search_skipping_rows_answers_the_full_scan_ties_included(channels):
    """The compiled search skips rows that cannot hold the answer; it must answer what a full scan of
    the window answers (the least cost, the first in row order among equal costs). Colours from a few
    levels and whole-pixel queries make many equal costs, and queries on their own pixel make cheap
    matches, so that rows are skipped often; windows run off the image's edges too."""
    from pcreg.registration.dense.window import _best_in_window

    rng = np.random.default_rng(7)
    h, w = 24, 32
    img = (rng.integers(0, 3, (h, w, channels)) / 2.0).astype(np.float32)
    skipped = 0
    for i in range(3000):
        radius = int(rng.integers(1, 5))
        lam2 = float(rng.choice([0.25, 1.0, 16.0]))
        sy, sx = int(rng.integers(0, h)), int(rng.integers(0, w))
        if i % 3 == 0:  # whole pixels: equal distances on either side
            x, y = float(sx + rng.integers(-2, 3)), float(sy + rng.integers(-2, 3))
        else:
            x, y = sx + rng.uniform(-radius - 1, radius + 1), sy + rng.uniform(-radius - 1, radius + 1)
        bx, by, cx, cy = _best_in_window(img, x, y, img, sy, sx, radius, lam2)
        x0, x1, y0, y1 = max(cx - radius, 0), min(cx + radius, w - 1), max(cy - radius, 0), min(cy + radius, h - 1)
        if x0 > x1 or y0 > y1:
            assert (bx, by) == (-1, -1)
            continue
        qy, qx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        d = img[y0:y1 + 1, x0:x1 + 1] - img[sy, sx]  # float32, squared in float32, summed in float64
        s = np.zeros(qx.shape)
        for k in range(channels):
            s += (d[..., k] * d[..., k]).astype(np.float64)
        cost = (qx - x) * (qx - x) + (qy - y) * (qy - y) + lam2 * s
        first = np.argmin(cost)  # the first least cost in row order
        assert (bx, by) == (qx.ravel()[first], qy.ravel()[first]), (x, y, sx, sy, radius, lam2)
        skipped += int(((qy[:, 0] - y) ** 2 > cost.min()).sum())
    assert skipped > 1000  # rows that a skip could leave out were common


def test_nan_median_is_numpys():
    """The evidence's compiled median gives np.nanmedian's number: odd and even counts, ties, NaNs, none left."""
    from pcreg.registration.dense.robust import _nan_median

    rng = np.random.default_rng(3)
    for n in [1, 2, 3, 4, 5, 1000, 1001]:
        for _ in range(20):
            a = np.round(rng.random(n), 2)  # ties
            a[rng.random(n) < 0.3] = np.nan
            want = np.nanmedian(a) if np.isfinite(a).any() else np.nan
            got = _nan_median(np.ascontiguousarray(a))
            assert got == want or (np.isnan(got) and np.isnan(want))
    strided = rng.random((9, 4))
    assert _nan_median(strided[:, 2]) == np.median(strided[:, 2])
    assert np.isnan(_nan_median(np.full(3, np.nan)))


def test_robust_scale_is_numpys():
    """Tukey's scale from the mutual matches' distances with np.median's numbers: odd and even counts,
    ties, unmatched and one-sided rows left out, too few mutual matches giving 0."""
    from pcreg.registration.dense.robust import TUKEY_C, _robust_scale

    rng = np.random.default_rng(5)
    for n in [3, 8, 9, 10, 11, 1000, 1001]:
        for _ in range(20):
            m = np.column_stack([rng.random(n), rng.random(n), np.round(rng.random(n), 2),
                                 (rng.random(n) < 0.8).astype(float)])
            m[rng.random(n) < 0.1, 0] = np.nan
            g = m[(m[:, 3] > 0) & np.isfinite(m[:, 0]), 2]
            sigma = float(rng.random()) * 0.05
            want = 0.0
            if g.size >= 8:
                med = np.median(g)
                mad = np.median(np.abs(g - med)) * 1.4826
                want = max(med + TUKEY_C * max(mad, 1e-6), 2.0 * np.sqrt(6.0) * sigma)
            assert _robust_scale(m, sigma) == want


def test_bad_inputs_are_refused():
    img = _textured()
    with pytest.raises(InputError):
        register_dense(img, img[:200])
    with pytest.raises(InputError):
        GlobalStep(model="warp")
    with pytest.raises(InputError):
        register_dense(img, img, global_result=np.zeros((3, 3)))
    with pytest.raises(InputError):
        DenseOptions(radius=0)
    with pytest.raises(InputError, match="grid_spacing"):  # beyond the images' longer side
        register_dense(img, img, options=DenseOptions(membrane=Membrane(grid_spacing=400.0)))
    with pytest.raises(InputError, match="options"):
        register_dense(img, img, options={"levels": 4})


# ---------------------------------------------------------------------------------------------------
# warping with a field
# ---------------------------------------------------------------------------------------------------

def test_warp_with_a_field_matches_the_matrix():
    img = shapes_image()
    T = rigid_about_centre(img.shape, 8.0, 6.0, -4.0)
    fld = field_from_matrix(T, img.shape[:2])
    by_matrix, valid_m = warp(img, T)
    by_field, valid_f = warp(img, fld)
    both = valid_m & valid_f
    assert np.median(np.abs(by_matrix.astype(int) - by_field.astype(int))[both]) <= 1
    assert (valid_m ^ valid_f).mean() < 0.01
    to_mov_m, vm = warp_to_moving(img, T, shape=img.shape[:2])
    to_mov_f, vf = warp_to_moving(img, fld, shape=img.shape[:2])
    assert np.abs(to_mov_m.astype(int) - to_mov_f.astype(int))[vm & vf].max() <= 2
    assert (vm ^ vf).mean() < 0.01
    # labels with nearest neighbour keep their values; fill outside
    labels = (img[:, :, 0] > 128).astype(np.uint8)
    lab, v = warp_to_moving(labels, fld, interpolation="nearest", fill=2)
    assert set(np.unique(lab)) <= {0, 1, 2} and np.all(lab[~v] == 2)


def test_field_inverse_round_trips():
    F = _smooth_field(120, 160)
    inv, ok = invert_field(F, (120, 160))
    back = cv2.remap(F, inv[..., 0], inv[..., 1], cv2.INTER_LINEAR)
    X, Y = np.meshgrid(np.arange(160, dtype=np.float32), np.arange(120, dtype=np.float32))
    err = np.hypot(back[..., 0] - X, back[..., 1] - Y)
    assert ok.mean() > 0.8 and err[ok].max() < 0.05


def test_warp_refuses_a_field_of_the_wrong_size():
    img = shapes_image()
    with pytest.raises(InputError):
        warp(img, np.zeros((10, 10, 2), np.float32))
    with pytest.raises(InputError):
        warp_to_moving(img, np.full((240, 320, 2), np.nan, np.float32), shape=(240, 320))


# ---------------------------------------------------------------------------------------------------
# the pipeline
# ---------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def frames():
    from pcreg.datasets import synthetic

    return synthetic("syn2a", 10, 0, width=160, height=120)


def test_dense_pipeline_on_a_short_sequence(frames):
    from pcreg.pipeline import METHODS, PIPELINE_REGISTRATION, PipelineConfig, run_sequence

    cfg = PipelineConfig(registration=PIPELINE_REGISTRATION.replace(model="dense"))
    res = run_sequence(frames, k=2, config=cfg, fusion_frames=3)
    assert res.pairs and all(p.registered for p in res.pairs)
    assert set(res.means) == set(METHODS) and "augmented_flow" in METHODS
    assert all(np.isfinite(res.means[m]) for m in ("augmented", "augmented_flow", "augmented_temporal"))
    assert res.means["augmented"] < res.means["plain"]
    assert res.flow_weight is not None and res.flow_weight.pairs > 0
    reg = res.pairs[0].registration
    assert reg["model"] == "dense" and 0 < reg["mean_confidence"] <= 1


def test_process_pair_keeps_the_field_for_recordings(frames):
    from pcreg.classification.bayes import fit_classifier
    from pcreg.pipeline import PIPELINE_REGISTRATION, PipelineConfig, process_pair

    clf = fit_classifier([frames[0]])
    cfg = PipelineConfig(registration=PIPELINE_REGISTRATION.replace(model="dense"))
    done = process_pair(frames[0], frames[2], clf, weight=2.0, config=cfg, keep_arrays=True)
    arrays = done.arrays
    assert arrays.motion.field.shape == frames[0].shape + (2,)
    assert arrays.motion.confidence.shape == frames[0].shape
    assert arrays.warped_prior.shape == frames[0].shape and arrays.flow.shape == frames[0].shape + (2,)
    assert np.isfinite(done.result.errors["augmented_flow"])


def test_temporal_chain_never_worse_than_plain_through_failed_and_poor_registrations(frames, monkeypatch):
    """A failed and a badly wrong registration mid-chain, with a weight chosen too large (the causes
    of the divergence): the chain falls back to plain where the registration failed, lets the
    classifier overrule the labels a wrong registration carried, and never does worse than plain."""
    import pcreg.pipeline as pl
    from pcreg.classification.fusion import FusionConfig
    from pcreg.registration.result import RegistrationResult

    real = pl.register_pair

    def flaky(reference_image, moving_image, *, config, callback=None):
        if np.array_equal(moving_image, frames[8].image):
            return pl.PairRegistration(None, "forced failure", 0.0)
        if np.array_equal(moving_image, frames[4].image):  # 30 px off and turned: a poor registration
            wrong = rigid_about_centre(frames[4].shape, 12.0, 30.0, 10.0)
            return pl.PairRegistration(RegistrationResult(matrix=wrong, fitness=0.5, inlier_rmse=3.0, iterations=1,
                                                          converged=True, backend="reference"), None, 0.0)
        return real(reference_image, moving_image, config=config, callback=callback)

    import pcreg.pipeline.sequence

    monkeypatch.setattr(pcreg.pipeline.sequence, "register_pair", flaky)
    cfg = pl.PipelineConfig(fusion=FusionConfig(weight=12.0))
    res = pl.run_sequence(frames, k=1, config=cfg, fusion_frames=2)
    assert any(not p.registered for p in res.pairs)
    for p in res.pairs:
        if not p.registered:
            assert p.errors["augmented_temporal"] == pytest.approx(p.errors["plain"])
    after = [p for p in res.pairs if 4 <= p.moving < 8]
    assert np.mean([p.errors["augmented_temporal"] for p in after]) <= np.mean([p.errors["plain"] for p in after])
    assert res.means["augmented_temporal"] <= res.means["plain"]


def test_a_change_of_brightness_and_colour_is_not_read_as_motion(warped_pair):
    ref, mov, F = warped_pair
    # the camera's exposure and white balance change between the frames
    lit = np.clip(mov.astype(np.float32) * np.array([1.2, 1.1, 0.9], np.float32) + 12.0, 0, 255).astype(np.uint8)
    res = register_dense(ref, lit, options=DenseOptions(levels=4))
    inner = (slice(16, -16), slice(16, -16))
    err = np.linalg.norm(res.field - F, axis=2)[inner]
    assert np.median(err) < 0.8, np.median(err)
    plain = register_dense(ref, lit, options=DenseOptions(levels=4, texture=None))
    assert np.median(err) < np.median(np.linalg.norm(plain.field - F, axis=2)[inner])


def test_compiled_normal_equations_match_scipy():
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from pcreg.registration.dense.grid import _NormalEquations

    rng = np.random.default_rng(0)
    ne = _NormalEquations(rng.uniform(0, [160, 120], (3000, 2)), (16, 21), 8.0)
    w = rng.random(3000)
    w[::5] = 0.0
    t = rng.normal(size=(3000, 2))
    x0 = rng.normal(size=(ne.m, 2))
    U_cg, node_w = ne.solve(w, t, 0.25, 1e-5, x0, maxiter=40)
    U_lu, _ = ne.solve(w, t, 0.25, 1e-5)
    # the same system assembled with scipy.sparse from the bilinear matrix
    from pcreg.registration.dense.grid import _bilinear_matrix, _membrane

    B = sp.csr_matrix((ne.vals.ravel(), ne.cols.ravel(), np.arange(0, 4 * 3000 + 1, 4)), shape=(3000, ne.m))
    A = (B.T @ sp.diags(w) @ B + 0.25 * _membrane((16, 21)) + 1e-5 * sp.identity(ne.m)).tocsc()
    np.testing.assert_allclose(U_lu, spla.spsolve(A, B.T @ (w[:, None] * t)), atol=1e-8)
    np.testing.assert_allclose(node_w, B.T @ w, atol=1e-10)
    x_ref, _ = spla.cg(A, (B.T @ (w[:, None] * t))[:, 0], x0=x0[:, 0].copy(), rtol=1e-4, maxiter=40,
                       M=sp.diags(1.0 / A.diagonal()))
    np.testing.assert_allclose(U_cg[:, 0], x_ref, atol=1e-9)
    assert _bilinear_matrix(np.array([[3.0, 4.0]]), (16, 21), 8.0).sum() == pytest.approx(1.0)


def test_evidence_against_chance_and_the_optional_refusal(warped_pair):
    from pcreg.errors import RegistrationError

    ref, mov, F = warped_pair
    res = register_dense(ref, mov, options=DenseOptions(levels=4))
    assert res.info["evidence"] > 1.5 and res.to_dict()["evidence"] == pytest.approx(res.info["evidence"])
    noise = np.random.default_rng(3).integers(0, 256, ref.shape).astype(np.uint8)
    unrelated = register_dense(ref, noise, global_result=np.eye(3), options=DenseOptions(levels=4))
    assert unrelated.info["evidence"] < 1.3
    with pytest.raises(RegistrationError):
        register_dense(ref, noise, global_result=np.eye(3), options=DenseOptions(levels=4, chance_factor=1.5))


def test_dense_is_a_model_of_register_and_of_the_command(frames, tmp_path, capsys):
    """``register(model="dense")`` is the global similarity refined by a field, as in the pipeline."""
    import pcreg
    import cv2

    from pcreg.cli import main

    res = pcreg.register(frames[0].image, frames[2].image, model="dense", init="identity")
    assert res.field.shape == frames[2].shape + (2,) and res.global_result.matrix.shape == (3, 3)
    for i in (0, 2):
        cv2.imwrite(str(tmp_path / f"{i}.png"), frames[i].image[:, :, ::-1])
    assert main(["register", str(tmp_path / "0.png"), str(tmp_path / "2.png"), "--model", "dense", "--init",
                 "identity", "--out", str(tmp_path / "w.png")]) == 0
    assert "DenseRegistrationResult" in capsys.readouterr().out
    assert cv2.imread(str(tmp_path / "w.png")).shape == frames[0].image.shape


def test_compiled_robust_step_matches_the_array_formulation():
    import math

    from pcreg.registration.dense.grid import _NormalEquations
    from pcreg.registration.dense.robust import TUKEY_C

    rng = np.random.default_rng(1)
    n, sigma = 3000, 0.004
    ne = _NormalEquations(rng.uniform(0, [160, 120], (n, 2)), (16, 21), 8.0)
    start = rng.uniform(0, [160, 120], (n, 2))
    X = start + rng.normal(0, 0.5, (n, 2))
    m = np.column_stack([X + rng.normal(0, 0.3, (n, 2)), rng.exponential(0.05, n), (rng.random(n) < 0.8) * 1.0])
    m[::7, :2] = np.nan  # no pixel in the gate
    m[::7, 2] = np.inf
    m[::7, 3] = 0.0
    # Tukey weights of the mutual matches, their targets and residuals, as arrays
    found = np.isfinite(m[:, 0])
    good = found & (m[:, 3] > 0)
    med = np.median(m[good, 2])
    scale = max(med + TUKEY_C * max(1.4826 * np.median(np.abs(m[good, 2] - med)), 1e-6), 2 * math.sqrt(6) * sigma)
    u = m[good, 2] / scale
    w = np.zeros(n)
    w[good] = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
    Q = np.where(found[:, None], m[:, :2], X)
    x0 = rng.normal(size=(ne.m, 2))
    U, node_w = ne.solve(w, Q - start, 0.25, 1e-5, x0, maxiter=30)
    U2, node_w2, sw, swr, inliers = ne.robust_step(m, X, start, sigma, 0.25, 1e-5, x0, maxiter=30)
    np.testing.assert_array_equal(U2, U)
    np.testing.assert_array_equal(node_w2, node_w)
    assert inliers == (w > 0).sum() and sw == w.sum() and swr == (w * ((Q - X) ** 2).sum(axis=1)).sum()
    few = m.copy()
    few[8:, 3] = 0.0  # at most 6 mutual matches left (rows 1-6): too few for a scale, no step
    assert ne.robust_step(few, X, start, sigma, 0.25, 1e-5, x0, maxiter=30) is None


@pytest.mark.parametrize("level", [0, 1, 2])
def test_the_full_size_field_interpolates_the_grid_at_each_pixels_place(level):
    """The field at full resolution is the global transform plus the grid's displacements interpolated
    bilinearly where each pixel lies on the grid of its level (pixel x at ``(x - (2^l - 1) / 2) / (2^l s)``
    cells, edge nodes repeated beyond the grid), and its confidence is 0 where it leaves the image."""
    from pcreg.registration.dense.field import _full_field
    from pcreg.registration.dense.grid import _grid_shape
    from pcreg.registration.dense.levels import _Level

    h, w, s = 97, 131, 2.0  # a fine grid: a cell is a few pixels, so a quarter-pixel slip shows
    f = 2 ** level
    gshape = _grid_shape(-(-h // f), -(-w // f), s)
    rng = np.random.default_rng(level)
    U = rng.normal(0, 4, (gshape[0] * gshape[1], 2))
    weights = rng.uniform(0, 40, gshape[0] * gshape[1])
    T = np.array([[1.01, 0.02, 3.5], [-0.02, 1.01, -60.0], [0, 0, 1]])  # leaves the image at the top
    lv = _Level(level, s, gshape, 0.5, None)
    out = _full_field(T, U, weights, lv, (h, w))

    def bilinear(nodes, gx, gy):
        gx = np.clip(gx, 0, gshape[1] - 1)
        gy = np.clip(gy, 0, gshape[0] - 1)
        x0 = np.minimum(np.floor(gx).astype(int), gshape[1] - 2)
        y0 = np.minimum(np.floor(gy).astype(int), gshape[0] - 2)
        ax, ay = gx - x0, gy - y0
        if nodes.ndim == 3:
            ax, ay = ax[..., None], ay[..., None]
        return ((1 - ay) * ((1 - ax) * nodes[y0, x0] + ax * nodes[y0, x0 + 1])
                + ay * ((1 - ax) * nodes[y0 + 1, x0] + ax * nodes[y0 + 1, x0 + 1]))

    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    gx, gy = (xs - (f - 1) / 2) / (f * s), (ys - (f - 1) / 2) / (f * s)
    grid = (f * U).reshape(gshape[0], gshape[1], 2)
    expected = field_from_matrix(T, (h, w)) + bilinear(grid, gx, gy)
    # bilinear weights in float64, the sum rounded once to float32 and added to the float32 global part:
    # a few float32 roundings of coordinates up to a few hundred pixels
    assert np.abs(out.field - expected).max() <= 1e-4
    conf = bilinear(np.clip(weights / (0.25 * s * s * 0.5), 0, 1).reshape(gshape), gx, gy)
    inside = ((out.field[..., 0] >= -0.5) & (out.field[..., 0] <= w - 0.5)
              & (out.field[..., 1] >= -0.5) & (out.field[..., 1] <= h - 0.5))
    assert 0 < inside.mean() < 1
    assert np.all(out.confidence[~inside] == 0)
    assert np.abs(out.confidence[inside] - conf[inside]).max() <= 1e-6
    assert out.field.dtype == np.float32 and out.confidence.dtype == np.float32


def test_a_registration_started_from_an_earlier_grid_follows_a_motion_beyond_the_cold_gate():
    """At one level (1), a 60 px shift is beyond what the cold start's eight steps can reach (a 3 px gate
    of the level, 6 px, each); from the grid of a registration that put the frame 54 px away, the 6 px
    left are within the gate."""
    ref = _textured(seed=3)
    h, w = ref.shape[:2]
    shift = lambda dx: cv2.warpAffine(ref, np.float32([[1, 0, dx], [0, 1, 0]]), (w, h),  # noqa: E731
                                      flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    options = DenseOptions(levels=2, texture=None, max_points=5000)
    earlier = register_dense(ref, shift(54.0), global_result=np.eye(3) + np.array([[0, 0, 54.0], [0, 0, 0], [0, 0, 0]]),
                             options=options)
    assert earlier.grid.shape == (16, 21, 2) and earlier.grid.dtype == np.float32 and not earlier.grid.flags.writeable
    grid = earlier.grid + np.float32([54.0, 0.0])  # its displacements from the identity
    inner = (slice(24, -24), slice(80, -80))
    cold = register_dense(ref, shift(60.0), global_result=np.eye(3), options=options)
    warm = register_dense(ref, shift(60.0), global_result=np.eye(3), initial=grid,
                          options=replace(options, initial_level=1))
    err = lambda r: np.median(np.abs(r.field[..., 0] - (np.arange(w) + 60.0))[inner])  # noqa: E731
    assert err(cold) > 10 and err(warm) < 0.5, (err(cold), err(warm))
    assert warm.info["levels"] == cold.info["levels"] == (1, 1)
    assert warm.info["evidence"] > 2 * cold.info["evidence"]


def test_an_initial_grid_at_the_finest_level_is_the_grid_itself_and_coarser_levels_interpolate_it():
    from pcreg.registration.dense.coarse_to_fine import _grid_at_level
    from pcreg.registration.dense.levels import _Level

    rng = np.random.default_rng(0)
    grid = rng.normal(0, 3, (31, 41, 2)).astype(np.float32)  # full-size px
    finest = _Level(level=1, spacing=8.0, gshape=(31, 41), rate=1.0, problem=None)
    np.testing.assert_allclose(_grid_at_level(grid, 1, finest), grid.reshape(-1, 2) / 2, atol=1e-5)  # level-1 px
    # an affine field is interpolated exactly: node (i, j) of level 2 sits at full-size x = 32 j + 1.5,
    # which is x = 16 j + 0.5 on level 1, 2 j + 1/16 of its nodes
    gy, gx = np.mgrid[0:31, 0:41].astype(np.float64)
    affine = np.dstack([0.5 * gx + 2.0, -0.25 * gy + 1.0]).astype(np.float32)
    coarse = _Level(level=2, spacing=8.0, gshape=(16, 21), rate=1.0, problem=None)
    got = _grid_at_level(affine, 1, coarse).reshape(16, 21, 2)
    cy, cx = np.mgrid[0:16, 0:21].astype(np.float64)
    ux, uy = np.minimum(2 * cx + 1 / 16, 40), np.minimum(2 * cy + 1 / 16, 30)  # the edge nodes held beyond
    np.testing.assert_allclose(got[..., 0], (0.5 * ux + 2.0) / 4, atol=1e-5)  # in level-2 px
    np.testing.assert_allclose(got[..., 1], (-0.25 * uy + 1.0) / 4, atol=1e-5)


def test_bad_initial_grids_are_refused(warped_pair):
    ref, mov, _ = warped_pair
    options = DenseOptions(levels=4)
    kw = dict(global_result=np.eye(3), options=options)
    good = register_dense(ref, mov, **kw)
    for bad, match in ((good.grid[:-1], "nodes"), (np.full_like(good.grid, np.nan), "non-finite"),
                       ("grid", "numeric"), (np.zeros((3, 3)), "nodes"), (good.grid > 0, "numeric"),
                       (good.grid.astype(complex), "numeric"), (np.full(good.grid.shape, 1e300), "non-finite"),
                       (np.full(good.grid.shape, "a"), "numeric"), (object(), "numeric")):
        with pytest.raises(InputError, match=match):
            register_dense(ref, mov, initial=bad, **kw)
    with pytest.raises(InputError, match="initial_level"):  # under finest_level: with an initial grid
        register_dense(ref, mov, initial=good, global_result=np.eye(3), options=replace(options, initial_level=0))
    for level in (8, 2.5, "2", "x"):  # refused when the options are made
        with pytest.raises(InputError, match="initial_level"):
            replace(options, initial_level=level)
    with pytest.raises(InputError, match="nodes"):  # another grid spacing
        register_dense(ref, mov, initial=good, global_result=np.eye(3), options=replace(options, membrane=Membrane(grid_spacing=12.0)))
    same = register_dense(ref, mov, initial=good, **kw)  # from its own end (level 2): no worse
    assert same.info["evidence"] >= 0.9 * good.info["evidence"]


def test_dense_options_are_one_checked_frozen_value():
    from pcreg.registration.dense import STIFFNESS_SCHEDULE

    o = DenseOptions(levels=np.int64(4), texture=2, membrane=Membrane(stiffness=[4, 2.0]),
                     global_step=GlobalStep(init=np.eye(3) * 2))
    assert type(o.levels) is int and o.membrane.stiffness == (4.0, 2.0) and type(o.texture) is float
    assert o.global_step.init == ((2.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 2.0))
    assert o.global_step.start.dtype == np.float64
    assert hash(o) == hash(DenseOptions(levels=4, texture=2.0, membrane=Membrane(stiffness=(4.0, 2.0)),
                                        global_step=GlobalStep(init=2 * np.eye(3))))
    assert DenseOptions().membrane.stiffness == STIFFNESS_SCHEDULE and DenseOptions().global_step.start == "identity"
    with pytest.raises(AttributeError):
        o.levels = 3  # type: ignore[misc]
    for part, bad, match in ((DenseOptions, {"levels": 0}, "levels"),
                             (DenseOptions, {"levels": 3, "finest_level": 3}, "finest_level"),
                             (DenseOptions, {"texture": 0}, "texture"), (DenseOptions, {"seed": -1}, "seed"),
                             (DenseOptions, {"chance_factor": float("nan")}, "chance_factor"),
                             (DenseOptions, {"membrane": {"strain": 1.0}}, "membrane"),
                             (DenseOptions, {"global_step": "identity"}, "global_step"),
                             (Membrane, {"grid_spacing": 1.0}, "grid_spacing"), (Membrane, {"stiffness": ()}, "stiffness"),
                             (Membrane, {"edge_aware": 1}, "edge_aware"), (Membrane, {"strain": 0}, "strain"),
                             (Membrane, {"cg_iterations": -1}, "cg_iterations"),
                             (GlobalStep, {"init": "nowhere"}, "init"), (GlobalStep, {"init": np.zeros((3, 3))}, "init"),
                             (GlobalStep, {"backend": "gpu"}, "backend"), (GlobalStep, {"model": "warp"}, "model"),
                             (GlobalStep, {"levels": 9}, "global_step.levels"),
                             (GlobalStep, {"iterations": 0}, "global_step.iterations")):
        with pytest.raises(InputError, match=match):
            part(**bad)
        with pytest.raises(InputError, match=match):  # a copy with a change is checked as well
            replace(part(), **bad)


def test_a_prepared_reference_gives_the_same_registration_and_is_refused_for_another_image(warped_pair):
    from pcreg.registration.dense import prepare_reference

    ref, mov, _ = warped_pair
    options = DenseOptions(levels=4, texture=None)
    prepared = prepare_reference(ref, options=options)
    assert len(prepared.levels) == len(prepared.valid) == 4 and "320x240" in repr(prepared)
    assert not prepared.image.flags.writeable and not any(a.flags.writeable for a in prepared.levels)
    assert prepared.image is not ref and ref.flags.writeable  # a copy: the caller's image is left as it was
    plain = register_dense(ref, mov, options=options, global_result=np.eye(3))
    for _ in range(2):  # reused: the same numbers each time, and as without it
        again = register_dense(ref, mov, options=options, global_result=np.eye(3), prepared=prepared)
        np.testing.assert_array_equal(again.field, plain.field)
        np.testing.assert_array_equal(again.confidence, plain.confidence)
    other = ref.copy()
    other[0, 0, 0] ^= 1
    with pytest.raises(InputError, match="another image"):
        register_dense(other, mov, options=options, prepared=prepared)
    with pytest.raises(InputError, match="levels"):  # prepared for three levels, given to four
        register_dense(ref, mov, options=options, prepared=prepare_reference(ref, options=replace(options, levels=3)))
    with pytest.raises(InputError, match="DenseReference"):
        register_dense(ref, mov, options=options, prepared=prepared.levels)


def test_a_prepared_reference_holds_the_grid_weights_its_registrations_use(warped_pair, monkeypatch):
    """The control grids' bilinear weights depend on the shapes alone: the prepared reference makes them
    once (read-only, the numbers made without it), and its registrations make none of their own."""
    from pcreg.registration.dense import grid, prepare_reference

    ref, mov, _ = warped_pair
    options = DenseOptions(levels=4, texture=None)
    prepared = prepare_reference(ref, options=options)
    assert prepared.grid_weights
    for key, made in prepared.grid_weights.items():
        fresh = (grid._upsample_weights if key[0] == "upsample" else grid._level_weights)(*key[1:])
        for a, b in zip(made, fresh):
            assert not a.flags.writeable
            np.testing.assert_array_equal(a, b)
    plain = register_dense(ref, mov, options=options, global_result=np.eye(3))

    def made_again(*args):
        raise AssertionError("grid weights made again")

    monkeypatch.setattr(grid, "_upsample_weights", made_again)
    again = register_dense(ref, mov, options=options, global_result=np.eye(3), prepared=prepared)
    np.testing.assert_array_equal(again.field, plain.field)
