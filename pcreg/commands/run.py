"""Stream a folder of frames through the label propagator: one label PNG per frame.

The first frame (in name order) is the key frame and ``--labels`` its label image. A naive Bayes
classifier is fitted on the key frame and those labels (unknown pixels left out); every following
frame is registered to the key frame (a dense field by default), the key frame's labels are warped in
as a prior and fused with the classifier (:class:`pcreg.Propagator`). Outputs and resuming:
:mod:`pcreg.pipeline.stream_run`. ``--truth LABELS_DIR`` scores every frame against its labels there
(``NAME.png`` for frame ``NAME``) and keeps the running error in ``run.json``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..recording.interface import RecorderProtocol
from ._common import add_record_arguments, open_recorder

def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..registration.transforms import MODELS

    p.add_argument("folder", help="folder of frames (image files, or an images/ sub-folder), read in name order")
    p.add_argument("--labels", required=True, metavar="KEYFRAME.png",
                   help="label image of the first frame: 0 ground, 1 obstacle, 2 unknown (or --mapping camvid)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the label PNGs, run.json and steps.jsonl")
    p.add_argument("--mapping", choices=("none", "camvid"), default="none",
                   help="how --labels and --truth are coded: none (0/1/2, the default) or camvid (CamVid class ids)")
    p.add_argument("--truth", metavar="LABELS_DIR", default=None,
                   help="score every frame against LABELS_DIR/NAME.png and keep the error in run.json")
    p.add_argument("--backend", choices=("reference", "open3d"), default="reference")
    p.add_argument("--model", choices=("dense",) + MODELS, default="dense",
                   help="dense (default: a dense field) or a global motion model")
    p.add_argument("--init", choices=("identity", "auto"), default="identity",
                   help="the global registration's start: identity (default) or auto (global search too)")
    p.add_argument("--weight", type=float, default=2.0, help="fusion weight of the prior (default 2; 0 = naive Bayes)")
    p.add_argument("--confidence", action="store_true",
                   help="also write OUT/confidence/NAME.png: 255 x the probability that each label is right")
    add_record_arguments(p)


def _frames(folder: Path) -> list[Path]:
    from ..errors import InputError
    from ..formats import IMAGE_SUFFIXES

    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    src = folder / "images" if (folder / "images").is_dir() else folder
    paths = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if len(paths) < 2:
        raise InputError(f"{src}: needs at least two frames (the key frame and one more), found {len(paths)}")
    names = [p.stem for p in paths]
    if len(set(names)) != len(names):
        raise InputError(f"{folder}: two frames share a name ({len(names) - len(set(names))} duplicates)")
    return paths


def _read_labels(path: Path, mapping: str):
    import cv2
    import numpy as np

    from ..datasets.folder import mapping_lut
    from ..errors import InputError
    from ..formats import read_image_file

    raw = read_image_file(path, flags=cv2.IMREAD_UNCHANGED)  # a regular file, its size checked first
    if raw.ndim == 3:  # a grey image saved in colour is read as grey; labels in colours are not labels
        if raw.shape[2] not in (3, 4) or not (raw[:, :, 1:3] == raw[:, :, :1]).all():
            raise InputError(f"{path}: labels must be a single-channel image (one class id per pixel), "
                             f"got {raw.shape[2]} channels that differ")
        raw = raw[:, :, 0]
    if raw.dtype != np.uint8:
        raise InputError(f"{path}: labels must be an 8-bit image, got {raw.dtype}")
    lut = mapping_lut(None if mapping == "none" else mapping)
    lab = lut[raw]
    if (lab == 255).any():
        bad = int(raw[lab == 255][0])
        raise InputError(f"{path}: label value {bad} is not {'a CamVid class id' if mapping == 'camvid' else '0, 1 or 2'}")
    return lab


class _TruthMaps:
    """Each frame's truth labels, read when the frame is scored: a long stream's maps are not all held in
    memory (2,000 frames at 640x480 are 600 MB)."""

    def __init__(self, paths: list[Path], mapping: str) -> None:
        self.paths, self.mapping = paths, mapping

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, t: int):
        return _read_labels(self.paths[t], self.mapping)


def _truth(folder: str | None, paths: list[Path], shape, mapping: str):
    """The frames' truth labels (:class:`_TruthMaps`), every one checked first, one at a time."""
    from ..errors import InputError
    from ..pipeline.stream_run import check_truth

    if folder is None:
        return None
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"--truth {root}: not a folder")
    files = [root / f"{p.stem}.png" for p in paths]
    for f, p in zip(files, paths):
        check_truth([_read_labels(f, mapping) if f.is_file() else None], shape, [p.name])
    return _TruthMaps(files, mapping)


def _check_spares_inputs(out: Path, paths: list[Path], labels: Path, truth) -> None:
    """Refuse an ``--out`` whose label PNGs (``OUT/NAME.png`` per frame) would overwrite a frame, the key
    frame's labels or a truth map: ``--out`` the frames' own folder, say."""
    from ..errors import InputError

    written = {(out / f"{p.stem}.png").resolve() for p in paths}
    for f in [*paths, labels, *(truth.paths if truth is not None else [])]:
        if f.resolve() in written:
            raise InputError(f"--out {out} would overwrite the input {f}; choose another folder")


def run(args: argparse.Namespace) -> int:
    from ..classification.fusion import MAX_WEIGHT
    from ..errors import InputError
    from ..outputs import OutputLock
    from ..pipeline.stream import Propagator
    from ..registration.clouds import load_image

    folder, out = Path(args.folder), Path(args.out)
    paths = _frames(folder)
    if not 0 <= args.weight <= MAX_WEIGHT:
        raise InputError(f"--weight must be a number in 0..{MAX_WEIGHT:g}, got {args.weight}")
    options = {"backend": args.backend, "model": args.model, "init": args.init, "weight": float(args.weight)}
    key_labels = _read_labels(Path(args.labels), args.mapping)
    key_image = load_image(paths[0])
    if key_labels.shape != key_image.shape[:2]:
        raise InputError(f"{args.labels}: labels are {key_labels.shape[1]}x{key_labels.shape[0]}, the key frame "
                         f"{paths[0].name} is {key_image.shape[1]}x{key_image.shape[0]}")
    truth = _truth(args.truth, paths, key_image.shape[:2], args.mapping)
    _check_spares_inputs(out, paths, Path(args.labels), truth)
    prop = Propagator.from_key_frame(key_image, key_labels, **options)
    identity = {"folder": str(folder.resolve()), "labels": str(Path(args.labels).resolve()), "mapping": args.mapping,
                "truth": None if args.truth is None else str(Path(args.truth).resolve()), **options}
    if args.confidence:  # a run's identity names it only when on, so runs from before it still resume
        identity["confidence"] = True
    with OutputLock(out):  # a second run on the same --out is refused, not raced
        return _label_frames(args, paths, prop, truth, options, identity, key_labels)


def _label_frames(args: argparse.Namespace, paths: list[Path], prop, truth, options: dict, identity: dict,
                  key_labels) -> int:
    """The frames not labelled yet, in order; ``OUT/run.json`` is the commit point of each."""
    import sys

    from .._runner import check_interrupted, progress
    from ..errors import InputError, OutputError
    from ..pipeline.stream_run import STATE, StreamRun
    from ..registration.clouds import load_image

    folder, out = Path(args.folder), Path(args.out)
    stream = StreamRun(paths, key_labels, out, options, truth=truth, identity=identity)
    start = stream.start(force=args.force)
    if start >= len(paths):
        print(f"{out}: all {len(paths)} frames already done")
        return 0
    if start > 1:
        try:
            prop.resume(start - 1, stream.carry_after(start - 1) if prop.warm_starts else None,
                        stream.learned_after(start - 1))
        except InputError as exc:  # a carry of another stream
            raise OutputError(f"{out}: {exc}; use --force to start over") from None
    with open_recorder(args, name=f"run {folder}") as rec, \
            progress(total=len(paths) - start, desc="frames", disable=None) as bar:
        for t in range(start, len(paths)):
            check_interrupted()
            image = load_image(paths[t])
            try:
                labels = prop.step(image)
            except InputError as exc:  # a frame of another size: the step's own check, the file named
                raise InputError(f"{paths[t]}: {exc}") from None
            plain = prop.classifier.predict(image) if truth is not None else None
            stream.record(t, labels, prop.last.to_dict(), plain, carry=prop.carry, learned=prop.learned,
                          confidence=prop.last.confidence if args.confidence else None)
            _log(rec, t, image, labels, prop.last, paths[t].name)
            bar.update(1)
    s = stream.state
    msg = f"{len(paths) - start} frame(s) labelled into {out}"
    if s["fallbacks"]:
        msg += (f"; {s['fallbacks']} registration(s) failed (those frames fuse the key frame's labels unwarped; "
                f"see {out / 'steps.jsonl'})")
    if s.get("truth") and s["truth"].get("error") is not None:
        msg += (f"\nerror against the truth: {s['truth']['error']:.2f}% over {s['truth']['frames']} frames "
                f"(naive Bayes alone {s['truth']['plain_error']:.2f}%; in {out / STATE})")
    print(msg, file=sys.stdout)
    return 0


def _log(rec: RecorderProtocol, t: int, image, labels, report, name: str) -> None:
    rec.set_frame(t)
    rec.log_images(moving=image)
    rec.log_labels(predicted=labels)
    reg = report.registration
    if reg is None:
        rec.log_failure(f"{name}: {report.reason} (the key frame's labels, unwarped)")
    elif getattr(reg, "field", None) is not None:
        rec.log_dense(reg.field, matrix=reg.matrix, confidence=reg.confidence)
    else:
        rec.log_transform(reg.matrix)
