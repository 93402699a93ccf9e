"""Following one moving, deforming object from its key-frame mask: ``pcreg run --follow object``.

::

    follower = ObjectFollower.from_key_frame(key_image, key_labels)   # 0 background, 1 the object, 2 unknown
    for image in frames:
        labels = follower.step(image)                                  # (H, W) uint8, 1 the object
        follower.last                                                  # what that step did (a StepReport)

The scene stream (:class:`pcreg.Propagator`) registers every frame to the key frame and fuses a naive
Bayes of colour and image row: right for a camera moving through a scene (CamVid), wrong for an object
that walks away from where it was in the key frame (DAVIS), whose row prior then pins it to the rows it
started in. Each step here, at half the frames' size (:data:`SCALE`), adds three log-odds terms:

1. **the previous frame's labels carried** by DIS optical flow from the new frame to the previous one,
   blurred by :data:`CARRY_BLUR` px before their logit, so that within a few px of their edge colour
   decides (:data:`CARRY_WEIGHT`), trusted as far as the flow explains the new frame (:func:`_chain_trust`):
   where it failed (a fast, blurred object) colour decides, so a part the chain was losing regrows;
2. **the key frame's colours**: a YCrCb histogram of the object and one of the background, each
   normalised (no area prior) and without position, so a moving object keeps its colours
   (:data:`COLOUR_WEIGHT`, the unit the other weights are relative to);
3. **the key frame's labels carried** by DIS flow from the new frame to the key frame, trusted per pixel
   by how well the key frame's colours carried along the same flow match the new frame
   (:data:`RESIDUAL_SIGMA`), and per frame by how far the key flow still finds the object where the
   chain has it: the IoU of the two carried masks squared (:data:`GATE_POWER`). When the object walks
   off its key-frame place the key term fades; where the key flow still follows it, it stops the
   chain's leaks (dark water beside a swan, the shadow under a car) (:data:`KEY_WEIGHT`).

A label is the sign of their sum at the frame's size (:func:`_read`): the carried terms resized
bilinearly, plus the colour term looked up on the full-size frame, so that thin parts the working size
blurs away (a kite's bar, a hand) keep their colour's say; then only the largest component and those
within :data:`NEAR` px of it are kept, which drops far-off blobs of the object's colours, and those on a part of
the key frame's object that lies farther than that from its largest, carried by the key flow (a part drawn
there is the object's, however far; :func:`_far_parts`). Its confidence
is a logistic regression over the sum's magnitude, the distance to the labels' edge and their product
(:mod:`~pcreg.pipeline.follow_confidence`); once the
labels hold no object (it left the frame), the colour term's alone, since the carried 'nowhere' saw nothing
(an object that left the frame is not searched for again; the five DAVIS sequences never lose theirs).

**A scene cut loses the object** (:func:`cut_evidence`): where the previous frame, carried by the flow just found,
leaves a mean grey residual above :data:`CUT_RESIDUAL` (0.3) of chance's (two unrelated pixels') and the two frames'
colour histograms share less than 1 - :data:`CUT_COLOUR_CHANGE` (0.55), the carried labels say nothing of the new
frame: they are dropped, the frame is read as lost. Real frames reach 0.145 (DAVIS) and, at one frame a second, 0.63
with colour changes of at most 0.401 (CamVid); 146 of 148 cuts built between those clips are found (docs/results.md).

**An object lost at a cut is searched for where its shot returns** (shot, other shot, the first shot again):
the last frame that held it is kept, and each later frame is tested against it with the cut test's two
signals, on a DIS flow from the new frame to it (a third flow, run only while the object is lost at a cut).
Where neither signal says another scene (residual at most :data:`CUT_RESIDUAL`, colour change at most
:data:`CUT_COLOUR_CHANGE`) the frame is back in that shot, and that frame's labels carried by the flow
replace the lost ones. A return to where the shot was left gives the labels an uncut run gives; a return
to a later moment of it is found only while the flow still explains it (docs/results.md, "A shot that
returns": 1 of 5 at 20 frames later); no frame of another clip was ever taken for the lost shot. The hard
labels at the working size, the frame's grey levels and its colour histogram are all a step hands to the next
(:class:`FollowCarry`, with the last frame that held an object lost at a cut), which ``pcreg run`` saves
with every frame, so a stopped run resumes exactly. The
step's two flows are independent: one runs on pcreg's helper thread (``pcreg._threads``).

Measured (docs/results.md, "Following one moving object"): on the five shared DAVIS 2016 sequences, the weights,
the residual's width, the blur and the reach chosen leaving one out (on J + F), J 0.751 / F 0.670 against the scene
stream's 0.552 / 0.482; with the chain's trust (since; DAVIS 2016 train J 0.624 -> 0.666), 0.756 / 0.693 on the five,
0.494 / 0.485 on val's 15 others (0.490 / 0.451 before). Every term is needed (without the chain J 0.507, the colours
0.632, the key carry 0.629, the gate 0.583, before the chain's trust). On CamVid's clips (scenes) it is worse than
plain naive Bayes on three of eight: a mode of its own, not the default.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .._calls import OneStream, one_caller
from ..errors import InputError
from ..frame import PreparedFrame
from .bars import Bars, kept_between
from .follow_colours import BINS, CLIP, _colour_index, _colour_table, _histogram
from .follow_confidence import (CONFIDENCE_INTERCEPT, CONFIDENCE_OFFSET, CONFIDENCE_SLOPE, CONFIDENCE_WEIGHTS,
                                colour_confidence, follow_confidence)
from .working import WorkingSize

if TYPE_CHECKING:
    from .report import StepReport

__all__ = ["ObjectFollower", "FollowCarry", "FollowTerms", "SCALE", "CARRY_WEIGHT", "COLOUR_WEIGHT", "KEY_WEIGHT", "RESIDUAL_SIGMA",
           "CARRY_BLUR", "GATE_POWER", "LOST_SHARE", "NEAR", "FAR_PART_SHARE", "CONFIDENCE_WEIGHTS", "CONFIDENCE_INTERCEPT",
           "CONFIDENCE_SLOPE", "CONFIDENCE_OFFSET", "FLOW_PRESET", "CUT_RESIDUAL", "CUT_COLOUR_CHANGE", "can_follow", "colour_change", "cut_evidence", "frame_colours"]

#: The working size, a share of the frames' sides (427x240 for 854x480): DIS at full size carried the
#: true mask one step only 0.008-0.023 IoU better, in four times the time.
SCALE = 0.5
#: DIS's preset of both flows (fast: J 0.735 / F 0.628 in about half the time, with residual 60 and blur 2).
FLOW_PRESET = "medium"
# Chosen on the five shared DAVIS sequences leaving one out, on the other four's mean J + F (carry {0.5, 0.7} x key {1, 1.5}
# x residual {40, 60} x blur {1, 2, 3, 4} x NEAR {none, 8, 16, 32, 64}): four folds chose these, breakdance's blur 3.
#: Weight of the previous frame's labels carried (chosen leaving one sequence out).
CARRY_WEIGHT = 0.5
#: Weight of the key frame's colour model (fixed: the unit the other weights are relative to).
COLOUR_WEIGHT = 0.5
#: Weight of the key frame's labels carried by the key flow (chosen leaving one sequence out).
KEY_WEIGHT = 1.0
#: Width of the trust in a residual (the key term's colour, the chain's grey levels; chosen leaving one out).
RESIDUAL_SIGMA = 40.0
#: Gaussian (px, working size) on the carried previous labels before their logit (chosen leaving one out).
CARRY_BLUR = 4.0
#: Gaussian (px, working size) on a residual before its trust.
RESIDUAL_BLUR = 2.0
#: The chain is trusted by its residual everywhere, not only near its object, once the flow carried less than this
#: share of the previous frame's object (of 0.25, 0.5, 0.75, chosen by 28-29 of the 30 folds of DAVIS 2016's train set).
LOST_SHARE = 0.5
#: The key term is weighted by the IoU of the key-carried and the chain-carried masks to this power.
GATE_POWER = 2.0
#: The labels at the frames' size keep their largest component and those within this many px of it: far-off blobs of
#: the object's colours (a red shirt beside a red dancer, a grey monument above a grey car) go (chosen leaving one out).
NEAR = 32.0
# A scene cut (:func:`cut_evidence`) is both of the two below. Measured at the working size on every pair of
# consecutive frames of the five shared DAVIS sequences and the eight shared CamVid clips (566 pairs) and on
# 148 cuts built from them (the last frame of one clip, the first of another of a different place;
# docs/results.md, "Scene cuts"):
#: The new frame's mean grey-level residual against the previous frame carried by the flow just found, as a
#: share of chance (the mean difference of two unrelated pixels, one from each frame's grey levels) above
#: which the flow does not explain the new frame: DAVIS's frames at most 0.145, CamVid's (one frame a second,
#: wide parallax) up to 0.63; every cut built at least 0.378.
CUT_RESIDUAL = 0.3
#: One minus the intersection of the two frames' colour histograms (the colour term's YCrCb bins) above which
#: the new frame shows other colours: the frames of the 36 real pairs above CUT_RESIDUAL (all CamVid's) at
#: most 0.401; the cuts built at least 0.367 (146 of 148 above this).
CUT_COLOUR_CHANGE = 0.45


@dataclass(frozen=True)
class FollowCarry:
    """What a step hands to the next: the hard labels (h, w) uint8 (1 the object) and the grey levels
    (h, w) uint8 of its frame, both at the working size, and its colour histogram ``colours``
    (:data:`BINS` ^ 3,) float32 summing to 1, which the cut test reads (None in a carry saved before there
    was one: that step's cut test then reads the residual alone, never a cut). Its arrays are kept read-only, a
    writeable array given as a copy: the next step goes on from them, and a caller may write into its own."""

    labels: np.ndarray
    grey: np.ndarray
    colours: np.ndarray | None = None
    #: The last frame that held the object before a cut lost it (its labels, grey levels and colours), which
    #: each later frame is tested against until one is back in its shot (:meth:`ObjectFollower.step`); None
    #: while the object is followed, and once it has been found again.
    held: FollowCarry | None = None

    def __post_init__(self) -> None:
        for name in ("labels", "grey"):
            a = getattr(self, name)
            if not (isinstance(a, np.ndarray) and a.ndim == 2 and a.dtype == np.uint8):
                raise InputError(f"a follower's carried {name} must be an (h, w) uint8 array")
        if self.labels.shape != self.grey.shape:
            raise InputError("a follower's carried labels and grey levels differ in size")
        c = self.colours
        if c is not None and not (isinstance(c, np.ndarray) and c.shape == (BINS ** 3,) and c.dtype == np.float32):
            raise InputError(f"a follower's carried colour histogram must be a ({BINS ** 3},) float32 array")
        for name in ("labels", "grey", "colours"):
            a = getattr(self, name)
            if a is not None and a.flags.writeable:
                a = a.copy()
                a.setflags(write=False)
                object.__setattr__(self, name, a)
        held = self.held
        if held is not None and not (isinstance(held, FollowCarry) and held.held is None and held.colours is not None
                                     and held.labels.shape == self.labels.shape):
            raise InputError("a follower's carried frame before a cut must be a FollowCarry of the same size, "
                             "with its colour histogram")


def _chance_residual(a: np.ndarray, b: np.ndarray) -> float:
    """The mean |difference| of a pixel of grey image ``a`` and an unrelated pixel of ``b`` (their
    histograms' independent draws): what a motion that explains nothing leaves."""
    ha = np.bincount(a.ravel(), minlength=256) / a.size
    hb = np.bincount(b.ravel(), minlength=256) / b.size
    v = np.arange(256, dtype=np.float64)
    return float(ha @ np.abs(v[:, None] - v[None, :]) @ hb)


def frame_colours(rgb: np.ndarray) -> np.ndarray:
    """(:data:`BINS` ^ 3,) float32 summing to 1: an (h, w, 3) uint8 RGB frame's colour histogram, the colour
    term's YCrCb bins, as the cut test (:func:`cut_evidence`) compares two frames'."""
    return _histogram(_colour_index(rgb))


def colour_change(colours: np.ndarray, reference_colours: np.ndarray) -> float:
    """One minus the intersection of two frames' colour histograms (:func:`frame_colours`): the cut test's
    colour term (:func:`cut_evidence`)."""
    return 1.0 - float(np.minimum(colours, reference_colours).sum())


def cut_evidence(grey: np.ndarray, colours: np.ndarray, reference_grey: np.ndarray,
                 reference_colours: np.ndarray | None, field: np.ndarray, difference: np.ndarray | None = None) -> dict:
    """Whether the new frame (``grey`` (h, w) uint8, its colour histogram ``colours``, :func:`frame_colours`) shows
    another scene than the reference frame (``reference_grey``, ``reference_colours``), whose motion to it the flow
    ``field`` ((h, w, 2) float32, reference coordinates of every new pixel) was found to be: ``residual``, the mean
    of their ``difference`` along it (:func:`_difference`, given where the caller has it) as a share of chance
    (:func:`_chance_residual`); ``colour_change``, one minus the intersection of the two colour histograms (None
    without the reference's); ``cut``, both above their limits (:data:`CUT_RESIDUAL`, :data:`CUT_COLOUR_CHANGE`).
    A cut that keeps the colours (two views of one place) or a frame the flow cannot follow is not one. The
    follower tests each frame against the previous one; a scene stream (:mod:`pcreg.pipeline.cuts`) against the
    last frame found in its key frame's scene."""
    difference = _difference(grey, reference_grey, field) if difference is None else difference
    residual = float(difference.mean()) / max(_chance_residual(grey, reference_grey), 1e-6)
    change = None if reference_colours is None else colour_change(colours, reference_colours)
    cut = change is not None and residual > CUT_RESIDUAL and change > CUT_COLOUR_CHANGE
    return {"residual": residual, "colour_change": change, "cut": cut}


def _logit(p: np.ndarray, eps: float) -> np.ndarray:
    return np.clip(np.log((p + eps) / (1 - p + eps)), -CLIP, CLIP).astype(np.float32)


@dataclass(frozen=True, eq=False)
class FollowTerms:
    """A follower's step's carried terms (its report's ``trust``): ``prior`` (h, w) float32 at the working
    size, the previous labels' and the key frame's labels' part of the fused log-odds; the report's
    ``log_odds`` is the colour term, the rest (as a scene stream's report splits naive Bayes from its
    priors)."""

    prior: np.ndarray

    def prior_term(self, shape: tuple[int, int]) -> np.ndarray:
        """(h, w) float32: the carried terms (``shape`` the working size's, as the log-odds')."""
        if tuple(shape) != self.prior.shape:
            raise ValueError(f"the carried terms are {self.prior.shape}, not {tuple(shape)}")  # a caller's bug
        return self.prior


def _near_largest(mask: np.ndarray, reach: float, carried: np.ndarray | None = None) -> np.ndarray:
    """(H, W) uint8: the mask's largest 8-connected component and every other component with a pixel
    within ``reach`` px of it, or on ``carried`` ((H, W) bool: the key frame's object carried to this frame);
    the rest, far-off blobs of object-like colour, dropped."""
    n, parts, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 2:
        return mask
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    distance = cv2.distanceTransform((parts != largest).astype(np.uint8), cv2.DIST_L2, 3)
    keep = np.zeros(n, np.uint8)
    keep[parts[distance <= reach]] = 1
    if carried is not None:
        keep[parts[carried]] = 1
    keep[0] = 0
    return keep[parts]


#: A part of the key frame's object farther than :data:`NEAR` px from its largest is followed when it holds at least
#: this share of the object's pixels: a part drawn there, not a stray speck of the brush (ten 8x8 specks about a
#: swan of 41,343 px were followed through the clip as object).
FAR_PART_SHARE = 0.01


def _far_parts(labels: np.ndarray, size: WorkingSize) -> np.ndarray | None:
    """(h, w) float32 at the working size: the object's share of each pixel in the key labels' parts farther than
    :data:`NEAR` px from its largest and of at least :data:`FAR_PART_SHARE` of the object (drawn there, so kept
    wherever the key flow carries them, as the labels of the frames after it would drop them); None where there is
    no such part."""
    obj = (labels == 1).astype(np.uint8)
    n, parts, stats, _ = cv2.connectedComponentsWithStats(obj - _near_largest(obj, NEAR), connectivity=8)
    big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= FAR_PART_SHARE * obj.sum())
    far = np.isin(parts, big[big > 0]).astype(np.uint8)
    if not far.any():
        return None
    return _object_share(np.where(far > 0, 1, np.where(labels == 2, 2, 0)).astype(np.uint8), size)[1]


def _read(prior: np.ndarray, colour: np.ndarray, size: WorkingSize, *,
          lost: bool = False, parts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(labels, confidence, log_odds)`` at the frames' size from the carried terms ``prior`` (h, w) at the
    working size and the colour term ``colour`` (H, W) at the frames' size: ``L`` = the carried terms
    brought to the frames' size bilinearly plus the colour term; the labels are its sign, less the
    components farther than :data:`NEAR` px from the largest (their ``L`` negated); the confidence is
    :func:`~pcreg.pipeline.follow_confidence.follow_confidence` of ``L`` and the labels.

    ``lost``: the previous labels held no object, so the carried terms say 'nowhere' without having seen
    it (it left the frame, or was lost, and may come back): the labels are still ``L``'s sign, but their
    confidence is the colour term's alone (:func:`~pcreg.pipeline.follow_confidence.colour_confidence`)."""
    full = size.grow(prior) + colour
    positive = (full > 0).astype(np.uint8)
    carried = None if parts is None else size.grow(parts.astype(np.float32)) > 0.5
    labels = _near_largest(positive, NEAR, carried)
    full = np.where(labels < positive, -full, full)
    confidence = colour_confidence(colour, labels) if lost else follow_confidence(full, labels)
    return labels, confidence, full


def _object_share(labels: np.ndarray, size: WorkingSize) -> tuple[np.ndarray, np.ndarray]:
    """``(known, share)`` (h, w) float32 at the working size of key labels (H, W): the known pixels' share of
    each working pixel, and the object's share of its known part (0.5 where mostly unknown: no evidence)."""
    h, w = size.shape
    known = cv2.resize((labels < 2).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    obj = cv2.resize((labels == 1).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return known, np.where(known > 0.5, obj / np.maximum(known, 1e-6), 0.5).astype(np.float32)


def can_follow(labels: np.ndarray) -> bool:
    """Whether key labels (H, W) (0 background, 1 the object, 2 unknown) hold an object the follower can start
    from: one that covers a pixel at its working size (:meth:`ObjectFollower.reset` refuses any other)."""
    lab = np.asarray(labels)
    return bool((lab == 1).any() and (_object_share(lab, WorkingSize(lab.shape, SCALE))[1] > 0.5).any())


def _difference(grey: np.ndarray, reference_grey: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(h, w) float32: |the new frame's grey levels - the reference frame's carried by ``field``|."""
    return np.abs(grey.astype(np.float32) - _warp(reference_grey.astype(np.float32), field))


def _chain_trust(difference: np.ndarray, carried: np.ndarray, previous_area: int) -> np.ndarray:
    """(h, w) float32 in (0, 1]: :func:`_trust` in the new frame's ``difference`` from the previous frame along the
    flow, within :data:`NEAR` px of the object it ``carried`` (1 farther), or everywhere when that is under
    :data:`LOST_SHARE` of the previous object's ``previous_area`` px (the flow lost it; an empty one is not)."""
    if int((on := carried > 0.5).sum()) < LOST_SHARE * previous_area:
        return _trust(difference)
    return np.where(cv2.distanceTransform((~on).astype(np.uint8), cv2.DIST_L2, 3) > NEAR * SCALE, np.float32(1), _trust(difference))


def _trust(residual: np.ndarray) -> np.ndarray:
    """``exp(-(r / RESIDUAL_SIGMA)^2)`` of a residual blurred by :data:`RESIDUAL_BLUR` px: how far a flow explains it."""
    return np.exp(-(cv2.GaussianBlur(residual, (0, 0), RESIDUAL_BLUR) / RESIDUAL_SIGMA) ** 2)


def _warp(values: np.ndarray, field: np.ndarray) -> np.ndarray:
    return cv2.remap(values, field, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


class ObjectFollower(OneStream):
    """Follow the key frame's object along a stream (see the module's docstring); what ``pcreg run`` steps
    with ``--follow object``, with :class:`pcreg.Propagator`'s stream interface (``reset``, ``step``,
    ``last``, ``carry``, ``resume``). ``classifier``: naive Bayes fitted on the key frame, used only to
    score naive Bayes alone beside the labels (``pcreg run --truth``); None without one."""

    trust = None  # no trust rule: one key frame only (a key-frames run is refused)

    def __init__(self, classifier=None) -> None:
        self.classifier = classifier
        self.last: StepReport | None = None
        #: The last step's fused log-odds (H, W) float32 at the frames' size, which its labels and
        #: confidence were read from (None before a step).
        self.log_odds: np.ndarray | None = None
        self._size: WorkingSize | None = None
        self._key_labels: np.ndarray | None = None
        self.bars: Bars | None = None  #: the key frame's black bars (:mod:`pcreg.pipeline.bars`)
        self._carry: FollowCarry | None = None
        self._key_carry: FollowCarry | None = None
        self._frame = 0

    @classmethod
    def from_key_frame(cls, image: np.ndarray, labels: np.ndarray) -> "ObjectFollower":
        """A follower reset to the key frame, with naive Bayes fitted on it (:attr:`classifier`)."""
        from ..classification.bayes import fit_classifier
        from ..datasets import Frame
        from ..classes import DAVIS
        from ..classes.keys import check_labels

        key = PreparedFrame.of(image, name="key frame")
        lab = check_labels(labels, key.shape, DAVIS)
        if not (lab < 2).any():
            raise InputError("the key frame's labels are all unknown (2): nothing to fit or propagate")
        follower = cls()
        follower.reset(key, lab)  # what the follower cannot take refused first
        follower.classifier = fit_classifier([Frame(key.rgb, lab, "key")])
        return follower

    @one_caller
    def reset(self, image, labels: np.ndarray) -> None:
        """Start at a labelled key frame: image (H, W, 3) uint8 RGB (or a PreparedFrame), labels (H, W)
        uint8 with 0 background, 1 the object, 2 unknown. A key frame refused (an :class:`InputError`) leaves
        the follower as it was."""
        from ..registration.flow import DIS_MIN_SIDE, pixel_grid
        from ..classes import DAVIS
        from ..classes.keys import check_labels

        full = PreparedFrame.of(image, name="key frame")
        lab = check_labels(labels, full.shape, DAVIS)
        size = WorkingSize(full.shape, SCALE)
        h, w = size.shape
        if min(h, w) < DIS_MIN_SIDE:
            H, W = full.shape
            raise InputError(f"frames of {W}x{H} are too small to follow an object (it works at {w}x{h}, DIS "
                             f"optical flow needs {DIS_MIN_SIDE} px a side)")
        rgb = size.shrunk(full).rgb
        known, share = _object_share(lab, size)
        if not (lab == 1).any():
            raise InputError("the key frame's mask has no object pixel (1): nothing to follow")
        if not (share > 0.5).any():  # nothing to carry: every frame would read 'no object', confidently
            raise InputError(f"the key frame's object ({int((lab == 1).sum())} px) covers no pixel at the size the "
                             f"follower works at ({w}x{h}): too small to follow")
        if not ((share <= 0.5) & (known > 0.5)).any():  # no colour of the background: its histogram is empty (0/0)
            raise InputError(f"the key frame's background ({int((lab == 0).sum())} px) covers no pixel at the size the "
                             f"follower works at ({w}x{h}): nothing to tell the object from")
        full.check_key(lab, 2)
        # made first, then taken at once: a key frame refused, or Ctrl-C while they are made, leaves the follower as it was
        key_grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        key_logit, colours, far = _logit(share, 1e-3), _colour_table(rgb, share, known > 0.5), _far_parts(lab, size)
        bars, grid, histogram = Bars.of(full.rgb, lab), pixel_grid((h, w)), _histogram(_colour_index(rgb))
        carry = FollowCarry((share > 0.5).astype(np.uint8), key_grey, histogram)
        self._share, self._key_logit, self._colours, self._far_share = share, key_logit, colours, far
        self._key_rgb, self._key_grey, self._size, self._key_labels = rgb.astype(np.float32), key_grey, size, lab
        self.bars, self._grid, self._carry, self._key_carry = bars, grid, carry, carry
        self._frame = 0
        self.last = self.log_odds = None

    @one_caller
    def step(self, image) -> np.ndarray:
        """Labels (H, W) uint8 (1 the object) of the next frame, an image or a PreparedFrame; see :attr:`last`. A step
        that raises (an error, Ctrl-C) leaves the follower as it was: the next step is the one it would have been."""
        from .._threads import both
        from ..registration.flow import dis_flow, flow_field
        from .report import StepReport
        from .trust import class_predicted_iou

        size, carry = self._size, self._carry
        if size is None or carry is None:
            raise InputError("ObjectFollower.step before reset: give the key frame and its labels first")
        t0 = time.perf_counter()
        frame = PreparedFrame.of(image, name="frame", shape=size.frame)
        rgb = size.shrunk(frame).rgb
        grey, previous_grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), carry.grey
        to_key, to_previous = both(lambda: dis_flow(grey, self._key_grey, FLOW_PRESET),
                                   lambda: dis_flow(grey, previous_grey, FLOW_PRESET))
        key_field, previous_field = flow_field(to_key, self._grid), flow_field(to_previous, self._grid)
        t1 = time.perf_counter()
        index = _colour_index(rgb)
        histogram = _histogram(index)
        difference = _difference(grey, previous_grey, previous_field)  # the cut test's, and the chain's trust
        cut = cut_evidence(grey, histogram, carry.grey, carry.colours, previous_field, difference)
        held, lost_here = carry.held, cut["cut"] and bool(carry.labels.any())
        if lost_here:  # the shot it is lost from: searched for again in the frames to come
            held = FollowCarry(carry.labels, carry.grey, carry.colours)
        if cut["cut"]:  # the carried labels say nothing of this frame: the object is lost
            carry = FollowCarry(np.zeros_like(carry.labels), carry.grey, carry.colours)
        back, back_trust, held = (None, None, held) if lost_here else self._search(grey, histogram, held)
        carried = _warp(carry.labels.astype(np.float32), previous_field) if back is None else back
        colour = COLOUR_WEIGHT * self._colours[index]
        t2 = time.perf_counter()
        trust = _trust(np.abs(rgb.astype(np.float32) - _warp(self._key_rgb, key_field)).mean(axis=2))
        on_key, on_chain = _warp(self._share, key_field) > 0.5, carried > 0.5
        gate = float((on_key & on_chain).sum()) / max(1, int((on_key | on_chain).sum()))
        prior = CARRY_WEIGHT * _logit(cv2.GaussianBlur(carried, (0, 0), CARRY_BLUR), 1e-4)
        if back_trust is not None:  # carried from the frame before the cut, trusted as the previous frame would be
            prior *= back_trust
        elif not cut["cut"]:
            prior *= _chain_trust(difference, carried, int(np.count_nonzero(carry.labels)))
        prior += (KEY_WEIGHT * gate ** GATE_POWER) * trust * _warp(self._key_logit, key_field)
        fused, far_share = colour + prior, getattr(self, "_far_share", None)  # None in a follower pickled before it
        labels, confidence, log_odds = _read(prior, COLOUR_WEIGHT * self._colours[_colour_index(frame.rgb)],
                                             size, lost=back is None and not carry.labels.any(),
                                             parts=None if far_share is None else _warp(far_share, key_field) > 0.5)
        labels, confidence, at = kept_between(self.bars, frame.rgb, labels, confidence)  # a letterbox's bars kept
        t3 = time.perf_counter()
        times = {"register": t1 - t0, "classify": t2 - t1, "fuse": t3 - t2, "total": t3 - t0}
        report = StepReport(frame=self._frame + 1, registration=_flow_result(key_field, t1 - t0), reason=None,
                            fallback=False, reference=0, times=times, confidence=confidence,
                            predicted_error=float(100.0 * (1.0 - confidence[at]).mean()),
                            trust=FollowTerms(prior), trust_summary={"gate": gate, **cut, "back": back is not None,
                                           "predicted_iou": class_predicted_iou(labels[at], confidence[at], None)},
                            log_odds=colour)
        # taken at once, at the end: a step that raises (Ctrl-C) leaves the follower as it was, as Propagator.step does
        new_carry = FollowCarry((fused > 0).astype(np.uint8), grey, histogram, held)
        self._carry, self._frame, self.log_odds, self.last = new_carry, self._frame + 1, log_odds, report
        return labels

    def _search(self, grey: np.ndarray, colours: np.ndarray,
                held: FollowCarry | None) -> tuple[np.ndarray | None, np.ndarray | None, FollowCarry | None]:
        """``(carried, trust, held)``: whether the new frame (``grey``, ``colours``) is back in the shot where a cut
        lost the object, whose last frame holding it is ``held`` (None: not lost at a cut), by the cut test's two
        signals (:func:`cut_evidence`) on a DIS flow from the new frame to that frame: where neither says another
        scene (residual at most :data:`CUT_RESIDUAL`, colour change at most :data:`CUT_COLOUR_CHANGE`), that frame's
        labels carried by the flow (float32 (h, w)), trusted as if it were the previous frame (:func:`_chain_trust`),
        and nothing held any more. Otherwise ``(None, None, held)``: one signal alone keeps the object lost, so that a
        frame of another place in like colours (a CamVid street against breakdance's: colour change 0.441, residual
        0.888) is not taken for it."""
        from ..registration.flow import dis_flow, flow_field

        if held is None:
            return None, None, None
        field = flow_field(dis_flow(grey, held.grey, FLOW_PRESET), self._grid)
        test = cut_evidence(grey, colours, held.grey, held.colours, field, difference := _difference(grey, held.grey, field))
        if test["residual"] > CUT_RESIDUAL or test["colour_change"] > CUT_COLOUR_CHANGE:
            return None, None, held
        carried = _warp(held.labels.astype(np.float32), field)
        return carried, _chain_trust(difference, carried, int(np.count_nonzero(held.labels))), None

    @property
    def carry(self) -> FollowCarry | None:
        """What the next step starts from (the last step's labels and grey levels); ``pcreg run`` saves it."""
        return self._carry if self._frame > 0 else None

    warm_starts = True  # each step needs the last one's carry (a resumed run reads it back)

    @property
    def learned(self) -> None:
        return None

    def learned_later(self):
        """Nothing is learned from the stream (the stream interface's :meth:`pcreg.Propagator.learned_later`)."""
        return lambda: None

    #: The stream interface's :attr:`pcreg.Propagator.scene`: the follower's cut test reads its carry instead.
    scene = None

    @one_caller
    def resume(self, frame: int, carry: FollowCarry | None, learned=None, scene=None) -> None:
        """Continue after step ``frame`` with the ``carry`` it left (:attr:`carry`, as saved): the next step
        does what it would have done in the uninterrupted stream (``scene``: the stream interface's, never
        kept for a follower)."""
        from ..validation import check_int

        if self._size is None:
            raise InputError("ObjectFollower.resume before reset: give the key frame and its labels first")
        frame = check_int(frame, "frame", lo=0)
        if frame > 0:
            if not isinstance(carry, FollowCarry):
                raise InputError("resuming a follower after a step needs the FollowCarry that step left")
            if carry.labels.shape != self._size.shape:
                h, w = carry.labels.shape
                raise InputError(f"the carried labels are {w}x{h}, a follower of these frames works at "
                                 f"{self._size.shape[1]}x{self._size.shape[0]}: they come from another stream")
            self._carry = carry
        else:  # right after the key frame: its own carry, whatever was stepped since
            self._carry = self._key_carry
        self._frame = frame

    @property
    def working_size(self) -> WorkingSize | None:
        """The frames' size and the size the steps run at (None before :meth:`reset`)."""
        return self._size

    @property
    def key_labels(self) -> np.ndarray | None:
        """(H, W) uint8 labels of the key frame (None before :meth:`reset`)."""
        return None if self._key_labels is None else self._key_labels.copy()


def _flow_result(field: np.ndarray, seconds: float):
    """The key flow as the step's registration (what a run's recording shows of the motion)."""
    from ..registration.flow import FlowResult

    return FlowResult(field, FLOW_PRESET, seconds)
