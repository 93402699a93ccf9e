"""``pcreg run`` on 640x480 frames, everything included: frames a second, and on a slow disk.

The CamVid clip ``--clip`` resized to 640x480 and written as PNG files, ``--times`` times over (the
clip again after its last frame: a cut back to its start each time), is labelled from its first frame's
labels by ``pcreg run`` as a subprocess, ``--repeats`` times. Each run gives two rates: the whole
command's (start-up, fitting, decoding, the steps and every output: label PNGs, ``steps.jsonl``, the
carry and ``run.json`` each frame) and its loop's, from the label PNGs' modification times (start-up
left out). ``--fsync-ms MS`` adds MS milliseconds to every ``os.fsync`` of the run, as a slow or network
disk would, to show what writing beside the step saves there. ``--key-every N`` labels the frames from
key frames instead (``--labels FOLDER``: every N-th frame's labels and the last frame's), each frame
between two key frames labelled from both (two steps a frame).

    python tools/bench_run.py --out out/bench [--times 1] [--repeats 5] [--fsync-ms 0] [--key-every 0] [--scale 1]
        [--model dense|flow] [--preset medium]
    python tools/bench_run.py --davis ../shared/data/davis/goat [--follow object] --out out/bench_davis

``--davis SEQ`` runs on a DAVIS sequence at its own size (854x480; ``SEQ/images``, the first mask of
``SEQ/labels``, ``--mapping davis``) instead, ``--follow object`` following its object; its target is
100 ms a frame, everything included (10 frames a second, the whole command, median of the runs).

Writes bench_run.json and bench_run.md; the target of a run from one key frame (15 frames a second, the
whole command, median of the runs) is in its checks table.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import SHARED_DATA, checks_markdown, machine_info, write_report

TARGET_FPS = 15.0
SIZE = (640, 480)

#: The run, in a Python that first slows every fsync by ``sys.argv[1]`` ms (0: as it is).
_RUN = ("import os, sys, time\n"
        "delay = float(sys.argv[1]) / 1000.0\n"
        "if delay > 0:\n"
        "    real = os.fsync\n"
        "    def slow(fd):\n"
        "        time.sleep(delay)\n"
        "        return real(fd)\n"
        "    os.fsync = slow\n"
        "from pcreg.cli import main\n"
        "raise SystemExit(main(sys.argv[2:]))\n")


def write_frames(clip: Path, work: Path, times: int) -> tuple[Path, Path, int]:
    """The clip at 640x480 as PNG files, ``times`` times over, and its first frame's labels."""
    import cv2

    from pcreg.datasets import load_folder

    frames = load_folder(clip)
    folder = work / "frames"
    folder.mkdir(parents=True)
    i = 0
    for _ in range(times):
        for f in frames:
            cv2.imwrite(str(folder / f"{i:05d}.png"), cv2.resize(f.image[:, :, ::-1], SIZE, interpolation=cv2.INTER_LINEAR))
            i += 1
    key = work / "key.png"
    cv2.imwrite(str(key), cv2.resize(frames[0].labels, SIZE, interpolation=cv2.INTER_NEAREST))
    return folder, key, i


def write_keys(clip: Path, work: Path, n: int, every: int) -> tuple[Path, int]:
    """A labels folder of key frames for the ``n`` frames :func:`write_frames` wrote: every ``every``-th
    frame from the first, and the last; returns it and how many key frames it holds."""
    import cv2

    from pcreg.datasets import load_folder

    frames = load_folder(clip)
    folder = work / "keys"
    folder.mkdir(parents=True)
    chosen = sorted(set(range(0, n, every)) | {n - 1})
    for i in chosen:
        labels = frames[i % len(frames)].labels
        cv2.imwrite(str(folder / f"{i:05d}.png"), cv2.resize(labels, SIZE, interpolation=cv2.INTER_NEAREST))
    return folder, len(chosen)


def run_once(folder: Path, key: Path, out: Path, fsync_ms: float, keys: int = 1, scale: float = 1.0,
             options: tuple[str, ...] = ()) -> tuple[float, float]:
    """``(seconds of the whole command, frames a second of its loop)``; a failure stops the benchmark.
    ``key``: a label image, or a folder of ``keys`` key frames' labels (written first, left out of the loop);
    ``scale``: ``pcreg run --scale``; ``options``: more of pcreg run's arguments."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _RUN, str(fsync_ms), "run", str(folder), "--labels", str(key),
                        "--out", str(out), *(["--scale", f"{scale:g}"] if scale != 1 else []), *options],
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"pcreg run failed ({p.returncode}): {p.stderr.strip()}")
    stamps = sorted(q.stat().st_mtime for q in out.glob("*.png"))[keys:]  # the key frames' labels come first
    return seconds, (len(stamps) - 1) / (stamps[-1] - stamps[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--data", default=str(SHARED_DATA / "camvid"))
    ap.add_argument("--clip", default="0016E5")
    ap.add_argument("--times", type=int, default=1, help="the clip this many times over (default 1)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--fsync-ms", type=float, default=0.0, help="milliseconds added to every fsync (default 0)")
    ap.add_argument("--key-every", type=int, default=0,
                    help="label from key frames every N frames and the last (--labels FOLDER) instead of the first")
    ap.add_argument("--scale", type=float, default=1.0, help="pcreg run's --scale (default 1: full size)")
    ap.add_argument("--model", default="dense", help="pcreg run's --model (default dense)")
    ap.add_argument("--preset", default=None, help="pcreg run's --preset, with --model flow")
    ap.add_argument("--davis", default=None, metavar="SEQ", help="a DAVIS sequence (SEQ/images, SEQ/labels) instead")
    ap.add_argument("--follow", default="scene", help="pcreg run's --follow (default scene)")
    args = ap.parse_args(argv)
    options = ("--model", args.model, *(("--preset", args.preset) if args.preset else ()), "--follow", args.follow)
    clip = Path(args.davis) if args.davis else Path(args.data) / args.clip
    if not clip.is_dir():
        print(f"{clip} not found: the benchmark needs the shared CamVid clips or a DAVIS sequence", file=sys.stderr)
        return 2
    target, what = (10.0, f"DAVIS {clip.name} at its own size") if args.davis else (TARGET_FPS, f"CamVid {args.clip} at 640x480")
    with tempfile.TemporaryDirectory() as tmp:
        if args.davis:
            images = sorted((clip / "images").glob("*.jpg"))
            folder, key, n = clip / "images", clip / "labels" / f"{images[0].stem}.png", len(images)
            options += ("--mapping", "davis")
        else:
            folder, key, n = write_frames(clip, Path(tmp), max(1, args.times))
        keys = 1
        if args.key_every > 0 and not args.davis:
            key, keys = write_keys(clip, Path(tmp), n, args.key_every)
        runs = [run_once(folder, key, Path(tmp) / "out", args.fsync_ms, keys, args.scale, options)
                for _ in range(max(1, args.repeats))]
    whole = [(n - keys) / s for s, _ in runs]
    loop = [r for _, r in runs]
    report = {"machine": machine_info(), "clip": clip.name, "follow": args.follow, "frames": n, "key_frames": keys, "fsync_ms": args.fsync_ms, "scale": args.scale,
              "model": args.model, "preset": args.preset,
              "whole_fps": whole, "loop_fps": loop, "median_whole_fps": float(np.median(whole)),
              "median_loop_fps": float(np.median(loop))}
    md = (f"## `pcreg run` on {n} frames of {what}"
          f"{f', from {keys} key frames (every {args.key_every}th and the last)' if args.key_every > 0 else ''}"
          f"{f', every fsync {args.fsync_ms:g} ms slower' if args.fsync_ms else ''}"
          f"{f', --scale {args.scale:g}' if args.scale != 1 else ''}"
          f"{f', --model {args.model}' if args.model != 'dense' else ''}{f' --preset {args.preset}' if args.preset else ''}"
          f"{f', --follow {args.follow}' if args.follow != 'scene' else ''}\n\n"
          f"| run | frames a second, the whole command | frames a second, its loop |\n|---|---|---|\n"
          + "".join(f"| {i + 1} | {w:.1f} | {r:.1f} |\n" for i, (w, r) in enumerate(zip(whole, loop)))
          + f"| **median** | **{report['median_whole_fps']:.1f}** | **{report['median_loop_fps']:.1f}** |\n\n"
          + (checks_markdown([(f"the whole command at {target:g} frames a second or more (median)",
                               f"{report['median_whole_fps']:.1f}", report["median_whole_fps"] >= target)])
             if keys == 1 else ""))
    write_report(args.out, "bench_run", report, md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
