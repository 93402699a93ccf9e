"""pcreg.recording.recorder: recordings are read back with rerun.chunk.RrdReader (through pcreg.recording.readback) and checked by value."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.errors import InputError, OutputError
from pcreg.recording.recorder import Recorder
from pcreg.registration.result import IcpIteration
from pcreg.recording import entities as E
from pcreg.recording.readback import image, points, read_recording, scalar, segmentation, tensor, text

RERUN = Path(sys.executable).parent / "rerun"
H, W = 48, 64


def _image(seed: int) -> np.ndarray:
    """A smooth RGB test image (JPEG-friendly) with a feature that moves with ``seed``."""
    y, x = np.mgrid[0:H, 0:W]
    img = np.stack([x * 4, y * 5, np.full_like(x, 40 * (seed % 5))], axis=-1).astype(np.uint8)
    cv2.circle(img, (10 + 3 * seed, 20), 6, (255, 255, 255), -1)
    return img


def _matrix(rng: np.random.Generator) -> np.ndarray:
    a = rng.uniform(-np.pi, np.pi)
    m = np.array([[np.cos(a), -np.sin(a), rng.normal() * 7.123456789],
                  [np.sin(a), np.cos(a), rng.normal() * 3.3e-7],
                  [0.0, 0.0, 1.0]])
    m[0, 1] += 1e-13  # digits beyond float32 must survive
    return m


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A 3-frame recording of every kind of log call, and what was logged."""
    rng = np.random.default_rng(0)
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    logged = {"matrices": [], "errors": [], "truth": [], "predicted": [], "images": []}
    with Recorder(path, recording_name="test run", recording_id="test-recording-1", label_stride=1) as rec:
        rec.log_config({"backend": "reference", "max_iteration": 14})
        for f in range(3):
            rec.set_frame(f)
            ref, mov = _image(f), _image(f + 1)
            logged["images"].append(ref)
            rec.log_images(reference=ref, moving=mov, warped=mov, valid_mask=np.ones((H, W), bool))
            pts = rng.uniform(0, [W, H], size=(2000, 2))
            cols = rng.random((2000, 3)).astype(np.float32)
            rec.log_clouds(reference_points=pts, reference_colors=cols, moving_points=pts, moving_colors=cols)
            m = _matrix(rng)
            logged["matrices"].append(m)
            rec.log_transform(m)
            truth = rng.integers(0, 3, (H, W)).astype(np.uint8)
            predicted = rng.integers(0, 2, (H, W)).astype(np.int64)
            logged["truth"].append(truth)
            logged["predicted"].append(predicted)
            rec.log_labels(truth=truth, predicted=predicted)
            rec.log_labels(predicted=1 - predicted, prefix="fused")
            errs = {"plain": float(rng.random()), "registered": float(rng.random())}
            logged["errors"].append(errs)
            rec.log_errors(errs)
            for backend in ("reference", "open3d"):
                cb = rec.icp_callback(backend)
                for k in range(4):
                    ti = np.where(rng.random(2000) < 0.8, rng.integers(0, 2000, 2000), -1)
                    cb(IcpIteration(backend, k // 2, k, m, 0.5 + 0.1 * k, 2.0 / (k + 1), pts + k, pts, ti))
        rec.log_crosscheck({"rotation_deg": 0.0125, "translation_px": {"max": 0.25}, "agree": True,
                            "reference": {"fitness": 0.9}, "open3d": {"fitness": 0.875}})
        rec.log_text("finished", level="warning")
    return path, logged, read_recording(path)


def test_ids_name_and_embedded_blueprint(recorded):
    _, _, rec = recorded
    assert rec.application_id == "pcreg"
    assert rec.recording_id == "test-recording-1"
    assert rec.blueprints == 1
    names = [r["RecordingInfo:name"].to_pylist()[0] for r in rec.get("__properties", "RecordingInfo:name")]
    assert names == ["test run"]


def test_fresh_recording_id_when_not_given(tmp_path):
    ids = set()
    for i in range(2):
        with Recorder(tmp_path / f"{i}.rrd") as rec:
            rec.log_text("x")
        ids.add(read_recording(tmp_path / f"{i}.rrd").recording_id)
    assert len(ids) == 2 and all(len(i) >= 32 for i in ids)


def test_transform_reads_back_exactly(recorded):
    _, logged, rec = recorded
    for f, m in enumerate(logged["matrices"]):
        back = tensor(rec.latest(E.transform_path("T_ref_mov"), frame=f))
        assert back.dtype == np.float64 and back.shape == (3, 3)
        assert np.array_equal(back, m)


def test_outline_is_the_moving_border_mapped(recorded):
    _, logged, rec = recorded
    m = logged["matrices"][1]
    strip = np.asarray(rec.latest(E.outline_path("T_ref_mov"), frame=1)["LineStrips2D:strips"].to_pylist()[0])
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5], [-0.5, -0.5]])
    expected = corners @ m[:2, :2].T + m[:2, 2]
    np.testing.assert_allclose(strip, expected, atol=1e-3)


def test_error_series_equal_the_logged_values(recorded):
    _, logged, rec = recorded
    for method in ("plain", "registered"):
        series = rec.series(E.error_path(method))
        assert series == {f: e[method] for f, e in enumerate(logged["errors"])}


def test_segmentation_classes_and_annotation_context(recorded):
    _, logged, rec = recorded
    for f in range(3):
        assert np.array_equal(segmentation(rec.latest(E.labels_path("truth"), frame=f)), logged["truth"][f])
        assert np.array_equal(segmentation(rec.latest(E.labels_path("predicted"), frame=f)), logged["predicted"][f])
        fused = segmentation(rec.latest(E.labels_path("predicted", "fused"), frame=f))
        assert np.array_equal(fused, 1 - logged["predicted"][f])
    ctx = rec.latest("/", component="AnnotationContext:context")
    assert ctx.static
    infos = {c["class_id"]: c["class_description"]["info"] for c in ctx["AnnotationContext:context"].to_pylist()[0]}
    assert {k: v["label"] for k, v in infos.items()} == {0: "ground", 1: "obstacle", 2: "unknown"}
    assert all(v["color"] is not None for v in infos.values())


def test_label_stride_subsamples_for_display(tmp_path):
    labels = np.arange(H * W).reshape(H, W) % 3
    with Recorder(tmp_path / "s.rrd") as rec:  # default stride 2 with JPEG images
        rec.set_frame(0)
        rec.log_labels(predicted=labels)
    back = segmentation(read_recording(tmp_path / "s.rrd").latest(E.PREDICTED, frame=0))
    assert np.array_equal(back, labels[::2, ::2])


def test_images_jpeg_by_default_and_raw_on_request(recorded, tmp_path):
    _, logged, rec = recorded
    row = rec.reference(frame=2)
    assert row["EncodedImage:media_type"].to_pylist() == ["image/jpeg"]
    back = image(row)
    assert back.shape == (H, W, 3)
    assert np.abs(back.astype(int) - logged["images"][2]).mean() < 4.0
    assert np.array_equal(image(rec.latest(E.VALID_MASK, frame=0)), np.full((H, W), 255, np.uint8))
    assert image(rec.latest(E.WARPED_IMAGE, frame=0)).shape == (H, W, 3)

    img = _image(3)
    with Recorder(tmp_path / "raw.rrd", raw_images=True) as raw:
        raw.set_frame(0)
        raw.log_images(reference=img, valid_mask=np.eye(H, W, dtype=bool))
    back = read_recording(tmp_path / "raw.rrd")
    assert np.array_equal(image(back.latest(E.REFERENCE_IMAGE, frame=0)), img)
    assert np.array_equal(image(back.latest(E.VALID_MASK, frame=0)), np.eye(H, W, dtype=np.uint8) * 255)


def test_clouds_subsampled_coloured_and_mapped(recorded):
    _, logged, rec = recorded
    ref = rec.latest(E.REFERENCE_CLOUD, frame=0)
    assert len(points(ref)) == 500
    assert len(ref["Points2D:colors"]) == 500
    moving = points(rec.latest(E.MOVING_CLOUD, frame=1)).astype(np.float64)
    moved = points(rec.latest(E.MOVED_CLOUD, frame=1)).astype(np.float64)
    m = logged["matrices"][1]
    np.testing.assert_allclose(moved, moving @ m[:2, :2].T + m[:2, 2], atol=1e-3)


def test_icp_iterations_on_their_timeline_per_backend(recorded):
    _, _, rec = recorded
    for backend in ("reference", "open3d"):
        fit = [r for r in rec.get(E.icp_path(backend, "fitness"), "Scalars:scalars") if not r.static]
        assert [(r.times["frame"], r.times["icp_iteration"]) for r in fit] == [(f, k) for f in range(3) for k in range(4)]
        assert [scalar(r) for r in fit[:4]] == pytest.approx([0.5, 0.6, 0.7, 0.8])
        rmse = rec.series(E.icp_path(backend, "inlier_rmse"), timeline="icp_iteration")
        assert rmse == pytest.approx({0: 2.0, 1: 1.0, 2: 2 / 3, 3: 0.5})
        corr = [r for r in rec.get(E.icp_path(backend, "correspondences")) if not r.static]  # static: the style
        assert len(corr) == 12
        assert all(len(r["LineStrips2D:strips"]) <= 200 for r in corr)
        moving = [r for r in rec.get(E.icp_path(backend, "moving")) if not r.static]
        assert len(moving) == 12 and len(points(moving[0])) == 300
        targets = [r for r in rec.get(E.icp_path(backend, "target")) if not r.static]
        assert len(targets) == 6  # once per frame and pyramid level
    # frame-level entities sit at the start of the iteration timelines (shown with the iterations)
    at_start = {"frame": 2, "icp_iteration": 0, "crosscheck_iteration": 0}
    assert rec.latest(E.transform_path("T_ref_mov"), frame=2).times == at_start
    assert rec.moving(frame=2).times == at_start


def test_text_config_and_crosscheck(recorded):
    _, _, rec = recorded
    import json

    assert json.loads(text(rec.latest(E.CONFIG))) == {"backend": "reference", "max_iteration": 14}
    lines = [(r["TextLog:level"].to_pylist()[0], text(r)) for r in rec.get(E.LOG)]
    assert lines[0][0] == "INFO" and lines[0][1].startswith("config: ")
    assert ("WARN", "finished") in lines
    report = json.loads(text(rec.latest(E.CROSSCHECK_REPORT)))
    assert report["translation_px"] == {"max": 0.25} and report["agree"] is True
    assert rec.series(f"{E.CROSSCHECK}/rotation_deg") == {2: 0.0125}
    assert rec.series(f"{E.CROSSCHECK}/open3d/fitness") == {2: 0.875}
    assert not rec.get(f"{E.CROSSCHECK}/agree")  # booleans are not series


def test_rrd_verify_passes(recorded, tmp_path):
    """rerun loads and interprets every chunk. The recording has no footer (pcreg.recording.sink), which is all
    ``rerun rrd verify`` finds wrong with it; the copy ``rerun rrd optimize`` writes, with one, verifies."""
    path, _, _ = recorded
    res = subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and "Missing RRD footer" in res.stderr and "1 errors" in res.stderr, res.stderr
    copy = tmp_path / "optimized.rrd"
    subprocess.run([str(RERUN), "rrd", "optimize", str(path), "-o", str(copy)], capture_output=True, check=True,
                   timeout=60)
    res = subprocess.run([str(RERUN), "rrd", "verify", str(copy)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr


def test_exception_in_with_block_is_logged_as_failure(tmp_path):
    path = tmp_path / "fail.rrd"
    with pytest.raises(ZeroDivisionError):
        with Recorder(path) as rec:
            rec.set_frame(0)
            rec.log_text("before")
            1 / 0
    rec_back = read_recording(path)
    lines = [(r["TextLog:level"].to_pylist()[0], text(r)) for r in rec_back.get(E.LOG)]
    assert lines[-1][0] == "ERROR" and "ZeroDivisionError" in lines[-1][1]
    assert rec.closed


def test_bad_input_before_any_frame_leaves_no_recording(tmp_path, capsys):
    """``evaluate sequence --data camvid:nowhere --record bad.rrd`` refused the folder and left ``bad.rrd``
    (holding only the refusal), which then refused the corrected command ("exists"). Bad input found after
    work began is logged in the recording, which is kept."""
    from pcreg.cli import main
    from pcreg.errors import InputError

    bad = tmp_path / "bad.rrd"
    assert main(["evaluate", "sequence", "--data", f"camvid:{tmp_path / 'nowhere'}", "--record", str(bad),
                 "--out", str(tmp_path / "out")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert not bad.exists() and not (tmp_path / "out").exists()
    # the folders the recording's path made go with it (they were left, empty); a folder already there stays
    (tmp_path / "kept").mkdir()
    for made in (tmp_path / "new" / "sub" / "bad.rrd", tmp_path / "kept" / "sub" / "bad.rrd"):
        assert main(["evaluate", "sequence", "--data", f"camvid:{tmp_path / 'nowhere'}", "--record", str(made),
                     "--out", str(tmp_path / "out")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"] and not any((tmp_path / "kept").iterdir())
    later = tmp_path / "later.rrd"
    with pytest.raises(InputError):
        with Recorder(later) as rec:
            rec.set_frame(0)
            raise InputError("frame 1: not an image")
    assert "not an image" in text(list(read_recording(later).get(E.LOG))[-1])


def test_interrupted_recording_is_readable_up_to_where_it_stopped(tmp_path):
    path = tmp_path / "killed.rrd"
    child = textwrap.dedent(f"""
        import sys
        import numpy as np
        from pcreg.recording.recorder import Recorder
        rec = Recorder({str(path)!r})
        for f in range(1000):
            rec.set_frame(f)
            rec.log_transform(np.eye(3) * (f + 1))
            rec.log_errors({{"plain": f / 1000}})
            if f == 5:
                rec.flush()  # frames 0..5 are in the file
                print("ready", flush=True)
                sys.stdin.read()  # hold still until killed
    """)
    proc = subprocess.Popen([sys.executable, "-c", child], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        proc.stdout.close()
        proc.stdin.close()
    assert proc.returncode == -signal.SIGKILL
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no footer": expected for a file whose writer was killed
        rec = read_recording(path)
    frames = {r.times["frame"]: tensor(r) for r in rec.get(E.transform_path("T_ref_mov"))}
    assert set(range(6)) <= set(frames)
    assert all(np.array_equal(frames[f], np.eye(3) * (f + 1)) for f in range(6))
    assert rec.series(E.error_path("plain"))[5] == 0.005


def test_existing_file_refused_unless_force(tmp_path):
    path = tmp_path / "x.rrd"
    path.write_bytes(b"old")
    with pytest.raises(OutputError, match="exists"):
        Recorder(path)
    assert path.read_bytes() == b"old"
    with Recorder(path, force=True) as rec:
        rec.log_text("new")
    assert read_recording(path).get(E.LOG)


def test_unwritable_paths_refused(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    with pytest.raises(OutputError) as err:
        Recorder(blocker / "x.rrd")
    assert "\n" not in str(err.value)
    with pytest.raises(OutputError):
        Recorder(tmp_path)  # a folder
    with pytest.raises(OutputError, match=r"\.rrd"):
        Recorder(tmp_path / "x.txt")


def test_bad_arrays_are_input_errors(tmp_path):
    with Recorder(tmp_path / "bad.rrd") as rec:
        rec.set_frame(0)
        with pytest.raises(InputError):
            rec.log_images(reference=np.zeros((4, 4, 3), np.float32))
        with pytest.raises(InputError):
            rec.log_transform(np.eye(2))
        with pytest.raises(InputError):
            rec.log_transform(np.full((3, 3), np.nan))
        with pytest.raises(InputError):
            rec.log_clouds(reference_points=np.zeros((5, 3)))
        with pytest.raises(InputError):
            rec.log_clouds(moving_points=np.zeros((5, 2)), moving_colors=np.zeros((4, 3)))
        with pytest.raises(InputError):
            rec.log_labels(truth=np.zeros((4, 4), np.float32))
        with pytest.raises(ValueError, match="unknown log level 'LOUD'"):
            rec.log_text("x", level="LOUD")


def test_closed_recorder_refuses_more(tmp_path):
    rec = Recorder(tmp_path / "c.rrd")
    rec.close()
    rec.close()  # idempotent
    with pytest.raises(OutputError, match="closed"):
        rec.log_text("late")


def test_kind_is_stored_and_picks_the_blueprint(tmp_path):
    """The kind (given, or inferred from what was logged) is a recording property, and the blueprint
    embedded on close has a view only where something was logged."""
    from pcreg.recording.readback import read_blueprint, read_kind

    with Recorder(tmp_path / "r.rrd", kind="register") as rec:
        rec.set_frame(0)
        rec.log_images(reference=_image(0), moving=_image(1))
    assert read_kind(tmp_path / "r.rrd") == "register"
    views, timeline = read_blueprint(tmp_path / "r.rrd")
    assert {v.name for v in views} == {"Registration", "Moving"} and timeline == "icp_iteration"

    with Recorder(tmp_path / "s.rrd") as rec:  # inferred: label maps and errors are a sequence's
        for f in range(2):
            rec.set_frame(f)
            rec.log_labels(truth=np.zeros((H, W), np.uint8), predicted=np.ones((H, W), np.uint8), prefix="plain")
            rec.log_errors({"plain": 0.25 + f, "alone": 1.0} if f == 0 else {"plain": 0.25 + f})
    assert read_kind(tmp_path / "s.rrd") == "sequence"
    views, timeline = read_blueprint(tmp_path / "s.rrd")
    assert {v.name for v in views} == {"Truth plain", "Predicted plain", "Errors"} and timeline == "frame"
    errors = next(v for v in views if v.name == "Errors")
    assert errors.query == ("+ /errors/**",)

    with Recorder(tmp_path / "c.rrd", blueprint="crosscheck") as rec:  # a kind given as the blueprint
        rec.set_frame(0)
        rec.log_text("x")
    assert read_kind(tmp_path / "c.rrd") == "crosscheck"

    with Recorder(tmp_path / "n.rrd", blueprint=False) as rec:
        rec.set_frame(0)
        rec.log_text("x")
    assert read_blueprint(tmp_path / "n.rrd") == ([], None)

    with pytest.raises(ValueError, match="unknown kind"):
        Recorder(tmp_path / "bad.rrd", kind="nonsense")
    with pytest.raises(ValueError, match="disagree"):
        Recorder(tmp_path / "bad2.rrd", kind="register", blueprint="sequence")


def test_entities_tracked_match_the_file(recorded):
    """What the recorder notes it logged (for the blueprint) is what the file holds."""
    from pcreg.recording.readback import read_entities

    path, _, rec = recorded
    on_file = read_entities(path)
    assert "/registration/reference" in on_file and "EncodedImage" in on_file["/registration/reference"]
    assert "Scalars" in on_file["/icp/open3d/fitness"] and "Points2D" in on_file["/icp/reference/moving"]
    assert not any(p.startswith("/__") for p in on_file)


def test_dense_field_is_logged_under_dense(tmp_path):
    path = tmp_path / "dense.rrd"
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    field = np.dstack([xs + 3.0 + 0.05 * ys, ys - 4.0]).astype(np.float32)
    T = np.array([[1.0, 0, 3.0], [0, 1.0, -4.0], [0, 0, 1.0]])
    conf = np.linspace(0, 1, H * W, dtype=np.float32).reshape(H, W)
    with Recorder(path, recording_id="dense-1", raw_images=True) as rec:
        rec.set_frame(0)
        rec.log_dense(field, matrix=T, confidence=conf, warped_prior=1.0 - conf, quiver_step=16)
        with pytest.raises(InputError):
            rec.log_dense(field[..., :1])
        with pytest.raises(InputError):
            rec.log_dense(field, confidence=conf[:10])
    r = read_recording(path)
    top = float(np.hypot(3.0 + 0.05 * ys, -4.0).max())
    assert r.series(E.DENSE_MAX_DISPLACEMENT)[0] == pytest.approx(top, rel=1e-5)
    mag = image(r.latest(E.DENSE_DISPLACEMENT, frame=0))
    assert mag.shape == (H, W, 3)
    refine = image(r.latest(E.DENSE_REFINEMENT, frame=0))
    assert refine.shape == (H, W, 3)
    # refinement 0.05 y grows down the image: the colour map changes between top and bottom rows
    assert not np.array_equal(refine[0], refine[-1])
    c = image(r.latest(E.DENSE_CONFIDENCE, frame=0))
    assert c.shape == (H, W) and c[0, 0] == 0 and c[-1, -1] == 255
    assert image(r.latest(E.DENSE_WARPED_PRIOR, frame=0))[0, 0] == 255
    row = r.latest(E.DENSE_QUIVER, frame=0)
    vectors = np.asarray(row["Arrows2D:vectors"].to_pylist(), dtype=np.float32).reshape(-1, 2)
    assert len(vectors) == (H // 16) * (W // 16)
    np.testing.assert_allclose(vectors[:, 1], -4.0, atol=1e-5)


# a's JPEG is logged once, as reference; b.copy() is the previous moving image in another buffer; d is a
# reference that is not, logged once for frames 2 and 3; a (frame 4) the previous moving image again
PAIRS = [(0, 1), (1, 2), (3, 4), (3, 0), (0, 2)]


def _pairs(path, **kw):
    images = [_image(i) for i in range(5)]
    with Recorder(path, kind="sequence", **kw) as rec:
        for f, (r, m) in enumerate(PAIRS):
            rec.set_frame(f)
            rec.log_images(reference=images[r].copy(), moving=images[m])
    return images, read_recording(path)


def _blob(row) -> bytes:
    return bytes(row["EncodedImage:blob"][0].values.to_numpy(zero_copy_only=False))


@pytest.mark.parametrize("raw_images", [False, True], ids=["jpeg", "raw"])
def test_each_frame_is_stored_once(tmp_path, monkeypatch, raw_images):
    """Every pair's moving image is stored once, in the image slots; a reference that is the previous
    pair's moving image is not stored again (its slot is placed as the reference and
    registration/reference cleared), another is stored when it changes; every pair's images read back."""
    from pcreg.recording.readback import read_blueprint

    calls = []
    real = cv2.imencode
    monkeypatch.setattr(cv2, "imencode", lambda ext, *a, **k: (calls.append(ext), real(ext, *a, **k))[1])
    images, back = _pairs(tmp_path / "r.rrd", raw_images=raw_images)
    key = "Image:buffer" if raw_images else "EncodedImage:blob"
    stored = [(r.entity, r.times["frame"]) for e in (E.REFERENCE_IMAGE, *E.IMAGE_SLOTS) for r in back.get(e, key)]
    assert sorted(f for e, f in stored if e == "/" + E.REFERENCE_IMAGE) == [0, 2]  # frame 3's is frame 2's
    assert sorted(f for e, f in stored if e != "/" + E.REFERENCE_IMAGE) == [0, 1, 2, 3, 4]  # the moving images
    assert [r.times["frame"] for r in back.get(E.REFERENCE_IMAGE, "Clear:is_recursive")] == [1, 4]
    assert calls.count(".jpg") == (0 if raw_images else 6)  # 0 1 2 3 4 as met, and 0 again (out of the last four kept)
    where = [back.reference(f).entity.strip("/") for f in range(5)]
    assert where == [E.REFERENCE_IMAGE, E.IMAGE_SLOTS[0], E.REFERENCE_IMAGE, E.REFERENCE_IMAGE, E.IMAGE_SLOTS[1]]
    assert [back.moving(f).entity.strip("/") for f in range(5)] == [E.IMAGE_SLOTS[f % 2] for f in range(5)]
    for f, (r, m) in enumerate(PAIRS):
        for row, want in ((back.reference(f), images[r]), (back.moving(f), images[m])):
            got = image(row).astype(int)
            assert np.array_equal(got, want) if raw_images else np.abs(got - want).mean() < 4.0
    views, _ = read_blueprint(tmp_path / "r.rrd")
    registration = next(v for v in views if v.name == "Registration")
    assert f"+ /{E.IMAGES}/**" in registration.query and registration.time_ranges == ()
    assert all(v.time_ranges == () for v in views)


def test_the_callers_buffers_are_free_at_once_and_lines_keep_their_order(tmp_path):
    """What is logged is built on the recorder's thread; the caller may reuse its arrays as soon as a call
    returns. The recorder's thread is held until the caller has overwritten them, so a call that kept a
    reference instead of a copy would log the overwritten values."""
    import threading

    rng = np.random.default_rng(3)
    m, truth = _matrix(rng), rng.integers(0, 3, (H, W)).astype(np.uint8)
    field = np.dstack(np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))) + 1.5
    confidence = np.full((H, W), 0.75, np.float32)
    pts = rng.uniform(0, [W, H], size=(50, 2))
    release = threading.Event()
    with Recorder(tmp_path / "r.rrd", label_stride=1) as rec:
        rec.set_frame(0)
        rec.sink.later(release.wait)  # holds the recorder's thread
        rec.log_transform(m)
        rec.log_labels(truth=truth)
        rec.log_clouds(moving_points=pts)
        rec.log_dense(field, confidence=confidence)
        for i in range(20):
            rec.log_text(f"line {i}")
        expected = (m.copy(), truth.copy(), pts.copy())
        for a in (m, truth, pts, field, confidence):
            a[...] = 0
        release.set()
    back = read_recording(tmp_path / "r.rrd")
    assert np.array_equal(tensor(back.latest(E.transform_path("T_ref_mov"), frame=0)), expected[0])
    assert np.array_equal(segmentation(back.latest(E.labels_path("truth", ""), frame=0)), expected[1])
    np.testing.assert_allclose(points(back.latest(E.MOVING_CLOUD, frame=0)), expected[2], atol=1e-4)
    assert back.series(E.DENSE_MAX_DISPLACEMENT) == {0: pytest.approx(1.5 * np.sqrt(2), rel=1e-6)}
    assert image(back.latest(E.DENSE_CONFIDENCE, frame=0)).min() > 150  # 0.75, not the zeros written after
    assert [text(r) for r in back.get(E.LOG)] == [f"line {i}" for i in range(20)]


def test_icp_iterations_before_the_first_frame_have_no_frame(tmp_path):
    """Iterations are sent in batches across frames; those logged before any frame are sent on their own."""
    pts = np.random.default_rng(4).uniform(0, [W, H], size=(40, 2))
    it = IcpIteration("reference", 0, 0, np.eye(3), 0.5, 1.0, pts, pts, np.arange(40))
    with Recorder(tmp_path / "r.rrd") as rec:
        cb = rec.icp_callback("reference")
        cb(it)
        cb(it)
        for f in range(2):
            rec.set_frame(f)
            cb(it)
    back = read_recording(tmp_path / "r.rrd")
    fit = [r for r in back.get(E.icp_path("reference", "fitness"), "Scalars:scalars") if not r.static]
    assert [(r.times.get("frame"), r.times["icp_iteration"]) for r in fit] == [(None, 0), (None, 1), (0, 0), (1, 0)]


def test_both_recorders_implement_the_protocol_method_for_method():
    """Recorder and NullRecorder have every method of RecorderProtocol with its signature, and nothing else
    answers: the null recorder has no catch-all."""
    import inspect

    from pcreg.recording.interface import RecorderProtocol
    from pcreg.recording.null import NULL_RECORDER, NullRecorder

    methods = [n for n, v in vars(RecorderProtocol).items() if callable(v) and not n.startswith("_")]
    assert {"set_frame", "flush", "log_images", "log_transform", "icp_callback", "log_crosscheck_iteration"} <= set(methods)
    for cls in (Recorder, NullRecorder):
        for name in methods:
            assert inspect.signature(getattr(cls, name)).parameters == inspect.signature(getattr(RecorderProtocol, name)).parameters, (cls, name)
    assert Recorder.enabled and not NULL_RECORDER.enabled
    assert NULL_RECORDER.icp_callback("reference") is None
    with pytest.raises(AttributeError):
        NULL_RECORDER.log_everything()


def test_only_the_recording_package_imports_rerun():
    import re

    root = Path(__file__).resolve().parents[1] / "pcreg"
    importers = {p.relative_to(root).parts[0] for p in root.rglob("*.py")
                 if re.search(r"^\s*(import rerun|from rerun)", p.read_text(encoding="utf-8"), re.M)}
    assert importers == {"recording"}


def test_a_transform_is_drawn_with_its_own_frames_moving_image(tmp_path):
    """The outline and the moved cloud are drawn from what was logged of the frame's pair (Recorder.pairs.pair):
    a frame without a moving image draws no outline until given ``moving_shape``."""
    pts = np.random.default_rng(5).uniform(0, [W, H], size=(30, 2))
    with Recorder(tmp_path / "r.rrd") as rec:
        rec.set_frame(0)
        rec.log_images(moving=_image(0))
        assert rec.pairs.pair.moving_shape == (H, W)
        rec.log_transform(np.eye(3))
        rec.set_frame(1)
        assert rec.pairs.pair.moving_shape is None and rec.pairs.pair.matrix is None
        rec.log_transform(np.eye(3))
        rec.log_clouds(moving_points=pts)  # after the transform: mapped by it
        rec.set_frame(2)
        rec.log_transform(np.eye(3), moving_shape=(10, 20))
    back = read_recording(tmp_path / "r.rrd")
    outlines = {r.times["frame"]: r for r in back.get(E.outline_path("T_ref_mov"))}
    assert set(outlines) == {0, 2}
    np.testing.assert_allclose(np.asarray(outlines[2]["LineStrips2D:strips"].to_pylist()[0])[2], [19.5, 9.5])
    np.testing.assert_allclose(points(back.latest(E.MOVED_CLOUD, frame=1)), pts, atol=1e-4)


def test_display_indices_are_numpys_evenly_spaced_ones():
    from pcreg.recording.values import display_indices

    assert display_indices(10, 300) == slice(None)
    for n in (2, 301, 1001, 4093, 100_000):
        for limit in (0, 1, 2, 3, 200, 300):
            if n > limit:
                np.testing.assert_array_equal(display_indices(n, limit), np.linspace(0, n - 1, limit).astype(np.intp))


def test_a_recording_whose_writer_stopped_is_refused_and_removed_not_waited_on(tmp_path, monkeypatch):
    """A full disk stops rerun's file writer; its flush and its exit then wait without end. The sink waits
    in bounded steps, and a file that stops growing while data is still held is a StuckOutput (the
    command line ends the process at once on it), the unfinished file removed."""
    from pcreg.errors import StuckOutput
    from pcreg.recording import sink as sink_module

    path = tmp_path / "r.rrd"
    rec = Recorder(path)
    rec.log_images(reference=np.zeros((32, 32, 3), np.uint8))
    waits = []

    def stalled_flush(*, timeout_sec=1e38):  # rerun's flush when its writer is gone: each wait runs out
        waits.append(timeout_sec)
        raise RuntimeError("Flush timed out - not all log messages were sent")

    monkeypatch.setattr(rec.sink._rec, "flush", stalled_flush)
    monkeypatch.setattr(rec.sink._rec, "disconnect", lambda: pytest.fail("a stuck writer must not be waited on"))
    with pytest.raises(StuckOutput, match="could not be written .* it was removed"):
        rec.close()
    assert not path.exists()
    # bounded waits, never rerun's default of 1e38 s; the real writer may still grow the file at first
    assert set(waits) == {sink_module.FLUSH_SECONDS} and sink_module.FLUSH_STALLS < len(waits) < 100


def test_implementations_whose_names_differ_in_punctuation_keep_apart(tmp_path, capfd):
    """Two ``cmd:`` implementations whose command lines differ only where an entity path takes no character
    (``--x 1`` and ``--x=1``) were logged to one entity, ``crosscheck/cmd_._icp_--x_1``: the viewer drew both
    clouds as one implementation's and mixed their series; and the report's numbers went to paths of the names as
    they are, which rerun re-read with a warning on stderr for each. Each implementation now has its own entity,
    the first one under the plain name, and rerun warns of nothing."""
    names = ("cmd:./icp --x 1", "cmd:./icp --x=1")
    path = tmp_path / "names.rrd"
    with Recorder(path) as rec:
        rec.set_frame(0)
        for k, name in enumerate(names):
            for it in range(3):
                rec.log_crosscheck_iteration(name, it, np.full((4, 2), float(k)), error=float(10 * k + it))
        rec.log_crosscheck({"implementations": {n: {"seconds": float(k + 1)} for k, n in enumerate(names)}})
    assert "parse_path" not in capfd.readouterr().err
    rec = read_recording(path)
    first, second = "/crosscheck/cmd_._icp_--x_1", "/crosscheck/cmd_._icp_--x_1_2"
    assert rec.series(f"{first}/error", timeline="crosscheck_iteration") == {0: 0.0, 1: 1.0, 2: 2.0}
    assert rec.series(f"{second}/error", timeline="crosscheck_iteration") == {0: 10.0, 1: 11.0, 2: 12.0}
    assert len([r for r in rec.get(f"{first}/cloud") if not r.static]) == 3
    assert rec.series("/crosscheck/implementations/cmd_._icp_--x_1/seconds") == {0: 1.0}
    assert rec.series("/crosscheck/implementations/cmd_._icp_--x_1_2/seconds") == {0: 2.0}
