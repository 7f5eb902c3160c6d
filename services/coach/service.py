"""The coach service: coaching sessions (contract: ``schemas/coach.py``).

The coach owns sessions and policies and nothing else: spaces and generation are the pss
service's (space ``coach-<session>``), feasibility and learners the simulator's. A session is
saved after every trial (JSON and the target clip, atomically), so a restarted coach continues
where the last completed trial left it. An attempt is added to the space under a fresh name
each try, so a trial interrupted by a crash can simply be sent again.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import asdict
from pathlib import Path

import numpy as np

from schemas import coach as contract
from schemas.common import clip_from_wire, clip_to_wire
from shared.bus.client import Client, RemoteError
from shared.bus.config import Settings
from shared.bus.runtime import OneWriter, Service
from shared.coaching.effort import EffortEstimate, performed_effort
from shared.coaching.policies import (
    SWEEP,
    Calibration,
    Policy,
    best_alpha,
    fit_emu1_corrected,
    fit_nb,
    simulated_coach_demonstrations,
)
from shared.coaching.session import Session, Trial, session_to_dict, start, trial, warm
from shared.deadline import check_time, completed
from shared.errors import BadInput, Conflict, DamagedFile, NotFound
from shared.io import load_clip, save_clip
from shared.io.atomic import atomic_write
from shared.io.saved import read_back
from shared.motion.clip import Clip
from shared.pss.store import check_name


class BusCoachPorts:
    def __init__(self, client: Client, skeleton_json: str | None):
        self.c, self.skeleton = client, skeleton_json
        self._last: tuple | None = None  # (clip, effort) of the last clip performed

    def build(self, space, target):
        t = target.with_data(target.data, name="target", label="target")
        self.c.request("pss", "build", {"space": space, "replace": True, "clips": [clip_to_wire(t)]})

    def add_attempt(self, space, name, attempts):
        self.c.request("pss", "add", {"space": space, "as_one": name,
                                      "clips": [clip_to_wire(a.with_data(a.data, name=f"{name}_{i}", label=name))
                                                for i, a in enumerate(attempts)]})

    def distance(self, space, a, b):
        return float(self.c.request("pss", "distance", {"space": space, "a": a, "b": b})["distance"])

    def points(self, space):
        info = self.c.request("pss", "info", {"space": space})
        return {s["name"]: np.asarray(p) for s, p in zip(info["proto_symbols"], info["points"])}

    def generate(self, space, mix):
        return clip_from_wire(self.c.request("pss", "generate", {"space": space, "mix": mix})["clip"])

    def perform(self, clip, track=True):
        if self.skeleton is None:
            return {"joint_limit_violations": {}, "support": {"checked": False}, "frames": clip.n_frames,
                    "not_checked": ["joint limits and balance (the target has no skeleton)"], "feasible": None}, None
        r = self.c.request("simulator", "perform", {"skeleton": self.skeleton, "clip": clip_to_wire(clip, False),
                                                    "track": track})
        out = clip_from_wire(r["clip"])
        self._last = (clip, performed_effort(out))  # the check and the effort policy ask about the same clip
        return r["report"], out.select(["cog.x", "cog.y", "cog.z"])

    def plant(self, clip, reference):
        if self.skeleton is None:
            return clip, {"planted": False, "why": "the target has no skeleton"}
        r = self.c.request("simulator", "plant", {"skeleton": self.skeleton, "clip": clip_to_wire(clip, False),
                                                  "reference": clip_to_wire(reference, False)})
        return clip_from_wire(r["clip"], clip.skeleton), r["changes"]

    def effort(self, clip):
        if self.skeleton is None:
            return None
        if self._last is not None and self._last[0] is clip:
            return self._last[1]
        r = self.c.request("simulator", "perform", {"skeleton": self.skeleton, "clip": clip_to_wire(clip, False)})
        return performed_effort(clip_from_wire(r["clip"]))


def trial_reply(session: Session, rec: Trial, demo: Clip) -> dict:
    return {"session": session.name, "trial": rec.number, "d_p": rec.d_p, "d_cop": rec.d_cop, "alpha": rec.alpha,
            "alpha_shown": rec.alpha_shown, "adverb": rec.adverb, "feasible": rec.feasible,
            "alpha_reduced": rec.alpha_reduced, "feasibility": rec.feasibility, "part": rec.part,
            **({"emphasis_kept": rec.emphasis_kept} if rec.emphasis_kept is not None else {}),
            **({"felt": rec.felt} if rec.felt is not None else {}),
            **({"felt_predicted": rec.felt_predicted} if rec.felt_predicted is not None else {}),
            "shares": rec.shares, "goal": rec.goal, "emphatic": clip_to_wire(demo), "x_t": rec.x_t, "x_p": rec.x_p, "x_s": rec.x_s,
            "seconds": rec.seconds}


class CoachHandlers:
    """The coach service's verbs, one method each: :func:`make_service` registers :meth:`handlers`
    on a :class:`~shared.bus.runtime.Service`; without one (tests), give it a folder, a bus client
    factory and a publisher."""

    def __init__(self, root: Path, bus, publish) -> None:
        self.root, self.bus, self.publish = root, bus, publish
        self.writing = OneWriter("session")  # one request at a time changes a session

    def paths(self, name: str) -> tuple[Path, Path]:
        check_name(name)
        return self.root / f"{name}.json", self.root / f"{name}.target.npz"

    def save(self, s: Session) -> None:
        meta, target = self.paths(s.name)
        if not target.exists():
            save_clip(s.target, target)
        text = json.dumps(session_to_dict(s)).encode()
        atomic_write(meta, lambda f: f.write(text))

    def load(self, name: str) -> Session:
        meta, target = self.paths(name)
        if not meta.exists():
            raise NotFound(f"no coaching session {name!r}", session=name)
        with read_back(meta, "coaching session", name):
            d = json.loads(meta.read_text())
            cog = d.get("target_cog")
            return Session(name, load_clip(target), Policy.from_dict(d["policy"]), d.get("learner"),
                           trials=[Trial(**t) for t in d["trials"]], mode=d.get("mode", "residual"),
                           check=d.get("check", True), target_report=d.get("target_report"),
                           target_cog=None if cog is None else np.asarray(cog), subgoals=d.get("subgoals"),
                           effort=EffortEstimate.from_dict(d.get("effort")))

    def info(self, s: Session) -> dict:
        d = s.d()
        return {"session": s.name, "target": s.target.name, "learner": s.learner, "mode": s.mode, "check": s.check,
                "policy": s.policy.to_dict(),
                "trials": [asdict(t) for t in s.trials], "R": [x / d[0] for x in d] if d and d[0] > 0 else []}

    def ports_of(self, s: Session) -> BusCoachPorts:
        return BusCoachPorts(self.bus(), None if s.target.skeleton is None else s.target.skeleton.to_json())

    def run_trial(self, s: Session, attempts: list[Clip], felt: int | None = None) -> tuple[Trial, Clip]:
        ports = self.ports_of(s)
        # a fresh proto-symbol name per try: a trial cut short by a crash is simply sent again
        rec, demo = trial(s, attempts, _Renamed(ports, f"-{uuid.uuid4().hex[:6]}"), felt)
        save_clip(demo, self.root / f"{s.name}.last.npz")  # what to show next, for run to continue from
        self.save(s)
        self.publish("trial", {"session": s.name, "trial": rec.number, "d_p": rec.d_p, "alpha": rec.alpha_shown,
                              "adverb": rec.adverb, "x_t": rec.x_t, "x_p": rec.x_p, "x_s": rec.x_s,
                              "learner": s.learner, "attempt": clip_to_wire(attempts[0], False),
                              "emphatic": clip_to_wire(demo, False), "alpha_chosen": rec.alpha,
                              "alpha_reduced": bool(rec.alpha_reduced), "feasibility": rec.feasibility[:1000],
                              **({"R": rec.d_p / s.trials[0].d_p} if s.trials[0].d_p > 0 else {}),
                              **({} if rec.d_cop is None else {"d_cop": rec.d_cop})})
        return rec, demo

    def learner_of(self, session_file: Path) -> str | None:
        try:
            return json.loads(session_file.read_text()).get("learner")
        except (OSError, ValueError, AttributeError):  # unreadable: it owns nothing we can name
            return None

    def check_owned(self, s: Session, replacing: bool) -> None:
        """A session never takes what is another's: its learner must not be
        learning in another session, and a new session's space ``coach-<session>`` and learner
        must not already exist (a user's own space or learner would be replaced)."""
        if s.learner:
            owner = next((p.stem for p in sorted(self.root.glob("*.json"))
                          if p.stem != s.name and self.learner_of(p) == s.learner), None)
            if owner is not None:
                raise Conflict(f"learner {s.learner!r} is learning in session {owner!r}; give this session another "
                               f"learner name, or delete session {owner!r} first", learner=s.learner, session=owner)
        if replacing:
            return
        if s.space in {x["space"] for x in self.bus().request("pss", "list", {}, timeout=30)["spaces"]}:
            raise Conflict(f"a space named {s.space!r} exists and is not this coach's; session {s.name!r} would "
                           f"replace it: choose another session name, or delete that space", space=s.space)
        if s.learner and s.learner in {x["learner"] for x in self.bus().request("simulator", "list", {}, timeout=30)["learners"]}:
            raise Conflict(f"a learner named {s.learner!r} exists in the simulator and belongs to no session; "
                           f"choose another learner name, or delete it (`mirrorcoach learner delete`)", learner=s.learner)

    def start_session(self, req):
        name = req["session"]
        meta, _ = self.paths(name)
        if meta.exists() and not req["replace"]:
            raise Conflict(f"session {name!r} exists; delete it or start with replace", session=name)
        if (req["target"] is None) == (req["target_space"] is None):
            raise BadInput("give exactly one of target (a clip) and target_space + target_label", field="target")
        if req["target"] is not None:
            target = clip_from_wire(req["target"])
        else:
            if not req["target_label"]:
                raise BadInput("target_space needs target_label", field="target_label")
            r = self.bus().request("pss", "generate", {"space": req["target_space"], "mix": {req["target_label"]: 1.0},
                                                  "name": "target"})
            target = clip_from_wire(r["clip"])
        target = target.resample(30.0) if target.fps != 30.0 else target
        if target.n_frames < 10:
            raise BadInput(f"the target has {target.n_frames} frames at 30 fps; at least 10", field="target")
        policy = Policy.from_dict(req["policy"])
        if policy.effort and req["learner"] and not (req["learner_params"] or {}).get("strength"):
            # refused before anything is created: without a strength the learner has nothing to feel with
            raise BadInput("the effort policy asks the learner how heavy each motion felt; a simulated learner needs a "
                           "strength for that (learner_params.strength, `--strength` in the CLI)", field="policy")
        s = Session(name, target, policy, req["learner"], mode=req["mode"], check=req["check"])
        self.check_owned(s, replacing=meta.exists())
        with self.writing(name):
            for p in (meta, self.paths(name)[1], self.root / f"{name}.last.npz"):
                p.unlink(missing_ok=True)
            if s.learner:
                try:
                    self.bus().request("simulator", "learner_create", {"learner": s.learner, "target": clip_to_wire(target),
                                                                  "population_seed": req["population_seed"],
                                                                  "index": req["index"], "family": req["family"],
                                                                  "replicate": req["replicate"], "replace": True,
                                                                  **({"params": req["learner_params"]}
                                                                     if req["learner_params"] else {})})
                except RemoteError as e:
                    raise BadInput(f"cannot create learner {s.learner!r}: {e.message}") from None
            start(s, self.ports_of(s))
            self.save(s)
        self.publish("session", {"session": name, "learner": s.learner, "target": clip_to_wire(target)})
        return self.info(s)

    def attempt(self, req):
        with self.writing(req["session"]):
            s = self.load(req["session"])
            rec, demo = self.run_trial(s, [clip_from_wire(c, s.target.skeleton) for c in req["clips"]], req["felt"])
        return trial_reply(s, rec, demo)

    def run(self, req):
        with self.writing(req["session"]):
            s = self.load(req["session"])
            if not s.learner:
                raise BadInput(f"session {s.name!r} coaches a person: send attempts with `coach attempt`")
            demo, adverb = s.target, None
            last = self.root / f"{s.name}.last.npz"
            if s.trials and last.exists():  # continue: show what the last trial chose
                demo, adverb = load_clip(last), s.trials[-1].adverb
            for i in range(req["trials"]):
                completed(f"{i} of {req['trials']} trial(s) completed and kept")
                check_time()
                r = self.bus().request("simulator", "learner_imitate", {"learner": s.learner, "demonstration": clip_to_wire(demo),
                                                                   **({"adverb": adverb} if adverb else {})})
                attempts = [clip_from_wire(a, s.target.skeleton) for a in r["attempts"]]
                if s.effort is not None and r.get("felt") is None:
                    raise BadInput(f"session {s.name!r} asks for felt effort, and learner {s.learner!r} has no strength "
                                   "to feel it with (create it with learner_params.strength)", field="policy")
                rec, demo = self.run_trial(s, attempts, r.get("felt") if s.effort is not None else None)
                adverb = rec.adverb
        return self.info(s)

    def state(self, req):
        return self.info(self.load(req["session"]))

    def policy_fit(self, req):
        kind = req["kind"]
        if kind in ("aeu1", "aeu2"):
            if req["trial_dp"]:
                cal = Calibration.separating(req["trial_dp"])
            elif req["first_trial_dp"]:
                cal = Calibration.fit(req["first_trial_dp"])
            else:
                raise BadInput("AEU calibration needs trial_dp (or first_trial_dp)", field="trial_dp")
            return {"policy": Policy(kind, alpha=req["alpha"], calibration=cal.scale).to_dict(),
                    "fit": {"scale": cal.scale, "reference": cal.reference, "method": cal.method,
                            "shares": cal.shares(req["trial_dp"] or req["first_trial_dp"])}}
        if kind in ("emu1", "emu1c"):
            if req["demonstrations"]:
                pts = [tuple(np.asarray(v, float) for v in d) for d in req["demonstrations"]]
                source = "observed demonstrations"
            else:
                sim = req["simulated_coach"] or contract.SIMULATED_COACH.check({}, "simulated_coach")
                pts = simulated_coach_demonstrations(**sim)
                source = "a simulated coach"
            corrected, plain = fit_emu1_corrected(pts)  # eq. 5.5's alpha = 1 + eq. 4.3's
            alpha = (corrected if kind == "emu1c" else plain) - 1.0
            return {"policy": Policy(kind, alpha=float(np.clip(alpha, 0.0, 5.0)), adverb="table").to_dict(),
                    "fit": {"alpha_eq5_5_corrected": corrected, "alpha_eq5_5_uncorrected": plain,
                            "alpha_eq4_3": float(alpha), "n": len(pts), "source": source}}
        if kind == "emu2":
            if not req["sweep"]:
                raise BadInput("EMU-2 needs a sweep: learner -> {alpha: final error}", field="sweep")
            per = {}
            for learner, errs in req["sweep"].items():
                try:
                    items = {float(a): float(e) for a, e in errs.items()}
                except ValueError:
                    raise BadInput(f"sweep of {learner!r} must map alphas (numbers as text) to errors",
                                   field="sweep") from None
                if not all(0.0 <= a <= 5.0 for a in items):
                    raise BadInput(f"sweep of {learner!r}: alphas must be in [0, 5]", field="sweep")
                per[learner] = best_alpha(items)
            return {"policy": Policy("emu2", alpha=req["alpha"], adverb=None, per_learner=per).to_dict(),
                    "fit": {"per_learner": per, "sweep_alphas": list(SWEEP)}}
        if not req["features"] or not req["labels"]:
            raise BadInput("naive Bayes needs features (d_p, d_cop) and labels", field="features")
        nb = fit_nb(req["features"], req["labels"])
        return {"policy": Policy("nb", alpha=req["alpha"], adverb=None, nb=nb).to_dict(),
                "fit": {"classes": nb["classes"], "n": len(req["labels"])}}

    def list_sessions(self, req):
        rows = []
        damaged = []
        for p in sorted(self.root.glob("*.json")):
            try:
                with read_back(p, "coaching session", p.stem):
                    d = json.loads(p.read_text())
                    rows.append({"session": p.stem, "trials": len(d["trials"]), "learner": d.get("learner")})
            except NotFound:  # deleted while listed
                continue
            except DamagedFile as e:  # listed apart, with what is wrong with its file
                damaged.append(e.listed())
        return {"sessions": rows, "damaged": damaged}

    def delete(self, req):
        name = req["session"]
        with self.writing(name):
            meta, target = self.paths(name)
            if not meta.exists():
                raise NotFound(f"no coaching session {name!r}", session=name)
            learner = self.learner_of(meta)
            meta.unlink()
            target.unlink(missing_ok=True)
            (self.root / f"{name}.last.npz").unlink(missing_ok=True)
        for service, what in (("pss", {"space": f"coach-{name}"}), ("simulator", {"learner": learner})):
            if None in what.values():
                continue
            try:  # the session's space and learner are its own: they go with it
                self.bus().request(service, "delete", what, timeout=30)
            except RemoteError:
                pass
        return {"session": name, "deleted": True}


    def handlers(self) -> dict:
        """The verbs of the contract and the methods that answer them."""
        return {"start": self.start_session, "attempt": self.attempt, "run": self.run, "state": self.state,
                "policy_fit": self.policy_fit, "list": self.list_sessions, "delete": self.delete}


def make_service(settings: Settings | None = None) -> Service:
    settings = settings or Settings()
    warm()  # before serving: a person's first trial waits on it otherwise
    root = settings.data_dir("coach")
    root.mkdir(parents=True, exist_ok=True)
    svc = Service(contract.SERVICE, contract.ENDPOINTS, contract.EVENTS, settings=settings)
    return svc.serve(CoachHandlers(root, svc.client, svc.publish).handlers())


class _Renamed:
    """Ports whose attempt proto-symbols get a unique suffix (see module docstring)."""

    def __init__(self, ports: BusCoachPorts, suffix: str):
        self.p, self.suffix, self.names = ports, suffix, {}

    def _n(self, name):  # the target and sub-goals keep their names across trials
        return name if name == "target" or name.startswith("subgoal") else self.names.setdefault(name, name + self.suffix)

    def build(self, space, target):
        self.p.build(space, target)

    def add_attempt(self, space, name, attempts):
        self.p.add_attempt(space, self._n(name), attempts)

    def distance(self, space, a, b):
        return self.p.distance(space, self._n(a), self._n(b))

    def points(self, space):
        pts = self.p.points(space)
        for short, long in self.names.items():
            if long in pts:
                pts[short] = pts[long]
        return pts

    def generate(self, space, mix):
        return self.p.generate(space, {self._n(k): v for k, v in mix.items()})

    def perform(self, clip, track=True):
        return self.p.perform(clip, track)

    def plant(self, clip, reference):
        return self.p.plant(clip, reference)

    def effort(self, clip):
        return self.p.effort(clip)

