"""What a stretch between two key frames keeps on disk a frame, and the time to write and read it back, for
each way of keeping it, against the time of a step.

One CamVid clip's frames resized to ``--size`` (from 480x360), its first frame the key frame; the propagator
steps through ``--frames`` frames with CamVid's eleven classes (``camvid11``) and with two (ground and
obstacle), and each step's prior term (float16) and summed trust weight are kept, as the forward pass of a
stretch keeps them. Each candidate writes each frame's prior term (and the frame itself, as a video's stretch
keeps it) into a file of ``--tmp`` and reads it back, checked equal to the bit; sizes are means a frame, times
medians.

    python tools/bench_keys_disk.py --out out/bench [--size 640x480] [--frames 12] [--clip 0001TP]

Writes bench_keys_disk.json and bench_keys_disk.md.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from benchlib import SHARED_DATA, machine_info

sys.path.insert(0, str(Path(__file__).parent))
from bench_classes import CAMVID_TO_LAGR  # noqa: E402


def load_clip(name: str, size: tuple[int, int]):
    """A clip's images (RGB) and labels at ``size``: images resized with bicubic interpolation (a frame made
    larger than the clip's 480x360 by repeating its pixels would compress better than a camera's frame of that
    size), labels with the nearest."""
    import cv2

    folder = SHARED_DATA / "camvid" / name
    if not folder.is_dir():
        sys.exit(f"{folder} is absent: this benchmark reads the shared CamVid clips")
    images, labels = [], []
    for p in sorted((folder / "images").iterdir()):
        im = cv2.resize(cv2.imread(str(p)), size, interpolation=cv2.INTER_CUBIC)
        lab = cv2.resize(cv2.imread(str(folder / "labels" / p.name), cv2.IMREAD_UNCHANGED), size,
                         interpolation=cv2.INTER_NEAREST)
        images.append(np.ascontiguousarray(im[:, :, ::-1]))
        labels.append(lab)
    return images, labels


def _npz(kept: dict, compressed: bool) -> tuple:
    def write(path: Path) -> None:
        buf = io.BytesIO()
        (np.savez_compressed if compressed else np.savez)(buf, **kept)
        path.write_bytes(buf.getvalue())

    def read(path: Path) -> dict:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    return write, read


def _pack(kept: dict, delta: bool) -> tuple:
    from pcreg.runs.kept import pack, unpack

    def write(path: Path) -> None:
        path.write_bytes(pack(kept, delta=delta))

    def read(path: Path) -> dict:
        return unpack(path.read_bytes())

    return write, read


def _png(image: np.ndarray, level: int) -> tuple:
    import cv2

    def write(path: Path) -> None:
        path.write_bytes(cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, level])[1].tobytes())

    def read(path: Path) -> dict:
        return {"image": cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)}

    return write, read


PRIORS = {"npz (uncompressed, before)": lambda kept: _npz(kept, False),
          "npz compressed (zlib 6)": lambda kept: _npz(kept, True),
          "shuffle + zlib 1": lambda kept: _pack(kept, False),
          "delta + shuffle + zlib 1 (chosen)": lambda kept: _pack(kept, True)}
FRAMES = {"npy (uncompressed, before)": lambda im: _npz({"image": im}, False),
          "delta + zlib 1 (chosen)": lambda im: _pack({"image": im}, True),
          "PNG level 1": lambda im: _png(im, 1),
          "PNG level 3": lambda im: _png(im, 3)}


def measure(kepts: list[dict], ways: dict, tmp: Path) -> dict:
    """{way: (mean bytes a frame, median write+read ms)}, each read checked equal to what was written."""
    out = {}
    for name, way in ways.items():
        sizes, times = [], []
        for i, kept in enumerate(kepts):
            write, read = way(kept if "image" not in kept else kept["image"])
            path = tmp / f"k{i}"
            t0 = time.perf_counter()
            write(path)
            back = read(path)
            times.append(1000 * (time.perf_counter() - t0))
            sizes.append(path.stat().st_size)
            for key, a in kept.items():
                assert back[key].dtype == a.dtype and back[key].shape == a.shape, (name, key)
                assert back[key].tobytes() == np.ascontiguousarray(a).tobytes(), (name, key)
        out[name] = (float(np.mean(sizes)), float(np.median(times)))
    return out


def steps(images, labels, classes) -> tuple[list[dict], float]:
    """The kept prior terms of a forward pass through ``images`` from the first, and its median step (ms)."""
    from pcreg.pipeline.engine import PRIOR_STORE_DTYPE
    from pcreg.pipeline.multiclass import weight_sum
    from pcreg.pipeline.stream import Propagator

    prop = Propagator.from_key_frame(images[0], labels, classes=classes)
    kepts, times = [], []
    for i, image in enumerate(images[1:]):
        prop.step(image)
        report = prop.last
        kept = {"prior": report.trust.prior_term(report.log_odds.shape).astype(PRIOR_STORE_DTYPE),
                "fallback": np.asarray(bool(report.fallback))}
        if prop.classes is not None:
            kept["weight"] = weight_sum(report.trust).astype(PRIOR_STORE_DTYPE)
        kepts.append(kept)
        if i:
            times.append(1000 * report.times["total"])  # the first step compiles
    return kepts, float(np.median(times))


#: The rule: the smallest way whose write + read takes at most this share of the time labelling its frame takes
#: (the frame's forward and backward steps, with its own classes; a video's frame, with two classes, the faster),
#: a way less than :data:`SMALLER` smaller than a faster one counting as no smaller.
SHARE = 1 / 3
SMALLER = 0.10


def render(report: dict) -> list[str]:
    """The report's table: each way's size, its time, and its time as a share of labelling the frame."""
    lines = [f"## What a stretch keeps on disk at {report['size']} ({report['frames']} frames of {report['clip']})", "",
             "| what | way | kB a frame | write + read ms | share of the frame's two steps |", "|---|---|---|---|---|"]
    for what, ways, step in (("prior, two classes", report["two"]["prior"], report["two"]["step_ms"]),
                             ("prior, camvid11", report["camvid11"]["prior"], report["camvid11"]["step_ms"]),
                             ("video frame", report["frame"], report["two"]["step_ms"])):
        for way, (size, ms) in ways.items():
            lines.append(f"| {what} | {way} | {size / 1000:.1f} | {ms:.1f} | {100 * ms / (2 * step):.0f}% |")
    return lines + ["", f"step: two classes {report['two']['step_ms']:.0f} ms, camvid11 {report['camvid11']['step_ms']:.0f} "
                    f"ms (medians); the rule: the smallest at most {100 * SHARE:.0f}% of the two steps, a way less than "
                    f"{100 * SMALLER:.0f}% smaller than a faster one counting as no smaller"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--clip", default="0001TP")
    ap.add_argument("--tmp", default=None, help="where the files are written (default: a temporary folder)")
    a = ap.parse_args(argv)
    from pcreg.classes import CAMVID11, LAGR

    w, h = (int(v) for v in a.size.split("x"))
    images, labels = load_clip(a.clip, (w, h))
    images = images[:a.frames + 1]
    report: dict = {"size": a.size, "frames": a.frames, "clip": a.clip, "data": str(SHARED_DATA),
                    "machine": machine_info()}
    with tempfile.TemporaryDirectory(dir=a.tmp) as tmp:
        for name, lab, classes in (("two", CAMVID_TO_LAGR[labels[0]], LAGR), ("camvid11", labels[0], CAMVID11)):
            kepts, step_ms = steps(images, lab, classes)
            report[name] = {"step_ms": step_ms, "prior": measure(kepts, PRIORS, Path(tmp))}
        report["frame"] = measure([{"image": im} for im in images[1:]], FRAMES, Path(tmp))
    lines = render(report)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    import json

    (out / "bench_keys_disk.json").write_text(json.dumps(report, indent=1))
    (out / "bench_keys_disk.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
