"""The coach service as a real process (with pss and the simulator): contract, bad attempts,
and a crash in the middle of a session."""

from __future__ import annotations

import time

import numpy as np
import pytest

from schemas import coach as contract
from schemas.common import clip_to_wire
from tests.conftest import assert_refused, kill_during, state_files


@pytest.fixture(scope="module")
def clips(bundled):
    from shared.io import load_clip

    squat = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc")
    other = [load_clip(bundled / f"amc/squat1Reps/HDM_bk_squat1Reps_01{i}_120.amc") for i in (3, 4)]
    kick = load_clip(bundled / "amc/kickLFront1Reps/HDM_bd_kickLFront1Reps_001_120.amc")
    return squat, other, kick


def _ok(ep, reply):
    return ep.reply.validate(reply)


def test_every_coach_verb_answers_within_its_contract(coach_services, client_of, clips):
    env, _ = coach_services
    c = client_of(env)
    squat, other, kick = clips
    events = []
    c.subscribe("events/coach/trial", lambda k, m: events.append(m))
    time.sleep(0.3)
    info = _ok(contract.START, c.request("coach", "start", {"session": "sim", "target": clip_to_wire(squat), "learner": "l0",
                                                            "index": 3, "policy": {"alpha": 2.0, "adverb": "table"}}))
    assert info["trials"] == [] and info["learner"] == "l0" and info["check"] is True
    run = _ok(contract.RUN, c.request("coach", "run", {"session": "sim", "trials": 3}))
    assert [t["number"] for t in run["trials"]] == [1, 2, 3] and run["R"][0] == 1.0 and run["R"][-1] < 1.0
    assert all(0 <= t["alpha_shown"] <= t["alpha"] == 2.0 for t in run["trials"])
    assert _ok(contract.STATE, c.request("coach", "state", {"session": "sim"}))["trials"] == run["trials"]
    deadline = time.monotonic() + 5
    while len(events) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [e["trial"] for e in events] == [1, 2, 3]

    # a person's session on a proto-symbol of a space: SPACE:LABEL
    c.request("pss", "build", {"space": "moves", "clips": [clip_to_wire(squat), clip_to_wire(kick)]})
    _ok(contract.START, c.request("coach", "start", {"session": "me", "target_space": "moves",
                                                     "target_label": "squat1Reps", "policy": {"adverb": "table"}}))
    t = _ok(contract.ATTEMPT, c.request("coach", "attempt", {"session": "me", "clips": [clip_to_wire(x) for x in other]}))
    assert t["trial"] == 1 and t["d_p"] > 0 and t["emphatic"]["channels"] == squat.channels and t["adverb"] in (
        None, "a little more", "more", "much more")
    assert t["emphatic"].get("skeleton"), t["feasibility"]  # repaired or not, a motion a viewer can play as BVH
    fits = {
        "aeu1": {"first_trial_dp": [10.0, 20.0, 30.0]},
        "emu1c": {"simulated_coach": {"n": 50, "alpha": 1.5, "seed": 2}},
        "emu2": {"sweep": {"a": {"1.5": 0.4, "2.0": 0.3}, "b": {"1.25": 0.2, "2.5": 0.5}}},
        "nb": {"features": [[10, 1], [11, 1], [30, 3], [31, 3]], "labels": ["more", "more", "much more", "much more"]},
    }
    for kind, data in fits.items():
        r = _ok(contract.POLICY_FIT, c.request("coach", "policy_fit", {"kind": kind, **data}))
        assert r["policy"]["kind"] == kind
    emu2 = c.request("coach", "policy_fit", {"kind": "emu2", **fits["emu2"]})["policy"]
    assert emu2["per_learner"] == {"a": 2.0, "b": 1.25}
    listed = _ok(contract.LIST, c.request("coach", "list"))["sessions"]
    assert {s["session"] for s in listed} >= {"sim", "me"}
    assert _ok(contract.DELETE, c.request("coach", "delete", {"session": "me"}))["deleted"]


def test_bad_attempts_get_clear_errors_and_leave_the_session_unchanged(coach_services, client_of, clips):
    env, procs = coach_services
    c = client_of(env)
    squat, other, kick = clips
    c.request("coach", "start", {"session": "p", "target": clip_to_wire(squat), "replace": True})
    c.request("coach", "attempt", {"session": "p", "clips": [clip_to_wire(other[0])]})
    before = c.request("coach", "state", {"session": "p"})
    w = clip_to_wire(other[0])
    robot = {"name": "r", "fps": 30.0, "channels": ["shoulder_pitch", "elbow"], "data": np.zeros((40, 2))}
    nan = dict(w, data=np.where(np.arange(w["data"].size).reshape(w["data"].shape) == 5, np.nan, w["data"]))
    cases = [
        ("wrong skeleton (other channels)", "attempt", {"session": "p", "clips": [robot]}, "bad_request"),
        ("too few frames", "attempt", {"session": "p", "clips": [dict(w, data=w["data"][:6])]}, "bad_request"),
        ("NaN", "attempt", {"session": "p", "clips": [nan]}, "bad_request"),
        ("no clips", "attempt", {"session": "p", "clips": []}, "bad_request"),
        ("unknown session", "attempt", {"session": "nope", "clips": [w]}, "not_found"),
        ("run a person's session", "run", {"session": "p"}, "bad_request"),
        ("start without a target", "start", {"session": "x"}, "bad_request"),
        ("existing session", "start", {"session": "p", "target": w}, "conflict"),
        ("unknown proto-symbol", "start", {"session": "y", "target_space": "moves2", "target_label": "z"}, "not_found"),
        ("bad alpha", "start", {"session": "z", "target": w, "policy": {"alpha": 9.0}}, "bad_request"),
        ("EMU-2 without a sweep", "policy_fit", {"kind": "emu2"}, "bad_request"),
        ("naive Bayes with one label", "policy_fit", {"kind": "nb", "features": [[1, 1], [2, 2]], "labels": ["more", "more"]},
         "bad_request"),
        ("session name with /", "state", {"session": "a/b"}, "bad_request"),
        ("a NaN target with a new learner", "start", {"session": "nanl", "target": nan, "learner": "fresh"}, "bad_request"),
        # unbounded work (the coach grew to 2.6 GB)
        ("a simulated coach of 10**9 demonstrations", "policy_fit", {"kind": "emu1", "simulated_coach": {"n": 10**9}},
         "bad_request"),
        ("a simulated coach with an unknown field", "policy_fit", {"kind": "emu1", "simulated_coach": {"m": 3}},
         "bad_request"),
        # accepted input that broke a session for good
        ("a per-learner alpha that is text", "start",
         {"session": "pl", "target": w, "policy": {"kind": "emu2", "per_learner": {"l2": "x"}}}, "bad_request"),
        ("naive Bayes parameters of the wrong shape", "start",
         {"session": "nbx", "target": w, "policy": {"kind": "nb", "nb": {"classes": 5}}}, "bad_request"),
        ("naive Bayes priors that do not sum to 1", "start",
         {"session": "nby", "target": w, "policy": {"kind": "nb", "nb": {
             "classes": ["more", "much more"], "theta": [[1, 1], [2, 2]], "var": [[1, 1], [1, 1]], "prior": [0.9, 0.9]}}},
         "bad_request"),
        ("sweep alphas that are not numbers", "policy_fit", {"kind": "emu2", "sweep": {"l": {"fast": 1.0}}}, "bad_request"),
    ]
    files = state_files(env)
    assert_refused(c, procs, [(name, "coach", verb, msg, code) for name, verb, msg, code in cases])
    assert c.request("coach", "state", {"session": "p"}) == before
    # a refused request leaves every state file byte-identical (the session's
    # space: no proto-symbol of a NaN attempt) and creates no learner
    assert state_files(env) == files
    assert "fresh" not in {x["learner"] for x in c.request("simulator", "list", {})["learners"]}



def test_killing_the_coach_mid_session_loses_no_completed_trial(coach_services, client_of, clips):
    env, procs = coach_services
    c = client_of(env)
    squat = clips[0]
    c.request("coach", "start", {"session": "k", "target": clip_to_wire(squat), "learner": "lk", "index": 1,
                                 "replace": True})
    done = []
    c.subscribe("events/coach/trial", lambda k, m: done.append(m["trial"]) if m["session"] == "k" else None)
    time.sleep(0.3)
    err = kill_during(env, procs, "coach", "services.coach",
                      lambda c2: c2.request("coach", "run", {"session": "k", "trials": 30}, timeout=600),
                      lambda: len(done) >= 2)
    assert getattr(err, "code", "") == "unavailable"
    reported = max(done)
    state = c.request("coach", "state", {"session": "k"})
    assert len(state["trials"]) >= reported
    r = c.request("coach", "run", {"session": "k", "trials": 1})  # and it goes on
    assert len(r["trials"]) == len(state["trials"]) + 1


def test_sessions_never_take_what_is_anothers(coach_services, client_of, clips):
    """A second session with the same learner name reset the first one's
    learner, and `coach start --session mine` replaced the user's own space `coach-mine`."""
    from shared.bus.client import RemoteError

    env, procs = coach_services
    c = client_of(env)
    squat, other, kick = clips
    c.request("coach", "start", {"session": "first", "target": clip_to_wire(squat), "learner": "lena", "replace": True})
    c.request("coach", "run", {"session": "first"})
    learners = lambda: {x["learner"]: x["trials"] for x in c.request("simulator", "list")["learners"]}  # noqa: E731
    before, trained = c.request("coach", "state", {"session": "first"}), learners()["lena"]
    c.request("pss", "build", {"space": "coach-mine", "clips": [clip_to_wire(kick)], "replace": True})
    files = state_files(env)
    with pytest.raises(RemoteError) as e:
        c.request("coach", "start", {"session": "second", "target": clip_to_wire(squat), "learner": "lena"})
    assert e.value.code == "conflict" and "'first'" in e.value.message, e.value.message
    with pytest.raises(RemoteError) as e:
        c.request("coach", "start", {"session": "mine", "target": clip_to_wire(squat)})
    assert e.value.code == "conflict" and "coach-mine" in e.value.message, e.value.message
    c.request("simulator", "learner_create", {"learner": "solo", "target": clip_to_wire(squat), "replace": True})
    with pytest.raises(RemoteError) as e:
        c.request("coach", "start", {"session": "third", "target": clip_to_wire(squat), "learner": "solo"})
    assert e.value.code == "conflict" and "solo" in e.value.message, e.value.message
    c.request("simulator", "delete", {"learner": "solo"})
    assert state_files(env) == {k: v for k, v in files.items() if "solo" not in k}
    assert c.request("coach", "state", {"session": "first"}) == before and learners()["lena"] == trained
    # replacing one's own session keeps its name, space and learner; deleting it frees them
    c.request("coach", "start", {"session": "first", "target": clip_to_wire(squat), "learner": "lena", "replace": True})
    c.request("coach", "delete", {"session": "first"})
    assert "lena" not in learners()
    assert "coach-first" not in {x["space"] for x in c.request("pss", "list")["spaces"]}
    c.request("coach", "start", {"session": "second", "target": clip_to_wire(squat), "learner": "lena"})
    c.request("coach", "delete", {"session": "second"})
