"""docs/figures/review_page.png: the review page of a ``pcreg run`` over the 60 frames of CamVid 0016E5.

    python tools/review_figure.py --data ../shared/data --out out/review_figure

The run labels every frame from the first one's CamVid labels (``--mapping camvid --confidence``), scored against
the clip's truth (``--truth``: the dashed line of the plot, the IoU against the truth in the legend);
``--suggest 3`` writes suggest.txt, the three frames :func:`pcreg.pipeline.keyframes.suggest` picks from the predicted
errors; the page (``pcreg view OUT --web``) is shown at frame 29 in headless Chromium (tests/_browser.py)
and stored with a palette (small).

docs/figures/overlay_frame.png: frame 29 of ``pcreg view OUT --overlay OUT.mp4`` (:func:`pcreg.review.video_frame`, before
the video's compression) of a run over the same clip's first 30 frames in CamVid's eleven classes (``--classes
camvid11 --confidence --truth``): the legend gives the frame's predicted error beside its error against the truth, and
each class's predicted IoU beside its IoU against the truth.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def small_png(src: Path, dst: Path, *, width: int = 1100) -> None:
    """``src`` scaled to ``width`` with a palette of 256 colours (octree: the page's few accent colours kept)."""
    from PIL import Image

    img = Image.open(src).convert("RGB")
    if img.width > width:
        img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    img.quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(dst, optimize=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--out", default="out/review_figure")
    ap.add_argument("--figure", default=str(ROOT / "docs" / "figures" / "review_page.png"))
    ap.add_argument("--overlay-figure", default=str(ROOT / "docs" / "figures" / "overlay_frame.png"))
    args = ap.parse_args()
    clip = Path(args.data) / "camvid" / "0016E5"
    images = sorted((clip / "images").glob("*.png"))
    if not images:
        sys.exit(f"no CamVid clip at {clip} (give --data)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = out / "0016E5"
    subprocess.run([sys.executable, "-m", "pcreg.cli", "run", str(clip / "images"), "--labels",
                    str(clip / "labels" / images[0].name), "--mapping", "camvid", "--out", str(run), "--confidence",
                    "--truth", str(clip / "labels"), "--suggest", "3", "--force"], check=True, env=env)

    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    from _browser import Browser
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    shot = out / "review_page.png"
    with ReviewServer(read_review(run), web_port=0) as server, Browser(width=1400, height=760) as browser:
        browser.open(server.url + "#29")

        def shown() -> bool:  # the frame's picture, and its classes' figures in the legend
            answer = browser.call("Runtime.evaluate", session=True, returnByValue=True,
                                  expression="document.body && document.body.dataset.shown === '/overlay/29.jpg' && "
                                             "Array.from(document.querySelectorAll('#legend span[data-class]'))"
                                             ".some((s) => s.textContent.includes('IoU'))")
            return answer["result"].get("value") is True

        for _ in range(600):  # the page draws the frame it opens on
            if shown():
                break
            time.sleep(0.1)
        else:
            sys.exit("the review page did not show frame 29")
        import cv2  # captureScreenshot waits for the next frame drawn, the loaded picture in it

        cv2.imwrite(str(shot), browser.screenshot())
    small_png(shot, Path(args.figure))
    print(f"{args.figure}: {Path(args.figure).stat().st_size // 1024} kB", flush=True)
    overlay_figure(clip, images, out / "0016E5_eleven", Path(args.overlay_figure), env)
    return 0


def overlay_figure(clip: Path, images: list[Path], run: Path, figure: Path, env: dict) -> None:
    """``figure``: frame 29 of the overlay video of an eleven-class run over the first 30 frames of ``clip``."""
    import cv2

    from pcreg.review import FrameImages, read_review, video_frame

    subprocess.run([sys.executable, "-m", "pcreg.cli", "run", str(clip / "images"), "--labels",
                    str(clip / "labels" / images[0].name), "--classes", "camvid11", "--stop", "30", "--out", str(run),
                    "--confidence", "--truth", str(clip / "labels"), "--force"], check=True, env=env)
    review = read_review(run)
    with FrameImages(review) as frames:
        drawn, legend = video_frame(review, 29, frames[29])
    if not (legend.figures and legend.scored):
        sys.exit("frame 29's legend holds no figures")
    shot = run.parent / "overlay_frame.png"
    cv2.imwrite(str(shot), drawn[:, :, ::-1])
    small_png(shot, figure)
    print(f"{figure}: {figure.stat().st_size // 1024} kB", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
