"""What pcreg's benchmarks share: the machine they ran on, timing, one ECC baseline, the ICP benchmarks'
clouds, and writing.

Every benchmark in ``tools/`` writes ``NAME.json`` (every number, the machine, the command), ``NAME.md``
(tables and the checks against its targets, then the command and the machine) and its figures (``NAME.png``,
``NAME_PART.png``) and table (``NAME.csv``) through :func:`write_report`, each file atomically;
:func:`finish` ends a benchmark's ``main`` with it. Timings are compared as ratios measured in the same
run, and summarised by medians.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
if str(REPO_ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO_ROOT))
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


def machine_info() -> dict:
    """CPU, core counts, library versions, the git commit and the load average at the call."""
    import cv2
    import scipy

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import open3d

        o3d_version = open3d.__version__
    except ImportError:
        o3d_version = None
    try:
        commit = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True,
                                text=True, timeout=10).stdout.strip() or None
        dirty = bool(subprocess.run(["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--", "pcreg"],
                                    capture_output=True, text=True, timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        commit, dirty = None, None
    return {
        "cpu_model": cpu, "cpu_count": os.cpu_count(),
        "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(), "python": sys.version.split()[0],
        "numpy": np.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__, "open3d": o3d_version,
        "opencv_threads": cv2.getNumThreads(),
        "env": {k: os.environ[k] for k in ("OPENBLAS_CORETYPE", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS")
                if k in os.environ},
        "git_commit": commit, "pcreg_dirty": dirty, "load_average": load_average(),
    }


def load_average() -> tuple[float, float, float] | None:
    """The 1, 5 and 15 minute load averages now (None where the system has none)."""
    try:
        return os.getloadavg()
    except OSError:
        return None


def machine_line(m: dict) -> str:
    """One Markdown line describing the machine of a report: CPU, libraries, pcreg's commit, load average."""
    load = m.get("load_average")
    commit = m.get("git_commit")
    return (f"Machine: {m['cpu_model']}, {m['cpu_count']} CPUs, {m['platform']}; Python {m['python']}, numpy {m['numpy']}, "
            f"scipy {m['scipy']}, OpenCV {m['opencv']}, Open3D {m['open3d']}"
            + (f"; pcreg at {commit[:12]}" + (" (pcreg/ modified)" if m.get("pcreg_dirty") else "") if commit else "")
            + (f"; load average {load[0]:.1f}" if load else "") + ".")


def median_ms(fn: Callable[[], object], repeats: int) -> tuple[float, list[float]]:
    """Median and all wall times of ``repeats`` calls of ``fn``, in milliseconds."""
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        times.append(1000.0 * (time.perf_counter() - t0))
    return float(np.median(times)), times


def ecc(reference: np.ndarray, moving: np.ndarray, *, motion: str = "affine", levels: int = 4) -> np.ndarray | None:
    """OpenCV's ECC baseline: ``findTransformECCMultiScale`` (OpenCV 5's ``ECCParameters``: ``levels``
    pyramid levels, ``motion`` "affine" or "euclidean") on grayscale float32 images, from the identity.
    Returns ``T_ref_mov`` (3, 3), or None where ECC does not converge (it throws then)."""
    import cv2

    ref = cv2.cvtColor(reference, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mov = cv2.cvtColor(moving, cv2.COLOR_RGB2GRAY).astype(np.float32)
    params = cv2.ECCParameters()
    params.motionType = {"affine": cv2.MOTION_AFFINE, "euclidean": cv2.MOTION_EUCLIDEAN}[motion]
    params.nlevels = levels
    try:
        _, W = cv2.findTransformECCMultiScale(ref, mov, np.eye(2, 3, dtype=np.float32), params)
    except cv2.error:
        return None
    # ECC's warp maps reference pixels to moving pixels (T_mov_ref); invert it for T_ref_mov.
    return np.linalg.inv(np.vstack([np.asarray(W, np.float64), [0.0, 0.0, 1.0]]))


# -- the ICP benchmarks' clouds (tools/bench_icp.py, tools/bench_registration.py) ---------------------

def camvid_images(data: Path) -> list[Path]:
    """The CamVid frames under ``data/camvid/*/images/``, in name order."""
    return sorted((data / "camvid").glob("*/images/*.png"))


def make_moving(reference: np.ndarray, T_ref_mov: np.ndarray) -> np.ndarray:
    """The moving image whose pixel x shows the reference at ``T_ref_mov @ x`` (black outside)."""
    import cv2

    h, w = reference.shape[:2]
    return cv2.warpAffine(reference, T_ref_mov[:2], (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def clouds_2d(data: Path, sizes: list[int], seed: int) -> tuple[str, dict[int, tuple[np.ndarray, np.ndarray]], float]:
    """(description, {N: (source, target)}, correspondence distance) for 2-D clouds."""
    import cv2

    import pcreg
    from pcreg.registration.transforms import about_point, image_center, rigid2d

    images = camvid_images(data)
    out = {}
    if images:
        img = pcreg.load_image(images[0])
        big = cv2.resize(img, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)
        c = image_center(big.shape)
        T = about_point(rigid2d(3.0, 6.0, -4.0), c, c)
        mov = make_moving(big, T)
        rng = np.random.default_rng(seed)
        for n in sizes:
            tgt = pcreg.image_cloud(big, sampler="gradient", top_k=n, mask=None).points
            # The moving copy's black padding is masked out after the top-k choice: ask for more, keep n.
            k = n
            while True:
                src = pcreg.image_cloud(mov, sampler="gradient", top_k=k, mask="auto").points
                if len(src) >= n or k >= mov.shape[0] * mov.shape[1]:
                    break
                k = int(k * 1.5) + 1
            if len(src) > n:
                src = src[np.sort(rng.choice(len(src), n, replace=False))]
            out[n] = (src, tgt)
        desc = (f"strongest-gradient pixels (sub-pixel) of {images[0].name} upscaled 3x "
                f"({big.shape[1]}x{big.shape[0]}) and of its copy rotated 3 deg, shifted (6, -4) px")
        return desc, out, 15.0
    # No real frames: points on random smooth closed curves in a 1000 x 1000 box.
    rng = np.random.default_rng(seed)
    k = 40
    centres = rng.uniform(100, 900, (k, 2))
    coef = rng.normal(0, 1, (k, 4, 2)) * np.array([60, 15, 8, 4])[None, :, None]

    def sample(n, r):
        curve = r.integers(k, size=n)
        t = r.uniform(0, 2 * np.pi, n)
        harm = np.arange(1, 5)
        pts = centres[curve] + np.einsum("nh,nhd->nd", np.cos(harm[None] * t[:, None]), coef[curve])
        pts += np.einsum("nh,nhd->nd", np.sin(harm[None] * t[:, None]), coef[curve][:, :, ::-1])
        return pts

    T = about_point(rigid2d(3.0, 6.0, -4.0), (500.0, 500.0))
    for n in sizes:
        r = np.random.default_rng(seed + n)
        tgt = sample(n, r)
        src = (sample(n, r) - T[:2, 2]) @ np.linalg.inv(T[:2, :2]).T
        out[n] = (src, tgt)
    return "points on 40 random smooth closed curves in a 1000 x 1000 box", out, 15.0


def clouds_3d(data: Path, sizes: list[int], seed: int) -> tuple[str, dict[int, tuple[np.ndarray, np.ndarray]], float] | None:
    """(description, {N: (source, target)}, correspondence distance) for 3-D clouds: random subsets of the
    LiDAR pair ``data/scans``; None (and a note on stderr) without it."""
    src_path, tgt_path = data / "scans" / "source.ply", data / "scans" / "target.ply"
    if not (src_path.is_file() and tgt_path.is_file()):
        print(f"skipping 3-D clouds: {src_path} or {tgt_path} not found", file=sys.stderr)
        return None
    import open3d as o3d

    src_all = np.asarray(o3d.io.read_point_cloud(str(src_path)).points, dtype=np.float64)
    tgt_all = np.asarray(o3d.io.read_point_cloud(str(tgt_path)).points, dtype=np.float64)
    rng = np.random.default_rng(seed)
    out = {}
    for n in sizes:
        ns, nt = min(n, len(src_all)), min(n, len(tgt_all))
        out[ns] = (src_all[np.sort(rng.choice(len(src_all), ns, replace=False))],
                   tgt_all[np.sort(rng.choice(len(tgt_all), nt, replace=False))])
    desc = (f"random subsets of the LiDAR pair data/scans (source {len(src_all)} / target {len(tgt_all)} points; "
            "sizes above that use every point)")
    return desc, out, 0.5


def checks_markdown(rows: Sequence[tuple[str, str, bool | None]], *, title: str = "Checks") -> str:
    """A Markdown table of (target, measured, met): ``met``, ``NOT met`` or ``n/a``."""
    from pcreg.outputs import markdown_table

    body = [[t, m, "n/a" if ok is None else ("met" if ok else "NOT met")] for t, m, ok in rows]
    return f"### {title}\n\n" + markdown_table(["target", "measured", ""], body)


def command_line(argv: Sequence[str] | None = None, script: str | Path | None = None) -> str:
    """``python SCRIPT ARGS``, the script relative to the checkout: by default the running program's
    (``sys.argv``); a benchmark's ``main`` called with ``argv`` passes it and its own file."""
    raw = sys.argv[0] if script is None else str(script)
    path = Path(raw).resolve()
    shown = path.relative_to(REPO_ROOT).as_posix() if path.is_relative_to(REPO_ROOT) else raw
    return "python " + " ".join([shown, *(sys.argv[1:] if argv is None else argv)])


def write_report(out: str | Path, name: str, report: dict, markdown: str, figure=None, *,
                 figures: Mapping[str, Any] | None = None, table: tuple[list[str], list[list]] | None = None,
                 command: str | None = None) -> list[Path]:
    """``out/NAME.json`` (``report`` with the command line), ``out/NAME.md`` (``markdown``, then the command
    line and the machine), and given them, matplotlib figures ``out/NAME.png`` (``figure``) and
    ``out/NAME_PART.png`` (``figures``, by PART) and ``out/NAME.csv`` (``table``: header, rows); each
    written atomically, every figure closed. ``command`` defaults to :func:`command_line`. Returns the paths."""
    from pcreg.outputs import atomic_save_figure, atomic_write_csv, atomic_write_json, atomic_write_text

    out = Path(out)
    command = command_line() if command is None else command
    report = {**report, "command": command}
    machine = report.get("machine")
    text = markdown.rstrip() + f"\n\nCommand: `{command}`.\n" + (machine_line(machine) + "\n" if machine else "")
    paths = [atomic_write_json(out / f"{name}.json", report), atomic_write_text(out / f"{name}.md", text)]
    if table is not None:
        paths.append(atomic_write_csv(out / f"{name}.csv", *table))
    pngs = {name: figure} if figure is not None else {}
    pngs.update({f"{name}_{part}": fig for part, fig in (figures or {}).items()})
    if pngs:
        import matplotlib.pyplot as plt

        for stem, fig in pngs.items():
            paths.append(atomic_save_figure(fig, out / f"{stem}.png"))
            plt.close(fig)
    return paths


def finish(out: str | Path, name: str, report: dict, render: Callable[[dict], str],
           figure: Callable[[dict], Any] | None = None) -> int:
    """The end of a benchmark's ``main``: the load average at the end noted with the machine, the report
    rendered as Markdown, written (:func:`write_report`, with ``figure(report)``) and the Markdown printed.
    Returns 0, the exit code."""
    report["machine"]["load_average_at_end"] = load_average()
    md = render(report)
    write_report(out, name, report, md, None if figure is None else figure(report))
    print(md)
    return 0
