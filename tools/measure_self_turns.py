"""How much of an image's edges land on its own edges turned about their centre: the measure by which
``pcreg register`` refuses a moving image whose rotation is not determined (a disk, rings;
:func:`pcreg.registration.plausibility.turned_onto_itself`). For every shared CamVid and DAVIS frame and
photograph, and for drawn shapes, the largest share at any level the test reads (the least of its three turns),
and whether the test refuses the image.

    python tools/measure_self_turns.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def pyramid(image: np.ndarray):
    from pcreg.registration.config import RegisterConfig
    from pcreg.registration.pyramid import CloudPyramid

    p = RegisterConfig().pyramid
    return CloudPyramid.from_image(image, levels=p.levels, mask=None, max_points=p.max_points, sampler=p.sampler,
                                   seed=1, canny_percentile=p.canny_percentile)


def most_landed(cloud) -> float:
    """The largest share over the levels :func:`turned_onto_itself` reads, each the least of its three turns."""
    from pcreg.registration.plausibility import SPREAD_POINTS, self_turn_share

    first = 1 if len(cloud) > 1 and len(cloud[1]) >= SPREAD_POINTS else 0
    shares = []
    for level in range(first, len(cloud)):
        c = cloud.every_point(level)
        if len(c) < SPREAD_POINTS:
            break
        shares.append(self_turn_share(c, level))
    return max(shares, default=0.0)


def shapes() -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:200, 0:200].astype(np.float64)
    r = np.hypot(x - 100, y - 100)
    disk = ((r < 60) * 200 + 20).astype(np.uint8)
    yy, xx = np.mgrid[0:480, 0:640].astype(np.float64)
    out = {"disk": disk, "disk, blurred": cv2.GaussianBlur(disk, (0, 0), 3),
           "disk, noise of 15": np.clip(disk + np.random.default_rng(0).normal(0, 15, disk.shape), 0, 255).astype(np.uint8),
           "disk off centre": ((np.hypot(x - 60, y - 130) < 40) * 200 + 20).astype(np.uint8),
           "disk, 64 px": cv2.resize(disk, (64, 64), interpolation=cv2.INTER_AREA),
           "annulus": (((r < 70) & (r > 40)) * 200 + 20).astype(np.uint8),
           "rings": ((np.sin(r / 6) > 0) * 180 + 40).astype(np.uint8),
           "rings, 640x480": ((np.sin(np.hypot(xx - 319.5, yy - 239.5) / 6) > 0) * 180 + 40).astype(np.uint8),
           "ellipse": ((((x - 100) / 80) ** 2 + ((y - 100) / 40) ** 2 < 1) * 200 + 20).astype(np.uint8),
           "square": (((abs(x - 100) < 50) & (abs(y - 100) < 50)) * 200 + 20).astype(np.uint8)}
    notch = disk.copy()
    notch[95:105, 150:170] = 20
    clock = disk.copy()
    cv2.line(clock, (100, 100), (100, 55), 20, 4)
    cv2.line(clock, (100, 100), (130, 110), 20, 4)
    out.update({"disk with a notch": notch, "disk with two hands": clock})
    return out


def main() -> int:
    import argparse

    from pcreg.registration.plausibility import turned_onto_itself

    argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " ")).parse_args()
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent: this measure reads the shared data")
    paths = sorted(p for p in (DATA / "photos").iterdir() if p.suffix in (".png", ".jpg"))
    for folder in sorted((DATA / "camvid").iterdir()) + sorted(p for p in (DATA / "davis").iterdir() if p.is_dir()):
        paths += sorted((folder / "images").iterdir())
    real = sorted(((most_landed(pyramid(np.ascontiguousarray(cv2.imread(str(p))[:, :, ::-1]))), p) for p in paths),
                  reverse=True)
    print(f"{len(real)} shared frames and photographs; the most that land:")
    for share, p in real[:3]:
        print(f"  {share:.3f}  {p.relative_to(DATA)}")
    print("| image | most that land | refused |\n|---|---|---|")
    for name, img in shapes().items():
        cloud = pyramid(np.dstack([img] * 3))
        print(f"| {name} | {most_landed(cloud):.3f} | {'yes' if turned_onto_itself(cloud) is not None else 'no'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
