"""A long H.264 video of CamVid frames for measuring ``pcreg run``, ``view`` and ``export`` at length, with key labels.

``python tools/make_long_video.py --data ../shared/data/camvid --out /tmp/long.mp4 --keys /tmp/keys
--frames 2400 --key-at 0,800,1600`` writes ``--frames`` frames of ``--size`` (default 160x120) at 25 frames/s:
each clip frame (the clips' frames in name order, resized to 1.5 x the size) is shown for ``--hold`` frames
as a window that pans across it, a cut to the next clip frame after each; the clip frames are used again from
the first when they run out. ``KEYS/{i:06d}.png`` holds frame i's labels (the clip's label ids, the same window
of them) for each i of ``--key-at``, what ``pcreg run --labels KEYS/ --mapping camvid`` (or ``--classes
camvid11``) reads.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def clip_frames(data: Path, width: int, height: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every clip frame of ``data`` (``CLIP/images/NAME.png`` with ``CLIP/labels/NAME.png``) as (BGR, labels),
    resized to 1.5 x (width, height)."""
    import cv2

    size = (width * 3 // 2, height * 3 // 2)
    out = []
    for images in sorted(p for p in data.glob("*/images") if not p.parent.name.endswith("_b")):
        for p in sorted(images.glob("*.png")):
            image = cv2.resize(cv2.imread(str(p)), size, interpolation=cv2.INTER_AREA)
            labels = cv2.resize(cv2.imread(str(p.parent.parent / "labels" / p.name), cv2.IMREAD_UNCHANGED), size,
                                interpolation=cv2.INTER_NEAREST)
            out.append((image, labels))
    if not out:
        raise SystemExit(f"{data}: no CLIP/images/*.png")
    return out


def write_video(path: Path, keys: Path, clips, *, frames: int, width: int, height: int, hold: int,
                key_at: set[int]) -> None:
    import av
    import cv2

    keys.mkdir(parents=True, exist_ok=True)
    box = av.open(str(path), "w")
    stream = box.add_stream("libx264", rate=25)
    stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
    stream.options = {"crf": "23", "preset": "veryfast"}
    spare_x, spare_y = clips[0][0].shape[1] - width, clips[0][0].shape[0] - height
    for i in range(frames):
        image, labels = clips[(i // hold) % len(clips)]
        t = (i % hold) / hold
        x, y = int(round(spare_x * (0.1 + 0.8 * t))), int(round(spare_y * (0.3 + 0.4 * t)))
        if i in key_at:
            cv2.imwrite(str(keys / f"{i:06d}.png"), labels[y:y + height, x:x + width])
        rgb = np.ascontiguousarray(image[y:y + height, x:x + width, ::-1])
        for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
            box.mux(packet)
    for packet in stream.encode():
        box.mux(packet)
    box.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/camvid"))
    ap.add_argument("--out", type=Path, required=True, help="the video (.mp4)")
    ap.add_argument("--keys", type=Path, required=True, help="folder for the key frames' labels")
    ap.add_argument("--frames", type=int, default=2400)
    ap.add_argument("--size", default="160x120", help="WxH")
    ap.add_argument("--hold", type=int, default=20, help="frames each clip frame is shown (a cut after)")
    ap.add_argument("--key-at", default="0,800,1600", help="the key frames, comma-separated")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    key_at = {int(k) for k in args.key_at.split(",")}
    write_video(args.out, args.keys, clip_frames(args.data, width, height), frames=args.frames, width=width,
                height=height, hold=args.hold, key_at=key_at)
    print(f"wrote {args.out}: {args.frames} frames of {width}x{height}; key labels {sorted(key_at)} in {args.keys}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
