"""Chapter 3 on real processes: the dialogue and estimator contracts, a misbehaving other, and
a killed estimator (router, pss, simulator, dialogue, estimator, each its own process)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from schemas import dialogue as dlg
from schemas import estimator as est
from schemas.common import clip_from_wire, clip_to_wire
from shared.estimation.motions import ALL, unknown_motions
from tests.conftest import assert_refused, kill_during, state_files


def _ok(endpoint, reply):
    return endpoint.reply.validate(reply)


def test_dialogue_and_estimator_answer_within_their_contracts(chapter3_services, client_of):
    env, _ = chapter3_services
    c = client_of(env)
    lines, progress = [], []
    c.subscribe("events/dialogue/transcript", lambda k, m: lines.append(m))
    c.subscribe("events/estimator/progress", lambda k, m: progress.append(m))
    time.sleep(0.3)
    c.request("simulator", "other_create", {"other": "r2", "params": {"d": 6, "g_max": 0.6}, "replace": True})
    motion = clip_to_wire(unknown_motions(1)[0])

    assert _ok(dlg.WORDS, c.request("dialogue", "words", {"d": 8}))["words"][0] == "extremely light"
    a = _ok(dlg.ASK_OPEN, c.request("dialogue", "ask_open", {"dialogue": "chat", "other": "r2", "d": 6, "clip": motion}))
    assert a["understood"] and a["question"] == "How heavy did that feel?" and 1 <= a["k"] <= 6
    b = _ok(dlg.ASK_COMPARE, c.request("dialogue", "ask_compare", {"dialogue": "chat", "other": "r2",
                                                                    "clips": [motion, motion]}))
    assert b["answer"] == "equal"
    t = _ok(dlg.TRANSCRIPT, c.request("dialogue", "transcript", {"dialogue": "chat"}))["lines"]
    assert [(x["speaker"], x["kind"]) for x in t] == [("self", "question"), ("r2", "answer")] * 2
    assert t[1]["k"] == a["k"] and t[3]["answer"] == "equal"
    assert {"dialogue": "chat", "lines": 4} in _ok(dlg.LIST, c.request("dialogue", "list"))["dialogues"]

    info = _ok(est.START, c.request("estimator", "start", {"estimate": "r2", "other": "r2", "d": 6, "replace": True}))
    assert info["sets_done"] == 0 and info["scale"] == 1.0
    r = _ok(est.CONVERSE, c.request("estimator", "converse", {"estimate": "r2", "sets": 3}))
    assert r["completed"] == 3 and r["info"]["sets_done"] == 3 and r["info"]["consistent"]
    assert r["info"]["scale"] == pytest.approx(2.0, rel=0.05)  # the other is twice as heavy
    from shared.bus.client import RemoteError

    others = [clip_to_wire(m) for m in unknown_motions(3)]
    for method in ("thesis", "space", "interval", "body"):
        e = _ok(est.ESTIMATE_EP, c.request("estimator", "estimate", {"estimate": "r2", "clip": motion, "method": method}))
        assert e["clip"]["sensor"] == ["tau.shoulder_pitch", "tau.shoulder_roll", "tau.elbow"] and e["g"] > 0
        # several motions in one request: each the estimate one request gives, in the request's order
        many = _ok(est.ESTIMATE_MANY, c.request("estimator", "estimate_many", {"estimate": "r2", "method": method,
                                                                              "clips": [motion] + others}))["estimates"]
        one = [e] + [c.request("estimator", "estimate", {"estimate": "r2", "clip": m, "method": method}) for m in others]
        assert [x["g"] for x in many] == [x["g"] for x in one] and len({x["g"] for x in many}) > 1
        assert all(np.array_equal(x["clip"]["data"], y["clip"]["data"]) for x, y in zip(many, one))
    with pytest.raises(RemoteError) as bad:
        c.request("estimator", "estimate_many", {"estimate": "r2", "clips": [motion, {**others[0], "channels": [
            "a", "b", "c"]}]})
    assert bad.value.code == "bad_request" and "clips[1]" in str(bad.value.details) + bad.value.message
    assert _ok(est.INFO_EP, c.request("estimator", "info", {"estimate": "r2"}))["sets_done"] == 3
    assert {"estimate": "r2", "other": "r2", "sets_done": 3} in _ok(est.LIST, c.request("estimator", "list"))["estimates"]
    import subprocess
    import sys

    listed = subprocess.run([sys.executable, "-m", "shared.cli", "estimator", "list"], env=env, capture_output=True,
                            text=True, timeout=120)
    assert listed.returncode == 0 and any(line.split() == ["r2", "of", "r2:", "3", "set(s)"]
                                          for line in listed.stdout.splitlines()), listed.stdout + listed.stderr
    deadline = time.monotonic() + 5
    while len(progress) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [p["set"] for p in progress] == [1, 2, 3]
    assert any(x["dialogue"] == "r2" and x["kind"] == "answer" for x in lines)
    # started again under the same name: the thesis estimator reads no space of the old answers
    # (it did: set 0 of a rerun gave the end of the last run's numbers)
    fresh = c.request("estimator", "estimate", {"estimate": "r2", "clip": motion, "method": "thesis"})["g"]
    c.request("estimator", "start", {"estimate": "r2", "other": "r2", "d": 6, "replace": True})
    assert not {"est-r2", "estspace-r2", "estself-r2"} & {s["space"] for s in c.request("pss", "list")["spaces"]}
    again = c.request("estimator", "estimate", {"estimate": "r2", "clip": motion, "method": "thesis"})["g"]
    c.request("estimator", "start", {"estimate": "r2x", "other": "r2", "d": 6, "replace": True})
    first = c.request("estimator", "estimate", {"estimate": "r2x", "clip": motion, "method": "thesis"})["g"]
    assert again == pytest.approx(first, rel=1e-9) and again != pytest.approx(fresh, rel=1e-3)

    # rule identification, applied to later sets
    c.request("simulator", "other_create", {"other": "r4", "params": {"rule": "f3", "joints": list(ALL), "g_max": 1.2},
                                            "replace": True})
    c.request("estimator", "start", {"estimate": "r4", "other": "r4", "joints": list(ALL), "g_max": 1.2, "replace": True})
    ident = _ok(est.IDENTIFY, c.request("estimator", "identify_rule", {"estimate": "r4"}))
    assert ident["rule"] == "f3" and 1 <= len(ident["questions"]) <= 30 and ident["design"]["max_relative_error"] < 1e-3
    assert ident["posterior"]["f3"] >= 0.99 and sum(ident["posterior"].values()) == pytest.approx(1.0)
    assert c.request("estimator", "info", {"estimate": "r4"})["language"]["rule"] == "f3"
    assert _ok(est.DELETE, c.request("estimator", "delete", {"estimate": "r4"}))["deleted"]

    # an uneven other: no shoulder roll, a payload in the hand; the self holds its roll still
    body = {"missing": ["shoulder_roll"], "payload": 0.2}
    c.request("simulator", "other_create", {"other": "u", "params": {"mass": 3.0, "d": 6, "g_max": 0.6, "body": body,
                                                                    "joints": ["shoulder_pitch", "elbow"]}, "replace": True})
    info = _ok(est.START, c.request("estimator", "start", {"estimate": "u", "other": "u", "d": 6, "missing": ["shoulder_roll"],
                                                          "probes": 2, "replace": True}))
    assert info["language"]["joints"] == ["shoulder_pitch", "elbow"] and info["language"]["missing"] == ["shoulder_roll"]
    r = _ok(est.CONVERSE, c.request("estimator", "converse", {"estimate": "u", "sets": 2}))
    assert r["completed"] == 2 and r["info"]["probes_asked"] == 4 and r.get("stopped") is None
    e = _ok(est.ESTIMATE_EP, c.request("estimator", "estimate", {"estimate": "u", "clip": motion, "method": "body"}))
    truth = c.request("simulator", "other_reveal", {"other": "u"})
    assert truth["params"]["body"] == body and e["clip"]["sensor"] == ["tau.shoulder_pitch", "tau.elbow"]
    held = clip_from_wire(e["clip"])
    assert np.all(held.column("shoulder_roll") == 0.0)  # the roll the other cannot make is not estimated as made


def test_bad_requests_get_clear_errors(chapter3_services, client_of):
    env, procs = chapter3_services
    c = client_of(env)
    c.request("simulator", "other_create", {"other": "ok", "replace": True})
    c.request("estimator", "start", {"estimate": "ok", "other": "ok", "replace": True})
    m = clip_to_wire(unknown_motions(1)[0])
    human_like = dict(m, channels=["a.rx", "b.rx", "c.rx"])
    nan_clip = dict(m, data=np.where(np.arange(m["data"].size).reshape(m["data"].shape) == 3, np.nan, m["data"]))
    cases = [
        ("dialogue", "ask_open", {"dialogue": "x", "other": "nobody", "clip": m}, "not_found"),
        ("dialogue", "ask_open", {"dialogue": "x", "other": "ok", "d": 3, "clip": m}, "bad_request"),
        ("dialogue", "ask_compare", {"dialogue": "x", "other": "ok", "clips": [m]}, "bad_request"),
        ("dialogue", "transcript", {"dialogue": "never"}, "not_found"),
        ("dialogue", "transcript", {"dialogue": "../etc"}, "bad_request"),
        ("estimator", "start", {"estimate": "ok", "other": "ok"}, "conflict"),
        ("estimator", "start", {"estimate": "j", "other": "ok", "joints": ["tail"]}, "bad_request"),
        ("estimator", "converse", {"estimate": "nope"}, "not_found"),
        ("estimator", "converse", {"estimate": "ok", "sets": 0}, "bad_request"),
        ("estimator", "estimate", {"estimate": "ok", "clip": human_like}, "bad_request"),
        ("estimator", "identify_rule", {"estimate": "ok", "candidates": "weighted", "method": "thesis"}, "bad_request"),
        ("estimator", "info", {"estimate": "a/b"}, "bad_request"),
        # refused, and nothing written (a transcript, a saved estimate, its space)
        ("estimator", "start", {"estimate": "ghost", "other": "nobody", "d": 6}, "not_found"),
        ("dialogue", "ask_open", {"dialogue": "nanclip", "other": "ok", "clip": nan_clip}, "bad_request"),
        ("dialogue", "ask_compare", {"dialogue": "nobodys", "other": "nobody", "clips": [m, m]}, "not_found"),
    ]
    before = state_files(env)
    assert_refused(c, procs, [(f"{service}/{verb}", service, verb, msg, code) for service, verb, msg, code in cases])
    assert state_files(env) == before  # every state file byte-identical, none added



@pytest.mark.parametrize("behaviour, reason", [("silent", "no answer"), ("nonsense", "not one of the words")])
def test_a_misbehaving_other_stops_the_conversation_and_keeps_the_estimate(chapter3_services, client_of, behaviour, reason):
    env, _ = chapter3_services
    c = client_of(env)
    name = f"bad-{behaviour}"
    c.request("simulator", "other_create", {"other": name, "params": {"d": 6, "g_max": 0.6, "seed": 3}, "replace": True})
    c.request("estimator", "start", {"estimate": name, "other": name, "d": 6, "replace": True})
    good = c.request("estimator", "converse", {"estimate": name, "sets": 1})["info"]  # one honest set first
    c.request("simulator", "other_create", {"other": name, "params": {"d": 6, "g_max": 0.6, "seed": 3,
                                                                      "behaviour": behaviour}, "replace": True})
    r = c.request("estimator", "converse", {"estimate": name, "sets": 8, "timeout": 1.0}, timeout=120)
    assert reason in r["stopped"], r.get("stopped")
    info = r["info"]
    assert info["sets_done"] >= good["sets_done"] == 1  # nothing learnt before is lost
    assert any(reason in n for n in info["notes"])
    assert info["sets_done"] == 1 and info["scale"] == pytest.approx(good["scale"])  # nothing learnt from it
    assert c.request("estimator", "info", {"estimate": name})["sets_done"] == info["sets_done"]
    lines = c.request("dialogue", "transcript", {"dialogue": name})["lines"]
    if behaviour == "silent":
        assert lines[-1]["kind"] == "note" and "no answer" in lines[-1]["text"]
    if behaviour == "nonsense":
        assert lines[-1]["understood"] is False


def test_contradiction_alone_never_stops_a_conversation_and_the_reply_says_how_sure_it_is(chapter3_services,
                                                                                         client_of):
    """An other whose words are random goes on being asked; the model check weighs its
    answers and says how inconsistent it is; an honest other of a body like the self's is neither
    doubted nor called outside what the estimator can model."""
    env, _ = chapter3_services
    c = client_of(env)
    for name, behaviour in (("liar", "contradict"), ("honest", "honest"), ("unsure", "honest")):
        extra = {"dont_know": 0.4} if name == "unsure" else {}
        c.request("simulator", "other_create", {"other": name, "params": {"d": 6, "g_max": 0.6, "seed": 3,
                                                                          "behaviour": behaviour, **extra},
                                                "replace": True})
        c.request("estimator", "start", {"estimate": name, "other": name, "d": 6, "replace": True})
        r = c.request("estimator", "converse", {"estimate": name, "sets": 3}, timeout=300)
        assert r.get("stopped") is None and r["completed"] == 3, r.get("stopped")
        m = r["model"]
        assert m["answers"] == r["info"]["answers"] > (6 if name == "unsure" else 12) and m["verdict"]
        if behaviour == "contradict":
            assert m["repeat_disagreement"] > 0.3 and m["agreement"] < 0.9, m
        elif name == "unsure":  # "I don't know" is understood: unanswered, counted, never a stop
            assert r["info"]["dont_know"] > 0 and not m["outside"]
            lines = c.request("dialogue", "transcript", {"dialogue": name})["lines"]
            assert sum(bool(x.get("dont_know")) for x in lines) == r["info"]["dont_know"]
        else:
            assert m["repeat_disagreement"] == 0.0 and m["agreement"] == 1.0 and not m["outside"], m


@pytest.mark.slow
def test_killing_the_estimator_between_sets_loses_no_completed_set(chapter3_services, client_of):
    env, procs = chapter3_services
    c = client_of(env)
    c.request("simulator", "other_create", {"other": "kk", "params": {"d": 6, "g_max": 0.6}, "replace": True})
    c.request("estimator", "start", {"estimate": "kk", "other": "kk", "d": 6, "replace": True})
    done = []
    c.subscribe("events/estimator/progress", lambda k, m: done.append(m["set"]) if m["estimate"] == "kk" else None)
    time.sleep(0.3)
    err = kill_during(env, procs, "estimator", "services.estimator",
                      lambda c2: c2.request("estimator", "converse", {"estimate": "kk", "sets": 40}, timeout=300),
                      lambda: len(done) >= 2)
    assert getattr(err, "code", "") == "unavailable"
    reported = max(done)
    info = c.request("estimator", "info", {"estimate": "kk"})
    assert info["sets_done"] >= reported  # every set reported done was saved
    r = c.request("estimator", "converse", {"estimate": "kk", "sets": 1})  # and it goes on from there
    assert r["info"]["sets_done"] == info["sets_done"] + 1
