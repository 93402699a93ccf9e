"""The optical-flow baseline: OpenCV's DIS flow as a dense field in pcreg's convention.

Kroeger et al. (2016, "Fast Optical Flow using Dense Inverse Search", ECCV), as OpenCV implements it
(``cv2.DISOpticalFlow``). It is what a user would otherwise pick to warp labels between video frames;
the evaluations run it beside pcreg's own dense registration (:mod:`pcreg.registration.dense`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from dataclasses import field as _field

import cv2
import numpy as np

from ..errors import InputError
from .clouds import as_rgb_uint8, magnitude

__all__ = ["PRESETS", "UNREFINED", "DIS_MIN_SIDE", "FlowResult", "dis_field", "dis_flow", "pixel_grid", "flow_field"]

PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
           "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, "medium-norefine": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
#: Presets run without OpenCV's variational refinement (0 iterations; its patch search and densification
#: as the preset has them): ``medium-norefine`` takes about half of ``medium``'s time at 640x480, and
#: carried CamVid's eleven classes better as the many-class stream's second motion (docs/results.md,
#: "Many classes").
UNREFINED = frozenset({"medium-norefine"})
#: The shortest side DIS takes, px. Below it OpenCV 5.0's DIS raises or crashes the process (a
#: segmentation fault measured at 8-12 x 48-64 px): its coarsest pyramid level, set by the shorter side
#: and the patch (8 px; 12 for medium), falls below its finest (2; 1 for medium), 32 px for every preset.
DIS_MIN_SIDE = 32


def dis_flow(moving_grey: np.ndarray, reference_grey: np.ndarray, preset: str) -> np.ndarray:
    """(H, W, 2) float32 DIS flow from ``moving_grey`` to ``reference_grey`` (uint8, one size), ``preset``
    one of :data:`PRESETS`; an :class:`~pcreg.errors.InputError` for images with a side under
    :data:`DIS_MIN_SIDE`, which OpenCV's DIS does not take."""
    h, w = moving_grey.shape[:2]
    if min(h, w) < DIS_MIN_SIDE:
        raise InputError(f"{w}x{h} px is too small for DIS optical flow (at least {DIS_MIN_SIDE} px a side)")
    dis = cv2.DISOpticalFlow_create(PRESETS[preset])
    if preset in UNREFINED:
        dis.setVariationalRefinementIterations(0)
    return dis.calc(moving_grey, reference_grey, None)


def pixel_grid(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(xs, ys)``: the x and y of every pixel of an image of ``shape`` ((H, W, ...)), (H, W) float32
    each, read-only (a stream makes it once for its key frame)."""
    h, w = shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    for a in (xs, ys):
        a.setflags(write=False)
    return xs, ys


def flow_field(flow: np.ndarray, grid: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(H, W, 2) float32 field of a flow: each moving pixel's reference coordinates, its own
    (:func:`pixel_grid`, or ``grid`` made beforehand) plus the flow there."""
    xs, ys = pixel_grid(flow.shape) if grid is None else grid
    out = np.empty(flow.shape[:2] + (2,), np.float32)  # each sum written in place (not stacked, then copied)
    np.add(xs, flow[:, :, 0], out=out[:, :, 0], casting="unsafe")
    np.add(ys, flow[:, :, 1], out=out[:, :, 1], casting="unsafe")
    return out


def dis_field(reference_image: np.ndarray, moving_image: np.ndarray, *, preset: str = "medium"
              ) -> tuple[np.ndarray, float]:
    """``(field (H, W, 2) float32, seconds)``: reference coordinates of every moving pixel by DIS flow
    from the moving to the reference image (grey levels), ``preset`` one of :data:`PRESETS`."""
    if preset not in PRESETS:
        raise InputError(f"unknown DIS preset {preset!r}; choose one of {', '.join(PRESETS)}")
    ref = as_rgb_uint8(reference_image, name="reference image")
    mov = as_rgb_uint8(moving_image, name="moving image")
    if ref.shape != mov.shape:
        raise InputError(f"optical flow needs images of one size, got {ref.shape[:2]} and {mov.shape[:2]}")
    g_ref = cv2.cvtColor(ref, cv2.COLOR_RGB2GRAY)
    g_mov = cv2.cvtColor(mov, cv2.COLOR_RGB2GRAY)
    t0 = time.perf_counter()
    flow = dis_flow(g_mov, g_ref, preset)
    seconds = time.perf_counter() - t0
    return flow_field(flow), seconds


@dataclass(frozen=True, eq=False, repr=False)
class FlowResult:
    """A DIS flow as a registration result (a stream's motion with ``model="flow"``): ``field`` (H, W, 2)
    float32, reference coordinates of every moving pixel; ``preset``; ``seconds`` the flow took. A flow
    has no global transform (``matrix`` is the identity) and no confidence of its own (None)."""

    field: np.ndarray
    preset: str
    seconds: float
    matrix: np.ndarray = _field(default_factory=lambda: np.eye(3), init=False)
    confidence: None = _field(default=None, init=False)

    def __post_init__(self) -> None:
        self.field.setflags(write=False)  # the motion made of it keeps it as it is, uncopied

    def __repr__(self) -> str:
        h, w = self.field.shape[:2]
        return f"FlowResult(field={w}x{h}, preset={self.preset!r})"

    def to_dict(self) -> dict:
        """JSON-ready summary: the model, the preset, the seconds and the displacement's median (every
        second pixel along each axis) and largest length, px."""
        xs, ys = pixel_grid(self.field.shape)
        disp = magnitude(self.field[:, :, 0] - xs, self.field[:, :, 1] - ys)  # the same to the bit in any buffer
        return {"model": "flow", "preset": self.preset, "seconds": float(self.seconds),
                "median_displacement": float(np.median(disp[::2, ::2])), "max_displacement": float(disp.max())}
