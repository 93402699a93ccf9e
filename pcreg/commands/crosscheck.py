"""Run the reference ICP and Open3D's ICP on identical inputs and report their disagreement."""

from __future__ import annotations

import argparse

from ._common import add_record_arguments, float_list, open_recorder, positive_float, positive_int, print_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("a", metavar="A", help="reference image, or target point cloud (.ply/.pcd/.xyz/.npy)")
    p.add_argument("b", metavar="B", help="moving image, or source point cloud")
    p.add_argument("--model", choices=("rigid", "similarity"), default="rigid")
    p.add_argument("--iterations", type=positive_int, default=30, help="max ICP iterations per level")
    p.add_argument("--levels", type=positive_int, default=4, help="image pyramid levels")
    p.add_argument("--voxel-sizes", type=float_list, default=None,
                   help="clouds: coarse-to-fine voxel sizes, e.g. 1.0,0.5,0.25 (default: from the extent)")
    p.add_argument("--max-distance", type=positive_float, default=2.5,
                   help="images: correspondence distance in px at full resolution (x 2^level)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_record_arguments(p)


def run(args: argparse.Namespace) -> int:
    from ..crosschecks import CLOUD_SUFFIXES, CrosscheckConfig, crosscheck

    config = CrosscheckConfig(model=args.model, iterations=args.iterations, levels=args.levels,
                              voxel_sizes=args.voxel_sizes, max_correspondence_distance=args.max_distance)
    clouds = args.a.lower().endswith(CLOUD_SUFFIXES)
    with open_recorder(args, name=f"crosscheck {args.b} -> {args.a}", layout="crosscheck") as rec:
        if rec is not None:
            rec.set_frame(0)
            rec.log_config({k: v for k, v in vars(args).items() if not k.startswith("_")})
        callbacks = {}
        if rec is not None:
            callbacks = {b: rec.icp_callback(b) for b in ("reference", "open3d")}
        # Per-iteration logging of 70k-point scans would dwarf the run; clouds log the results only.
        cb = (lambda it: callbacks[it.backend](it)) if rec is not None and not clouds else None
        report = crosscheck(args.a, args.b, config=config, callback=cb)  # B registered onto A
        out = report.to_dict()
        if rec is not None:
            rec.log_crosscheck(out)
    if args.json:
        print_json(out)
    else:
        print(f"reference: {report.reference}")
        print(f"open3d:    {report.open3d}")
        for key in ("max_corner_disagreement_px", "rotation_disagreement_deg", "translation_disagreement",
                    "matrix_relative_disagreement"):
            if out.get(key) is not None:
                print(f"{key}: {out[key]:.3g}")
    return 0
