"""Cross-check suites: pinned cases with exact (or published) ground truth, exported as test vectors
with the reference ICP's per-iteration trace, and run through every implementation.

Test-vector format (``pcreg crosscheck --export DIR``; readable without Python):

``DIR/index.json``
    ``{"format": "pcreg-crosscheck-suite/1", "cases": [NAME, ...]}``
``DIR/NAME/source.npy``, ``DIR/NAME/target.npy``
    (N, d) / (M, d) float64 arrays (NumPy .npy, version 1.0, little-endian '<f8', C order), d = 2 or 3.
``DIR/NAME/init.txt``, ``DIR/NAME/truth.txt`` (when known)
    (d+1)x(d+1) matrices ``T_target_source``, one row per line, whitespace-separated.
``DIR/NAME/params.json``
    ``max_correspondence_distance``, ``max_iterations``, ``relative_fitness``, ``relative_rmse`` (the
    same file a ``cmd:`` implementation gets as ``{params}``).
``DIR/NAME/case.json``
    name, description, dimension, point counts, whether ``truth.txt`` exists.
``DIR/NAME/reference/``
    the reference ICP run with those settings, K iterations: ``transforms.npy`` (K+1, d+1, d+1) float64,
    the pose after k = 0..K updates (0 = init); ``correspondences.npy`` (K+1, N) int64, the target index
    of each source point at pose k (-1: none within the distance), also as ``correspondences.txt`` (one
    line per pose); ``trace.json`` (``iterations``, ``converged``, and per pose ``iteration``,
    ``matrix``, ``fitness``, ``inlier_rmse``); ``final.txt`` the returned matrix.

Pose k+1 is the closed-form (Umeyama) update from the correspondences at pose k; fitness = matched /
N, inlier RMSE = sqrt(mean squared matched distance); the run stops after the first update with
|Δfitness| < relative_fitness and |Δinlier_rmse| < relative_rmse, or after max_iterations.
"""

from __future__ import annotations

import csv
import io
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..outputs import atomic_write_bytes, atomic_write_text, to_json
from ..formats import loads_json
from ..text_files import read_text_matrix
from ..errors import InputError, RegistrationError
from ..registration.transforms import apply, rigid2d
from .base import Pinned, reported

FORMAT = "pcreg-crosscheck-suite/1"


@dataclass(frozen=True)
class Case(Pinned):
    """A pinned cross-check input (:class:`~pcreg.implementations.base.Pinned`) with its name, a
    description and, where known, the true ``T_target_source``."""

    name: str = ""
    description: str = ""
    truth: np.ndarray | None = None
    folder: str = ""  # the case's folder, when read from a suite: messages name its files

    def _init_name(self) -> str:
        return str(Path(self.folder) / "init.txt") if self.folder else "init"


def _rigid3d(axis, angle_deg: float, t) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    axis = np.asarray(axis, dtype=np.float64)
    T[:3, :3] = Rotation.from_rotvec(np.deg2rad(angle_deg) * axis / np.linalg.norm(axis)).as_matrix()
    T[:3, 3] = t
    return T


def _synthetic(name: str, description: str, target: np.ndarray, truth: np.ndarray, *, gate: float,
               source: np.ndarray | None = None) -> Case:
    """Source = truth^-1 applied to the target (or the given source): the exact answer is ``truth``."""
    src = apply(np.linalg.inv(truth), target) if source is None else source
    d = target.shape[1]
    return Case(src, target, np.eye(d + 1), gate, name=name, description=description, truth=truth)


def _edge_images(seed: int = 3):
    import cv2

    from ..registration.transforms import about_point, image_center

    h, w = 240, 320
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.dstack([(60 + 60 * xx / w), (80 + 40 * yy / h), (100 + 30 * np.sin(xx / 37.0))]).astype(np.uint8)
    for _ in range(16):
        color = tuple(int(c) for c in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        kind = rng.integers(3)
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(10, 70)), y + int(rng.integers(10, 50))), color, -1)
        elif kind == 1:
            cv2.circle(img, (x, y), int(rng.integers(6, 35)), color, -1)
        else:
            cv2.line(img, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), color, 3)
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    T = about_point(rigid2d(4.0, 3.0, -2.0), image_center(img.shape))  # T_ref_mov
    mov = cv2.warpAffine(img, T[:2], (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    return img, mov, T


def edge_cloud_pair(max_points: int = 1500, seed: int = 3):
    """A 2-D edge-cloud pair: sub-pixel Canny edges of a synthetic image (target) and of the image
    warped by a known rigid motion (source), and that motion ``T_target_source`` (px)."""
    from ..registration.clouds import image_cloud

    ref, mov, T = _edge_images(seed)
    tgt = image_cloud(ref, max_points=max_points * 2, seed=seed).points
    src = image_cloud(mov, max_points=max_points, seed=seed + 1).points
    return src, tgt, T


def builtin_cases(*, scans: str | os.PathLike | None = None, seed: int = 0) -> tuple[list[Case], dict[str, str]]:
    """The built-in suite and the cases skipped with their reason (the LiDAR pair when ``scans`` is absent).

    Synthetic cases hold 400-1500 points in a 20-unit box, moved 4-5° and ~0.4 units; their ground truth
    is exact (the source is the target moved by the inverse of ``truth``, plus noise where stated).
    """
    rng = np.random.default_rng(seed)
    T2 = rigid2d(5.0, 0.3, -0.2)
    T3 = _rigid3d([1, 2, 3], 4.0, [0.3, -0.2, 0.25])
    cases: list[Case] = []
    box2 = rng.uniform(-10, 10, (600, 2))
    box3 = rng.uniform(-10, 10, (800, 3))
    cases.append(_synthetic("2d-random", "2-D uniform random points, exact", box2, T2, gate=2.0))
    src, tgt, Te = edge_cloud_pair()
    cases.append(Case(src, tgt, np.eye(3), 5.0, name="2d-edges", truth=Te,
                      description="2-D sub-pixel Canny edge clouds of an image and of its rigidly warped copy "
                                  "(different samples of the same edges; truth = the warp)"))
    line = np.column_stack([np.linspace(-10, 10, 300), np.zeros(300)]) @ rigid2d(30)[:2, :2].T
    cases.append(_synthetic("2d-collinear", "2-D points on one segment: the slide along it is fixed only by the "
                            "ends", line, rigid2d(2.0, 0.2, 0.1), gate=2.0))
    ang = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    circle = 8 * np.column_stack([np.cos(ang), np.sin(ang)])
    cases.append(_synthetic("2d-symmetric", "2-D circle: any rotation about its centre fits", circle, T2, gate=2.0))
    part_src = apply(np.linalg.inv(T2), box2[box2[:, 0] < 4])
    cases.append(_synthetic("2d-partial", "2-D partial overlap: source x < 4, target x > -4 (same points)",
                            box2[box2[:, 0] > -4], T2, gate=2.0, source=part_src))
    outl = np.vstack([box2, rng.uniform(-12, 12, (150, 2))])
    cases.append(_synthetic("2d-outliers", "2-D with 20% uniform outliers added to the target", outl, T2, gate=2.0,
                            source=apply(np.linalg.inv(T2), box2)))
    cases.append(_synthetic("2d-noise", "2-D with Gaussian noise (sigma 0.05) on the source", box2, T2, gate=2.0,
                            source=apply(np.linalg.inv(T2), box2) + rng.normal(scale=0.05, size=box2.shape)))
    cases.append(_synthetic("3d-random", "3-D uniform random points, exact", box3, T3, gate=2.0))
    plane = np.column_stack([rng.uniform(-10, 10, (800, 2)), np.zeros(800)])
    cases.append(_synthetic("3d-planar", "3-D points on a plane: the fit holds, surface normals are all alike",
                            plane, _rigid3d([0, 0, 1], 4.0, [0.3, -0.2, 0.0]), gate=2.0))
    seg = np.column_stack([np.linspace(-10, 10, 300), np.zeros(300), np.zeros(300)])
    cases.append(_synthetic("3d-collinear", "3-D points on a line: the rotation about it is undetermined",
                            seg, _rigid3d([0, 0, 1], 2.0, [0.2, 0.1, 0.0]), gate=2.0))
    v = rng.normal(size=(800, 3))
    sphere = 8 * v / np.linalg.norm(v, axis=1, keepdims=True)
    cases.append(_synthetic("3d-symmetric", "3-D sphere: any rotation about its centre fits", sphere, T3, gate=2.0))
    cases.append(_synthetic("3d-partial", "3-D partial overlap: source x < 4, target x > -4",
                            box3[box3[:, 0] > -4], T3, gate=2.0, source=apply(np.linalg.inv(T3), box3[box3[:, 0] < 4])))
    cases.append(_synthetic("3d-outliers", "3-D with 20% uniform outliers added to the target",
                            np.vstack([box3, rng.uniform(-12, 12, (200, 3))]), T3, gate=2.0,
                            source=apply(np.linalg.inv(T3), box3)))
    cases.append(_synthetic("3d-noise", "3-D with Gaussian noise (sigma 0.05) on the source", box3, T3, gate=2.0,
                            source=apply(np.linalg.inv(T3), box3) + rng.normal(scale=0.05, size=box3.shape)))
    skipped: dict[str, str] = {}
    scans_dir = Path(scans) if scans is not None else None
    if scans_dir is not None and all((scans_dir / f).exists() for f in ("source.ply", "target.ply", "T_target_source.txt")):
        from ..cloud_reader import load_cloud
        from ..registration.api import voxel_downsample

        s = voxel_downsample(load_cloud(scans_dir / "source.ply"), 0.5)
        t = voxel_downsample(load_cloud(scans_dir / "target.ply"), 0.5)
        cases.append(Case(s, t, np.eye(4), 1.0, name="lidar",
                          description="real LiDAR pair (small_gicp's test data), voxel 0.5 m, gate 1 m, from "
                                      "identity; truth = T_target_source.txt",
                          truth=read_text_matrix(scans_dir / "T_target_source.txt", what="ground truth")))
    else:
        skipped["lidar"] = f"the LiDAR pair is not at {scans_dir}/{{source,target}}.ply + T_target_source.txt"
    return cases, skipped


# ---------------------------------------------------------------------------------------------------
# Export / load
# ---------------------------------------------------------------------------------------------------

def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _txt(m: np.ndarray) -> str:
    buf = io.StringIO()
    np.savetxt(buf, m, fmt="%.17g")
    return buf.getvalue()


def _params(case: Case) -> dict:
    return {"max_correspondence_distance": case.max_correspondence_distance, "max_iterations": case.max_iterations,
            "relative_fitness": case.relative_fitness, "relative_rmse": case.relative_rmse}


def export_suite(out: str | os.PathLike, cases: Sequence[Case], *, progress: bool = False) -> Path:
    """Write every case and the reference ICP's per-iteration trace (format in the module docstring)."""
    from . import get

    out = Path(out)
    ref = get("reference")
    it = cases
    if progress:
        import sys

        from tqdm import tqdm

        it = tqdm(cases, desc="export", unit="case", file=sys.stderr, leave=False)
    for c in it:
        d = Path(out) / c.name
        atomic_write_bytes(d / "source.npy", _npy_bytes(np.ascontiguousarray(c.source, dtype="<f8")))
        atomic_write_bytes(d / "target.npy", _npy_bytes(np.ascontiguousarray(c.target, dtype="<f8")))
        atomic_write_text(d / "init.txt", _txt(c.init))
        atomic_write_text(d / "params.json", to_json(_params(c)) + "\n")
        if c.truth is not None:
            atomic_write_text(d / "truth.txt", _txt(c.truth))
        else:  # written over an earlier export (--force): no truth of another case left to be read as this one's
            (d / "truth.txt").unlink(missing_ok=True)
        meta = {"name": c.name, "description": c.description, "dimension": int(c.source.shape[1]),
                "source_points": len(c.source), "target_points": len(c.target), "truth": c.truth is not None}
        try:
            r = ref.run(c, trace=True)  # a case is a pinned input
        except Exception as exc:  # noqa: BLE001 - a refused case is exported with the refusal
            meta["reference_error"] = " ".join(str(exc).split())
            atomic_write_text(d / "case.json", to_json(meta) + "\n")
            shutil.rmtree(d / "reference", ignore_errors=True)  # an earlier export's trace is not this case's
            continue
        atomic_write_text(d / "case.json", to_json(meta) + "\n")
        tr = r.trace
        atomic_write_bytes(d / "reference" / "transforms.npy", _npy_bytes(np.stack([s.matrix for s in tr]).astype("<f8")))
        corr = np.stack([s.target_indices for s in tr]).astype("<i8")
        atomic_write_bytes(d / "reference" / "correspondences.npy", _npy_bytes(corr))
        atomic_write_text(d / "reference" / "correspondences.txt",
                          "".join(" ".join(map(str, row)) + "\n" for row in corr))
        atomic_write_text(d / "reference" / "trace.json", to_json({
            "iterations": r.iterations, "converged": r.converged,
            "steps": [{"iteration": s.iteration, "matrix": s.matrix.tolist(), "fitness": reported(s.fitness),
                       "inlier_rmse": reported(s.inlier_rmse)} for s in tr]}) + "\n")
        atomic_write_text(d / "reference" / "final.txt", _txt(r.matrix))
    atomic_write_text(out / "index.json", to_json({"format": FORMAT, "cases": [c.name for c in cases]}) + "\n")
    return out


def load_suite(path: str | os.PathLike) -> list[Case]:
    """The cases of a suite written by :func:`export_suite` (or by hand in its format)."""
    path = Path(path)
    index = path / "index.json"
    from ..formats import read_regular_file

    try:
        meta = loads_json(read_regular_file(index, max_bytes=1 << 20, what="suite index"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{index}: not a cross-check suite index ({' '.join(str(exc).split())[:160]})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("cases"), list):
        raise InputError(f"{index}: expected {{\"format\": ..., \"cases\": [...]}}")
    if not meta["cases"]:
        raise InputError(f"{index}: lists no case")
    twice = next((n for i, n in enumerate(meta["cases"]) if n in meta["cases"][:i]), None)
    if twice is not None:
        raise InputError(f"{index}: lists the case {twice!r} twice")
    from ..cloud_reader import load_cloud
    from .crosscheck import check_truth

    from ..validation import check_float, check_int

    cases = []
    for name in meta["cases"]:
        if not isinstance(name, str) or not name or name in (".", "..") or "/" in name or "\\" in name or "\0" in name:
            raise InputError(f"{index}: case {name!r} is not the name of a folder in the suite")
        d = path / name
        try:  # regular files only, bounded reads; a damaged case is one line, never a traceback
            params = loads_json(read_regular_file(d / "params.json", max_bytes=1 << 20, what="params.json"))
            info = (loads_json(read_regular_file(d / "case.json", max_bytes=1 << 20, what="case.json"))
                    if (d / "case.json").exists() else {})
            init = read_text_matrix(d / "init.txt", what="initial guess")
            truth = read_text_matrix(d / "truth.txt", what="ground truth") if (d / "truth.txt").exists() else None
            where = f"{d / 'params.json'}: "
            distance = check_float(params["max_correspondence_distance"], where + "max_correspondence_distance",
                                   lo=0, lo_open=True)
            iterations = check_int(params.get("max_iterations", 30), where + "max_iterations", lo=1, hi=100_000)
            fitness, rmse = (check_float(params.get(k, 1e-6), where + k, lo=0) for k in ("relative_fitness",
                                                                                         "relative_rmse"))
            source, target = load_cloud(d / "source.npy"), load_cloud(d / "target.npy")
            _check_case_files(d, source.shape[1], target.shape[1], info.get("dimension"), init)
            if truth is not None:
                truth = check_truth(truth, source.shape[1], str(d / "truth.txt"))
            case = Case(source, target, init, distance, iterations,
                        fitness, rmse, name=name, description=str(info.get("description", "")), truth=truth,
                        folder=str(d))
        except InputError:
            raise
        except KeyError as exc:
            raise InputError(f"{d / 'params.json'}: lacks {exc}") from None
        except AttributeError:  # a JSON document that is not an object
            raise InputError(f"{d}: params.json and case.json must each hold a JSON object") from None
        except (OSError, ValueError, TypeError, OverflowError) as exc:
            raise InputError(f"{d}: unreadable case ({type(exc).__name__}: {' '.join(str(exc).split())[:160]})") from None
        cases.append(case)
    return cases


def _check_case_files(d: Path, source: int, target: int, declared, init: np.ndarray) -> None:
    """An :class:`InputError` naming the file of the case in ``d`` that does not fit the others: clouds of
    ``source``-D and ``target``-D points, a dimension ``declared`` in case.json (None: none), an ``init`` matrix
    of another size (the messages named truth.txt, or no file, for these). :class:`Case` checks that ``init``
    is rigid, naming init.txt."""
    from ..validation import check_matrix

    if target != source:
        raise InputError(f"{d / 'target.npy'}: holds {target}-D points, source.npy {source}-D")
    if declared is not None and declared != source:
        raise InputError(f"{d / 'source.npy'}: holds {source}-D points, and case.json gives the case's dimension "
                         f"as {declared!r}")
    check_matrix(init, str(d / "init.txt"), source + 1)


# ---------------------------------------------------------------------------------------------------
# Run a suite
# ---------------------------------------------------------------------------------------------------

COLUMNS = ("case", "implementation", "comparability", "status", "agrees", "matrix_relative_disagreement", "pose_relative_disagreement",
           "rotation_disagreement_deg", "translation_disagreement", "truth_rotation_deg", "truth_translation",
           "iterations", "converged", "seconds", "divergence", "error")


def run_suite(cases: Sequence[Case], implementations: Sequence[str], *, timeout: float | None = None,
              progress: bool = False) -> list[dict]:
    """One row per (case, implementation): the cross-check row plus the case's name."""
    from ..registration.icp_options import ICPOptions
    from .crosscheck import check_implementations, crosscheck_implementations

    check_implementations(implementations, timeout=timeout)  # a misspelt name is bad input, not a row of each case
    rows = []
    it = cases
    if progress:
        import sys

        from tqdm import tqdm

        it = tqdm(cases, desc="suite", unit="case", file=sys.stderr)
    from .._runner import check_interrupted

    for c in it:
        check_interrupted()
        try:
            options = ICPOptions(max_correspondence_distance=c.max_correspondence_distance, max_iteration=c.max_iterations,
                                 relative_fitness=c.relative_fitness, relative_rmse=c.relative_rmse)
            r = crosscheck_implementations(c.source, c.target, implementations=implementations, options=options,
                                           init=c.init, truth=c.truth, timeout=timeout)
        except (InputError, RegistrationError) as exc:  # bad, or nothing to compare: that case's one row
            rows.append({"case": c.name, "implementation": "reference", "agrees": False, "error": str(exc),
                         "status": "refused" if isinstance(exc, RegistrationError) else "failed"})
            continue
        for name, row in r.rows.items():
            div = row.get("divergence")
            rows.append({"case": c.name, "implementation": name, **{k: row.get(k) for k in COLUMNS[2:]},
                         "divergence": None if not div else f"iteration {div['iteration']}: {div['cause']}",
                         "better_fit": row.get("better_fit")})
    return rows


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


#: The files :func:`write_results` writes.
RESULT_FILES = ("results.csv", "results.md", "results.json", "results.png")


def write_results(out: str | os.PathLike, rows: list[dict], *, skipped: dict[str, str] | None = None) -> dict:
    """results.csv, results.md, results.json and results.png (cases x implementations) in ``out``."""
    out = Path(out)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(COLUMNS), extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: _fmt(r.get(k)) if not isinstance(r.get(k), str) else r.get(k) for k in COLUMNS})
    atomic_write_text(out / "results.csv", buf.getvalue())
    cols = ("case", "implementation", "comparability", "agrees", "pose_relative_disagreement",
            "rotation_disagreement_deg", "translation_disagreement", "truth_rotation_deg", "truth_translation",
            "iterations", "seconds", "error")
    md = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        md.append("| " + " | ".join(_fmt(r.get(k)).replace("|", "\\|") for k in cols) + " |")
    notes = [f"- {r['case']} / {r['implementation']}: {r['divergence']}" for r in rows if r.get("divergence")]
    if notes:
        md += ["", "First divergence from the reference's trace:", "", *notes]
    better = [f"- {r['case']} / {r['implementation']}: RMS distance capped at the gate {r['better_fit']['capped_rms']:.3g} "
              f"against the {r['better_fit']['compared_with']}'s {r['better_fit']['compared_with_capped_rms']:.3g}"
              for r in rows if r.get("better_fit")]
    if better:
        md += ["", "Fits the clouds better than the reference (its pose is not ICP's best there):", "", *better]
    if skipped:
        md += ["", "Skipped:", "", *[f"- {k}: {v}" for k, v in skipped.items()]]
    atomic_write_text(out / "results.md", "\n".join(md) + "\n")
    atomic_write_text(out / "results.json", to_json({"rows": rows, "skipped": skipped or {}}) + "\n")
    _figure(out / "results.png", rows)
    return {"csv": str(out / "results.csv"), "markdown": str(out / "results.md"), "json": str(out / "results.json"),
            "figure": str(out / "results.png")}


def _figure(path: Path, rows: list[dict]) -> None:
    from ..outputs import pyplot

    plt = pyplot()
    from matplotlib.colors import ListedColormap

    cases = list(dict.fromkeys(r["case"] for r in rows))
    impls = list(dict.fromkeys(r["implementation"] for r in rows))
    code = np.full((len(cases), len(impls)), 3.0)  # 0 agrees, 1 disagrees, 2 failed, 3 not run/missing
    text = [["" for _ in impls] for _ in cases]
    for r in rows:
        i, j = cases.index(r["case"]), impls.index(r["implementation"])
        status = r.get("status")
        if status == "ok" and r.get("pose_relative_disagreement") is None:
            text[i][j] = "no ref."  # the reference refused the case: nothing to compare with
        elif status == "ok":
            code[i, j] = 0 if r.get("agrees") else 1
            v = r.get("pose_relative_disagreement")
            text[i][j] = f"{v:.0e}"
        elif status == "failed":
            code[i, j] = 2
            text[i][j] = "fail"
        elif status == "unconstrained":  # the clouds leave the transform free: a pose, but one of many
            text[i][j] = "unconstr."
        elif status == "refused":  # nothing to compare: no correspondence at the initial pose
            text[i][j] = "refused"
        else:
            text[i][j] = "n/a"
    fig, ax = plt.subplots(figsize=(1.1 * len(impls) + 2.5, 0.38 * len(cases) + 1.8), dpi=110)
    ax.imshow(code, cmap=ListedColormap(["#8fd18f", "#f2a65a", "#e06666", "#dddddd"]), vmin=-0.5, vmax=3.5,
              aspect="auto")
    for i in range(len(cases)):
        for j in range(len(impls)):
            ax.text(j, i, text[i][j], ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(impls)), [n if len(n) < 24 else n[:21] + "..." for n in impls], rotation=35, ha="right",
                  fontsize=8)
    ax.set_yticks(range(len(cases)), cases, fontsize=8)
    ax.set_title("agreement with the reference ICP (green: within its tolerance; orange: outside; red: failed; "
                 "grey: not run)\ncell: relative pose disagreement, about the source's centroid", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
