"""`pcreg evaluate stream`: every method on the same frames, outputs, resume and bad input."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from pcreg.cli import main
from pcreg.experiments.stream import run_clip

CAMVID = Path(__file__).resolve().parents[2] / "shared" / "data" / "camvid"


@pytest.mark.parametrize("bad", [np.nan, 1.5, -0.1])
def test_calibration_refuses_a_confidence_that_is_no_probability(bad):
    # NaN or -0.1 raised numpy's "'list' argument must have no negative elements"; 1.5 gave 383 levels, and
    # calibration() an IndexError on them
    from pcreg.errors import InputError
    from pcreg.experiments.stream_methods import calibration, calibration_counts

    labels, truth = np.zeros((2, 2), np.uint8), np.array([[0, 1], [0, 2]], np.uint8)
    good = calibration_counts(np.full((2, 2), 0.9, np.float32), labels, truth)
    assert good.shape == (2, 256) and good.sum() == 3 and calibration(good)["error"] == pytest.approx(100 / 3)
    with pytest.raises(InputError, match="confidence"):
        calibration_counts(np.array([[0.9, bad], [0.5, 1.0]], np.float32), labels, truth)


def test_evaluate_stream_writes_every_table_and_resumes(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--frames", "4", "--size", "160x120", "--data", "synthetic:syn1a,syn2b",
            "--methods", "unregistered,pcreg,flow_key", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "mean error % per clip" in printed and "### Checks" in printed
    res = json.loads((out / "results.json").read_text())
    assert set(res["datasets"]) == {"syn1a", "syn2b"} and res["methods"] == ["plain", "unregistered", "pcreg", "flow_key"]
    for name, c in res["datasets"].items():
        assert c["scored"] == 3
        assert c["reduction"]["plain"] == 0
        assert c["means"]["pcreg"] < c["means"]["plain"]  # the key frame's labels carried by the dense field
    with open(out / "stream_frames.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 6 and {r["since_key"] for r in rows} == {"1", "2", "3"}
    for f in ("stream_reference.md", "checks.md", "stream.png", "config.json"):
        assert (out / f).stat().st_size > 0
    before = {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()}
    assert main(args) == 0  # resumed: no unit is run again
    assert {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()} == before
    assert json.loads((out / "results.json").read_text())["resumed_units"] == 2
    assert (out / "stream_reference.md").read_text().startswith("### Labelling a stream from its key frame: ")


@pytest.mark.parametrize("kept", ["[1, 2]", '{"means": {}}', '{"dataset": "syn2b", "backend": "reference"}'])
def test_a_kept_unit_edited_into_another_shape_is_run_again(tmp_path, capsys, kept):
    """A unit file that reads as JSON but holds no clip's result (a list, a dict without its means, another clip's
    name) ended the rerun with "internal error, a bug in pcreg" (exit 1): it is run again, as a damaged one is."""
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--frames", "3", "--size", "96x72", "--data", "synthetic:syn1a,syn2b",
            "--methods", "unregistered", "--out", str(out)]
    assert main(args) == 0
    first = json.loads((out / "results.json").read_text())
    (out / "units" / "syn1a_reference.json").write_text(kept)
    (out / "results.json").unlink()
    assert main(args) == 0, capsys.readouterr().err
    again = json.loads((out / "results.json").read_text())
    assert again["resumed_units"] == 1 and again["datasets"]["syn1a"]["means"] == first["datasets"]["syn1a"]["means"]


def test_a_kept_unit_without_its_confidence_counts_is_run_again(tmp_path):
    """A clip kept without ``calibration`` (by a pcreg from before pcreg's confidence was scored) was read as one of
    no pixel: the confidence over all clips left its pixels out without a word."""
    out = tmp_path / "out"
    args = ["evaluate", "stream", "--frames", "3", "--size", "96x72", "--data", "synthetic:syn1a,syn2b",
            "--methods", "pcreg", "--out", str(out)]
    assert main(args) == 0
    first = json.loads((out / "results.json").read_text())["calibration"]
    kept = out / "units" / "syn1a_reference.json"
    kept.write_text(json.dumps({k: v for k, v in json.loads(kept.read_text()).items() if k != "calibration"}))
    (out / "results.json").unlink()
    assert main(args) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["resumed_units"] == 1 and res["calibration"]["pixels"] == first["pixels"] > 0


def test_a_stream_with_several_key_frames_says_so_in_its_table(tmp_path):
    """``--keys`` (and ``--key-every``) label each clip from several key frames; the table's title said one."""
    out = tmp_path / "out"
    assert main(["evaluate", "stream", "--frames", "5", "--size", "160x120", "--data", "synthetic:syn1a",
                 "--methods", "pcreg", "--keys", "first,last", "--out", str(out)]) == 0
    assert (out / "stream_reference.md").read_text().startswith("### Labelling a stream from its key frames: ")


def test_evaluate_returns_typed_results_and_the_report_writes_exactly_them(tmp_path):
    from pcreg.experiments.reports.stream import write_outputs
    from pcreg.experiments.results import Results
    from pcreg.experiments.stream import StreamConfig, evaluate
    from pcreg.outputs import finite

    config = StreamConfig(data="synthetic:syn1a", frames=3, size=(96, 72), methods=("plain", "unregistered"))
    res = evaluate(config, show_progress=False)
    assert isinstance(res, Results) and res.kind == "stream" and res.primary_backend == "reference"
    assert res.methods == ("plain", "unregistered") and list(res.datasets) == ["syn1a"]
    assert res.datasets["syn1a"]["scored"] == 2 and len(res.units) == 1 and res.resumed_units == 0
    assert set(res.average_reduction) == {"plain", "unregistered"} and res.k is None and res.backends is None
    write_outputs(res, tmp_path)
    on_disk = json.loads((tmp_path / "results.json").read_text())
    assert on_disk == json.loads(json.dumps(finite(res.to_dict())))
    assert list(on_disk) == ["config", "primary_backend", "methods", "datasets", "average_reduction", "calibration",
                             "units", "resumed_units", "seconds"]  # what an evaluation does not have is left out
    with pytest.raises(ValueError, match="kind must be one of"):
        Results("streams", {}, {}, [])


def test_pcreg_is_exactly_the_propagator_and_key_frames_restart(tmp_path):
    import pcreg

    frames = pcreg.synthetic("syn1a", 5, 0, width=160, height=120)
    r = run_clip(frames, methods=("plain", "pcreg", "dense_key"), key_every=3)
    assert [f["key"] for f in r["frames"]] == [0, 0, 3] and r["key_frames"] == [0, 3]
    expected = []
    for key, later in ((0, (1, 2)), (3, (4,))):  # a propagator as pcreg run makes it, restarted at each key frame
        prop = pcreg.Propagator.from_key_frame(frames[key].image, frames[key].labels)
        expected += [pcreg.error_rate(prop.step(frames[t].image), frames[t].labels) for t in later]
    assert [f["errors"]["pcreg"] for f in r["frames"]] == expected
    cal = r["calibration"]  # pcreg's confidence over the known pixels of the three scored frames
    assert np.sum(cal) == sum(int((f.labels < 2).sum()) for i, f in enumerate(frames) if i not in (0, 3))


def test_evaluate_stream_bad_input(tmp_path, capsys):
    assert main(["evaluate", "stream", "--frames", "1", "--size", "160x120", "--data", "synthetic:syn1a",
                 "--out", str(tmp_path / "o")]) == 2
    assert "needs a key frame and one more" in capsys.readouterr().err
    assert main(["evaluate", "stream", "--methods", "warp", "--out", str(tmp_path / "o")]) == 2
    assert "--methods: unknown warp" in capsys.readouterr().err
    clip = tmp_path / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    import cv2

    for i in range(2):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), np.full((40, 60, 3), 60 * i, np.uint8))
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), np.full((40, 60), 2, np.uint8))
    assert main(["evaluate", "stream", "--data", f"folder:{clip}", "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no known label" in err
    # a key frame of obstacle alone, in the same process: the clip is read again, not taken from the last run's
    cv2.imwrite(str(clip / "labels" / "f0.png"), np.full((40, 60), 1, np.uint8))
    assert main(["evaluate", "stream", "--data", f"folder:{clip}", "--out", str(tmp_path / "o3")]) == 2
    assert capsys.readouterr().err == (f"pcreg: error: clip {clip.name} of folder:{clip}: the labels of the key frame f0 hold one class "
                                       "only, obstacle; the classifier that starts the stream needs pixels of both "
                                       "ground and obstacle\n")


@pytest.mark.skipif(not CAMVID.is_dir(), reason="needs ../shared/data/camvid (real CamVid clips)")
def test_pcreg_beats_plain_and_unregistered_on_a_real_clip():
    from pcreg.datasets.folder import load_folder

    frames = load_folder(CAMVID / "0016E5")[:12]
    r = run_clip(frames, methods=("plain", "unregistered", "pcreg"))
    assert r["means"]["pcreg"] < r["means"]["unregistered"] < r["means"]["plain"]


def test_pcreg_flow_is_pcreg_run_with_the_flow_model_at_half_size():
    import pcreg
    from pcreg.datasets import synthetic

    frames = synthetic("syn1a", 5, 0, width=320, height=240)
    r = run_clip(frames, methods=("plain", "pcreg_flow"))
    assert r["means"]["pcreg_flow"] < r["means"]["plain"] and r["ms_per_frame"]["pcreg_flow"] > 0
    prop = pcreg.Propagator.from_key_frame(frames[0].image, frames[0].labels, model="flow", scale=0.5)
    direct = [pcreg.error_rate(prop.step(f.image), f.labels) for f in frames[1:]]
    np.testing.assert_allclose([f["errors"]["pcreg_flow"] for f in r["frames"]], direct)


def _synthetic_clip(clip):
    """``clip``: a folder of four synthetic 96x72 frames and their labels (images/, labels/), made and returned."""
    import cv2

    import pcreg

    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i, f in enumerate(pcreg.synthetic("syn1a", 4, 0, width=96, height=72)):
        cv2.imwrite(str(clip / "images" / f"f{i}.png"), f.image[:, :, ::-1])
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), f.labels)
    return clip


def _refused_once_a_frame_changed(data, clip, out, capsys) -> list[str]:
    """The arguments of an evaluation of ``data`` into ``out``, run and resumed, then refused once a frame of ``clip``
    changed."""
    import cv2

    args = ["evaluate", "stream", "--data", f"folder:{data}", "--methods", "plain", "--out", str(out)]
    assert main(args) == 0 and main(args) == 0  # the same data resumes
    cv2.imwrite(str(clip / "images" / "f2.png"), cv2.imread(str(clip / "images" / "f3.png")))
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err  # the file named (it said "its files changed since" and no more)
    assert "its files changed since: " in err and "images/f2.png written again" in err and "(use --force" in err, err
    return args


def test_results_of_data_that_changed_since_are_not_resumed(tmp_path, capsys):
    """A finished evaluation rerun over the same --out after its frames changed gave the old units' numbers
    (8.41% where a fresh run gives 33.4%) with exit 0."""
    clip = _synthetic_clip(tmp_path / "data" / "clip")
    args = _refused_once_a_frame_changed(tmp_path / "data", clip, tmp_path / "o", capsys)
    assert main(args + ["--force"]) == 0


def test_data_in_a_linked_folder_that_changed_since_is_not_resumed(tmp_path, capsys):
    """A clip linked into the --data folder (a subset of a dataset made of links) was left out of the data's
    digest: its frames changed and the rerun gave the old units' numbers with exit 0. A link to a folder above
    is walked once, not for ever."""
    import os

    clip = _synthetic_clip(tmp_path / "elsewhere" / "clip")
    (tmp_path / "data").mkdir()
    os.symlink(clip, tmp_path / "data" / "clip")
    os.symlink(tmp_path / "elsewhere", clip / "loop")  # a loop of links
    _refused_once_a_frame_changed(tmp_path / "data", clip, tmp_path / "o", capsys)


def test_the_checks_name_only_the_methods_that_ran():
    """``--methods plain,pcreg`` reported "pcreg never worse than unregistered on any clip: met", though the
    unregistered key frame never ran."""
    from pcreg.experiments.reports.stream import checks
    from pcreg.experiments.stream import StreamConfig, evaluate

    res = evaluate(StreamConfig(data="synthetic:syn1a", frames=3, size=(96, 72), methods=("plain", "pcreg")),
                   show_progress=False).to_dict()
    said = checks(res)
    assert "never worse than plain" in said and "unregistered" not in said, said


def test_a_stream_recording_draws_each_frame_over_its_key_frame(tmp_path):
    """The Registration view of an ``evaluate stream --record`` recording was empty; it shows the key frame
    every method carries, under each frame."""
    import pcreg
    from pcreg.recording.readback import image, read_recording

    rrd = tmp_path / "stream.rrd"
    assert main(["evaluate", "stream", "--data", "synthetic:syn1a", "--frames", "4", "--size", "96x72",
                 "--methods", "plain,pcreg", "--out", str(tmp_path / "out"), "--record", str(rrd), "--record-raw"]) == 0
    rec = read_recording(rrd)
    frames = pcreg.synthetic("syn1a", 4, 0, width=96, height=72)
    for counter, t in enumerate((1, 2, 3)):  # the recording's frames count the scored frames
        np.testing.assert_array_equal(image(rec.reference(counter)), frames[0].image)
        np.testing.assert_array_equal(image(rec.moving(counter)), frames[t].image)


def test_a_resumed_evaluation_records_only_what_it_runs_and_says_so(tmp_path, capsys):
    """A finished evaluation run again with a new ``--record`` wrote a recording of no frame, which its report
    named as the evaluation's own; one resumed after a stop recorded the rest without a word."""
    import pcreg
    from pcreg.experiments.reports.files import recordings
    from pcreg.recording.readback import ended, image, read_recording

    out = tmp_path / "out"
    args = ["evaluate", "stream", "--data", "synthetic:syn1a,syn2b", "--frames", "4", "--size", "96x72", "--methods",
            "plain,pcreg", "--out", str(out)]
    assert main(args) == 0
    capsys.readouterr()
    assert main([*args, "--record", str(out / "all.rrd"), "--record-raw"]) == 0
    err = capsys.readouterr().err
    assert f"every unit is already done, so nothing is recorded and {out / 'all.rrd'} is not written" in err, err
    assert not (out / "all.rrd").exists() and recordings(out) == []
    (out / "units" / "syn1a_reference.json").unlink()  # as a stop after the first clip leaves it
    assert main([*args, "--record", str(out / "rest.rrd"), "--record-raw"]) == 0
    err = capsys.readouterr().err
    assert f"{out / 'rest.rrd'} records the 1 unit(s) this run runs: the 1 an earlier run finished are not in it" in err
    assert ended(out / "rest.rrd") and recordings(out) == ["rest.rrd"]
    frames = pcreg.synthetic("syn1a", 4, 0, width=96, height=72)
    np.testing.assert_array_equal(image(read_recording(out / "rest.rrd").moving(0)), frames[1].image)


def test_the_confidence_check_says_the_error_rate_and_the_share_of_the_errors():
    """The check read "carry at most a third of the error" while it compared error rates: 0.383 of the rate is
    0.306 of the errors (80% of the pixels), which the line now says beside it."""
    from pcreg.experiments.reports.stream import _calibration_checks

    cal = {"pixels": 1000, "ece": 0.004, "error": 13.68, "error_top80": 5.24, "top80_ratio": 5.24 / 13.68}
    line = _calibration_checks({"calibration": cal})[1]
    assert "at most a third of the error rate of all: NOT met" in line, line
    assert "0.383; they hold 0.306 of the errors" in line, line


def test_a_report_writes_numpy_float32_nan_and_inf_as_null(tmp_path):
    """results.json is strict JSON: a float32 NaN (a mean of no pixel in float32) was written as ``NaN``, which
    a browser's or jq's JSON reader refuses; float64 ones were already null."""
    import json

    from pcreg.experiments.reports.files import write_files

    results = {"config": {"clips": 1}, "mean": np.float32("nan"), "rows": [np.float32(np.inf), np.float32(0.5)],
               "counts": np.arange(3, dtype=np.int64)}
    write_files(tmp_path, results)
    text = (tmp_path / "results.json").read_text()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"results.json holds {c}")) == {
        "config": {"clips": 1}, "mean": None, "rows": [None, 0.5], "counts": [0, 1, 2]}


def test_the_kernels_are_ready_before_a_step_is_timed(monkeypatch):
    """Compiled within the first clip's timed steps, pcreg's kernels read 1,819 ms a frame against 16.6 for the same
    clip again (the report's time a frame, a median over few clips, with them): they are compiled, or loaded from
    the cache, once in the process before the first step is timed."""
    import pcreg.kernels
    from pcreg.experiments import stream_methods

    calls: list[str] = []

    class Labeller:
        def step(self, image):
            calls.append("step")
            return image

    monkeypatch.setattr(stream_methods, "_READY", [])
    monkeypatch.setattr(pcreg.kernels, "warm_up", lambda: calls.append("warm"))
    for _ in range(2):
        stream_methods.Timed(Labeller()).step(np.zeros((4, 4), np.uint8))
    assert calls == ["warm", "step", "step"]


@pytest.mark.parametrize("protocol", ["keys", "classes"])
def test_the_kernels_are_ready_before_label_clip_is_timed(monkeypatch, protocol):
    """The key-frame and many-class protocols time pcreg's label_clip whole, not through Timed: the kernels compiled
    in the first clip's read 819 ms a frame against 148-247 for the same clips again."""
    import pcreg
    import pcreg.kernels
    import pcreg.pipeline.keyframes
    from pcreg.classes import CAMVID11
    from pcreg.experiments import stream_methods
    from pcreg.experiments.stream_classes import run_clip_classes
    from pcreg.experiments.stream_keys import run_clip_keys

    calls: list[str] = []

    class Labelled(Exception):
        pass

    def label_clip(*args, **kwargs):
        calls.append("label")
        raise Labelled

    monkeypatch.setattr(stream_methods, "_READY", [])
    monkeypatch.setattr(pcreg.kernels, "warm_up", lambda: calls.append("warm"))
    monkeypatch.setattr(pcreg.pipeline.keyframes, "label_clip", label_clip)
    frames = pcreg.synthetic("syn1a", 3, 0, width=64, height=48)
    with pytest.raises(Labelled):
        if protocol == "keys":
            run_clip_keys(frames, [0], methods=("plain", "pcreg"))
        else:
            run_clip_classes(frames, [0], CAMVID11, methods=("plain", "pcreg"))
    assert calls == ["warm", "label"]
