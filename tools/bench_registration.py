"""Benchmark: image registration on real photographs, procedural textures and CamVid; refusals; ICP cost.

Part 1 (accuracy, refusals and time). Images get a known rigid motion about their centre: angle uniform
in [-180, 180] deg, shift uniform within +-10% of the width/height. The moving image is
``cv2.warpAffine(ref, T[:2], (w, h), flags=INTER_LINEAR | WARP_INVERSE_MAP)``, so ``T`` is exactly
``T_ref_mov`` (black borders included). Two sets:

- ``terrain``: the real photographs of ``../shared/data/photos`` (several texture-dominated) and
  procedural textures (:mod:`pcreg.datasets.textures`: multi-scale noise, grass, gravel, brick, leaves;
  seeded), each scaled so that its longer side is at most ``--max-side`` px;
- ``camvid``: CamVid frames (480x360) from ``../shared/data/camvid``.

Each case is registered by ``pcreg.register`` with ``backend="reference"`` and ``backend="open3d"``
(default options: the same algorithm on both sides), by ORB+RANSAC (OpenCV, 2000 features at full
resolution, cross-checked Hamming matches, ``estimateAffinePartial2D`` with RANSAC at 3 px) and by
``findTransformECCMultiScale`` (4 levels, MOTION_EUCLIDEAN, from the identity; ECC's warp maps
reference to moving pixels, so ``T_ref_mov = inv(W)``; an exception counts as a failure). The error is
the largest distance (px) between the moving image's four corners mapped by the estimate and by the
truth; success is error <= 1 px; a refused genuine pair is a failure. The methods run in a shuffled
order per case; time ratios are the median of pcreg's times over the median of the other method's on
the same cases (for ECC: on the cases where ECC succeeds).

Impossible pairs (``--impossible`` of each kind, from the terrain pool): an unrelated image of the pool
moved by a random rigid motion, uniform noise, and the image mirrored left-right and moved. pcreg
must refuse them (``RegistrationError``).

Part 2 (scaling). Identical clouds of 1k..100k points -- 2-D: the strongest-gradient pixels (sub-pixel)
of a CamVid frame upscaled 3x and of its copy rotated by 3 deg and shifted; 3-D: random subsets of the
LiDAR pair ``../shared/data/scans`` -- registered by pcreg's reference ICP and by Open3D's legacy
``registration_icp`` with the same correspondence distance and exactly ``--icp-iterations`` iterations.

    python tools/bench_registration.py --out out/bench [--cases 60] [--camvid-cases 40] [--impossible 8] [--quick]

Writes ``registration.json`` (every raw number, the machine, the command line), ``registration.csv``
(one row per case and method), ``registration.md`` (tables and targets), ``registration_accuracy.png`` and
``registration_scaling.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import SHARED_DATA, camvid_images, clouds_2d, clouds_3d, command_line, ecc, machine_info, make_moving, write_report

DEFAULT_DATA = SHARED_DATA

METHODS = ("pcreg_reference", "pcreg_open3d", "orb", "ecc")
IMPOSSIBLE = ("unrelated", "noise", "mirror")
LABELS = {
    "pcreg_reference": "pcreg.register (reference ICP)",
    "pcreg_open3d": "pcreg.register (Open3D ICP)",
    "pcreg_reference_p2l": "pcreg.register (reference ICP, point-to-line finish)",
    "pcreg_reference_unchecked": "pcreg.register (reference ICP, model_check=False)",
    "orb": "ORB+RANSAC (2000 features)",
    "ecc": "OpenCV ECC multi-scale",
}
COLORS = {"pcreg_reference": "tab:blue", "pcreg_open3d": "tab:orange", "pcreg_reference_p2l": "tab:purple",
          "pcreg_reference_unchecked": "tab:cyan",
          "orb": "tab:red", "ecc": "tab:green"}
SUCCESS_PX = 1.0
TARGETS = {"median_px": 0.1, "p95_px": 0.5, "success": 0.99, "icp_ratio_vs_open3d": 1.0}


# ---------------------------------------------------------------------------------------------------
# Part 1: images with known rigid motions, impossible pairs
# ---------------------------------------------------------------------------------------------------

def find_photos(data: Path) -> list[Path]:
    return sorted(p for p in (data / "photos").glob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))


def load_source(source: str, *, max_side: int) -> np.ndarray:
    """An image by name: ``texture:KIND:SEED`` (procedural, 384x512) or a file path, scaled down so its
    longer side is at most ``max_side`` (INTER_AREA)."""
    import cv2

    import pcreg

    if source.startswith("texture:"):
        from pcreg.datasets.textures import texture

        _, kind, seed = source.split(":")
        img = texture(kind, height=384, width=512, seed=int(seed))
    else:
        img = pcreg.load_image(source)
    s = max_side / max(img.shape[:2])
    if s < 1:
        img = cv2.resize(img, (max(16, round(img.shape[1] * s)), max(16, round(img.shape[0] * s))),
                         interpolation=cv2.INTER_AREA)
    return img


def terrain_sources(data: Path, *, texture_seeds: int = 3) -> list[str]:
    """The real photographs (if present) and procedural textures of every kind, ``texture_seeds`` each."""
    from pcreg.datasets.textures import KINDS

    return [str(p) for p in find_photos(data)] + [f"texture:{k}:{s}" for s in range(texture_seeds) for k in KINDS]


def make_cases(sources: list[str], n: int, *, max_angle: float, seed: int, kind: str = "genuine") -> list[dict]:
    """``n`` cases: an image (cycling through ``sources`` in a shuffled order), an angle uniform in
    [-max_angle, max_angle] and a shift within +-10% of the size (as fractions, applied per image)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(sources))
    cases = []
    for i in range(n):
        src = sources[int(order[i % len(sources)])]
        case = {"case": i, "kind": kind, "image": src,
                "angle_deg": float(rng.uniform(-max_angle, max_angle)),
                "fx": float(rng.uniform(-0.1, 0.1)), "fy": float(rng.uniform(-0.1, 0.1)),
                "order_seed": int(rng.integers(2**31))}
        if kind == "unrelated":
            others = [s for s in sources if s != src]
            case["other"] = others[int(rng.integers(len(others)))]
        cases.append(case)
    return cases


def truth_matrix(case: dict, shape: tuple[int, ...]) -> np.ndarray:
    from pcreg.registration.transforms import about_point, image_center, rigid2d

    c = image_center(shape)
    h, w = shape[:2]
    return about_point(rigid2d(case["angle_deg"], case.get("fx", 0.0) * w, case.get("fy", 0.0) * h), c, c)


def ecc_register(reference: np.ndarray, moving: np.ndarray, *, levels: int = 4) -> np.ndarray:
    """``T_ref_mov`` by OpenCV's multi-scale ECC (Euclidean, :func:`benchlib.ecc`) from the identity;
    raises ValueError when ECC does not converge."""
    T = ecc(reference, moving, motion="euclidean", levels=levels)
    if T is None:
        raise ValueError("ECC did not converge")
    return T


def orb_register(reference: np.ndarray, moving: np.ndarray, *, n_features: int = 2000) -> np.ndarray:
    """``T_ref_mov`` by ORB (``n_features``, full resolution), cross-checked Hamming matches and a
    similarity by RANSAC (``cv2.estimateAffinePartial2D``, 3 px); raises ValueError when it finds none."""
    import cv2

    g1 = cv2.cvtColor(reference, cv2.COLOR_RGB2GRAY)
    g2 = cv2.cvtColor(moving, cv2.COLOR_RGB2GRAY)
    orb = cv2.ORB_create(nfeatures=n_features)
    k1, d1 = orb.detectAndCompute(g1, None)
    k2, d2 = orb.detectAndCompute(g2, None)
    if d1 is None or d2 is None:
        raise ValueError("ORB: no features")
    m = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d2, d1)
    if len(m) < 3:
        raise ValueError("ORB: fewer than 3 matches")
    p2 = np.float32([k2[x.queryIdx].pt for x in m])
    p1 = np.float32([k1[x.trainIdx].pt for x in m])
    M, _ = cv2.estimateAffinePartial2D(p2, p1, method=cv2.RANSAC, ransacReprojThreshold=3.0)
    if M is None:
        raise ValueError("ORB: RANSAC found no model")
    return np.vstack([M, [0.0, 0.0, 1.0]])


def _run_method(method: str, reference: np.ndarray, moving: np.ndarray) -> tuple[np.ndarray | None, dict]:
    import pcreg

    if method in ("pcreg_reference", "pcreg_open3d"):
        r = pcreg.register(reference, moving, backend=method.split("_", 1)[1])
        return r.matrix, {"inlier_ratio": r.inlier_ratio, "chance_ratio": r.chance_ratio, "generator": r.generator,
                          "inner_seconds": r.seconds}
    if method == "pcreg_reference_unchecked":  # without the checks beyond the plausibility test (as the streams run)
        r = pcreg.register(reference, moving, config=pcreg.RegisterConfig.of(backend="reference", model_check=False))
        return r.matrix, {"inlier_ratio": r.inlier_ratio, "generator": r.generator, "inner_seconds": r.seconds}
    if method == "pcreg_reference_p2l":
        r = pcreg.register(reference, moving, config=pcreg.RegisterConfig.of(backend="reference", refine="point_to_line"))
        return r.matrix, {"inlier_ratio": r.inlier_ratio, "generator": r.generator, "inner_seconds": r.seconds}
    if method == "orb":
        return orb_register(reference, moving), {}
    if method == "ecc":
        return ecc_register(reference, moving), {}
    raise ValueError(method)


def _moving_for(case: dict, reference: np.ndarray, cache: dict, max_side: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(moving image, truth or None) for a case of any kind."""
    import cv2

    T = truth_matrix(case, reference.shape)
    kind = case["kind"]
    if kind == "genuine":
        return make_moving(reference, T), T
    if kind == "unrelated":
        other = cache_get(cache, case["other"], max_side)
        other = cv2.resize(other, (reference.shape[1], reference.shape[0]), interpolation=cv2.INTER_AREA)
        return make_moving(other, T), None
    if kind == "noise":
        return np.random.default_rng(case["order_seed"]).integers(0, 256, reference.shape, dtype=np.uint8), None
    if kind == "mirror":
        return make_moving(np.ascontiguousarray(reference[:, ::-1]), T), None
    raise ValueError(kind)


def cache_get(cache: dict, source: str, max_side: int) -> np.ndarray:
    if source not in cache:
        cache[source] = load_source(source, max_side=max_side)
    return cache[source]


def run_case(case: dict, methods: tuple[str, ...], cache: dict, *, max_side: int = 512) -> dict:
    """Register one pair with every method; errors in px (genuine pairs), refusals, wall-clock seconds."""
    import cv2

    from pcreg.errors import RegistrationError
    from pcreg.registration.transforms import max_corner_error

    reference = cache_get(cache, case["image"], max_side)
    moving, T = _moving_for(case, reference, cache, max_side)
    out = dict(case)
    out["shape"] = list(reference.shape[:2])
    order = list(methods)
    np.random.default_rng(case["order_seed"]).shuffle(order)
    out["order"] = order
    for m in order:
        t0 = time.perf_counter()
        refused = False
        try:
            M, extra = _run_method(m, reference, moving)
            failure = None
        except RegistrationError as exc:
            M, extra, failure, refused = None, {}, f"refused: {str(exc)[:200]}", True
        except (cv2.error, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # pcreg errors are ValueErrors
            M, extra, failure = None, {}, f"{type(exc).__name__}: {str(exc).strip().splitlines()[-1][:200]}"
        seconds = time.perf_counter() - t0
        err = None
        if T is not None:
            err = float("inf") if M is None or not np.all(np.isfinite(M)) else max_corner_error(M, T, reference.shape)
        out[m] = {"error_px": err, "seconds": seconds, "failure": failure, "refused": refused, **extra,
                  "matrix": None if M is None else np.asarray(M).tolist()}
    return out


def _p(x, q):
    return float(np.percentile(x, q, method="inverted_cdf")) if len(x) else float("nan")


def summarise(rows: list[dict], methods: tuple[str, ...]) -> dict:
    """Per method on genuine rows: median / p95 error, success, refusals, median seconds and time ratios."""
    summary = {}
    for m in methods:
        err = np.array([r[m]["error_px"] for r in rows])
        sec = np.array([r[m]["seconds"] for r in rows])
        s = {"cases": len(rows), "median_px": float(np.median(err)), "p95_px": _p(err, 95),
             "success": float(np.mean(err <= SUCCESS_PX)), "refused": int(sum(r[m]["refused"] for r in rows)),
             "exceptions": int(sum(r[m]["failure"] is not None and not r[m]["refused"] for r in rows)),
             "median_seconds": float(np.median(sec))}
        for base in ("orb", "ecc"):
            if base in methods and base != m:
                bs = np.array([r[base]["seconds"] for r in rows])
                s[f"time_ratio_vs_{base}"] = float(np.median(sec) / np.median(bs))
                s[f"per_case_time_ratio_vs_{base}"] = float(np.median(sec / bs))
        if "ecc" in methods and m != "ecc":
            ok = np.array([r["ecc"]["error_px"] <= SUCCESS_PX for r in rows])
            if ok.any():
                bs = np.array([r["ecc"]["seconds"] for r in rows])[ok]
                s["ecc_success_cases"] = int(ok.sum())
                s["time_ratio_vs_ecc_where_ecc_succeeds"] = float(np.median(sec[ok]) / np.median(bs))
        summary[m] = s
    return summary


def summarise_impossible(rows: list[dict], methods: tuple[str, ...]) -> dict:
    out = {}
    for m in methods:
        by_kind = {}
        for kind in IMPOSSIBLE:
            kr = [r for r in rows if r["kind"] == kind]
            by_kind[kind] = {"cases": len(kr), "refused": int(sum(r[m]["refused"] for r in kr))}
        out[m] = {"cases": len(rows), "refused": int(sum(r[m]["refused"] for r in rows)), "by_kind": by_kind,
                  "median_seconds": float(np.median([r[m]["seconds"] for r in rows])) if rows else float("nan")}
    return out


def success_by_angle(rows: list[dict], methods: tuple[str, ...], *, bin_deg: float = 30.0,
                     max_angle: float = 180.0) -> dict:
    edges = np.arange(-max_angle, max_angle + bin_deg / 2, bin_deg)
    ang = np.array([r["angle_deg"] for r in rows])
    idx = np.clip(np.digitize(ang, edges) - 1, 0, len(edges) - 2)
    out = {"edges": edges.tolist(), "counts": np.bincount(idx, minlength=len(edges) - 1).tolist()}
    for m in methods:
        ok = np.array([r[m]["error_px"] <= SUCCESS_PX for r in rows])
        out[m] = [float(ok[idx == b].mean()) if np.any(idx == b) else float("nan") for b in range(len(edges) - 1)]
    return out


def per_source(rows: list[dict], methods: tuple[str, ...]) -> dict:
    """Success and median error per source image (texture kinds pooled over seeds)."""
    def name(src):
        return src.split(":")[1] if src.startswith("texture:") else Path(src).name

    out: dict = {}
    for r in rows:
        out.setdefault(name(r["image"]), []).append(r)
    return {k: {"cases": len(v), **{m: {"success": float(np.mean([x[m]["error_px"] <= SUCCESS_PX for x in v])),
                                        "median_px": float(np.median([x[m]["error_px"] for x in v]))}
                                    for m in methods}} for k, v in sorted(out.items())}


def run_images(data: Path, *, cases: int, camvid_cases: int, impossible: int, seed: int, max_side: int,
               methods: tuple[str, ...], texture_seeds: int = 3) -> dict:
    from pcreg._runner import progress

    cache: dict = {}
    sets = {}
    terrain = terrain_sources(data, texture_seeds=texture_seeds)
    # Warm-up: imports, Open3D's first call, OpenCV's thread pool; not recorded.
    for c in make_cases(terrain, 2, max_angle=30.0, seed=seed + 999):
        run_case(c, methods, cache, max_side=max_side)
    plan = [("terrain", terrain, cases, seed, "photographs (../shared/data/photos) and procedural textures")]
    camvid = [str(p) for p in camvid_images(data)]
    if camvid and camvid_cases:
        plan.append(("camvid", camvid, camvid_cases, seed + 1, "CamVid frames (../shared/data/camvid)"))
    elif camvid_cases:
        print(f"skipping CamVid cases: no frames under {data / 'camvid'}/*/images/", file=sys.stderr)
    for name, sources, n, s, desc in plan:
        rows = [run_case(c, methods, cache, max_side=max_side)
                for c in progress(make_cases(sources, n, max_angle=180.0, seed=s), desc=f"{name} ±180°", total=n)]
        sets[name] = {"description": desc, "sources": len(sources), "seed": s, "rows": rows,
                      "summary": summarise(rows, methods), "success_by_angle": success_by_angle(rows, methods),
                      "per_source": per_source(rows, methods)}
    imp_methods = tuple(m for m in methods if m.startswith("pcreg"))
    imp_rows = []
    if impossible:
        cases_i = []
        for k, kind in enumerate(IMPOSSIBLE):
            cases_i += make_cases(terrain, impossible, max_angle=180.0, seed=seed + 10 + k, kind=kind)
        imp_rows = [run_case(c, imp_methods, cache, max_side=max_side)
                    for c in progress(cases_i, desc="impossible pairs", total=len(cases_i))]
    return {"methods": list(methods), "max_side": max_side, "sets": sets,
            "impossible": {"methods": list(imp_methods), "rows": imp_rows,
                           "summary": summarise_impossible(imp_rows, imp_methods)}}


# ---------------------------------------------------------------------------------------------------
# Part 2: ICP cost against the number of points
# ---------------------------------------------------------------------------------------------------

def time_icp_pair(src: np.ndarray, tgt: np.ndarray, *, dist: float, iterations: int, repeats: int) -> dict:
    """Reference vs Open3D legacy ICP on identical clouds, exactly ``iterations`` iterations each."""
    import open3d as o3d

    from pcreg.registration.open3d_icp import to_pointcloud
    from pcreg.registration.icp_options import ICPOptions
    from pcreg.registration.reference import icp_reference

    reg = o3d.pipelines.registration
    d = src.shape[1]
    est = reg.TransformationEstimationPointToPoint()
    crit = reg.ICPConvergenceCriteria(relative_fitness=0.0, relative_rmse=0.0, max_iteration=iterations)

    def ref_run():
        t0 = time.perf_counter()
        r = icp_reference(src, tgt, ICPOptions(max_correspondence_distance=dist, max_iteration=iterations,
                                               relative_fitness=0.0, relative_rmse=0.0), init=np.eye(d + 1))
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


def _image_targets(img: dict) -> list[list]:
    targets = []
    for set_name in ("terrain", "camvid"):
        st = img["sets"].get(set_name)
        if not st:
            continue
        for meth in ("pcreg_reference", "pcreg_open3d"):
            s = st["summary"].get(meth)
            if not s:
                continue
            who = f"{set_name}, {LABELS[meth]}"
            targets += [
                [f"{who}: success >= {100 * TARGETS['success']:.0f}%", f"{100 * s['success']:.1f}%",
                 _met(s["success"] >= TARGETS["success"])],
                [f"{who}: median error <= {TARGETS['median_px']} px", f"{s['median_px']:.3f} px",
                 _met(s["median_px"] <= TARGETS["median_px"])],
                [f"{who}: p95 error <= {TARGETS['p95_px']} px", f"{s['p95_px']:.3f} px",
                 _met(s["p95_px"] <= TARGETS["p95_px"])],
                [f"{who}: genuine pairs refused = 0", str(s["refused"]), _met(s["refused"] == 0)],
            ]
            if "time_ratio_vs_orb" in s:
                targets.append([f"{who}: median time / ORB+RANSAC's < 1", f"{s['time_ratio_vs_orb']:.2f}",
                               _met(s["time_ratio_vs_orb"] < 1.0)])
            if "time_ratio_vs_ecc_where_ecc_succeeds" in s:
                targets.append([f"{who}: median time / ECC's where ECC succeeds < 1 ({s['ecc_success_cases']} cases)",
                               f"{s['time_ratio_vs_ecc_where_ecc_succeeds']:.2f}",
                               _met(s["time_ratio_vs_ecc_where_ecc_succeeds"] < 1.0)])
    imp = img["impossible"]
    for meth, s in imp["summary"].items():
        if s["cases"]:
            targets.append([f"impossible pairs, {LABELS[meth]}: 100% refused", f"{s['refused']}/{s['cases']}",
                           _met(s["refused"] == s["cases"])])
    return targets


def _set_section(st: dict, img: dict) -> list[str]:
    """One set of genuine pairs: the summary per method, success per image and by angle, the misses."""
    from pcreg.outputs import markdown_table

    methods = img["methods"]
    lines = [f"## {st['description']}: rigid motion, angle uniform in ±180°, shift within ±10% "
             f"({len(st['rows'])} cases over {st['sources']} images, longer side <= {img['max_side']} px, "
             f"seed {st['seed']})\n"]
    header = ["method", "success (<= 1 px)", "median error (px)", "p95 error (px)", "refused", "exceptions",
              "median time (ms)", "time / ORB's", "time / ECC's where ECC succeeds"]
    rows = []
    for meth in methods:
        s = st["summary"][meth]
        rows.append([LABELS[meth], f"{100 * s['success']:.1f}%", f"{s['median_px']:.3f}", f"{s['p95_px']:.3f}",
                     s["refused"], s["exceptions"], f"{1e3 * s['median_seconds']:.0f}",
                     f"{s.get('time_ratio_vs_orb', float('nan')):.2f}" if meth != "orb" else "1",
                     f"{s.get('time_ratio_vs_ecc_where_ecc_succeeds', float('nan')):.2f}" if meth != "ecc" else "1"])
    lines.append(markdown_table(header, rows))
    ps = st["per_source"]
    lines.append("\nSuccess per image (texture kinds pooled over seeds):\n")
    lines.append(markdown_table(["image", "cases"] + [LABELS[x] for x in methods],
                                [[k, v["cases"]] + [f"{100 * v[x]['success']:.0f}% ({v[x]['median_px']:.2f} px)"
                                                    for x in methods] for k, v in ps.items()]))
    sba = st["success_by_angle"]
    e = sba["edges"]
    lines.append("\nSuccess rate (error <= 1 px) by angle:\n")
    lines.append(markdown_table(["angle bin (deg)", "cases"] + [LABELS[x] for x in methods],
                                [[f"[{e[b]:.0f}, {e[b + 1]:.0f})", sba["counts"][b]]
                                 + [f"{100 * sba[x][b]:.0f}%" if np.isfinite(sba[x][b]) else "-"
                                    for x in methods] for b in range(len(e) - 1)]))
    ours = [x for x in methods if x.startswith("pcreg")]
    fails = [r for r in st["rows"] if any(r[x]["error_px"] > SUCCESS_PX for x in ours)]
    if fails:
        lines.append("\nCases where pcreg.register missed 1 px:\n")
        lines.append(markdown_table(
            ["case", "image", "angle (deg)"] + [LABELS[x] for x in ours],
            [[r["case"], r["image"].split("/")[-1], f"{r['angle_deg']:.1f}"]
             + [f"{r[x]['error_px']:.3g}" + (f" ({r[x]['failure'][:60]})" if r[x]["failure"] else "") for x in ours]
             for r in fails]))
    lines.append("")
    return lines


def _impossible_section(imp: dict) -> list[str]:
    """The impossible pairs refused per method and kind (nothing without them)."""
    from pcreg.outputs import markdown_table

    if not imp["rows"]:
        return []
    n_kind = {k: sum(r["kind"] == k for r in imp["rows"]) for k in IMPOSSIBLE}
    return [f"## Impossible pairs ({', '.join(f'{n} {k}' for k, n in n_kind.items())}): refused?\n",
            "Unrelated: a different image of the same pool, moved; noise: uniform noise; mirror: the "
            "image mirrored left-right, moved. ORB+RANSAC and ECC have no refusal: they return a "
            "transform for every pair.\n",
            markdown_table(["method"] + list(IMPOSSIBLE) + ["all", "median time (ms)"],
                           [[LABELS[x]] + [f"{s['by_kind'][k]['refused']}/{s['by_kind'][k]['cases']}" for k in IMPOSSIBLE]
                            + [f"{s['refused']}/{s['cases']}", f"{1e3 * s['median_seconds']:.0f}"]
                            for x, s in imp["summary"].items()]),
            ""]


def _scaling_section(sc: dict) -> list[str]:
    """The ICP's cost per cloud size, reference against Open3D, per kind of cloud."""
    from pcreg.outputs import markdown_table

    lines = [f"## ICP cost against the number of points: reference ICP vs Open3D legacy ICP "
             f"({sc['iterations']} iterations each, thresholds 0, median of {sc['repeats']} repeats)\n"]
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
    return lines


def _scaling_targets(sc: dict) -> list[list]:
    targets = []
    for kind, k in sc["kinds"].items():
        ratios = [r["median_ratio"] for r in k["rows"]]
        targets.append([f"{kind} clouds: reference ICP no slower than Open3D (median ratio <= 1), per size",
                        ", ".join(f"{x:.2f}" for x in ratios), _met(max(ratios) <= TARGETS["icp_ratio_vs_open3d"])])
    return targets


def render_markdown(report: dict) -> str:
    """The report's Markdown: the targets, then each part (:func:`benchlib.write_report` adds the command
    line and the machine)."""
    from pcreg.outputs import markdown_table

    lines = ["# Registration benchmark\n",
             f"Started {report['started']}, took {report['wall_seconds'] / 60:.1f} min. Times are wall clock on a shared "
             "machine; compare the ratios (same cases, same run), not the absolute times.\n"]
    targets = []
    img = report.get("images")
    if img:
        for st in img["sets"].values():
            lines += _set_section(st, img)
        lines += _impossible_section(img["impossible"])
        targets += _image_targets(img)
    else:
        lines.append("Image benchmark skipped.\n")
    sc = report.get("scaling")
    if sc:
        lines += _scaling_section(sc)
        targets += _scaling_targets(sc)
    if targets:
        lines.insert(1, "## Targets\n\n" + markdown_table(["target", "measured", ""], targets) + "\n")
    return "\n".join(lines) + "\n"


def _label(ax, xlabel: str | None, ylabel: str, title: str, *, grid: str = "both", legend: str = "best") -> None:
    """Axis labels, a title, a light grid (``"both"``: major and minor lines; ``"y"``: horizontal ones) and
    the legend at ``legend``."""
    if xlabel is not None:
        ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if grid == "y":
        ax.grid(True, axis="y", alpha=0.3)
    else:
        ax.grid(True, which=grid, alpha=0.3)
    ax.legend(fontsize=8, loc=legend)


def plot_accuracy(report: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img = report["images"]
    methods = img["methods"]
    sets = list(img["sets"].items())
    fig, axes = plt.subplots(1, len(sets) + 1, figsize=(6 * (len(sets) + 1), 4.8))
    axes = np.atleast_1d(axes)
    cap = 1e3
    for ax, (name, st) in zip(axes, sets):
        for m in methods:
            err = np.sort(np.clip([r[m]["error_px"] for r in st["rows"]], 1e-4, cap))
            ax.step(err, np.arange(1, len(err) + 1) / len(err), where="post", color=COLORS[m], lw=2, label=LABELS[m])
        ax.axvline(SUCCESS_PX, color="k", ls="--", lw=1)
        ax.set_xscale("log")
        ax.set_xlim(1e-3, cap)
        ax.set_ylim(0, 1.01)
        _label(ax, "max corner error (px, log; failures at the right edge)", "fraction of cases with error <= x",
               f"{name}: ±180°, {len(st['rows'])} cases", legend="upper left")
    ax = axes[-1]
    x = np.arange(len(sets))
    wbar = 0.8 / len(methods)
    for i, m in enumerate(methods):
        ax.bar(x + i * wbar, [1e3 * st["summary"][m]["median_seconds"] for _, st in sets], wbar, color=COLORS[m],
               label=LABELS[m])
    ax.set_xticks(x + 0.4 - wbar / 2)
    ax.set_xticklabels([n for n, _ in sets])
    _label(ax, None, "median time per pair (ms)", "Time, same cases, same run", grid="y")
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
        _label(ax, "points per cloud N", f"seconds for {sc['iterations']} ICP iterations", f"{kind} clouds: time vs N")
    ax = axes[-1]
    for (kind, k), marker in zip(kinds, "os"):
        n = [r["source_points"] for r in k["rows"]]
        ax.plot(n, [r["median_ratio"] for r in k["rows"]], marker + "-", lw=2, label=f"{kind} clouds")
    ax.axhline(1.0, color="k", ls="--", lw=1)
    ax.set_xscale("log")
    ax.set_ylim(0, max(2.0, 1.1 * max(r["median_ratio"] for _, k in kinds for r in k["rows"])))
    _label(ax, "points per cloud N", "median time ratio reference / Open3D",
           "Same clouds, same iterations: ratio (< 1: reference faster)")
    fig.tight_layout()
    return fig


CSV_HEADER = ["set", "case", "kind", "image", "other", "angle_deg", "shift_x_frac", "shift_y_frac", "method", "error_px",
              "refused", "seconds", "inlier_ratio", "generator", "failure"]


def csv_rows(img: dict) -> list[list]:
    """A row per case and method (:data:`CSV_HEADER`), genuine sets then the impossible pairs."""
    rows = []
    for set_name, st in list(img["sets"].items()) + [("impossible", img["impossible"])]:
        meths = img["methods"] if set_name != "impossible" else img["impossible"]["methods"]
        for r in st["rows"]:
            for m in meths:
                x = r[m]
                rows.append([set_name, r["case"], r["kind"], r["image"], r.get("other", ""), f"{r['angle_deg']:.3f}",
                             f"{r['fx']:.4f}", f"{r['fy']:.4f}", m,
                             "" if x["error_px"] is None else f"{x['error_px']:.5g}", int(x["refused"]),
                             f"{x['seconds']:.5f}", "" if x.get("inlier_ratio") is None else f"{x['inlier_ratio']:.4f}",
                             x.get("generator") or "", x["failure"] or ""])
    return rows


def write_outputs(report: dict, out: Path, *, command: str | None = None) -> list[Path]:
    """``registration.json``, ``.md``, ``.csv`` and the figures ``registration_accuracy.png`` and
    ``registration_scaling.png`` (those with data), through :func:`benchlib.write_report`."""
    img = report.get("images")
    figures = {}
    if img and img["sets"]:
        figures["accuracy"] = plot_accuracy(report)
    if report.get("scaling"):
        figures["scaling"] = plot_scaling(report)
    return write_report(out, "registration", report, render_markdown(report), figures=figures,
                        table=(CSV_HEADER, csv_rows(img)) if img else None, command=command)


# ---------------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench", help="output folder (default out/bench)")
    parser.add_argument("--cases", type=int, default=None,
                        help="genuine cases on photographs and textures (default 60, --quick 20)")
    parser.add_argument("--camvid-cases", type=int, default=None, help="genuine cases on CamVid (default 40, --quick 10)")
    parser.add_argument("--impossible", type=int, default=None,
                        help="impossible pairs of each kind: unrelated, noise, mirror (default 8, --quick 3)")
    parser.add_argument("--texture-seeds", type=int, default=3, help="procedural textures of each kind (default 3)")
    parser.add_argument("--max-side", type=int, default=512, help="longer side of photographs and textures (px)")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help=f"comma-separated, of {', '.join(LABELS)} (default {','.join(METHODS)})")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sizes", type=str, default=None, help="cloud sizes, comma-separated (default 1000,10000,100000)")
    parser.add_argument("--icp-iterations", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=None, help="repeats per cloud size (default 5, --quick 3)")
    parser.add_argument("--quick", action="store_true", help="fewer cases, sizes and repeats")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder (default ../shared/data)")
    parser.add_argument("--skip-images", action="store_true")
    parser.add_argument("--skip-scaling", action="store_true")
    args = parser.parse_args(argv)
    cases = args.cases if args.cases is not None else (20 if args.quick else 60)
    camvid = args.camvid_cases if args.camvid_cases is not None else (10 if args.quick else 40)
    impossible = args.impossible if args.impossible is not None else (3 if args.quick else 8)
    repeats = args.repeats if args.repeats is not None else (3 if args.quick else 5)
    sizes = ([int(s) for s in args.sizes.split(",")] if args.sizes
             else ([1000, 10000] if args.quick else [1000, 10000, 100000]))
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    bad = [m for m in methods if m not in LABELS]
    if bad or not methods:
        print(f"error: unknown method(s) {', '.join(bad) or '(none)'}; choose from {', '.join(LABELS)}", file=sys.stderr)
        return 2
    if (cases < 1 or camvid < 0 or impossible < 0 or repeats < 1 or args.icp_iterations < 1 or min(sizes) < 10
            or args.max_side < 32 or args.texture_seeds < 1):
        print("error: --cases, --repeats, --icp-iterations, --texture-seeds must be >= 1, --camvid-cases and "
              "--impossible >= 0, --max-side >= 32, sizes >= 10", file=sys.stderr)
        return 2
    out = Path(args.out)
    started = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    t0 = time.perf_counter()
    report: dict = {"started": started, "machine": machine_info(),
                    "settings": {"cases": cases, "camvid_cases": camvid, "impossible_per_kind": impossible,
                                 "texture_seeds": args.texture_seeds, "max_side": args.max_side, "seed": args.seed,
                                 "sizes": sizes, "icp_iterations": args.icp_iterations, "repeats": repeats,
                                 "success_px": SUCCESS_PX, "methods": list(methods),
                                 "register_options": "defaults (levels=4, iterations=14, init='auto', model='rigid', "
                                                     "refine='none', min_inlier_ratio=0.15)",
                                 "orb_options": "2000 features, full resolution, BFMatcher Hamming crossCheck, "
                                                "estimateAffinePartial2D RANSAC 3 px",
                                 "ecc_options": "nlevels=4, MOTION_EUCLIDEAN, default criteria, identity start"},
                    "targets": TARGETS}
    try:
        if not args.skip_images:
            report["images"] = run_images(args.data, cases=cases, camvid_cases=camvid, impossible=impossible,
                                          seed=args.seed, max_side=args.max_side, methods=methods,
                                          texture_seeds=args.texture_seeds)
        if not args.skip_scaling:
            report["scaling"] = run_scaling(args.data, sizes=sizes, iterations=args.icp_iterations, repeats=repeats,
                                            seed=args.seed)
    except KeyboardInterrupt:
        print("interrupted; nothing written", file=sys.stderr)
        return 130
    report["wall_seconds"] = time.perf_counter() - t0
    try:
        paths = write_outputs(report, out, command=command_line(argv, __file__))
    except OSError as exc:
        print(f"error: cannot write to {out}: {exc}", file=sys.stderr)
        return 2
    print(Path(out, "registration.md").read_text())
    print("wrote " + ", ".join(str(p) for p in paths), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
