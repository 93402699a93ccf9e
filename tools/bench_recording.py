"""Cost of recording: time added to a per-frame pipeline (a ratio measured in the same run) and the size
of a 100-frame 640x480 recording with JPEG frames.

Each frame runs a realistic pipeline on a pair of 640x480 frames (i, i+1) -- edge cloud, registration,
warp, valid mask, per-pixel Gaussian naive Bayes, error rates -- once without and once with a
:class:`pcreg.recording.recorder.Recorder` logging everything a sequence evaluation logs per frame (reference,
moving and warped images as JPEG, valid mask, both clouds, the transform, truth and predicted labels,
errors). Runs alternate off/on ``--repeats`` times; the ratio is median(on) / median(off).

Frames: CamVid ``0016E5`` from ``../shared/data`` resized to 640x480 (real texture, so JPEG sizes are
realistic), else smooth synthetic frames. Workload ``cv2`` registers with OpenCV's multi-scale ECC
(stable, ~the cost of a subsampled ICP); ``register`` uses ``pcreg.register`` (reference ICP).

    python tools/bench_recording.py --out out/bench [--frames 100] [--repeats 3] [--workload cv2]

Writes ``recording.json`` and ``recording.md`` to ``--out``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pcreg._io import atomic_write_json, atomic_write_text, markdown_table  # noqa: E402
from pcreg.recording.recorder import DEFAULT_JPEG_QUALITY, Recorder  # noqa: E402

CAMVID = ROOT.parent / "shared" / "data" / "camvid" / "0016E5"
CAMVID_TO_LAGR = np.array([2, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 2] + [2] * 244, np.uint8)
W, H = 640, 480


def load_frames(n: int, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray], str]:
    """``n + 1`` RGB frames (H, W, 3) uint8 and their labels (H, W) uint8 (0 ground, 1 obstacle, 2 unknown)."""
    if (CAMVID / "images").is_dir():
        names = sorted((CAMVID / "images").glob("*.png"))
        imgs, labs = [], []
        for name in names:
            img = cv2.cvtColor(cv2.imread(str(name), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            lab = CAMVID_TO_LAGR[cv2.imread(str(CAMVID / "labels" / name.name), cv2.IMREAD_GRAYSCALE)]
            imgs.append(cv2.resize(img, (W, H), interpolation=cv2.INTER_LINEAR))
            labs.append(cv2.resize(lab, (W, H), interpolation=cv2.INTER_NEAREST))
        order = list(range(len(imgs))) + list(range(len(imgs) - 2, 0, -1))  # ping-pong keeps neighbours close
        idx = [order[i % len(order)] for i in range(n + 1)]
        return [imgs[i] for i in idx], [labs[i] for i in idx], f"CamVid 0016E5 ({len(names)} frames) resized to {W}x{H}"
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 255, (H * 2, W * 2, 3), dtype=np.uint8), (0, 0), 6)
    base = cv2.normalize(base, None, 0, 255, cv2.NORM_MINMAX)
    imgs, labs = [], []
    for i in range(n + 1):
        x, y = int(40 + 3 * i) % W, int(30 + 2 * i) % H
        img = np.ascontiguousarray(base[y:y + H, x:x + W])
        imgs.append(img)
        labs.append((img[..., 1] > img[..., 0]).astype(np.uint8))
    return imgs, labs, f"synthetic smooth noise {W}x{H}"


class Pipeline:
    """One frame's work: edge cloud, registration, warp, valid mask, naive Bayes, errors."""

    def __init__(self, train_image: np.ndarray, train_labels: np.ndarray, *, workload: str) -> None:
        from sklearn.naive_bayes import GaussianNB

        keep = train_labels.ravel() < 2
        x = train_image.reshape(-1, 3)[keep][::20].astype(np.float32)
        self.nb = GaussianNB().fit(x, train_labels.ravel()[keep][::20])
        self.workload = workload

    def cloud(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        edges = cv2.Canny(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), 80, 160)
        ys, xs = np.nonzero(edges)
        return np.column_stack([xs, ys]).astype(np.float64), image[ys, xs].astype(np.float32) / 255.0

    def register(self, reference: np.ndarray, moving: np.ndarray) -> np.ndarray:
        if self.workload == "register":
            import pcreg

            return np.asarray(pcreg.register(reference, moving, backend="reference").matrix)
        g_ref = cv2.cvtColor(reference, cv2.COLOR_RGB2GRAY).astype(np.float32)
        g_mov = cv2.cvtColor(moving, cv2.COLOR_RGB2GRAY).astype(np.float32)
        warp = np.eye(2, 3, dtype=np.float32)
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-4)
        try:
            _, warp = cv2.findTransformECCMultiScale(g_ref, g_mov, warp, cv2.MOTION_EUCLIDEAN, criteria, None, 4)
        except (cv2.error, TypeError):
            small_r, small_m = (cv2.resize(g, (W // 4, H // 4)) for g in (g_ref, g_mov))
            _, warp = cv2.findTransformECC(small_r, small_m, warp, cv2.MOTION_EUCLIDEAN, criteria, None, 5)
            warp[:, 2] *= 4
        # ECC's warp maps reference pixels to moving pixels: T_mov_ref; invert for T_ref_mov
        t_mov_ref = np.vstack([warp.astype(np.float64), [0, 0, 1]])
        return np.linalg.inv(t_mov_ref)

    def frame(self, reference, moving, truth, recorder: Recorder | None, index: int) -> dict:
        ref_pts, ref_cols = self.cloud(reference)
        mov_pts, mov_cols = self.cloud(moving)
        matrix = self.register(reference, moving)
        warped = cv2.warpPerspective(moving, matrix, (W, H), flags=cv2.INTER_LINEAR)
        valid = cv2.warpPerspective(np.ones((H, W), np.uint8), matrix, (W, H), flags=cv2.INTER_NEAREST) > 0
        plain = self.nb.predict(moving.reshape(-1, 3).astype(np.float32)).reshape(H, W).astype(np.uint8)
        registered = self.nb.predict(warped.reshape(-1, 3).astype(np.float32)).reshape(H, W).astype(np.uint8)
        known = truth < 2
        errors = {"plain": float((plain != truth)[known].mean()),
                  "registered": float((registered != truth)[known & valid].mean())}
        if recorder is not None:
            recorder.set_frame(index)
            recorder.log_images(reference=reference, moving=moving, warped=warped, valid_mask=valid)
            recorder.log_clouds(reference_points=ref_pts, reference_colors=ref_cols,
                                moving_points=mov_pts, moving_colors=mov_cols)
            recorder.log_transform(matrix)
            recorder.log_labels(truth=truth, predicted=registered)
            recorder.log_errors(errors)
        return errors


def run_once(pipe: Pipeline, imgs, labs, recorder: Recorder | None) -> float:
    t0 = time.perf_counter()
    for i in range(len(imgs) - 1):
        pipe.frame(imgs[i], imgs[i + 1], labs[i], recorder, i)
    if recorder is not None:
        recorder.close()  # the file is complete when the run ends: count its flush
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench", help="folder for recording.json / recording.md (default out/bench)")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workload", choices=("cv2", "register"), default="cv2")
    ap.add_argument("--jpeg-quality", type=int, default=DEFAULT_JPEG_QUALITY)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    imgs, labs, source = load_frames(args.frames)
    pipe = Pipeline(imgs[0], labs[0], workload=args.workload)
    pipe.frame(imgs[0], imgs[1], labs[0], None, 0)  # warm-up (imports, caches)
    off, on, sizes = [], [], []
    with tempfile.TemporaryDirectory(dir=out) as tmp:
        for r in range(args.repeats):
            off.append(run_once(pipe, imgs, labs, None))
            path = Path(tmp) / f"run{r}.rrd"
            rec = Recorder(path, recording_name=f"bench {r}", jpeg_quality=args.jpeg_quality)
            on.append(run_once(pipe, imgs, labs, rec))
            sizes.append(path.stat().st_size)
        # what each logged thing costs in bytes: one recording per kind, same frames
        parts = {}
        for kind in ("images", "labels", "clouds"):
            path = Path(tmp) / f"{kind}.rrd"
            with Recorder(path, blueprint=False, jpeg_quality=args.jpeg_quality) as rec:
                for i in range(args.frames):
                    rec.set_frame(i)
                    if kind == "images":
                        rec.log_images(reference=imgs[i], moving=imgs[i + 1], warped=imgs[i + 1])
                    elif kind == "labels":
                        rec.log_labels(truth=labs[i], predicted=labs[i + 1])
                    else:
                        p, c = pipe.cloud(imgs[i])
                        rec.log_clouds(reference_points=p, reference_colors=c, moving_points=p, moving_colors=c)
            parts[kind] = path.stat().st_size / 1e6

    t_off, t_on = statistics.median(off), statistics.median(on)
    result = {
        "frames": args.frames,
        "size": f"{W}x{H}",
        "source": source,
        "workload": args.workload,
        "jpeg_quality": args.jpeg_quality,
        "repeats": args.repeats,
        "seconds_off": off,
        "seconds_on": on,
        "ms_per_frame_off": 1e3 * t_off / args.frames,
        "ms_per_frame_on": 1e3 * t_on / args.frames,
        "overhead_ratio": t_on / t_off,
        "recording_mb": statistics.median(sizes) / 1e6,
        "recording_mb_parts": parts,
        "floors": {"overhead_ratio_max": 1.10, "recording_mb_max": 15.0},
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}",
        "command": "python tools/bench_recording.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    result["pass"] = result["overhead_ratio"] <= 1.10 and result["recording_mb"] <= 15.0
    atomic_write_json(out / "recording.json", result)
    md = [
        "# Recording cost\n",
        f"`{result['command']}` on {result['machine']}; frames: {source}; workload: {args.workload}; "
        f"JPEG quality {args.jpeg_quality}; median of {args.repeats} alternating runs.\n",
        markdown_table(
            ["frames", "ms/frame off", "ms/frame on", "ratio on/off", "MB per recording"],
            [[args.frames, result["ms_per_frame_off"], result["ms_per_frame_on"], result["overhead_ratio"],
              result["recording_mb"]]],
            digits=3,
        ),
        "\nBytes by kind (MB for the same frames, recorded alone): "
        + ", ".join(f"{k} {v:.2f}" for k, v in parts.items()) + ".\n",
        f"\nFloors: ratio <= 1.10, size <= 15 MB per 100 frames: {'met' if result['pass'] else 'NOT met'}.\n",
    ]
    atomic_write_text(out / "recording.md", "".join(md))
    print("".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
