"""The README's viewer screenshots: each command records a run on real data, ``pcreg view --screenshot``
renders the recording headless, and the PNG is stored palette-quantised (small) under docs/figures/.

    python tools/view_figures.py --data ../shared/data --out out/view_figures [--kinds register,sequence]

Kinds: register, crosscheck (CamVid 0016E5 frames 07959 -> 07965), crosscheck_clouds (the LiDAR scan
pair, four implementations), sequence (its first 8 frames, k = 1),
rotation (its first frame rotated by 10-40 degrees), demo (``pcreg demo --frames 8``), compare (the register
run with each backend, ``pcreg view A.rrd B.rrd``), dense (the sequence run with ``--model dense``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("register", "crosscheck", "crosscheck_clouds", "sequence", "rotation", "demo", "compare", "dense")


def pcreg(*argv: str) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    print("$ pcreg", " ".join(argv), flush=True)
    code = subprocess.run([sys.executable, "-m", "pcreg.cli", *argv], env=env, stdout=subprocess.DEVNULL).returncode
    if code != 0:  # its one line is above, on stderr
        sys.exit(f"view_figures: pcreg {argv[0]} ended with exit code {code}; no figure written for it")


def small_png(src: Path, dst: Path, *, width: int = 1100, colours: int = 96) -> None:
    """``src`` scaled to ``width`` and stored with a palette of ``colours`` (a screenshot is flat UI)."""
    from PIL import Image

    img = Image.open(src).convert("RGB")
    if img.width > width:
        img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    img.quantize(colors=colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(dst, optimize=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--out", default="out/view_figures")
    ap.add_argument("--figures", default=str(ROOT / "docs" / "figures"))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--size", default="1280x720")
    args = ap.parse_args()
    out, figures = Path(args.out), Path(args.figures)
    out.mkdir(parents=True, exist_ok=True)
    clip = Path(args.data) / "camvid" / "0016E5"
    ref, mov = clip / "images" / "0016E5_07959.png", clip / "images" / "0016E5_07965.png"
    if not ref.is_file():
        sys.exit(f"no CamVid clip at {clip} (give --data)")
    camvid = ["--data", f"camvid:{clip}"]
    runs = {
        "register": [["register", str(ref), str(mov), "--model", "similarity", "--record", str(out / "register.rrd"),
                      "--force"]],
        "crosscheck": [["crosscheck", str(ref), str(mov), "--record", str(out / "crosscheck.rrd"), "--force"]],
        "crosscheck_clouds": [["crosscheck", str(Path(args.data) / "scans" / "target.ply"),
                               str(Path(args.data) / "scans" / "source.ply"), "--with", "reference,open3d,small_gicp,kiss-icp",
                               "--voxel-size", "0.25", "--max-distance", "0.5", "--json",
                               "--record", str(out / "crosscheck_clouds.rrd"), "--force"]],
        "sequence": [["evaluate", "sequence", *camvid, "--frames", "8", "-k", "1", "--out", str(out / "sequence"),
                      "--record", str(out / "sequence.rrd"), "--force"]],
        "rotation": [["evaluate", "rotation", *camvid, "--frames", "1", "--angles", "10,20,30,40", "--samples", "1",
                      "--out", str(out / "rotation"), "--record", str(out / "rotation.rrd"), "--force"]],
        "demo": [["demo", "--frames", "8", "--out", str(out / "demo"), "--record", str(out / "demo.rrd"), "--force"]],
        "dense": [["evaluate", "sequence", *camvid, "--frames", "8", "-k", "1", "--model", "dense",
                   "--out", str(out / "dense"), "--record", str(out / "dense.rrd"), "--force"]],
        "compare": [["register", str(ref), str(mov), "--model", "similarity", "--backend", b,
                     "--record", str(out / f"{b}.rrd"), "--force"]
                    for b in ("reference", "open3d")],
    }
    for kind in args.kinds.split(","):
        for argv in runs[kind]:
            pcreg(*argv)
        shown = [str(out / "reference.rrd"), str(out / "open3d.rrd")] if kind == "compare" else [str(out / f"{kind}.rrd")]
        shot = out / f"view_{kind}.png"
        pcreg("view", *shown, "--screenshot", str(shot), "--size", args.size, "--force")
        small_png(shot, figures / f"view_{kind}.png")
        print(f"{figures / f'view_{kind}.png'}: {(figures / f'view_{kind}.png').stat().st_size // 1024} kB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
