"""Entity paths and timelines of a pcreg recording: the one place that names them.

The recorder (``pcreg.recording.recorder``) writes to these paths, the blueprint (``pcreg.recording.blueprint``) lays out
views over them, and tests read them back. Plain strings, no imports.

Timelines: ``frame`` (the frame or unit being processed), ``icp_iteration`` (ICP steps, restarting at
every frame) and ``crosscheck_iteration`` (a cloud cross-check's iterations, shared by every
implementation); what is logged outside the iterations sits at 0 on both iteration timelines, so a view
on any timeline shows it.

Layout (``{x}`` is filled in at log time)::

    /                                   AnnotationContext (static): 0 ground, 1 obstacle, 2 unknown
    config                              TextDocument (static): the run's configuration as JSON
    log                                 TextLog: configuration, progress, failures
    registration                        Transform3D (static): z = SLOT_DEPTH, where images/{0,1} stand to be
                                        the reference (pcreg.recording.pair_log)
    registration/reference              reference image, reference pixel frame (JPEG or raw); logged when
                                        it changes; a Clear where the reference is the previous frame's
                                        moving image, which images/{0,1} then show
    registration/warped                 moving image warped into the reference frame (drawn at half opacity)
    registration/reference_cloud        Points2D: reference cloud (display subsample), coloured by pixel colour
    registration/moving_cloud           Points2D: moving cloud mapped into the reference by the transform
    registration/outline/{name}         LineStrips2D: the moving image's border mapped into the reference
    images/0, images/1                  each frame's moving image, stored once: the two alternate, each with a
                                        Transform3D at every frame that puts it at z = 0 (the moving image,
                                        drawn by the Moving view), z = SLOT_DEPTH (the reference, drawn by the
                                        Registration view) or z = -SLOT_DEPTH (neither); pcreg.recording.pair_log
    moving/image                        moving image, its own pixel frame (recordings made before images/)
    moving/cloud                        Points2D: moving cloud (display subsample), moving pixel frame
    warped/valid_mask                   where the warped image has data (PNG-encoded 0/255, or raw)
    transforms/{name}                   Tensor (3, 3) float64: the exact matrix, e.g. T_ref_mov
    labels/truth[/{prefix}]             SegmentationImage (H, W) uint8 class ids
    labels/predicted[/{prefix}]         SegmentationImage (H, W) uint8 class ids
    errors/{method}                     Scalars: error rate per method, on the frame timeline
    icp/{backend}/moving                Points2D per ICP iteration: the source cloud as it moves
    icp/{backend}/target                Points2D: the target cloud (per frame and pyramid level)
    icp/{backend}/correspondences       LineStrips2D: a subsample of source -> target pairs
    icp/{backend}/fitness               Scalars on the icp_iteration timeline
    icp/{backend}/inlier_rmse           Scalars on the icp_iteration timeline
    dense/displacement                  Image RGB: |field(p) - p| of a dense registration, colour-mapped (moving frame)
    dense/refinement                    Image RGB: |field(p) - T_ref_mov p|, what the dense step adds to the global one
    dense/quiver                        Arrows2D: field(p) - p on a coarse grid of moving pixels
    dense/confidence                    Image L: the field's per-pixel confidence, 0..255
    dense/warped_prior                  Image L: reference labels' obstacle probability warped into the moving frame
    dense/max_displacement              Scalars: the largest |field(p) - p| (px), the colour scale's top
    crosscheck/report                   TextDocument: both results and their disagreement as JSON
    crosscheck/{key}                    Scalars: every number of the report, nested keys joined by '/'
    crosscheck/target                   Points2D/3D: the target cloud of a cloud cross-check (static)
    crosscheck/{implementation}/cloud   Points2D/3D per iteration: the source cloud at that implementation's pose
    crosscheck/{implementation}/error   Scalars: RMS distance of those points from where the reference's
                                        final pose puts them, on the crosscheck_iteration timeline
    crosscheck/{implementation}/fitness, .../inlier_rmse   Scalars on the crosscheck_iteration timeline
    crosscheck/{implementation}/...     anything else an implementation logs: each implementation with a cloud
                                        gets a 2-D (or 3-D) view, each series name one plot with every
                                        implementation on it (on crosscheck_iteration, else icp_iteration)
    dense/{what}                        dense registration: images (e.g. dense/magnitude, the displacement
                                        magnitude; dense/warped_prior, the prior warped by the field),
                                        Arrows2D (dense/field), each a 2-D view; Scalars under dense/ in one plot
    __properties/pcreg                  recording property ``kind``: which command made the recording
                                        (register, crosscheck, sequence, rotation, demo, dense), so that
                                        the viewer gets that command's blueprint
"""

from __future__ import annotations

FRAME_TIMELINE = "frame"
ICP_TIMELINE = "icp_iteration"
CROSSCHECK_TIMELINE = "crosscheck_iteration"

CONFIG = "config"
LOG = "log"

REGISTRATION = "registration"
REFERENCE_IMAGE = "registration/reference"
WARPED_IMAGE = "registration/warped"
REFERENCE_CLOUD = "registration/reference_cloud"
MOVED_CLOUD = "registration/moving_cloud"
OUTLINE = "registration/outline"

MOVING = "moving"
MOVING_IMAGE = "moving/image"

#: The two entities that hold each frame's moving image once (they alternate), and their depths: a 2-D view
#: draws what is at its origin's depth and clips what is this far in front of it or behind it.
IMAGES = "images"
IMAGE_SLOTS = (f"{IMAGES}/0", f"{IMAGES}/1")
SLOT_DEPTH = float(1 << 20)
MOVING_CLOUD = "moving/cloud"

VALID_MASK = "warped/valid_mask"

TRANSFORMS = "transforms"

LABELS = "labels"
TRUTH = "labels/truth"
PREDICTED = "labels/predicted"

ERRORS = "errors"

DENSE = "dense"
DENSE_DISPLACEMENT = "dense/displacement"
DENSE_REFINEMENT = "dense/refinement"
DENSE_QUIVER = "dense/quiver"
DENSE_CONFIDENCE = "dense/confidence"
DENSE_WARPED_PRIOR = "dense/warped_prior"
DENSE_MAX_DISPLACEMENT = "dense/max_displacement"

ICP = "icp"
CROSSCHECK = "crosscheck"
CROSSCHECK_REPORT = "crosscheck/report"
CROSSCHECK_TARGET = "crosscheck/target"

#: The recording property (``/__properties/pcreg``) that holds the kind of recording.
PROPERTY = "pcreg"
KIND_FIELD = "kind"

#: Terrain classes: id -> (name, RGB colour).
CLASSES = {
    0: ("ground", (64, 160, 64)),
    1: ("obstacle", (200, 48, 48)),
    2: ("unknown", (128, 128, 128)),
}


def transform_path(name: str) -> str:
    return f"{TRANSFORMS}/{name}"


def outline_path(name: str) -> str:
    return f"{OUTLINE}/{name}"


def labels_path(kind: str, prefix: str = "") -> str:
    """``labels/truth`` or ``labels/predicted``, with ``/{prefix}`` appended when given."""
    base = TRUTH if kind == "truth" else PREDICTED
    prefix = prefix.strip("/")
    return f"{base}/{prefix}" if prefix else base


def error_path(method: str) -> str:
    return f"{ERRORS}/{method}"


def path_part(name: str) -> str:
    """``name`` as one part of an entity path: characters other than letters, digits, '-', '_' and '.' (a
    ``cmd:`` spec's) become '_'; '' and dots alone (which a path reads as no part, or as a step up) get a '_'
    before them. Two names may share a part: :meth:`pcreg.recording.crosscheck_log.CrosscheckLogger.part`
    keeps the names of one recording apart."""
    import re

    part = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
    return part if part.strip(".") else "_" + part


def icp_path(backend: str, what: str) -> str:
    return f"{ICP}/{backend}/{what}"
