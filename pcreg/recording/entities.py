"""Entity paths and timelines of a pcreg recording: the one place that names them.

The recorder (``pcreg.recording.recorder``) writes to these paths, the blueprint (``pcreg.recording.blueprint``) lays out
views over them, and tests read them back. Plain strings, no imports.

Layout (``{x}`` is filled in at log time)::

    /                                   AnnotationContext (static): 0 ground, 1 obstacle, 2 unknown
    config                              TextDocument (static): the run's configuration as JSON
    log                                 TextLog: configuration, progress, failures
    registration/reference              reference image, reference pixel frame (JPEG or raw)
    registration/warped                 moving image warped into the reference frame (drawn at half opacity)
    registration/reference_cloud        Points2D: reference cloud (display subsample), coloured by pixel colour
    registration/moving_cloud           Points2D: moving cloud mapped into the reference by the transform
    registration/outline/{name}         LineStrips2D: the moving image's border mapped into the reference
    moving/image                        moving image, its own pixel frame
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
    crosscheck/report                   TextDocument: both results and their disagreement as JSON
    crosscheck/{key}                    Scalars: every number of the report, nested keys joined by '/'
    crosscheck/target                   Points2D/3D: the target cloud of a cloud cross-check (static)
    crosscheck/{implementation}/cloud   Points2D/3D per iteration: the source cloud at that implementation's pose
    crosscheck/{implementation}/error   Scalars: RMS distance of those points from where the reference's
                                        final pose puts them, on the crosscheck_iteration timeline
    crosscheck/{implementation}/fitness, .../inlier_rmse   Scalars on the crosscheck_iteration timeline
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
MOVING_CLOUD = "moving/cloud"

VALID_MASK = "warped/valid_mask"

TRANSFORMS = "transforms"

LABELS = "labels"
TRUTH = "labels/truth"
PREDICTED = "labels/predicted"

ERRORS = "errors"
ICP = "icp"
CROSSCHECK = "crosscheck"
CROSSCHECK_REPORT = "crosscheck/report"

#: Backends that get a view of their own in the blueprint (others still appear in the ICP series).
ICP_BACKENDS = ("reference", "open3d")

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


def crosscheck_path(implementation: str, what: str) -> str:
    """``crosscheck/{implementation}/{what}``; characters other than letters, digits, '-', '_' and '.'
    in the implementation's name (a ``cmd:`` spec) become '_'."""
    import re

    return f"{CROSSCHECK}/{re.sub(r'[^A-Za-z0-9_.-]', '_', implementation)}/{what}"


def icp_path(backend: str, what: str) -> str:
    return f"{ICP}/{backend}/{what}"
