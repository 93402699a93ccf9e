"""What pcreg's benchmarks share: the machine they ran on, timing, one ECC baseline, and writing.

Every benchmark in ``tools/`` writes ``NAME.json`` (every number, the machine, the command), ``NAME.md``
(tables and the checks against its targets) and ``NAME.png`` through :func:`write_report`, each file
atomically. Timings are compared as ratios measured in the same run, and summarised by medians.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

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
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {
        "cpu_model": cpu, "cpu_count": os.cpu_count(),
        "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(), "python": sys.version.split()[0],
        "numpy": np.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__, "open3d": o3d_version,
        "opencv_threads": cv2.getNumThreads(),
        "env": {k: os.environ[k] for k in ("OPENBLAS_CORETYPE", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
                if k in os.environ},
        "git_commit": commit, "pcreg_dirty": dirty, "load_average": load,
    }


def machine_line(m: dict) -> str:
    """One Markdown line describing the machine of a report."""
    load = m.get("load_average")
    return (f"Machine: {m['cpu_model']}, {m['cpu_count']} CPUs, Python {m['python']}, OpenCV {m['opencv']}, "
            f"Open3D {m['open3d']}" + (f", load average {load[0]:.1f}" if load else "") + ".")


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


def checks_markdown(rows: Sequence[tuple[str, str, bool | None]], *, title: str = "Checks") -> str:
    """A Markdown table of (target, measured, met): ``met``, ``NOT met`` or ``n/a``."""
    from pcreg.outputs import markdown_table

    body = [[t, m, "n/a" if ok is None else ("met" if ok else "NOT met")] for t, m, ok in rows]
    return f"### {title}\n\n" + markdown_table(["target", "measured", ""], body)


def write_report(out: str | Path, name: str, report: dict, markdown: str, figure=None) -> list[Path]:
    """``out/NAME.json``, ``out/NAME.md`` (with the command line and the machine) and, given a
    matplotlib figure, ``out/NAME.png``; each written atomically. Returns the paths."""
    from pcreg.outputs import atomic_save_figure, atomic_write_json, atomic_write_text

    out = Path(out)
    script = Path(sys.argv[0]).resolve()
    shown = script.relative_to(REPO_ROOT).as_posix() if script.is_relative_to(REPO_ROOT) else sys.argv[0]
    command = "python " + " ".join([shown, *sys.argv[1:]])
    report = {**report, "command": command}
    machine = report.get("machine")
    text = markdown.rstrip() + f"\n\nCommand: `{command}`.\n" + (machine_line(machine) + "\n" if machine else "")
    paths = [atomic_write_json(out / f"{name}.json", report), atomic_write_text(out / f"{name}.md", text)]
    if figure is not None:
        import matplotlib.pyplot as plt

        paths.append(atomic_save_figure(figure, out / f"{name}.png"))
        plt.close(figure)
    return paths
