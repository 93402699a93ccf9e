"""Property-based fuzzing of the videos pcreg reads: small MP4 and Matroska files made here (H.264 with B-frames,
MPEG-4 Part 2, VP9), damaged as bytes (flipped, cut, inserted, a part repeated), random bytes, and a video's first
bytes then random ones, opened with pcreg.datasets.sources.open_frames and every frame read. The reader returns frames
of one size or raises PcregError naming the file; nothing else, and never hangs. FFmpeg may crash the process on a
damaged file, so the videos are read in a process of their own (tests/_video_worker.py), which a crash ends: a signal's
end is a failure, reported with the file."""

from __future__ import annotations

import json
import select
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from _fuzz import FUZZ, FUZZ_MORE, header_then_random, mutated_bytes

av = pytest.importorskip("av")

#: How long the parent waits for an answer: past the worker's own bound, FFmpeg looping in its C code.
WAIT_SECONDS = 60


class Worker:
    """The process that reads the videos (tests/_video_worker.py), started again after it ends."""

    def __init__(self, log: Path) -> None:
        self.log, self.proc = log, None

    def start(self) -> None:
        self.err = open(self.log, "ab")
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("_video_worker.py"))],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.err)
        assert self._line() == "ready"

    def _line(self) -> str | None:
        """The worker's next line; None when it ended; a hang (no line within WAIT_SECONDS) ends it."""
        ready, _, _ = select.select([self.proc.stdout], [], [], WAIT_SECONDS)
        if not ready:
            self.stop()
            return "hang"
        line = self.proc.stdout.readline()
        return line.decode().rstrip("\n") if line else None

    def read(self, path: Path) -> dict:
        """The worker's answer for the video at ``path``: ``{"read": N}``, ``{"refused": LINE}``, ``{"error": ...}``,
        ``{"hang": ...}`` or, when the process died, ``{"died": EXIT}`` (a signal's: -N)."""
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        self.proc.stdin.write(f"{path}\n".encode())
        self.proc.stdin.flush()
        line = self._line()
        if line == "hang":
            return {"hang": WAIT_SECONDS}
        if line is None:
            code = self.proc.wait()
            self.proc = None
            return {"died": code}
        return json.loads(line)

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None
        self.err.close()


@pytest.fixture(scope="module")
def worker(tmp_path_factory):
    w = Worker(tmp_path_factory.mktemp("video_worker") / "stderr.log")
    w.start()
    yield w
    w.stop()


def _images(n: int = 6, shape=(48, 64)) -> list[np.ndarray]:
    """``n`` frames of a textured scene drifting right by 2 px a frame."""
    import cv2

    rng = np.random.default_rng(0)
    h, w = shape
    scene = cv2.GaussianBlur(rng.integers(0, 256, (h, w + 2 * n, 3), dtype=np.uint8), (0, 0), 1.5)
    return [np.ascontiguousarray(scene[:, 2 * (n - i):2 * (n - i) + w]) for i in range(n)]


def _video(suffix: str, codec: str, options: dict | None = None) -> bytes:
    import io

    from _videos import mux_all

    buf = io.BytesIO()
    with av.open(buf, "w", format={".mp4": "mp4", ".mkv": "matroska"}[suffix]) as c:
        s = c.add_stream(codec, rate=10, options=options or {})
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        mux_all(c, s, _images())
    return buf.getvalue()


def _seeds() -> dict[str, tuple[str, bytes]]:
    """The videos damaged here: ``{name: (suffix, bytes)}``."""
    out = {"mp4_h264": (".mp4", _video(".mp4", "libx264", {"bf": "2", "g": "3"})),
           "mkv_h264": (".mkv", _video(".mkv", "libx264", {"bf": "2", "g": "3"})),
           "mp4_mpeg4": (".mp4", _video(".mp4", "mpeg4"))}
    if "libvpx-vp9" in av.codecs_available:
        out["mkv_vp9"] = (".mkv", _video(".mkv", "libvpx-vp9", {"deadline": "realtime", "cpu-used": "8"}))
    return out


SEEDS = _seeds()


def _check(worker: Worker, folder: Path, suffix: str, data: bytes) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"video{suffix}"
    path.write_bytes(data)
    said = worker.read(path)
    if "died" in said:  # kept for the report: the file FFmpeg died on
        kept = folder.parent / f"died-{abs(said['died'])}-{len(data)}{suffix}"
        kept.write_bytes(data)
        pytest.fail(f"the process reading {path} died (exit {said['died']}); the file is kept as {kept}")
    if "error" in said or "hang" in said:
        pytest.fail(f"reading {path}: {said.get('error') or said}", pytrace=False)
    if "refused" in said:
        assert str(path) in said["refused"], said
        event("refused")
    else:
        event("read")


def test_the_seeds_read_whole(worker, tmp_path):
    for name, (suffix, data) in SEEDS.items():
        path = tmp_path / f"{name}{suffix}"
        path.write_bytes(data)
        assert worker.read(path) == {"read": 6}, name


@pytest.mark.parametrize("name", sorted(SEEDS))
@FUZZ
@given(data=st.data())
def test_mutated_videos(tmp_path_factory, worker, name, data):
    suffix, seed = SEEDS[name]
    _check(worker, tmp_path_factory.getbasetemp() / f"video_{name}", suffix, data.draw(mutated_bytes(seed)))


@pytest.mark.parametrize("name", ["mp4_h264", "mkv_h264"])
@FUZZ
@given(data=st.data())
def test_random_videos(tmp_path_factory, worker, name, data):
    """Random bytes, or a video's first bytes (its container's header, part of its first frame) then random ones."""
    suffix, seed = SEEDS[name]
    blob = data.draw(st.binary(max_size=1024) | header_then_random(seed, head=1024))
    _check(worker, tmp_path_factory.getbasetemp() / f"random_{name}", suffix, blob)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SEEDS))
@FUZZ_MORE
@given(data=st.data())
def test_mutated_videos_more(tmp_path_factory, worker, name, data):
    suffix, seed = SEEDS[name]
    blob = data.draw(mutated_bytes(seed) | header_then_random(seed, head=2048) | st.binary(max_size=2048))
    _check(worker, tmp_path_factory.getbasetemp() / f"video_more_{name}", suffix, blob)


# -- what the fuzzing found --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, tag, unknown", [("mp4_h264", b"avc1", b"avcX"), ("mkv_h264", b"V_MPEG4/ISO/AVC", b"V_MPEG4/ISO/AVX")])
def test_a_video_stream_of_a_codec_ffmpeg_does_not_know_is_refused(worker, tmp_path, name, tag, unknown):
    """A video stream whose codec FFmpeg does not know (its tag damaged, or a codec this FFmpeg lacks) has no codec
    context in PyAV: opening it raised an AttributeError, a bug (exit 1), where the file is to be named."""
    suffix, seed = SEEDS[name]
    path = tmp_path / f"video{suffix}"
    path.write_bytes(seed.replace(tag, unknown))
    said = worker.read(path)
    assert set(said) == {"refused"} and said["refused"].startswith(f"{path}: ") and "codec" in said["refused"], said
