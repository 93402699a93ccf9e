"""Affine and projective registrations of the shared photographs under random views: right, wrong or refused.

Each pair is a photograph of ``../shared/data/photos`` (halved when its longer side exceeds 800 px) and
the same warped by ``M``: a rotation uniform in [-180, 180] deg and a scale log-uniform in [0.6, 1.6] about the
centre, a shift within +-15% of the size, then for ``projective`` a perspective row (both terms uniform in
+-3e-4 per px), for ``affine`` a shear (+-0.2) and a second scale (0.8-1.2). ``pcreg register --model MODEL``
is run on it as a user runs it (the command line); a result is right when every point of a 16 px grid of the
moving image that lands inside the reference lies within 3 px of where ``inv(M)`` puts it, wrong (exit 0)
otherwise: marked when the result carries a note (a user is told it may be wrong), unmarked when it does not;
exit 3 is a refusal. Pair ``k`` of a run uses the random seed ``--seed + k`` and photograph
``k`` modulo ten, so a set is named by its seed. ``--moving jpeg:Q`` saves the view as a JPEG of quality ``Q``
(a photograph warped and saved by an editor: its padding smeared by the JPEG's blocks) instead of a PNG; the
last line gives the mean and median error of the pairs not refused.

    python tools/bench_warped_photos.py --model projective --pairs 25 --seed 700
    python tools/bench_warped_photos.py --model affine --pairs 20 --moving jpeg:85
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from benchlib import SHARED_DATA

PHOTOS = ("camera.png", "coins.png", "moon.png", "cell.png", "page.png", "clock_motion.png", "ihc.png",
          "retina.jpg", "hubble_deep_field.jpg", "horse.png")


def view(k: int, seed: int, model: str, photos: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Pair ``k``: the photograph (BGR), its view, the view's matrix ``M`` and the photograph's name."""
    rng = np.random.default_rng(seed + k)
    name = PHOTOS[k % len(PHOTOS)]
    img = cv2.imread(str(photos / name), cv2.IMREAD_COLOR)
    if max(img.shape[:2]) > 800:
        img = cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    h, w = img.shape[:2]
    angle, scale = rng.uniform(-180, 180), np.exp(rng.uniform(np.log(0.6), np.log(1.6)))
    shift = rng.uniform(-0.15, 0.15, 2) * [w, h]
    M = np.vstack([cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), angle, scale), [0, 0, 1]])
    M[:2, 2] += shift
    extra = np.eye(3)
    if model == "projective":
        extra[2, :2] = rng.uniform(-3e-4, 3e-4, 2)
    elif model == "affine":
        extra[0, 1], extra[1, 1] = rng.uniform(-0.2, 0.2), rng.uniform(0.8, 1.2)
    M = extra @ M
    return img, cv2.warpPerspective(img, M, (w, h)), M, name


def grid_error(T: np.ndarray, M: np.ndarray, shape: tuple[int, ...]) -> float:
    """The largest distance (px) between ``T`` and ``inv(M)`` over the 16 px grid points that land inside."""
    h, w = shape[:2]
    ys, xs = np.mgrid[0:h:16, 0:w:16]
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    truth = np.linalg.inv(M) @ pts
    truth = truth[:2] / truth[2]
    inside = (truth[0] >= 0) & (truth[0] < w) & (truth[1] >= 0) & (truth[1] < h)
    got = T @ pts[:, inside]
    return float(np.linalg.norm(got[:2] / got[2] - truth[:, inside], axis=0).max())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", choices=("affine", "projective"), default="projective")
    ap.add_argument("--pairs", type=int, default=25)
    ap.add_argument("--seed", type=int, default=700)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--moving", default="png", help="how the view is saved: png (default) or jpeg:QUALITY")
    args = ap.parse_args()
    quality = int(args.moving.partition(":")[2] or 95) if args.moving.startswith("jpeg") else None
    photos = args.data / "photos"
    if not photos.is_dir():
        sys.exit(f"{photos}: no such folder (the shared photographs)")
    counts = {"right": 0, "marked": 0, "wrong": 0, "refused": 0}
    errors = []
    with tempfile.TemporaryDirectory(prefix="pcreg-views-") as tmp:
        for k in range(args.pairs):
            img, moved, M, name = view(k, args.seed, args.model, photos)
            ref, mov = Path(tmp) / "ref.png", Path(tmp) / ("mov.png" if quality is None else "mov.jpg")
            cv2.imwrite(str(ref), img)
            cv2.imwrite(str(mov), moved, [] if quality is None else [cv2.IMWRITE_JPEG_QUALITY, quality])
            p = subprocess.run([sys.executable, "-m", "pcreg.cli", "register", str(ref), str(mov), "--json",
                                "--model", args.model], capture_output=True, text=True)
            if p.returncode == 3:
                outcome, said = "refused", p.stderr.strip().splitlines()[-1][:100]
            elif p.returncode == 0:
                result = json.loads(p.stdout)
                error = grid_error(np.array(result["matrix"]), M, moved.shape)
                errors.append(error)
                outcome = "right" if error <= 3.0 else "marked" if result.get("notes") else "wrong"
                said = (f"{error:.2f} px, inlier ratio {result['inlier_ratio']:.3f}, {result['generator']}"
                        + (f"; note: {result['notes'][0][:60]}" if result.get("notes") else ""))
            else:
                raise SystemExit(f"pair {k} ({name}): exit {p.returncode}: {p.stderr.strip()}")
            counts[outcome] += 1
            print(f"{k:3d} {name:22s} {outcome:8s} {said}", flush=True)
    print(f"{args.model}, {args.pairs} pairs from seed {args.seed}: {counts['right']} right, {counts['marked']} wrong "
          f"but marked (exit 0 with a note), {counts['wrong']} wrong and unmarked, {counts['refused']} refused; grid error of those not refused: mean {np.mean(errors):.2f} px, "
          f"median {np.median(errors):.2f} px (view saved as {args.moving})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
