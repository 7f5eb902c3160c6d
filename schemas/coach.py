"""Contract of the coach service (``services/coach``): coaching sessions and their policies.

Keys: ``<prefix>/coach/<verb>``; every trial is published on ``<prefix>/events/coach/trial``.
"""

from __future__ import annotations

from schemas.base import AnyMap, Bool, Endpoint, F, Float, Int, List, Map, MapOf, Message, Str
from schemas.common import CLIP, DAMAGED, name
from schemas.simulator import FAMILIES, LEARNER_PARAMS
from shared.errors import BadInput

SERVICE = "coach"
SESSION = name("session id")
ADVERB = Str(choices=("a little more", "more", "much more", "more like this", "table"))
ADVERB_WORD = Str(choices=("a little more", "more", "much more", "more like this"))



def _nb_consistent(m: dict, path: str) -> None:
    """theta, var and prior have one row per class, two columns (d_p, d_cop); priors sum to 1."""
    k = len(m["classes"])
    if len(set(m["classes"])) != k:
        raise BadInput(f"{path}.classes: the classes must differ", field=f"{path}.classes")
    for key in ("theta", "var", "prior"):
        if len(m[key]) != k:
            raise BadInput(f"{path}.{key}: one entry per class ({k}), got {len(m[key])}", field=f"{path}.{key}")
    if abs(sum(m["prior"]) - 1.0) > 1e-6:
        raise BadInput(f"{path}.prior must sum to 1, got {sum(m['prior']):.6g}", field=f"{path}.prior")


#: the parameters of a GaussianNB over (d_p, d_cop), as policy_fit returns them (eq. 6.6)
NB = Map({
    "classes": F(List(ADVERB_WORD, min_len=2, max_len=8), "the adverbs it chooses among"),
    "theta": F(List(List(Float(-1e9, 1e9), min_len=2, max_len=2), min_len=2, max_len=8), "per class: mean d_p, d_cop"),
    "var": F(List(List(Float(1e-12, 1e18), min_len=2, max_len=2), min_len=2, max_len=8), "per class: variances"),
    "prior": F(List(Float(0.0, 1.0), min_len=2, max_len=8), "P(V) per class"),
}, checks=[_nb_consistent])

POLICY = Map({
    "kind": F(Str(choices=("fixed", "aeu1", "aeu2", "emu1", "emu1c", "emu2", "nb")), "which model", required=False,
              default="fixed"),
    "alpha": F(Float(0.0, 5.0), "emphasis alpha (eq. 4.3)", required=False, default=2.0),
    "adverb": F(ADVERB, "none, a fixed adverb, or 'table' (Table 4.1 for the alpha)", required=False),
    "calibration": F(Float(1e-9, 1e9), "AEU: thesis distance units per ours", required=False, default=1.0),
    "thresholds": F(List(Float(0.0), max_len=2), "AEU: the two d_p thresholds in our units, fitted from human "
                    "coaches (`study aeu`); replaces the thesis's thresholds and the calibration", required=False),
    "per_learner": F(MapOf(Str(max_len=64), Float(0.0, 5.0), max_len=10_000), "EMU-2: learner -> alpha",
                     required=False, default=dict),
    "nb": F(NB, "naive Bayes parameters (from policy_fit)", required=False),
    "body_part": F(Bool(), "emphasise the worst body part only", required=False, default=False),
    "subgoal": F(Bool(), "coach through sub-goals, worst body part first (thesis 4.6, 7.3)", required=False,
                 default=False),
    "effort": F(Bool(), "ask the learner how heavy each demonstration felt and keep the emphasis within what its "
                "body can give (thesis 6.5.1, chapter 3's interval estimator)", required=False, default=False),
})

TRIAL = Map({
    "session": SESSION, "trial": F(Int(1)),
    "d_p": F(Float(0.0), "|x_t - x_p| (eq. 4.4, HMM distance)"),
    "d_cop": F(Float(0.0), "HMM distance of the centre-of-gravity trajectories (6.5)", required=False),
    "alpha": F(Float(0.0), "the policy's alpha"), "alpha_shown": F(Float(0.0), "after the feasibility check"),
    "adverb": F(Str(max_len=32), "what the coach says", required=False),
    "feasible": F(Bool(), "whether the policy's alpha passed the simulator's check"),
    "alpha_reduced": F(Bool()), "feasibility": F(Str(max_len=1000)),
    "emphasis_kept": F(Float(0.0), "when the emphatic motion was made feasible (joint angles held at their limits, "
                       "the emphasis taken out where the balance fails): the RMS share of its difference from the "
                       "target kept", required=False),
    "part": F(Str(max_len=16), "the body part emphasised (body-part policy)", required=False),
    "goal": F(Str(max_len=64), "the proto-symbol emphasised towards: target, or a sub-goal", required=False),
    "felt": F(Int(1, 4), "the learner's word for the last demonstration's effort (effort policy)", required=False),
    "felt_predicted": F(Float(0.0), "the effort the learner is estimated to feel for the motion shown next, as a "
                        "share of its strength (effort policy, once it has answered)", required=False),
    "shares": F(AnyMap(), "share of the error per body part"),
    "emphatic": F(CLIP, "the motion to show next (the target when alpha is 0)"),
    "x_t": F(List(Float(), max_len=20)), "x_p": F(List(Float(), max_len=20)), "x_s": F(List(Float(), max_len=20)),
    "seconds": F(Float(0.0)),
})

INFO = Map({
    "session": SESSION, "target": F(Str(max_len=128)), "learner": F(Str(max_len=64), required=False),
    "mode": F(Str(max_len=16)), "check": F(Bool()),
    "policy": F(AnyMap()), "trials": F(List(AnyMap(), max_len=1000), "every trial so far"),
    "R": F(List(Float(0.0), max_len=1000), "d_l / d_1 (this learner's term of eq. 4.5)"),
})

START = Endpoint(
    "start",
    Message("coach.start", Map({
        "session": SESSION,
        "target": F(CLIP, "the target motion", required=False),
        "target_space": F(Str(max_len=64), "or: a pss space ...", required=False),
        "target_label": F(Str(max_len=64), "... and the proto-symbol (label or name) to take as target", required=False),
        "learner": F(Str(max_len=64), "a simulated learner (created if new); absent: a person sends attempts",
                     required=False),
        "population_seed": F(Int(0, 2**32 - 1), required=False, default=0),
        "index": F(Int(0, 9999), "which learner of the population", required=False, default=0),
        "family": F(Str(choices=FAMILIES), "the simulated learner's family (shared/agents/learner.py)",
                    required=False, default="thesis"),
        "replicate": F(Int(0, 2**31 - 1), "0: the population's motor noise; k > 0: fresh noise", required=False,
                       default=0),
        "learner_params": F(LEARNER_PARAMS, "override the drawn learner's parameters (sensitivity sweeps)",
                            required=False),
        "policy": F(POLICY, required=False, default=dict),
        "mode": F(Str(choices=("residual", "thesis")),
                  "residual: the emphasis applied to the real target; thesis: show F_gen(x_s) itself",
                  required=False, default="residual"),
        "check": F(Bool(), "check every emphatic motion on the simulator and lower alpha if infeasible",
                   required=False, default=True),
        "replace": F(Bool(), required=False, default=False),
    })),
    Message("coach.start.reply", INFO),
    "Start a coaching session on a target (a clip, or SPACE:LABEL) for a simulated learner or a person.",
)

ATTEMPT = Endpoint(
    "attempt",
    Message("coach.attempt", Map({"session": SESSION, "clips": F(List(CLIP, min_len=1, max_len=20),
                                                                 "the attempt: its repetitions (5 in the thesis)"),
                                  "felt": F(Int(1, 4), "how heavy the last demonstration felt to the learner, "
                                            "1 light .. 4 at the limit (effort policy)", required=False)})),
    Message("coach.attempt.reply", TRIAL),
    "One trial: recognise the attempt, choose alpha and adverb, generate and check the emphatic motion.",
)

RUN = Endpoint(
    "run",
    Message("coach.run", Map({"session": SESSION, "trials": F(Int(1, 50), required=False, default=4)})),
    Message("coach.run.reply", INFO),
    "Coach the session's simulated learner for a number of trials (the first shows the target).",
)

STATE = Endpoint("state", Message("coach.state", Map({"session": SESSION})), Message("coach.state.reply", INFO),
                 "A session and its trials.")

#: EMU-1 without observed data: the demonstrations of a simulated coach (policies.simulated_coach_demonstrations);
#: n is bounded (n = 10**9 grew the coach to 2.6 GB)
SIMULATED_COACH = Map({
    "n": F(Int(3, 10_000), "how many demonstrations", required=False, default=40),
    "alpha": F(Float(0.0, 5.0), "the coach's emphasis", required=False, default=1.8),
    "off_line": F(Float(0.0, 5.0), "relative error perpendicular to the line", required=False, default=0.35),
    "seed": F(Int(0, 2**32 - 1), required=False, default=0),
})

POLICY_FIT = Endpoint(
    "policy_fit",
    Message("coach.policy_fit", Map({
        "kind": F(Str(choices=("aeu1", "aeu2", "emu1", "emu1c", "emu2", "nb"))),
        "first_trial_dp": F(List(Float(0.0), max_len=100_000), "AEU: learners' first-trial d_p (calibration)",
                            required=False),
        "trial_dp": F(List(Float(0.0), max_len=100_000),
                      "AEU: the population's d_p over all trials; the scale that best separates them into the "
                      "three adverbs (replaces first_trial_dp)", required=False),
        "demonstrations": F(List(List(List(Float(), max_len=20), min_len=3, max_len=3), max_len=100_000),
                            "EMU-1: observed (x_t, x_p, x_s)", required=False),
        "simulated_coach": F(SIMULATED_COACH, "EMU-1 without data: a simulated coach's demonstrations",
                             required=False),
        "sweep": F(MapOf(Str(max_len=64), MapOf(Str(max_len=16), Float(0.0), min_len=1, max_len=32), max_len=10_000),
                   "EMU-2: learner -> {alpha: final error}", required=False),
        "features": F(List(List(Float(), min_len=2, max_len=2), max_len=100_000), "NB: (d_p, d_cop) rows",
                      required=False),
        "labels": F(List(Str(max_len=32), max_len=100_000), "NB: the adverb that worked best", required=False),
        "alpha": F(Float(0.0, 5.0), "the alpha the fitted policy uses where it does not choose one", required=False,
                   default=2.0),
    })),
    Message("coach.policy_fit.reply", Map({"policy": F(POLICY), "fit": F(AnyMap(), "what was fitted")})),
    "Fit a policy from data (EMU-1, EMU-2, AEU calibration, naive Bayes).",
)

LIST = Endpoint("list", Message("coach.list", Map({})),
                Message("coach.list.reply", Map({"sessions": F(List(Map({"session": SESSION, "trials": F(Int(0)),
                                                                         "learner": F(Str(max_len=64), required=False)}),
                                                                    max_len=100_000)),
                                                 "damaged": DAMAGED})),
                "Every session (and those whose files cannot be read back, in damaged).")
DELETE = Endpoint("delete", Message("coach.delete", Map({"session": SESSION})),
                  Message("coach.delete.reply", Map({"session": SESSION, "deleted": F(Bool())})), "Delete a session.")

ENDPOINTS = {e.verb: e for e in (START, ATTEMPT, RUN, STATE, POLICY_FIT, LIST, DELETE)}
EVENTS = {"trial": Message("coach.event.trial", Map({
    "session": SESSION, "trial": F(Int(1)), "d_p": F(Float(0.0)), "alpha": F(Float(0.0)),
    "adverb": F(Str(max_len=32), required=False), "x_t": F(List(Float(), max_len=20)),
    "x_p": F(List(Float(), max_len=20)), "x_s": F(List(Float(), max_len=20)), "learner": F(Str(max_len=64), required=False),
    "attempt": F(CLIP, "the attempt's first repetition (for the dashboard)", required=False),
    "emphatic": F(CLIP, "the motion shown next (for the dashboard)", required=False),
    "R": F(Float(0.0), "d_p over the first trial's d_p", required=False),
    "d_cop": F(Float(0.0), "centre-of-pressure distance to the target's, when measured", required=False),
    "alpha_chosen": F(Float(0.0), "the policy's alpha before the feasibility check", required=False),
    "alpha_reduced": F(Bool(), "the simulator found alpha_chosen infeasible", required=False),
    "feasibility": F(Str(max_len=1000), "the feasibility check's words", required=False),
}), doc="after every trial"),
    "session": Message("coach.event.session", Map({
        "session": SESSION, "learner": F(Str(max_len=64), required=False),
        "target": F(CLIP, "the target, with its skeleton (for the dashboard)"),
    }), doc="when a session starts")}
