"""Contract of the simulator service (``services/simulator``): MuJoCo bodies, simulated (or
human) *others* of chapter 3, simulated *learners* of chapters 4-6.

Keys: ``<prefix>/simulator/<verb>``; events on ``<prefix>/events/simulator/performed``.
"""

from __future__ import annotations

from schemas.base import AnyMap, Array, Bool, Endpoint, F, Float, Int, List, Map, MapOf, Message, Str
from schemas.common import CLIP, DAMAGED, name
from shared.errors import BadInput
from shared.estimation.symbols import COMPARISONS, RULES, WORDS

SERVICE = "simulator"

OTHER = name("name of the other agent")
LEARNER = name("name of the learner")
ADVERBS = ("a little more", "more", "much more", "more like this")
#: the learner families of shared/agents/learner.py (a test checks they agree)
FAMILIES = ("thesis", "error_based", "two_rate", "copy", "fixed_step")


def _body_or_skeleton(req: dict, path: str):
    """exactly one of body (a robot's name) and skeleton (to build a human body) is given."""
    if (req["body"] is None) == (req["skeleton"] is None):
        raise BadInput("perform: give exactly one of body (a robot's name) and skeleton (JSON of an ASF/BVH skeleton)",
                       field="body")


BODY_INFO = Map({"name": F(Str(max_len=128)), "kind": F(Str(choices=("robot", "human"))), "mass": F(Float(0.0), "kg"),
                 "channels": F(List(Str(max_len=64), max_len=1000), "motion channels the body needs"),
                 "n_bodies": F(Int(0)), "floating": F(Bool(), "free root (human bodies)"),
                 "feet": F(List(Str(max_len=128), max_len=1000), "bones whose points make the support area",
                           required=False),
                 "unmapped_bones": F(List(Str(max_len=128), max_len=1000),
                                     "unusual bones: a limb no person has, a tail or a prop (no segment's mass)", required=False),
                 "missing_segments": F(List(Str(max_len=64), max_len=100),
                                       "body segments the skeleton lacks (their mass spread over the rest)",
                                       required=False)})

BODIES = Endpoint(
    "bodies",
    Message("simulator.bodies", Map({})),
    Message("simulator.bodies.reply", Map({"robots": F(List(BODY_INFO, max_len=100), "the named robots")})),
    "The named robots; human bodies are built from a skeleton given to perform.",
)

PERFORM = Endpoint(
    "perform",
    Message("simulator.perform", Map({
        "body": F(Str(max_len=64), "a robot's name: self (2.4 kg) or other (4.8 kg)", required=False),
        "skeleton": F(Str(max_len=2_000_000), "skeleton JSON: build a human body from it", required=False),
        "mass": F(Float(0.1, 500.0), "body mass in kg (robots: their own by default; humans: 70)", required=False),
        "clip": F(CLIP, "the motion, with the body's joint channels"),
        "track": F(Bool(), "a human body also follows the motion in a simulation with a floor: the report's support "
                   "gains tracking_runs, the frames it needs a helping hand in (shared/bodies/tracking.py)",
                   required=False, default=False),
    }, checks=[_body_or_skeleton]), doc="inverse dynamics, centre of gravity and feasibility of a motion"),
    Message("simulator.perform.reply", Map({
        "clip": F(CLIP, "the motion with sensor channels tau.<joint> (N m) and cog.x|y|z (m)"),
        "report": F(AnyMap(), "feasibility: joint-limit violations, support, feasible"),
        "body": F(BODY_INFO),
    })),
    "Perform a motion with a body: torques by inverse dynamics, centre of gravity, feasibility report.",
)

JOINT = Str(choices=("shoulder_pitch", "shoulder_roll", "elbow", "knee"))

PLANT = Endpoint(
    "plant",
    Message("simulator.plant", Map({
        "skeleton": F(Str(max_len=2_000_000), "skeleton JSON: build a human body from it"),
        "mass": F(Float(0.1, 500.0), "body mass in kg (70 by default)", required=False),
        "clip": F(CLIP, "the motion whose feet are put down, with the body's joint channels"),
        "reference": F(CLIP, "the motion whose feet stand where this one's must (the target)"),
    }), doc="the motion's feet where the reference stands on them"),
    Message("simulator.plant.reply", Map({
        "clip": F(CLIP, "the motion, its root height and leg angles changed (same channels and frames)"),
        "changes": F(AnyMap(), "planted, stance_frames, root_height_change_m, leg_angle_change_deg, stance_error_m; "
                               "or planted false and why"),
    })),
    "Keep a motion's feet on the ground where the reference has them there, under the body as the reference's "
    "are, by the smallest change of the root's height and the legs' angles (footskate cleanup).",
)

REGRESSOR = Endpoint(
    "regressor",
    Message("simulator.regressor", Map({
        "clip": F(CLIP, "the motion, with the small humanoid's joint channels (degrees)"),
        "joints": F(List(JOINT, min_len=1, max_len=4), "the felt joints (rows of Y)"),
        "missing": F(List(JOINT, max_len=4), "joints the other lacks: the self holds them still", required=False,
                     default=list),
        "offsets": F(Bool(), "also the arm links' first moments off their lines (rule identification's bodies)",
                     required=False, default=False),
    })),
    Message("simulator.regressor.reply", Map({
        "names": F(List(Str(max_len=64), max_len=64), "the columns: physical components of a body like the self's"),
        "y": F(Array((None, None, None)), "Y (frames x joints x columns): tau = Y theta, theta_self = links 1"),
    })),
    "The self's body regressor of a motion (shared.estimation.body): torques linear in the body's parameters.",
)

OTHER_PARAMS = Map({
    "mass": F(Float(0.1, 500.0), "the other's body mass, kg", required=False, default=4.8),
    "rule": F(Str(choices=RULES), "its conversion rule F_conv (eq. 3.8, 3.13-3.16)", required=False, default="eq3.8"),
    "weights": F(List(Float(0.0, 100.0), min_len=1, max_len=4), "per-joint weights of the rule", required=False),
    "d": F(Int(2, 8), "density of its words (2, 4, 5, 6, 7 or 8)", required=False, default=4),
    "tau_max": F(Float(1e-6, 1e6), "its tau_MAX, N m", required=False, default=1.0),
    "g_max": F(Float(1e-6, 1e6), "top of the range F_div splits into d bins", required=False, default=1.0),
    "joints": F(List(Str(choices=("shoulder_pitch", "shoulder_roll", "elbow", "knee")), min_len=1, max_len=4),
                "joints whose torques it feels", required=False),
    "noise": F(Float(0.0, 1.0), "probability an answer is one bin off", required=False, default=0.0),
    "jnd": F(Float(0.0, 1.0), "just-noticeable difference of comparisons (relative)", required=False, default=0.05),
    "seed": F(Int(0, 2**32 - 1), "seed of its answer noise", required=False, default=0),
    "behaviour": F(Str(choices=("honest", "nonsense", "contradict", "silent")),
                   "fault injection for robustness tests", required=False, default="honest"),
    "body": F(AnyMap(), "how its body differs unevenly: lengths {upper, fore, thigh, shin} (m), shares {link: share "
                        "of the mass}, payload (kg in the hand), damping / friction {joint: N m s/rad / N m}, missing "
                        "[joints], stiffness {joint: N m/rad} with rest {joint: degrees}, armature {joint: kg m^2}, "
                        "fused {elbow or knee: degrees} (welded at that angle) (shared.bodies.robot.BodySpec)", required=False),
    "kind": F(Str(max_len=32), "the population kind it was drawn from, for reports", required=False, default=""),
    "gamma": F(Float(0.25, 4.0), "its own word boundaries: it words g_max (g / g_max)^gamma", required=False,
               default=1.0),
    "drift": F(Float(-0.05, 0.05), "its boundaries drift: g worded (1 + drift * questions asked) times as heavy",
               required=False, default=0.0),
    "dont_know": F(Float(0.0, 1.0), "probability it answers \"I don't know\"", required=False, default=0.0),
    "transmission": F(AnyMap(), "how its torques become what it feels: gear {joint: ratio}, efficiency, coupling "
                      "{'src>dst': c}, stribeck {joint: [F_c, F_s, v_s]}, fatigue per question "
                      "(shared.agents.other.transmitted)", required=False),
})

OTHER_CREATE = Endpoint(
    "other_create",
    Message("simulator.other_create", Map({
        "other": OTHER,
        "kind": F(Str(choices=("simulated", "person")), "a simulated agent, or a person answering through the CLI",
                  required=False, default="simulated"),
        "params": F(OTHER_PARAMS, "hidden parameters (a person's: only d is used)", required=False, default=dict),
        "replace": F(Bool(), required=False, default=False),
    })),
    Message("simulator.other_create.reply", Map({"other": OTHER, "kind": F(Str(max_len=16))})),
    "Create an other agent with hidden parameters (or a person's seat).",
)

OTHER_ASK = Endpoint(
    "other_ask",
    Message("simulator.other_ask", Map({
        "other": OTHER,
        "kind": F(Str(choices=("open", "compare")), "open: a word; compare: which of two motions felt heavier"),
        "clips": F(List(CLIP, min_len=1, max_len=2), "one motion (open) or two (compare)"),
        "text": F(Str(max_len=500), "the question as worded by the asker", required=False, default=""),
        "timeout": F(Float(1.0, 3600.0), "seconds to wait for a person's answer", required=False, default=300.0),
    })),
    Message("simulator.other_ask.reply", Map({
        "other": OTHER,
        "answer": F(Str(max_len=64), "a word of Table 3.1 (open) or >, <, equal (compare)"),
    })),
    "Ask an other an open or a comparative question about motions it performs with its own body.",
    waits=True,
)

QUESTION = Map({"question": F(Str(max_len=64)), "other": OTHER, "kind": F(Str(choices=("open", "compare"))),
                "text": F(Str(max_len=500)), "clips": F(List(CLIP, max_len=2)),
                "accepted": F(List(Str(max_len=64), max_len=20), "answers that will be accepted")})

OTHER_PENDING = Endpoint(
    "other_pending",
    Message("simulator.other_pending", Map({"other": F(Str(max_len=64), "only this other's questions", required=False)})),
    Message("simulator.other_pending.reply", Map({"questions": F(List(QUESTION, max_len=1000))})),
    "Questions waiting for a person's answer.",
)

OTHER_ANSWER = Endpoint(
    "other_answer",
    Message("simulator.other_answer", Map({"question": F(Str(max_len=64)), "answer": F(Str(max_len=64))})),
    Message("simulator.other_answer.reply", Map({"question": F(Str(max_len=64)), "answer": F(Str(max_len=64))})),
    "A person answers a pending question.",
)

OTHER_REVEAL = Endpoint(
    "other_reveal",
    Message("simulator.other_reveal", Map({"other": OTHER})),
    Message("simulator.other_reveal.reply", Map({"other": OTHER, "kind": F(Str(max_len=16)), "asked": F(Int(0)),
                                                 "params": F(AnyMap(), "the hidden parameters")})),
    "For evaluation only: an other's hidden parameters.",
)

LEARNER_PARAMS = Map({
    "gain": F(Float(0.0, 1.0), required=False), "threshold": F(Float(0.0, 90.0), required=False),
    "overshoot": F(Float(0.0, 5.0), required=False), "noise": F(Float(0.0, 30.0), required=False),
    "tempo": F(Float(0.5, 2.0), required=False), "adverb_sensitivity": F(Float(0.0, 5.0), required=False),
    "deviation": F(MapOf(Str(choices=("arms", "legs", "trunk")),
                         Map({"scale": F(Float(0.0, 3.0), "of the learner's range of motion"),
                              "offset": F(Float(-90.0, 90.0), "degrees added to the joint angles")}), max_len=3),
                   "body part -> {scale, offset}", required=False),
    "seed": F(Int(0, 2**32 - 1), required=False),
    "family": F(Str(choices=FAMILIES), "the learner's rules (shared/agents/learner.py)", required=False),
    "retention": F(Float(0.0, 1.0), "error_based: A, the share of the learnt change kept per trial", required=False),
    "step": F(Float(0.0, 90.0), "fixed_step: degrees RMS moved per trial", required=False),
    "adverb_response": F(Float(-3.0, 3.0), "error_based: r, a word's effect on the error taken up (< 0: less)",
                         required=False),
    "strength": F(Float(0.1, 100.0), "effort its body can give, in multiples of the target's (thesis 6.5.1); "
                  "absent: unlimited", required=False),
})

LEARNER_CREATE = Endpoint(
    "learner_create",
    Message("simulator.learner_create", Map({
        "learner": LEARNER,
        "target": F(CLIP, "the motion to be learnt"),
        "population_seed": F(Int(0, 2**32 - 1), "which seeded population", required=False, default=0),
        "index": F(Int(0, 9999), "which learner of it", required=False, default=0),
        "family": F(Str(choices=FAMILIES), "the learner family (shared/agents/learner.py)", required=False,
                    default="thesis"),
        "replicate": F(Int(0, 2**31 - 1), "0: the population's motor noise; k > 0: the same learner with fresh noise",
                       required=False, default=0),
        "params": F(LEARNER_PARAMS, "override the drawn parameters", required=False),
        "replace": F(Bool(), required=False, default=False),
    })),
    Message("simulator.learner_create.reply", Map({"learner": LEARNER, "channels": F(List(Str(max_len=64), max_len=1000))})),
    "Create a simulated learner of a target motion (drawn from a seeded population).",
)

LEARNER_IMITATE = Endpoint(
    "learner_imitate",
    Message("simulator.learner_imitate", Map({
        "learner": LEARNER,
        "demonstration": F(CLIP, "the motion shown (target or emphatic motion)"),
        "adverb": F(Str(choices=ADVERBS), "the adverb said with it", required=False),
    })),
    Message("simulator.learner_imitate.reply", Map({
        "learner": LEARNER, "trial": F(Int(1)),
        "attempts": F(List(CLIP, min_len=1, max_len=20), "the next attempt: 5 repetitions"),
        "felt": F(Int(1, 4), "how heavy the demonstration felt, a word 1..4 (learners with a strength only; "
                  "shared/coaching/effort.py)", required=False),
    })),
    "The learner watches a demonstration and answers with its next attempt (5 repetitions).",
)

LEARNER_REVEAL = Endpoint(
    "learner_reveal",
    Message("simulator.learner_reveal", Map({"learner": LEARNER})),
    Message("simulator.learner_reveal.reply", Map({"learner": LEARNER, "trials": F(Int(0)),
                                                   "error_deg": F(Float(0.0), "true RMS error of its motor memory"),
                                                   "params": F(AnyMap())})),
    "For evaluation only: a learner's parameters and true error.",
)

LIST = Endpoint(
    "list",
    Message("simulator.list", Map({})),
    Message("simulator.list.reply", Map({
        "others": F(List(Map({"other": OTHER, "kind": F(Str(max_len=16))}), max_len=10_000)),
        "learners": F(List(Map({"learner": LEARNER, "trials": F(Int(0))}), max_len=10_000)),
        "damaged": DAMAGED,
    })),
    "Every other and learner.",
)

DELETE = Endpoint(
    "delete",
    Message("simulator.delete", Map({"other": F(Str(max_len=64), required=False),
                                     "learner": F(Str(max_len=64), required=False)})),
    Message("simulator.delete.reply", Map({"deleted": F(Str(max_len=64))})),
    "Delete an other or a learner.",
)

ENDPOINTS = {e.verb: e for e in (BODIES, PERFORM, PLANT, REGRESSOR, OTHER_CREATE, OTHER_ASK, OTHER_PENDING, OTHER_ANSWER, OTHER_REVEAL,
                                 LEARNER_CREATE, LEARNER_IMITATE, LEARNER_REVEAL, LIST, DELETE)}

EVENTS = {
    "performed": Message("simulator.event.performed", Map({
        "body": F(Str(max_len=128)), "frames": F(Int(0)),
        "feasible": F(Bool(), "true only when something was checked and nothing failed"),
        "checked": F(Bool(), "false: the body offered nothing to check (no joint limits, no feet)", required=False,
                     default=True),
    }), doc="published on <prefix>/events/simulator/performed after every perform"),
    "answered": Message("simulator.event.answered", Map({
        "other": OTHER, "kind": F(Str(max_len=16)), "answer": F(Str(max_len=64)),
    }), doc="published when an other answers"),
    "imitated": Message("simulator.event.imitated", Map({"learner": LEARNER, "trial": F(Int(1))})),
}

ACCEPTED = {"compare": list(COMPARISONS), **{f"open:{d}": list(w) for d, w in WORDS.items()}}
