"""Stream a folder of frames through the label propagator: one label PNG per frame.

The first frame (in name order) is the key frame and ``--labels`` its label image. A naive Bayes
classifier is fitted on the key frame and those labels (unknown pixels left out); every following
frame is registered to the previous one, the previous labels are warped in as a prior and fused with
the classifier (:class:`pcreg.Propagator`). Each frame's labels are written to ``OUT/NAME.png``
(0 ground, 1 obstacle; the key frame's own labels as given), atomically; ``OUT/run.json`` records what
every step did. An interrupted run resumes where it stopped when started again with the same options.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_record_arguments, open_recorder

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm")
STATE = "run.json"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="folder of frames (image files, or an images/ sub-folder), read in name order")
    p.add_argument("--labels", required=True, metavar="KEYFRAME.png",
                   help="label image of the first frame: 0 ground, 1 obstacle, 2 unknown (or --mapping camvid)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the label PNGs and run.json")
    p.add_argument("--mapping", choices=("none", "camvid"), default="none",
                   help="how --labels is coded: none (0/1/2, the default) or camvid (CamVid class ids)")
    p.add_argument("--backend", choices=("reference", "open3d"), default="reference")
    p.add_argument("--model", choices=("translation", "rigid", "similarity", "affine", "projective"),
                   default="similarity")
    p.add_argument("--init", choices=("identity", "auto"), default="identity",
                   help="identity: consecutive frames are close (default); auto: global rotation search too")
    p.add_argument("--weight", type=float, default=1.0, help="fusion weight of the prior (default 1; 0 = naive Bayes)")
    add_record_arguments(p)


def _frames(folder: Path) -> list[Path]:
    from ..errors import InputError

    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    src = folder / "images" if (folder / "images").is_dir() else folder
    paths = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if len(paths) < 2:
        raise InputError(f"{src}: needs at least two frames (the key frame and one more), found {len(paths)}")
    return paths


def _read_labels(path: Path, mapping: str):
    import cv2
    import numpy as np

    from ..datasets.folder import _mapping_lut
    from ..errors import InputError

    if not path.is_file():
        raise InputError(f"{path}: no such file")
    raw = cv2.imdecode(np.fromfile(str(path), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError(f"{path}: not an image")
    if raw.ndim == 3:
        raw = raw[:, :, 0]
    if raw.dtype != np.uint8:
        raise InputError(f"{path}: labels must be an 8-bit image, got {raw.dtype}")
    lut = _mapping_lut(None if mapping == "none" else mapping)
    lab = lut[raw]
    if (lab == 255).any():
        bad = int(raw[lab == 255][0])
        raise InputError(f"{path}: label value {bad} is not {'a CamVid class id' if mapping == 'camvid' else '0, 1 or 2'}")
    return lab


def _write_png(path: Path, labels) -> None:
    import cv2

    from ..errors import OutputError
    from ..outputs import atomic_write_bytes

    ok, buf = cv2.imencode(".png", labels)
    if not ok:
        raise OutputError(f"cannot encode {path}")
    atomic_write_bytes(path, buf.tobytes())


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    import numpy as np

    from .._runner import progress
    from ..errors import InputError, OutputError
    from ..outputs import atomic_write_json
    from ..pipeline.stream import Propagator
    from ..registration.clouds import load_image

    folder, out = Path(args.folder), Path(args.out)
    paths = _frames(folder)
    if not np.isfinite(args.weight) or args.weight < 0:
        raise InputError(f"--weight must be a finite number >= 0, got {args.weight}")
    options = {"folder": str(folder.resolve()), "labels": str(Path(args.labels).resolve()), "mapping": args.mapping,
               "backend": args.backend, "model": args.model, "init": args.init, "weight": float(args.weight)}
    key_labels = _read_labels(Path(args.labels), args.mapping)
    key_image = load_image(paths[0])
    if key_labels.shape != key_image.shape[:2]:
        raise InputError(f"{args.labels}: labels are {key_labels.shape[1]}x{key_labels.shape[0]}, the key frame "
                         f"{paths[0].name} is {key_image.shape[1]}x{key_image.shape[0]}")
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    state = None
    if state_path.is_file() and not args.force:
        try:
            state = json.loads(state_path.read_text())
        except (OSError, ValueError):
            raise OutputError(f"{state_path}: unreadable; use --force to start over") from None
        if state.get("options") != options:
            raise OutputError(f"{out} holds a run with other options; use --force to start over or another --out")
    names = [p.stem for p in paths]
    if len(set(names)) != len(names):
        raise InputError(f"{folder}: two frames share a name ({len(names) - len(set(names))} duplicates)")

    prop = Propagator.from_key_frame(key_image, key_labels, backend=args.backend, model=args.model, init=args.init,
                                     weight=args.weight)
    if state is None:
        _write_png(out / f"{names[0]}.png", key_labels)
        state = {"options": options, "key_frame": paths[0].name, "done": 1, "reference": names[0],
                 "state_labels": None, "steps": []}
        atomic_write_json(state_path, state)
    else:
        ref = state["reference"]
        if ref not in names[: state["done"]]:
            raise OutputError(f"{state_path}: reference frame {ref!r} is not among the finished frames; use --force")
        if state.get("state_labels"):
            ref_labels = _read_labels(out / state["state_labels"], "none")
            prop.reset(load_image(paths[names.index(ref)]), ref_labels)
    start = int(state["done"])
    if start >= len(paths):
        print(f"{out}: all {len(paths)} frames already done")
        return 0
    refused = 0
    with open_recorder(args, name=f"run {folder}") as rec, \
            progress(total=len(paths) - start, desc="frames", disable=None) as bar:
        for t in range(start, len(paths)):
            image = load_image(paths[t])
            ref_name = state["reference"]
            labels = prop.step(image)
            info = prop.last
            refused += int(info.fallback)
            _write_png(out / f"{names[t]}.png", labels)
            if not info.fallback:  # the state travels with the reference frame
                state_name = f".state-{names[t]}.png"
                _write_png(out / state_name, prop.labels_state)
                old = state.get("state_labels")
                state.update(reference=names[t], state_labels=state_name)
            else:
                old = None
            step = info.to_dict()
            step["name"] = paths[t].name
            step["reference_name"] = paths[names.index(ref_name)].name
            state["steps"].append(step)
            state["done"] = t + 1
            atomic_write_json(state_path, state)  # the commit point: a frame counts once this is written
            if old and old != state.get("state_labels"):
                (out / old).unlink(missing_ok=True)
            if rec is not None:
                rec.set_frame(t)
                rec.log_images(moving=image)
                rec.log_labels(predicted=labels)
                if info.registration is not None:
                    rec.log_transform(info.registration.matrix)
                else:
                    rec.log_failure(f"{paths[t].name}: {info.reason} (plain naive Bayes)")
            bar.update(1)
    n = len(paths) - start
    msg = f"{n} frame(s) labelled into {out}"
    if refused:
        msg += f"; {refused} registration(s) refused (those frames use plain naive Bayes; see {STATE})"
    print(msg, file=sys.stdout)
    return 0
