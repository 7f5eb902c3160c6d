"""The simulator service: MuJoCo bodies, others and learners (contract: ``schemas/simulator.py``).

State (others, learners) lives in an :class:`AgentStore` under
``$MIRRORCOACH_HOME/data/simulator``. A person in an other's seat is served like a simulated
one: ``other_ask`` waits (bounded by the request's ``timeout``) until ``other_answer`` brings
the person's answer, so the asker never needs to know who answers. Pending questions live in
memory: a restart drops them and the asker gets ``unavailable``.
"""

from __future__ import annotations

import hashlib
import threading
import uuid
from collections import OrderedDict
from dataclasses import asdict

from schemas import simulator as contract
from schemas.common import clip_from_wire, clip_to_wire
from shared.agents.learner import LearnerParams, SimulatedLearner, population
from shared.agents.store import AgentStore, PersonOther
from shared.bodies.human import human_body
from shared.bodies.robot import ROBOTS, robot
from shared.bodies.tracking import perform_tracked
from shared.bus.config import Settings
from shared.bus.runtime import Service
from shared.errors import BadInput, NotFound, Unavailable
from shared.estimation.symbols import COMPARISONS, WORDS, parse_answer
from shared.motion.skeleton import Skeleton


class _Bodies:
    """Compiled bodies by (robot name or skeleton hash, mass); the last 16 human bodies kept."""

    def __init__(self):
        self.cache: OrderedDict = OrderedDict()
        self.lock = threading.Lock()

    def get(self, body: str | None, skeleton: str | None, mass: float | None):
        key = (body, None if skeleton is None else hashlib.sha256(skeleton.encode()).hexdigest(), mass)
        with self.lock:
            if key in self.cache:
                self.cache.move_to_end(key)
                return self.cache[key]
        if body is not None:
            b = robot(body, mass)
        else:
            try:
                sk = Skeleton.from_json(skeleton)
            except (ValueError, KeyError, TypeError) as e:
                raise BadInput(f"perform: the skeleton is not valid skeleton JSON ({type(e).__name__}: {e})",
                               field="skeleton") from None
            b = human_body(sk, 70.0 if mass is None else mass)
        with self.lock:
            self.cache[key] = b
            while len(self.cache) > 16:
                self.cache.popitem(last=False)
        return b


#: inverse dynamics keeps about this many times its clip's bytes (bench.budget: four performs of a
#: 100,000-frame human clip at once peaked at 1.86 GB, three running; two arm motions of 900,000
#: frames asked about at once held 490 MB)
INVERSE_DYNAMICS_BYTES = 14


class SimulatorHandlers:
    """The simulator service's verbs, one method each: :func:`make_service` registers :meth:`handlers`
    and :meth:`costs` on a :class:`~shared.bus.runtime.Service`; without one (tests), give it an
    agent store and a publisher."""

    def __init__(self, store: AgentStore, publish) -> None:
        self.store, self.publish = store, publish
        self.bodies = _Bodies()
        self.locks: dict[str, threading.Lock] = {}
        self.locks_guard = threading.Lock()
        self.pending: dict[str, dict] = {}
        self.pending_guard = threading.Lock()

    def lock_of(self, key: str) -> threading.Lock:
        with self.locks_guard:
            return self.locks.setdefault(key, threading.Lock())

    def list_bodies(self, req):
        return {"robots": [self.bodies.get(n, None, None).describe() for n in ROBOTS]}

    def perform_cost(self, req):
        return INVERSE_DYNAMICS_BYTES * req["clip"]["data"].nbytes

    def ask_cost(self, req):
        """An other performs the motions one after another: the largest one's inverse dynamics."""
        return INVERSE_DYNAMICS_BYTES * max(c["data"].nbytes for c in req["clips"])

    def do_perform(self, req):
        b = self.bodies.get(req["body"], req["skeleton"], req["mass"])
        clip = clip_from_wire(req["clip"], getattr(b, "skeleton", None))
        out, report = perform_tracked(b, clip, track=req["track"])
        self.publish("performed", {"body": b.name, "frames": out.n_frames, "feasible": report["feasible"] is True,
                                  "checked": report["feasible"] is not None})
        return {"clip": clip_to_wire(out, with_skeleton=False), "report": report, "body": b.describe()}

    def plant_cost(self, req):
        return INVERSE_DYNAMICS_BYTES * (req["clip"]["data"].nbytes + req["reference"]["data"].nbytes)

    def do_plant(self, req):
        from shared.bodies.stance import plant_feet

        b = self.bodies.get(None, req["skeleton"], req["mass"])
        clip = clip_from_wire(req["clip"], b.skeleton)
        out, changes = plant_feet(b, clip_from_wire(req["reference"], b.skeleton), clip)
        return {"clip": clip_to_wire(out, with_skeleton=False), "changes": changes}

    def do_regressor(self, req):
        from shared.estimation.body import column_names, self_regressor

        y = self_regressor(clip_from_wire(req["clip"]), req["joints"], req["missing"], req["offsets"])
        return {"names": column_names(req["joints"], req["offsets"]), "y": y}

    # ------------------------------------------------------------------ others
    def other_create(self, req):
        kind, _ = self.store.add_other(req["other"], req["kind"], req["params"] or {}, req["replace"])
        return {"other": req["other"], "kind": kind}

    def other_ask(self, req):
        kind, other = self.store.other(req["other"])
        clips = [clip_from_wire(c) for c in req["clips"]]
        want = 1 if req["kind"] == "open" else 2
        if len(clips) != want:
            raise BadInput(f"an {req['kind']} question needs {want} motion(s), got {len(clips)}", field="clips")
        if kind == "person":
            answer = self.ask_person(req, other)
        elif other.params.behaviour == "silent":  # fault injection: a bounded wait, then no answer
            threading.Event().wait(min(req["timeout"], 600.0))
            raise Unavailable(f"{req['other']} did not answer within {req['timeout']:g} s", other=req["other"])
        else:
            with self.lock_of(f"other:{req['other']}"):
                answer = other.answer_open(clips[0]) if want == 1 else other.answer_compare(*clips)
                self.store.save_other(req["other"], durable=False)  # its question counter moved
        self.publish("answered", {"other": req["other"], "kind": req["kind"], "answer": answer})
        return {"other": req["other"], "answer": answer}

    def ask_person(self, req, other: PersonOther) -> str:
        qid = uuid.uuid4().hex[:12]
        accepted = list(COMPARISONS) if req["kind"] == "compare" else list(WORDS[other.d])
        entry = {"question": qid, "other": req["other"], "kind": req["kind"], "text": req["text"],
                 "clips": req["clips"], "accepted": accepted, "event": threading.Event(), "answer": None}
        with self.pending_guard:
            self.pending[qid] = entry
        try:
            if not entry["event"].wait(req["timeout"]):
                raise Unavailable(f"{req['other']} (a person) did not answer within {req['timeout']:g} s "
                                  "(answer with `mirrorcoach other answer`)", other=req["other"])
        finally:
            with self.pending_guard:
                self.pending.pop(qid, None)
        other.asked += 1
        self.store.save_other(req["other"], durable=False)
        return entry["answer"]

    def other_pending(self, req):
        with self.pending_guard:
            rows = [e for e in self.pending.values() if req["other"] in (None, e["other"]) and e["answer"] is None]
            return {"questions": [{k: e[k] for k in ("question", "other", "kind", "text", "clips", "accepted")}
                                  for e in rows]}

    def other_answer(self, req):
        with self.pending_guard:
            e = self.pending.get(req["question"])
            if e is None or e["answer"] is not None:
                raise NotFound(f"no self.pending question {req['question']!r} (answered, timed out or never asked)",
                               question=req["question"])
            _, other = self.store.other(e["other"])
            d = getattr(other, "d", 4)
            e["answer"] = parse_answer(req["answer"], e["kind"], d)
            e["event"].set()
            return {"question": req["question"], "answer": e["answer"]}

    def other_reveal(self, req):
        kind, other = self.store.other(req["other"])
        r = other.reveal()
        return {"other": req["other"], "kind": kind, "asked": int(r.pop("asked")),
                "params": {k: v for k, v in r.items() if k != "name"}}

    # ------------------------------------------------------------------ learners
    def learner_create(self, req):
        target = clip_from_wire(req["target"])
        params = population(req["index"] + 1, req["population_seed"], req["family"], req["replicate"])[req["index"]]
        if req["params"]:
            merged = {**asdict(params), **{k: v for k, v in req["params"].items() if v is not None}}
            params = LearnerParams(**merged)
        learner = SimulatedLearner(req["learner"], target, params)
        self.store.add_learner(req["learner"], learner, req["replace"])
        return {"learner": req["learner"], "channels": learner.channels}

    def learner_imitate(self, req):
        learner = self.store.learner(req["learner"])
        demo = clip_from_wire(req["demonstration"], learner.target.skeleton)
        with self.lock_of(f"learner:{req['learner']}"):
            attempts = learner.imitate(demo, req["adverb"])
            self.store.save_learner(req["learner"])
            trial, felt = learner.trials, learner.felt
        self.publish("imitated", {"learner": req["learner"], "trial": trial})
        return {"learner": req["learner"], "trial": trial,
                "attempts": [clip_to_wire(a, with_skeleton=False) for a in attempts],
                **({"felt": felt} if felt is not None else {})}

    def learner_reveal(self, req):
        r = self.store.learner(req["learner"]).reveal()
        return {"learner": req["learner"], "trials": int(r.pop("trials")), "error_deg": float(r.pop("error_deg")),
                "params": {k: v for k, v in r.items() if k != "name"}}

    def list_all(self, req):
        with self.store.lock:
            return {"others": [{"other": n, "kind": k} for n, (k, _) in sorted(self.store.others.items())],
                    "learners": [{"learner": n, "trials": lr.trials} for n, lr in sorted(self.store.learners.items())],
                    "damaged": [e.listed() for _, e in sorted(self.store.damaged.items())]}

    def delete(self, req):
        return {"deleted": self.store.delete(req["other"], req["learner"])}


    def handlers(self) -> dict:
        """The verbs of the contract and the methods that answer them."""
        return {"bodies": self.list_bodies, "perform": self.do_perform, "plant": self.do_plant,
                "regressor": self.do_regressor, "other_create": self.other_create, "other_ask": self.other_ask,
                "other_pending": self.other_pending, "other_answer": self.other_answer,
                "other_reveal": self.other_reveal, "learner_create": self.learner_create,
                "learner_imitate": self.learner_imitate, "learner_reveal": self.learner_reveal,
                "list": self.list_all, "delete": self.delete}

    def costs(self) -> dict:
        """The verbs whose memory cost is estimated before they run, and their estimates."""
        return {"perform": self.perform_cost, "other_ask": self.ask_cost, "plant": self.plant_cost}


def make_service(settings: Settings | None = None) -> Service:
    settings = settings or Settings()
    store = AgentStore(settings.data_dir("simulator"))
    svc = Service(contract.SERVICE, contract.ENDPOINTS, contract.EVENTS, settings=settings)
    handlers = SimulatorHandlers(store, svc.publish)
    svc.serve(handlers.handlers(), handlers.costs())
    svc.store = store
    svc.on_promote.append(store.reload)
    return svc

