"""Stream a folder of frames or a video file through the label propagator: one label PNG per frame.

The first chosen frame (in name order, or a video's first; ``--start``, ``--stop`` and ``--every N``
choose) is the key frame and ``--labels`` its label image. A naive Bayes classifier is fitted on the
key frame and those labels (unknown pixels left out); every following frame is registered to the key
frame (a dense field by default), the key frame's labels are warped in as a prior and fused with the
classifier (:class:`pcreg.Propagator`). Frames are read one at a time
(:mod:`pcreg.datasets.sources`; a video's frame ``i`` is named ``{i:06d}``). The command hands what it
parsed to :meth:`pcreg.runs.run.Run.label` (a :class:`~pcreg.runs.run.RunRequest`); outputs and resuming:
:mod:`pcreg.runs.run`, the inputs' checks: :mod:`pcreg.runs.inputs`. ``--truth LABELS_DIR`` scores every frame against its labels there
(``NAME.png`` for frame ``NAME``) and keeps the running error in ``run.json``. ``--follow object``
follows one moving object from the key frame's mask instead
(:class:`pcreg.pipeline.follow.ObjectFollower`; one key frame). ``--classes`` names the class table the
labels are ids of (:mod:`pcreg.classes.keys`); the label PNGs are written in its colours.

``--labels`` may also be a folder of key frames' labels anywhere in the video, ``NAME.png`` for the frame
``NAME`` (a folder's frame names are its files' stems, a video's ``{i:06d}``): every frame is labelled
from the key frames around it, forwards and backwards (:mod:`pcreg.pipeline.keys_run`). ``--suggest N``
writes ``OUT/suggest.txt``, the N frames to label next, best first, each with its predicted error
(:func:`pcreg.pipeline.keyframes.suggest`). ``--labels`` may be a CVAT "Segmentation mask 1.1" export
too, a .zip or its unpacked folder (:mod:`pcreg.classes.cvat`), read as a folder of key frames.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import START_OVER, add_record_arguments, arg_int

def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..registration.flow import PRESETS
    from ..registration.transforms import MODELS

    p.add_argument("folder", metavar="FRAMES",
                   help="a video file (.mp4, .m4v, .mov, .3gp, .avi, .mkv, .webm, .ts, .mts, .m2ts) or a folder of frames "
                        "(image files, or an images/ sub-folder, read in name order)")
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
    p.add_argument("--backend", choices=("reference", "open3d"), default="reference",
                   help="with a global --model: the ICP, pcreg's own (reference, the default) or Open3D's; the same "
                        "algorithm")
    p.add_argument("--model", choices=("dense", "flow") + MODELS, default="dense",
                   help="dense (default: a dense field), flow (DIS optical flow at --preset: the fast choice) or a "
                        "global motion model")
    p.add_argument("--preset", choices=tuple(PRESETS), default=None,
                   help="with --model flow: DIS's preset (default medium). --model flow --scale 0.5 runs the step about "
                        "3.5x faster than the default (the whole command 1.8-2.3x), a little less accurate")
    p.add_argument("--init", choices=("identity", "auto"), default="identity",
                   help="with a global --model: the registration's start, identity (default) or auto (global "
                        "search too)")
    p.add_argument("--weight", type=float, default=2.0, help="fusion weight of the prior (default 2, the weight the confidence is calibrated at; 0 = naive Bayes)")
    p.add_argument("--scale", type=float, default=1.0, metavar="S",
                   help="run each step at this share of the frames' width and height (0 < S <= 1; default 1); the "
                        "labels come back at full size. 0.5 runs the step 1.8x faster, a little less accurate")
    p.add_argument("--follow", choices=("scene", "object"), default="scene",
                   help="scene (default: the camera moves through a scene) or object: follow one moving, deforming "
                        "object from its key-frame mask (DAVIS: J 0.756 against 0.552, F 0.693 against 0.482; worse than "
                        "plain on 3 of 8 CamVid clips, so not the default); its own motion: one key frame, the default options")
    p.add_argument("--confidence", action="store_true",
                   help="also write OUT/confidence/NAME.png: 255 x the probability that each label is right")
    p.add_argument("--start", type=arg_int(0), default=0, metavar="I",
                   help="the key frame: frame I (from 0, in name or decoding order; default 0)")
    p.add_argument("--stop", type=arg_int(1), default=None, metavar="J", help="stop before frame J (default: the end)")
    p.add_argument("--every", type=arg_int(1), default=1, metavar="N", help="every N-th frame from --start (default 1)")
    p.add_argument("--suggest", type=arg_int(1), default=None, metavar="N",
                   help="write OUT/suggest.txt: the N frames to label next, best first, with their predicted error")
    add_record_arguments(p, force=START_OVER)


def run(args: argparse.Namespace) -> int:
    from ..classes.keys import LabelCoding
    from ..datasets.sources import Selection
    from ..pipeline.config import PropagatorConfig
    from ..pipeline.stream import STREAM_WEIGHT
    from ..runs.run import Run, RunRequest

    config = PropagatorConfig(model=args.model, preset=args.preset, backend=args.backend, init=args.init,
                              weight=args.weight, scale=args.scale, follow=args.follow)
    request = RunRequest(Path(args.folder), Path(args.labels), Path(args.out), config,
                         Selection(args.start, args.stop, args.every), LabelCoding(args.classes, args.mapping),
                         truth=None if args.truth is None else Path(args.truth), confidence=args.confidence,
                         suggest=args.suggest, force=args.force, record=args.record, record_raw=args.record_raw)
    import warnings

    from ..errors import UncalibratedWarning

    with warnings.catch_warnings():  # the closing message says it, beside the predicted error, not every stream
        if config.weight != STREAM_WEIGHT:
            warnings.filterwarnings("ignore", category=UncalibratedWarning)
        return Run.label(request)
