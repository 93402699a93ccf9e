"""Stream a folder of frames or a video file through the label propagator: one label PNG per frame.

The first chosen frame (in name order, or a video's first; ``--start``, ``--stop`` and ``--every N``
choose) is the key frame and ``--labels`` its label image. A naive Bayes classifier is fitted on the
key frame and those labels (unknown pixels left out); every following frame is registered to the key
frame (a dense field by default), the key frame's labels are warped in as a prior and fused with the
classifier (:class:`pcreg.Propagator`). Frames are read one at a time
(:mod:`pcreg.datasets.sources`; a video's frame ``i`` is named ``{i:06d}``). Outputs and resuming:
:mod:`pcreg.pipeline.stream_run`. ``--truth LABELS_DIR`` scores every frame against its labels there
(``NAME.png`` for frame ``NAME``) and keeps the running error in ``run.json``. ``--follow object``
follows one moving object from the key frame's mask instead
(:class:`pcreg.pipeline.follow.ObjectFollower`; one key frame).

``--labels`` may also be a folder of key frames' labels anywhere in the video, ``NAME.png`` for the frame
``NAME`` (a folder's frame names are its files' stems, a video's ``{i:06d}``): every frame is labelled
from the key frames around it, forwards and backwards (:mod:`pcreg.pipeline.keys_run`). ``--suggest N``
writes ``OUT/suggest.txt``, the N frames to label next, best first, each with its predicted error
(:func:`pcreg.pipeline.keyframes.suggest`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..recording.interface import RecorderProtocol
from ._common import add_record_arguments, arg_int, open_recorder

def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..registration.transforms import MODELS

    p.add_argument("folder", metavar="FRAMES",
                   help="a video file (.mp4, .avi, .mkv, .mov) or a folder of frames (image files, or an images/ "
                        "sub-folder, read in name order)")
    p.add_argument("--labels", required=True, metavar="KEYFRAME.png|DIR",
                   help="label image of the first frame (class ids of --classes, a palette PNG, or the table's colours); or a "
                        "folder of key frames' labels, NAME.png for the frame NAME, every frame labelled from those "
                        "around it; or a CVAT 'Segmentation mask 1.1' export (its .zip or unpacked folder)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the label PNGs, run.json and steps.jsonl")
    p.add_argument("--mapping", choices=("none", "camvid", "davis"), default="none",
                   help="how --labels and --truth are coded: none (the class table's ids, colours or palette; the "
                        "default), camvid (CamVid class ids mapped to ground and obstacle) or davis (an object mask: "
                        "0 the background, anything else the object; the same as --classes davis)")
    p.add_argument("--classes", metavar="lagr|camvid11|davis|FILE", default=None,
                   help="the class table: lagr (0 ground, 1 obstacle, 2 unknown; the default), camvid11 (CamVid's "
                        "eleven classes and void), davis (background and object), or a labelmap.txt or JSON file")
    p.add_argument("--truth", metavar="LABELS_DIR", default=None,
                   help="score every frame against LABELS_DIR/NAME.png and keep the error in run.json")
    p.add_argument("--backend", choices=("reference", "open3d"), default="reference")
    p.add_argument("--model", choices=("dense", "flow") + MODELS, default="dense",
                   help="dense (default: a dense field), flow (DIS optical flow at --preset: the fast choice) or a "
                        "global motion model")
    p.add_argument("--preset", choices=("ultrafast", "fast", "medium"), default=None,
                   help="with --model flow: DIS's preset (default medium). --model flow --scale 0.5 labels about 3x "
                        "faster than the default, a little less accurate")
    p.add_argument("--init", choices=("identity", "auto"), default="identity",
                   help="the global registration's start: identity (default) or auto (global search too)")
    p.add_argument("--weight", type=float, default=2.0, help="fusion weight of the prior (default 2; 0 = naive Bayes)")
    p.add_argument("--scale", type=float, default=1.0, metavar="S",
                   help="run each step at this share of the frames' width and height (0 < S <= 1; default 1); the "
                        "labels come back at full size. 0.5 runs the step 1.8x faster, a little less accurate")
    p.add_argument("--follow", choices=("scene", "object"), default="scene",
                   help="scene (default: the camera moves through a scene) or object: follow one moving, deforming "
                        "object from its key-frame mask (DAVIS: J 0.742 against 0.552; worse than plain on 3 of 8 "
                        "CamVid clips, so not the default); its own motion: one key frame, the default options")
    p.add_argument("--confidence", action="store_true",
                   help="also write OUT/confidence/NAME.png: 255 x the probability that each label is right")
    p.add_argument("--start", type=arg_int(0), default=0, metavar="I",
                   help="the key frame: frame I (from 0, in name or decoding order; default 0)")
    p.add_argument("--stop", type=arg_int(1), default=None, metavar="J", help="stop before frame J (default: the end)")
    p.add_argument("--every", type=arg_int(1), default=1, metavar="N", help="every N-th frame from --start (default 1)")
    p.add_argument("--suggest", type=arg_int(1), default=None, metavar="N",
                   help="write OUT/suggest.txt: the N frames to label next, best first, with their predicted error")
    add_record_arguments(p)


def _read_labels(path: Path, mapping: str, table=None):
    """A key frame's (or a truth map's) labels read through the run's class table
    (:func:`pcreg.classes.keys.read_key_labels`)."""
    from ..classes import DEFAULT_TABLE
    from ..classes.keys import read_key_labels

    return read_key_labels(path, DEFAULT_TABLE if table is None else table, mapping)


class _TruthMaps:
    """Each frame's truth labels, ``ROOT/STEM.png``, read when the frame is scored: a long stream's maps are
    not all held in memory (2,000 frames at 640x480 are 600 MB). A folder's are all checked before the
    run starts; a video's length is known only once decoded, so each of its maps is checked when read."""

    def __init__(self, root: Path, frames, mapping: str, shape: tuple[int, int], table=None) -> None:
        self.root, self.frames, self.mapping, self.shape, self.table = root, frames, mapping, shape, table

    def path(self, t: int) -> Path:
        return self.root / f"{self.frames.stem(t)}.png"

    def __getitem__(self, t: int):
        from ..runs.truth import check_truth

        f = self.path(t)
        lab = _read_labels(f, self.mapping, self.table) if f.is_file() else None
        check_truth([lab], self.shape, [self.frames.name(t)])
        return lab


def _truth(folder: str | None, frames, shape, mapping: str, table=None):
    """The frames' truth labels (:class:`_TruthMaps`); a folder's checked first, every one, one at a time."""
    from ..errors import InputError

    if folder is None:
        return None
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"--truth {root}: not a folder")
    truth = _TruthMaps(root, frames, mapping, shape, table)
    if frames.kind == "folder":
        for t in range(len(frames)):
            truth[t]
    return truth


def _check_spares_inputs(out: Path, frames, labels: Path, truth) -> None:
    """Refuse an ``--out`` whose label PNGs (``OUT/NAME.png`` per frame) would overwrite a frame, the key
    frame's labels or a truth map: ``--out`` the frames' own folder, say."""
    from ..errors import InputError

    if truth is not None and truth.root.resolve() == out.resolve():
        raise InputError(f"--out {out} would overwrite the truth maps in {truth.root}; choose another folder")
    if frames.kind == "folder":
        written = {(out / f"{p.stem}.png").resolve() for p in frames.paths}
        clobbered = [f for f in [*frames.paths, labels] if f.resolve() in written]
    else:  # a video's outputs are OUT/{i:06d}.png, as many as it has frames
        clobbered = [labels] if frames.writes(labels.stem) and (out / f"{labels.stem}.png").resolve() == labels.resolve() else []
    if clobbered:
        raise InputError(f"--out {out} would overwrite the input {clobbered[0]}; choose another folder")


def run(args: argparse.Namespace) -> int:
    from ..classes.keys import choose_table, with_classes
    from ..classes.cvat import is_cvat_export
    from ..datasets.davis import check_key_mask
    from ..datasets.sources import Selection, open_frames
    from ..errors import InputError
    from ..outputs import OutputLock
    from ..pipeline.config import PropagatorConfig
    from ..runs.state import run_identity

    source, out = Path(args.folder), Path(args.out)
    args.table, args.mapping = choose_table(getattr(args, "classes", None), args.mapping)
    config = PropagatorConfig(model=args.model, preset=args.preset, backend=args.backend, init=args.init,
                              weight=args.weight, scale=args.scale, follow=args.follow)
    if config.follow == "object" and (Path(args.labels).is_dir() or is_cvat_export(Path(args.labels))):
        raise InputError(f"--labels {args.labels}: --follow object follows one key frame's mask, not a folder of "
                         "key frames; give one label image")
    frames = open_frames(source, Selection(args.start, args.stop, args.every))
    if Path(args.labels).is_dir() or is_cvat_export(Path(args.labels)):
        return _run_keys(args, frames, config)
    key_labels = _read_labels(Path(args.labels), args.mapping, args.table)
    if args.mapping == "davis":
        check_key_mask(key_labels, args.labels)
    decoded = frames.frames(0)
    key = next(decoded)  # a source with no frame at --start raises, never ends empty
    second = next(decoded, None)
    if second is None:
        raise InputError(f"{source}: needs at least two frames (the key frame and one more), found 1")
    if key_labels.shape != key.image.shape[:2]:
        raise InputError(f"{args.labels}: labels are {key_labels.shape[1]}x{key_labels.shape[0]}, the key frame "
                         f"{key.name} is {key.image.shape[1]}x{key.image.shape[0]}")
    truth = _truth(args.truth, frames, key.image.shape[:2], args.mapping, args.table)
    _check_spares_inputs(out, frames, Path(args.labels), truth)
    _check_suggest(args.suggest, frames, 1)
    prop = config.from_key_frame(key.image, key_labels, classes=args.table if args.table.n_known > 2 else None)
    identity = with_classes(run_identity(frames, source, Path(args.labels), config, mapping=args.mapping,
                                         truth=args.truth, confidence=args.confidence), args.table, args.mapping)
    with OutputLock(out):  # a second run on the same --out is refused, not raced
        return _label_frames(args, frames, (second, decoded), prop, truth, config, identity, key_labels)


def _label_frames(args: argparse.Namespace, frames, pending, prop, truth, config, identity: dict,
                  key_labels) -> int:
    """The frames not labelled yet, in order; ``OUT/run.json`` is the commit point of each. ``pending``: the
    frame after the key frame and the decoder it came from, which a fresh run continues."""
    import itertools
    import sys

    from ..datasets.sources import read_ahead
    from .._runner import check_interrupted, progress
    from ..errors import InputError, OutputError
    from ..frame import PreparedFrame
    from ..outputs import WriteBehind
    from ..pipeline.engine import propagate
    from ..pipeline.stream_run import StreamRun
    from ..runs.state import STATE

    out = Path(args.out)
    stream = StreamRun(frames, key_labels, out, config, truth=truth, identity=identity)
    start = stream.start(force=args.force)
    # a video's count is what its container declares or its duration suggests: it sizes the progress bar,
    # never where the run stops (decoding finds the end)
    total = len(frames) if frames.kind == "folder" else frames.count()
    if frames.kind == "folder" and start >= len(frames):
        print(f"{out}: all {start} frames already done")
        _write_suggest(args.suggest, out, frames, [0])
        return 0
    if start == 1:
        todo = itertools.chain([pending[0]], pending[1])
    else:
        pending[1].close()
        todo = frames.frames(start)  # decodes (a video) or skips (a folder) the frames done
    if start > 1:
        try:
            carry, learned = stream.carry_after(start - 1)
            prop.resume(start - 1, carry if prop.warm_starts else None, learned)
        except InputError as exc:  # a carry of another stream
            raise OutputError(f"{out}: {exc}; use --force to start over") from None
    done = start
    with open_recorder(args, name=f"run {args.folder}") as rec, \
            progress(total=None if total is None or total <= start else total - start, desc="frames", disable=None) as bar, \
            WriteBehind() as writer:  # a frame's outputs written while the next is labelled
        prepared = ((f.position, PreparedFrame.of(f.image, name="frame")) for f in read_ahead(todo))
        # the next frame decoded while this one is labelled; checked once: naive Bayes alone (with --truth)
        # reads the features the step made
        for t, image, labels in propagate(prop, prepared, check=check_interrupted, where=frames.where):
            plain = prop.classifier.predict(image) if truth is not None else None
            writer.submit(stream.record, t, labels, prop.last, plain, carry=prop.carry, learned=prop.learned_later(),
                          confidence=prop.last.confidence if args.confidence else None)
            _log(rec, t, image.rgb, labels, prop.last, frames.name(t), prop.working_size)
            done = t + 1
            bar.update(1)
    if done == start:
        print(f"{out}: all {start} frames already done")
        _write_suggest(args.suggest, out, frames, [0])
        return 0
    _write_suggest(args.suggest, out, frames, [0])
    s = stream.state
    msg = f"{done - start} frame(s) labelled into {out}"
    if s["fallbacks"]:
        msg += (f"; {s['fallbacks']} registration(s) failed (those frames fuse the key frame's labels unwarped; "
                f"see {out / 'steps.jsonl'})")
    if s.get("truth") and s["truth"].get("error") is not None:
        msg += (f"\nerror against the truth: {s['truth']['error']:.2f}% over {s['truth']['frames']} frames "
                f"(naive Bayes alone {s['truth']['plain_error']:.2f}%; in {out / STATE})")
    print(msg, file=sys.stdout)
    return 0


def _check_suggest(count: int | None, frames, keys: int) -> None:
    """``--suggest N`` no larger than the frames that are not key frames (a video's count where its
    container gives it; else checked once the run has decoded them all)."""
    from ..errors import InputError

    n = len(frames) if frames.kind == "folder" else frames.count()
    if count is not None and n is not None and count > n - keys:
        raise InputError(f"--suggest {count}: only {n - keys} frame(s) are not key frames")


def _write_suggest(count: int | None, out: Path, frames, keys: list[int]) -> None:
    """``OUT/suggest.txt``: the ``count`` frames to label next, best first, with their predicted error
    (:func:`pcreg.runs.files.write_suggestions`), from the predicted errors in steps.jsonl
    (:func:`pcreg.pipeline.keyframes.suggest`)."""
    from ..errors import InputError
    from ..pipeline.keyframes import suggest
    from ..runs.files import STEPS, parse_steps, read_step_lines, write_suggestions

    if count is None:
        return
    steps = parse_steps(out / STEPS, [ln for ln in read_step_lines(out) if ln.strip()])
    predicted = {s["frame"]: float(s["predicted_error"]) for s in steps if s.get("predicted_error") is not None}
    try:
        chosen = suggest(predicted, keys, count, max([*predicted, *keys]) + 1)
    except InputError as exc:
        raise InputError(f"--suggest {count}: {exc}") from None
    path = write_suggestions(out, [(frames.stem(t), predicted[t]) for t in chosen])
    print(f"the {count} frame(s) to label next, best first: {path}")


def _key_labels(folder: Path, frames, mapping: str, shape: tuple[int, int], table=None) -> dict:
    """``{position: labels}`` of the label PNGs in ``folder`` (``NAME.png`` labels the frame ``NAME``), each
    checked: a frame it names, one label a frame, the frames' size, something known."""
    from ..classes import DEFAULT_TABLE
    from ..classes.keys import all_unknown
    from ..errors import InputError

    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() == ".png" and not p.name.startswith("."))
    if not files:
        raise InputError(f"--labels {folder}: holds no label PNG (NAME.png for the frame NAME)")
    if frames.kind == "folder":
        positions = {p.stem: t for t, p in enumerate(frames.paths)}

        def where(stem: str) -> int | None:
            return positions.get(stem)
    else:
        s = frames.selection

        def where(stem: str) -> int | None:
            if not (stem.isascii() and stem.isdigit()) or not s.chosen(int(stem)):
                return None
            if frames.declared is not None and int(stem) >= frames.declared:
                return None
            return (int(stem) - s.start) // s.every

    keys: dict = {}
    seen: dict[int, Path] = {}
    for f in files:
        t = where(f.stem)
        if t is None:
            raise InputError(f"{f}: names no frame of {frames.path}" + ("" if frames.selection.to_dict() is None
                                                                           else " among those chosen"))
        if t in seen:
            raise InputError(f"{f}: a second label for the frame {frames.name(t)} (also {seen[t].name})")
        lab = _read_labels(f, mapping, table)
        if lab.shape != shape:
            raise InputError(f"{f}: labels are {lab.shape[1]}x{lab.shape[0]}, the frames {shape[1]}x{shape[0]}")
        if all_unknown(lab, table or DEFAULT_TABLE):
            raise InputError(f"{f}: the labels are all unknown ({(table or DEFAULT_TABLE).unknown}): nothing to fit or "
                             "propagate")
        keys[t], seen[t] = lab, f
    return {t: keys[t] for t in sorted(keys)}


def _run_keys(args: argparse.Namespace, frames, config) -> int:
    """``--labels FOLDER``: every frame labelled from the key frames around it (:mod:`pcreg.pipeline.keys_run`)."""
    import sys

    from .._runner import check_interrupted, progress
    from ..errors import InputError
    from ..outputs import OutputLock
    from ..classes.cvat import is_cvat_export, read_cvat_keys
    from ..classes.keys import with_classes
    from ..pipeline.keys_run import KeyRun
    from ..runs.state import STATE, run_identity

    source, out, folder = Path(args.folder), Path(args.out), Path(args.labels)
    first = next(frames.frames(0))  # a source with no frame at --start raises, never ends empty
    shape = first.image.shape[:2]
    if folder.resolve() == out.resolve():
        raise InputError(f"--out {out} would overwrite the key frames' labels in {folder}; choose another folder")
    if is_cvat_export(folder):
        args.table, keys = read_cvat_keys(folder, frames, shape, getattr(args, "classes", None),
                                          mapping=args.mapping)
    else:
        keys = _key_labels(folder, frames, args.mapping, shape, args.table)
    truth = _truth(args.truth, frames, shape, args.mapping, args.table)
    # the key files sit in the labels folder, which is not --out: only a frame or a truth map could be overwritten
    _check_spares_inputs(out, frames, folder / f"{frames.stem(next(iter(keys)))}.png", truth)
    _check_suggest(args.suggest, frames, len(keys))
    identity = with_classes(run_identity(frames, source, folder, config, mapping=args.mapping, truth=args.truth,
                                         confidence=args.confidence), args.table, args.mapping)
    with OutputLock(out), open_recorder(args, name=f"run {args.folder}") as rec:
        job = KeyRun(frames, keys, out, config, identity=identity, truth=truth, confidence=args.confidence)
        job.start(force=args.force)
        n = len(frames) if frames.kind == "folder" else frames.count()
        left = None if n is None else max(0, n - len(keys) - job.state["lines"])  # what the bar counts, not the run
        with progress(total=left, desc="frames", disable=None) as bar:
            def on_frame(t, image, labels, report, name, size) -> None:
                _log(rec, t, image, labels, report, name, size)
                bar.update(1)

            done = job.run(on_frame=on_frame, check=check_interrupted)
        s = job.state
        if done == 0:
            print(f"{out}: all frames already done")
        else:
            msg = f"{done} frame(s) labelled from {len(keys)} key frame(s) into {out}"
            if s["fallbacks"]:
                msg += f"; {s['fallbacks']} registration(s) failed (see {out / 'steps.jsonl'})"
            if s.get("truth") and s["truth"].get("error") is not None:
                msg += (f"\nerror against the truth: {s['truth']['error']:.2f}% over {s['truth']['frames']} frames "
                        f"(naive Bayes alone {s['truth']['plain_error']:.2f}%; in {out / STATE})")
            print(msg, file=sys.stdout)
        _write_suggest(args.suggest, out, frames, sorted(keys))
    return 0


def _log(rec: RecorderProtocol, t: int, image, labels, report, name: str, size) -> None:
    """One frame into the recording; ``size``: the propagator's working size (its motion is logged in the
    frames' pixels)."""
    rec.set_frame(t)
    rec.log_images(moving=image)
    rec.log_labels(predicted=labels)
    reg = report.registration
    if reg is None:
        rec.log_failure(f"{name}: {report.reason} (the key frame's labels, unwarped)")
        return
    matrix = size.frame_matrix(reg.matrix)
    if getattr(reg, "field", None) is not None:
        rec.log_dense(size.frame_field(reg.field), matrix=matrix,
                      confidence=None if reg.confidence is None else size.grow(reg.confidence))
    else:
        rec.log_transform(matrix)
