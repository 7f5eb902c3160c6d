"""The dashboard's layout (rerun blueprint): one tab per coaching session, one per estimate, one
for the other spaces, one for the cluster and one explaining the views.

Every tab is readable on the timeline the recording opens on (``playback`` when it holds a
session): a session's data is on ``playback``; an estimate's and the cluster's are on their own
timelines *and* at ``playback`` 0, so the latest of them shows there too. Per-trial and per-set
values are bar charts whose axis is the trial or the conversation set, not a timeline's frames.
"""

from __future__ import annotations

import rerun as rr
import rerun.blueprint as rrb

from shared.observe.labels import region

#: the smallest size in pixels (width, height) of a space's panel at the viewer's 1600 x 1000:
#: labels are placed so that none overlaps another there (and so in any larger panel)
SESSION_SPACE_PX = (600.0, 290.0)
ESTIMATE_SPACE_PX = (760.0, 400.0)
OTHER_SPACE_PX = (520.0, 300.0)

README = """# mirrorcoach dashboard

**Tabs.** One per coaching session (named by its motion, its learner and its id), one per
estimate (the other it talks to), `spaces` (every other proto-symbol space), `cluster` (failed
requests, live capture takes, every transcript, request latencies) and this one.

**A session's tab.** Left: three people side by side, blue the target, orange the learner's
attempt, red the emphatic motion shown next (yellow joints are the left side, cyan the right),
the same three overlaid, and joint angles. Right: the trial playing and the coach's words; the
session's proto-symbol space on its first two axes (its points grey, the attempts' path in
orange, the emphatic points in red, the target in blue, the playing trial labelled); `d_p` (distance to the target)
and alpha per trial, the playing trial's bar lighter; one line per trial with `R` (`d_p` over the
first trial's).

**Timelines.** `playback` (the default) plays every trial in turn: the target, the attempt and
the emphatic motion shown next, resampled to one length so they move in step. `trial` shows
each trial's last frame, `set` the estimator's conversation sets, `log_time` the requests.
Estimates and the cluster's logs show their latest state on every timeline.

**An estimate's tab.** The felt symbol per conversation set: the other's answer (red) and the
self's estimate (blue); the torque scale other / self; the other's space; the transcript, each
line with its set.
"""


def short(name: str, n: int = 24) -> str:
    return name if len(name) <= n else name[: n - 3] + "..."


def text_columns(timeline: str | None = None):
    """A text log showing its words (and ``timeline``), not entity paths and every timeline."""
    enc = rrb.encodings
    return rrb.archetypes.TextLogColumns(
        timeline_columns=[enc.TimelineColumn(t, visible=t == timeline) for t in ("playback", "trial", "set", "log_time")],
        text_log_columns=[enc.TextLogColumn("EntityPath", visible=False), enc.TextLogColumn("LogLevel", visible=False),
                          enc.TextLogColumn("Body")])


def front(x: float, distance: float, up: int) -> rrb.EyeControls3D:
    """A camera in front of people standing on the floor at ``x`` (up axis 1 = Y or 2 = Z) who
    face it: the dashboard turns every motion so that its first frame faces +Z (Y up) or -Y (Z up)."""
    position, target, eye_up = [x, 1.1, distance], [x, 0.8, 0.0], [0.0, 1.0, 0.0]
    if up == 2:
        position, target, eye_up = [x, -distance, 1.1], [x, 0.0, 0.8], [0.0, 0.0, 1.0]
    return rrb.EyeControls3D(kind=rrb.components.Eye3DKind.Orbital, position=position, look_target=target,
                             eye_up=eye_up)


def space_view(origin: str, name: str, panel_px: tuple[float, float]) -> rrb.Spatial2DView:
    """A space in 2-D showing exactly the region its points are mapped to, ``[-a, a] x [-1, 1]``
    with ``a`` the panel's aspect (:meth:`shared.observe.dashboard.Dashboard.space_2d`): the
    labels were placed for that region on a panel of ``panel_px``."""
    lo, hi = region(panel_px)
    return rrb.Spatial2DView(origin=origin, name=name,
                             visual_bounds=rrb.VisualBounds2D(x_range=[lo[0], hi[0]], y_range=[lo[1], hi[1]]))


def bars(origin: str, name: str) -> rrb.BarChartView:
    return rrb.BarChartView(origin=origin, name=name, plot_legend=rrb.PlotLegend(visible=False))


def session_tab(s: str, title: str, curves: list[str], up: int, side_by_side_x: float) -> rrb.Container:
    """A coaching session: the people (left) and the trial, the space, the values and the words (right)."""
    curve_views = [rrb.TimeSeriesView(origin=f"sessions/{s}/curves/{c}", name=f"{c} (deg)",
                                      plot_legend=rrb.PlotLegend(visible=False)) for c in curves]
    return rrb.Horizontal(
        rrb.Vertical(
            rrb.Spatial3DView(origin=f"sessions/{s}/body", name="target (blue) | attempt (orange) | shown next (red)",
                              eye_controls=front(side_by_side_x, 4.0, up)),
            rrb.Horizontal(rrb.Spatial3DView(origin=f"sessions/{s}/overlay", name="overlaid",
                                             eye_controls=front(0.0, 2.4, up)), *curve_views),
            row_shares=[3, 2]),
        rrb.Vertical(
            rrb.TextDocumentView(origin=f"sessions/{s}/now", name="the trial playing"),
            space_view(f"sessions/{s}/space", f"space coach-{short(s)} (first two axes)", SESSION_SPACE_PX),
            rrb.Horizontal(bars(f"sessions/{s}/d_p", "d_p (distance to the target) by trial"),
                           bars(f"sessions/{s}/alpha", "alpha by trial")),
            rrb.TextLogView(origin=f"sessions/{s}/coaching", name="the coach's words by trial", columns=text_columns()),
            row_shares=[1, 2.6, 2.6, 1.4]),
        column_shares=[5, 4], name=title)


def estimate_tab(e: str, title: str) -> rrb.Container:
    return rrb.Horizontal(
        rrb.Vertical(bars(f"estimates/{e}/symbols", "felt symbol by set: other (red), self's estimate (blue)"),
                     bars(f"estimates/{e}/scale", "torque scale other / self by set")),
        rrb.Vertical(space_view(f"estimates/{e}/space", f"the other's space est-{short(e)}", ESTIMATE_SPACE_PX),
                     rrb.TextLogView(origin=f"estimates/{e}/transcript", name="transcript (by set)",
                                     columns=text_columns("set"))),
        name=title)


def cluster_tab() -> rrb.Container:
    return rrb.Horizontal(
        rrb.Vertical(rrb.TextLogView(origin="cluster/warnings", name="failed requests", columns=text_columns()),
                     rrb.TextLogView(origin="cluster/captures", name="capture takes", columns=text_columns()),
                     rrb.TextLogView(origin="estimates", name="every transcript", columns=text_columns("set")),
                     row_shares=[1, 1, 2]),
        rrb.TextDocumentView(origin="cluster/latency", name="request latency"),
        name="cluster")


def blueprint(sessions: list[rrb.Container], estimates: list[rrb.Container], spaces: list[str]) -> rrb.Blueprint:
    tabs: list = sessions + estimates
    if spaces:
        tabs.append(rrb.Grid(*[space_view(f"spaces/{sp}", f"space {short(sp)} (first two axes)", OTHER_SPACE_PX)
                               for sp in spaces], name="spaces"))
    tabs += [cluster_tab(), rrb.TextDocumentView(origin="readme", name="about these views")]
    return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=0),
                         rrb.TimePanel(state="collapsed", timeline="playback" if sessions else "log_time"),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))


def views(layout) -> int:
    """The number of views in a layout or a container (what a layout's size in the file grows with)."""
    if isinstance(layout, rrb.Blueprint):
        layout = layout.root_container
    if not isinstance(layout, rrb.Container):
        return 1
    return sum(views(x) for x in layout.contents)


def readme() -> rr.TextDocument:
    return rr.TextDocument(README, media_type=rr.MediaType.MARKDOWN)
