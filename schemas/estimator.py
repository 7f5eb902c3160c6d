"""Contract of the estimator service (``services/estimator``): per other, the estimated
database and space (built by pss), conversation sets, estimates, rule identification.

Keys: ``<prefix>/estimator/<verb>``; progress on ``<prefix>/events/estimator/progress``.
"""

from __future__ import annotations

from schemas.base import AnyMap, Bool, Endpoint, F, Float, Int, List, Map, MapOf, Message, Str
from schemas.common import CLIP, DAMAGED, name

SERVICE = "estimator"
ESTIMATE = name("estimate id (one per other being estimated)")
JOINT = Str(choices=("shoulder_pitch", "shoulder_roll", "elbow", "knee"))

INFO = Map({
    "estimate": ESTIMATE, "other": F(Str(max_len=64)),
    "language": F(AnyMap(), "d, g_max, tau_max, joints, rule, weights"),
    "sets_done": F(Int(0), "completed conversation sets"),
    "scale": F(Float(0.0), "interval estimator: S_other ~ scale * S_self"),
    "scale_low": F(Float(0.0), "lowest scale every answer allows"),
    "scale_high": F(Float(0.0), "highest scale every answer allows (absent: unbounded)", required=False),
    "consistent": F(Bool(), "whether every answer so far can be true together"),
    "answers": F(Int(0), "answers used by the interval estimator"),
    "probes_asked": F(Int(0), "probe questions asked"),
    "dont_know": F(Int(0), "questions the other answered \"I don't know\" (unanswered, not a stop)", required=False,
                   default=0),
    "last_set": F(AnyMap(), "k_other, k_self and ratio per shared motion of the last set", required=False),
    "notes": F(List(Str(max_len=1000), max_len=10_000), "rule identification, stops"),
    "body": F(AnyMap(), "the body estimate: columns of the self's regressor, theta, the proportional "
                        "scale it is nearest to, answers fitted, model (rigid, or extended: springs and rotor "
                        "inertia)", required=False),
})

START = Endpoint(
    "start",
    Message("estimator.start", Map({
        "estimate": ESTIMATE, "other": F(Str(max_len=64), "the other to talk to (simulator name)"),
        "d": F(Int(2, 8), "density of the words", required=False, default=4),
        "g_max": F(Float(1e-6, 1e6), "top of the g range split into d bins (shared language)", required=False, default=0.6),
        "tau_max": F(Float(1e-6, 1e6), "tau_MAX of eq. 3.8", required=False, default=1.0),
        "joints": F(List(JOINT, min_len=1, max_len=4), "joints whose torques are estimated", required=False),
        "rule": F(Str(choices=("eq3.8", "f1", "f2", "f3", "f4")), "the rule the self assumes", required=False,
                  default="eq3.8"),
        "probes": F(Int(0, 20), "probe motions asked per set, chosen where the body estimate is least sure "
                                "(true: 4, false: 0)", required=False, default=4),
        "missing": F(List(JOINT, max_len=3), "joints the other lacks (seen when it imitates); the self holds "
                                             "them still", required=False, default=list),
        "replace": F(Bool(), required=False, default=False),
    })),
    Message("estimator.start.reply", INFO),
    "Start estimating an other: D_other_hat = D_self, build P_other_hat (step 1).",
)

CONVERSE = Endpoint(
    "converse",
    Message("estimator.converse", Map({
        "estimate": ESTIMATE, "sets": F(Int(1, 50), "how many conversation sets", required=False, default=1),
        "timeout": F(Float(1.0, 3600.0), "seconds to wait for each answer", required=False, default=120.0),
    })),
    Message("estimator.converse.reply", Map({
        "info": F(INFO), "completed": F(Int(0), "sets completed by this request"),
        "stopped": F(Str(max_len=1000), "why the conversation stopped early (a silent or senseless other; never "
                     "contradiction alone)", required=False),
        "model": F(AnyMap(), "how far the answers agree with the estimated body: agreement, repeat_disagreement, "
                   "misfits, p, outside (the other is beyond what the self can model), a verdict sentence and the "
                   "body estimate's residual correction (active, amplitude, length, drift, evidence)",
                   required=False),
    })),
    "Run conversation sets (eq. 3.2-3.6); each completed set is saved before the next starts.",
    waits=True,
)

METHOD = F(Str(choices=("thesis", "space", "interval", "body")), "thesis: eq. 3.5 through the space; space: the same "
           "with the words' bins and every motion talked about in the space; interval: one torque scale; body: the "
           "regressor on the estimated body", required=False, default="thesis")
ESTIMATED = {
    "clip": F(CLIP, "the motion with the estimated torques tau.<joint> as sensor channels"),
    "g": F(Float(0.0), "F_conv of the estimate"), "k": F(Int(1, 8)), "word": F(Str(max_len=64)),
}
ESTIMATE_EP = Endpoint(
    "estimate",
    Message("estimator.estimate", Map({
        "estimate": ESTIMATE, "clip": F(CLIP, "any motion of the joints, known or not"), "method": METHOD,
    })),
    Message("estimator.estimate.reply", Map({"estimate": ESTIMATE, "method": F(Str(max_len=16)), **ESTIMATED})),
    "The other's estimated torques for a motion.",
)

ESTIMATE_MANY = Endpoint(
    "estimate_many",
    Message("estimator.estimate_many", Map({
        "estimate": ESTIMATE, "clips": F(List(CLIP, min_len=1, max_len=64), "motions of the joints, known or not"),
        "method": METHOD,
    })),
    Message("estimator.estimate_many.reply", Map({
        "estimate": ESTIMATE, "method": F(Str(max_len=16)),
        "estimates": F(List(Map(ESTIMATED), max_len=64), "one per motion, in the request's order"),
    })),
    "The other's estimated torques for several motions in one request (an evaluation asks dozens).",
)

IDENTIFY = Endpoint(
    "identify_rule",
    Message("estimator.identify_rule", Map({
        "estimate": ESTIMATE,
        "candidates": F(Str(choices=("thesis", "weighted")), "f1-f4, or f1-f4 with joint weights (12)",
                        required=False, default="thesis"),
        "method": F(Str(choices=("auto", "thesis")), "auto: pairs chosen on the estimated body, answers weighed "
                    "against noise; thesis: its m1/m2, m3/m4", required=False, default="auto"),
        "noise": F(Float(0.0, 0.5), "auto: the share of comparisons the self allows to be wrong (default: weighed "
                   "over levels from 5 % to answering at random)", required=False),
        "confidence": F(Float(0.5, 0.9999), "auto: stop when one rule holds this share of the posterior",
                        required=False, default=0.999),
        "jnd": F(Float(0.0, 1.0), "the just-noticeable difference assumed", required=False, default=0.05),
        "apply": F(Bool(), "use the identified rule in later conversation sets", required=False, default=True),
        "timeout": F(Float(1.0, 3600.0), required=False, default=120.0),
    })),
    Message("estimator.identify_rule.reply", Map({
        "estimate": ESTIMATE, "rule": F(Str(max_len=64), "the identified rule", required=False),
        "questions": F(List(AnyMap(), max_len=100), "pair asked and answer, in order"),
        "reason": F(Str(max_len=1000)), "design": F(AnyMap(), "m1-m4 design report (thesis method)", required=False),
        "posterior": F(MapOf(Str(max_len=64), Float(0.0, 1.0)), "auto: each candidate rule's share of the posterior", required=False),
    })),
    "Identify the other's conversion rule by comparative questions (3.4).",
    waits=True,
)

INFO_EP = Endpoint("info", Message("estimator.info", Map({"estimate": ESTIMATE})), Message("estimator.info.reply", INFO),
                   "An estimate's state.")
LIST = Endpoint("list", Message("estimator.list", Map({})),
                Message("estimator.list.reply", Map({"estimates": F(List(Map({"estimate": ESTIMATE, "other": F(Str(max_len=64)),
                                                                               "sets_done": F(Int(0))}), max_len=10_000)),
                                                                     "damaged": DAMAGED})),
                "Every estimate (and those whose files cannot be read back, in damaged).")
DELETE = Endpoint("delete", Message("estimator.delete", Map({"estimate": ESTIMATE})),
                  Message("estimator.delete.reply", Map({"estimate": ESTIMATE, "deleted": F(Bool())})), "Delete an estimate.")

ENDPOINTS = {e.verb: e for e in (START, CONVERSE, ESTIMATE_EP, ESTIMATE_MANY, IDENTIFY, INFO_EP, LIST, DELETE)}
EVENTS = {"progress": Message("estimator.event.progress", Map({
    "estimate": ESTIMATE, "set": F(Int(1)), "scale": F(Float(0.0)), "consistent": F(Bool()),
    "k_other": F(List(Int(1, 8), max_len=100)), "k_self": F(List(Int(1, 8), max_len=100)),
}), doc="after every completed conversation set")}
