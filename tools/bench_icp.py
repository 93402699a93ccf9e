"""Benchmark: the reference ICP against Open3D's legacy ICP and small_gicp's ICP, 1k..100k points, 2-D and 3-D.

Identical clouds (``clouds_2d`` and ``clouds_3d`` of ``tools/benchlib.py``, as in
``tools/bench_registration.py``): 2-D, the strongest-gradient pixels (sub-pixel) of a CamVid frame
upscaled 3x and of its copy rotated by 3 deg and shifted; 3-D, random subsets of the LiDAR pair
``../shared/data/scans``. Each implementation runs point-to-point rigid ICP
from the identity with the same correspondence distance for exactly ``--iterations`` iterations:

- ``reference``: ``pcreg.registration.reference.icp_reference`` (thresholds 0), building its grid;
- ``open3d``: ``open3d.pipelines.registration.registration_icp`` in one call (thresholds 0), building
  its KD-tree inside the call;
- ``small_gicp``: ``small_gicp.align(..., registration_type="ICP")`` with its KD-tree built in the
  timing and its epsilons 0 (Gauss-Newton steps: its transform is not Open3D's, only its time is compared).

Conversions numpy -> PointCloud are not timed. The order of the three rotates per repeat; ratios are
taken per repeat and summarised by their median. ``transform difference`` is the largest absolute
difference between the reference's and Open3D's matrices; where it exceeds 1e-9, ``tied queries`` says
how many source points had two target points at exactly the same distance at the start (both clouds
lie on the pixel lattice there): the reference breaks ties by the lowest index, Open3D's KD-tree by
its traversal order. The equality check holds the sizes without tied queries to 1e-9 and lists
the others. The cost curve (PNG) shows seconds / (N log2 N), relative to its value at the
smallest N: flat or falling means the cost grows no faster than N log N.

The profile section splits the reference's time at the smallest N (where a fixed cost per call weighs
most) with ``cProfile``: the index build, the first match, the compiled loop (every iteration: the
update, the move, the search, the sums and the stopping rule, without returning to Python) and the
Python around them. cProfile adds a little to every Python call, so the Python part reads high.

The last section runs ``pcreg crosscheck`` on the LiDAR pair itself (reference and Open3D, the command's
defaults) ``--crosscheck-runs`` times and compares the seconds each implementation reports.

``--threads N`` gives every implementation N threads: numba's (``NUMBA_NUM_THREADS``), Open3D's OpenMP
(``OMP_NUM_THREADS``, read when Open3D loads) and small_gicp's ``num_threads``; without it each library
takes its default (all CPUs). The targets: reference / Open3D <= 1.0 at every size with one thread, and
with more <= 1.0 in 2-D and <= 0.8 in 3-D.

    python tools/bench_icp.py --out out/bench [--threads 1] [--sizes 1000,3000,10000,30000,100000] [--iterations 15] [--repeats 5]

Writes bench_icp.json, bench_icp.md and bench_icp.png to --out.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import SHARED_DATA, checks_markdown, clouds_2d, clouds_3d, finish, machine_info

IMPLEMENTATIONS = ("reference", "open3d", "small_gicp")


def tied_queries(src: np.ndarray, tgt: np.ndarray, dist: float) -> int:
    """Source points whose two nearest target points (within ``dist``) are exactly equidistant."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(tgt).query(src, k=2, distance_upper_bound=dist)
    return int(np.count_nonzero(np.isfinite(d[:, 1]) & (d[:, 0] == d[:, 1])))


def time_pair(src: np.ndarray, tgt: np.ndarray, *, dist: float, iterations: int, repeats: int,
              implementations=IMPLEMENTATIONS, threads: int | None = None) -> dict:
    import open3d as o3d

    from pcreg.registration.open3d_icp import to_pointcloud
    from pcreg.registration.icp_options import ICPOptions
    from pcreg.registration.reference import icp_reference
    from pcreg.registration.transforms import lift_to_3d

    d = src.shape[1]
    reg = o3d.pipelines.registration
    est = reg.TransformationEstimationPointToPoint()
    crit = reg.ICPConvergenceCriteria(relative_fitness=0.0, relative_rmse=0.0, max_iteration=iterations)
    s3 = np.column_stack([src, np.zeros(len(src))]) if d == 2 else src
    t3 = np.column_stack([tgt, np.zeros(len(tgt))]) if d == 2 else tgt

    def reference():
        t0 = time.perf_counter()
        r = icp_reference(src, tgt, ICPOptions(max_correspondence_distance=dist, max_iteration=iterations,
                                               relative_fitness=0.0, relative_rmse=0.0), init=np.eye(d + 1))
        return time.perf_counter() - t0, lift_to_3d(r.matrix) if d == 2 else r.matrix

    def open3d():
        s, t = to_pointcloud(src), to_pointcloud(tgt)
        t0 = time.perf_counter()
        r = reg.registration_icp(s, t, dist, np.eye(4), est, crit)
        return time.perf_counter() - t0, np.asarray(r.transformation)

    def small_gicp():
        import small_gicp as sg

        s, t = sg.PointCloud(s3), sg.PointCloud(t3)
        t0 = time.perf_counter()
        tree = sg.KdTree(t, num_threads=threads or 2)
        r = sg.align(t, s, tree, np.eye(4), registration_type="ICP", max_correspondence_distance=dist,
                     num_threads=threads or 2, max_iterations=iterations, rotation_epsilon=0.0, translation_epsilon=0.0)
        return time.perf_counter() - t0, np.asarray(r.T_target_source)

    fns = {"reference": reference, "open3d": open3d, "small_gicp": small_gicp}
    names = [n for n in IMPLEMENTATIONS if n in implementations]
    for n in names:  # warm-up: imports, compiled kernels, page faults
        fns[n]()
    secs = {n: [] for n in names}
    mats = {}
    for k in range(repeats):
        order = names[k % len(names):] + names[:k % len(names)]
        for n in order:
            s, M = fns[n]()
            secs[n].append(s)
            mats[n] = M
    row = {"source_points": len(src), "target_points": len(tgt), "seconds": secs,
           "median_seconds": {n: float(np.median(v)) for n, v in secs.items()}}
    if "open3d" in secs:
        for n in names:
            if n != "open3d":
                row[f"ratio_{n}_over_open3d"] = float(np.median(np.array(secs[n]) / np.array(secs["open3d"])))
        if "reference" in mats:
            row["max_abs_matrix_difference"] = float(np.abs(mats["reference"] - mats["open3d"]).max())
            if row["max_abs_matrix_difference"] > 1e-9:
                row["tied_queries_at_start"] = tied_queries(src, tgt, dist)
    return row


#: (part, functions whose cumulative time it is), by ``(file name, function name)``; the parts are
#: disjoint and "the rest of the call" is the call's total minus them.
PROFILE_PARTS = (
    ("index build (KDTreeIndex)", (("kdtree.py", "__init__"),)),
    ("first match (move_and_match)", (("kdtree.py", "move_and_match"),)),
    # one thread or numba's threads (nn.threaded): the reference runs one of the two loops
    ("compiled loop (update, move, search, sums, stopping rule)", (("reference.py", "_moment_loop"),
                                                                   ("reference.py", "_moment_loop_threads"))),
)


def profile_reference(src: np.ndarray, tgt: np.ndarray, *, dist: float, iterations: int, calls: int) -> dict:
    """Where one reference ICP call's time goes (ms per call, by :data:`PROFILE_PARTS`), from cProfile
    over ``calls`` calls; what is left is the Python around the compiled loop (checks, set-up, the
    result)."""
    import cProfile
    import pstats

    from pcreg.registration.icp_options import ICPOptions
    from pcreg.registration.reference import icp_reference

    d = src.shape[1]

    def call():
        icp_reference(src, tgt, ICPOptions(max_correspondence_distance=dist, max_iteration=iterations,
                                           relative_fitness=0.0, relative_rmse=0.0), init=np.eye(d + 1))

    call()
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(calls):
        call()
    prof.disable()
    stats = pstats.Stats(prof).stats  # (file, line, name) -> (calls, primitive calls, tottime, cumtime, callers)

    def cum(keys) -> float:
        return sum(v[3] for (f, _, name), v in stats.items() if any(f.endswith(kf) and name == kn for kf, kn in keys))

    total = cum((("reference.py", "icp_reference"),))
    parts = {name: cum(keys) for name, keys in PROFILE_PARTS}
    parts["the rest of the call (checks, set-up, the result)"] = max(total - sum(parts.values()), 0.0)
    return {"source_points": len(src), "calls": calls, "total_ms": 1e3 * total / calls,
            "parts_ms": {k: 1e3 * v / calls for k, v in parts.items()}}


#: Each size is timed over at least this many source points per implementation (repeats of a small
#: cloud): a call of a few milliseconds is at the mercy of a shared machine's scheduler, and a median
#: of 5 such calls swung by +-0.5 in the ratio at 1k points.
MIN_POINTS_TIMED = 50_000


def repeats_at(n: int, repeats: int) -> int:
    """Repeats for a cloud of ``n`` points: ``repeats``, or more where that times under
    :data:`MIN_POINTS_TIMED` points."""
    return max(repeats, -(-MIN_POINTS_TIMED // max(n, 1)))


def run(data: Path, *, sizes: list[int], iterations: int, repeats: int, seed: int,
        implementations=IMPLEMENTATIONS, profile_calls: int = 20, threads: int | None = None) -> dict:
    from pcreg._runner import progress

    jobs = [("2-D", clouds_2d(data, sizes, seed))]
    c3 = clouds_3d(data, sizes, seed)
    if c3 is not None:
        jobs.append(("3-D", c3))
    kinds = {}
    with progress(total=sum(len(c[1]) for _, c in jobs), desc="ICP sizes") as bar:
        for kind, (desc, clouds, dist) in jobs:
            rows = []
            profile = None
            for n, (src, tgt) in clouds.items():
                if profile is None and "reference" in implementations and profile_calls > 0:
                    profile = profile_reference(src, tgt, dist=dist, iterations=iterations, calls=profile_calls)
                row = time_pair(src, tgt, dist=dist, iterations=iterations, repeats=repeats_at(len(src), repeats),
                                implementations=implementations, threads=threads)
                rows.append(row)
                bar.update(1)
            ns = np.array([r["source_points"] for r in rows], dtype=np.float64)
            curve = {}
            for n in rows[0]["median_seconds"]:
                t = np.array([r["median_seconds"][n] for r in rows])
                per = t / (ns * np.log2(ns))
                curve[n] = {"loglog_slope": float(np.polyfit(np.log(ns), np.log(t), 1)[0]) if len(ns) > 1 else None,
                            "cost_per_nlogn_relative": (per / per[0]).tolist()}
            kinds[kind] = {"description": desc, "max_correspondence_distance": dist, "rows": rows, "curve": curve,
                           "profile": profile}
    return {"iterations": iterations, "repeats": repeats, "threads": threads, "kinds": kinds}


def crosscheck_lidar(data: Path, repeats: int) -> dict | None:
    """``pcreg crosscheck`` on the LiDAR pair (``data/scans``, the command's defaults: reference and
    Open3D legacy, every iteration traced): each implementation's own seconds, ``repeats`` times; the
    ratio reference / Open3D per run, then the median. None without the pair."""
    src_path, tgt_path = data / "scans" / "source.ply", data / "scans" / "target.ply"
    if not (src_path.is_file() and tgt_path.is_file()):
        return None
    from pcreg.implementations.crosscheck import crosscheck, load_cloud

    source, target = load_cloud(src_path), load_cloud(tgt_path)
    crosscheck(target, source)  # warm-up: imports, compiled kernels, page faults
    runs = []
    for _ in range(repeats):
        rows = crosscheck(target, source).rows
        runs.append({n: float(rows[n]["seconds"]) for n in ("reference", "open3d")})
    ratios = [r["reference"] / r["open3d"] for r in runs]
    return {"source_points": len(source), "target_points": len(target), "runs": runs,
            "median_seconds": {n: float(np.median([r[n] for r in runs])) for n in ("reference", "open3d")},
            "ratio_reference_over_open3d": float(np.median(ratios)), "ratios": ratios}


#: The reference's time / (N log N) at the largest N, at most this many times the smallest N's: in 3-D a
#: denser LiDAR subset puts more points within each query's reach, and every implementation's time grows
#: faster than N log N there.
COST_TARGET = {"2-D": 1.0, "3-D": 1.5}


def ratio_target(kind: str, threads: int | None) -> float:
    """The target reference / Open3D legacy: 1.0 with one thread each, and with more 1.0 in 2-D and
    0.8 in 3-D (Open3D's legacy ICP takes no more from a second thread; the reference's search does)."""
    return 1.0 if threads == 1 or kind != "3-D" else 0.8


def set_threads(threads: int) -> None:
    """Give numba and OpenMP (Open3D) ``threads`` threads: their environment variables, read when each
    loads, so before either is imported; numba's count is also set where it is already loaded (a test
    calling :func:`main`). Open3D already loaded with another count is refused."""
    if "open3d" in sys.modules and os.environ.get("OMP_NUM_THREADS") != str(threads):
        raise SystemExit(f"--threads {threads}: Open3D was loaded before; run the benchmark as a script, "
                         f"or set OMP_NUM_THREADS={threads} before it starts")
    os.environ["OMP_NUM_THREADS"] = str(threads)
    if "numba" not in sys.modules:
        os.environ["NUMBA_NUM_THREADS"] = str(threads)
        return
    import numba

    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def render(report: dict) -> str:
    from pcreg.outputs import markdown_table

    threads = report.get("threads")
    lines = [f"## ICP: reference vs Open3D legacy vs small_gicp ({report['iterations']} iterations, "
             f"median of {report['repeats']} repeats, more below {MIN_POINTS_TIMED:,} points: "
             f"at least {MIN_POINTS_TIMED:,} points timed per size; "
             f"{'each library its default threads' if threads is None else f'{threads} thread(s) each'})\n"]
    checks = []
    for kind, k in report["kinds"].items():
        lines.append(f"{kind}: {k['description']}; correspondence distance {k['max_correspondence_distance']:g}.\n")
        impls = list(k["rows"][0]["median_seconds"])
        header = ["N"] + [f"{n} (ms)" for n in impls] + [f"{n} / open3d" for n in impls if n != "open3d"] + [
            "transform difference", "tied queries"]
        body = []
        for r in k["rows"]:
            body.append([r["source_points"]] + [1e3 * r["median_seconds"][n] for n in impls]
                        + [r.get(f"ratio_{n}_over_open3d", float("nan")) for n in impls if n != "open3d"]
                        + [f"{r.get('max_abs_matrix_difference', float('nan')):.1e}", r.get("tied_queries_at_start", 0)])
        lines.append(markdown_table(header, body, digits=2))
        slopes = ", ".join(f"{n} {c['loglog_slope']:.2f}" for n, c in k["curve"].items() if c["loglog_slope"] is not None)
        lines.append(f"Log-log slope of time against N: {slopes} (N log N over this range is about 1.1).\n")
        if "reference" in impls and "open3d" in impls:
            ratios = [r["ratio_reference_over_open3d"] for r in k["rows"]]
            target = ratio_target(kind, threads)
            checks.append((f"reference ICP <= {target}x Open3D legacy, {kind}, every size, "
                           f"{'default threads' if threads is None else f'{threads} thread(s)'}",
                           "max " + f"{max(ratios):.2f}x (" + ", ".join(f"{x:.2f}" for x in ratios) + ")",
                           max(ratios) <= target))
            # a tied query has two right answers (the reference takes the lower index, Open3D's KD-tree
            # the one its traversal meets first), so the steps may part there: sizes with ties are
            # reported, not held to the equality
            untied = [r["max_abs_matrix_difference"] for r in k["rows"] if not r.get("tied_queries_at_start", 0)]
            tied = [f"N = {r['source_points']}: {r['max_abs_matrix_difference']:.1e}, "
                    f"{r['tied_queries_at_start']} tied queries" for r in k["rows"] if r.get("tied_queries_at_start", 0)]
            measured = (f"max {max(untied):.1e}" if untied else "no size without tied queries") + (
                f" (sizes with ties, not held to it: {'; '.join(tied)})" if tied else "")
            checks.append((f"transforms equal to 1e-9, {kind}, sizes without tied queries", measured,
                           bool(untied) and max(untied) <= 1e-9))
            rel = k["curve"]["reference"]["cost_per_nlogn_relative"]
            checks.append((f"reference cost: time/(N log N) at the largest N <= {COST_TARGET[kind]}x the smallest's, {kind}",
                           f"{rel[-1]:.2f}x", rel[-1] <= COST_TARGET[kind]))
    profiles = {kind: k["profile"] for kind, k in report["kinds"].items() if k.get("profile")}
    if profiles:
        lines.append("### Profile: where the reference's time goes at the smallest N (cProfile, ms per call)\n")
        names = list(next(iter(profiles.values()))["parts_ms"])
        body = [[name] + [p["parts_ms"][name] for p in profiles.values()] for name in names]
        body.append(["total (under cProfile)"] + [p["total_ms"] for p in profiles.values()])
        lines.append(markdown_table(["part"] + [f"{kind}, N = {p['source_points']}" for kind, p in profiles.items()],
                                    body, digits=3))
        lines.append("")
    cc = report.get("crosscheck")
    if cc:
        lines.append(f"### `pcreg crosscheck` on the LiDAR pair ({cc['source_points']} / {cc['target_points']} "
                     f"points, its defaults, {len(cc['runs'])} runs)\n")
        lines.append(markdown_table(["reference (s)", "open3d (s)", "reference / open3d (median of the runs' ratios)"],
                                    [[cc["median_seconds"]["reference"], cc["median_seconds"]["open3d"],
                                      cc["ratio_reference_over_open3d"]]], digits=2))
        lines.append("")
        checks.append(("`pcreg crosscheck` on the LiDAR pair: reference <= 1.0x Open3D",
                       f"{cc['ratio_reference_over_open3d']:.2f}x (runs: "
                       + ", ".join(f"{x:.2f}" for x in cc["ratios"]) + ")", cc["ratio_reference_over_open3d"] <= 1.0))
    lines.append(checks_markdown(checks))
    return "\n".join(lines)


def figure(report: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = report["kinds"]
    fig, axes = plt.subplots(1, len(kinds), figsize=(5.2 * len(kinds), 4.0), squeeze=False)
    colours = {"reference": "tab:blue", "open3d": "tab:orange", "small_gicp": "tab:green"}
    for ax, (kind, k) in zip(axes[0], kinds.items()):
        ns = np.array([r["source_points"] for r in k["rows"]], dtype=np.float64)
        for n in k["rows"][0]["median_seconds"]:
            t = np.array([r["median_seconds"][n] for r in k["rows"]])
            ax.loglog(ns, 1e3 * t, "o-", color=colours.get(n), label=n)
        ref = np.array([r["median_seconds"]["reference"] for r in k["rows"]]) if "reference" in k["curve"] else None
        if ref is not None:
            nlogn = ns * np.log2(ns)
            ax.loglog(ns, 1e3 * ref[0] * nlogn / nlogn[0], "k--", lw=1, label="N log N (from the reference's first)")
        ax.set_xlabel("points N")
        ax.set_ylabel(f"ms for {report['iterations']} iterations")
        ax.set_title(f"{kind}", fontsize=10)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--data", type=Path, default=SHARED_DATA, help="../shared/data (synthetic 2-D clouds without it)")
    p.add_argument("--sizes", default="1000,3000,10000,30000,100000")
    p.add_argument("--iterations", type=int, default=15)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None,
                   help="threads for every implementation (numba, Open3D's OpenMP, small_gicp); default: theirs")
    p.add_argument("--implementations", default=",".join(IMPLEMENTATIONS))
    p.add_argument("--crosscheck-runs", type=int, default=5,
                   help="runs of `pcreg crosscheck` on the LiDAR pair (default 5; 0: none)")
    p.add_argument("--profile-calls", type=int, default=20,
                   help="reference calls profiled at the smallest size (default 20; 0: no profile)")
    args = p.parse_args(argv)
    if args.threads is not None:
        if args.threads < 1:
            p.error("--threads takes a positive count")
        set_threads(args.threads)
    sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    impls = tuple(s.strip() for s in args.implementations.split(",") if s.strip())
    report = {"machine": machine_info(), **run(args.data, sizes=sizes, iterations=args.iterations,
                                               repeats=args.repeats, seed=args.seed, implementations=impls,
                                               profile_calls=args.profile_calls, threads=args.threads)}
    if args.crosscheck_runs > 0 and "reference" in impls and "open3d" in impls:
        report["crosscheck"] = crosscheck_lidar(args.data, args.crosscheck_runs)
    return finish(args.out, "bench_icp", report, render, figure)


if __name__ == "__main__":
    sys.exit(main())
