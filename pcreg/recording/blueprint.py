"""The rerun blueprint embedded in every pcreg recording.

Layout: the registration view (reference image, warped moving image at half opacity, both clouds and
the moving image's outline mapped by ``T_ref_mov``) beside the segmentation views (truth, predicted);
below them the error and ICP time series and the text log. ``layout="crosscheck"`` puts the two
ICP backends' clouds side by side instead of the segmentation views.
"""

from __future__ import annotations

import rerun.blueprint as rrb

from . import entities as E

LAYOUTS = ("default", "crosscheck")

#: Names of the views (``pcreg view --screenshot --view NAME`` screenshots one of them).
REGISTRATION_VIEW = "Registration"


def _icp_cloud_view(backend: str) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(
        origin=f"/{E.ICP}/{backend}",
        contents=[f"+ /{E.ICP}/{backend}/**"],
        name=f"ICP {backend}",
    )


def _series_view(what: str, name: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        origin=f"/{E.ICP}",
        contents=[f"+ /{E.icp_path(b, what)}" for b in E.ICP_BACKENDS],
        name=name,
    )


def blueprint(*, layout: str = "default") -> rrb.Blueprint:
    """The blueprint for a recording; ``layout`` is ``"default"`` or ``"crosscheck"``."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown blueprint layout {layout!r} (choose from {', '.join(LAYOUTS)})")
    registration = rrb.Spatial2DView(origin=f"/{E.REGISTRATION}", name=REGISTRATION_VIEW)
    truth = rrb.Spatial2DView(origin=f"/{E.TRUTH}", name="Truth")
    predicted = rrb.Spatial2DView(origin=f"/{E.PREDICTED}", name="Predicted")
    moving = rrb.Spatial2DView(origin=f"/{E.MOVING}", name="Moving")
    mask = rrb.Spatial2DView(origin=f"/{E.VALID_MASK}", name="Valid mask")
    icp_clouds = [_icp_cloud_view(b) for b in E.ICP_BACKENDS]
    if layout == "crosscheck":
        top = rrb.Horizontal(registration, *icp_clouds, column_shares=[2, 1, 1])
    else:
        top = rrb.Horizontal(
            registration,
            rrb.Vertical(truth, predicted, name="Segmentation"),
            rrb.Tabs(moving, mask, *icp_clouds, name="More"),
            column_shares=[2, 1, 1],
        )
    series = rrb.Tabs(
        rrb.TimeSeriesView(origin=f"/{E.ERRORS}", name="Errors"),
        _series_view("fitness", "ICP fitness"),
        _series_view("inlier_rmse", "ICP inlier RMSE"),
        active_tab=1 if layout == "crosscheck" else 0,
    )
    text = rrb.Tabs(
        rrb.TextLogView(origin=f"/{E.LOG}", name="Log"),
        rrb.TextDocumentView(origin=f"/{E.CROSSCHECK_REPORT}", name="Crosscheck"),
        rrb.TextDocumentView(origin=f"/{E.CONFIG}", name="Config"),
        active_tab=1 if layout == "crosscheck" else 0,
    )
    return rrb.Blueprint(
        rrb.Vertical(top, rrb.Horizontal(series, text), row_shares=[3, 2]),
        rrb.TimePanel(timeline=E.FRAME_TIMELINE, state="collapsed"),
        collapse_panels=True,
    )
