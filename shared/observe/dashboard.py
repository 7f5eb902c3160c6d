"""What the cluster does, logged to rerun (DESIGN.md "Observability"). Only the observer
process imports this module: services publish events and never import rerun.

The recording opens with its own blueprint (re-sent whenever a session, space or estimate
appears): one tab per coaching session, one per estimate, one for the other spaces and one for
the cluster, in the style of rerun's robotics examples.

Entities and timelines (each kind of data on the timelines where it belongs; the layout and
why every tab reads on ``playback`` in :mod:`shared.observe.layout`):

* ``readme``: a short markdown text explaining the views (static);
* ``sessions/<s>/body/{target,attempt,emphatic}``: upright people (the skeleton's own up axis
  as the view coordinates, a floor, a front camera), side by side 1.5 m apart, each turned so
  that its first frame faces the camera; joints are keypoints of an annotation context (named
  on hover; left side, right side, head and feet coloured apart, bones in the motion's colour);
  ``sessions/<s>/overlay/...`` the same three overlaid. Timeline ``playback``: trial ``n``
  occupies ``n * K ... n * K + K - 1`` where ``K`` is the target's frame count at 30 fps, and
  the target, the attempt and the emphatic motion shown next are each resampled to those ``K``
  frames, so any trial plays in step; also timeline ``trial`` (its last frame at ``n``);
* ``sessions/<s>/curves/<channel>/<role>``: joint angles on the same timelines;
* ``sessions/<s>/now``: the trial playing (adverb, alpha shown and chosen, why it was lowered,
  d_p, R, d_cop) at the start of its ``playback`` block; ``sessions/<s>/{d_p,alpha}``: bar
  charts of every trial so far, the playing trial's bar lighter (``.../now``);
  ``sessions/<s>/coaching``: one short line per trial;
* ``sessions/<s>/space``: the session's space (``coach-<s>``) on its first two axes: its
  proto-symbols, the attempts ``x_p`` as a path, the emphatic points ``x_s``, the target
  ``x_t``, labels placed so that none overlaps another (:mod:`shared.observe.labels`);
* ``spaces/<space>``: any other space, coloured by class, one label per class where it fits;
* ``estimates/<e>/{symbols,scale}``: bar charts per conversation set, ``estimates/<e>/transcript``
  with each line on the set it belongs to, ``estimates/<e>/space``: on timeline ``set`` and at
  ``playback`` 0 (the latest shows on ``playback``);
* ``cluster/warnings`` and ``cluster/captures`` (one line per live take's start and end: its
  source, frames, why it ended or failed) on the log time and at ``playback`` 0;
  ``cluster/latency``: a table of the requests' latencies per service and verb (static).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from shared.motion.clip import Clip, time_normalised
from shared.motion.skeleton import Skeleton
from shared.observe import labels as lab
from shared.observe import layout as lay
from shared.observe.latency import LatencyTable

CURVE_CHANNELS = ("rfemur.rx", "rtibia.rx", "lowerback.rx", "rhumerus.rx", "shoulder_pitch", "elbow")
MAX_CURVES = 3
ROLES = ("target", "attempt", "emphatic")
SIDE_BY_SIDE = {"target": 0.0, "attempt": 1.5, "emphatic": 3.0}
COLOURS = {"target": (80, 160, 255), "attempt": (255, 170, 60), "emphatic": (230, 60, 90)}
LIGHTER = {"d_p": (255, 215, 160), "alpha": (250, 160, 180)}  # the playing trial's bar
METRIC_COLOURS = {"d_p": COLOURS["attempt"], "alpha": COLOURS["emphatic"]}
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
#: a session's own tables (carried to a new recording, forgotten together)
SESSION_TABLES = ("targets", "learners", "frames", "poses", "paths", "emphatic", "curves", "metrics", "session_space")


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


def face_the_camera(pos: np.ndarray, sides: list[str], up: int) -> np.ndarray:
    """Joint positions (frames x joints x 3, the first frame's root at the origin) turned about the
    up axis so that the first frame's left side points along the first ground axis: a person then
    faces +Z (Y up) or -Y (Z up), where :func:`shared.observe.layout.front` puts the camera
    (their left on the viewer's right). Unchanged without a left and a right side."""
    left = [i for i, s in enumerate(sides) if s == "left"]
    right = [i for i, s in enumerate(sides) if s == "right"]
    if not left or not right:
        return pos
    g0, g1 = [a for a in range(3) if a != up]
    lr = pos[0, left].mean(axis=0) - pos[0, right].mean(axis=0)
    if np.hypot(lr[g0], lr[g1]) < 1e-9:
        return pos
    theta = -np.arctan2(lr[g1], lr[g0])
    c, s = np.cos(theta), np.sin(theta)
    out = pos.copy()
    out[..., g0], out[..., g1] = c * pos[..., g0] - s * pos[..., g1], s * pos[..., g0] + c * pos[..., g1]
    return out


def _xy(p) -> list[float]:
    return ([float(v) for v in list(p)[:2]] + [0.0, 0.0])[:2]  # a point on the first two axes (0 where it has none)


def _bars(rec, entity: str, xs: list[int], values: list[float], colour, width: float = 0.8, offset: float = 0.0):
    """A bar per ``x`` (a trial, a conversation set), centred on it (rerun puts a bar's left edge
    at its abscissa)."""
    rec.log(entity, rr.BarChart(np.asarray(values, float), abscissa=np.asarray(xs, float) + offset - width / 2,
                                widths=np.full(len(xs), width), color=colour))



def _space_trial(ev: dict) -> int | None:
    """The trial a session's space was built for: the number of the last attempt it holds
    (:func:`shared.coaching.session.attempt_number`), read from the space itself because pss's event
    and the coach's trial event come from two processes and can arrive in either order (drawn as the
    trial in progress, a space that arrived after its trial's event was drawn on one trial more)."""
    from shared.coaching.session import attempt_number

    numbers = [attempt_number(str(p.get("name", ""))) for p in (ev.get("info") or {}).get("proto_symbols", [])]
    return max((n for n in numbers if n is not None), default=None)


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
        self.learners: dict[str, str | None] = {}
        self.frames: dict[str, int] = {}  # K per session: the target's frames at 30 fps
        self.poses: dict[str, tuple | None] = {}  # the target's, resampled and by forward kinematics
        self.paths: dict[str, list] = {}
        self.emphatic: dict[str, list] = {}
        self.metrics: dict[str, dict[str, list]] = {}  # per session: trial numbers, d_p and alpha
        self.session_space: dict[str, tuple] = {}  # per session: its space's points (2-D) and their classes
        self.spaces: dict[str, None] = {}  # in order of arrival
        self.estimates: dict[str, int] = {}  # conversation sets completed per estimate
        self.others: dict[str, str] = {}  # the other each estimate talks to (from its transcript)
        self.sets: dict[str, dict[str, list]] = {}  # per estimate: sets, mean k of the other and self, scale
        self.pending: dict[str, dict] = {}  # a session's space event that came before the session
        self.curves: dict[str, list[str]] = {}
        self.latency = LatencyTable()
        self.path = None if path is None else Path(path)
        self.view_bytes = 0.0  # measured when a layout is written to the file
        self._layout_due, self._layout_sent = False, float("-inf")
        self.rec.log("readme", lay.readme(), static=True)
        # the failed requests' panel has a line before any request fails: empty, it looked broken
        self._everywhere()
        self.rec.log("cluster/warnings", rr.TextLog("recording started: a request that fails is listed here",
                                                    level="INFO"))
        self._layout()

    def close(self) -> None:
        self.refresh(force=True)
        self.send_layout(force=True)
        self.rec.flush()
        self.rec.disconnect()

    # ------------------------------------------------------------------ layout
    def session_title(self, s: str) -> str:
        """A session's tab: its motion, its learner and its id."""
        target = self.targets[s]
        parts = [lay.short(target.label or target.name or "target", 20)]
        learner = self.learners.get(s)
        if learner:
            parts.append(lay.short(learner, 16))
        return " · ".join(parts + [s])  # the id whole: tabs are told apart by it

    def _session_tab(self, s: str) -> rrb.Container:
        sk = self.targets[s].skeleton
        up = sk.up_axis if sk is not None else 1
        return lay.session_tab(s, self.session_title(s), self.curves.get(s, []), up, SIDE_BY_SIDE["attempt"])

    def trials_done(self, s: str) -> int:
        """The number of a session's last trial (0 before its first)."""
        done = self.metrics.get(s, {}).get("trial")
        return done[-1] if done else 0

    def estimate_title(self, e: str) -> str:
        """An estimate's tab: the other it talks to (once a transcript line named it) and its id."""
        other = f"{lay.short(self.others[e], 16)} · " if e in self.others else ""
        return f"estimate · {other}{e}"

    def blueprint(self) -> rrb.Blueprint:
        return lay.blueprint([self._session_tab(s) for s in self.targets],
                             [lay.estimate_tab(e, self.estimate_title(e)) for e in self.estimates], sorted(self.spaces))

    def _layout(self) -> None:
        """The layout changed (a tab came or went): :meth:`send_layout` sends it (the observer, at
        most every ``LAYOUT_EVERY_S``; :meth:`close` in any case)."""
        self._layout_due = True

    def layout_ready(self) -> bool:
        """The layout changed and ``LAYOUT_EVERY_S`` has passed since the last one was sent."""
        return self._layout_due and time.monotonic() - self._layout_sent >= LAYOUT_EVERY_S

    def layout_bytes(self) -> float:
        """What sending the layout now would add to the file (0 until one has been measured)."""
        return lay.views(self.blueprint()) * self.view_bytes

    def send_layout(self, force: bool = False) -> bool:
        """Send the layout if it changed and ``LAYOUT_EVERY_S`` has passed (or ``force``)."""
        if not (self.layout_ready() or (force and self._layout_due)):
            return False
        blueprint = self.blueprint()
        before = self.file_bytes() if self.path is not None else 0
        self.rec.send_blueprint(blueprint)
        if self.path is not None:  # what a view costs in the file, for the rotation's estimates
            self.view_bytes = max(self.view_bytes, (self.file_bytes() - before) / max(1, lay.views(blueprint)))
        self._layout_due, self._layout_sent = False, time.monotonic()
        return True

    # ------------------------------------------------------------------ helpers
    def _at(self, **times) -> None:
        """Exactly these times for the next log calls (nothing carried over from another event)."""
        self.rec.reset_time()
        for k, v in times.items():
            self.rec.set_time(k, sequence=int(v))

    def _everywhere(self, **times) -> None:
        """``times`` and ``playback`` and ``trial`` 0: what an estimate or the cluster logs shows on
        the timeline the recording opens on too (the latest of it, from the first frame on)."""
        self._at(**{"playback": 0, "trial": 0, **times})

    def _body_context(self, s: str, sk: Skeleton) -> None:
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
        from the same start, on the floor and facing the camera (``None`` without a skeleton)."""
        sk = clip.skeleton or self.targets[s].skeleton
        if sk is None:
            return None
        data = time_normalised(clip.data, self.frames[s])
        pos = sk.forward_kinematics(data, clip.channels, ends=False)
        ground = [a for a in range(3) if a != sk.up_axis]
        pos[..., ground] -= pos[:1, :1, ground]
        pos[..., sk.up_axis] -= pos[..., sk.up_axis].min()
        lower = {j.name.lower() for j in sk.joints}
        pos = face_the_camera(pos, [_side(j.name, lower) for j in sk.joints], sk.up_axis)
        return clip.with_data(data, skeleton=sk), pos

    def _people(self, s: str, role: str, pose: tuple[Clip, np.ndarray] | None, trial: int) -> None:
        """One motion (:meth:`_pose`: with a skeleton) on the trial's block of ``playback``, side by
        side and overlaid."""
        if pose is None:
            return
        clip, pos = pose
        k = self.frames[s]
        up = clip.skeleton.up_axis if clip.skeleton is not None else 1
        data, ground = clip.data, [a for a in range(3) if a != up]
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
    def session_started(self, session: str, target: Clip, learner: str | None = None) -> None:
        new = session not in self.targets
        self.targets[session] = target
        self.learners[session] = learner
        self.frames[session] = max(2, int(round(target.n_frames * PLAYBACK_FPS / target.fps)))
        self.paths[session], self.emphatic[session] = [], []
        self.metrics[session] = {"trial": [], "d_p": [], "alpha": []}
        self.curves[session] = [c for c in CURVE_CHANNELS if c in target.channels][:MAX_CURVES]
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
                self.rec.log(f"sessions/{session}/curves/{c}/{r}", rr.SeriesLines(colors=[COLOURS[r]], names=[r]),
                             static=True)

    def _show_target(self, session: str, target: Clip) -> None:
        self._at(playback=0, trial=0)
        who = f", learner {self.learners[session]}" if self.learners.get(session) else ""
        self.rec.log(f"sessions/{session}/now", rr.TextDocument(
            f"**The target** {target.name or ''} ({target.label or 'no label'}){who}: no trial yet. Each trial plays "
            "the target, the attempt and the emphatic motion shown after it.", media_type=rr.MediaType.MARKDOWN))
        if target.skeleton is None:
            return
        self._body_context(session, target.skeleton)
        self.poses[session] = self._pose(session, target)  # drawn again in every trial's block, computed once
        self._people(session, "target", self.poses[session], 0)

    def continue_from(self, old: Dashboard, budget_bytes: float | None = None, spaces=()) -> None:
        """A new recording goes on from ``old`` with what is still true, not its history: the
        newest session's target, ``spaces`` (the latest event of each, newest first), older
        sessions' targets (at most ``CARRY_OVER`` in all), the estimates' tabs, and the layout.
        With ``budget_bytes`` (and a file) nothing more is carried once the file and the layout it
        will need would pass it, so a new file starts small (the newest session always goes on)."""
        self.view_bytes = view_bytes = max(old.view_bytes, self.view_bytes)
        self.estimates, self.pending, self.others = dict(old.estimates), dict(old.pending), dict(old.others)
        self.latency = old.latency  # counts since the observer started
        self.latency.due = bool(self.latency.stats)
        self.spaces = {}

        def fits(extra_views: int) -> bool:
            if budget_bytes is None or self.path is None:
                return True
            layout = (lay.views(self.blueprint()) + extra_views) * view_bytes
            return self.file_bytes() + layout <= budget_bytes

        def carry(s: str) -> None:
            for name in SESSION_TABLES:
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
            if not fits(lay.views(old._session_tab(s))):
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
            for name in (*SESSION_TABLES, "pending"):
                getattr(self, name).pop(s, None)
        while len(self.estimates) > MAX_KEPT:
            e = next(iter(self.estimates))
            for table in (self.estimates, self.others, self.sets):
                table.pop(e, None)
        while len(self.spaces) > MAX_KEPT:
            self.spaces.pop(next(iter(self.spaces)))

    def trial(self, ev: dict, attempt: Clip | None, emphatic: Clip | None) -> None:
        s, n = ev["session"], int(ev["trial"])
        if s not in self.targets:
            return  # a session started before this recording: nothing to draw it against
        k = self.frames[s]
        self._at(trial=n, playback=n * k)
        d_p, r, alpha = float(ev["d_p"]), ev.get("R"), float(ev["alpha"])  # R: absent when the first d_p was 0
        m = self.metrics[s]
        m["trial"].append(n)
        for name, value in (("d_p", d_p), ("alpha", alpha)):
            m[name].append(float(value))
            _bars(self.rec, f"sessions/{s}/{name}", m["trial"], m[name], METRIC_COLOURS[name])
            _bars(self.rec, f"sessions/{s}/{name}/now", [n], [m[name][-1]], LIGHTER[name])
        chosen = ev.get("alpha_chosen")
        lowered = bool(ev.get("alpha_reduced") and chosen)
        adverb = f"\"{ev['adverb']}\"" if ev.get("adverb") else "no adverb"
        values = f"d_p {d_p:.1f}" + (f", R {r:.2f}" if r is not None else "") + (
            f", d_cop {ev['d_cop']:.2f}" if ev.get("d_cop") is not None else "")
        shown = f"alpha {alpha:g}" + (f" (lowered from {chosen:g})" if lowered else "")
        self.rec.log(f"sessions/{s}/coaching", rr.TextLog(f"trial {n}: {adverb}, {shown}, {values}",
                                                          level="WARN" if lowered else "INFO"))
        why = f"\n\nLowered from alpha {chosen:g}: {ev.get('feasibility') or 'infeasible'}" if lowered else ""
        self.rec.log(f"sessions/{s}/now", rr.TextDocument(
            f"**Trial {n}**: the coach said {adverb} and showed the emphatic motion with {shown}. "
            f"The attempt: {values}.{why}", media_type=rr.MediaType.MARKDOWN))
        self.paths[s].append(_xy(ev["x_p"]))
        self.emphatic[s].append(_xy(ev["x_s"]))
        self._draw_session_space(s, n, _xy(ev["x_t"]))
        self._people(s, "target", self.poses.get(s), n)
        for role, clip in (("attempt", attempt), ("emphatic", emphatic)):
            if clip is not None:  # drawn with the target's skeleton when it came without one
                self._people(s, role, self._pose(s, clip), n)

    def _draw_session_space(self, s: str, n: int, x_t: list[float]) -> None:
        """The session's space at trial ``n``: its proto-symbols (grey: they are the target and the
        attempts themselves, named on hover), the attempts' path, the emphatic points, the target,
        and the labels of the target and the playing trial's two points."""
        path, emph = np.array(self.paths[s]), np.array(self.emphatic[s])
        pts, ids = self.session_space.get(s, (np.zeros((0, 2)), []))
        layers = [("proto_symbols/points", rr.Points2D, pts,
                   {"class_ids": ids, "radii": [-3.0], "colors": [(110,) * 3], "show_labels": False}),
                  ("path", rr.LineStrips2D, path, {"colors": [COLOURS["attempt"]]}),
                  ("attempts", rr.Points2D, path, {"colors": [COLOURS["attempt"]], "radii": [-4.0]}),
                  ("emphatic", rr.Points2D, emph, {"colors": [COLOURS["emphatic"]], "radii": [-4.0]}),
                  ("target", rr.Points2D, np.array([x_t]), {"colors": [COLOURS["target"]], "radii": [-6.0]})]
        self.space_2d(f"sessions/{s}/space", layers, [x_t, path[-1], emph[-1]],
                      ["target", f"attempt {n}", f"shown after {n}"], lay.SESSION_SPACE_PX,
                      [COLOURS["target"], COLOURS["attempt"], COLOURS["emphatic"]])

    def space_2d(self, base: str, layers, anchors, texts: list[str], panel_px, colours, static: bool = False) -> None:
        """A space's layers ``(entity, archetype, points, style)`` and its labels, in a fixed region:
        the points are mapped so that their frame (:func:`shared.observe.labels.frame`) is always
        the region the view shows (:func:`shared.observe.labels.region`; left to itself, a view
        fits all it has ever shown, with margins of its own, and labels landed where they were
        not placed). Labels go where
        none overlaps another (:func:`shared.observe.labels.place`), each at an invisible point,
        with a thin line to its point where it had to move away from it."""
        anchors = np.asarray(anchors, float).reshape(-1, 2)
        lo, hi = lab.frame(np.vstack([np.asarray(x, float).reshape(-1, 2) for *_, x, _ in layers] + [anchors]), panel_px)
        centre, half = (lo + hi) / 2, (hi - lo)[1] / 2

        def mapped(x):
            return ((np.asarray(x, float).reshape(-1, 2) - centre) / half).tolist()

        for entity, archetype, x, style in layers:
            data = [mapped(x)] if archetype is rr.LineStrips2D else mapped(x)
            self.rec.log(f"{base}/{entity}", archetype(data, **style), static=static)
        placed = lab.place(mapped(anchors), texts, panel_px, lab.region(panel_px))
        self.rec.log(f"{base}/labels", rr.Points2D([p.xy for p in placed], labels=[p.text for p in placed],
                                                   radii=[0.0], colors=[colours[p.index] for p in placed],
                                                   show_labels=True), static=static)
        moved = [[p.anchor, p.xy] for p in placed if p.anchor != p.xy]
        self.rec.log(f"{base}/labels/leaders", rr.LineStrips2D(moved, colors=[(120, 120, 120)], radii=[-0.5]),
                     static=static)

    def space(self, ev: dict) -> None:
        """A session's space (``coach-<s>``: kept, and drawn on the trial whose attempt it holds, or the
        next trial before any attempt; before the session's first event, it waits for it), an estimate's on its conversation set
        (``est-<e>``, and at ``playback`` 0), any other as it is now (static: on every timeline)."""
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
            entity, panel = f"sessions/{s}/space", lay.SESSION_SPACE_PX
            n = _space_trial(ev) or self.trials_done(s) + 1  # the trial whose attempt it holds, else the one in progress
            self._at(trial=n, playback=n * self.frames[s])
        elif name.startswith("est-"):
            e = name[4:]
            entity, panel = f"estimates/{e}/space", lay.ESTIMATE_SPACE_PX
            if e not in self.estimates:
                self.estimates[e] = 0
                self._forget_oldest()
                self._layout()
            self._everywhere(set=self.estimates[e] + 1)  # the conversation set in progress
        else:
            entity, static, panel = f"spaces/{name}", True, lay.OTHER_SPACE_PX
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
            if name.startswith("coach-"):  # the session's path and target stay
                self.session_space.pop(name[6:], None)
                entity += "/proto_symbols"
            self.rec.log(entity, rr.Clear(recursive=True))
            return
        info = ev["info"]
        pts = np.asarray(info["points"], float)
        if pts.ndim != 2 or len(pts) == 0:
            return
        pts = np.hstack([pts[:, :2], np.zeros((len(pts), max(0, 2 - pts.shape[1])))])
        names = [p["label"] for p in info["proto_symbols"]]
        classes = sorted(set(names))
        ids = [classes.index(x) + 1 for x in names]
        self.rec.log(f"{entity}/proto_symbols", rr.AnnotationContext(
            [rr.AnnotationInfo(i + 1, lay.short(c), PALETTE[i % len(PALETTE)]) for i, c in enumerate(classes)]),
            static=static)
        if name.startswith("coach-"):
            self.session_space[s] = (pts, ids)
            return
        medoids = []  # each class labelled at its proto-symbol nearest the class's centre
        for c in classes:
            members = pts[[i for i, x in enumerate(names) if x == c]]
            medoids.append(members[np.argmin(((members - members.mean(axis=0)) ** 2).sum(axis=1))])
        colours = [PALETTE[i % len(PALETTE)] for i in range(len(classes))]
        layers = [("proto_symbols/points", rr.Points2D, pts,
                   {"class_ids": ids, "radii": [-5.0], "colors": [colours[i - 1] for i in ids], "show_labels": False})]
        self.space_2d(entity, layers, medoids, [lay.short(c) for c in classes], panel, colours, static=static)

    def progress(self, ev: dict) -> None:
        """A conversation set completed: bars per set of the felt symbol (the other's answer and the
        self's estimate, mean over the set's motions) and of the torque scale."""
        e, n = ev["estimate"], int(ev["set"])
        if e not in self.estimates:
            self.estimates[e] = 0
            self._forget_oldest()
            self._layout()
        self.estimates[e] = n
        k_o, k_s = np.asarray(ev["k_other"], float), np.asarray(ev["k_self"], float)
        t = self.sets.setdefault(e, {"set": [], "k_other": [], "k_self": [], "scale": []})
        for key, value in (("set", n), ("k_other", k_o.mean()), ("k_self", k_s.mean()), ("scale", ev["scale"])):
            t[key].append(float(value))
        self._everywhere(set=n)
        _bars(self.rec, f"estimates/{e}/symbols/other", t["set"], t["k_other"], COLOURS["emphatic"], 0.4, -0.2)
        _bars(self.rec, f"estimates/{e}/symbols/self", t["set"], t["k_self"], COLOURS["target"], 0.4, 0.2)
        _bars(self.rec, f"estimates/{e}/scale", t["set"], t["scale"], COLOURS["attempt"])

    def transcript(self, line: dict) -> None:
        """A line goes on the conversation set in progress: one more than the estimate has completed."""
        d = line["dialogue"]
        who = line["speaker"]
        if d in self.estimates and d not in self.others and who != "self":
            self.others[d] = who  # the estimate's tab is named by the other it talks to
            self._layout()
        self._everywhere(set=self.estimates.get(d, 0) + 1)
        extra = f" (k = {line['k']})" if line.get("k") else (f" ({line['answer']})" if line.get("answer") else "")
        level = "WARN" if line.get("understood") is False or line["kind"] == "note" else "INFO"
        self.rec.log(f"estimates/{d}/transcript", rr.TextLog(f"{who}: {line['text']}{extra}", level=level))

    def capture_take(self, ev: dict) -> None:
        """A live take started, ended or failed (the capture service's take event)."""
        self._everywhere()
        text = f"take {ev['take']}: {ev['state']}, {ev['frames']} frames ({ev['seconds']:.1f} s) from {ev['source']}"
        if ev.get("ended"):
            text += f"; {ev['ended']}"
        if ev.get("error"):
            text += f"; {ev['error']}"
        level = "ERROR" if ev["state"] == "failed" else ("WARN" if ev.get("dropped") or ev.get("skipped") else "INFO")
        self.rec.log("cluster/captures", rr.TextLog(text, level=level))

    def request(self, ev: dict) -> None:
        """A request's latency (into the table) and, when it failed, a line."""
        failed = ev.get("code") not in (None, "ok")
        self.latency.add(ev["service"], ev["verb"], ev["ms"], failed)
        if failed:
            self._everywhere()
            self.rec.log("cluster/warnings", rr.TextLog(f"{ev['service']}/{ev['verb']} failed: {ev['code']}",
                                                        level="ERROR" if ev["code"] == "internal" else "WARN"))
        self.refresh()

    def refresh(self, force: bool = False) -> None:
        """Write what waits: the latency table when requests came and a second has passed (the
        observer calls this between events, so the table is current a second after the last
        request, not only at the next one)."""
        if self.latency.stats and (self.latency.ready() or (force and self.latency.due)):
            self.rec.log("cluster/latency", rr.TextDocument(self.latency.markdown(), media_type=rr.MediaType.MARKDOWN),
                         static=True)
