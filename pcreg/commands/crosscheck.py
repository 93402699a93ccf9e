"""Cross-check ICP implementations on identical inputs and report where and why they differ.

Two images: the reference ICP and Open3D's through the image pipeline. Two point clouds: every
implementation named with ``--with`` (built in, ``py:MODULE:FUNCTION``, ``cmd:"PROGRAM {source} ..."``).
``--export DIR`` writes the built-in suite as test vectors; ``--suite DIR`` runs every implementation on
a suite and writes a table and a figure.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..recording.interface import RecorderProtocol
from ._common import add_record_arguments, float_list, init_refusal, open_recorder, positive_float, positive_int, print_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("a", metavar="A", nargs="?", help="reference image, or target point cloud (.ply/.pcd/.xyz/.npy/.txt/.csv)")
    p.add_argument("b", metavar="B", nargs="?", help="moving image, or source point cloud")
    p.add_argument("--with", dest="implementations", action="append", metavar="LIST",
                   help="clouds: comma-separated implementations (default reference,open3d; 'all' = every built-in "
                        "one); built in: reference, open3d, open3d-tensor, small_gicp, small_gicp-plane, "
                        "small_gicp-gicp, kiss-icp, pycpd, probreg-cpd, probreg-filterreg; or py:MODULE:FUNCTION, "
                        "cmd:\"PROGRAM {source} {target} {init} {out} {params}\"; may be repeated")
    p.add_argument("--model", choices=("rigid", "similarity"), default=None, help="images: motion model (default rigid)")
    p.add_argument("--iterations", "--max-iterations", dest="iterations", type=positive_int, default=30,
                   help="max ICP iterations (per level for images; default 30)")
    from ._common import arg_int

    p.add_argument("--levels", type=arg_int(1, 8), default=None, help="images: pyramid levels (default 4)")
    p.add_argument("--max-distance", type=positive_float, default=None,
                   help="correspondence distance: images, px at full resolution (x 2^level; default 2.5); "
                        "clouds, in their units (default 1%% of the target's bounding-box diagonal)")
    p.add_argument("--voxel-size", type=positive_float, default=None,
                   help="clouds: voxel-downsample both clouds once, before every implementation")
    p.add_argument("--init", metavar="FILE", help="clouds: initial guess, a (d+1)x(d+1) text matrix, its numbers separated by spaces or commas (default identity)")
    from ._common import arg_float

    p.add_argument("--relative-fitness", type=arg_float(0, 1), default=1e-6, help="stopping rule: |Δfitness| threshold (default 1e-6)")
    p.add_argument("--relative-rmse", type=arg_float(0), default=None,
                   help="stopping rule: |Δinlier RMSE| threshold (default 1e-6; 1e-6 of their extent for clouds under one unit across)")
    p.add_argument("--timeout", type=positive_float, default=60.0, help="time limit of a cmd: program, s (default 60)")
    p.add_argument("--export", metavar="DIR", help="write the built-in suite as test vectors with the reference's traces")
    p.add_argument("--suite", metavar="DIR", help="run every implementation on the suite in DIR (written by --export; "
                                                  "the built-in suite when DIR holds none) and write a table + figure")
    p.add_argument("--out", metavar="DIR", help="--suite: where results go (default: the suite's DIR)")
    p.add_argument("--scans", metavar="DIR", default=None,
                   help="the LiDAR pair for the built-in suite (default ../shared/data/scans if present)")
    p.add_argument("--voxel-sizes", type=float_list, default=None, help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    add_record_arguments(p)


def _bar_wanted() -> bool:
    """Progress bars only on a terminal: a log or a pipe gets the command's own lines alone."""
    return sys.stderr.isatty()


def _implementations(args) -> list[str]:
    from ..errors import InputError
    from ..implementations import parse_list

    items: list[str] = []
    for text in args.implementations or ["reference,open3d"]:
        names = parse_list(text)
        if not names:
            raise InputError(f"--with {text!r} names no implementation")
        items.extend(names)
    return list(dict.fromkeys(items))


def _scans(args):
    if args.scans:
        return Path(args.scans)
    for base in (Path.cwd(), Path(__file__).resolve().parents[2]):
        cand = base.parent / "shared" / "data" / "scans"
        if cand.is_dir():
            return cand
    return None


def run(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..implementations import stdout_to_stderr

    if args.out and not args.suite:  # it was taken and ignored: nothing written, exit 0
        raise InputError(f"--out {args.out}: where --suite writes its results; "
                         + ("--export DIR is where the suite goes" if args.export else
                            "two images or clouds are compared on the terminal, or in one JSON object with --json "
                            f"(pcreg crosscheck A B --json > {Path(args.out) / 'crosscheck.json'})"))
    if args.export or args.suite:
        if args.a or args.b:
            raise InputError("--export and --suite take no A B clouds")
        with stdout_to_stderr():
            out = _suite(args)
        if args.json:
            print_json(out)
        else:
            print("\n".join(_suite_lines(out)))
        return 0
    if not (args.a and args.b):
        raise InputError("give two images or two clouds A B (or --export DIR / --suite DIR)")
    from ..cloud_reader import CLOUD_SUFFIXES
    from ..formats import IMAGE_SUFFIXES

    for path in (args.a, args.b):  # as pcreg.crosscheck reads paths; said first, not "--with applies to point clouds"
        suffix = Path(path).suffix.lower()
        if suffix and suffix not in IMAGE_SUFFIXES + CLOUD_SUFFIXES:
            raise InputError(f"{path}: unknown file type {suffix!r} (an image: {', '.join(IMAGE_SUFFIXES)}; or a point "
                             f"cloud: {', '.join(CLOUD_SUFFIXES)})")
    if args.a.lower().endswith(CLOUD_SUFFIXES) or args.b.lower().endswith(CLOUD_SUFFIXES):
        return _clouds(args)
    return _images(args)


def _suite(args) -> dict:
    from ..errors import InputError
    from ..implementations.suite import RESULT_FILES, builtin_cases, export_suite, load_suite, run_suite, write_results

    out: dict = {}
    if args.export:
        there = Path(args.export)
        if there.is_dir() and any(there.iterdir()) and not args.force:
            raise InputError(f"--export {there}: holds files already (use --force to write the suite over them)")
        cases, skipped = builtin_cases(scans=_scans(args))
        export_suite(args.export, cases, progress=_bar_wanted())
        out["exported"] = args.export
        out["cases"] = [c.name for c in cases]
        out["skipped"] = skipped
    if args.suite:
        suite = Path(args.suite)
        for where, what in ((suite, "--suite"), (Path(args.out) if args.out else None, "--out")):
            if where is not None and where.exists() and not where.is_dir():  # refused now, not after the suite ran
                raise InputError(f"{what} {where}: exists and is not a folder")
        results = Path(args.out or suite)
        earlier = [results / n for n in RESULT_FILES if (results / n).exists()]
        if earlier and not args.force:
            raise InputError(f"{earlier[0]}: results of an earlier run (use --force to replace them, or another --out)")
        skipped = {}
        if args.export and Path(args.export).resolve() == suite.resolve():  # the suite just exported: what it could not make
            skipped = dict(out["skipped"])
        if (suite / "index.json").exists():
            cases = load_suite(suite)
        else:
            cases, skipped = builtin_cases(scans=_scans(args))
        names = _implementations(args) if args.implementations else ["all"]
        from ..implementations import parse_list

        names = [n for t in names for n in parse_list(t)]
        rows = run_suite(cases, names, timeout=args.timeout, progress=_bar_wanted())
        out["results"] = write_results(Path(args.out or suite), rows, skipped=skipped)
        out["agreeing"] = sum(1 for r in rows if r.get("agrees"))
        out["rows"] = len(rows)
        out["skipped"] = skipped
    return out


def _suite_lines(out: dict) -> list[str]:
    """What ``--export`` and ``--suite`` did (:func:`_suite`'s ``out``), as lines for a person (``--json`` gives it whole)."""
    lines = []
    if "exported" in out:
        lines.append(f"exported {len(out['cases'])} case(s) to {out['exported']}: {', '.join(out['cases'])}")
    if "results" in out:
        lines.append(f"{out['agreeing']} of {out['rows']} row(s) agree with the reference ICP; results: "
                     + ", ".join(str(v) for v in out["results"].values()))
    lines += [f"skipped {name}: {why}" for name, why in out.get("skipped", {}).items()]
    return lines


def _clouds(args) -> int:
    from ..errors import InputError
    from ..implementations.crosscheck import crosscheck
    from ..implementations import stdout_to_stderr
    from ..registration.icp_options import ICPOptions

    given = [o for o, v in (("--model", args.model), ("--levels", args.levels)) if v is not None]
    if given:
        raise InputError(f"{' and '.join(given)} appl{'y' if len(given) > 1 else 'ies'} to images; point clouds are "
                         "cross-checked with the rigid ICP of every implementation")
    init = None
    if args.init:
        from ..text_files import read_text_matrix

        init = read_text_matrix(args.init, what="initial guess")  # regular file, bounded, finite
    voxel = args.voxel_size or (args.voxel_sizes[-1] if args.voxel_sizes else None)
    names = _implementations(args)
    with open_recorder(args, name=f"crosscheck {args.b} -> {args.a}", layout="crosscheck", inputs=(args.a, args.b)) as rec:
        rec.set_frame(0)
        rec.log_config({k: v for k, v in vars(args).items() if not k.startswith("_")})
        # Libraries print from C++ straight to file descriptor 1: keep stdout for the report alone.
        with stdout_to_stderr():
            options = ICPOptions(max_correspondence_distance=args.max_distance, max_iteration=args.iterations,
                                 relative_fitness=args.relative_fitness, relative_rmse=args.relative_rmse)
            try:
                report = crosscheck(args.a, args.b, implementations=names, init=init, options=options,
                                    voxel_size=voxel, timeout=args.timeout, progress=_bar_wanted() and not args.json)
            except InputError as exc:  # "init must be a finite 4x4 matrix ...": name its file
                named = init_refusal(exc, args.init) if args.init else None
                if named is not None:
                    raise named from None
                raise
        out = report.to_dict()
        if rec.enabled:  # the moved clouds are made for the recording alone
            log_cloud_crosscheck(rec, report)
    if args.json:
        print_json(out)
    else:
        print(format_table(out))
    failed = out["implementations"]["reference"]["error"]
    if failed is None:
        return 0
    failed = out["settings"].get("unconstrained") or failed  # the same refusal, naming the cloud it is about
    sys.stderr.write(f"pcreg: registration refused: the reference ICP failed to register {args.b} onto {args.a}: {failed}\n")
    return 3


def log_cloud_crosscheck(rec: RecorderProtocol, report) -> None:
    """Every implementation's moved cloud and error per iteration on the crosscheck_iteration timeline."""
    import numpy as np

    from ..implementations import reported
    from ..registration.transforms import apply

    rec.log_crosscheck_target(report.target)
    ref = report.rows["reference"]
    final = np.asarray(ref["matrix"]) if ref["matrix"] is not None else None
    src = report.source
    goal = apply(final, src) if final is not None else None
    for name, row in report.rows.items():
        if row["matrix"] is None:
            rec.log_text(f"crosscheck {name}: {row['error']}", level="WARN")
            continue
        steps = report.traces.get(name) or ()
        poses = [(s.iteration, s.matrix, reported(s.fitness), reported(s.inlier_rmse)) for s in steps] or \
                [(row["iterations"] or 0, np.asarray(row["matrix"]), row["fitness"], row["inlier_rmse"])]
        for k, m, fit, rmse in poses:
            moved = apply(np.asarray(m), src)
            err = float(np.sqrt(np.mean(np.sum((moved - goal) ** 2, axis=1)))) if goal is not None else None
            rec.log_crosscheck_iteration(name, k, moved, error=err, fitness=fit, inlier_rmse=rmse)
    slim = {"implementations": {n: {k: v for k, v in r.items() if k in (
        "iterations", "fitness", "inlier_rmse", "seconds", "rotation_disagreement_deg", "translation_disagreement",
        "centroid_disagreement", "matrix_relative_disagreement", "pose_relative_disagreement", "agrees")}
        for n, r in report.rows.items()}}
    rec.log_crosscheck(slim)


def _mixture_width(row: dict, gate: float) -> str | None:
    """Why a Gaussian mixture's row (pycpd, probreg) that disagrees may do so, in its table's words: the mixture's
    width at its end (its sigma2) against the gate, when wider. A mixture that ends wider than the gate still
    weighs each point against many of the other cloud's, so its optimum is not nearest-point ICP's (a uniform
    square of points, shifted 1% of its side: probreg's CPD ends at sigma 0.26, 19x the gate, 0.7 degrees off)."""
    sigma2 = (row.get("info") or {}).get("sigma2")
    if row.get("agrees") is not False or not isinstance(sigma2, float) or not math.isfinite(sigma2) or gate <= 0:
        return None
    sigma = math.sqrt(max(sigma2, 0.0))
    if sigma <= gate:
        return None
    return (f"its mixture ended wide: sigma {sigma:.3g}, {sigma / gate:.3g}x the gate (each point still weighed "
            "against many, not its nearest: not ICP's optimum)")


def format_table(out: dict) -> str:
    def f(v, spec=".3g"):
        return "-" if v is None else (("yes" if v else "no") if isinstance(v, bool) else format(v, spec))

    lines = [f"{'implementation':24s} {'comparability':12s} {'iter':>5s} {'fitness':>8s} {'rmse':>9s} "
             f"{'rot deg':>9s} {'centroid':>9s} {'rel':>9s} {'agrees':>6s} {'s':>6s}"]
    cut = [name for name in out["implementations"] if len(name) > 24]  # each named in full below the table
    for name, r in out["implementations"].items():
        tag = f"... [{cut.index(name) + 1}]" if len(name) > 24 else ""
        label = name[:24 - len(tag)] + tag if tag else name
        if r["error"]:
            lines.append(f"{label:24s} {r['comparability']:12s} {r['status']}: {r['error']}")
            continue
        lines.append(f"{label:24s} {r['comparability']:12s} {f(r['iterations'], 'd'):>5s} {f(r['fitness'], '.4f'):>8s} "
                     f"{f(r['inlier_rmse']):>9s} {f(r['rotation_disagreement_deg']):>9s} "
                     f"{f(r.get('centroid_disagreement')):>9s} {f(r.get('pose_relative_disagreement')):>9s} "
                     f"{f(r['agrees']):>6s} {r['seconds']:6.2f}")
        if r.get("converged") is False and r["comparability"] == "step":  # its pose is not where ICP ends
            lines.append(f"{'':24s} stopped at its {r['iterations']} iterations before its stopping rule fired: the pose "
                         "where it stopped" + (_run_on(out.get("reference_at_convergence")) if name == "reference" else ""))
        if (r.get("scale_disagreement") or 0.0) > 1e-6:  # neither rot deg nor centroid shows it
            lines.append(f"{'':24s} not rigid: it scales the cloud {100 * r['scale_disagreement']:.3g}% against the "
                         "reference")
        if r.get("unconstrained"):
            lines.append(f"{'':24s} unconstrained, not trusted: {r['unconstrained']} (this pose is one of many "
                         "that fit as well)")
        if r.get("divergence"):
            lines.append(f"{'':24s} first divergence at iteration {r['divergence']['iteration']}: "
                         f"{r['divergence']['cause']}")
        better = r.get("better_fit")
        if better:
            converged = better["compared_with"] != "reference"
            lines.append(f"{'':24s} fits the clouds better than the reference{' run to convergence' if converged else ''}: "
                         f"RMS distance capped at the gate {better['capped_rms']:.3g} against "
                         f"{better['compared_with_capped_rms']:.3g} (what point-to-point ICP lowers at every step), so the "
                         f"reference's pose is not ICP's best here ({'a local minimum' if converged else 'a local minimum, or stopped early'}) "
                         "and 'no' does not make this row wrong")
        wide = _mixture_width(r, out["settings"]["max_correspondence_distance"])
        if wide:
            lines.append(f"{'':24s} {wide}")
        replay = (r.get("info") or {}).get("trace_seconds") or 0.0
        if replay > max(1.0, r["seconds"]):  # time the command took that the row's s does not show
            lines.append(f"{'':24s} its iterations, replayed one call a step to count and trace them, took a further "
                         f"{replay:.1f} s (its s is its own call's)")
        said = (r.get("info") or {}).get("said")
        if said:  # what the library printed or warned, kept off the terminal: its row says it
            lines.append(f"{'':24s} its library said: {said[0]}" + (f" (and {len(said) - 1} more)" if len(said) > 1 else ""))
    s = out["settings"]
    lines.append(f"settings: gate {s['max_correspondence_distance']:.4g}, max {s['max_iterations']} iterations, "
                 f"{s['source_points']} source / {s['target_points']} target points; rot deg, centroid (how far "
                 "apart the two poses put the source's centroid) and rel (the poses' relative difference about that "
                 "centroid, which agrees judges) are disagreements with the reference (fixed-point and objective rows: "
                 "with the reference run to convergence)")
    if s.get("unconstrained"):
        lines.append(f"unconstrained: {s['unconstrained']}; no row's pose can be trusted")
    lines += [f"[{i}] {name}" for i, name in enumerate(cut, 1)]
    return "\n".join(lines)


def _run_on(conv: dict | None) -> str:
    """What the reference's row adds of the reference run on to convergence (``reference_at_convergence``), which the
    fixed-point and objective rows are compared with: nothing without such rows."""
    if not conv:
        return ""
    if conv.get("error") or conv.get("iterations") is None:
        return f"; run on, the reference failed ({conv.get('error') or 'no result'})"
    rmse = conv.get("inlier_rmse")
    reached = f" (rmse {rmse:.3g})" if isinstance(rmse, (int, float)) else ""
    how = "converges in" if conv.get("converged") else "had not converged in"
    return (f"; run on, the reference {how} {conv['iterations']}{reached}, which the fixed-point and objective rows "
            "are compared with")


def _read_image(path: str):
    """:func:`~pcreg.formats.read_image_file_and_damage` of ``path``, its refusal saying how clouds are read where
    the file has no suffix."""
    from ..errors import InputError
    from ..formats import read_image_file_and_damage
    from ..implementations.crosscheck import suffixless

    try:
        return read_image_file_and_damage(path)
    except InputError as error:
        if Path(path).suffix:
            raise
        raise suffixless(error) from None


def _images(args) -> int:
    from ..implementations.crosscheck import CROSSCHECK_REGISTRATION, CrosscheckConfig, crosscheck_images

    from ..errors import InputError, RegistrationError
    from ..registration.clouds import image_and_mask
    from ..registration.icp_options import RMSE_TOLERANCE
    from .register import _file_notes, _naming_its_file, _repeat_notes

    if args.implementations:
        raise InputError("--with applies to point clouds; images are cross-checked with both register backends")
    given = [o for o, v in (("--voxel-size", args.voxel_size), ("--init", args.init)) if v is not None]
    if given:
        raise InputError(f"{' and '.join(given)} appl{'y' if len(given) > 1 else 'ies'} to point clouds, not images")
    config = CrosscheckConfig(registration=CROSSCHECK_REGISTRATION.replace(
        model=args.model or "rigid", iterations=args.iterations, levels=args.levels or 4,
        max_correspondence_distance=args.max_distance if args.max_distance else 2.5,
        relative_fitness=args.relative_fitness,
        relative_rmse=RMSE_TOLERANCE if args.relative_rmse is None else args.relative_rmse))
    with open_recorder(args, name=f"crosscheck {args.b} -> {args.a}", layout="crosscheck", inputs=(args.a, args.b)) as rec:
        rec.set_frame(0)
        rec.log_config({k: v for k, v in vars(args).items() if not k.startswith("_")})
        callbacks = {b: rec.icp_callback(b) for b in ("reference", "open3d")}  # None each without a recording
        cb = (lambda it: callbacks[it.backend](it)) if callbacks["reference"] is not None else None
        # B registered onto A, read as pcreg register reads them: transparent pixels left out
        read = [_read_image(path) for path in (args.a, args.b)]
        stored = [image for image, _ in read]
        (ref, ref_mask), (mov, mov_mask) = (image_and_mask(img, path) for img, path in zip(stored, (args.a, args.b)))
        try:
            report = crosscheck_images(ref, mov, config=config, callback=cb, reference_mask=ref_mask,
                                       moving_mask=mov_mask)
        except (InputError, RegistrationError) as exc:  # "the moving image has no usable edges": name its file
            raise _naming_its_file(exc, tuple(zip((args.a, args.b), stored))) from None
        out = report.to_dict()
        rec.log_crosscheck(out)
    # what pcreg register notes of the files (damage, an EXIF orientation) and of a pattern that repeats; its model
    # check's notes are its own (the cross-check compares the backends on the search's pose, unchecked)
    notes = [*_file_notes([(path, damage) for path, (_, damage) in zip((args.a, args.b), read)], "cross-checks"),
             *_repeat_notes([(args.a, ref), (args.b, mov)])]
    if notes:
        out["notes"] = notes
    if args.json:
        print_json(out)
    else:
        print(f"reference: {report.reference}")
        print(f"open3d:    {report.open3d}")
        for key in ("max_corner_disagreement_px", "rotation_disagreement_deg", "translation_disagreement",
                    "matrix_relative_disagreement"):
            if out.get(key) is not None:
                print(f"{key}: {out[key]:.3g}")
        if report.refused:
            print(f"refused, not trusted: {report.refused} (pcreg register refuses this pair; both poses are its search's "
                  "best, compared all the same)")
    for note in notes:
        sys.stderr.write(f"pcreg: note: {note}\n")
    if report.refused is None:
        return 0
    sys.stderr.write(f"pcreg: registration refused: pcreg register refuses these images: {report.refused}\n")
    return 3
