"""A copy of a CamVid-layout root (CLIP/images, CLIP/labels) with every frame brought to another size, to see what
the stream does on frames of another size than its constants were set at (docs/results.md, "Frames of other sizes").

    python tools/resize_clips.py ../shared/data/camvid out/camvid960 960x720
    python tools/sweep_scale.py --data camvid:out/camvid960 --scales 1,0.667,0.5 --flow-presets "" --out out/sweep960

Images are resized with ``cv2.INTER_CUBIC`` up and ``cv2.INTER_AREA`` down, label images with ``cv2.INTER_NEAREST``
(their values are class ids). Every file is written as PNG under the same name.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2


def resize_root(src: Path, dst: Path, size: tuple[int, int]) -> int:
    """Write every clip of ``src`` at ``size`` (width, height) under ``dst``; the number of files written."""
    written = 0
    for clip in sorted(p for p in src.iterdir() if (p / "images").is_dir()):
        for sub in ("images", "labels"):
            folder = clip / sub
            if not folder.is_dir():
                continue
            (dst / clip.name / sub).mkdir(parents=True, exist_ok=True)
            for f in sorted(folder.glob("*.png")):
                im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
                if im is None:
                    sys.exit(f"{f}: not an image OpenCV reads")
                up = size[0] * size[1] > im.shape[0] * im.shape[1]
                how = cv2.INTER_NEAREST if sub == "labels" else cv2.INTER_CUBIC if up else cv2.INTER_AREA
                cv2.imwrite(str(dst / clip.name / sub / f.name), cv2.resize(im, size, interpolation=how))
                written += 1
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path, help="a CamVid-layout root (CLIP/images/*.png, CLIP/labels/*.png)")
    ap.add_argument("dst", type=Path, help="where the resized copy goes")
    ap.add_argument("size", help="WxH, e.g. 960x720")
    args = ap.parse_args()
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        sys.exit(f"size must be WxH, got {args.size!r}")
    if w < 1 or h < 1:
        sys.exit(f"size must be positive, got {args.size!r}")
    if not args.src.is_dir():
        sys.exit(f"{args.src} is not a folder")
    print(f"{resize_root(args.src, args.dst, (w, h))} files written under {args.dst}")


if __name__ == "__main__":
    main()
