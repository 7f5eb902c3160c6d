"""What the cluster does, logged to rerun (DESIGN.md "Observability"). Only the observer
process imports this module: services publish events and never import rerun.

The recording opens with its own blueprint (re-sent whenever a session, space or estimate
appears): one tab per coaching session, one per estimate, one for the other spaces and one for
the cluster, in the style of rerun's robotics examples.

Entities and timelines (each kind of data on the timelines where it belongs):

* ``readme``: a short markdown text explaining the views (static);
* ``sessions/<s>/body/{target,attempt,emphatic}``: upright people (the skeleton's own up axis
  as the view coordinates, a floor, a front camera), side by side 1.5 m apart; joints are
  keypoints of an annotation context (named on hover; left side, right side, head and feet
  coloured apart, bones in the motion's colour); ``sessions/<s>/overlay/...`` the same three
  overlaid. Timeline ``playback``: trial ``n`` occupies ``n * K ... n * K + K - 1`` where ``K``
  is the target's frame count at 30 fps, and the target, the attempt and the emphatic motion
  shown next are each resampled to those ``K`` frames, so any trial plays in step; also
  timeline ``trial`` (its last frame at ``n``);
* ``sessions/<s>/curves/<channel>/<role>``: joint angles on the same timelines;
* ``sessions/<s>/{d_p,R,alpha}`` per trial with markers and ``sessions/<s>/coaching``: one text
  line per trial (adverb, alpha shown and chosen, why it was lowered, d_p, R, d_cop), on
  ``trial`` and at the start of the trial's ``playback`` block;
* ``sessions/<s>/space``: the session's space (``coach-<s>``): its proto-symbols, the attempts
  ``x_p`` as a path, the emphatic points ``x_s``, the target ``x_t``, and the playing trial's
  two labelled (``now``);
* ``spaces/<space>``: any other space, coloured by class, one label per class;
* ``estimates/<e>/{k_other,k_self,symbol_error,scale}`` per conversation set (timeline ``set``),
  ``estimates/<e>/transcript`` with each line on the set it belongs to, ``estimates/<e>/space``;
* ``cluster/warnings`` and ``cluster/latency/<service>/<verb>`` on the log time only;
* ``cluster/captures``: one line per live take's start and end (the capture service: its
  source, frames, why it ended or failed), on the log time.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from shared.motion.clip import Clip

CURVE_CHANNELS = ("rfemur.rx", "rtibia.rx", "lowerback.rx", "rhumerus.rx", "shoulder_pitch", "elbow")
MAX_CURVES = 3
ROLES = ("target", "attempt", "emphatic")
SIDE_BY_SIDE = {"target": 0.0, "attempt": 1.5, "emphatic": 3.0}
COLOURS = {"target": (80, 160, 255), "attempt": (255, 170, 60), "emphatic": (230, 60, 90)}
CLASS_OF = {"target": 1, "attempt": 2, "emphatic": 3}
JOINT_COLOURS = {"left": (255, 235, 90), "right": (90, 235, 255), "head": (60, 230, 60), "foot": (255, 60, 255),
                 "centre": (235, 235, 235)}
PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
           (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207), (255, 200, 80), (120, 200, 120)]
PLAYBACK_FPS = 30.0
#: sessions (and estimates, and other spaces) the dashboard keeps: its memory and its tabs stay
#: bounded over a long run; a new recording (rotation) starts with the newest CARRY_OVER sessions
MAX_KEPT = 16
CARRY_OVER = 4
#: the layout (blueprint) is sent at most this often: a blueprint costs about 55 KB per session tab
#: in the file (rerun writes each view's properties as their own chunks), so sending it on every new
#: session made the layout most of a long run's recording (0.9 MB per session at 16 tabs)
LAYOUT_EVERY_S = 2.0

README = """# mirrorcoach dashboard

**Timelines.** `playback` (the default) plays every coaching trial in turn: the target, the
learner's attempt and the emphatic motion shown next, resampled to one length so they move in
step. `trial` shows the last frame of each trial; `set` is the estimator's conversation sets;
`log_time` the cluster's requests.

**A session's tab.** Left: the three people side by side (blue target, orange attempt, red
emphatic motion; yellow joints are the left side, cyan the right), the same overlaid, and joint
angles. Right: the session's proto-symbol space (the attempts' path and the emphatic points,
the playing trial's labelled), `d_p` (distance to the target), `R` (d_p over the first trial's) and
alpha, and the coach's words per trial with the reason alpha was lowered.

**Estimates** (switch the timeline to `set`): the other's felt symbol against the self's
estimate, the torque scale, the transcript of each conversation set. **Spaces**: every other
space, coloured by class. **Cluster**: failed requests, live capture takes (started, ended, why)
and latencies.
"""


def _short(name: str) -> str:
    return name if len(name) <= 24 else name[:21] + "..."


def _side(name: str, names: set[str]) -> str:
    """``left``, ``right``, ``head``, ``foot`` or ``centre``; ``names``: every joint, lower case."""
    n = name.lower()
    if "head" in n:
        return "head"
    if "foot" in n or "toe" in n:
        return "foot"
    for a, b, side in (("left", "right", "left"), ("right", "left", "right"), ("l", "r", "left"), ("r", "l", "right")):
        if n.startswith(a) and (b + n[len(a):]) in names:
            return side
    return "centre"


def _text_columns(timeline: str | None = None):
    """A text log showing its words (and ``timeline``), not entity paths and every timeline."""
    enc = rrb.encodings
    return rrb.archetypes.TextLogColumns(
        timeline_columns=[enc.TimelineColumn(t, visible=t == timeline) for t in ("playback", "trial", "set", "log_time")],
        text_log_columns=[enc.TextLogColumn("EntityPath", visible=False), enc.TextLogColumn("LogLevel", visible=False),
                          enc.TextLogColumn("Body")])


def _resample(clip: Clip, n: int) -> np.ndarray:
    """The clip's frames resampled to ``n`` (time-normalised: start to start, end to end)."""
    x = np.asarray(clip.data, float)
    if len(x) == n:
        return x
    src = np.linspace(0.0, 1.0, len(x))
    dst = np.linspace(0.0, 1.0, n)
    return np.stack([np.interp(dst, src, x[:, j]) for j in range(x.shape[1])], axis=1)


def _front(x: float, distance: float, up: int) -> rrb.EyeControls3D:
    """A camera in front of people standing on the floor at ``x`` (up axis 1 = Y or 2 = Z)."""
    position, target, eye_up = [x, 1.2, distance], [x, 0.85, 0.0], [0.0, 1.0, 0.0]
    if up == 2:
        position, target, eye_up = [x, -distance, 1.2], [x, 0.0, 0.85], [0.0, 0.0, 1.0]
    return rrb.EyeControls3D(kind=rrb.components.Eye3DKind.Orbital, position=position, look_target=target,
                             eye_up=eye_up)


def _series_style(rec, entity: str, name: str, colour, markers: bool = True) -> None:
    """A series' name and colour (and markers, for values per trial or per set), once."""
    parts: list = [rr.SeriesLines(colors=[colour], names=[name])]
    if markers:
        parts.append(rr.SeriesPoints(colors=[colour], markers=["circle"], marker_sizes=[4.0], names=[name]))
    rec.log(entity, *parts, static=True)


def _views(layout) -> int:
    """The number of views in a layout or a container (what a layout's size in the file grows with)."""
    if isinstance(layout, rrb.Blueprint):
        layout = layout.root_container
    return sum(_views(x) if isinstance(x, rrb.Container) else 1 for x in layout.contents)


def _xyz(p) -> list[float]:
    p = list(p)[:3]
    return [float(v) for v in p] + [0.0] * (3 - len(p))


class Dashboard:
    """A rerun recording fed with the cluster's events."""

    def __init__(self, path=None, viewer_url: str | None = None, application_id: str = "mirrorcoach"):
        self.rec = rr.RecordingStream(application_id)
        sinks: list = []
        if path is not None:
            sinks.append(rr.FileSink(str(path)))
        if viewer_url:
            sinks.append(rr.GrpcSink(viewer_url))
        if sinks:
            self.rec.set_sinks(*sinks)
        self.targets: dict[str, Clip] = {}
        self.frames: dict[str, int] = {}  # K per session: the target's frames at 30 fps
        self.poses: dict[str, tuple | None] = {}  # the target's, resampled and by forward kinematics
        self.paths: dict[str, list] = {}
        self.emphatic: dict[str, list] = {}
        self.spaces: dict[str, None] = {}  # in order of arrival
        self.estimates: dict[str, int] = {}  # conversation sets completed per estimate
        self.trials: dict[str, int] = {}  # trials completed per session
        self.pending: dict[str, dict] = {}  # a session's space event that came before the session
        self.curves: dict[str, list[str]] = {}
        self.path = None if path is None else Path(path)
        self.view_bytes = 0.0  # measured when a layout is written to the file
        self._layout_due, self._layout_sent = False, float("-inf")
        self.rec.log("readme", rr.TextDocument(README, media_type=rr.MediaType.MARKDOWN), static=True)
        self._layout()

    def close(self) -> None:
        self.send_layout(force=True)
        self.rec.flush()
        self.rec.disconnect()

    # ------------------------------------------------------------------ layout
    def _session_tab(self, s: str) -> rrb.Container:
        up = self.targets[s].skeleton.up_axis if self.targets[s].skeleton else 1
        curves = [rrb.TimeSeriesView(origin=f"sessions/{s}/curves/{c}", name=f"{c} (deg)",
                                     plot_legend=rrb.PlotLegend(corner=rrb.components.Corner2D.LeftTop))
                  for c in self.curves.get(s, [])]
        series = [rrb.TimeSeriesView(origin=f"sessions/{s}/{m}", name=label, plot_legend=rrb.PlotLegend(visible=False))
                  for m, label in (("d_p", "d_p"), ("R", "R"), ("alpha", "alpha"))]
        return rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin=f"sessions/{s}/body", name="target | attempt | emphatic",
                                  eye_controls=_front(SIDE_BY_SIDE["attempt"], 4.3, up)),
                rrb.Horizontal(rrb.Spatial3DView(origin=f"sessions/{s}/overlay", name="overlaid",
                                                 eye_controls=_front(0.0, 3.2, up)), *curves),
                row_shares=[3, 2]),
            rrb.Vertical(
                rrb.Spatial3DView(origin=f"sessions/{s}/space", name=f"space coach-{_short(s)}"),
                rrb.Horizontal(*series),
                rrb.TextLogView(origin=f"sessions/{s}/coaching", name="coaching", columns=_text_columns()),
                rrb.TextDocumentView(origin="readme", name="about these views"),
                row_shares=[2.6, 2, 1.7, 1.2]),
            column_shares=[3, 2], name=f"session {_short(s)}")

    def _estimate_tab(self, e: str) -> rrb.Container:
        return rrb.Horizontal(
            rrb.Vertical(rrb.TimeSeriesView(origin=f"estimates/{e}/symbols", name="felt symbol: other vs self's estimate",
                                            plot_legend=rrb.PlotLegend(corner=rrb.components.Corner2D.LeftTop)),
                         rrb.TimeSeriesView(origin=f"estimates/{e}/scale", name="torque scale other / self",
                                            plot_legend=rrb.PlotLegend(visible=False))),
            rrb.Vertical(rrb.Spatial3DView(origin=f"estimates/{e}/space", name=f"the other's space est-{_short(e)}"),
                         rrb.TextLogView(origin=f"estimates/{e}/transcript", name="transcript (by set)",
                                         columns=_text_columns("set"))),
            name=f"estimate {_short(e)}")

    def blueprint(self) -> rrb.Blueprint:
        tabs = [self._session_tab(s) for s in self.targets]
        tabs += [self._estimate_tab(e) for e in self.estimates]
        others = sorted(self.spaces)
        if others:
            tabs.append(rrb.Grid(*[rrb.Spatial3DView(origin=f"spaces/{sp}", name=f"space {_short(sp)}") for sp in others],
                                 name="spaces"))
        tabs.append(rrb.Horizontal(
            rrb.TextDocumentView(origin="readme", name="about these views"),
            rrb.Vertical(rrb.TextLogView(origin="cluster/warnings", name="failed requests", columns=_text_columns()),
                         rrb.TextLogView(origin="cluster/captures", name="capture takes", columns=_text_columns()),
                         rrb.TextLogView(origin="estimates", name="every transcript", columns=_text_columns("set")),
                         rrb.TimeSeriesView(origin="cluster/latency", name="request latency (ms)",
                                            plot_legend=rrb.PlotLegend(corner=rrb.components.Corner2D.LeftTop))),
            name="cluster"))
        return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=0),
                             rrb.TimePanel(state="expanded", timeline="playback" if self.targets else "log_time"),
                             rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))

    def _layout(self) -> None:
        """The layout changed (a tab came or went): :meth:`send_layout` sends it (the observer, at
        most every ``LAYOUT_EVERY_S``; :meth:`close` in any case)."""
        self._layout_due = True

    def layout_ready(self) -> bool:
        """The layout changed and ``LAYOUT_EVERY_S`` has passed since the last one was sent."""
        return self._layout_due and time.monotonic() - self._layout_sent >= LAYOUT_EVERY_S

    def layout_bytes(self) -> float:
        """What sending the layout now would add to the file (0 until one has been measured)."""
        return _views(self.blueprint()) * self.view_bytes

    def send_layout(self, force: bool = False) -> bool:
        """Send the layout if it changed and ``LAYOUT_EVERY_S`` has passed (or ``force``)."""
        if not (self.layout_ready() or (force and self._layout_due)):
            return False
        blueprint = self.blueprint()
        before = self.file_bytes() if self.path is not None else 0
        self.rec.send_blueprint(blueprint)
        if self.path is not None:  # what a view costs in the file, for the rotation's estimates
            self.view_bytes = max(self.view_bytes, (self.file_bytes() - before) / max(1, _views(blueprint)))
        self._layout_due, self._layout_sent = False, time.monotonic()
        return True

    # ------------------------------------------------------------------ helpers
    def _at(self, **times) -> None:
        """Exactly these times for the next log calls (nothing carried over from another event)."""
        self.rec.reset_time()
        for k, v in times.items():
            self.rec.set_time(k, sequence=int(v))

    def _body_context(self, s: str, clip: Clip) -> None:
        sk = clip.skeleton
        names = [j.name for j in sk.joints]
        lower = {n.lower() for n in names}
        keypoints = [rr.AnnotationInfo(i, n, JOINT_COLOURS[_side(n, lower)]) for i, n in enumerate(names)]
        bones = [(j.parent, i) for i, j in enumerate(sk.joints) if j.parent >= 0]
        ctx = rr.AnnotationContext([rr.ClassDescription(info=rr.AnnotationInfo(CLASS_OF[r], r, COLOURS[r]),
                                                        keypoint_annotations=keypoints, keypoint_connections=bones)
                                    for r in ROLES])
        up = sk.up_axis
        coords = rr.ViewCoordinates.RIGHT_HAND_Z_UP if up == 2 else rr.ViewCoordinates.RIGHT_HAND_Y_UP
        for view in ("body", "overlay"):
            base = f"sessions/{s}/{view}"
            self.rec.log(base, coords, ctx, static=True)
            width = 2.7 if view == "body" else 1.35  # three people side by side, or one place
            centre, half = [SIDE_BY_SIDE["attempt"] if view == "body" else 0.0, 0.0, 0.0], [width, 1.2, 1.2]
            centre[up], half[up] = -0.006, 0.005  # a thin slab just under the feet
            self.rec.log(f"{base}/floor", rr.Boxes3D(centers=[centre], half_sizes=[half], colors=[(70, 70, 70)],
                                                     fill_mode="solid"), static=True)
            for r in ROLES:
                self.rec.log(f"{base}/{r}", rr.Points3D.from_fields(class_ids=[CLASS_OF[r]] * len(names),
                                                                    keypoint_ids=list(range(len(names))),
                                                                    radii=[0.025] * len(names)), static=True)

    def _pose(self, s: str, clip: Clip) -> tuple[Clip, np.ndarray] | None:
        """A motion resampled to the session's K frames, and its joints by forward kinematics,
        from the same start and on the floor (``None`` without a skeleton)."""
        sk = clip.skeleton or self.targets[s].skeleton
        if sk is None:
            return None
        data = _resample(clip, self.frames[s])
        pos = sk.forward_kinematics(data, clip.channels, ends=False)
        ground = [a for a in range(3) if a != sk.up_axis]
        pos[..., ground] -= pos[:1, :1, ground]
        pos[..., sk.up_axis] -= pos[..., sk.up_axis].min()
        return clip.with_data(data, skeleton=sk), pos

    def _people(self, s: str, role: str, pose: tuple[Clip, np.ndarray] | None, trial: int) -> None:
        """One motion (:meth:`_pose`) on the trial's block of ``playback``, side by side and overlaid."""
        if pose is None:
            return
        clip, pos = pose
        k = self.frames[s]
        data, ground = clip.data, [a for a in range(3) if a != clip.skeleton.up_axis]
        n, j = pos.shape[:2]
        times = [rr.TimeColumn("playback", sequence=trial * k + np.arange(n)),
                 rr.TimeColumn("trial", sequence=np.full(n, trial))]
        for view, offset in (("body", SIDE_BY_SIDE[role]), ("overlay", 0.0)):
            shifted = pos.copy()
            shifted[..., ground[0]] += offset
            rr.send_columns(f"sessions/{s}/{view}/{role}", indexes=times, recording=self.rec,
                            columns=rr.Points3D.columns(positions=shifted.reshape(-1, 3)).partition(lengths=[j] * n))
        for c in self.curves.get(s, []):
            if c in clip.channels:
                rr.send_columns(f"sessions/{s}/curves/{c}/{role}", indexes=times, recording=self.rec,
                                columns=rr.Scalars.columns(scalars=data[:, clip.channels.index(c)]))

    # ------------------------------------------------------------------ events
    def session_started(self, session: str, target: Clip) -> None:
        new = session not in self.targets
        self.targets[session] = target
        self.frames[session] = max(2, int(round(target.n_frames * PLAYBACK_FPS / target.fps)))
        self.paths[session], self.emphatic[session] = [], []
        self.curves[session] = [c for c in CURVE_CHANNELS if c in target.channels][:MAX_CURVES]
        self.trials[session] = 0
        self._forget_oldest()
        self._session_series(session)
        self._show_target(session, target)
        if new:
            self._layout()
        if session in self.pending:
            self.space(self.pending.pop(session))

    def _session_series(self, session: str) -> None:
        for c in self.curves[session]:
            for r in ROLES:
                _series_style(self.rec, f"sessions/{session}/curves/{c}/{r}", r, COLOURS[r], markers=False)
        for m, colour in (("d_p", (255, 170, 60)), ("R", (200, 200, 200)), ("alpha", (230, 60, 90))):
            _series_style(self.rec, f"sessions/{session}/{m}", m, colour)

    def _show_target(self, session: str, target: Clip) -> None:
        if target.skeleton is None:
            return
        self._body_context(session, target)
        self.poses[session] = self._pose(session, target)  # drawn again in every trial's block, computed once
        self._people(session, "target", self.poses[session], 0)

    def continue_from(self, old: Dashboard, budget_bytes: float | None = None, spaces=()) -> None:
        """A new recording goes on from ``old`` with what is still true, not its history: the
        newest session's target, ``spaces`` (the latest event of each, newest first), older
        sessions' targets (at most ``CARRY_OVER`` in all), the estimates' tabs, and the layout.
        With ``budget_bytes`` (and a file) nothing more is carried once the file and the layout it
        will need would pass it, so a new file starts small (the newest session always goes on)."""
        self.view_bytes = view_bytes = max(old.view_bytes, self.view_bytes)
        self.estimates, self.pending = dict(old.estimates), dict(old.pending)
        self.spaces = {}

        def fits(extra_views: int) -> bool:
            if budget_bytes is None or self.path is None:
                return True
            layout = (_views(self.blueprint()) + extra_views) * view_bytes
            return self.file_bytes() + layout <= budget_bytes

        def carry(s: str) -> None:
            for name in ("targets", "frames", "poses", "paths", "emphatic", "trials", "curves"):
                table = getattr(old, name)
                if s in table:  # (a target without a skeleton has no pose)
                    getattr(self, name)[s] = table[s]
            self._session_series(s)
            self._show_target(s, self.targets[s])

        newest_first = list(reversed(list(old.targets)[-CARRY_OVER:]))
        if newest_first:  # the newest session always; then the spaces (small); then older sessions
            carry(newest_first[0])
        for ev in reversed(list(spaces)[-MAX_KEPT:]):
            if not fits(1):
                break
            self.space(ev)
        for s in newest_first[1:]:
            if not fits(_views(old._session_tab(s))):
                break
            carry(s)
        self.targets = {s: self.targets[s] for s in old.targets if s in self.targets}  # in order of arrival
        self.send_layout(force=True)

    def file_bytes(self) -> int:
        """The recording file's size with everything logged so far written (rerun batches in memory)."""
        self.rec.flush()
        return self.path.stat().st_size if self.path is not None and self.path.exists() else 0

    def _forget_oldest(self) -> None:
        """At most ``MAX_KEPT`` sessions, estimates and spaces (the oldest go first)."""
        while len(self.targets) > MAX_KEPT:
            s = next(iter(self.targets))
            for table in (self.targets, self.frames, self.poses, self.paths, self.emphatic, self.trials,
                          self.curves, self.pending):
                table.pop(s, None)
        while len(self.estimates) > MAX_KEPT:
            self.estimates.pop(next(iter(self.estimates)))
        while len(self.spaces) > MAX_KEPT:
            self.spaces.pop(next(iter(self.spaces)))

    def trial(self, ev: dict, attempt: Clip | None, emphatic: Clip | None) -> None:
        s, n = ev["session"], int(ev["trial"])
        if s not in self.targets:
            return  # a session started before this recording: nothing to draw it against
        self.trials[s] = n
        k = self.frames[s]
        self._at(trial=n, playback=n * k)
        d_p, r = float(ev["d_p"]), ev.get("R")  # R is absent when the first trial's d_p was 0
        self.rec.log(f"sessions/{s}/d_p", rr.Scalars(d_p))
        self.rec.log(f"sessions/{s}/alpha", rr.Scalars(float(ev["alpha"])))
        if r is not None:
            self.rec.log(f"sessions/{s}/R", rr.Scalars(float(r)))
        chosen = ev.get("alpha_chosen")
        lowered = (f"; lowered from {chosen:g}: {ev.get('feasibility', '')}" if ev.get("alpha_reduced") and chosen
                   else "")
        extra = f", d_cop {ev['d_cop']:.2f}" if ev.get("d_cop") is not None else ""
        self.rec.log(f"sessions/{s}/coaching", rr.TextLog(
            f"trial {n}: \"{ev.get('adverb') or 'no adverb'}\", alpha {ev['alpha']:g}{lowered} | d_p {d_p:.1f}"
            + (f", R {r:.2f}" if r is not None else "") + extra,
            level="WARN" if ev.get("alpha_reduced") else "INFO"))
        path, emph = self.paths.setdefault(s, []), self.emphatic.setdefault(s, [])
        path.append(_xyz(ev["x_p"]))
        emph.append(_xyz(ev["x_s"]))
        base = f"sessions/{s}/space"
        self.rec.log(f"{base}/target", rr.Points3D([_xyz(ev["x_t"])], labels=["target"], radii=[0.0],
                                                   colors=[COLOURS["target"]], show_labels=True))
        self.rec.log(f"{base}/path", rr.LineStrips3D([path], colors=[COLOURS["attempt"]]))
        # every trial's points drawn, only this trial's labelled (the labels of all of them piled up
        # into one blob where the attempts converge): which trial is playing reads off the space
        self.rec.log(f"{base}/attempts", rr.Points3D(path, colors=[COLOURS["attempt"]], show_labels=False))
        self.rec.log(f"{base}/emphatic", rr.Points3D(emph, colors=[COLOURS["emphatic"]], show_labels=False))
        self.rec.log(f"{base}/now", rr.Points3D([path[-1], emph[-1]], labels=[f"attempt {n}", f"shown after {n}"],
                                                colors=[COLOURS["attempt"], COLOURS["emphatic"]], radii=[0.0],
                                                show_labels=True))
        self._people(s, "target", self.poses.get(s), n)
        for role, clip in (("attempt", attempt), ("emphatic", emphatic)):
            if clip is not None:  # drawn with the target's skeleton when it came without one
                self._people(s, role, self._pose(s, clip), n)

    def space(self, ev: dict) -> None:
        """A session's space on the trial it changed in (``coach-<s>``: before the session's first
        event, it waits for it), an estimate's on its conversation set (``est-<e>``), any other
        as it is now (static: visible on every timeline)."""
        name = ev["space"]
        static = False
        if name.startswith(("estspace-", "estself-")):  # the space estimator's own spaces: not drawn
            return
        if name.startswith("coach-"):
            s = name[6:]
            if s not in self.targets:
                self.pending.pop(s, None)
                self.pending[s] = ev
                while len(self.pending) > MAX_KEPT:
                    self.pending.pop(next(iter(self.pending)))
                return
            entity = f"sessions/{s}/space/proto_symbols"
            n = self.trials.get(s, 0) + 1  # the trial in progress
            self._at(trial=n, playback=n * self.frames[s])
        elif name.startswith("est-"):
            e = name[4:]
            entity = f"estimates/{e}/space/proto_symbols"
            if e not in self.estimates:
                self.estimates[e] = 0
                self._forget_oldest()
                self._layout()
            self._at(set=self.estimates[e] + 1)  # the conversation set in progress
        else:
            entity, static = f"spaces/{name}", True
            if name not in self.spaces and ev["change"] != "deleted":
                self.spaces[name] = None
                self._forget_oldest()
                self._layout()
            self.rec.reset_time()
        if ev["change"] == "deleted" or not ev.get("info"):
            if static:
                self.spaces.pop(name, None)
                self.rec.log(entity, rr.Clear(recursive=True), static=True)
                self._layout()
                return
            self.rec.log(entity, rr.Clear(recursive=True))
            return
        info = ev["info"]
        pts = np.asarray(info["points"], float)
        if pts.ndim != 2 or len(pts) == 0:
            return
        pts = np.hstack([pts[:, :3], np.zeros((len(pts), max(0, 3 - pts.shape[1])))])
        labels = [p["label"] for p in info["proto_symbols"]]
        classes = sorted(set(labels))
        ids = [classes.index(x) + 1 for x in labels]
        self.rec.log(entity, rr.AnnotationContext([rr.AnnotationInfo(i + 1, _short(c), PALETTE[i % len(PALETTE)])
                                                   for i, c in enumerate(classes)]), static=static)
        scale = float(np.ptp(pts, axis=0).max()) or 1.0
        self.rec.log(f"{entity}/points", rr.Points3D(pts, class_ids=ids, radii=[scale * 0.012], show_labels=False),
                     static=static)
        if name.startswith("coach-"):
            return  # the session's own points carry the labels (target, 1, 2, ..., s1, s2, ...)
        centres = [pts[[i for i, x in enumerate(labels) if x == c]].mean(axis=0) for c in classes]
        self.rec.log(f"{entity}/classes", rr.Points3D(centres, class_ids=list(range(1, len(classes) + 1)),
                                                      labels=[_short(c) for c in classes], radii=[0.0], show_labels=True),
                     static=static)

    def progress(self, ev: dict) -> None:
        e, n = ev["estimate"], int(ev["set"])
        if e not in self.estimates:
            self.estimates[e] = 0
            self._forget_oldest()
            self._layout()
        if n == 1 or not self.estimates[e]:
            for m, colour in (("symbols/k_other", (230, 60, 90)), ("symbols/k_self", (80, 160, 255)),
                              ("symbols/symbol_error", (200, 200, 200)), ("scale", (255, 170, 60))):
                _series_style(self.rec, f"estimates/{e}/{m}", m.split("/")[-1], colour)
        self.estimates[e] = n
        self._at(set=n)
        k_o, k_s = np.asarray(ev["k_other"], float), np.asarray(ev["k_self"], float)
        self.rec.log(f"estimates/{e}/symbols/k_other", rr.Scalars(float(k_o.mean())))
        self.rec.log(f"estimates/{e}/symbols/k_self", rr.Scalars(float(k_s.mean())))
        self.rec.log(f"estimates/{e}/symbols/symbol_error", rr.Scalars(float(np.mean(np.abs(k_o - k_s)))))
        self.rec.log(f"estimates/{e}/scale", rr.Scalars(float(ev["scale"])))

    def transcript(self, line: dict) -> None:
        """A line goes on the conversation set in progress: one more than the estimate has completed."""
        d = line["dialogue"]
        self._at(set=self.estimates.get(d, 0) + 1)
        who = line["speaker"]
        extra = f" (k = {line['k']})" if line.get("k") else (f" ({line['answer']})" if line.get("answer") else "")
        level = "WARN" if line.get("understood") is False or line["kind"] == "note" else "INFO"
        self.rec.log(f"estimates/{d}/transcript", rr.TextLog(f"{who}: {line['text']}{extra}", level=level))

    def capture_take(self, ev: dict) -> None:
        """A live take started, ended or failed (the capture service's take event)."""
        self.rec.reset_time()
        text = f"take {ev['take']}: {ev['state']}, {ev['frames']} frames ({ev['seconds']:.1f} s) from {ev['source']}"
        if ev.get("ended"):
            text += f"; {ev['ended']}"
        if ev.get("error"):
            text += f"; {ev['error']}"
        level = "ERROR" if ev["state"] == "failed" else ("WARN" if ev.get("dropped") or ev.get("skipped") else "INFO")
        self.rec.log("cluster/captures", rr.TextLog(text, level=level))

    def request(self, ev: dict) -> None:
        self.rec.reset_time()
        self.rec.log(f"cluster/latency/{ev['service']}/{ev['verb']}", rr.Scalars(float(ev["ms"])))
        if ev.get("code") not in (None, "ok"):
            self.rec.log("cluster/warnings", rr.TextLog(f"{ev['service']}/{ev['verb']} failed: {ev['code']}",
                                                        level="ERROR" if ev["code"] == "internal" else "WARN"))
