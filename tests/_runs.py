"""What the tests of `pcreg run` share: its one-line errors, its steps without their clocks, a run killed
after a frame's files were written but before run.json counted it, a run killed at its n-th commit, and a
folder of frames to run on, small drifting frames with their key labels, and a command run in a terminal."""

from __future__ import annotations

import json


def one_line_errors(capsys) -> list[str]:
    """The lines the command printed on stderr."""
    return capsys.readouterr().err.strip().splitlines()


def timeless(line: str) -> dict:
    """A steps.jsonl line without what differs from run to run (its clocks, and the frame file's modification time)."""
    step = json.loads(line)
    step.pop("times")
    step.pop("mtime_ns", None)
    step["registration"].pop("seconds")
    return step


def _kill(*args, **kwargs):
    raise KeyboardInterrupt


def kill_at_commit(monkeypatch, n: int, phase: str) -> None:
    """Make a run stop (as at Ctrl-C) at its ``n``-th commit, which must be one of its ``phase``
    (``run.json``'s cursor: ``"between"``, ``"backward"``, ...); ``monkeypatch.undo()`` lets the next run go on."""
    from pcreg.runs.run import Run

    real, count = Run.commit, [0]

    def crash(self):
        count[0] += 1
        if count[0] == n:
            assert self.state["cursor"]["phase"] == phase
            raise KeyboardInterrupt
        real(self)

    monkeypatch.setattr(Run, "commit", crash)


def kill_before_commit(monkeypatch, frame: int) -> None:
    """Make a one-key run stop (as at Ctrl-C) after ``frame``'s label PNG and step line are written and
    before run.json counts it; ``monkeypatch.undo()`` lets the next run go on."""
    import pcreg.outputs
    from pcreg.runs.run import Run

    real = Run.record

    def crash(self, t, labels, report, plain=None, **kw):
        if t == frame:
            monkeypatch.setattr(pcreg.outputs, "atomic_write_json", _kill)
        return real(self, t, labels, report, plain, **kw)

    monkeypatch.setattr(Run, "record", crash)


def stopped_and_resumed(monkeypatch, args: list, tmp_path, frame: int):
    """``(whole, cut)``: a one-key run's command ``args`` (without ``--out``) run whole into ``tmp_path/whole``, and
    into ``tmp_path/cut`` stopped after ``frame``'s files were written, before run.json counted them
    (:func:`kill_before_commit`), then run again there."""
    import json

    from pcreg.cli import main

    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main([*args, "--out", str(whole)]) == 0
    kill_before_commit(monkeypatch, frame)
    assert main([*args, "--out", str(cut)]) == 130
    monkeypatch.undo()
    assert json.loads((cut / "run.json").read_text())["done"] == frame
    assert main([*args, "--out", str(cut)]) == 0
    return whole, cut


def frames_folder(path, frames, keys=(0, 4)):
    """``(folder, keys)``: ``frames`` written as PNGs ``f0.png``, ``f1.png``, ... into ``path / "frames"``, and
    the labels of the frames ``keys`` under the same names into ``path / "keys"``."""
    import cv2

    folder, labels = path / "frames", path / "keys"
    folder.mkdir()
    labels.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i}.png"), f.image[:, :, ::-1])
    for k in keys:
        cv2.imwrite(str(labels / f"f{k}.png"), frames[k].labels)
    return folder, labels


def assert_same_run(whole, cut, frames: int) -> None:
    """Two run folders hold the same labels and confidence PNGs, byte for byte, of frames ``f1`` ..
    ``f{frames - 1}``, and the same steps but for their clocks: an interrupted run resumed as the whole one."""
    for i in range(1, frames):
        frame = f"f{i:0{len(str(frames - 1))}d}.png"  # as drifting_frames names them
        for name in (frame, f"confidence/{frame}"):
            assert (whole / name).read_bytes() == (cut / name).read_bytes(), name
    steps = [[timeless(line) for line in (run / "steps.jsonl").read_text().splitlines()] for run in (whole, cut)]
    assert steps[0] == steps[1]


def drifting_frames(folder, shape=(48, 64), n=4, seed=0):
    """``n`` frames of a textured scene drifting right by 1 px a frame, written into ``folder`` (made here) as
    ``f0.png``, ``f1.png``, ... (numbers zero-padded from 11 frames on), and the key frame's labels beside it:
    ``(folder, key.png)``."""
    import cv2
    import numpy as np

    h, w = shape
    rng = np.random.default_rng(seed)
    scene = cv2.GaussianBlur(rng.integers(0, 256, (h, w + n, 3), dtype=np.uint8), (0, 0), 1.5)
    folder.mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / f"f{i:0{len(str(n - 1))}d}.png"), np.ascontiguousarray(scene[:, n - i:n - i + w]))
    labels = (np.arange(h)[:, None] * np.ones((1, w)) > h / 2).astype(np.uint8)
    cv2.imwrite(str(folder.parent / "key.png"), labels)
    return folder, folder.parent / "key.png"


def key_frames_of(key, keys, positions=(0, 4)):
    """A folder ``keys`` (made here) of key labels: the label image ``key`` as the frames ``f{i}`` of ``positions``."""
    import cv2

    keys.mkdir()
    labels = cv2.imread(str(key), cv2.IMREAD_UNCHANGED)
    for i in positions:
        cv2.imwrite(str(keys / f"f{i}.png"), labels)
    return keys


#: Two CamVid classes, as a ``labelmap.txt`` names them (``colour_keys``' colours).
ROAD_AND_CAR = "background:0,0,0::\nroad:128,64,128::\ncar:0,0,192::\n"


def colour_keys(keys, shape=(48, 64)):
    """A folder ``keys`` (made here) holding ``f0.png``: colour labels, road over car in CamVid's colours."""
    import cv2
    import numpy as np

    keys.mkdir()
    rgb = np.zeros((*shape, 3), np.uint8)
    rgb[: shape[0] // 2], rgb[shape[0] // 2:] = (128, 64, 128), (0, 0, 192)
    cv2.imwrite(str(keys / "f0.png"), rgb[:, :, ::-1])
    return keys


def in_a_terminal(args: list[str]) -> tuple[int, str]:
    """``python -m pcreg ARGS`` with its stdout and stderr a terminal 100 columns wide, as a person runs it:
    its exit code and everything the terminal received."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import sys
    import termios

    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 100, 0, 0))
    p = subprocess.Popen([sys.executable, "-m", "pcreg", *args], stdin=subprocess.DEVNULL, stdout=follower,
                         stderr=follower, close_fds=True)
    os.close(follower)
    seen = b""
    while True:
        try:
            chunk = os.read(leader, 65536)
        except OSError:  # EIO: the program ended and closed the terminal
            break
        if not chunk:
            break
        seen += chunk
    os.close(leader)
    return p.wait(timeout=120), seen.decode("utf-8", "replace")




def killed_mid_write(path):
    """The temporary file a process killed (SIGKILL) while writing ``path`` through
    :func:`pcreg.outputs.atomic_file` leaves beside it: a real writer, killed once it has written a part."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    path = Path(path)
    before = set(path.parent.glob(f".{path.name}.*.tmp"))
    code = ("import sys; from pcreg.outputs import atomic_file\n"
            "with atomic_file(sys.argv[1]) as fh:\n"
            "    fh.write(b'PK' * 4096); fh.flush(); print('written', flush=True); sys.stdin.read()\n")
    with subprocess.Popen([sys.executable, "-c", code, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                          text=True) as proc:
        assert proc.stdout.readline() == "written\n"
        proc.send_signal(signal.SIGKILL)
        assert proc.wait() == -signal.SIGKILL
    [tmp] = set(path.parent.glob(f".{path.name}.*.tmp")) - before
    assert tmp.stat().st_size == 8192
    return tmp


def write_video(path, frames, fourcc: str = "mp4v"):
    """``frames`` (objects with an RGB ``image``, all of one size) written to a video at ``path`` (``mp4v`` in MP4,
    ``MJPG`` in AVI) at 10 frames a second: ``path``."""
    import cv2
    import numpy as np

    h, w = frames[0].image.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (w, h))
    for f in frames:
        writer.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    writer.release()
    return path


def video_and_keys(tmp_path, n: int, positions):
    """A synthetic ``n``-frame 96x72 MJPG video in ``tmp_path`` and a folder ``keys`` there of its frames' labels at
    ``positions`` (``000006.png`` for frame 6): (the frames, the video, the folder)."""
    import cv2

    import pcreg

    frames = pcreg.synthetic("syn1a", n, 0, width=96, height=72)
    video = write_video(tmp_path / "clip.avi", frames, "MJPG")
    keys = tmp_path / "keys"
    keys.mkdir()
    for i in positions:
        cv2.imwrite(str(keys / f"{i:06d}.png"), frames[i].labels)
    return frames, video, keys


def video_run(tmp_path, frames: int = 3):
    """``pcreg run`` of a synthetic ``frames``-frame 96x72 MP4 in ``tmp_path`` from its first frame's labels:
    (the video, the run's folder)."""
    import contextlib
    import io

    import cv2

    import pcreg
    from pcreg.cli import main

    synthetic = pcreg.synthetic("syn1a", frames, 0, width=96, height=72)
    video = write_video(tmp_path / "clip.mp4", synthetic)
    cv2.imwrite(str(tmp_path / "key.png"), synthetic[0].labels)
    out = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(video), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 0
    return video, out
