"""What ``pcreg run --follow object`` does when a shot returns after a cut: DAVIS sequence A's frames 0-19,
10 frames of clip B (another DAVIS sequence or a CamVid clip, at A's size; truth: no object), then A's frames
from ``--back`` on. Prints J (pcreg.classification.davis_measures.jaccard) on the returned frames (the last
left out, as the benchmark does), on the same frames of A followed without the cut, on B's frames, and the
frame where the object was found again. ``--never``: A's frames 0-19, then every frame of the eight CamVid
clips and the other four DAVIS sequences, nothing of A again: where the object was found (it should not be).

    python tools/measure_returns.py --back 20         # back where A was left
    python tools/measure_returns.py --back 40         # back to a later place of A
    python tools/measure_returns.py --never
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
DAVIS = ["blackswan", "breakdance", "car-roundabout", "goat", "kite-surf"]
CAMVID = ["0001TP", "0001TP_b", "0006R0", "0006R0_b", "0016E5", "0016E5_b", "Seq05VD", "Seq05VD_b"]


def davis(name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    from pcreg.datasets.davis import load_sequence

    root = DATA / "davis" / name
    return [(f.image, (f.labels == 1).astype(np.uint8)) for f in load_sequence(root / "images", root / "labels")]


def camvid(name: str) -> list[np.ndarray]:
    from pcreg.datasets import load_folder

    return [f.image for f in load_folder(DATA / "camvid" / name, mapping="camvid")]


def follow(frames) -> tuple[list[float], list[int], float]:
    """J of every frame, the frames found again, the largest share labelled the object on truth-empty frames."""
    from pcreg.classification.davis_measures import jaccard
    from pcreg.pipeline.follow import ObjectFollower

    follower = ObjectFollower.from_key_frame(*frames[0])
    j, back, stray = [1.0], [], 0.0
    for t, (image, truth) in enumerate(frames[1:], start=1):
        labels = follower.step(image)
        j.append(jaccard(labels, truth))
        back += [t] if follower.last.trust_summary["back"] else []
        stray = max(stray, float(labels.mean())) if not truth.any() else stray
    return j, back, stray


def shot(images, like) -> list[tuple[np.ndarray, np.ndarray]]:
    h, w = like.shape[:2]
    return [(cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA), np.zeros((h, w), np.uint8)) for im in images]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--back", type=int, default=20, help="A's first frame after B")
    p.add_argument("--never", action="store_true", help="A's object never back: every other clip as B")
    args = p.parse_args(argv)
    for i, a in enumerate(DAVIS):
        seq = davis(a)
        if args.never:
            others = [im for c in CAMVID for im in camvid(c)] + [im for d in DAVIS if d != a for im, _ in davis(d)]
            _, back, stray = follow(seq[:20] + shot(others, seq[0][0]))
            print(f"{a:15s} B {len(others)} frames  found again at {back}  largest object share on B {stray:.4f}")
            continue
        whole, _, _ = follow(seq)
        for b in (DAVIS[(i + 1) % len(DAVIS)], CAMVID[0]):
            b_images = [im for im, _ in davis(b)[:10]] if b in DAVIS else camvid(b)[:10]
            j, back, _ = follow(seq[:20] + shot(b_images, seq[0][0]) + seq[args.back:])
            print(f"{a:15s} B {b:15s} J returned {np.mean(j[30:-1]):.3f} (without the cut "
                  f"{np.mean(whole[args.back:-1]):.3f})  J on B {np.mean(j[20:30]):.3f}  found again at {back}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
