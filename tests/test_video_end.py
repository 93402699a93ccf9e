"""A video run labelled to its end: run.json keeps the video file's fingerprint (``video_file``) and that its
frames were labelled to their end (``video_end``), so the same command again says every frame is done without
decoding the video or reading a carry; a video that changed since is not taken as finished, and one replaced by
another file at the same path is refused (exit 2, ``--force`` starts over). Videos of the shared CamVid frames,
written with PyAV."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets.sources import VideoFrames
from _runs import kill_before_commit, one_line_errors
from _videos import mux_all

N = 10


@pytest.fixture(scope="module")
def camvid(shared_data):
    """``(frames, key labels)``: N CamVid frames of 0001TP at 160x120 and the first one's labels (lagr's ids)."""
    from pcreg.classes.mappings import mapping_lut

    clip = shared_data / "camvid" / "0001TP"
    if not (clip / "images").is_dir():
        pytest.skip(f"{clip} is absent (the shared CamVid clips)")
    images = [cv2.resize(cv2.imread(str(p)), (160, 120), interpolation=cv2.INTER_AREA)[:, :, ::-1].copy()
              for p in sorted((clip / "images").iterdir())[:N]]
    labels = mapping_lut("camvid")[cv2.imread(str(sorted((clip / "labels").iterdir())[0]), cv2.IMREAD_UNCHANGED)]
    return images, cv2.resize(labels, (160, 120), interpolation=cv2.INTER_NEAREST)


def _video(path, images, fmt=None):
    """``images`` as H.264 in ``path`` (its container by its suffix, or ``fmt``); skipped without the encoder."""
    av = pytest.importorskip("av")
    try:
        av.codec.Codec("h264", "w")
    except (av.FFmpegError, ValueError):
        pytest.skip("this FFmpeg has no h264 encoder")
    with av.open(str(path), "w", format=fmt) as c:
        s = c.add_stream("h264", rate=10)
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        s.options = {"crf": "18", "g": "5"}
        mux_all(c, s, images)
    return path


@pytest.fixture
def decoded(monkeypatch):
    """How many frames the runs decode from here on (every one the decoder hands on, chosen or not)."""
    count = [0]
    real = VideoFrames._decoded

    def counting(self, reading):
        for item in real(self, reading):
            count[0] += 1
            yield item

    monkeypatch.setattr(VideoFrames, "_decoded", counting)
    return count


def _state(out):
    return json.loads((out / "run.json").read_text())


def _files(out):
    """Every file in ``out`` but the carries and the lock, with its bytes and modification time."""
    return {p.relative_to(out): (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(out.rglob("*"))
            if p.is_file() and not p.name.startswith(("carry-", ".pcreg.lock"))}


def _finished_run(camvid, tmp_path):
    """``(video, out, args)``: a video of the clip's frames labelled to its end from its first frame's labels into
    ``out`` by the command ``args``."""
    images, labels = camvid
    video = _video(tmp_path / "clip.mp4", images)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    out = tmp_path / "out"
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--out", str(out)]
    assert main(args) == 0
    return video, out, args


def test_a_finished_video_run_is_known_done_without_decoding_or_its_carries(camvid, tmp_path, capsys, decoded):
    video, out, args = _finished_run(camvid, tmp_path)
    state = _state(out)
    st = video.stat()
    assert state["done"] == N and state["video_end"] == N
    assert state["video_file"]["size"] == st.st_size and state["video_file"]["mtime_ns"] == st.st_mtime_ns
    assert len(state["video_file"]["sha256"]) == 64
    capsys.readouterr()

    # the carries deleted: a run that resumed from the last frame's carry could not go on; this one needs none
    for slot in (0, 1):
        (out / f"carry-{slot}.npz").unlink()
    before, decoded[0] = _files(out), 0
    assert main([*args, "--suggest", "2"]) == 0
    said = capsys.readouterr().out
    assert f"{out}: all {N} frames already done" in said and "suggest.txt" in said
    assert decoded[0] <= 2  # the key frame and the next, read to check the labels against: not the video
    after = _files(out)
    lines = after.pop(Path("suggest.txt"))[0].decode().splitlines()
    assert after == before  # nothing rewritten
    assert main([*args, "--record", str(tmp_path / "r.rrd")]) == 0  # nothing to record: said, no file
    assert "nothing is recorded" in capsys.readouterr().err and not (tmp_path / "r.rrd").exists()
    assert len(lines) == 2 and all(line.split("\t")[0] in {f"{i:06d}" for i in range(1, N)} for line in lines)


def test_a_run_json_without_the_record_or_a_changed_file_goes_as_before(camvid, tmp_path, capsys, decoded):
    """A run.json from before the record (or a video whose fingerprint changed: touched, copied over with the same
    bytes) is not taken as finished: the run decodes its way to its end, as before, and keeps the record then."""
    video, out, args = _finished_run(camvid, tmp_path)
    state = _state(out)
    older = {k: v for k, v in state.items() if k not in ("video_file", "video_end")}
    (out / "run.json").write_text(json.dumps(older))
    decoded[0] = 0
    assert main(args) == 0 and f"all {N} frames already done" in capsys.readouterr().out
    assert decoded[0] >= N  # decoded to its end to find no frame left
    assert _state(out) == state  # and the record kept

    st = video.stat()
    os.utime(video, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # the same bytes, another time
    decoded[0] = 0
    assert main(args) == 0 and f"all {N} frames already done" in capsys.readouterr().out
    assert decoded[0] >= N
    assert _state(out)["video_file"]["mtime_ns"] == st.st_mtime_ns + 10**9 and _state(out)["video_end"] == N
    decoded[0] = 0
    assert main(args) == 0 and decoded[0] <= 2

    for bad in ({"size": -1, "mtime_ns": 0, "sha256": "0" * 64}, {"size": 1, "mtime_ns": 0, "sha256": "x"}, [1]):
        (out / "run.json").write_text(json.dumps(dict(state, video_file=bad)))
        assert main(args) == 2
        assert one_line_errors(capsys) == [f"pcreg: error: {out / 'run.json'}: its 'video_file' is not as pcreg run "
                                           "writes it; use --force to start over"]


def test_a_video_replaced_at_the_same_path_is_refused(camvid, tmp_path, capsys, monkeypatch):
    """Another video at the run's path (the frames in another order, re-encoded) was labelled from the first one's
    carry when the run resumed, and a finished run over it said every frame done. Refused, one line; --force starts
    over."""
    images, labels = camvid
    video = _video(tmp_path / "clip.mp4", images)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    out = tmp_path / "out"
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--out", str(out)]
    kill_before_commit(monkeypatch, 4)
    assert main(args) == 130
    monkeypatch.undo()
    assert _state(out)["done"] == 4
    size = video.stat().st_size
    _video(tmp_path / "other.mp4", images[:1] + images[:0:-1])  # the same key frame, then the others backwards
    os.replace(tmp_path / "other.mp4", video)
    capsys.readouterr()
    assert main(args) == 2
    assert one_line_errors(capsys) == [
        f"pcreg: error: {video}: not the video the run in {out} began on (its size or bytes changed since: "
        f"{size} bytes then, {video.stat().st_size} now); use --force to start over"]
    assert _state(out)["done"] == 4
    assert main([*args, "--force"]) == 0 and _state(out)["video_end"] == N

    # a finished run: refused too, not said done
    _video(tmp_path / "other.mp4", images[::-1])
    os.replace(tmp_path / "other.mp4", video)
    assert main(args) == 2 and "not the video the run" in one_line_errors(capsys)[0]

    # a run from a folder of key frames over it as well
    keys = tmp_path / "keys"
    keys.mkdir()
    cv2.imwrite(str(keys / "000000.png"), labels)
    cv2.imwrite(str(keys / "000006.png"), labels)
    kout = tmp_path / "kout"
    assert main(["run", str(video), "--labels", str(keys), "--out", str(kout)]) == 0
    _video(tmp_path / "other.mp4", images)
    os.replace(tmp_path / "other.mp4", video)
    capsys.readouterr()
    assert main(["run", str(video), "--labels", str(keys), "--out", str(kout)]) == 2
    assert "not the video the run" in one_line_errors(capsys)[0]


def test_a_video_written_again_while_the_run_labels_it_is_refused_at_its_end(camvid, tmp_path, capsys, monkeypatch):
    """A video written again at its path while a run decoded it (another encode put in its place): the run ended with
    exit 0 and its frames possibly of two videos, the fingerprint checked only when a run began. Checked again where
    decoding ends: refused naming the file, from one label image and from key frames alike, and not marked labelled
    to its end; the run again refuses the file as not the video it began on."""
    from pcreg.runs.run import Run

    images, labels = camvid
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    keys = tmp_path / "keys"
    keys.mkdir()
    for i in (0, N - 1):
        cv2.imwrite(str(keys / f"{i:06d}.png"), labels)
    real = Run.write_frame
    for labelled_from, out in ((tmp_path / "key.png", tmp_path / "one"), (keys, tmp_path / "keyed")):
        video = _video(tmp_path / "clip.mp4", images)
        other = _video(tmp_path / "other.mp4", images[::-1])

        def write_frame(self, t, *a, **k):
            if t == 4 and other.exists():
                os.replace(other, video)
            return real(self, t, *a, **k)

        monkeypatch.setattr(Run, "write_frame", write_frame)
        args = ["run", str(video), "--labels", str(labelled_from), "--out", str(out)]
        capsys.readouterr()
        assert main(args) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{video}: written again while the run in {out} labelled it" in err[0], err
        assert "video_end" not in _state(out)
        monkeypatch.undo()
        assert main(args) == 2 and "not the video the run" in one_line_errors(capsys)[0]


def test_a_transport_stream_appended_to_goes_on(camvid, tmp_path, capsys):
    """A recording still growing (a transport stream with frames appended) is the same video, longer: a run from one
    label image labels the frames added after its end, as before; a key-frames run labels its stretch to the end
    again, as it does a folder's that gained frames after its last key frame."""
    images, labels = camvid
    first = _video(tmp_path / "a.ts", images[:6]).read_bytes()
    rest = _video(tmp_path / "b.ts", images[6:]).read_bytes()
    video = tmp_path / "clip.ts"
    video.write_bytes(first)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    keys = tmp_path / "keys"
    keys.mkdir()
    cv2.imwrite(str(keys / "000000.png"), labels)
    cv2.imwrite(str(keys / "000002.png"), labels)
    runs = {tmp_path / "one": tmp_path / "key.png", tmp_path / "many": keys}
    for out, key in runs.items():
        assert main(["run", str(video), "--labels", str(key), "--out", str(out)]) == 0
    assert _state(tmp_path / "one")["video_end"] == 6
    with open(video, "ab") as fh:
        fh.write(rest)
    capsys.readouterr()
    for out, key in runs.items():
        assert main(["run", str(video), "--labels", str(key), "--out", str(out)]) == 0, one_line_errors(capsys)
        assert sorted(p.name for p in out.glob("*.png")) == [f"{i:06d}.png" for i in range(N)]
    assert "4 frame(s) labelled" in capsys.readouterr().out
    assert _state(tmp_path / "one")["video_end"] == N
    steps = [json.loads(line)["frame"] for line in (tmp_path / "many" / "steps.jsonl").read_text().splitlines()]
    assert sorted(steps) == [1, *range(3, N)]


def _random_video_file(path, size: int, seed: int):
    """``(bytes, frames, state)``: ``size`` random bytes written at ``path``, a stand-in for its
    :class:`~pcreg.datasets.sources.VideoFrames`, and a run.json's state of 5 frames done that ``keep_video`` took it
    into (not yet labelled to its end)."""
    from types import SimpleNamespace

    from pcreg.runs.video_file import fingerprint, keep_video

    data = np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes()
    path.write_bytes(data)
    frames = SimpleNamespace(path=path)
    state = {"done": 5}
    assert keep_video(state, frames, path.parent) is False and state["video_file"] == fingerprint(path)
    return data, frames, state


def test_the_fingerprint_tells_a_file_appended_to_from_one_changed(tmp_path):
    """``keep_video`` on files of more than two MiB: the same file, one appended to (grown, goes on), one whose last
    MiB or size changed (refused), one touched (kept anew, its end forgotten)."""
    from pcreg.errors import OutputError
    from pcreg.runs.video_file import MIB, keep_video, labelled_to_end

    path = tmp_path / "v.ts"
    data, frames, state = _random_video_file(path, 3 * MIB + 17, 0)
    state["video_end"] = 5
    assert keep_video(state, frames, tmp_path) is False and labelled_to_end(state)
    kept = dict(state)

    path.write_bytes(data + b"more")
    assert keep_video(state, frames, tmp_path) is True and not labelled_to_end(state)
    assert state["video_file"]["size"] == len(data) + 4

    for changed in (data[:-1] + b"x", data[:-1], data[:MIB // 2] + b"x" + data[MIB // 2 + 1:]):
        path.write_bytes(changed)
        with pytest.raises(OutputError, match="not the video the run"):
            keep_video(dict(kept), frames, tmp_path)

    path.write_bytes(data)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, kept["video_file"]["mtime_ns"] + 1))
    state = dict(kept)
    assert keep_video(state, frames, tmp_path) is False and not labelled_to_end(state)
    assert state["video_file"]["mtime_ns"] == kept["video_file"]["mtime_ns"] + 1


@pytest.mark.parametrize("where", ["in the middle", "at the end"])
def test_a_transport_stream_with_a_run_of_other_bytes_is_read_through(camvid, tmp_path, capsys, where):
    """FFmpeg's MPEG-TS demuxer scans a bounded stretch for the next packet and then gives up (EAGAIN): a whole
    file with 200 kB of zeros between its packets (or after the last) was refused as "truncated or damaged"."""
    av = pytest.importorskip("av")
    images, labels = camvid
    video = _video(tmp_path / "clip.ts", images)
    data = video.read_bytes()
    with av.open(str(video)) as c:
        places = [p.pos for p in c.demux(video=0) if p.size]
    cut = places[N // 2] if where == "in the middle" else len(data)
    padded = tmp_path / "padded.ts"
    padded.write_bytes(data[:cut] + b"\0" * 200_000 + data[cut:])
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    for name, path in (("whole", video), ("padded", padded)):
        assert main(["run", str(path), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / name)]) == 0, \
            one_line_errors(capsys)
    labelled = {name: {p.name: p.read_bytes() for p in sorted((tmp_path / name).glob("*.png"))} for name in ("whole", "padded")}
    assert len(labelled["padded"]) == N and labelled["padded"] == labelled["whole"]


def test_the_fingerprint_sees_a_change_inside_a_file_of_the_same_size_and_ends(tmp_path):
    """A file of frames all of one size (raw video) written again with other frames in its middle keeps its size and
    its first and last MiB: it was taken as the video the run began on. Its spread of blocks tells it (a change of more
    than a 255th of the file, for certain); a run.json of an earlier pcreg (no ``spread``) is checked by the rest and
    gains it, keeping that the video was labelled to its end; one holding a field pcreg does not write is checked as
    before (it ended in a KeyError)."""
    from types import SimpleNamespace

    from pcreg.errors import OutputError
    from pcreg.runs.video_file import MIB, SPREAD, fingerprint, keep_video, labelled_to_end, video_file_problem

    path = tmp_path / "v.avi"
    data, frames, state = _random_video_file(path, 5 * MIB + 3, 1)
    state["video_end"] = 5
    kept = dict(state)
    for at in (MIB + 1, 2 * MIB + 12345, 4 * MIB - len(data) // SPREAD - 1):
        changed = bytearray(data)
        changed[at:at + len(data) // SPREAD + 1] = bytes(len(data) // SPREAD + 1)
        path.write_bytes(bytes(changed))
        assert fingerprint(path)["sha256"] == kept["video_file"]["sha256"]  # its ends are the same
        with pytest.raises(OutputError, match="not the video the run"):
            keep_video(dict(kept), frames, tmp_path)
        bigger = SimpleNamespace(path=tmp_path / "grown.avi")
        bigger.path.write_bytes(bytes(changed) + b"more")
        with pytest.raises(OutputError, match="not the video the run"):  # nor appended to
            keep_video(dict(kept), bigger, tmp_path)

    path.write_bytes(data)
    os.utime(path, ns=(path.stat().st_atime_ns, kept["video_file"]["mtime_ns"]))
    old = {**kept, "video_file": {k: v for k, v in kept["video_file"].items() if k != "spread"}}
    assert video_file_problem(old) is None
    assert keep_video(old, frames, tmp_path) is False and labelled_to_end(old) and old["video_file"] == fingerprint(path)
    assert video_file_problem({**kept, "video_file": {**kept["video_file"], "spread": "x"}}) == "video_file"
    odd = {**old, "video_file": {**old["video_file"], "note": "x"}}
    odd["video_file"].pop("spread")
    assert keep_video(odd, frames, tmp_path) is False and odd["video_file"] == fingerprint(path)


def test_a_raw_video_written_again_with_other_frames_inside_is_refused(camvid, tmp_path, capsys):
    """Raw video (every frame 57,600 bytes at 160x120) labelled to its end, then written again with ten other frames in
    its middle: the same command said every frame done (exit 0), its labels those of the frames no longer there."""
    av = pytest.importorskip("av")
    images, labels = camvid
    clip = [images[i % N] for i in range(50)]

    def raw(path, frames):
        with av.open(str(path), "w") as c:
            s = c.add_stream("rawvideo", rate=10)
            s.width, s.height, s.pix_fmt = 160, 120, "bgr24"
            mux_all(c, s, frames)
        return path

    video = raw(tmp_path / "clip.avi", clip)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    args = ["run", str(video), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "out"), "--model", "flow"]
    assert main(args) == 0
    size = video.stat().st_size
    raw(tmp_path / "other.avi", clip[:20] + [im[::-1].copy() for im in clip[20:30]] + clip[30:])
    os.replace(tmp_path / "other.avi", video)
    assert video.stat().st_size == size
    capsys.readouterr()
    assert main(args) == 2
    assert "not the video the run" in one_line_errors(capsys)[0]
