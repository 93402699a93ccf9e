"""The rerun blueprint of a pcreg recording: one per kind of recording, built from what the recording holds.

A blueprint is a list of :class:`Pane` (a view: its name, class, origin and the entities it shows) chosen
by :func:`panes` from the recording's kind (``register``, ``crosscheck``, ``sequence``, ``rotation``,
``demo``, ``dense``; see :data:`KINDS`) and its entity paths with the archetypes logged at each. A pane is
made only where there is data for it, so no view of a blueprint is empty. :func:`blueprint` lays the
panes out (images and clouds on top, series and text below); :func:`compare_blueprint` puts several
recordings merged under ``/{label}/...`` side by side, one column per recording, with their series
overlaid in one plot.

The recorder embeds :func:`blueprint` of what it logged when it closes; ``pcreg view`` rebuilds it from
the file (so recordings from any version, or cut short, get the layout of what they hold).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from . import entities as E

#: Kinds of recording, one per command that records.
KINDS = ("register", "crosscheck", "sequence", "rotation", "demo", "dense", "stream")

#: Archetypes drawn by a 2-D view, by a time-series view and by the two text views.
SPATIAL = frozenset({"Image", "EncodedImage", "SegmentationImage", "DepthImage", "Points2D", "LineStrips2D",
                     "Arrows2D", "Boxes2D"})
SPATIAL_3D = frozenset({"Points3D", "LineStrips3D", "Arrows3D", "Boxes3D", "Mesh3D"})
#: A plot needs a line: "Scalars+" marks an entity with Scalars at two times or more (a single value is
#: one dot, an empty-looking plot); :func:`pcreg.recording.readback.read_entities` and the recorder add it.
SERIES = frozenset({"Scalars+"})
TEXT_LOG = frozenset({"TextLog"})
DOCUMENT = frozenset({"TextDocument"})

#: Pane classes and the archetypes that give each data.
VIEW_DATA = {"2D": SPATIAL, "3D": SPATIAL_3D, "TimeSeries": SERIES, "TextLog": TEXT_LOG, "TextDocument": DOCUMENT}

#: Names of the views (``pcreg view --screenshot --view NAME`` screenshots one of them).
REGISTRATION_VIEW = "Registration"

Entities = Mapping[str, Iterable[str]]


#: What marks a recording of raw images made before the image slots whose pairs' references may be the
#: previous frame's moving image, stored once: a ``Clear`` at ``registration/reference`` (and no ``images/``).
PREVIOUS_FRAME_MARK = frozenset({"Clear"})


@dataclass(frozen=True)
class Pane:
    """One view: ``view`` is ``2D``, ``TimeSeries``, ``TextLog`` or ``TextDocument``; ``include`` holds
    entity paths, exact or ending in ``/**`` (the path and everything below it). ``offsets`` maps some of
    them, exact, to a number of frames: the view draws that entity as it was that many frames from the
    time cursor on the ``frame`` timeline (a visible time range of one frame), e.g. ``-1``, the previous
    frame."""

    name: str
    view: str
    origin: str
    include: tuple[str, ...]
    offsets: tuple[tuple[str, int], ...] = ()

    def shows(self, path: str) -> bool:
        """Whether ``path`` is one of the entities this pane shows."""
        path = "/" + path.strip("/")
        for pattern in self.include:
            if pattern.endswith("/**"):
                base = pattern[:-3]
                if path == base or path.startswith(base + "/"):
                    return True
            elif path == pattern:
                return True
        return False

    def data(self, entities: Entities) -> list[str]:
        """The entities of ``entities`` (path -> archetype names) that give this pane something to draw."""
        wanted = VIEW_DATA[self.view]
        return sorted(p for p, arch in entities.items() if self.shows(p) and wanted & set(arch))


def normalise(entities: Entities) -> dict[str, frozenset[str]]:
    """``{"/path": archetypes}`` without rerun's own ``/__properties`` entities."""
    out: dict[str, frozenset[str]] = {}
    for path, arch in entities.items():
        p = "/" + str(path).strip("/")
        if p.startswith("/__"):
            continue
        out[p] = out.get(p, frozenset()) | frozenset(arch)
    return out


def _with(entities: dict[str, frozenset[str]], prefix: str, kinds: frozenset[str]) -> list[str]:
    base = "/" + prefix.strip("/")
    return sorted(p for p, a in entities.items() if (p == base or p.startswith(base + "/")) and kinds & a)


def _children(entities: dict[str, frozenset[str]], prefix: str, kinds: frozenset[str]) -> list[str]:
    """Names of the direct children of ``prefix`` with data of ``kinds`` at or below them, in order."""
    base = "/" + prefix.strip("/") + "/"
    seen: dict[str, None] = {}
    for p in _with(entities, prefix, kinds):
        if p.startswith(base):
            seen.setdefault(p[len(base):].split("/", 1)[0], None)
    return list(seen)


def _title(name: str) -> str:
    return name.replace("_", " ")


def _spatial(entities, name: str, prefix: str) -> list[Pane]:
    base = "/" + prefix.strip("/")
    return [Pane(name, "2D", base, (base + "/**",))] if _with(entities, prefix, SPATIAL) else []


def _exact_spatial(entities, name: str, path: str) -> list[Pane]:
    p = "/" + path.strip("/")
    return [Pane(name, "2D", p, (p,))] if SPATIAL & entities.get(p, frozenset()) else []


def _labels(entities) -> list[Pane]:
    """Truth and one pane per prediction (``labels/predicted/{method}``), each on its own."""
    out: list[Pane] = []
    for kind, title in (("truth", "Truth"), ("predicted", "Predicted")):
        base = "/" + E.labels_path(kind)
        for p in _with(entities, base, SPATIAL):
            suffix = p[len(base):].strip("/")
            out.append(Pane(f"{title} {_title(suffix)}" if suffix else title, "2D", p, (p,)))
    return out


def _icp(entities, prefix: str = E.ICP) -> tuple[list[Pane], list[Pane]]:
    """Per implementation (a child of ``prefix`` with clouds of its iterations) a 2-D or 3-D pane; per
    series of the implementations (fitness, inlier RMSE, error, ...) one plot with all of them on it."""
    spatial = []
    impls = []
    target = f"/{E.CROSSCHECK_TARGET}"
    for view, kinds in (("2D", SPATIAL), ("3D", SPATIAL_3D)):
        shared = (target,) if prefix == E.CROSSCHECK and kinds & entities.get(target, frozenset()) else ()
        for b in _children(entities, prefix, kinds):
            if f"/{prefix}/{b}" == target:  # the cross-check's target cloud: drawn in every implementation's view
                continue
            origin = f"/{prefix}" if shared else f"/{prefix}/{b}"  # one space holding both clouds
            spatial.append(Pane(f"ICP {b}" if prefix == E.ICP else _title(b), view, origin,
                                (f"/{prefix}/{b}/**", *shared)))
            impls.append(b)
    leaves: dict[str, list[str]] = {}
    for p in _with(entities, prefix, SERIES):
        parts = p.strip("/").split("/")
        if len(parts) >= 3 and (prefix == E.ICP or parts[1] in impls):  # {prefix}/{implementation}/{series...}
            leaves.setdefault("/".join(parts[2:]), []).append(p)
    series = [Pane(("ICP " if prefix == E.ICP else "") + _title(leaf).replace("inlier rmse", "inlier RMSE"),
                   "TimeSeries", f"/{prefix}", tuple(paths)) for leaf, paths in leaves.items()]
    return spatial, series


def _texts(entities) -> list[Pane]:
    out = []
    if TEXT_LOG & entities.get("/" + E.LOG, frozenset()):
        out.append(Pane("Log", "TextLog", "/" + E.LOG, ("/" + E.LOG,)))
    if DOCUMENT & entities.get("/" + E.CROSSCHECK_REPORT, frozenset()):
        out.append(Pane("Crosscheck report", "TextDocument", "/" + E.CROSSCHECK_REPORT, ("/" + E.CROSSCHECK_REPORT,)))
    if DOCUMENT & entities.get("/" + E.CONFIG, frozenset()):
        out.append(Pane("Config", "TextDocument", "/" + E.CONFIG, ("/" + E.CONFIG,)))
    return out


def _registration(entities) -> list[Pane]:
    """The registration (the reference, and what is drawn over it), the moving image and the valid mask.
    Each frame's moving image in the image slots (``images/0``, ``images/1``): both views draw both slots,
    each the one at its depth (:mod:`pcreg.recording.pair_log`). Recordings of raw images made before the
    slots: the previous frame's moving image drawn one frame back where ``registration/reference`` was cleared."""
    base, moving_base = "/" + E.REGISTRATION, "/" + E.MOVING
    if any(SPATIAL & entities.get("/" + s, frozenset()) for s in E.IMAGE_SLOTS):
        shared = (f"/{E.IMAGES}/**",)
        return [Pane(REGISTRATION_VIEW, "2D", base, (base + "/**", *shared)),
                Pane("Moving", "2D", f"/{E.IMAGES}", (moving_base + "/**", *shared))] + _exact_spatial(
            entities, "Valid mask", E.VALID_MASK)
    main = _spatial(entities, REGISTRATION_VIEW, E.REGISTRATION)
    reference, moving = "/" + E.REFERENCE_IMAGE, "/" + E.MOVING_IMAGE
    if PREVIOUS_FRAME_MARK & entities.get(reference, frozenset()) and SPATIAL & entities.get(moving, frozenset()):
        main = [Pane(REGISTRATION_VIEW, "2D", base, (base + "/**", moving), ((moving, -1),))]
    return main + _spatial(entities, "Moving", E.MOVING) + _exact_spatial(entities, "Valid mask", E.VALID_MASK)


def _dense(entities) -> tuple[list[Pane], list[Pane]]:
    """A dense registration's images (displacement, refinement, confidence, warped prior, ...) one view
    each, the quiver (``dense/quiver``) drawn over the displacement; its series one plot each."""
    base = "/" + E.DENSE
    quiver, displacement = f"{base}/quiver", f"{base}/displacement"
    over = SPATIAL & entities.get(quiver, frozenset()) and SPATIAL & entities.get(displacement, frozenset())
    spatial = []
    for child in _children(entities, E.DENSE, SPATIAL):
        if over and child == "quiver":
            continue
        path = f"{base}/{child}"
        if over and path == displacement:
            spatial.append(Pane("Displacement", "2D", base, (displacement + "/**", quiver + "/**")))
        else:
            spatial.append(Pane(_title(child).capitalize(), "2D", path, (path + "/**",)))
    spatial += _exact_spatial(entities, "Dense", E.DENSE)
    series = [Pane(_title(p[len(base) + 1:]).capitalize(), "TimeSeries", base, (p,)) for p in _with(entities, E.DENSE, SERIES)
              if p != base]
    return spatial, series


def panes(kind: str, entities: Entities) -> list[Pane]:
    """The panes of a ``kind`` recording holding ``entities`` (entity path -> archetype names logged there).

    Every pane returned shows at least one entity with data of its class (:meth:`Pane.data`).
    """
    if kind not in KINDS:
        raise ValueError(f"unknown kind of recording {kind!r} (choose from {', '.join(KINDS)})")
    ent = normalise(entities)
    icp_spatial, icp_series = _icp(ent)
    series: list[Pane] = []
    if kind == "crosscheck":
        cc_spatial, cc_series = _icp(ent, E.CROSSCHECK)
        spatial = cc_spatial + _registration(ent) + icp_spatial
        series = cc_series + icp_series
    elif kind == "dense":
        dense, dense_series = _dense(ent)
        spatial = dense + _registration(ent) + _labels(ent) + icp_spatial
        series = dense_series + icp_series
    else:  # register, sequence, rotation, demo, stream; a dense registration's field beside the registration
        dense, dense_series = _dense(ent)
        spatial = _registration(ent) + dense + _labels(ent) + icp_spatial
        series = icp_series + dense_series
    if _with(ent, E.ERRORS, SERIES):
        series.insert(0, Pane("Errors", "TimeSeries", "/" + E.ERRORS, ("/" + E.ERRORS + "/**",)))
    out = spatial + series + _texts(ent)
    assert all(p.data(ent) for p in out)
    return out


def infer_kind(entities: Entities) -> str:
    """The kind of a recording whose kind was not stored, from its entity paths."""
    ent = normalise(entities)
    cc = _children(ent, E.CROSSCHECK, SPATIAL | SPATIAL_3D)
    if cc or "/" + E.CROSSCHECK_REPORT in ent:
        return "crosscheck"
    if _with(ent, E.DENSE, SPATIAL | SERIES):
        return "dense"
    if _with(ent, E.LABELS, SPATIAL) or _with(ent, E.ERRORS, SERIES):
        return "sequence"
    return "register"


def timeline(kind: str, entities: Entities | None = None) -> str:
    """The timeline a kind of recording opens on: a cloud cross-check's iterations (when ``entities`` hold
    an implementation's cloud under ``crosscheck/``), the ICP iterations for a registration or an image
    cross-check, frames otherwise."""
    if kind == "crosscheck" and entities is not None:
        if _children(normalise(entities), E.CROSSCHECK, SPATIAL | SPATIAL_3D):
            return E.CROSSCHECK_TIMELINE
    return E.ICP_TIMELINE if kind in ("crosscheck", "register") else E.FRAME_TIMELINE


def _view(pane: Pane):
    import rerun.blueprint as rrb

    cls = {"2D": rrb.Spatial2DView, "3D": rrb.Spatial3DView, "TimeSeries": rrb.TimeSeriesView, "TextLog": rrb.TextLogView,
           "TextDocument": rrb.TextDocumentView}[pane.view]
    kw: dict[str, Any] = {}
    if pane.offsets:
        kw["overrides"] = {path: rrb.VisibleTimeRanges([_frame_offset(n)]) for path, n in pane.offsets}
    return cls(origin=pane.origin, contents=[f"+ {p}" for p in pane.include], name=pane.name, **kw)


def _frame_offset(n: int):
    """The visible time range of the one frame ``n`` frames from the time cursor."""
    import rerun.blueprint as rrb

    at = rrb.TimeRangeBoundary.cursor_relative(seq=int(n))
    return rrb.VisibleTimeRange(E.FRAME_TIMELINE, start=at, end=at)


def _layout(main: list, side: list, labels: list, series: list, texts: list):
    """``main`` views side by side with ``side`` in a grid beside them; ``labels`` in a row below; then the
    series and the text (each group in tabs)."""
    import rerun.blueprint as rrb

    def group(items, container=rrb.Tabs):
        return items[0] if len(items) == 1 else container(*items)

    rows, shares = [], []
    top = list(main)
    if side:
        top.append(group(side, rrb.Grid))
    if top:
        rows.append(group(top, rrb.Horizontal))
        shares.append(3)
    if labels:
        rows.append(group(labels, rrb.Horizontal))
        shares.append(2)
    bottom = [group(x) for x in (series, texts) if x]
    if bottom:
        rows.append(group(bottom, rrb.Horizontal))
        shares.append(2)
    if not rows:
        return rrb.Vertical()
    return rows[0] if len(rows) == 1 else rrb.Vertical(*rows, row_shares=shares)


def _arrange(ps: list[Pane], kind: str, view=None):
    """Split panes into the groups of :func:`_layout`: the main views (the registration, the dense
    field, or every implementation of a cross-check), the others, the label maps, series and text."""
    view = view or _view
    spatial = [p for p in ps if p.view in ("2D", "3D")]
    labels = [p for p in spatial if p.origin.startswith("/" + E.LABELS)]
    rest = [p for p in spatial if p not in labels]
    if kind == "crosscheck":
        main = [p for p in rest if p.origin.startswith("/" + E.CROSSCHECK)] or [p for p in rest if p.origin.startswith("/" + E.ICP)]
    elif kind == "dense":
        main = [p for p in rest if p.origin.startswith("/" + E.DENSE)][:2] or rest[:1]
    else:
        main = rest[:1]
    side = [p for p in rest if p not in main]
    series = [p for p in ps if p.view == "TimeSeries"]
    texts = [p for p in ps if p.view in ("TextLog", "TextDocument")]
    return tuple([view(p) for p in g] for g in (main, side, labels, series, texts))


def blueprint(kind: str, entities: Entities):
    """The ``rerun.blueprint.Blueprint`` of a ``kind`` recording holding ``entities`` (see :func:`panes`)."""
    import rerun.blueprint as rrb

    root = _layout(*_arrange(panes(kind, entities), kind))
    return rrb.Blueprint(root, rrb.TimePanel(timeline=timeline(kind, entities), state="collapsed"),
                         collapse_panels=True)


def prefixed(pane: Pane, label: str) -> Pane:
    """``pane`` moved under ``/{label}`` (a recording merged into a comparison)."""
    root = "/" + label.strip("/")
    return Pane(f"{label}: {pane.name}", pane.view, root + pane.origin,
                tuple(root + p for p in pane.include), tuple((root + p, n) for p, n in pane.offsets))


def compare_panes(recordings: list[tuple[str, str, Entities]]) -> list[list[Pane]]:
    """Panes of recordings merged under ``/{label}``: ``[(label, kind, entities)]`` -> groups of panes.

    A 2-D or text pane that several recordings have is one group with a pane per recording (shown side
    by side); a series pane is one pane with every recording's series on it.
    """
    groups: dict[tuple[str, str], list[Pane]] = {}
    for label, kind, ent in recordings:
        for p in panes(kind, ent):
            # one ICP backend per recording (a run per backend): their ICP views side by side
            key = "ICP" if p.view == "2D" and p.origin.startswith(f"/{E.ICP}/") else p.name
            groups.setdefault((p.view, key), []).append(prefixed(p, label))
    out = []
    for (view, name), ps in groups.items():
        if view == "TimeSeries":
            out.append([Pane(name, view, "/", tuple(x for p in ps for x in p.include))])
        else:
            out.append(ps)
    return out


def _group_name(group: list[Pane]) -> str:
    names = {p.name.split(": ", 1)[-1] for p in group}
    return names.pop() if len(names) == 1 else "ICP"


def compare_blueprint(recordings: list[tuple[str, str, Entities]]):
    """The blueprint of several recordings merged under ``/{label}`` (see :func:`compare_panes`): a tab
    per 2-D pane with the recordings side by side, the series overlaid, the logs in tabs."""
    import rerun.blueprint as rrb

    groups = compare_panes(recordings)
    spatial = [rrb.Horizontal(*[_view(p) for p in g], name=_group_name(g))
               if len(g) > 1 else _view(g[0]) for g in groups if g[0].view in ("2D", "3D")]
    series = [_view(g[0]) for g in groups if g[0].view == "TimeSeries"]
    texts = [_view(p) for g in groups if g[0].view in ("TextLog", "TextDocument") for p in g]
    root = _layout([rrb.Tabs(*spatial)] if len(spatial) > 1 else spatial, [], [], series, texts)
    tls = {timeline(k, e) for _, k, e in recordings}
    tl = tls.pop() if len(tls) == 1 else timeline("sequence")
    return rrb.Blueprint(root, rrb.TimePanel(timeline=tl, state="collapsed"), collapse_panels=True)
