"""Property-based fuzzing of a run's folder as its readers find it: run.json, steps.jsonl, suggest.txt, the label and
confidence PNGs, the carry and what a key-frames stretch keeps, each damaged (as bytes, as JSON, as lines, as arrays,
or gone) in a small run made here (finished, or stopped part way), then read by `pcreg view RUN --overlay`,
`pcreg export` and the resume (`pcreg run` again), in this process; the run over a folder of frames, from one label
image or a folder of key frames, or over a video that skips a frame by its times. Each ends in exit 0, or exit 2 with one error line
naming a file of the run's folder; never another exit, and never hangs."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from pcreg.cli import main
from _fuzz import FUZZ, FUZZ_MORE, bounded, mutated_bytes, mutated_json, mutated_text
from _runs import drifting_frames, key_frames_of

SHAPE = (48, 64)


def _stopped_at(n: int):
    """A monkeypatch of Run.commit that stops the run (as at Ctrl-C) at its ``n``-th commit."""
    from pcreg.runs.run import Run

    real, count = Run.commit, [0]

    def commit(self):
        count[0] += 1
        if count[0] == n:
            raise KeyboardInterrupt
        real(self)

    return commit


def _video_with_a_gap(path: Path, images) -> Path:
    """A Matroska file of ``images``, 10 a second but for one frame missing by the times before the fourth."""
    from fractions import Fraction

    import av

    from _videos import mux_all

    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=10)
        s.width, s.height, s.pix_fmt = SHAPE[1], SHAPE[0], "yuv420p"
        s.time_base = s.codec_context.time_base = Fraction(1, 1000)
        frames = [av.VideoFrame.from_ndarray(im, format="rgb24") for im in images]
        for f, t in zip(frames, [0, 100, 200, 400, 500, 600]):
            f.pts, f.time_base = t, Fraction(1, 1000)
        mux_all(c, s, frames)
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, tuple[Path, list[str]]]:
    """Runs made here, ``{name: (folder, the command's arguments but --out)}``: from one label image, from a folder
    of key frames, and over a video that skips a frame by its times (run.json's ``gaps``), each with --confidence and
    --suggest, finished or stopped after its second commit."""
    import cv2

    from pcreg.runs.run import Run

    base = tmp_path_factory.mktemp("fuzz_runs")
    folder, key = drifting_frames(base / "frames", shape=SHAPE, n=6)
    keys = key_frames_of(key, base / "keys", positions=(0, 4))
    video = _video_with_a_gap(base / "gap.mkv", [cv2.imread(str(p))[:, :, ::-1] for p in sorted(folder.iterdir())])
    made = {}
    for name, frames, labels in (("one_key", folder, key), ("key_folder", folder, keys), ("video", video, key)):
        args = ["run", str(frames), "--labels", str(labels), "--confidence", "--suggest", "2"]
        out = base / name
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert main([*args, "--out", str(out)]) == 0
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(Run, "commit", _stopped_at(3))
                assert main([*args, "--out", str(base / f"{name}_stopped")]) == 130
        made[name], made[f"{name}_stopped"] = (out, args), (base / f"{name}_stopped", args)
    return made


def _files(run: Path) -> list[str]:
    return sorted(str(p.relative_to(run)) for p in run.rglob("*") if p.is_file() and p.name != ".pcreg.lock")


def _kind(name: str) -> str:
    """What a file of a run's folder is: run.json, steps.jsonl, suggest.txt, labels, confidence, a carry, or kept by a
    key-frames stretch."""
    if name.startswith(".keys/"):
        return "kept"
    if name.startswith("confidence/"):
        return "confidence"
    return {".png": "labels", ".npz": "carry"}.get(Path(name).suffix, name)


def _npz_members(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _filled(dtype: str, shape: tuple, fill) -> np.ndarray:
    with np.errstate(invalid="ignore"):  # NaN and infinities cast to integers: any value
        return np.full(shape, fill).astype(dtype)


arrays = st.builds(
    _filled,
    st.sampled_from(["uint8", "int64", "float32", "float64", "bool", "<U3", "complex64"]),
    st.lists(st.integers(0, 4), max_size=3).map(tuple),
    st.sampled_from([0, 1, 2, -1, 255, 1e30, float("nan"), float("inf")]))


@st.composite
def damaged(draw, name: str, data: bytes) -> bytes | None:
    """The file ``name`` of a run (its bytes ``data``) damaged as its kind may be: run.json as JSON, steps.jsonl a line
    at a time, suggest.txt as lines, a carry's arrays; any of them as bytes; None: the file gone."""
    how = draw(st.sampled_from(["bytes", "kind", "kind", "kind", "gone"]))
    if how == "gone":
        return None
    if how == "bytes":
        return draw(mutated_bytes(data))
    if name.endswith(".json"):
        return json.dumps(draw(mutated_json(json.loads(data)))).encode()
    if name.endswith(".jsonl"):
        lines = data.decode().splitlines()
        i = draw(st.integers(0, max(0, len(lines) - 1)))
        if lines and draw(st.booleans()):
            lines[i] = json.dumps(draw(mutated_json(json.loads(lines[i]))))
        else:
            lines = draw(mutated_text("\n".join(lines), sep=",")).split("\n")
        return ("\n".join(lines) + draw(st.sampled_from(["\n", ""]))).encode("utf-8", "surrogatepass")
    if name.endswith(".txt"):
        return draw(mutated_text(data.decode(), sep="\t")).encode("utf-8", "surrogatepass")
    if name.endswith(".npz"):
        members = _npz_members(data)
        k = draw(st.sampled_from(sorted(members)))
        if draw(st.booleans()):
            members[k] = draw(arrays)
        else:
            del members[k]
        buf = io.BytesIO()
        np.savez(buf, **members)
        return buf.getvalue()
    if name.endswith(".png"):  # another PNG in its place: another size, depth or number of channels
        import cv2

        h, w = draw(st.sampled_from([SHAPE, SHAPE[::-1], (1, 1), (48, 65)]))
        dtype = draw(st.sampled_from([np.uint8, np.uint16]))
        channels = draw(st.sampled_from([1, 3, 4]))
        image = np.full((h, w, channels), draw(st.integers(0, 255)), dtype)
        return cv2.imencode(".png", image)[1].tobytes()
    return draw(mutated_bytes(data))


#: The bound of one command on a damaged run (a resume labels frames): a hang, not a slow example on a busy
#: machine, which a bound near the commands' own time could fail at random.
COMMAND_HANG_SECONDS = 120


def _command(args: list[str]) -> tuple[int, list[str]]:
    """``pcreg ARGS`` in this process (bounded, :func:`_fuzz.bounded`): its exit code and the lines it wrote on
    stderr."""
    err = io.StringIO()
    with bounded(COMMAND_HANG_SECONDS), contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(args)
    return code, err.getvalue().splitlines()


def _held(code: int, lines: list[str], folder: Path, what: str) -> None:
    """Exit 0, or 2 with one error line that names a file of the run's ``folder``."""
    assert code in (0, 2), f"{what}: exit {code}: {lines}"
    errors = [line for line in lines if line.startswith("pcreg: error:")]
    if code == 0:
        assert not errors, f"{what}: {lines}"
        event(f"{what}: read")
        return
    assert len(errors) == 1 and str(folder) in errors[0], f"{what}: {lines}"
    event(f"{what}: refused")


def _read_damaged(runs, tmp: Path, data) -> None:
    which = data.draw(st.sampled_from(sorted(runs)))
    source, args = runs[which]
    run = tmp / "run"
    if run.exists():
        shutil.rmtree(run)
    shutil.copytree(source, run, ignore=shutil.ignore_patterns(".pcreg.lock"))
    by_kind: dict[str, list[str]] = {}
    for f in _files(run):  # a kind of file first, so that the many PNGs are not most of the examples
        by_kind.setdefault(_kind(f), []).append(f)
    name = data.draw(st.sampled_from(by_kind[data.draw(st.sampled_from(sorted(by_kind)))]))
    blob = data.draw(damaged(name, (run / name).read_bytes()))
    if blob is None:
        (run / name).unlink()
    else:
        (run / name).write_bytes(blob)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("PCREG_TRACEBACK", "1")  # a bug shows where it is
        _held(*_command(["view", str(run), "--overlay", str(tmp / "overlay.mp4"), "--force"]), run, "view")
        _held(*_command(["export", str(run), "--to", str(tmp / "export.zip"), "--force", "--min-confidence", "0.5"]),
              run, "export")
        _held(*_command([*args, "--out", str(run)]), run, "resume")


def test_the_runs_read_whole(runs, tmp_path):
    """The runs made here, undamaged, are read by each reader, and the stopped ones resume."""
    for name, (source, args) in runs.items():
        run = tmp_path / name
        shutil.copytree(source, run, ignore=shutil.ignore_patterns(".pcreg.lock"))
        for command in (["view", str(run), "--overlay", str(tmp_path / f"{name}.mp4")],
                        ["export", str(run), "--to", str(tmp_path / f"{name}.zip"), "--min-confidence", "0.5"],
                        [*args, "--out", str(run)]):
            code, lines = _command(command)
            assert code == 0, (command, lines)
    assert {"carry-0.npz", "suggest.txt", "steps.jsonl", "run.json", "confidence/f1.png", "f5.png"} \
        <= set(_files(runs["one_key"][0]))
    assert any(f.startswith(".keys/") for f in _files(runs["key_folder_stopped"][0]))
    assert json.loads((runs["video"][0] / "run.json").read_text())["gaps"]["listed"] == {"000003": 1}


@FUZZ
@given(data=st.data())
def test_damaged_runs(tmp_path_factory, runs, data):
    _read_damaged(runs, tmp_path_factory.getbasetemp() / "damaged_run", data)


@pytest.mark.slow
@FUZZ_MORE
@given(data=st.data())
def test_damaged_runs_more(tmp_path_factory, runs, data):
    _read_damaged(runs, tmp_path_factory.getbasetemp() / "damaged_run_more", data)


# -- what the fuzzing found --------------------------------------------------------------------------------------

def test_an_overlay_of_a_folder_without_run_json_names_the_folder(runs, tmp_path):
    """A run's folder whose run.json is gone: `pcreg view RUN --overlay` said only what --overlay takes, not which
    folder was none."""
    run = tmp_path / "run"
    shutil.copytree(runs["one_key"][0], run, ignore=shutil.ignore_patterns(".pcreg.lock"))
    (run / "run.json").unlink()
    code, lines = _command(["view", str(run), "--overlay", str(tmp_path / "overlay.mp4")])
    assert code == 2 and lines == [f"pcreg: error: {run}: no run.json, so not the output of pcreg run, which --overlay "
                                   "takes"]


@pytest.mark.parametrize("which", ["one_key", "video"])
def test_a_step_of_a_frame_beyond_the_frames_is_refused_by_the_suggestions(runs, tmp_path, which):
    """A finished run resumed with --suggest reads the predicted errors of its steps.jsonl: a step whose frame is
    beyond the frames (one of six, numbered 256) made the suggestions look its name up out of range, an IndexError
    reported as a bug (exit 1); over a video, they suggested labelling frame 000256 of six."""
    source, args = runs[which]
    run = tmp_path / "run"
    shutil.copytree(source, run, ignore=shutil.ignore_patterns(".pcreg.lock"))
    lines = (run / "steps.jsonl").read_text().splitlines()
    lines[0] = json.dumps({**json.loads(lines[0]), "frame": 256})
    (run / "steps.jsonl").write_text("".join(f"{line}\n" for line in lines))
    code, said = _command([*args, "--out", str(run)])
    assert code == 2 and said[-1].startswith(f"pcreg: error: {run / 'steps.jsonl'}: ") and "frame 256" in said[-1], said


@pytest.mark.parametrize("field, value", [("gaps.last", "²"), ("gaps.last", "9" * 5000), ("gaps.listed", {"²": 1}),
                                          ("damaged.listed", ["²"]), ("damaged.last", "9" * 5000)])
def test_a_frame_number_in_run_json_that_int_refuses_is_a_run_json_pcreg_did_not_write(runs, tmp_path, field, value):
    """run.json names the frames where a video skips frames, and those that decode with errors, by their numbers:
    one that str.isdigit takes and int() does not (a superscript two, a number of 5000 digits) made the readers
    raise int()'s ValueError, a bug (exit 1), where run.json is to be named."""
    run = tmp_path / "run"
    shutil.copytree(runs["video"][0], run, ignore=shutil.ignore_patterns(".pcreg.lock"))
    state = json.loads((run / "run.json").read_text())
    state["damaged"] = {"frames": 1, "last": "000002", "listed": ["000002"]}  # as a frame that decodes with errors
    record, key = field.split(".")
    state[record][key] = value
    if field == "gaps.listed":  # the place's time under the same name
        state["gaps"]["times"] = {"²": 0.4}
    (run / "run.json").write_text(json.dumps(state))
    for command in (["view", str(run), "--overlay", str(tmp_path / "overlay.mp4")],
                    ["export", str(run), "--to", str(tmp_path / "export.zip")], [*runs["video"][1], "--out", str(run)]):
        code, said = _command(command)
        assert code == 2 and said[-1].startswith(f"pcreg: error: {run / 'run.json'}"), (command, said)


def test_a_cursor_without_its_next_frame_is_a_run_json_pcreg_did_not_write(runs, tmp_path):
    """A key-frames run stopped part way keeps in run.json's cursor the next frame of its stretch (null at its
    start): a cursor without the field passed the check of run.json and the resume raised a KeyError, a bug (exit 1)."""
    run = tmp_path / "run"
    shutil.copytree(runs["key_folder_stopped"][0], run, ignore=shutil.ignore_patterns(".pcreg.lock"))
    state = json.loads((run / "run.json").read_text())
    del state["cursor"]["next"]
    (run / "run.json").write_text(json.dumps(state))
    code, said = _command([*runs["key_folder_stopped"][1], "--out", str(run)])
    assert code == 2 and said == [f"pcreg: error: {run / 'run.json'}: its 'cursor' is not as pcreg run writes it; use "
                                  "--force to start over"], said


def test_a_frame_with_two_steps_is_named_in_steps_jsonl_by_the_export(runs, tmp_path):
    """A steps.jsonl whose first line is there twice (the last line read as the one a stopped run may leave): the
    export refused the frame by its name alone (`f1.png: two frames named f1`), not the file that lists it twice."""
    run = tmp_path / "run"
    shutil.copytree(runs["one_key"][0], run, ignore=shutil.ignore_patterns(".pcreg.lock"))
    lines = (run / "steps.jsonl").read_text().splitlines(keepends=True)
    (run / "steps.jsonl").write_text("".join([lines[0], *lines]))
    code, said = _command(["export", str(run), "--to", str(tmp_path / "export.zip")])
    assert code == 2 and said == [f"pcreg: error: {run / 'steps.jsonl'}: two steps of the frame f1.png (not a "
                                  "steps.jsonl pcreg run wrote)"], said
