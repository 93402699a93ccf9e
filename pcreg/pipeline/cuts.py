"""A scene stream's cut test: does the frame still show the key frame's scene?

A stream (:class:`pcreg.Propagator`) carries the key frame's labels into every frame. After a scene cut
(the video switches to another shot) nothing carried means anything, and naive Bayes labels a scene it
was never fitted on: on shared CamVid clips cut to another clip the two-class stream's labels were right
64-68% of the time where their mean confidence said 93-95%, the eleven-class stream's 38-41% where it
said 60-61% (docs/results.md, "Scene cuts").

Each step runs the object follower's cut test (:func:`pcreg.pipeline.follow.cut_evidence`, its limits
:data:`~pcreg.pipeline.follow.CUT_RESIDUAL` and :data:`~pcreg.pipeline.follow.CUT_COLOUR_CHANGE`, its DIS
preset and its half size, where they were measured) against the last frame found in the key frame's
scene: the key frame first, then each frame that passes. Before a cut that is the previous frame, as the
follower tests; after one every frame is still tested against the last frame before it, so every frame
of the other shot is found (a test against the key frame itself is not one: on a shared clip at one
frame a second the frames of a turn a few seconds on differ from the key frame as much as a cut does,
and are labelled 97% right). A frame found so is marked (:func:`~pcreg.pipeline.trust.least_confident`): its report's trust
summary says ``cut`` (the evidence's numbers are not kept: a resumed run writes its steps as the
uninterrupted one did), every label's confidence is the
least the stream gives (1/2 with two classes; with K classes the larger of 1/K and
:data:`~pcreg.pipeline.multiclass.CLASS_MIN_CONFIDENCE`). Its labels are left as they are: the trust
rule has already faded the carried priors there, and what remains is naive Bayes' best guess, marked as
one (learning from its sure pixels is kept: on the cut measured it raised the two-class stream's accuracy
after the cut from 64% to 65-68%).

The last frame in the scene (:class:`Scene`) is the stream's own state, handed on with the carry ``pcreg run``
saves (:attr:`pcreg.Propagator.scene`), so that a run resumed after a cut goes on finding the other shot as the
uninterrupted run does; a carry saved before it was kept has none, and such a run tests from the frame it resumes
at (:meth:`SceneCheck.restore` of None).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .follow import BINS, CUT_COLOUR_CHANGE, FLOW_PRESET, colour_change, cut_evidence, frame_colours

__all__ = ["Scene", "SceneCheck"]


@dataclass(frozen=True, eq=False)
class Scene:
    """The last frame found in the key frame's scene, as the cut test compares the next frame with it: its grey
    levels (h, w) uint8 at half the working size and its colour histogram ``colours`` (:data:`~pcreg.pipeline.
    follow.BINS` ^ 3,) float32 (:func:`~pcreg.pipeline.follow.frame_colours`). Both are kept read-only, a
    writeable array given as a copy: the stream goes on from it, and its caller may write into its own."""

    grey: np.ndarray
    colours: np.ndarray

    def __post_init__(self) -> None:
        g, c = self.grey, self.colours
        if not (isinstance(g, np.ndarray) and g.ndim == 2 and g.dtype == np.uint8 and g.size):
            raise InputError("a stream's carried scene frame must be an (h, w) uint8 array")
        if not (isinstance(c, np.ndarray) and c.shape == (BINS ** 3,) and c.dtype == np.float32
                and np.all(np.isfinite(c))):
            raise InputError(f"a stream's carried scene colours must be a ({BINS ** 3},) float32 array")
        object.__setattr__(self, "grey", _read_only(g))
        object.__setattr__(self, "colours", _read_only(c))


def _read_only(a: np.ndarray) -> np.ndarray:
    """``a`` itself when it is read-only (the stream's own), else a read-only copy (a caller's array)."""
    if a.flags.writeable:
        a = a.copy()
        a.setflags(write=False)
    return a


def _small(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(grey, colours)`` of an (h, w, 3) uint8 RGB frame at half its size, as the follower measures them."""
    import cv2

    h, w = rgb.shape[:2]
    small = cv2.resize(rgb, (max(1, w // 2), max(1, h // 2)), interpolation=cv2.INTER_AREA)
    grey, colours = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), frame_colours(small)
    grey.setflags(write=False)  # handed out as they are (:attr:`SceneCheck.scene`)
    colours.setflags(write=False)
    return grey, colours


class SceneCheck:
    """The cut test of a stream (see the module's docstring): ``key_rgb`` (h, w, 3) uint8, the key frame at
    the stream's working size, is the first frame of its scene."""

    def __init__(self, key_rgb: np.ndarray) -> None:
        self._scene: tuple[np.ndarray, np.ndarray] | None = _small(key_rgb)  # the last frame in the key's scene
        self._shape = self._scene[0].shape  # a scene frame's size: half the key frame's

    @property
    def scene(self) -> Scene | None:
        """The last frame found in the key frame's scene (None: not known, the next frame is taken as one)."""
        return None if self._scene is None else Scene(*self._scene)

    def check(self, scene: Scene | None) -> None:
        """Refuse a ``scene`` that :meth:`restore` cannot go on from: not a :class:`Scene`, or one of another
        size than this stream's (half the key frame's), which comes from another stream."""
        if scene is not None and not isinstance(scene, Scene):
            raise InputError("a stream's carried scene must be a pcreg.pipeline.cuts.Scene or None")
        if scene is not None and scene.grey.shape != self._shape:
            (h, w), (hh, ww) = scene.grey.shape, self._shape
            raise InputError(f"the carried scene frame is {w}x{h}, a stream of these frames keeps {ww}x{hh}: "
                             "it comes from another stream")

    def restore(self, scene: Scene | None) -> None:
        """Go on from ``scene`` (:attr:`scene`, as saved: a resumed stream); None, the last frame of the scene not
        known (a carry saved before it was kept): the next frame is taken as one. A scene :meth:`check`
        refuses is refused."""
        self.check(scene)
        self._scene = None if scene is None else (scene.grey, scene.colours)

    def test(self, rgb: np.ndarray) -> dict:
        """The cut evidence of the next frame ((h, w, 3) uint8 at the working size) against the last frame of
        the key frame's scene (:func:`~pcreg.pipeline.follow.cut_evidence`'s ``residual``, ``colour_change``
        and ``cut``); a frame that is no cut becomes that frame. The flow is measured only where the colours
        changed beyond :data:`~pcreg.pipeline.follow.CUT_COLOUR_CHANGE` (``residual`` None elsewhere): a cut
        is both, and on every pair of frames of the shared CamVid clips the colours alone rule one out (DIS
        medium at half of 640x480 takes about 25 ms, the colours about 1). Where the half-size frame is too small
        for DIS (a working size under 64 px a side), the colours alone decide: a change beyond the threshold is a
        cut (taken as none, untested, noise or a black frame at 80x60 would keep a confidence of 0.94-0.98)."""
        from ..registration.flow import DIS_MIN_SIDE, dis_flow, flow_field

        grey, colours = _small(rgb)
        if self._scene is None or grey.shape != self._scene[0].shape:
            self._scene = (grey, colours)
            return {"residual": None, "colour_change": None, "cut": False}
        last_grey, last_colours = self._scene
        change = colour_change(colours, last_colours)
        if change <= CUT_COLOUR_CHANGE:
            self._scene = (grey, colours)
            return {"residual": None, "colour_change": change, "cut": False}
        if min(grey.shape) < DIS_MIN_SIDE:
            return {"residual": None, "colour_change": change, "cut": True}
        field = flow_field(dis_flow(grey, last_grey, FLOW_PRESET))
        evidence = cut_evidence(grey, colours, last_grey, last_colours, field)
        if not evidence["cut"]:
            self._scene = (grey, colours)
        return evidence
