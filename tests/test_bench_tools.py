"""Smoke runs of the benchmark programs in tools/: tiny settings, outputs exist and parse."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parent.parent / "tools"


def _load(name: str):
    """A tool as a module, with tools/ importable as when it runs as a script (its shared benchlib)."""
    if str(TOOLS) not in sys.path:
        sys.path.insert(0, str(TOOLS))
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_bench_registration_without_data_uses_textures_and_synthetic_clouds(tmp_path):
    bench = _load("bench_registration")
    out = tmp_path / "bench"
    rc = bench.main(["--out", str(out), "--data", str(tmp_path / "absent"), "--sizes", "200,400",
                     "--repeats", "1", "--icp-iterations", "3", "--cases", "2", "--camvid-cases", "1",
                     "--impossible", "1", "--texture-seeds", "1", "--max-side", "160"])
    assert rc == 0
    report = json.loads((out / "registration.json").read_text())
    img = report["images"]
    assert set(img["sets"]) == {"terrain"}  # no CamVid frames without the data
    rows = img["sets"]["terrain"]["rows"]
    assert len(rows) == 2 and all(r["image"].startswith("texture:") for r in rows)
    for method in bench.METHODS:
        s = img["sets"]["terrain"]["summary"][method]
        assert 0.0 <= s["success"] <= 1.0 and s["median_seconds"] > 0
    imp = img["impossible"]
    assert {r["kind"] for r in imp["rows"]} == set(bench.IMPOSSIBLE)
    for method in imp["methods"]:
        assert imp["summary"][method]["cases"] == 3
    rows = report["scaling"]["kinds"]["2-D"]["rows"]
    assert [r["source_points"] for r in rows] == [200, 400]
    assert all(r["max_abs_matrix_difference"] < 1e-6 for r in rows)  # same clouds, same iterations
    md = (out / "registration.md").read_text()
    assert "## Targets" in md and "Impossible pairs" in md
    assert (out / "registration.csv").read_text().startswith("set,case,kind")
    for png in ("registration_accuracy.png", "registration_scaling.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
@pytest.mark.data
def test_bench_registration_on_the_shared_data(tmp_path, shared_data):
    bench = _load("bench_registration")
    out = tmp_path / "bench"
    rc = bench.main(["--out", str(out), "--data", str(shared_data), "--cases", "2", "--camvid-cases", "2",
                     "--impossible", "1", "--sizes", "300,600", "--repeats", "1", "--icp-iterations", "3"])
    assert rc == 0
    report = json.loads((out / "registration.json").read_text())
    m = report["machine"]
    assert m["cpu_count"] >= 1 and m["opencv"] and m["open3d"]
    assert set(report["images"]["sets"]) == {"terrain", "camvid"}
    for st in report["images"]["sets"].values():
        assert len(st["rows"]) == 2
        for method in bench.METHODS:
            assert all(r[method]["seconds"] > 0 for r in st["rows"])
    assert set(report["scaling"]["kinds"]) == {"2-D", "3-D"}


def test_bench_registration_rejects_bad_options(tmp_path):
    bench = _load("bench_registration")
    assert bench.main(["--out", str(tmp_path), "--methods", "sift"]) == 2
    assert bench.main(["--out", str(tmp_path), "--cases", "0"]) == 2


def test_ecc_warp_direction_on_a_pure_translation():
    """ECC's warp maps reference -> moving pixels; the tool inverts it into T_ref_mov."""
    import numpy as np

    from pcreg.registration.transforms import max_corner_error, rigid2d

    bench = _load("bench_registration")
    rng = np.random.default_rng(0)
    import cv2

    base = cv2.GaussianBlur(rng.uniform(0, 255, (120, 160)).astype(np.float32), (0, 0), 3)
    ref = np.repeat(cv2.normalize(base, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)[..., None], 3, axis=2)
    T = rigid2d(0.0, 3.0, -2.0)
    mov = bench.make_moving(ref, T)
    est = bench.ecc_register(ref, mov)
    assert max_corner_error(est, T, ref.shape) < 0.5


def test_bench_recording_measures_the_real_sequence_pipeline(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(TOOLS))
    bench = _load("bench_recording")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--pairs", "3", "--repeats", "1", "--data", "synthetic:syn1a"]) == 0
    report = json.loads((out / "recording.json").read_text())
    (run,) = report["runs"]
    assert run["pairs"] == 3 and run["overhead_ratio"] > 0 and run["recording_mb"] > 0
    assert report["command"].startswith("python ") and report["machine"]["cpu_count"] >= 1
    assert "### Checks" in (out / "recording.md").read_text()


def test_bench_icp_threads_set_both_libraries_and_the_targets(monkeypatch):
    """--threads N: numba's and OpenMP's counts (Open3D loaded with another count is refused); one thread
    each is held to 1.0 in 2-D and 3-D, more to 1.0 in 2-D and 0.8 in 3-D."""
    import numba

    bench = _load("bench_icp")
    assert bench.ratio_target("3-D", 1) == bench.ratio_target("2-D", 1) == bench.ratio_target("2-D", 2) == 1.0
    assert bench.ratio_target("3-D", 2) == bench.ratio_target("3-D", None) == 0.8
    monkeypatch.setitem(sys.modules, "open3d", object())
    monkeypatch.setenv("OMP_NUM_THREADS", "4")
    with pytest.raises(SystemExit, match="Open3D was loaded before"):
        bench.set_threads(1)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    before = numba.get_num_threads()
    try:
        bench.set_threads(1)
        assert numba.get_num_threads() == 1
    finally:
        numba.set_num_threads(before)


@pytest.mark.slow
@pytest.mark.parametrize("threads", [False, True])
def test_bench_icp_without_data_compares_three_implementations(tmp_path, monkeypatch, threads):
    from pcreg.registration import nn

    # the profile finds the compiled loop whichever of its two forms runs
    monkeypatch.setattr(nn, "threaded", lambda n: threads)
    bench = _load("bench_icp")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--data", str(tmp_path / "absent"), "--sizes", "300,600",
                       "--repeats", "1", "--iterations", "3"]) == 0
    report = json.loads((out / "bench_icp.json").read_text())
    assert report["threads"] is None  # each library its default
    rows = report["kinds"]["2-D"]["rows"]
    assert [r["source_points"] for r in rows] == [300, 600]
    assert all(set(r["median_seconds"]) == {"reference", "open3d", "small_gicp"} for r in rows)
    assert all(r["max_abs_matrix_difference"] < 1e-9 for r in rows)  # same clouds, no ties: the same steps
    prof = report["kinds"]["2-D"]["profile"]
    assert prof["source_points"] == 300 and prof["total_ms"] > 0
    assert prof["parts_ms"]["compiled loop (update, move, search, sums, stopping rule)"] > 0 and all(v >= 0 for v in prof["parts_ms"].values())
    assert sum(prof["parts_ms"].values()) == pytest.approx(prof["total_ms"])
    md = (out / "bench_icp.md").read_text()
    assert "### Checks" in md and "### Profile" in md
    assert "| transforms equal to 1e-9, 2-D, sizes without tied queries | max " in md and "not held" not in md
    assert (out / "bench_icp.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a size with tied queries (two right answers) is listed, not held to the equality; the others are
    rows[1].update(max_abs_matrix_difference=5e-4, tied_queries_at_start=7)
    md = bench.render(report)
    assert "sizes with ties, not held to it: N = 600: 5.0e-04, 7 tied queries) | met |" in md
    rows[0]["max_abs_matrix_difference"] = 1e-6
    assert "| transforms equal to 1e-9, 2-D, sizes without tied queries | max 1.0e-06 (" in bench.render(report)


def test_bench_pipeline_times_the_default_step_and_its_stages(tmp_path):
    bench = _load("bench_pipeline")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--data", "synthetic", "--frames", "3", "--cores", "0"]) == 0
    s = json.loads((out / "bench_pipeline.json").read_text())["streams"]["synthetic"]
    assert s["pairs"] == 2 and set(s["median_ms"]) == set(bench.METHODS) and s["refused"] == 0
    st = s["stages_median_ms"]
    assert st["total"] > 0 and st["register.search"] > 0 and st["register.field"] > 0 and st["fuse.warp"] > 0
    assert all(0 <= e <= 100 for e in s["mean_error"].values())
    md = (out / "bench_pipeline.md").read_text()
    assert "Propagator.step (default) / DIS fast <= 1" in md and "Propagator.step (default) / DIS medium <= 1" in md
    assert "the trust map and learning add <= 15% to the step" in md and st["fuse.trust"] > 0
    assert "without the second motion" in md and "without learning" in md  # what each part of the trust costs
    assert "Propagator.step at half size / DIS fast <= 1" in md and 0 < s["ratio_half_over_step"]
    assert "DIS medium's flow at a quarter size (trust and learning on) / DIS fast <= 1" in md
    assert 0 < s["ratio_flow_quarter_over_dis_fast"] and 0 <= s["mean_error"]["flow_half"] <= 100
    assert (out / "bench_pipeline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert bench.main(["--out", str(out), "--frames", "2"]) == 2


def test_sweep_scale_scores_each_working_size_beside_dis(tmp_path):
    sweep = _load("sweep_scale")
    out = tmp_path / "sweep"
    assert sweep.main(["--out", str(out), "--data", "synthetic:syn1a,syn2b", "--frames", "3", "--scales", "1,0.5",
                       "--flow-presets", "fast", "--flow-scales", "0.5", "--workers", "1"]) == 0
    r = json.loads((out / "sweep_scale.json").read_text())
    assert set(r["reduction"]) == {"scale 1", "scale 0.5", "flow fast, scale 0.5", *sweep.BASELINES,
                                   *(f"{m} blurred" for m in sweep.BASELINES)}
    assert all(len(v) == 2 for v in r["reduction"].values()) and all(v > 0 for v in r["median_ms"].values())
    assert r["reduction"]["scale 0.5"] != r["reduction"]["scale 1"]  # the working size changed the labels
    assert "| scale 0.5 |" in (out / "sweep_scale.md").read_text()
    assert (out / "sweep_scale.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_dense_runs_and_reports_the_ratio_to_dis(tmp_path):
    bench = _load("bench_dense")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--pairs", "1", "--repeats", "1"]) == 0
    report = json.loads((out / "bench_dense.json").read_text())
    assert report["pairs"] == 1 and report["ratio_to_dis"]["dis_medium"] == 1.0
    assert set(report["median_ms"]) == {"dis_medium", "dense_step", "global", "dense_total"}
    assert "ratio to DIS medium" in (out / "bench_dense.md").read_text()


@pytest.mark.slow
def test_bench_soak_short_stream_reports_and_resumes_exactly(tmp_path):
    bench = _load("bench_soak")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--frames", "30", "--size", "160x120", "--seed", "1", "--interval", "0.01"]) == 0
    report = json.loads((out / "bench_soak.json").read_text())
    a = report["soak"]
    assert a["frames"] == 30 and a["window"] == 2 and a["same_content_in_windows"]
    series = a["series"]
    assert len(series["frame_ms"]) == len(series["step_ms"]) == len(series["step_line_bytes"]) == 29
    assert series["samples"] and all(s["rss_mb"] > 0 for s in series["samples"])
    # a window of two short frames may fall between two samples: sampled sizes are checked over the run
    assert a["rss_mb_at_warm"] > 0 and a["state_bytes_max"] > 0 and a["step_line_bytes_first"] > 0
    k = report["kill"]
    assert k["killed"] and 2 <= k["done_at_kill"] < 30 and k["returncode_killed"] == -9
    assert k["returncode_resumed"] == 0 and k["compare"]["identical"], k["compare"]
    assert k["compare"]["files"] == 30 + 4  # a label PNG per frame, run.json, steps.jsonl and the two carry slots
    md = (out / "bench_soak.md").read_text()
    assert "### Checks" in md and "killed (SIGKILL) and resumed" in md and report["command"].startswith("python ")
    assert (out / "bench_soak.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_bench_run_times_pcreg_run_and_slows_its_disk(tmp_path, shared_data):
    bench = _load("bench_run")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--data", str(shared_data / "camvid"), "--repeats", "1",
                       "--fsync-ms", "1"]) == 0
    report = json.loads((out / "bench_run.json").read_text())
    assert report["frames"] > 2 and report["fsync_ms"] == 1.0
    assert 0 < report["median_whole_fps"] < report["median_loop_fps"]  # start-up is in the whole command only
    assert "15 frames a second or more" in (out / "bench_run.md").read_text()
    assert bench.main(["--out", str(out), "--data", str(tmp_path / "nowhere")]) == 2


def test_make_long_video_writes_the_frames_and_the_key_labels_of_the_frames_shown(tmp_path, shared_data):
    from pcreg.datasets.sources import Selection, open_frames

    tool = _load("make_long_video")
    video, keys = tmp_path / "long.mp4", tmp_path / "keys"
    assert tool.main(["--data", str(shared_data / "camvid"), "--out", str(video), "--keys", str(keys),
                      "--frames", "45", "--hold", "20", "--key-at", "0,30"]) == 0
    frames = open_frames(video, Selection(0, None, 1))
    assert sum(1 for _ in frames.frames(0)) == 45 and sorted(p.name for p in keys.iterdir()) == ["000000.png", "000030.png"]
    import cv2

    labels = cv2.imread(str(keys / "000030.png"), cv2.IMREAD_UNCHANGED)
    assert labels.shape == (120, 160) and labels.max() <= 11  # the clip's ids, at the frames' size


def test_bench_keys_disk_reads_back_every_way_and_reports_its_size(tmp_path, shared_data):
    bench = _load("bench_keys_disk")
    out = tmp_path / "bench"
    assert bench.main(["--out", str(out), "--size", "96x72", "--frames", "3", "--tmp", str(tmp_path)]) == 0
    report = json.loads((out / "bench_keys_disk.json").read_text())
    for what in (report["two"]["prior"], report["camvid11"]["prior"], report["frame"]):
        sizes = {way: size for way, (size, _) in what.items()}
        chosen = next(size for way, size in sizes.items() if "chosen" in way)
        assert chosen < next(size for way, size in sizes.items() if "before" in way)
    assert "the rule: the smallest" in (out / "bench_keys_disk.md").read_text()


def test_resize_clips_keeps_the_layout_and_the_class_ids(tmp_path):
    import cv2
    import numpy as np

    resize = _load("resize_clips")
    clip = tmp_path / "src" / "clip1"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (36, 48, 3), dtype=np.uint8)
    labels = np.zeros((36, 48), np.uint8)
    labels[:, 24:] = 3
    labels[10:20, 5:15] = 7
    cv2.imwrite(str(clip / "images" / "f1.png"), image)
    cv2.imwrite(str(clip / "labels" / "f1.png"), labels)
    assert resize.resize_root(tmp_path / "src", tmp_path / "up", (96, 72)) == 2
    assert resize.resize_root(tmp_path / "src", tmp_path / "down", (24, 18)) == 2
    up_image = cv2.imread(str(tmp_path / "up" / "clip1" / "images" / "f1.png"))
    up_labels = cv2.imread(str(tmp_path / "up" / "clip1" / "labels" / "f1.png"), cv2.IMREAD_UNCHANGED)
    down_labels = cv2.imread(str(tmp_path / "down" / "clip1" / "labels" / "f1.png"), cv2.IMREAD_UNCHANGED)
    assert up_image.shape == (72, 96, 3) and up_labels.shape == (72, 96) and down_labels.shape == (18, 24)
    assert set(np.unique(up_labels)) == {0, 3, 7} and set(np.unique(down_labels)) <= {0, 3, 7}  # ids, not blends
    assert np.array_equal(up_labels[::2, ::2], labels)  # nearest: each label doubled


@pytest.mark.slow
def test_fit_follow_confidence_fits_each_sequence_left_out_and_reads_its_samples_back(tmp_path, monkeypatch, capsys,
                                                                                        shared_data):
    """Three shared DAVIS sequences cut to 12 frames: the three features and |L| alone are each fitted with one
    sequence left out and on all; the samples kept by ``--samples`` (``.npz`` added) are read back by a later run of
    the same ``--data`` (the follower not run again) and refused, not written over, for another folder; an ``--out``
    whose folder does not exist is refused before the follower runs; ``--score`` refuses a sequence
    that ``--data`` fits on; labels all right (nothing to fit), a folder of no sequence and a damaged samples file end
    with a message."""
    import shutil

    from _davis import frames_and_masks, write_pcreg_layout

    tool = _load("fit_follow_confidence")
    data = tmp_path / "data"
    for name in ("blackswan", "breakdance", "goat"):
        for part in ("images", "labels"):
            (data / name / part).mkdir(parents=True)
            for f in sorted((shared_data / "davis" / name / part).iterdir())[:12]:
                shutil.copy(f, data / name / part / f.name)
    samples, out = tmp_path / "samples", tmp_path / "fit.json"
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(data), "--samples", str(samples), "--out", str(out)])
    assert tool.main() == 0
    result = json.loads(out.read_text())
    assert [f["left_out"] for f in result["features"]["folds"]] == ["blackswan", "breakdance", "goat"]
    assert len(result["features"]["shipped"]["w"]) == 3 and len(result["alone"]["shipped"]["w"]) == 1
    assert 0 < result["features"]["pooled_left_out"]["error"] < 10 and 0 <= result["features"]["pooled_left_out"]["ece"] < 0.2
    with monkeypatch.context() as m:
        m.setattr(tool, "record", lambda frames: pytest.fail("the kept samples were not read back"))
        assert tool.main() == 0
    assert json.loads(out.read_text()) == result and (tmp_path / "samples.npz").is_file()
    shutil.copytree(data, tmp_path / "other")
    shutil.rmtree(tmp_path / "other" / "goat")
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(tmp_path / "other"), "--samples", str(samples), "--out", str(out)])
    with pytest.raises(SystemExit, match="holds the samples of"):  # kept, not written over
        tool.main()
    assert json.loads(out.read_text()) == result
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(tmp_path / "other"), "--samples", str(tmp_path / "s2"), "--out",
                                      str(tmp_path / "no" / "fit.json")])
    with pytest.raises(SystemExit):  # said before the follower runs
        tool.main()
    assert "its folder does not exist" in capsys.readouterr().err and not (tmp_path / "s2.npz").exists()
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(data), "--score", str(data)])
    with pytest.raises(SystemExit):
        tool.main()
    assert "holds sequences --data fits on" in capsys.readouterr().err
    easy = tmp_path / "easy"
    for i in range(2):
        write_pcreg_layout(easy / f"seq{i}", frames_and_masks(4, shape=(96, 128), seed=i))
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(easy)])
    with pytest.raises(SystemExit):
        tool.main()
    assert "labels both right and wrong" in capsys.readouterr().err
    (tmp_path / "none").mkdir()
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(tmp_path / "none")])
    with pytest.raises(SystemExit, match="no DAVIS sequence"):
        tool.main()
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    monkeypatch.setattr(sys, "argv", ["fit", "--data", str(data), "--samples", str(tmp_path / "bad.npz")])
    with pytest.raises(SystemExit, match="holds no samples this tool kept"):
        tool.main()
