"""What each way ``pcreg run`` labels a video does at a scene cut: clip A's first frames, then clip B's
(resized to A's size), labelled from A's first frame. Per frame after the cut: the share labelled the
object (the first non-background class), the error against truth, plain naive Bayes' error, the mean
confidence of the wrong labels, the share of pixels wrong with confidence > 0.9, the predicted error.

    python tools/measure_cuts.py follow goat blackswan        # --follow object, DAVIS
    python tools/measure_cuts.py scene goat blackswan         # the two-class stream, DAVIS (--mapping davis)
    python tools/measure_cuts.py classes 0001TP 0016E5        # --classes camvid11, CamVid
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def load(mode: str, name: str):
    from pcreg.datasets import load_davis, load_folder

    if mode == "classes":
        return load_folder(DATA / "camvid" / name, mapping=None, classes="camvid11")
    if name in {p.name for p in (DATA / "camvid").iterdir()}:
        return load_folder(DATA / "camvid" / name, mapping="camvid")
    return next(iter(load_davis(DATA / "davis" / name).values()))


def cut_frames(mode: str, a: str, b: str, n: int):
    """``(images, truths, cut)``: n frames of a, then n of b at a's size (truth resized nearest)."""
    fa, fb = load(mode, a)[:n], load(mode, b)[:n]
    h, w = fa[0].image.shape[:2]
    images = [f.image for f in fa] + [cv2.resize(f.image, (w, h), interpolation=cv2.INTER_AREA) for f in fb]
    truths = [f.labels for f in fa] + [cv2.resize(f.labels, (w, h), interpolation=cv2.INTER_NEAREST) for f in fb]
    return images, truths, len(fa)


def labeller(mode: str, image, labels):
    from pcreg.classes import class_table
    from pcreg.pipeline.config import PropagatorConfig

    if mode == "follow":
        return PropagatorConfig(follow="object").from_key_frame(image, labels)
    return PropagatorConfig().from_key_frame(image, labels, classes=class_table("camvid11") if mode == "classes" else None)


def run(mode: str, a: str, b: str, n: int, before: int = 3) -> list[dict]:
    images, truths, cut = cut_frames(mode, a, b, n)
    prop = labeller(mode, images[0], truths[0])
    unknown = 2
    if mode == "classes":
        from pcreg.classes import class_table
        unknown = class_table("camvid11").unknown
    rows = []
    for i in range(1, len(images)):
        labels = prop.step(images[i])
        if i < cut - before:
            continue
        rep, truth = prop.last, truths[i]
        known = truth != unknown
        wrong = (labels != truth) & known
        conf = rep.confidence
        rows.append({"frame": i - cut, "object": 100.0 * float((labels == 1).mean()),
                     "error": 100.0 * wrong.sum() / max(1, known.sum()),
                     "wrong_conf": float(conf[wrong].mean()) if conf is not None and wrong.any() else float("nan"),
                     "sure_wrong": 100.0 * float((wrong & (conf > 0.9)).mean()) if conf is not None else float("nan"),
                     "predicted": rep.predicted_error if rep.predicted_error is not None else float("nan"),
                     "cut": dict(rep.trust_summary or {}).get("cut")})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mode", choices=("follow", "scene", "classes"))
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("-n", type=int, default=30, help="frames of each clip")
    args = p.parse_args(argv)
    print("frame  object%  error%  conf(wrong)  wrong>0.9%  predicted%  cut")
    for r in run(args.mode, args.a, args.b, args.n):
        print(f"{r['frame']:5d}  {r['object']:7.1f}  {r['error']:6.1f}  {r['wrong_conf']:11.3f}  {r['sure_wrong']:10.1f}"
              f"  {r['predicted']:10.1f}  {r['cut']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
