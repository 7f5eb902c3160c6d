"""The estimator service: learns what each other feels (contract: ``schemas/estimator.py``).

It never trains a model itself: ``P_other_hat`` lives on the pss service (space
``est-<estimate>``; the space estimator's ``estspace-<estimate>`` beside the self's
``estself-<estimate>``), the self's torques come from the simulator (body ``self``) and every
question goes through the dialogue service. The chapter-3 algorithm is
``shared.estimation`` run on :class:`BusPorts`.

Every completed conversation set is saved (atomically) before the next one starts, so a kill
loses at most the set in progress; ``converse`` first rebuilds the pss space from the saved
database, so the space always matches the saved state. A conversation stops with a reason,
keeping what was learnt, when the other does not answer, answers outside the words, or its
answers contradict each other.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import asdict
from pathlib import Path

import numpy as np

from schemas import estimator as contract
from schemas.common import clip_from_wire, clip_to_wire
from shared.bus.client import Client, RemoteError
from shared.bus.config import Settings
from shared.bus.runtime import OneWriter, Service
from shared.deadline import check_time, completed
from shared.errors import BadInput, Conflict, DamagedFile, MirrorcoachError, NotFound
from shared.estimation.conversation import SPACES, TORQUE_PREFIX, Language, OtherEstimate, hold, with_torques
from shared.estimation.motions import ALL, ARM, basic_motions
from shared.estimation.rules import (
    THESIS_CANDIDATES,
    candidate_bodies,
    design_thesis_pairs,
    identification_motions,
    identify_bodies,
    identify_thesis,
    weighted_candidates,
)
from shared.estimation.symbols import word
from shared.io.saved import read_back
from shared.once import Once
from shared.pss.store import check_name


class Stopped(MirrorcoachError):
    """The conversation cannot go on (no answer, nonsense, contradiction)."""

    code = "conflict"


class BusPorts:
    """The chapter-3 ports on the cluster (see ``shared.estimation.conversation``)."""

    def __init__(self, client: Client, name: str, other: str, language: Language, timeout: float = 120.0):
        self.c, self.name, self.other, self.language, self.timeout = client, name, other, language, timeout

    def _taus(self, wire: dict) -> np.ndarray:
        clip = clip_from_wire(wire)
        return clip.select([TORQUE_PREFIX + j for j in self.language.joints])

    def perform_self(self, motion):
        """The self's torques of a motion (its body never changes: performed once per motion for
        every estimate, like :meth:`regressor`)."""
        motion = hold(motion, self.language.missing)
        key = (motion.fingerprint(), tuple(self.language.joints))
        return _PERFORMED.once(key, lambda: self._taus(self.c.request("simulator", "perform", {
            "body": "self", "clip": clip_to_wire(motion)})["clip"]), self.timeout + 60).copy()

    def regressor(self, motion, offsets: bool = False) -> np.ndarray:
        """The self's regressor of a motion (the self's body never changes: one per motion for
        every estimate); ``offsets``: with the columns rule identification's bodies have."""
        key = (motion.fingerprint(), tuple(self.language.joints), tuple(self.language.missing), offsets)
        return _REGRESSORS.once(key, lambda: self.c.request("simulator", "regressor", {
            "clip": clip_to_wire(motion), "joints": self.language.joints, "missing": self.language.missing,
            "offsets": offsets})["y"], self.timeout + 60)

    def ask_open(self, motion) -> int | None:
        try:
            r = self.c.request("dialogue", "ask_open", {"dialogue": self.name, "other": self.other, "d": self.language.d,
                                                        "clip": clip_to_wire(motion), "timeout": self.timeout},
                               timeout=self.timeout + 60)
        except MirrorcoachError as e:
            raise Stopped(f"no answer about {motion.name}: {e.message}") from None
        if not r["understood"]:
            raise Stopped(f"the other's answer {r['raw']!r} about {motion.name} is not one of the words ({r['problem']})")
        if r.get("dont_know"):
            return None  # "I don't know": the question goes unanswered, the conversation goes on
        return int(r["k"])

    def ask_compare(self, first, second) -> str:
        try:
            r = self.c.request("dialogue", "ask_compare", {"dialogue": self.name, "other": self.other,
                                                           "clips": [clip_to_wire(first), clip_to_wire(second)],
                                                           "timeout": self.timeout}, timeout=self.timeout + 60)
        except MirrorcoachError as e:
            raise Stopped(f"no answer comparing {first.name} and {second.name}: {e.message}") from None
        if not r["understood"]:
            raise Stopped(f"the other's answer {r['raw']!r} is not a comparison ({r['problem']})")
        return r["answer"]

    def space_of(self, space: str = "thesis") -> str:
        """The pss space of the thesis estimator (``est-<estimate>``), of the space estimator
        (``estspace-<estimate>``) or the self's (``estself-<estimate>``); a name too long for pss
        (64 characters) ends in a hash of the estimate's name instead."""
        import hashlib

        prefix = {"thesis": "est-", "space": "estspace-", "self": "estself-"}[space]
        name = prefix + self.name
        return name if len(name) <= 64 else prefix + hashlib.sha1(self.name.encode()).hexdigest()[:32]

    def build(self, clips, space: str = "thesis") -> None:
        # association only: recognition's open-set tests are not fitted (most of saving a few clips' space)
        self.c.request("pss", "build", {"space": self.space_of(space), "replace": True, "open_set": False,
                                        "clips": [clip_to_wire(c) for c in clips]})

    def associate(self, motion, space: str = "thesis") -> np.ndarray:
        r = self.c.request("pss", "associate", {"space": self.space_of(space), "clip": clip_to_wire(motion),
                                                "missing": "sensor", "weighting": "inverse_distance",
                                                "whole": False})  # the torques on the motion's own frames only
        return self._taus(r["aligned"])


def info_of(name: str, est: OtherEstimate) -> dict:
    lo, hi = est.interval()
    out = {"estimate": name, "other": est.other, "language": asdict(est.language), "sets_done": len(est.sets),
           "scale": float(est.scale()), "scale_low": float(lo), "scale_high": None if not np.isfinite(hi) else float(hi),
           "consistent": bool(est.consistent()), "answers": len(est.answers), "probes_asked": len(est.probes_asked),
           "dont_know": est.dont_know,
           "notes": list(est.notes)}
    if est.sets:
        out["last_set"] = asdict(est.sets[-1])
    body = est.body_state()
    if body:
        from shared.estimation.body import column_names

        out["body"] = {"columns": column_names(est.language.joints), "theta": body["theta"], "scale": body["s"],
                       "answers": body["answers"], "model": body.get("model", "rigid")}
    return out


def model_reply(check: dict) -> dict:
    """The model check (:meth:`OtherEstimate.model_check`) with a sentence a person reads."""
    if not check["answers"]:
        return {**check, "verdict": "no answers yet"}
    if check["outside"]:
        why = []
        if check.get("misfit_outside", True):
            why.append(f"{check['misfits']} of {check['answers']} answers disagree with every body I can write down, while "
                       f"the other's repeated answers differ {check['repeat_disagreement']:.0%} of the time (binomial p = "
                       f"{check['p']:.2g})")
        drift = check.get("drift") or {}
        if drift.get("drifting"):
            why.append(f"its answers grow {'heavier' if drift['tau'] > 0 else 'lighter'} against every body I can write "
                       f"down as the conversation goes on (Kendall's tau {drift['tau']:.2f}, p = {drift['p']:.2g})")
        verdict = "outside what I can model: " + "; and ".join(why)
    else:
        verdict = (f"{check['agreement']:.0%} of {check['answers']} answers agree with the estimated body; the other's "
                   f"repeated answers differ {check['repeat_disagreement']:.0%} of the time")
    return {**check, "verdict": verdict}


_REGRESSORS = Once()  # (motion, joints, missing) -> the self's regressor Y
_PERFORMED = Once()  # (motion, joints) -> the self's torques (perform on the simulator's "self" body)
_DESIGN: dict = {}  # the self's designed pairs: they depend on the self's body only


def _design(ports: BusPorts) -> dict:
    """The thesis's m1-m4 designed on the self's whole body (never on an estimate's view of it
    that holds a joint still), once per process."""
    if "design" not in _DESIGN:
        whole = BusPorts(ports.c, ports.name, ports.other, Language(joints=list(ALL)), ports.timeout)
        _DESIGN["design"] = design_thesis_pairs(whole.perform_self)
    return _DESIGN["design"]


def _identify_on_bodies(est: OtherEstimate, cands, ports: BusPorts, design: dict, req: dict) -> dict:
    """Rule identification with answers predicted from the estimated body: per
    candidate, the bodies the estimate's open answers allow under that rule (only when the
    estimate feels all four joints the candidates weigh; otherwise the bodies the self thinks
    possible)."""
    motions = identification_motions(design)
    regs = {m.name: ports.regressor(m, offsets=True) for m in motions}
    answers, shared = [], []
    if est.language.joints == list(ALL):
        answers = [(key, est.regressor(ports, key), k) for key, k in est.body_answers]
        shared = [ports.regressor(m) for m in est.motions]
    bodies = candidate_bodies(ports.language, shared, answers, cands, scale=est.scale())
    return identify_bodies(cands, motions, regs, bodies, ports.ask_compare, jnd=req["jnd"], noise=req.get("noise"),
                           confidence=req["confidence"])


class EstimatorHandlers:
    """The estimator service's verbs, one method each: :func:`make_service` registers :meth:`handlers`
    on a :class:`~shared.bus.runtime.Service`; without one (tests), give it a folder, a bus client
    factory and a publisher."""

    def __init__(self, root: Path, bus, publish) -> None:
        self.root, self.bus, self.publish = root, bus, publish
        self.writing = OneWriter("estimate")  # one request at a time changes an estimate
        self.building: dict = {}  # name -> lock: a fresh estimate's space is built by one request
        self.building_lock = threading.Lock()
        self.loaded: dict = {}  # name -> (file stamp, estimate): estimate requests reuse the last load and its body fit
        self.loaded_lock = threading.Lock()  # the workers' requests read and trim it at once

    def path(self, name: str):
        return self.root / f"{check_name(name)}.npz"

    def load(self, name: str) -> OtherEstimate:
        return self._load(name)[1]

    def _load(self, name: str) -> tuple[tuple, OtherEstimate]:
        """The saved estimate (a copy of the last one loaded while its file is unchanged) and
        the file's stamp."""
        if not self.path(name).exists():
            raise NotFound(f"no estimate named {name!r}", estimate=name)
        stamp = self._stamp(name)
        with self.loaded_lock:
            hit = self.loaded.get(name)
        if hit is not None and hit[0] == stamp:
            return stamp, copy.deepcopy(hit[1])  # a copy: a handler may change it and then fail before saving
        est = self._read(name, self.path(name))
        self._remember(name, stamp, est)
        return stamp, copy.deepcopy(est)

    def _stamp(self, name: str) -> tuple:
        st = self.path(name).stat()
        return st.st_mtime_ns, st.st_size, st.st_ino

    def _remember(self, name: str, stamp: tuple, est: OtherEstimate) -> None:
        """``est`` is the estimate the file of ``stamp`` holds (the last 64 estimates kept)."""
        with self.loaded_lock:
            self.loaded[name] = (stamp, est)
            while len(self.loaded) > 64:
                self.loaded.pop(next(iter(self.loaded)))

    def keep(self, name: str, stamp: tuple, est: OtherEstimate) -> None:
        """Keep what a request that changes nothing computed on its copy (the body fit from the
        saved answers, the residual correction) for the next request on the same saved
        estimate: both follow from the saved state alone, so every ``estimate`` request after
        the first reuses them instead of fitting them again."""
        with self.loaded_lock:
            hit = self.loaded.get(name)
            if hit is not None and hit[0] == stamp:
                self.loaded[name] = (stamp, est)

    def start(self, req):
        name = req["estimate"]
        if self.path(name).exists() and not req["replace"]:
            raise Conflict(f"estimate {name!r} exists; delete it or start with replace", estimate=name)
        others = {o["other"] for o in self.bus().request("simulator", "list", {}, timeout=30)["others"]}
        if req["other"] not in others:  # checked before anything is built or saved
            raise NotFound(f"no other named {req['other']!r} (create it with `mirrorcoach other create`)",
                           other=req["other"])
        joints = req["joints"] or [j for j in ARM if j not in req["missing"]]
        felt_missing = [j for j in joints if j in req["missing"]]
        if felt_missing:
            raise BadInput(f"joints {felt_missing} are both felt and missing", field="missing")
        lang = Language(d=req["d"], g_max=req["g_max"], tau_max=req["tau_max"], joints=joints, rule=req["rule"],
                        missing=list(req["missing"]))
        lang.k(np.zeros((2, len(joints))))  # validates d
        shared = basic_motions(ALL if "knee" in joints else ARM)
        est = OtherEstimate(lang, [hold(m, lang.missing) for m in shared], probes=req["probes"])
        est.other = req["other"]
        with self.writing(name):
            # P_other_hat is built when first needed (converse rebuilds it anyway; estimate builds a missing one),
            # so a space left by an earlier estimate of this name must go: its answers are not this one's
            ports = BusPorts(self.bus(), name, req["other"], lang)
            for space in SPACES:  # (mostly none: a failed request each was a warning on the dashboard)
                self.bus().request("pss", "delete", {"space": ports.space_of(space), "missing_ok": True}, timeout=30)
            est.start(ports, build=False)
            est.save(self.path(name))
        return info_of(name, est)

    def converse(self, req):
        name = req["estimate"]
        with self.writing(name):
            est = self.load(name)
            ports = BusPorts(self.bus(), name, est.other, est.language, req["timeout"])
            for space in SPACES:  # the spaces match the saved state, whatever happened before
                ports.build(est.database(space), space)
            done, stopped = 0, None
            for _ in range(req["sets"]):
                completed(f"{done} of {req['sets']} conversation set(s) completed and kept")
                check_time()
                work = copy.deepcopy(est)
                try:
                    rec = work.conversation_set(ports)
                except Stopped as e:
                    stopped = e.message
                    break
                est = work
                # contradiction alone never stops the conversation: the least squares weighs every
                # answer, and the reply's model check says how sure it is, or that the other is outside
                # what the self can model. The body is fitted to every answer (the last probe's too)
                # before the set is saved.
                est.body(ports)
                est.save(self.path(name))
                done += 1
                self.publish("progress", {"estimate": name, "set": len(est.sets), "scale": float(est.scale()),
                                         "consistent": bool(est.consistent()), "k_other": rec.k_other,
                                         "k_self": rec.k_self})
            if stopped:
                est.notes.append(f"stopped after {len(est.sets)} set(s): {stopped}")
                est.save(self.path(name))
                for space in SPACES:
                    ports.build(est.database(space), space)
            stamp = self._stamp(name)  # the file as this request left it
        check = est.model_check(ports)  # the body fitted to every answer before the info reads it
        # the estimate requests that follow start from this fitted body and correction (loaded again, the
        # saved file would give the same after fitting them anew, once per request in flight)
        self._remember(name, stamp, est)
        out = {"info": info_of(name, est), "completed": done, "model": model_reply(check)}
        if stopped:
            out["stopped"] = stopped
        return out

    def estimate(self, req):
        name = req["estimate"]
        stamp, est = self._load(name)
        out = self._estimated(name, est, req["clip"], req["method"], "clip")
        self.keep(name, stamp, est)  # (this request changes it no more)
        return {"estimate": name, "method": req["method"], **out}

    def estimate_many(self, req):
        """:meth:`estimate` of every clip on one loaded estimate (an evaluation asks dozens)."""
        name = req["estimate"]
        stamp, est = self._load(name)
        out = []
        for i, clip in enumerate(req["clips"]):
            check_time()
            out.append(self._estimated(name, est, clip, req["method"], f"clips[{i}]"))
        self.keep(name, stamp, est)
        return {"estimate": name, "method": req["method"], "estimates": out}

    def _estimated(self, name: str, est: OtherEstimate, wire: dict, method: str, field: str) -> dict:
        """One motion's estimate: the clip with its torques, g, k and the word."""
        motion = clip_from_wire(wire)
        ports = BusPorts(self.bus(), name, est.other, est.language)
        missing = [j for j in est.language.joints if j not in motion.channels]
        if missing:
            raise BadInput(f"the motion lacks the joints {missing} this estimate is about", field=field)
        motion = hold(motion, est.language.missing)
        try:
            tau = est.estimate(motion, ports, method)
        except RemoteError as e:  # the space of a fresh estimate (or one pss lost): build it from the saved database
            if e.code != "not_found" or method not in ("thesis", "space"):
                raise
            with self.building_lock:
                lock = self.building.setdefault(name, threading.Lock())
                while len(self.building) > 256:  # bounded: the oldest estimates' locks go (a later build takes a new one)
                    self.building.pop(next(iter(self.building)))
            with lock:  # one request builds; the others wait for it, then find the space
                try:
                    tau = est.estimate(motion, ports, method)
                except RemoteError as again:
                    if again.code != "not_found":
                        raise
                    for space in SPACES:
                        ports.build(est.database(space), space)
                    tau = est.estimate(motion, ports, method)
        g = est.language.g(tau)
        k = est.language.k(tau)
        if len(tau) != motion.n_frames:  # the space's estimate is on its own frame rate
            motion = motion.resample(len(tau) / max(motion.duration, 1e-9) if motion.duration > 0 else motion.fps)
        out = with_torques(motion.frames(0, len(tau)), tau[: motion.n_frames], est.language.joints)
        return {"clip": clip_to_wire(out), "g": float(g), "k": int(k), "word": word(k, est.language.d)}

    def identify_rule(self, req):
        name = req["estimate"]
        with self.writing(name):
            est = self.load(name)
            lang4 = Language(**{**asdict(est.language), "joints": list(ALL)})
            ports = BusPorts(self.bus(), name, est.other, lang4, req["timeout"])
            design = _design(ports)
            try:
                if req["method"] == "thesis":
                    if req["candidates"] != "thesis":
                        raise BadInput("the thesis's pairs only separate f1-f4; use method auto for weighted candidates")
                    r = identify_thesis(design, ports.ask_compare)
                else:
                    cands = THESIS_CANDIDATES if req["candidates"] == "thesis" else weighted_candidates()
                    r = _identify_on_bodies(est, cands, ports, design, req)
            except Stopped as e:
                r = {"rule": None, "questions": [], "reason": e.message}
            rule = r["rule"]
            if rule is not None and req["apply"]:
                if rule.weights is not None and len(rule.weights) != len(est.language.joints):
                    est.notes.append(f"identified {rule.name}, whose weights do not fit this estimate's joints; not applied")
                else:
                    est.language.rule = rule.rule
                    est.language.weights = None if rule.weights is None else list(rule.weights)
                    est.answers = []  # bounds were computed with the old rule: the interval starts again
                    est.forget_body()  # and the body is fitted again under the identified rule
                    est.notes.append(f"identified rule {rule.name} in {len(r['questions'])} question(s); now used")
                est.save(self.path(name))
        out = {"estimate": name, "questions": [{"pair": q["pair"], "answer": q["answer"]} for q in r["questions"]],
               "reason": r["reason"], "design": design["report"]}
        if rule is not None:
            out["rule"] = rule.name
        if "posterior" in r:
            out["posterior"] = r["posterior"]
        return out

    def info(self, req):
        return info_of(req["estimate"], self.load(req["estimate"]))

    def list_estimates(self, req):
        rows, damaged = [], []
        for p in sorted(self.root.glob("*.npz")):
            try:
                est = self._read(p.stem, p)
            except NotFound:  # deleted while listed
                continue
            except DamagedFile as e:  # listed apart, with what is wrong with its file
                damaged.append(e.listed())
                continue
            rows.append({"estimate": p.stem, "other": est.other, "sets_done": len(est.sets)})
        return {"estimates": rows, "damaged": damaged}

    @staticmethod
    def _read(name: str, path: Path) -> OtherEstimate:
        """The estimate saved at ``path`` (a damaged file: :class:`DamagedFile`, the file kept)."""
        with read_back(path, "estimate", name, npz=True):
            return OtherEstimate.load(path)

    def delete(self, req):
        name = req["estimate"]
        with self.writing(name):
            if not self.path(name).exists():
                raise NotFound(f"no estimate named {name!r}", estimate=name)
            self.path(name).unlink()
        for space in SPACES:
            try:
                self.bus().request("pss", "delete", {"space": BusPorts(self.bus(), name, "", Language()).space_of(space),
                                                     "missing_ok": True}, timeout=30)  # it may never have been built
            except MirrorcoachError:
                pass  # pss down: the estimate goes anyway
        return {"estimate": name, "deleted": True}

    def handlers(self) -> dict:
        """The verbs of the contract and the methods that answer them."""
        return {"start": self.start, "converse": self.converse, "estimate": self.estimate,
                "estimate_many": self.estimate_many, "identify_rule": self.identify_rule, "info": self.info, "list": self.list_estimates,
                "delete": self.delete}


def make_service(settings: Settings | None = None) -> Service:
    settings = settings or Settings()
    root = settings.data_dir("estimator")
    root.mkdir(parents=True, exist_ok=True)
    svc = Service(contract.SERVICE, contract.ENDPOINTS, contract.EVENTS, settings=settings)
    return svc.serve(EstimatorHandlers(root, svc.client, svc.publish).handlers())

