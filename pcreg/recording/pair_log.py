"""A registration pair: its images, clouds and transforms (``registration/``, ``images/``, ``moving/``,
``warped/``, ``transforms/``): :class:`PairLogger`, and :class:`Pair`, what it holds of the frame's pair.

Each frame's moving image is stored once. A sequence's pair (k = 1) has the previous pair's moving image
as its reference, and rerun's viewer (0.41) draws an image at the time cursor only (an ``EncodedImage``
ignores a view's visible time range), so one entity cannot be the moving image at one frame and the
reference at the next. Two entities (:data:`~pcreg.recording.entities.IMAGE_SLOTS`) take the moving
images in turn, and a Transform3D logged on each at every frame places it: at depth 0, where the Moving
view (origin ``moving``) draws it; at the depth of ``registration`` (a static transform), where the
Registration view draws it as the reference; or at neither, hidden. A 2-D view clips what lies far from
its origin's depth (:data:`~pcreg.recording.entities.SLOT_DEPTH`), and depth moves nothing on the image
plane, so each view draws the one image it shows, framed as before. ``registration/reference`` then
holds a ``Clear``.

A slot gets one Transform3D row at a frame, never two: the viewer's transform cache keeps one transform
per entity and time, and of two rows at one time in different chunks (an image's row and a transform-only
row are batched apart, and the viewer's store merges them only while the images' chunk is small, about
384 KiB) it keeps whichever chunk it read last, not the newer row. A slot hidden by the reference and then
given the frame's moving image would stay hidden. :meth:`PairLogger.log_images` therefore places the slots
of one call once, where each ends up.

A reference that is not the previous frame's moving image (a rotation's angles, k > 1, the first pair) is
logged at ``registration/reference``, and only when it changes: the viewer's latest-at query keeps
showing the one logged. :meth:`pcreg.recording.readback.Recording.reference` and
:meth:`~pcreg.recording.readback.Recording.moving` read a pair's images back from this layout and from
those of earlier recordings."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import rerun as rr

from pcreg.recording import entities as E

from ..errors import InputError
from .sink import Sink
from .values import apply_homography, as_colors, as_image, as_points, display_indices

__all__ = ["Pair", "PairLogger", "REFERENCE_DRAW_ORDER", "MOVING_DRAW_ORDER"]

#: Draw orders in the Registration view: a reference logged for its pair above the previous frame's moving
#: image, both below the warped image (-5).
REFERENCE_DRAW_ORDER = -9.0
MOVING_DRAW_ORDER = -10.0

#: Where an image slot stands (a translation along z): drawn by the Moving view, by the Registration view
#: as the reference, or by neither.
MOVING_AT = (0.0, 0.0, 0.0)
REFERENCE_AT = (0.0, 0.0, E.SLOT_DEPTH)
HIDDEN_AT = (0.0, 0.0, -E.SLOT_DEPTH)

@dataclass(frozen=True)
class Pair:
    """What the logs of one pair (one frame) draw with, from what was logged of it so far.

    moving_shape : (H, W) of the moving image logged (its border is drawn by a 3x3 transform).
    moving_cloud : (points (n, 2) float64, colours (n, 3) uint8 or None), the moving cloud's display
        subsample (drawn in the reference by ``T_ref_mov``).
    matrix : (3, 3) ``T_ref_mov`` logged (moves the moving cloud logged after it).
    """

    moving_shape: tuple[int, int] | None = None
    moving_cloud: tuple[np.ndarray, np.ndarray | None] | None = None
    matrix: np.ndarray | None = None


class PairLogger:
    """Logs a registration pair to a :class:`~pcreg.recording.sink.Sink`.

    The moving cloud in the reference needs both the cloud and ``T_ref_mov``, and a transform's outline
    the moving image's size: whichever comes second draws it, from :attr:`pair` (what was logged of the
    frame's pair so far), which :meth:`new_pair` clears.
    """

    def __init__(self, sink: Sink, *, max_display_points: int = 500) -> None:
        self.sink = sink
        self.max_display_points = int(max_display_points)
        self.pair = Pair()
        # on the sink's thread only: each slot's image and the frame it was logged at, the slot holding the
        # newest, the slot shown as the reference (None: none), the reference registration/reference shows
        # (None: none, or cleared), whether it was cleared last, and the latest frame an image was logged at
        self._slots: list[tuple[int | None, np.ndarray] | None] = [None, None]
        self._newest: int | None = None
        self._reference_slot: int | None = None
        self._shown_reference: np.ndarray | None = None
        self._cleared = False
        self._last_frame: int | None = None
        # within _log_pair_images: each slot's place and images so far, sent at its end (one row a slot)
        self._placing: dict[int, tuple[tuple[float, float, float], tuple]] = {}

    def new_pair(self) -> None:
        """Forget the pair logged so far (a new frame)."""
        self.pair = Pair()

    def log_images(self, *, reference: np.ndarray | None = None, moving: np.ndarray | None = None,
                   warped: np.ndarray | None = None, valid_mask: np.ndarray | None = None) -> None:
        """Images as JPEG (or raw), the mask as PNG; checked and copied here (the caller may reuse its buffers)."""
        sink = self.sink
        frame = sink.frame
        jobs = []
        a = None if reference is None else as_image(reference, "reference").copy()
        m = None if moving is None else as_image(moving, "moving").copy()
        if m is not None:
            self.pair = dataclasses.replace(self.pair, moving_shape=(int(m.shape[0]), int(m.shape[1])))
        if a is not None or m is not None:
            sink.later(lambda: self._log_pair_images(a, m, frame))
        if warped is not None:
            w = as_image(warped, "warped").copy()
            jobs.append((E.WARPED_IMAGE, lambda w=w: sink.image(w, opacity=0.5, draw_order=-5.0)))
        if valid_mask is not None:
            mask = np.asarray(valid_mask)
            if mask.ndim != 2:
                raise InputError(f"valid_mask must be (H, W), got shape {mask.shape}")
            m8 = np.where(mask.astype(bool), np.uint8(255), np.uint8(0))
            jobs.append((E.VALID_MASK, lambda m8=m8: sink.mask(m8)))
        for path, make in jobs:
            sink.log_later(path, make)

    def _log_pair_images(self, a: np.ndarray | None, m: np.ndarray | None, frame: int | None) -> None:
        """On the sink's thread: the reference, then the moving image, each slot placed once, where it ends up
        (see the module: a second row at the same frame may win over the first in the viewer)."""
        self._placing = {}
        if a is not None:
            self._log_reference(a, frame)
        if m is not None:
            self._log_moving(m, frame)
        for slot, (at, images) in sorted(self._placing.items()):
            self.sink.send(E.IMAGE_SLOTS[slot], *images, rr.Transform3D(translation=at))

    def _place(self, slot: int, at: tuple[float, float, float], *images) -> None:
        """Put ``slot`` at ``at`` (with ``images``) once :meth:`_log_pair_images` sends its slots: the last place
        of a slot replaces the earlier ones of the call, its images kept."""
        earlier = self._placing.get(slot)
        self._placing[slot] = (at, (earlier[1] if earlier else ()) + images)

    def _log_moving(self, m: np.ndarray, frame: int | None) -> None:
        """On the sink's thread: the moving image, in the slot that is not the reference shown (else the one
        not holding the newest image), at depth 0; the other slot hidden unless it is the reference."""
        self.sink.once(E.REGISTRATION, "slot depth", lambda: rr.Transform3D(translation=REFERENCE_AT))
        if self._reference_slot is not None:
            slot = 1 - self._reference_slot
        else:
            slot = 0 if self._newest is None else 1 - self._newest
        self._place(slot, MOVING_AT, self.sink.image(m, draw_order=MOVING_DRAW_ORDER))
        other = 1 - slot
        if self._slots[other] is not None and other != self._reference_slot:
            self._place(other, HIDDEN_AT)
        self._slots[slot], self._newest = (frame, m), slot
        self._note_frame(frame)

    def _log_reference(self, a: np.ndarray, frame: int | None) -> None:
        """On the sink's thread: the reference, shown from the slot holding the previous frame's moving image
        where it is that image, else logged at ``registration/reference`` unless shown already (see the
        module). Only while frames go forward: a view's latest-at query at ``frame`` must see what was
        logged before."""
        sink = self.sink
        forward = frame is not None and (self._last_frame is None or frame >= self._last_frame)
        self._note_frame(frame)
        newest = self._newest
        previous = None if newest is None else self._slots[newest]
        if forward and frame is not None and previous is not None and previous[0] == frame - 1 and _same(previous[1], a):
            assert newest is not None
            if self._reference_slot is not None and self._reference_slot != newest:
                self._place(self._reference_slot, HIDDEN_AT)
            self._place(newest, REFERENCE_AT)
            self._reference_slot = newest
            if not self._cleared:
                sink.send(E.REFERENCE_IMAGE, rr.Clear(recursive=False))
                self._cleared, self._shown_reference = True, None
            return
        shown = self._slots[self._reference_slot] if self._reference_slot is not None else None
        if forward and shown is not None and _same(shown[1], a):
            return  # latest-at: the slot still shows it
        if forward and self._shown_reference is not None and _same(self._shown_reference, a):
            return  # latest-at: registration/reference still shows it
        if self._reference_slot is not None:
            self._place(self._reference_slot, HIDDEN_AT)
            self._reference_slot = None
        sink.send(E.REFERENCE_IMAGE, sink.image(a, draw_order=REFERENCE_DRAW_ORDER))
        self._cleared, self._shown_reference = False, a

    def _note_frame(self, frame: int | None) -> None:
        if frame is not None and (self._last_frame is None or frame > self._last_frame):
            self._last_frame = frame

    def _shown(self, points: np.ndarray, colors: np.ndarray | None, name: str) -> tuple[np.ndarray, np.ndarray | None]:
        """The display subsample of a cloud and its colours, copied (the caller may reuse its buffers)."""
        p = as_points(points, f"{name}_points")
        c = as_colors(colors, len(p), f"{name}_colors")
        idx = display_indices(len(p), self.max_display_points)
        return p[idx].copy(), None if c is None else c[idx].copy()

    def log_clouds(self, *, reference_points: np.ndarray | None = None, reference_colors: np.ndarray | None = None,
                   moving_points: np.ndarray | None = None, moving_colors: np.ndarray | None = None) -> None:
        """Points2D of at most ``max_display_points`` each; the moving cloud also mapped by the pair's matrix."""
        if reference_points is not None:
            shown = self._shown(reference_points, reference_colors, "reference")
            self.sink.log_later(E.REFERENCE_CLOUD, lambda: _points(*shown))
        if moving_points is not None:
            moving = self._shown(moving_points, moving_colors, "moving")
            self.sink.log_later(E.MOVING_CLOUD, lambda: _points(*moving))
            self.pair = dataclasses.replace(self.pair, moving_cloud=moving)
            self._log_moved_cloud()

    def _log_moved_cloud(self) -> None:
        """The moving cloud in the reference, once the pair has both it and ``T_ref_mov``."""
        cloud, matrix = self.pair.moving_cloud, self.pair.matrix
        if cloud is not None and matrix is not None:
            points, colors = cloud
            self.sink.log_later(E.MOVED_CLOUD, lambda: _points(apply_homography(matrix, points), colors))

    def log_transform(self, matrix: np.ndarray, *, name: str = "T_ref_mov",
                      moving_shape: tuple[int, int] | None = None) -> None:
        """A Tensor at ``transforms/{name}``; a 3x3 one also drawn (``registration/outline/{name}``, and the
        moving cloud for ``T_ref_mov``)."""
        m = np.array(matrix, dtype=np.float64)  # a copy: logged on the sink's thread
        if m.shape not in ((3, 3), (4, 4)) or not np.all(np.isfinite(m)):
            raise InputError(f"matrix must be a finite (3, 3) or (4, 4) array, got shape {m.shape}")
        self.sink.log_later(E.transform_path(name), lambda: rr.Tensor(m, dim_names=["row", "col"]))
        if m.shape != (3, 3):
            return
        if name == "T_ref_mov":
            self.pair = dataclasses.replace(self.pair, matrix=m)
            self._log_moved_cloud()
        shape = moving_shape or self.pair.moving_shape
        if shape is not None:
            h, w = shape
            corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5], [-0.5, -0.5]])
            self.sink.log_later(E.outline_path(name),
                                lambda: rr.LineStrips2D([apply_homography(m, corners)], colors=[255, 220, 0], radii=1.0))


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two images are equal (a sparse look first: most that differ do so at once)."""
    return a.shape == b.shape and np.array_equal(a.ravel()[::997], b.ravel()[::997]) and np.array_equal(a, b)


def _points(points: np.ndarray, colors: np.ndarray | None) -> rr.Points2D:
    return rr.Points2D(points, colors=colors, radii=1.5)
