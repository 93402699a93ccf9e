"""``pcreg run`` on a video file against the same frames in a folder: labels, peak memory, frame rate.

Three measurements, each ``pcreg run`` as a subprocess (its peak resident memory from ``os.wait4``):

- **accuracy**: a CamVid clip (``--clip``, its first ``--frames``) written to an MP4 file with OpenCV's
  writer (``mp4v``, lossy), run from the file and from the folder, both scored against the clip's truth
  labels (the video's through ``--truth`` with the maps linked as ``{i:06d}.png``); the target: the video's
  error within 0.5 points of the folder's;
- **memory**: the clip resized to 640x480 and played forwards and backwards into a ``--long`` frame and a
  ``--short`` frame video, each run with ``--every STRIDE`` (every frame decoded, one in ``--stride``
  labelled; 1, every frame, by default); the target: the long run's peak memory within 10% of the short run's;
- **speed**: the first ``--speed-frames`` frames of the 640x480 video against the same frames written
  as PNG files (decoded from the video, so the pixels are the same), run alternately ``--repeats``
  times each; the loop's frame rate from the label PNGs' modification times (start-up left out); the
  target: the video at no less than 0.9x the folder's frame rate (medians).

    python tools/bench_video.py --out out/bench --work /tmp/bench-video

Writes bench_video.json and bench_video.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import SHARED_DATA, checks_markdown, machine_info, write_report

PCREG = [sys.executable, "-m", "pcreg", "run"]


def _run(args: list[str]) -> tuple[float, int]:
    """Wall seconds and peak resident memory (MiB) of ``pcreg ARGS``; a failure stops the benchmark."""
    t0 = time.perf_counter()
    p = subprocess.Popen([*PCREG, *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    seconds = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    err = p.stderr.read().decode() if p.stderr else ""
    if p.returncode != 0:
        raise SystemExit(f"pcreg {' '.join(map(str, args))} failed ({p.returncode}): {err.strip()}")
    return seconds, usage.ru_maxrss // 1024


def _write_video(path: Path, frames, size: tuple[int, int], fps: float = 30.0) -> None:
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    if not writer.isOpened():
        raise SystemExit(f"OpenCV cannot write {path}")
    for rgb in frames:
        writer.write(np.ascontiguousarray(rgb[:, :, ::-1]))
    writer.release()


def _clip(clip: Path, n: int):
    import cv2

    images = sorted((clip / "images").glob("*.png"))[:n]
    if len(images) < 2:
        raise SystemExit(f"{clip}: no CamVid clip there")
    return images, [cv2.imread(str(p))[:, :, ::-1] for p in images]


def _error(out: Path) -> float:
    return float(json.loads((out / "run.json").read_text())["truth"]["error"])


def accuracy(clip: Path, n: int, work: Path) -> dict:
    images, rgb = _clip(clip, n)
    h, w = rgb[0].shape[:2]
    video = work / "clip.mp4"
    _write_video(video, rgb, (w, h))
    truth = work / "truth"
    shutil.rmtree(truth, ignore_errors=True)
    truth.mkdir()
    for i, p in enumerate(images):
        (truth / f"{i:06d}.png").symlink_to(clip / "labels" / p.name)
    folder = work / "frames"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    for p in images:
        (folder / p.name).symlink_to(p)
    key = clip / "labels" / images[0].name
    common = ["--labels", key, "--mapping", "camvid", "--force"]
    _run([folder, *common, "--truth", clip / "labels", "--out", work / "acc-folder"])
    _run([video, *common, "--truth", truth, "--out", work / "acc-video"])
    e_folder, e_video = _error(work / "acc-folder"), _error(work / "acc-video")
    return {"clip": clip.name, "frames": len(images), "size": [w, h], "video_bytes": video.stat().st_size,
            "error_folder": e_folder, "error_video": e_video, "difference": e_video - e_folder}


def _big_frames(clip: Path, n: int, count: int):
    """``count`` 640x480 frames: the clip's first ``n`` resized, forwards and backwards (a generator)."""
    import cv2

    _, rgb = _clip(clip, n)
    rgb = [cv2.resize(f, (640, 480), interpolation=cv2.INTER_AREA) for f in rgb]
    cycle = rgb + rgb[-2:0:-1]
    for i in range(count):
        yield cycle[i % len(cycle)]


def _key(clip: Path, work: Path) -> Path:
    import cv2

    first = sorted((clip / "labels").glob("*.png"))[0]
    lab = cv2.resize(cv2.imread(str(first), cv2.IMREAD_UNCHANGED), (640, 480), interpolation=cv2.INTER_NEAREST)
    path = work / "key640.png"
    cv2.imwrite(str(path), lab)
    return path


def memory(clip: Path, n: int, work: Path, short: int, long: int, stride: int) -> dict:
    key = _key(clip, work)
    rows = {}
    for count in (short, long):
        video = work / f"loop{count}.mp4"
        _write_video(video, _big_frames(clip, n, count), (640, 480))
        seconds, mib = _run([video, "--labels", key, "--mapping", "camvid", "--every", stride, "--force",
                             "--out", work / f"mem{count}"])
        rows[str(count)] = {"frames": count, "labelled": -(-count // stride), "peak_mib": mib, "seconds": seconds}
    return {"stride": stride, "runs": rows, "ratio": rows[str(long)]["peak_mib"] / rows[str(short)]["peak_mib"]}


def speed(clip: Path, n: int, work: Path, frames: int, repeats: int) -> dict:
    import cv2

    from pcreg.datasets.sources import Selection, VideoFrames

    key = _key(clip, work)
    video = work / f"speed{frames}.mp4"
    _write_video(video, _big_frames(clip, n, frames), (640, 480))
    folder = work / "speed-frames"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    for f in VideoFrames(video, Selection()).frames():
        cv2.imwrite(str(folder / f"{f.name}.png"), np.ascontiguousarray(f.image[:, :, ::-1]))
    rates: dict[str, list[float]] = {"video": [], "folder": []}
    for _ in range(repeats):
        for what, src in (("video", video), ("folder", folder)):
            out = work / f"speed-{what}"
            _run([src, "--labels", key, "--mapping", "camvid", "--force", "--out", out])
            rates[what].append(_loop_rate(out))
    fps = {k: float(np.median(v)) for k, v in rates.items()}
    return {"frames": frames, "frames_per_second": rates, "fps": fps, "ratio": fps["video"] / fps["folder"]}


def _loop_rate(out: Path) -> float:
    """Frames a second of the run's loop (reading, the step, writing), from the label PNGs' modification
    times: the frames after the first step over the time between its label and the last (start-up and
    the key frame left out)."""
    times = sorted(p.stat().st_mtime for p in out.glob("*.png"))[1:]  # the key frame's labels are written first
    return (len(times) - 1) / (times[-1] - times[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--work", default="/tmp/bench-video", help="where the videos and runs go")
    ap.add_argument("--data", default=str(SHARED_DATA / "camvid"))
    ap.add_argument("--clip", default="0016E5")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--short", type=int, default=200)
    ap.add_argument("--long", type=int, default=2000)
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--speed-frames", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--only", choices=("accuracy", "memory", "speed"), action="append")
    a = ap.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    clip = Path(a.data) / a.clip
    only = set(a.only or ("accuracy", "memory", "speed"))
    report: dict = {"machine": machine_info()}
    checks = []
    if "accuracy" in only:
        r = report["accuracy"] = accuracy(clip, a.frames, work)
        checks.append((f"{r['clip']} from an MP4 file within 0.5 points of the folder",
                       f"{r['error_video']:.2f}% against {r['error_folder']:.2f}% ({r['difference']:+.2f})",
                       abs(r["difference"]) <= 0.5))
    if "memory" in only:
        r = report["memory"] = memory(clip, a.frames, work, a.short, a.long, a.stride)
        runs = r["runs"]
        labelled = "every frame labelled" if a.stride == 1 else f"one frame in {a.stride} labelled"
        checks.append((f"peak memory, {a.long} frames within 10% of {a.short} (640x480, {labelled})",
                       f"{runs[str(a.long)]['peak_mib']} MiB against {runs[str(a.short)]['peak_mib']} MiB "
                       f"({r['ratio']:.3f}x)", r["ratio"] <= 1.10))
    if "speed" in only:
        r = report["speed"] = speed(clip, a.frames, work, a.speed_frames, a.repeats)
        checks.append(("640x480 video at no less than 0.9x the folder's frame rate",
                       f"{r['fps']['video']:.2f} against {r['fps']['folder']:.2f} frames/s ({r['ratio']:.3f}x)",
                       r["ratio"] >= 0.9))
    md = "## pcreg run: a video file against a folder of frames\n\n" + checks_markdown(checks)
    write_report(a.out, "bench_video", report, md)
    print(md)
    return 0 if all(ok for _, _, ok in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
