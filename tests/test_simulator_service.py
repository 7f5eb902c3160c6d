"""Contract and bad-input tests of the real simulator service process (``schemas/simulator.py``)."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from schemas import simulator as contract
from schemas.common import clip_to_wire
from shared.bus.client import RemoteError
from shared.motion.clip import Clip
from tests.conftest import assert_refused, chain_skeleton, cycle_skeleton


def _robot_motion(amplitude=60.0, n=90):
    t = np.linspace(0, 3, n)
    data = np.column_stack([amplitude * (1 - np.cos(t)), 10 * np.sin(t), -30 - 20 * np.sin(2 * t), 20 * np.sin(t)])
    return Clip(data, ["shoulder_pitch", "shoulder_roll", "elbow", "knee"], 30.0, name=f"m{amplitude:g}")


@pytest.fixture(scope="module")
def squat(bundled):
    from shared.io import load_clip

    return load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc")


def _ok(endpoint, reply):
    return endpoint.reply.validate(reply)


def test_every_simulator_verb_answers_within_its_contract(simulator_service, client_of, squat):
    env, _ = simulator_service
    c = client_of(env)
    robots = _ok(contract.BODIES, c.request("simulator", "bodies"))["robots"]
    assert {r["name"]: r["mass"] for r in robots} == pytest.approx({"self": 2.4, "other": 4.8})

    # perform: robots and a human body from a skeleton
    m = clip_to_wire(_robot_motion())
    r_self = _ok(contract.PERFORM, c.request("simulator", "perform", {"body": "self", "clip": m}))
    r_other = _ok(contract.PERFORM, c.request("simulator", "perform", {"body": "other", "clip": m}))
    i = r_self["clip"]["channels"].index("tau.elbow")
    np.testing.assert_allclose(r_other["clip"]["data"][:, i], 2 * r_self["clip"]["data"][:, i], rtol=1e-9, atol=1e-12)
    assert r_self["clip"]["sensor"][-3:] == ["cog.x", "cog.y", "cog.z"]
    h = _ok(contract.PERFORM, c.request("simulator", "perform", {"skeleton": squat.skeleton.to_json(), "mass": 80.0,
                                                                "clip": clip_to_wire(squat, with_skeleton=False),
                                                                "track": True}))
    assert h["body"]["kind"] == "human" and h["body"]["mass"] == pytest.approx(80.0, rel=1e-3)
    assert h["report"]["support"]["checked"] and "joint_limit_violations" in h["report"]
    # the simulated test, asked for: the squat followed on a floor, the frames it needed a hand in said
    s = h["report"]["support"]
    assert s["tracking_checked"] and 0 <= s["frames_tracking_helped"] <= squat.n_frames and s["max_root_error_m"] < 0.1
    # the body's simulation model is shared by requests in parallel and changed by none: the same answer
    req = {"skeleton": squat.skeleton.to_json(), "mass": 80.0, "clip": clip_to_wire(squat, with_skeleton=False),
           "track": True}
    with ThreadPoolExecutor(3) as pool:
        again = list(pool.map(lambda _: c.request("simulator", "perform", req)["report"]["support"], range(3)))
    assert all(a["tracking_runs"] == s["tracking_runs"] and a["mean_help"] == s["mean_help"] for a in again)
    # plant: a squat whose hips float 10 cm gets its feet back on the floor (the root's height mostly)
    lifted = squat.data.copy()
    lifted[:, squat.channels.index("root.ty")] += 0.10 / squat.skeleton.unit_m
    p = _ok(contract.PLANT, c.request("simulator", "plant", {"skeleton": squat.skeleton.to_json(),
                                                            "clip": clip_to_wire(squat.with_data(lifted), False),
                                                            "reference": clip_to_wire(squat, False)}))
    assert p["changes"]["planted"] and 0.07 < p["changes"]["root_height_change_m"] < 0.13
    assert p["clip"]["channels"] == squat.channels and p["clip"]["data"].shape == squat.data.shape

    # a simulated other: open and comparative answers, reveal
    _ok(contract.OTHER_CREATE, c.request("simulator", "other_create", {"other": "r2", "params": {"d": 6, "mass": 4.8}}))
    a = _ok(contract.OTHER_ASK, c.request("simulator", "other_ask", {"other": "r2", "kind": "open", "clips": [m]}))
    assert a["answer"] in contract.ACCEPTED["open:6"]
    cmp_ = c.request("simulator", "other_ask", {"other": "r2", "kind": "compare",
                                                "clips": [clip_to_wire(_robot_motion(80)), clip_to_wire(_robot_motion(20))]})
    assert cmp_["answer"] == ">"
    rev = _ok(contract.OTHER_REVEAL, c.request("simulator", "other_reveal", {"other": "r2"}))
    assert rev["asked"] == 2 and rev["params"]["d"] == 6 and rev["params"]["rule"] == "eq3.8"

    # a learner of the squat
    _ok(contract.LEARNER_CREATE, c.request("simulator", "learner_create", {"learner": "l1", "target": clip_to_wire(squat),
                                                                           "population_seed": 3, "index": 2}))
    im = _ok(contract.LEARNER_IMITATE, c.request("simulator", "learner_imitate", {"learner": "l1",
                                                                                  "demonstration": clip_to_wire(squat)}))
    assert im["trial"] == 1 and len(im["attempts"]) == 5
    im2 = c.request("simulator", "learner_imitate", {"learner": "l1", "demonstration": clip_to_wire(squat), "adverb": "more"})
    assert im2["trial"] == 2
    lr = _ok(contract.LEARNER_REVEAL, c.request("simulator", "learner_reveal", {"learner": "l1"}))
    assert lr["trials"] == 2 and lr["error_deg"] > 0

    listed = _ok(contract.LIST, c.request("simulator", "list"))
    assert listed["others"] == [{"other": "r2", "kind": "simulated"}] and listed["learners"] == [{"learner": "l1", "trials": 2}]
    _ok(contract.DELETE, c.request("simulator", "delete", {"learner": "l1"}))
    assert c.request("simulator", "list")["learners"] == []


def test_a_person_answers_in_the_others_seat(simulator_service, client_of):
    env, _ = simulator_service
    c = client_of(env)
    c.request("simulator", "other_create", {"other": "alice", "kind": "person", "params": {"d": 4}})
    got = {}

    def ask():
        from shared.bus.client import Client
        from tests.conftest import settings_of

        with Client(settings_of(env)) as c2:
            got["reply"] = c2.request("simulator", "other_ask", {"other": "alice", "kind": "open", "text": "How heavy did that feel?",
                                                                 "clips": [clip_to_wire(_robot_motion())], "timeout": 60})

    t = threading.Thread(target=ask)
    t.start()
    deadline = time.monotonic() + 30
    qs = []
    while not qs and time.monotonic() < deadline:
        qs = _ok(contract.OTHER_PENDING, c.request("simulator", "other_pending", {"other": "alice"}))["questions"]
        time.sleep(0.05)
    assert len(qs) == 1 and qs[0]["text"] == "How heavy did that feel?" and qs[0]["accepted"] == list(contract.ACCEPTED["open:4"])
    with pytest.raises(RemoteError, match="accepted: light, bit light, bit heavy, heavy"):
        c.request("simulator", "other_answer", {"question": qs[0]["question"], "answer": "featherweight"})
    _ok(contract.OTHER_ANSWER, c.request("simulator", "other_answer", {"question": qs[0]["question"], "answer": " Bit  Heavy "}))
    t.join(timeout=30)
    assert got["reply"]["answer"] == "bit heavy"
    with pytest.raises(RemoteError) as e:
        c.request("simulator", "other_answer", {"question": qs[0]["question"], "answer": "heavy"})
    assert e.value.code == "not_found"
    with pytest.raises(RemoteError) as e:  # nobody answers: a bounded wait, then a clear error
        c.request("simulator", "other_ask", {"other": "alice", "kind": "open", "clips": [clip_to_wire(_robot_motion())],
                                             "timeout": 1.0})
    assert e.value.code == "unavailable" and "did not answer" in e.value.message


def test_questions_to_people_never_hold_the_workers(simulator_service, client_of):
    """Four questions to a person-other held every simulator worker, and `list`
    waited 14-29 s. Six questions (more than the four workers) wait for their person while
    every other verb answers; then the person answers them all."""

    from shared.bus.client import Client
    from tests.conftest import settings_of

    env, _ = simulator_service
    c = client_of(env)
    c.request("simulator", "other_create", {"other": "carol", "kind": "person", "params": {"d": 4}, "replace": True})
    events = []

    def ask(i):
        with Client(settings_of(env)) as c2:
            r = c2.request("simulator", "other_ask", {"other": "carol", "kind": "open", "text": f"question {i}",
                                                      "clips": [clip_to_wire(_robot_motion())], "timeout": 120})
        events.append("answered")
        return r["answer"]

    with ThreadPoolExecutor(6) as pool:
        asks = [pool.submit(ask, i) for i in range(6)]
        deadline = time.monotonic() + 60
        qs = []
        while len(qs) < 6 and time.monotonic() < deadline:
            qs = c.request("simulator", "other_pending", {"other": "carol"}, timeout=30)["questions"]
            time.sleep(0.05)
        assert len(qs) == 6, f"{len(qs)} of 6 questions reached the person"
        assert "carol" in {o["other"] for o in c.request("simulator", "list", timeout=30)["others"]}
        c.request("simulator", "perform", {"body": "self", "clip": clip_to_wire(_robot_motion())}, timeout=60)
        events.append("other verbs answered")
        for q in qs:
            c.request("simulator", "other_answer", {"question": q["question"], "answer": "heavy"})
        assert [a.result(timeout=60) for a in asks] == ["heavy"] * 6
    assert events[0] == "other verbs answered", events


def test_bad_simulator_input_gets_clear_errors_and_the_service_stays_up(simulator_service, client_of, squat):
    env, procs = simulator_service
    c = client_of(env)
    c.request("simulator", "other_create", {"other": "bob", "replace": True})
    m = clip_to_wire(_robot_motion())
    human = clip_to_wire(squat, with_skeleton=False)
    nan = dict(m, data=np.where(np.arange(m["data"].size).reshape(m["data"].shape) == 3, np.nan, m["data"]))
    cases = [
        ("unknown body", "perform", {"body": "robocop", "clip": m}, "not_found"),
        ("body and skeleton", "perform", {"body": "self", "skeleton": "{}", "clip": m}, "bad_request"),
        ("neither body nor skeleton", "perform", {"clip": m}, "bad_request"),
        ("wrong joints", "perform", {"body": "self", "clip": human}, "bad_request"),
        ("robot motion on a human", "perform", {"skeleton": squat.skeleton.to_json(), "clip": m}, "bad_request"),
        ("bad skeleton JSON", "perform", {"skeleton": "{not json", "clip": m}, "bad_request"),
        ("NaN", "perform", {"body": "self", "clip": nan}, "bad_request"),
        ("plant without a reference", "plant", {"skeleton": squat.skeleton.to_json(), "clip": human}, "bad_request"),
        ("plant a robot motion", "plant", {"skeleton": squat.skeleton.to_json(), "clip": m, "reference": human},
         "bad_request"),
        ("too short to differentiate", "perform", {"body": "self", "clip": dict(m, data=m["data"][:4])}, "bad_request"),
        ("absurd mass", "perform", {"body": "self", "mass": 1e9, "clip": m}, "bad_request"),
        ("negative mass", "other_create", {"other": "x", "params": {"mass": -2.0}}, "bad_request"),
        ("unknown rule", "other_create", {"other": "x", "params": {"rule": "f9"}}, "bad_request"),
        ("bad density", "other_create", {"other": "x", "params": {"d": 3}}, "bad_request"),
        ("existing other", "other_create", {"other": "bob"}, "conflict"),
        ("unknown other", "other_ask", {"other": "nobody", "kind": "open", "clips": [m]}, "not_found"),
        ("compare with one motion", "other_ask", {"other": "bob", "kind": "compare", "clips": [m]}, "bad_request"),
        ("open question, human motion", "other_ask", {"other": "bob", "kind": "open", "clips": [human]}, "bad_request"),
        ("unknown learner", "learner_imitate", {"learner": "nobody", "demonstration": m}, "not_found"),
        ("unknown adverb", "learner_imitate", {"learner": "nobody", "demonstration": m, "adverb": "way more"}, "bad_request"),
        ("bad learner gain", "learner_create", {"learner": "x", "target": human, "params": {"gain": 7.0}}, "bad_request"),
        ("name with /", "other_reveal", {"other": "a/b"}, "bad_request"),
        ("delete nothing", "delete", {}, "bad_request"),
        # a 10,000-joint skeleton held a worker 39 s
        ("a skeleton of 1,500 joints", "perform", {"skeleton": chain_skeleton(1500), "clip": human}, "bad_request"),
        ("a simulated person of 300 joints", "perform", {"skeleton": chain_skeleton(300), "clip": human}, "bad_request"),
        # accepted input that broke an object for good
        ("a skeleton with a parent cycle", "perform", {"skeleton": cycle_skeleton(squat.skeleton), "clip": human}, "bad_request"),
        ("a NaN deviation", "learner_create",
         {"learner": "x", "target": human, "params": {"deviation": {"legs": {"scale": float("nan"), "offset": 0.0}}}},
         "bad_request"),
        ("a 1e300 deviation", "learner_create",
         {"learner": "x", "target": human, "params": {"deviation": {"legs": {"scale": 1e300, "offset": 0.0}}}},
         "bad_request"),
        ("a deviation of an unknown body part", "learner_create",
         {"learner": "x", "target": human, "params": {"deviation": {"tail": {"scale": 1.0, "offset": 0.0}}}},
         "bad_request"),
        ("a 1e300 demonstration", "learner_imitate",
         {"learner": "steady", "demonstration": dict(human, data=human["data"] * 1e300)}, "bad_request"),
    ]
    c.request("simulator", "learner_create", {"learner": "steady", "target": human, "replace": True})
    before = c.request("simulator", "list")
    assert_refused(c, procs, [(name, "simulator", verb, msg, code) for name, verb, msg, code in cases])
    assert c.request("simulator", "list") == before
    # the learner that was shown a 1e300 demonstration still learns from a real one
    out = c.request("simulator", "learner_imitate", {"learner": "steady", "demonstration": human})
    assert all(np.isfinite(a["data"]).all() for a in out["attempts"])


def test_a_reply_over_the_payload_limit_is_an_error_not_silence(tmp_path_factory, squat):
    """A router drops a message over the payload limit unread, so a reply that large would leave
    its caller waiting for nothing: the service says so instead (inverse dynamics adds the torques
    of every joint: the reply is larger than the request)."""
    from shared.bus.client import Client
    from tests.conftest import _serve, settings_of

    serve = _serve(tmp_path_factory, "simulator", MIRRORCOACH_MAX_PAYLOAD=120_000)
    env, procs = next(serve)
    try:
        with Client(settings_of(env)) as c, pytest.raises(RemoteError) as e:
            c.request("simulator", "perform", {"skeleton": squat.skeleton.to_json(),
                                               "clip": clip_to_wire(squat, with_skeleton=False)}, timeout=120)
        assert e.value.code == "bad_request" and e.value.details["cause"] == "too_large", e.value.message
        assert "the reply of simulator/perform is" in e.value.message and "shorter clip" in e.value.message
        assert "Traceback" not in procs.log("simulator")
    finally:
        serve.close()
