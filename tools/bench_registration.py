"""Benchmark: accuracy and time of image registration, and the cost of ICP against the number of points.

Part 1 (accuracy and time, real images). CamVid frames (480x360) from ``../shared/data/camvid`` get a
known rigid motion about the image centre: angle uniform in [-90, 90] deg, translation uniform within
+-10% of the width/height. The moving image is ``cv2.warpAffine(ref, T[:2], (w, h),
flags=INTER_LINEAR | WARP_INVERSE_MAP)``, so ``T`` is exactly ``T_ref_mov`` (black borders included).
Each case is registered by

- ``pcreg.register`` with ``backend="reference"`` (pcreg's ICP) and with ``backend="open3d"``;
- OpenCV's ``findTransformECCMultiScale`` (4 levels, MOTION_EUCLIDEAN, grayscale float32, from the
  identity, as the thesis's aligner would be; no masks: OpenCV 5.0.0's multi-scale ECC gives the same
  result with and without a ``sampleMask``). ECC's warp maps reference pixels to moving pixels, so
  ``T_ref_mov = inv(W)``; when ECC throws (it does when it does not converge) the case counts as a
  failure (error = inf).

The error is the largest distance (px) between the moving image's four corners mapped by the estimate
and by the truth (``pcreg.registration.transforms.max_corner_error``); success is error <= 1 px. Times are wall
clock around each call (ECC's includes the grayscale conversion); the methods run in a shuffled order
per case and the time ratio pcreg / ECC is taken per case, in the same run, and summarised by its
median. A second sweep with angles uniform in [-180, 180] gives the success rate over angle.

Part 2 (scaling). Identical clouds of 1k..100k points -- 2-D: the strongest-gradient pixels (sub-pixel)
of a CamVid frame upscaled 3x and of its copy rotated by 3 deg and shifted; 3-D: random subsets of the
LiDAR pair ``../shared/data/scans`` -- registered by pcreg's reference ICP
(``pcreg.registration.reference.icp_reference``) and by Open3D's legacy ``registration_icp`` called directly in
one call, with the same correspondence distance and exactly ``--icp-iterations`` iterations
(thresholds 0, so neither stops early). Both timings include building the KD-tree (Open3D builds it
inside the call; the numpy -> PointCloud conversion is timed apart and not counted). The two
backends alternate within each repeat; the ratio reference / Open3D is taken per repeat.

    python tools/bench_registration.py --out out/bench [--cases 200] [--sweep-cases 120] [--seed 0] [--quick]

Writes ``registration.json`` (every raw number, the machine, the command line), ``registration.md``
(tables), ``registration_accuracy.png`` and ``registration_scaling.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_DATA = REPO_ROOT.parent / "shared" / "data"

METHODS = ("pcreg_reference", "pcreg_open3d", "ecc")
LABELS = {
    "pcreg_reference": "pcreg.register (reference ICP)",
    "pcreg_open3d": "pcreg.register (Open3D ICP)",
    "ecc": "OpenCV ECC multi-scale",
}
COLORS = {"pcreg_reference": "tab:blue", "pcreg_open3d": "tab:orange", "ecc": "tab:green"}
STYLES = {"pcreg_reference": ("-", "o"), "pcreg_open3d": ("-", "s"), "ecc": ("-", "^")}
SUCCESS_PX = 1.0
FLOORS = {"median_px": 0.1, "p95_px": 0.5, "success": 0.99, "time_ratio_vs_ecc": 1.0, "icp_ratio_vs_open3d": 1.0}


# ---------------------------------------------------------------------------------------------------
# Machine
# ---------------------------------------------------------------------------------------------------

def machine_info() -> dict:
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
        "git_commit": commit, "pcreg_dirty": dirty, "load_average_at_start": load,
    }


# ---------------------------------------------------------------------------------------------------
# Part 1: images with known rigid motions
# ---------------------------------------------------------------------------------------------------

def find_images(data: Path) -> list[Path]:
    return sorted((data / "camvid").glob("*/images/*.png"))


def make_cases(images: list[Path], n: int, *, max_angle: float, seed: int, shape: tuple[int, int]) -> list[dict]:
    """``n`` cases: an image, an angle uniform in [-max_angle, max_angle], a shift within +-10% of the size."""
    rng = np.random.default_rng(seed)
    h, w = shape
    cases = []
    for i in range(n):
        cases.append({
            "case": i,
            "image": str(images[int(rng.integers(len(images)))]),
            "angle_deg": float(rng.uniform(-max_angle, max_angle)),
            "tx": float(rng.uniform(-0.1 * w, 0.1 * w)),
            "ty": float(rng.uniform(-0.1 * h, 0.1 * h)),
            "order_seed": int(rng.integers(2**31)),
        })
    return cases


def truth_matrix(case: dict, shape: tuple[int, ...]) -> np.ndarray:
    from pcreg.registration.transforms import about_point, image_center, rigid2d

    c = image_center(shape)
    return about_point(rigid2d(case["angle_deg"], case["tx"], case["ty"]), c, c)


def make_moving(reference: np.ndarray, T_ref_mov: np.ndarray) -> np.ndarray:
    """The moving image whose pixel x shows the reference at ``T_ref_mov @ x`` (black outside)."""
    import cv2

    h, w = reference.shape[:2]
    return cv2.warpAffine(reference, T_ref_mov[:2], (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def ecc_register(reference: np.ndarray, moving: np.ndarray, *, levels: int = 4) -> np.ndarray:
    """``T_ref_mov`` by OpenCV's multi-scale ECC (Euclidean) from the identity; raises cv2.error on failure."""
    import cv2

    ref = cv2.cvtColor(reference, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mov = cv2.cvtColor(moving, cv2.COLOR_RGB2GRAY).astype(np.float32)
    params = cv2.ECCParameters()
    params.motionType = cv2.MOTION_EUCLIDEAN
    params.nlevels = levels
    _, W = cv2.findTransformECCMultiScale(ref, mov, np.eye(2, 3, dtype=np.float32), params)
    W3 = np.vstack([np.asarray(W, np.float64), [0.0, 0.0, 1.0]])
    return np.linalg.inv(W3)  # ECC's W maps reference -> moving pixels


def _run_method(method: str, reference: np.ndarray, moving: np.ndarray) -> tuple[np.ndarray | None, dict]:
    import pcreg

    if method == "pcreg_reference":
        r = pcreg.register(reference, moving, backend="reference")
        return r.matrix, {"fitness": r.fitness, "inlier_rmse": r.inlier_rmse, "iterations": r.iterations,
                          "inner_seconds": r.seconds}
    if method == "pcreg_open3d":
        r = pcreg.register(reference, moving, backend="open3d")
        return r.matrix, {"fitness": r.fitness, "inlier_rmse": r.inlier_rmse, "iterations": r.iterations,
                          "inner_seconds": r.seconds}
    if method == "ecc":
        return ecc_register(reference, moving), {}
    raise ValueError(method)


def run_case(case: dict, methods: tuple[str, ...], cache: dict) -> dict:
    """Register one synthetic pair with every method; errors in px, wall-clock seconds."""
    import cv2

    from pcreg.registration.transforms import max_corner_error

    path = case["image"]
    if path not in cache:
        cache[path] = cv2.cvtColor(cv2.imread(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    reference = cache[path]
    T = truth_matrix(case, reference.shape)
    moving = make_moving(reference, T)
    out = dict(case)
    order = list(methods)
    np.random.default_rng(case["order_seed"]).shuffle(order)
    out["order"] = order
    for m in order:
        t0 = time.perf_counter()
        try:
            M, extra = _run_method(m, reference, moving)
            failure = None
        except (cv2.error, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # pcreg errors are ValueErrors
            M, extra, failure = None, {}, f"{type(exc).__name__}: {str(exc).strip().splitlines()[-1][:200]}"
        seconds = time.perf_counter() - t0
        err = float("inf") if M is None or not np.all(np.isfinite(M)) else max_corner_error(M, T, reference.shape)
        out[m] = {"error_px": err, "seconds": seconds, "failure": failure, **extra,
                  "matrix": None if M is None else np.asarray(M).tolist()}
    return out


def summarise(rows: list[dict], methods: tuple[str, ...]) -> dict:
    """Per method: median / p95 error, success rate, median seconds, median per-case time ratio vs ECC."""
    summary = {}
    for m in methods:
        err = np.array([r[m]["error_px"] for r in rows])
        sec = np.array([r[m]["seconds"] for r in rows])
        s = {"cases": len(rows), "median_px": float(np.median(err)),
             "p95_px": float(np.percentile(err, 95, method="inverted_cdf")) if len(err) else float("nan"),
             "success": float(np.mean(err <= SUCCESS_PX)), "exceptions": int(sum(r[m]["failure"] is not None for r in rows)),
             "median_seconds": float(np.median(sec))}
        if "ecc" in methods:
            s["time_ratio_vs_ecc"] = float(np.median(sec / np.array([r["ecc"]["seconds"] for r in rows])))
        summary[m] = s
    return summary


def success_by_angle(rows: list[dict], methods: tuple[str, ...], *, bin_deg: float = 20.0,
                     max_angle: float = 180.0) -> dict:
    edges = np.arange(-max_angle, max_angle + bin_deg / 2, bin_deg)
    ang = np.array([r["angle_deg"] for r in rows])
    idx = np.clip(np.digitize(ang, edges) - 1, 0, len(edges) - 2)
    out = {"edges": edges.tolist(), "counts": np.bincount(idx, minlength=len(edges) - 1).tolist()}
    for m in methods:
        ok = np.array([r[m]["error_px"] <= SUCCESS_PX for r in rows])
        out[m] = [float(ok[idx == b].mean()) if np.any(idx == b) else float("nan") for b in range(len(edges) - 1)]
    return out


def run_images(data: Path, *, cases: int, sweep_cases: int, seed: int, methods: tuple[str, ...]) -> dict | None:
    import cv2

    from pcreg._runner import progress

    images = find_images(data)
    if not images:
        print(f"skipping the image benchmark: no CamVid frames under {data / 'camvid'}/*/images/", file=sys.stderr)
        return None
    first = cv2.imread(str(images[0]), cv2.IMREAD_COLOR)
    shape = first.shape[:2]
    cache: dict = {}
    # Warm-up: imports, Open3D's first call, OpenCV's thread pool; not recorded.
    for c in make_cases(images, 2, max_angle=30.0, seed=seed + 999, shape=shape):
        run_case(c, methods, cache)
    sets = {}
    for name, n, max_angle, s in (("pm90", cases, 90.0, seed), ("pm180", sweep_cases, 180.0, seed + 1)):
        rows = []
        for c in progress(make_cases(images, n, max_angle=max_angle, seed=s, shape=shape),
                          desc=f"images ±{max_angle:g}°", total=n):
            rows.append(run_case(c, methods, cache))
        sets[name] = {"max_angle_deg": max_angle, "seed": s, "rows": rows, "summary": summarise(rows, methods),
                      "success_by_angle": success_by_angle(rows, methods, bin_deg=30.0 if max_angle > 90 else 15.0,
                                                           max_angle=max_angle)}
    return {"image_shape": list(shape), "n_images": len(images), "methods": list(methods), "sets": sets}


# ---------------------------------------------------------------------------------------------------
# Part 2: ICP cost against the number of points
# ---------------------------------------------------------------------------------------------------

def clouds_2d(data: Path, sizes: list[int], seed: int) -> tuple[str, dict[int, tuple[np.ndarray, np.ndarray]], float]:
    """(description, {N: (source, target)}, correspondence distance) for 2-D clouds."""
    import cv2

    import pcreg
    from pcreg.registration.transforms import about_point, image_center, rigid2d

    images = find_images(data)
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


def time_icp_pair(src: np.ndarray, tgt: np.ndarray, *, dist: float, iterations: int, repeats: int) -> dict:
    """Reference vs Open3D legacy ICP on identical clouds, exactly ``iterations`` iterations each."""
    import open3d as o3d

    from pcreg.registration.open3d_icp import to_pointcloud
    from pcreg.registration.reference import icp_reference

    reg = o3d.pipelines.registration
    d = src.shape[1]
    est = reg.TransformationEstimationPointToPoint()
    crit = reg.ICPConvergenceCriteria(relative_fitness=0.0, relative_rmse=0.0, max_iteration=iterations)

    def ref_run():
        t0 = time.perf_counter()
        r = icp_reference(src, tgt, model="rigid", max_correspondence_distance=dist, init=np.eye(d + 1),
                          max_iteration=iterations, relative_fitness=0.0, relative_rmse=0.0)
        return time.perf_counter() - t0, r.matrix, r.fitness, r.inlier_rmse, r.iterations

    def o3d_run():
        t0 = time.perf_counter()
        s, t = to_pointcloud(src), to_pointcloud(tgt)
        t1 = time.perf_counter()
        r = reg.registration_icp(s, t, dist, np.eye(4), est, crit)
        t2 = time.perf_counter()
        return t2 - t1, t1 - t0, np.asarray(r.transformation), float(r.fitness), float(r.inlier_rmse)

    ref_run(), o3d_run()  # warm-up
    ref_s, o3d_s, conv_s, ratio = [], [], [], []
    for k in range(repeats):
        if k % 2 == 0:
            a = ref_run()
            b = o3d_run()
        else:
            b = o3d_run()
            a = ref_run()
        ref_s.append(a[0])
        o3d_s.append(b[0])
        conv_s.append(b[1])
        ratio.append(a[0] / b[0])
    T_ref, T_o3d = a[1], b[2]
    if d == 2:
        T_o3d = T_o3d[np.ix_([0, 1, 3], [0, 1, 3])]
    return {"source_points": len(src), "target_points": len(tgt), "iterations_reference": a[4],
            "reference_seconds": ref_s, "open3d_seconds": o3d_s, "open3d_conversion_seconds": conv_s,
            "ratio_reference_over_open3d": ratio,
            "median_reference_seconds": float(np.median(ref_s)), "median_open3d_seconds": float(np.median(o3d_s)),
            "median_ratio": float(np.median(ratio)),
            "fitness_reference": a[2], "fitness_open3d": b[3], "rmse_reference": a[3], "rmse_open3d": b[4],
            "max_abs_matrix_difference": float(np.abs(T_ref - T_o3d).max())}


def loglog_slope(n: list[float], t: list[float]) -> float:
    return float(np.polyfit(np.log(n), np.log(t), 1)[0])


def run_scaling(data: Path, *, sizes: list[int], iterations: int, repeats: int, seed: int) -> dict:
    from pcreg._runner import progress

    kinds = {}
    c2 = clouds_2d(data, sizes, seed)
    c3 = clouds_3d(data, sizes, seed)
    jobs = [("2-D", c2)] + ([("3-D", c3)] if c3 else [])
    total = sum(len(c[1]) for _, c in jobs)
    with progress(total=total, desc="ICP scaling") as bar:
        for kind, (desc, clouds, dist) in jobs:
            rows = []
            for n, (src, tgt) in clouds.items():
                row = time_icp_pair(src, tgt, dist=dist, iterations=iterations, repeats=repeats)
                row["n"] = int(n)
                rows.append(row)
                bar.update(1)
            ns = [r["source_points"] for r in rows]
            fit = {}
            for b in ("reference", "open3d"):
                t = [r[f"median_{b}_seconds"] for r in rows]
                nlogn = [x * np.log2(x) for x in ns]
                fit[b] = {"loglog_slope": loglog_slope(ns, t),
                          # seconds / (N log2 N), normalised to its value at the smallest N: flat or falling
                          # means the cost grows no faster than N log N
                          "cost_per_nlogn_relative": [float((ti / c) / (t[0] / nlogn[0])) for ti, c in zip(t, nlogn)]}
            kinds[kind] = {"description": desc, "max_correspondence_distance": dist, "rows": rows, "fit": fit,
                           "nlogn_loglog_slope": loglog_slope(ns, [x * np.log(x) for x in ns])}
    return {"iterations": iterations, "repeats": repeats, "kinds": kinds}


# ---------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------

def _met(ok: bool) -> str:
    return "met" if ok else "NOT met"


def render_markdown(report: dict) -> str:
    from pcreg.outputs import markdown_table

    m = report["machine"]
    lines = [f"# Registration benchmark\n",
             f"Command: `{report['command']}`  \n"
             f"Machine: {m['cpu_model']}, {m['cpu_count']} CPUs (load average at start "
             f"{', '.join(f'{x:.1f}' for x in m['load_average_at_start'] or [])}), {m['platform']}; Python {m['python']}, "
             f"numpy {m['numpy']}, scipy {m['scipy']}, OpenCV {m['opencv']}, Open3D {m['open3d']}; "
             f"pcreg at {str(m['git_commit'])[:12]}{' (pcreg/ modified)' if m['pcreg_dirty'] else ''}.  \n"
             f"Started {report['started']}, took {report['wall_seconds'] / 60:.1f} min. Times are wall clock on a shared "
             "machine; compare the ratios (taken per case / per repeat in the same run), not the absolute times.\n"]
    img = report.get("images")
    floors = []
    if img:
        for name, title in (("pm90", "±90°"), ("pm180", "±180°")):
            st = img["sets"][name]
            lines.append(f"## Real images, {img['image_shape'][1]}x{img['image_shape'][0]} CamVid, rigid motion, "
                         f"angle in {title}, shift within ±10% ({len(st['rows'])} cases, seed {st['seed']})\n")
            header = ["method", "median error (px)", "p95 error (px)", "success (<= 1 px)", "ECC exceptions",
                      "median time (ms)", "median of per-case time ratios vs ECC"]
            rows = []
            for meth in img["methods"]:
                s = st["summary"][meth]
                rows.append([LABELS[meth], f"{s['median_px']:.3f}", f"{s['p95_px']:.3f}", f"{100 * s['success']:.1f}%",
                             s["exceptions"] if meth.startswith("ecc") else "-", f"{1e3 * s['median_seconds']:.0f}",
                             f"{s.get('time_ratio_vs_ecc', float('nan')):.2f}"])
            lines.append(markdown_table(header, rows))
            sba = st["success_by_angle"]
            e = sba["edges"]
            header = ["angle bin (deg)", "cases"] + [LABELS[x] for x in img["methods"]]
            rows = [[f"[{e[b]:.0f}, {e[b + 1]:.0f})", sba["counts"][b]]
                    + [f"{100 * sba[x][b]:.0f}%" if np.isfinite(sba[x][b]) else "-" for x in img["methods"]]
                    for b in range(len(e) - 1)]
            lines.append(f"\nSuccess rate (error <= 1 px) by angle, {title}:\n")
            lines.append(markdown_table(header, rows))
            lines.append("")
        s = img["sets"]["pm90"]["summary"]
        for meth in ("pcreg_reference", "pcreg_open3d"):
            if meth not in s:
                continue
            floors += [
                [f"{LABELS[meth]}: median error <= {FLOORS['median_px']} px (±90°)", f"{s[meth]['median_px']:.3f} px",
                 _met(s[meth]["median_px"] <= FLOORS["median_px"])],
                [f"{LABELS[meth]}: p95 error <= {FLOORS['p95_px']} px", f"{s[meth]['p95_px']:.3f} px",
                 _met(s[meth]["p95_px"] <= FLOORS["p95_px"])],
                [f"{LABELS[meth]}: success >= {100 * FLOORS['success']:.0f}%", f"{100 * s[meth]['success']:.1f}%",
                 _met(s[meth]["success"] >= FLOORS["success"])],
                [f"{LABELS[meth]}: median time ratio vs ECC < 1", f"{s[meth]['time_ratio_vs_ecc']:.2f}",
                 _met(s[meth]["time_ratio_vs_ecc"] < FLOORS["time_ratio_vs_ecc"])],
            ]
        fails = [r for r in img["sets"]["pm90"]["rows"] if r["pcreg_reference"]["error_px"] > SUCCESS_PX]
        if fails:
            lines.append("Cases (±90°) where pcreg.register (reference) missed 1 px:\n")
            lines.append(markdown_table(
                ["case", "image", "angle (deg)", "tx, ty (px)", "reference error (px)", "open3d error (px)", "ECC error (px)",
                 "failure"],
                [[r["case"], Path(r["image"]).name, f"{r['angle_deg']:.1f}", f"{r['tx']:.1f}, {r['ty']:.1f}",
                  f"{r['pcreg_reference']['error_px']:.3g}", f"{r['pcreg_open3d']['error_px']:.3g}",
                  f"{r['ecc']['error_px']:.3g}", r["pcreg_reference"]["failure"] or ""] for r in fails]))
            lines.append("")
    else:
        lines.append("Real-image benchmark skipped: no CamVid frames found.\n")
    sc = report.get("scaling")
    if sc:
        lines.append(f"## ICP cost against the number of points: reference ICP vs Open3D legacy ICP "
                     f"({sc['iterations']} iterations each, thresholds 0, median of {sc['repeats']} repeats)\n")
        for kind, k in sc["kinds"].items():
            lines.append(f"{kind}: {k['description']}; correspondence distance {k['max_correspondence_distance']:g}.\n")
            header = ["points (source / target)", "reference (ms)", "Open3D (ms)", "median ratio reference / Open3D",
                      "reference cost / (N log N), rel.", "Open3D cost / (N log N), rel.", "max |ΔT|"]
            rows = [[f"{r['source_points']} / {r['target_points']}", f"{1e3 * r['median_reference_seconds']:.1f}",
                     f"{1e3 * r['median_open3d_seconds']:.1f}", f"{r['median_ratio']:.2f}",
                     f"{k['fit']['reference']['cost_per_nlogn_relative'][i]:.2f}",
                     f"{k['fit']['open3d']['cost_per_nlogn_relative'][i]:.2f}",
                     f"{r['max_abs_matrix_difference']:.1e}"] for i, r in enumerate(k["rows"])]
            lines.append(markdown_table(header, rows))
            lines.append(f"\nLog-log slope of time against N: reference {k['fit']['reference']['loglog_slope']:.2f}, "
                         f"Open3D {k['fit']['open3d']['loglog_slope']:.2f} (N log N over this range: "
                         f"{k['nlogn_loglog_slope']:.2f}).\n")
            ratios = [r["median_ratio"] for r in k["rows"]]
            floors.append([f"{kind} clouds: reference ICP no slower than Open3D (median ratio <= 1), per size",
                           ", ".join(f"{x:.2f}" for x in ratios), _met(max(ratios) <= FLOORS["icp_ratio_vs_open3d"])])
            floors.append([f"{kind} clouds: reference ICP cost grows no worse than N log N "
                           "(log-log slope within 0.05 of N log N's)",
                           f"slope {k['fit']['reference']['loglog_slope']:.2f} vs {k['nlogn_loglog_slope']:.2f}",
                           _met(k["fit"]["reference"]["loglog_slope"] <= k["nlogn_loglog_slope"] + 0.05)])
    if floors:
        lines.insert(1, "## Floors (issue 2)\n\n" + markdown_table(["floor", "measured", ""], floors))
    return "\n".join(lines) + "\n"


def plot_accuracy(report: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img = report["images"]
    methods = img["methods"]
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.0))
    rows90 = img["sets"]["pm90"]["rows"]
    cap = 1e3
    ax = axes[0]
    for m in methods:
        err = np.sort(np.clip([r[m]["error_px"] for r in rows90], 1e-4, cap))
        ax.step(err, np.arange(1, len(err) + 1) / len(err), where="post", color=COLORS[m], ls=STYLES[m][0], lw=2,
                label=LABELS[m])
    ax.axvline(SUCCESS_PX, color="k", ls="--", lw=1)
    ax.text(SUCCESS_PX * 1.1, 0.02, "1 px", fontsize=9)
    ax.set_xscale("log")
    ax.set_xlim(1e-3, cap)
    ax.set_ylim(0, 1.01)
    ax.set_xlabel("max corner error (px, log; failures at the right edge)")
    ax.set_ylabel("fraction of cases with error <= x")
    ax.set_title(f"Error distribution, |angle| <= 90° ({len(rows90)} cases)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")

    ax = axes[1]
    for m in methods:
        ang = [r["angle_deg"] for r in rows90]
        err = np.clip([r[m]["error_px"] for r in rows90], 1e-4, cap)
        ax.scatter(ang, err, s=14, color=COLORS[m], marker=STYLES[m][1], alpha=0.6, label=LABELS[m])
    ax.axhline(SUCCESS_PX, color="k", ls="--", lw=1)
    ax.set_yscale("log")
    ax.set_ylim(1e-3, cap * 1.5)
    ax.set_xlabel("rotation angle (deg)")
    ax.set_ylabel("max corner error (px, log; failures at the top)")
    ax.set_title("Error against angle, |angle| <= 90°")
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[2]
    sba = img["sets"]["pm180"]["success_by_angle"]
    e = np.array(sba["edges"])
    mid = (e[:-1] + e[1:]) / 2
    for m in methods:
        ax.plot(mid, 100 * np.array(sba[m]), color=COLORS[m], ls=STYLES[m][0], marker=STYLES[m][1], lw=2,
                label=LABELS[m])
    ax.set_xticks(np.arange(-180, 181, 45))
    ax.set_ylim(-3, 103)
    ax.set_xlabel(f"rotation angle (deg), {e[1] - e[0]:.0f}° bins")
    ax.set_ylabel("success rate (error <= 1 px), %")
    ax.set_title(f"Success over angle, ±180° sweep ({len(img['sets']['pm180']['rows'])} cases)")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return fig


def plot_scaling(report: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc = report["scaling"]
    kinds = list(sc["kinds"].items())
    fig, axes = plt.subplots(1, len(kinds) + 1, figsize=(6 * (len(kinds) + 1), 4.8))
    for ax, (kind, k) in zip(axes, kinds):
        n = np.array([r["source_points"] for r in k["rows"]], dtype=float)
        for b, color, label in (("reference", "tab:blue", "pcreg reference ICP"), ("open3d", "tab:orange", "Open3D legacy ICP")):
            t = np.array([r[f"median_{b}_seconds"] for r in k["rows"]])
            allt = [r[f"{b}_seconds"] for r in k["rows"]]
            for x, ts in zip(n, allt):
                ax.scatter([x] * len(ts), ts, s=8, color=color, alpha=0.35)
            ax.plot(n, t, "o-", color=color, lw=2, label=f"{label} (slope {k['fit'][b]['loglog_slope']:.2f})")
        # N log N through the reference's median at the middle size.
        i = len(n) // 2
        t_ref = np.array([r["median_reference_seconds"] for r in k["rows"]])
        nn = np.geomspace(n.min(), n.max(), 50)
        ax.plot(nn, t_ref[i] * nn * np.log(nn) / (n[i] * np.log(n[i])), "k--", lw=1.2, label="∝ N log N")
        ax.plot(nn, t_ref[i] * nn / n[i], ":", color="gray", lw=1.2, label="∝ N")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("points per cloud N")
        ax.set_ylabel(f"seconds for {sc['iterations']} ICP iterations")
        ax.set_title(f"{kind} clouds: time vs N")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[-1]
    for (kind, k), marker in zip(kinds, "os"):
        n = [r["source_points"] for r in k["rows"]]
        ax.plot(n, [r["median_ratio"] for r in k["rows"]], marker + "-", lw=2, label=f"{kind} clouds")
    ax.axhline(1.0, color="k", ls="--", lw=1)
    ax.set_xscale("log")
    ax.set_ylim(0, max(2.0, 1.1 * max(r["median_ratio"] for _, k in kinds for r in k["rows"])))
    ax.set_xlabel("points per cloud N")
    ax.set_ylabel("median time ratio reference / Open3D")
    ax.set_title("Same clouds, same iterations: ratio (< 1: reference faster)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def write_outputs(report: dict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pcreg.outputs import atomic_save_figure, atomic_write_json, atomic_write_text

    paths = [atomic_write_json(out / "registration.json", report),
             atomic_write_text(out / "registration.md", render_markdown(report))]
    if report.get("images"):
        fig = plot_accuracy(report)
        paths.append(atomic_save_figure(fig, out / "registration_accuracy.png"))
        plt.close(fig)
    if report.get("scaling"):
        fig = plot_scaling(report)
        paths.append(atomic_save_figure(fig, out / "registration_scaling.png"))
        plt.close(fig)
    return paths


# ---------------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench", help="output folder (default out/bench)")
    parser.add_argument("--cases", type=int, default=None, help="cases with |angle| <= 90 deg (default 200, --quick 30)")
    parser.add_argument("--sweep-cases", type=int, default=None, help="cases with |angle| <= 180 deg (default 120, --quick 24)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sizes", type=str, default=None, help="cloud sizes, comma-separated (default 1000,3000,10000,30000,100000)")
    parser.add_argument("--icp-iterations", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=None, help="repeats per cloud size (default 7, --quick 3)")
    parser.add_argument("--quick", action="store_true", help="fewer cases, sizes and repeats")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder (default ../shared/data)")
    parser.add_argument("--skip-images", action="store_true")
    parser.add_argument("--skip-scaling", action="store_true")
    args = parser.parse_args(argv)
    cases = args.cases if args.cases is not None else (30 if args.quick else 200)
    sweep = args.sweep_cases if args.sweep_cases is not None else (24 if args.quick else 120)
    repeats = args.repeats if args.repeats is not None else (3 if args.quick else 7)
    sizes = ([int(s) for s in args.sizes.split(",")] if args.sizes
             else ([1000, 10000, 100000] if args.quick else [1000, 3000, 10000, 30000, 100000]))
    if cases < 1 or sweep < 1 or repeats < 1 or args.icp_iterations < 1 or min(sizes) < 10:
        print("error: --cases, --sweep-cases, --repeats and --icp-iterations must be >= 1, sizes >= 10", file=sys.stderr)
        return 2
    out = Path(args.out)
    started = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    t0 = time.perf_counter()
    report: dict = {"command": " ".join(["python", "tools/bench_registration.py"] + (sys.argv[1:] if argv is None else list(argv))),
                    "started": started, "machine": machine_info(),
                    "settings": {"cases": cases, "sweep_cases": sweep, "seed": args.seed, "sizes": sizes,
                                 "icp_iterations": args.icp_iterations, "repeats": repeats, "success_px": SUCCESS_PX,
                                 "register_options": "defaults (levels=4, iterations=14, init='auto', model='rigid')",
                                 "ecc_options": "nlevels=4, MOTION_EUCLIDEAN, default criteria, identity start"},
                    "floors": FLOORS}
    try:
        if not args.skip_images:
            report["images"] = run_images(args.data, cases=cases, sweep_cases=sweep, seed=args.seed, methods=METHODS)
        if not args.skip_scaling:
            report["scaling"] = run_scaling(args.data, sizes=sizes, iterations=args.icp_iterations, repeats=repeats,
                                            seed=args.seed)
    except KeyboardInterrupt:
        print("interrupted; nothing written", file=sys.stderr)
        return 130
    report["wall_seconds"] = time.perf_counter() - t0
    try:
        paths = write_outputs(report, out)
    except OSError as exc:
        print(f"error: cannot write to {out}: {exc}", file=sys.stderr)
        return 2
    print(Path(out, "registration.md").read_text())
    print("wrote " + ", ".join(str(p) for p in paths), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
