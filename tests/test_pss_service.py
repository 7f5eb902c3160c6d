"""Contract, bad-input and concurrency tests of the real pss service process.

The service runs as its own process against a private router on a free loopback port
(fixture ``pss_service``); every request goes over Zenoh and every reply is checked against
the same contract the service imports (``schemas/pss.py``).
"""

from __future__ import annotations

import hashlib
import re
import threading
import time

import numpy as np
import pytest

from schemas import pss as contract
from schemas.common import clip_to_wire
from shared.bus.client import RemoteError
from shared.bus.codec import pack
from tests.conftest import assert_refused, cycle_skeleton


@pytest.fixture(scope="module")
def clips(bundled):
    from shared.bodies.arm import arm_model, with_arm_torques
    from shared.io import find_clips, load_clip

    model = arm_model(body_mass=2.4)
    all_clips = [load_clip(f) for f in find_clips([bundled / "amc"])]
    train = [with_arm_torques(c, model) for c in all_clips if "_dg_" not in c.name]
    test = [with_arm_torques(c, model) for c in all_clips if "_dg_" in c.name]
    motion_only = [c for c in all_clips if "_dg_" in c.name]
    return train, test, motion_only


def _checked(endpoint, reply):
    """The reply matches the contract (validated independently of the service)."""
    return endpoint.reply.validate(reply)


def _state(env):
    """What is on the service's disk: file name -> sha256."""
    from pathlib import Path

    root = Path(env["MIRRORCOACH_HOME"]) / "data" / "pss"
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.iterdir())}


@pytest.fixture(scope="module")
def built(pss_service, clips):
    """Space 'base' built once from the bundled bd/bk clips with arm torques."""
    from shared.bus.client import Client
    from tests.conftest import settings_of

    env, _ = pss_service
    with Client(settings_of(env)) as c:
        info = c.request("pss", "build", {"space": "base", "clips": [clip_to_wire(x) for x in clips[0]], "replace": True})
    return info


def test_every_verb_answers_within_its_contract(pss_service, clips, built, client_of, tmp_path):
    env, _ = pss_service
    c = client_of(env)
    train, test, motion_only = clips
    info = _checked(contract.BUILD, built)
    assert info["n_proto_symbols"] == len(train) and len(info["labels"]) == 4
    assert info["points"].shape == (len(train), 3) and info["sensor_channels"]

    events = []
    c.subscribe("events/pss/space", lambda key, msg: events.append(msg))
    time.sleep(0.3)

    # recognize: every held-out clip (motion only, no skeleton sent) by its class
    for clip in test:
        r = _checked(contract.RECOGNIZE, c.request("pss", "recognize", {"space": "base", "clips": [clip_to_wire(clip, False)]}))
        assert r["label"] == clip.label and r["point"].shape == (3,) and len(r["nearest"]) == 5
        assert r["known"] and r["nearest_label"] == clip.label and 0.0 <= r["confidence"] <= 1.0
        assert [n["distance"] for n in r["nearest"]] == sorted(n["distance"] for n in r["nearest"])

    # the same clips as files, unread (what `mirrorcoach space recognize` sends): read by the
    # service as the library reads them, so the same answer
    from shared.bus.wirefiles import wire_file
    from shared.io import save_clip

    for clip in test:  # NPZ carries the arm torques the space was built with
        save_clip(clip, tmp_path / f"{clip.name}.npz")
        by_clip = c.request("pss", "recognize", {"space": "base", "clips": [clip_to_wire(clip)]})
        by_file = _checked(contract.RECOGNIZE, c.request("pss", "recognize", {
            "space": "base", "files": [wire_file(tmp_path / f"{clip.name}.npz")]}))
        assert by_file["label"] == by_clip["label"] == clip.label
        assert np.allclose([n["distance"] for n in by_file["nearest"]], [n["distance"] for n in by_clip["nearest"]])
        assert not by_file["another_skeleton"]

    # a clip on a game studio's skeleton, as its BVH file: read by where its body's parts are, and said so
    from shared.reports.evaluation import on_studio_skeleton

    for clip in motion_only:
        save_clip(on_studio_skeleton(clip), tmp_path / f"{clip.name}.studio.bvh")
        r = _checked(contract.RECOGNIZE, c.request("pss", "recognize", {
            "space": "base", "files": [wire_file(tmp_path / f"{clip.name}.studio.bvh")]}))
        assert r["nearest_label"] == clip.label and r["another_skeleton"] is True

    names = [p["name"] for p in info["proto_symbols"]]
    # generate from a point and from a mix
    g = _checked(contract.GENERATE, c.request("pss", "generate", {"space": "base", "point": info["points"][0]}))
    assert g["clip"]["data"].shape[0] > 10 and np.isclose(g["weights"].sum(), 1.0)
    g2 = _checked(contract.GENERATE, c.request("pss", "generate", {"space": "base", "mix": {names[0]: 3.0, names[1]: -2.0},
                                                                   "method": "monte_carlo", "seed": 3}))
    assert g2["weights"][0] == pytest.approx(3.0) and g2["clip"]["skeleton"]

    # associate both ways
    m = motion_only[0]
    a = _checked(contract.ASSOCIATE, c.request("pss", "associate", {"space": "base", "clip": clip_to_wire(m)}))
    assert a["label"] == m.label and a["aligned"]["data"].shape[0] == m.resample(30).n_frames
    assert a["aligned"]["sensor"] == info["sensor_channels"] and a["whole"]["data"].shape[0] > 10
    # the estimator's form: the sensor channels on the clip's frames alone, the same, without the whole pattern
    lean = _checked(contract.ASSOCIATE, c.request("pss", "associate", {"space": "base", "clip": clip_to_wire(m),
                                                                       "whole": False}))
    assert lean["whole"] is None and np.array_equal(lean["aligned"]["data"], a["aligned"]["data"])
    assert lean["label"] == a["label"] and np.array_equal(lean["point"], a["point"])
    part = test[0].frames(0, int(0.8 * test[0].n_frames))
    f = _checked(contract.ASSOCIATE, c.request("pss", "associate", {"space": "base", "clip": clip_to_wire(part),
                                                                    "missing": "frames"}))
    assert 0 < f["progress"] <= 1 and f["aligned"] is None

    d = _checked(contract.DISTANCE, c.request("pss", "distance", {"space": "base", "a": names[0], "b": names[1]}))
    assert d["distance"] > 0
    assert c.request("pss", "distance", {"space": "base", "a": names[0], "b": names[0]})["distance"] == 0

    # add, info, list, delete on a copy
    four = {"space": "copy", "clips": [clip_to_wire(x) for x in train[:4]]}
    first = _checked(contract.BUILD, c.request("pss", "build", four))
    # the same request again: the space it built is this one (not made again: no event below)
    again = _checked(contract.BUILD, c.request("pss", "build", {**four, "replace": True}))
    assert np.array_equal(again["points"], first["points"]) and again["n_proto_symbols"] == 4
    added = _checked(contract.ADD, c.request("pss", "add", {"space": "copy", "clips": [clip_to_wire(train[5])]}))
    assert added["n_proto_symbols"] == 5
    before = _checked(contract.INFO_EP, c.request("pss", "info", {"space": "copy"}))
    assert before["n_proto_symbols"] == 5
    assert before["params"].get("recognition_pose_floor") is None  # none by default
    placed = _checked(contract.ADD, c.request("pss", "add", {"space": "copy", "clips": [clip_to_wire(train[6])],
                                                             "rebuild": False}))
    assert placed["n_proto_symbols"] == 6 and np.allclose(placed["points"][:5], before["points"])  # the rest kept
    with pytest.raises(RemoteError) as e:
        c.request("pss", "add", {"space": "copy", "clips": [clip_to_wire(train[7])], "rebuild": False, "as_one": "x"})
    assert e.value.code == "bad_request" and "as_one needs rebuild" in e.value.message
    listed = _checked(contract.LIST, c.request("pss", "list"))
    assert {s["space"] for s in listed["spaces"]} >= {"base", "copy"} and listed["interrupted"] == []
    # the space changed since that build: the same request makes it again, of its four clips
    assert _checked(contract.BUILD, c.request("pss", "build", {**four, "replace": True}))["n_proto_symbols"] == 4
    assert _checked(contract.DELETE, c.request("pss", "delete", {"space": "copy"}))["deleted"] is True
    assert "copy" not in {s["space"] for s in c.request("pss", "list")["spaces"]}
    assert c.request("pss", "delete", {"space": "copy", "missing_ok": True})["deleted"] is False  # no event
    with pytest.raises(RemoteError) as gone:
        c.request("pss", "delete", {"space": "copy"})
    assert gone.value.code == "not_found"

    deadline = time.monotonic() + 5
    while len(events) < 5 and time.monotonic() < deadline:
        time.sleep(0.05)
    changes = [(e["space"], e["change"]) for e in events]
    assert changes == [("copy", "built"), ("copy", "added"), ("copy", "added"), ("copy", "built"), ("copy", "deleted")]
    for e in events:
        contract.EVENTS["space"].validate(e)
    # two spaces built from the same clips under two names (the estimator's spaces of the self's
    # torques): the same association, each answer naming its own space; once one has changed, its
    # answers are its own again
    for name in ("twin-a", "twin-b"):
        c.request("pss", "build", {**four, "space": name})
    ask = {"clip": clip_to_wire(m), "whole": False}
    ta, tb = (c.request("pss", "associate", {**ask, "space": name}) for name in ("twin-a", "twin-b"))
    assert (ta["space"], tb["space"]) == ("twin-a", "twin-b") and ta["label"] == tb["label"]
    assert np.array_equal(ta["aligned"]["data"], tb["aligned"]["data"]) and np.array_equal(ta["point"], tb["point"])
    c.request("pss", "add", {"space": "twin-a", "clips": [clip_to_wire(train[5])]})
    changed_a, same_b = (c.request("pss", "associate", {**ask, "space": name}) for name in ("twin-a", "twin-b"))
    assert not np.array_equal(changed_a["point"], ta["point"]) and np.array_equal(same_b["point"], tb["point"])
    assert np.array_equal(c.request("pss", "associate", {**ask, "space": "twin-a"})["point"], changed_a["point"])
    for name in ("twin-a", "twin-b"):
        c.request("pss", "delete", {"space": name})
    styled = _checked(contract.BUILD, c.request("pss", "build", {"space": "styled", "pose_floor": 0.03,
                                                                 "clips": [clip_to_wire(x) for x in train[:4]]}))
    assert styled["params"]["recognition_pose_floor"] == 0.03  # a space for other styles
    c.request("pss", "delete", {"space": "styled"})
    firsts = list({x.label: x for x in reversed(train)}.values())  # one clip of each class
    plain = _checked(contract.BUILD, c.request("pss", "build", {"space": "plain", "open_set": False,
                                                                "clips": [clip_to_wire(x) for x in firsts]}))
    assert "without the novelty model" in plain["open_set"]  # association only: the distance rule alone
    assert "without" not in info["open_set"]
    a = c.request("pss", "associate", {"space": "plain", "clip": clip_to_wire(m)})
    assert a["aligned"]["data"].shape[0] == m.resample(30).n_frames
    c.request("pss", "delete", {"space": "plain"})


def _bad_cases(clip, other_clip, amc_file):
    """(name, verb, raw payload, expected code): the bad-input list of the issue (``amc_file``: a
    clip file as `space recognize` sends it)."""
    w = clip_to_wire(clip)
    nan = dict(w, data=np.where(np.arange(w["data"].size).reshape(w["data"].shape) == 7, np.nan, w["data"]))
    inf = dict(w, data=np.full(w["data"].shape, np.inf))
    one = dict(w, data=w["data"][:1])
    empty = dict(w, data=w["data"][:0])
    short = dict(w, data=w["data"][:20])  # 20 frames at 120 fps -> 5 frames at 30 fps
    mismatch = dict(w, channels=w["channels"][:-1])
    foreign = dict(w, channels=[f"x{i}.rx" for i in range(len(w["channels"]))])
    # ~8.4 MB: over the service's 8 MB limit, under the 9 MB Zenoh message ceiling (the router
    # drops anything larger, see test_an_oversize_request_is_dropped_before_it_is_read_whole)
    big = {"space": "base", "clips": [dict(w, data=np.zeros((17_000, 62)))]}
    from shared.bus.wirefiles import wire_file

    f = wire_file(amc_file)
    return [
        ("clips and files at once", "recognize", pack({"space": "base", "clips": [w], "files": [f]}), "bad_request"),
        ("a file name that is a path", "recognize", pack({"space": "base", "files": [dict(f, name="../x.amc")]}),
         "bad_request"),
        ("a file that is no clip format", "recognize", pack({"space": "base", "files": [dict(f, name="x.txt")]}),
         "bad_request"),
        ("an AMC file without its skeleton", "recognize",
         pack({"space": "base", "files": [{"name": f["name"], "data": f["data"]}]}), "bad_request"),
        ("garbage in a BVH file", "recognize", pack({"space": "base", "files": [{"name": "x.bvh", "data": b"\x00HIER"}]}),
         "bad_request"),
        ("an AMC file read with the wrong skeleton", "recognize",
         pack({"space": "base", "files": [dict(f, skeleton=b"not an asf")]}), "bad_request"),
        ("unknown unit for the files", "recognize", pack({"space": "base", "files": [f], "units": "furlong"}),
         "bad_request"),
        ("file data of the wrong type", "recognize", pack({"space": "base", "files": [dict(f, data="text")]}),
         "bad_request"),
        ("not msgpack", "recognize", b"\xc1\xc1\xc1garbage", "bad_request"),
        ("not a map", "recognize", pack([1, 2, 3]), "bad_request"),
        ("missing field", "recognize", pack({"space": "base"}), "bad_request"),
        ("wrong type", "recognize", pack({"space": "base", "clips": "squat"}), "bad_request"),
        ("wrong type in clip", "recognize", pack({"space": "base", "clips": [dict(w, fps="fast")]}), "bad_request"),
        ("NaN", "recognize", pack({"space": "base", "clips": [nan]}), "bad_request"),
        ("Inf", "build", pack({"space": "new1", "clips": [inf]}), "bad_request"),
        ("empty clip", "build", pack({"space": "new2", "clips": [empty]}), "bad_request"),
        ("one-frame clip", "recognize", pack({"space": "base", "clips": [one]}), "bad_request"),
        ("fewer frames than states", "build", pack({"space": "new3", "clips": [short], "n_states": 12}), "bad_request"),
        ("fewer frames than states (recognize)", "recognize", pack({"space": "base", "clips": [short]}), "bad_request"),
        ("channel count mismatch", "recognize", pack({"space": "base", "clips": [mismatch]}), "bad_request"),
        ("channels the space lacks", "recognize", pack({"space": "base", "clips": [foreign]}), "bad_request"),
        ("point of the wrong dimension", "generate", pack({"space": "base", "point": np.zeros(5)}), "bad_request"),
        ("mix not summing to 1", "generate", pack({"space": "base", "mix": {other_clip: 2.0}}), "bad_request"),
        ("unknown proto-symbol", "generate", pack({"space": "base", "mix": {"nobody": 1.0}}), "not_found"),
        ("unknown space", "recognize", pack({"space": "nowhere", "clips": [w]}), "not_found"),
        ("unknown space (delete)", "delete", pack({"space": "nowhere"}), "not_found"),
        ("name with ../", "build", pack({"space": "../base", "clips": [w]}), "bad_request"),
        ("name with /", "info", pack({"space": "a/b"}), "bad_request"),
        ("existing space without replace", "build", pack({"space": "base", "clips": [w]}), "conflict"),
        ("unknown field", "info", pack({"space": "base", "spaec": 1}), "bad_request"),
        ("bytes and text keys mixed", "list", pack({b"a": 1, "b": 2}), "bad_request"),
        ("a bytes field name", "info", pack({b"space": "base"}), "bad_request"),
        ("future schema version", "info", pack({"v": 9, "space": "base"}), "bad_request"),
        ("unknown verb", "explode", pack({}), "not_found"),
        ("associate without a clip", "associate", pack({"space": "base"}), "bad_request"),
        ("associate, unknown kind", "associate", pack({"space": "base", "clip": w, "missing": "smell"}), "bad_request"),
        ("distance to an unknown proto-symbol", "distance", pack({"space": "base", "a": other_clip, "b": "nobody"}), "not_found"),
        ("distance, wrong type", "distance", pack({"space": "base", "a": 1, "b": 2}), "bad_request"),
        ("list with a stray field", "list", pack({"space": "base"}), "bad_request"),
        ("add to an unknown space", "add", pack({"space": "nowhere", "clips": [w]}), "not_found"),
        ("add a name the space has", "add", pack({"space": "base", "clips": [dict(w, name=other_clip)]}), "bad_request"),
        ("payload over the size limit", "add", pack(big), "bad_request"),
        ("a skeleton with a parent cycle", "build",
         pack({"space": "cyc", "clips": [dict(w, skeleton=cycle_skeleton(clip.skeleton))]}), "bad_request"),
    ]


def test_bad_input_gets_a_clear_error_and_changes_nothing(pss_service, clips, built, client_of):
    env, procs = pss_service
    c = client_of(env)
    before_list = c.request("pss", "list")
    before_disk = _state(env)
    assert_refused(c, procs, [(name, "pss", verb, payload, code)
                              for name, verb, payload, code in _bad_cases(clips[1][0], built["proto_symbols"][0]["name"], clips[2][0].source)])
    assert c.request("pss", "list") == before_list
    assert _state(env) == before_disk
    assert "Traceback" not in procs.log("pss")


#: builds that hold pss busy, smallest first: a test needing one to outlast its own requests takes
#: the first that does on this machine (measured in the order of events, never in seconds, so a
#: loaded machine uses the small one and a fast machine a larger one)
BUILD_SIZES = ((6, "diag"), (14, "full"), (43, "full"))


def while_building(env, dev_split, action, outlasted):
    """Run ``action(events)`` while pss builds a space (``events`` gets "build done" when the
    build ends); builds grow until ``outlasted(events, result)`` says this one outlasted what it had
    to. Returns (result, events, the build's space name, its number of clips)."""
    from pathlib import Path

    from shared.bus.client import Client
    from tests.conftest import settings_of

    for i, (n, cov) in enumerate(BUILD_SIZES):
        pool = dev_split[0]
        big = [clip_to_wire(x.resample(30)) for x in pool[:: max(1, len(pool) // n)][:n]]
        name, events = f"busy{i}", []

        def build():
            with Client(settings_of(env)) as c:
                c.request("pss", "build", {"space": name, "clips": big, "replace": True, "covariance_type": cov},
                          timeout=1200)
            events.append("build done")

        t = threading.Thread(target=build)
        t.start()
        marker = Path(env["MIRRORCOACH_HOME"]) / "data" / "pss" / f"{name}.pending.json"
        deadline = time.monotonic() + 120
        while not marker.exists() and time.monotonic() < deadline and t.is_alive():
            time.sleep(0.01)
        assert marker.exists() or "build done" in events, "the build never started"
        result = action(events)
        t.join(timeout=1200)
        assert "build done" in events, "the build never finished"
        if outlasted(events, result):
            return result, events, name, len(big)
    pytest.fail(f"even a {BUILD_SIZES[-1][0]}-clip build finished before the requests made during it")


@pytest.mark.slow
def test_a_long_build_does_not_stall_recognition_on_another_space(pss_service, dev_split, clips, built, client_of):
    env, _ = pss_service
    c = client_of(env)
    latencies = []

    def recognitions(events):
        for clip in clips[1]:
            t0 = time.monotonic()
            r = c.request("pss", "recognize", {"space": "base", "clips": [clip_to_wire(clip, False)]})
            latencies.append(time.monotonic() - t0)
            assert r["label"] == clip.label
        events.append("answered")

    _, events, name, n = while_building(env, dev_split, recognitions,
                                        lambda ev, _: ev.index("answered") < ev.index("build done"))
    print(f"\nrecognitions during a {n}-clip build: {[round(1e3 * x) for x in latencies[-len(clips[1]):]]} ms")
    assert c.request("pss", "info", {"space": name})["n_proto_symbols"] == n


def _rss_kb(pid: int) -> int:
    from pathlib import Path

    return next(int(line.split()[1]) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                if line.startswith("VmRSS:"))


def _shm_maps(pid: int) -> list[str]:
    """Shared-memory pools a process maps (not POSIX semaphores, ``/dev/shm/sem.*``: one page
    each, made by Python's multiprocessing when joblib or numba start, not by Zenoh)."""
    from pathlib import Path

    return [line for line in Path(f"/proc/{pid}/maps").read_text().splitlines()
            if "/dev/shm/" in line and "/dev/shm/sem." not in line]


def test_concurrent_clients_leave_nothing_in_shared_memory(pss_service, clips, built):
    """Zenoh's shared memory was on by default, and every client session that
    sent more than 3 KB left a pool in /dev/shm (7.4 GB after two bursts of 200 clients)."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    from shared.bus.client import Client
    from tests.conftest import settings_of

    env, procs = pss_service
    probe = clip_to_wire(clips[1][0], with_skeleton=False)  # ~60 KB, far above the 3 KB threshold

    def one(_):
        with Client(settings_of(env)) as c:
            return c.request("pss", "recognize", {"space": "base", "clips": [probe]}, timeout=120)["nearest"][0]["name"]

    for _ in range(2):
        with ThreadPoolExecutor(30) as pool:
            names = list(pool.map(one, range(30)))
        assert len(set(names)) == 1  # every client got the same real answer
    for pid in (os.getpid(), procs.procs["router"].pid, procs.procs["pss"].pid):
        assert _shm_maps(pid) == [], pid


@pytest.mark.slow
def test_an_oversize_request_is_dropped_before_it_is_read_whole(pss_service, built):
    """A 600 MiB request was reassembled whole by the router (1.1 GB kept) and
    the service (1.66 GB) before the 64 MiB limit applied. Now Zenoh's message ceiling is the
    payload limit plus 1 MiB: the router drops the rest, and our client refuses to send it."""
    from shared.bus.client import Client, Unavailable
    from shared.errors import BadInput
    from tests.conftest import settings_of

    env, procs = pss_service
    size = 100 * 2**20  # twelve times the cluster's 8 MB limit
    router, pss = procs.procs["router"].pid, procs.procs["pss"].pid
    before = {pid: _rss_kb(pid) for pid in (router, pss)}
    s = settings_of(env)
    s.max_payload = 2**30  # a client that does not check, as a hostile one would not
    with Client(s) as rogue:
        with pytest.raises(Unavailable) as e:
            rogue.request_raw("pss", "list", b"\x80" + b"x" * size, timeout=10)
        assert e.value.details["cause"] == "oversize" and "100 MiB" in e.value.message, e.value.message
    for pid, kb in before.items():
        assert _rss_kb(pid) - kb < 30 * 1024, (pid, kb, _rss_kb(pid))  # nowhere near 100 MiB kept
    s.max_payload = int(env["MIRRORCOACH_MAX_PAYLOAD"])
    with Client(s) as c:
        with pytest.raises(BadInput, match="at most 8 MiB"):
            c.request_raw("pss", "list", b"\x80" + b"x" * 9_000_000)
        assert "base" in {x["space"] for x in c.request("pss", "list")["spaces"]}  # the service is fine


@pytest.mark.slow
def test_a_saturated_service_answers_unavailable_at_once(tmp_path_factory, dev_split):
    """Requests queued without bound behind long work. With one worker and two
    places in the queue, a long build holds the worker: two requests wait, the rest are told
    `unavailable` (cause `saturated`) while the build still runs, and the waiting two are
    answered."""
    from concurrent.futures import ThreadPoolExecutor

    from shared.bus.client import Client, RemoteError
    from tests.conftest import _serve, settings_of

    serve = _serve(tmp_path_factory, "pss", MIRRORCOACH_WORKERS=1, MIRRORCOACH_QUEUE=2)
    env, procs = next(serve)
    try:
        def listings(events):
            def listing(_):
                with Client(settings_of(env)) as c:
                    try:
                        c.request("pss", "list", timeout=1200)
                        events.append("answered")
                        return "answered"
                    except RemoteError as e:
                        events.append(e.code)
                        return e.details.get("cause"), e.code, e.message

            with ThreadPoolExecutor(6) as pool:
                return list(pool.map(listing, range(6)))

        def outlasted(events, outcomes):  # every refusal came while the build still held the only worker
            refused = [i for i, e in enumerate(events) if e == "unavailable"]
            return len(refused) == 4 and events.index("build done") > max(refused)

        outcomes, events, _, _ = while_building(env, dev_split, listings, outlasted)
        refused = [o for o in outcomes if o != "answered"]
        assert outcomes.count("answered") == 2 and len(refused) == 4, outcomes
        assert all(o[:2] == ("saturated", "unavailable") and "saturated" in o[2] for o in refused), refused
        assert "Traceback" not in procs.log("pss")
    finally:
        serve.close()


def test_a_request_that_never_fits_the_memory_budget_is_refused_up_front(tmp_path_factory, clips):
    """A generation's working memory is estimated before it starts (frames x features); one
    larger than what the budget leaves beside the service is refused at once, saying how much
    it needs and how to fit; a small one on the same service runs."""
    from shared.bus.client import Client, RemoteError
    from tests.conftest import _serve, settings_of

    serve = _serve(tmp_path_factory, "pss", MIRRORCOACH_MEMORY_MB=700)
    env, procs = next(serve)
    try:
        with Client(settings_of(env)) as c:
            c.request("pss", "build", {"space": "b", "clips": [clip_to_wire(x) for x in clips[0][:3]]})
            mix = {clips[0][0].name: 1.0}
            t0 = time.monotonic()
            with pytest.raises(RemoteError) as e:
                c.request("pss", "generate", {"space": "b", "mix": mix, "frames": 100_000})
            assert e.value.code == "bad_request" and e.value.details["cause"] == "too_large", e.value.message
            assert "MIRRORCOACH_MEMORY_MB=700" in e.value.message and time.monotonic() - t0 < 5
            small = c.request("pss", "generate", {"space": "b", "mix": mix, "frames": 500})
            assert small["clip"]["data"].shape[0] == 500
            # a recognition is estimated by its frames at the space's rate x its features (a long
            # clip at 30 fps: 7x its 30 MB payload would fit, its features would not)
            long = clips[0][0].resample(30.0)
            long = long.with_data(np.tile(long.data, (60_000 // long.n_frames + 1, 1))[:60_000])
            with pytest.raises(RemoteError) as e:
                c.request("pss", "recognize", {"space": "b", "clips": [clip_to_wire(long, False)]})
            assert e.value.details["cause"] == "too_large" and "pss/recognize needs about" in e.value.message
            needed = int(re.search(r"needs about (\d+) MB", e.value.message).group(1))
            assert needed > 7 * long.data.nbytes / 2**20, e.value.message  # the features' estimate, not the payload's
            assert c.request("pss", "recognize", {"space": "b", "clips": [clip_to_wire(long.frames(0, 3000), False)]})
        assert "memory: " in procs.log("pss") and "Traceback" not in procs.log("pss")
    finally:
        serve.close()


@pytest.mark.slow
def test_a_client_that_stops_waiting_before_the_verbs_limit_is_told_it_may_still_run(pss_service, dev_split,
                                                                                    client_of):
    """A build may run up to its time limit (600 s); a client that waits less is told the service
    may still be working and how to wait longer, and the space is indeed built afterwards."""
    from shared.bus.client import Unavailable

    env, _ = pss_service
    c = client_of(env)
    clips = [clip_to_wire(x.resample(30)) for x in dev_split[0][:14]]  # full covariances: more than 0.1 s anywhere
    with pytest.raises(Unavailable) as e:
        c.request("pss", "build", {"space": "slowpoke", "clips": clips, "replace": True, "covariance_type": "full"},
                  timeout=0.1)
    assert e.value.details["cause"] == "timeout", e.value.message
    assert "may still be working: pss/build may run up to 600 s" in e.value.message and "--timeout 600" in e.value.message
    deadline = time.monotonic() + 600
    while "slowpoke" not in {s["space"] for s in c.request("pss", "list")["spaces"]} and time.monotonic() < deadline:
        time.sleep(0.2)
    assert c.request("pss", "info", {"space": "slowpoke"})["n_proto_symbols"] == 14
