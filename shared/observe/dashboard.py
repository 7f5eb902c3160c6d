"""What the cluster does, logged to rerun (DESIGN.md "Observability"). Only the observer
process imports this module: services publish events and never import rerun.

Entity layout (the saved blueprint arranges it):

* ``skeletons/<session>/{target,attempt,emphatic}``: 3-D bones by forward kinematics, side by
  side (1.5 m apart), on the ``frame`` timeline, for the latest trial (``trial`` timeline);
* ``space/<space>/proto_symbols``: every proto-symbol as a labelled point;
  ``space/coach-<session>/path``: the session's attempts ``x_p`` across trials as a line, and
  ``.../emphatic``: the emphatic points ``x_s``; ``space/est-<estimate>`` is each estimator's
  estimated space of its other, as it moves set by set;
* ``curves/<session>/<channel>/{target,attempt,emphatic}``: joint angles over the frames;
* ``coach/<session>/{d_p,alpha}`` per trial and ``coach/<session>/adverb`` as text;
* ``estimator/<estimate>/{k_other,k_self,symbol_error,scale}`` per conversation set (the
  other's felt symbol against the self's estimate of it);
* ``dialogue/<dialogue>``: transcript lines; ``warnings/<service>``: failed requests;
  ``latency/<service>/<verb>``: request milliseconds.
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from shared.clip import Clip

CURVE_CHANNELS = ("rfemur.rx", "rtibia.rx", "lowerback.rx", "rhumerus.rx", "rradius.rx", "shoulder_pitch", "elbow")
SIDE_BY_SIDE = {"target": 0.0, "attempt": 1.5, "emphatic": 3.0}
COLOURS = {"target": (80, 160, 255), "attempt": (255, 170, 60), "emphatic": (230, 60, 90)}


def blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Spatial3DView(origin="skeletons", name="target | attempt | emphatic"),
                         rrb.TimeSeriesView(origin="curves", name="joint angles")),
            rrb.Vertical(rrb.Spatial3DView(origin="space", name="proto-symbol spaces"),
                         rrb.TimeSeriesView(origin="coach", name="d_p and alpha per trial"),
                         rrb.TimeSeriesView(origin="estimator", name="estimator per conversation set")),
            rrb.Vertical(rrb.TextLogView(origin="dialogue", name="dialogue transcripts"),
                         rrb.TextLogView(origin="warnings", name="warnings and errors"),
                         rrb.TimeSeriesView(origin="latency", name="request latency (ms)")),
            column_shares=[2, 2, 1.5],
        ),
        collapse_panels=True,
    )


class Dashboard:
    """A rerun recording fed with the cluster's events."""

    def __init__(self, path=None, viewer_url: str | None = None, application_id: str = "mirrorcoach"):
        self.rec = rr.RecordingStream(application_id)
        sinks = []
        if path is not None:
            sinks.append(rr.FileSink(str(path)))
        if viewer_url:
            sinks.append(rr.GrpcSink(viewer_url))
        if sinks:
            self.rec.set_sinks(*sinks)
        self.rec.send_blueprint(blueprint())
        self.targets: dict[str, Clip] = {}
        self.paths: dict[str, list] = {}
        self.emphatic: dict[str, list] = {}

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()

    # ------------------------------------------------------------------ helpers
    def _times(self, n: int, trial: int) -> list:
        return [rr.TimeColumn("frame", sequence=np.arange(n)), rr.TimeColumn("trial", sequence=np.full(n, trial))]

    def _skeleton(self, entity: str, clip: Clip, offset: float, colour, trial: int) -> None:
        """Bones of every frame, sent as one column chunk (not one log call per frame)."""
        sk = clip.skeleton
        if sk is None:
            return
        pos = sk.forward_kinematics(clip.data, clip.channels, ends=False)
        pos = pos - pos[:1, :1] + np.array([offset, 0.0, 0.0])  # side by side, from the same start
        bones = [(j.parent, i) for i, j in enumerate(sk.joints) if j.parent >= 0]
        strips = [np.stack([pos[f, a], pos[f, b]]) for f in range(len(pos)) for a, b in bones]
        n = len(pos)
        rr.send_columns(entity, indexes=self._times(n, trial), recording=self.rec,
                        columns=rr.LineStrips3D.columns(strips=strips, colors=[colour] * len(strips)).partition(
                            lengths=[len(bones)] * n))

    def _curves(self, session: str, kind: str, clip: Clip, trial: int) -> None:
        for c in CURVE_CHANNELS:
            if c in clip.channels:
                x = clip.column(c).astype(float)
                rr.send_columns(f"curves/{session}/{c}/{kind}", indexes=self._times(len(x), trial), recording=self.rec,
                                columns=rr.Scalars.columns(scalars=x))

    # ------------------------------------------------------------------ events
    def session_started(self, session: str, target: Clip) -> None:
        self.targets[session] = target
        self.paths[session], self.emphatic[session] = [], []
        self._show_target(session, target)

    def _show_target(self, session: str, target: Clip) -> None:
        self._skeleton(f"skeletons/{session}/target", target, SIDE_BY_SIDE["target"], COLOURS["target"], 0)
        self._curves(session, "target", target, 0)

    def continue_from(self, old: "Dashboard") -> None:
        """A new recording goes on from ``old``: the sessions' targets and paths so far."""
        self.targets, self.paths, self.emphatic = old.targets, old.paths, old.emphatic
        for session, target in self.targets.items():
            self._show_target(session, target)

    def trial(self, ev: dict, attempt: Clip | None, emphatic: Clip | None) -> None:
        s, n = ev["session"], int(ev["trial"])
        self.rec.set_time("trial", sequence=n)
        self.rec.log(f"coach/{s}/d_p", rr.Scalars(float(ev["d_p"])))
        self.rec.log(f"coach/{s}/alpha", rr.Scalars(float(ev["alpha"])))
        self.rec.log(f"coach/{s}/adverb", rr.TextLog(f"trial {n}: alpha {ev['alpha']:g}, "
                                                     f"\"{ev.get('adverb') or 'no adverb'}\", d_p {ev['d_p']:.1f}"))
        path, emph = self.paths.setdefault(s, []), self.emphatic.setdefault(s, [])
        path.append(list(ev["x_p"])[:3] + [0.0] * (3 - len(ev["x_p"][:3])))
        emph.append(list(ev["x_s"])[:3] + [0.0] * (3 - len(ev["x_s"][:3])))
        x_t = list(ev["x_t"])[:3] + [0.0] * (3 - len(ev["x_t"][:3]))
        base = f"space/coach-{s}"
        self.rec.log(f"{base}/target", rr.Points3D([x_t], labels=["target"], radii=[2.0], colors=[COLOURS["target"]]))
        self.rec.log(f"{base}/path", rr.LineStrips3D([path], colors=[COLOURS["attempt"]]))
        self.rec.log(f"{base}/attempts", rr.Points3D(path, labels=[f"x_p{i + 1}" for i in range(len(path))],
                                                     colors=[COLOURS["attempt"]]))
        self.rec.log(f"{base}/emphatic", rr.Points3D(emph, labels=[f"x_s{i + 1}" for i in range(len(emph))],
                                                     colors=[COLOURS["emphatic"]]))
        target = self.targets.get(s)
        for kind, clip in (("attempt", attempt), ("emphatic", emphatic)):
            if clip is None:
                continue
            if clip.skeleton is None and target is not None:
                clip = clip.with_data(clip.data, skeleton=target.skeleton)
            self._skeleton(f"skeletons/{s}/{kind}", clip, SIDE_BY_SIDE[kind], COLOURS[kind], n)
            self._curves(s, kind, clip, n)

    def space(self, ev: dict) -> None:
        name = ev["space"]
        if ev["change"] == "deleted" or not ev.get("info"):
            self.rec.log(f"space/{name}", rr.Clear(recursive=True))
            return
        info = ev["info"]
        pts = np.asarray(info["points"], float)
        if pts.ndim != 2 or len(pts) == 0:
            return
        pts = np.hstack([pts[:, :3], np.zeros((len(pts), max(0, 3 - pts.shape[1])))])
        labels = [f"{p['label']}" if p["label"] == p["name"] else f"{p['label']} ({p['name']})" for p in info["proto_symbols"]]
        self.rec.log(f"space/{name}/proto_symbols", rr.Points3D(pts, labels=labels))

    def progress(self, ev: dict) -> None:
        e = ev["estimate"]
        self.rec.set_time("set", sequence=int(ev["set"]))
        k_o, k_s = np.asarray(ev["k_other"], float), np.asarray(ev["k_self"], float)
        self.rec.log(f"estimator/{e}/k_other", rr.Scalars(float(k_o.mean())))
        self.rec.log(f"estimator/{e}/k_self", rr.Scalars(float(k_s.mean())))
        self.rec.log(f"estimator/{e}/symbol_error", rr.Scalars(float(np.mean(np.abs(k_o - k_s)))))
        self.rec.log(f"estimator/{e}/scale", rr.Scalars(float(ev["scale"])))

    def transcript(self, line: dict) -> None:
        who = line["speaker"]
        extra = f" (k = {line['k']})" if line.get("k") else (f" ({line['answer']})" if line.get("answer") else "")
        level = "WARN" if line.get("understood") is False or line["kind"] == "note" else "INFO"
        self.rec.log(f"dialogue/{line['dialogue']}", rr.TextLog(f"{who}: {line['text']}{extra}", level=level))

    def request(self, ev: dict) -> None:
        self.rec.log(f"latency/{ev['service']}/{ev['verb']}", rr.Scalars(float(ev["ms"])))
        if ev.get("code") not in (None, "ok"):
            self.rec.log(f"warnings/{ev['service']}", rr.TextLog(f"{ev['verb']} failed: {ev['code']}",
                                                                 level="ERROR" if ev["code"] == "internal" else "WARN"))
