"""Each service's verbs, one by one, without a service or a bus: the handler classes take a
folder (or a store), a bus client factory and a publisher. Requests and replies go through the
verbs' contracts, as the runtime sends them. Verbs that call other services are tested with
real clusters in the contract and end-to-end tests; here the ones that answer on their own."""

from __future__ import annotations

import numpy as np
import pytest

from schemas import coach as coach_contract
from schemas import estimator as estimator_contract
from schemas import simulator as simulator_contract
from services.coach.service import CoachHandlers
from services.estimator.service import EstimatorHandlers
from services.simulator.service import SimulatorHandlers
from shared.agents.store import AgentStore
from shared.errors import BadInput, NotFound


def _no_bus():
    raise AssertionError("this verb must answer without asking another service")


def _call(contract, handlers, verb: str, request: dict) -> dict:
    endpoint = contract.ENDPOINTS[verb]
    reply = handlers.handlers()[verb](endpoint.request.validate(request))
    return endpoint.reply.validate(reply)


def test_the_coach_fits_policies_and_keeps_sessions_without_a_bus(tmp_path):
    published: list = []
    coach = CoachHandlers(tmp_path, _no_bus, lambda *event: published.append(event))
    assert set(coach.handlers()) == set(coach_contract.ENDPOINTS)
    emu2 = _call(coach_contract, coach, "policy_fit", {"kind": "emu2", "sweep": {"l1": {"0": 9.0, "1": 4.0, "2": 6.0}}})
    assert emu2["fit"]["per_learner"] == {"l1": 1.0} and emu2["policy"]["kind"] == "emu2"
    dp = [float(x) for x in np.linspace(20, 200, 40)]
    aeu = _call(coach_contract, coach, "policy_fit", {"kind": "aeu1", "trial_dp": dp})
    assert aeu["policy"]["calibration"] == pytest.approx(aeu["fit"]["scale"]) and aeu["fit"]["scale"] > 0
    with pytest.raises(BadInput, match="sweep"):
        _call(coach_contract, coach, "policy_fit", {"kind": "emu2"})
    assert _call(coach_contract, coach, "list", {})["sessions"] == []
    with pytest.raises(NotFound, match="no coaching session 'nobody'"):
        _call(coach_contract, coach, "state", {"session": "nobody"})
    with pytest.raises(NotFound):
        _call(coach_contract, coach, "delete", {"session": "nobody"})
    with pytest.raises(BadInput, match="exactly one of target"):  # refused before the bus is asked
        _call(coach_contract, coach, "start", {"session": "s1"})
    assert published == [] and list(tmp_path.iterdir()) == []


def test_the_estimator_answers_for_missing_estimates_without_a_bus(tmp_path):
    est = EstimatorHandlers(tmp_path, _no_bus, lambda *event: None)
    assert set(est.handlers()) == set(estimator_contract.ENDPOINTS)
    assert _call(estimator_contract, est, "list", {})["estimates"] == []
    for verb in ("info", "delete"):
        with pytest.raises(NotFound, match="no estimate named 'nobody'"):
            _call(estimator_contract, est, verb, {"estimate": "nobody"})


def test_the_simulator_creates_asks_and_reveals_an_other_on_its_own(tmp_path):
    published: list = []
    sim = SimulatorHandlers(AgentStore(tmp_path), lambda *event: published.append(event))
    assert set(sim.handlers()) == set(simulator_contract.ENDPOINTS)
    assert set(sim.costs()) <= set(simulator_contract.ENDPOINTS)
    assert _call(simulator_contract, sim, "bodies", {})["robots"]
    _call(simulator_contract, sim, "other_create", {"other": "o1", "kind": "simulated", "params": {"mass": 4.8, "d": 4}})
    assert _call(simulator_contract, sim, "list", {})["others"] == [{"other": "o1", "kind": "simulated"}]
    from schemas.common import clip_to_wire
    from shared.estimation.motions import basic_motions
    from shared.estimation.symbols import WORDS

    motion = basic_motions()[0]
    answer = _call(simulator_contract, sim, "other_ask", {"other": "o1", "kind": "open", "clips": [clip_to_wire(motion)]})
    assert answer["answer"] in WORDS[4]
    assert published and published[-1][0] == "answered"
    revealed = _call(simulator_contract, sim, "other_reveal", {"other": "o1"})
    assert revealed["params"]["mass"] == 4.8
    assert _call(simulator_contract, sim, "delete", {"other": "o1"})["deleted"] == "o1"
    assert _call(simulator_contract, sim, "list", {})["others"] == []


def test_what_the_selfs_body_gives_is_computed_once_and_a_failure_is_asked_again():
    """The estimator's cache of the self's regressors and torques (``Once``): requests for one
    key at once wait for one computation; a failed one is not kept; the table is bounded by keys
    and by bytes."""
    import threading

    from shared.once import Once

    once, calls, asked = Once(limit=3), [], threading.Semaphore(0)

    def slow():  # the computation ends only once every request has come (no clock: the machine may be slow)
        calls.append(1)
        for _ in range(4):
            assert asked.acquire(timeout=30)
        return np.arange(3.0)

    def ask():
        asked.release()
        out.append(once.once("k", slow, 60.0))

    out: list = []
    threads = [threading.Thread(target=ask) for _ in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(calls) == 1 and len(out) == 4 and all(np.array_equal(o, np.arange(3.0)) for o in out)

    def broken():
        raise RuntimeError("simulator away")

    with pytest.raises(RuntimeError):
        once.once("bad", broken, 10.0)
    assert once.once("bad", lambda: 7, 10.0) == 7  # asked again, not the kept failure
    for i in range(5):
        once.once(i, lambda i=i: i, 10.0)
    assert len(once.table) == 3
    once.once(2, lambda: "again", 10.0)  # kept: asked again, it becomes the most recent
    once.once(5, lambda: 5, 10.0)
    assert list(once.table) == [4, 2, 5]  # the least recently asked (3) forgotten, not the oldest kept (2)

    # bounded by bytes too: a value over max_bytes / 16 is answered but not kept, and past max_bytes
    # of kept values the least recently asked go
    sized = Once(limit=100, max_bytes=16 * 800)
    huge = sized.once("huge", lambda: np.zeros(101), 10.0)  # 808 bytes > 800
    assert huge.shape == (101,) and "huge" not in sized.table and sized.kept_bytes == 0
    for i in range(20):
        sized.once(i, lambda: np.zeros(100), 10.0)  # 800 bytes each: 16 fit
    assert list(sized.table) == list(range(4, 20)) and sized.kept_bytes == 16 * 800
    sized.once("pair", lambda: (np.zeros(50), np.zeros(50)), 10.0)  # a tuple's arrays summed
    assert list(sized.table)[0] == 5 and sized.kept_bytes == 16 * 800
    sized.clear()
    assert not sized.table and sized.kept_bytes == 0


def test_the_estimators_kept_loads_under_many_workers_at_once(tmp_path):
    """Requests on more estimates than the 64 the estimator keeps loaded, eight workers at once:
    every load answers with its own estimate, and no more than 64 stay kept."""
    from concurrent.futures import ThreadPoolExecutor

    from shared.estimation.conversation import Language, OtherEstimate
    from shared.estimation.motions import basic_motions

    est = EstimatorHandlers(tmp_path, _no_bus, lambda *event: None)
    motions = basic_motions()
    for i in range(80):
        OtherEstimate(Language(d=4 + i % 5), motions, probes=False).save(est.path(f"e{i}"))
    names = [f"e{(7 * i) % 80}" for i in range(3000)]
    with ThreadPoolExecutor(8) as pool:
        got = list(pool.map(lambda n: (n, est.load(n).language.d), names))
    assert all(d == 4 + int(n[1:]) % 5 for n, d in got) and len(got) == 3000
    assert len(est.loaded) <= 64


def test_an_others_file_is_synced_when_made_and_its_counter_written_atomically_after_each_answer(tmp_path, monkeypatch):
    """Creating an other is synced to the disk; after an answer only its question counter moved, and
    the file is rewritten whole (by rename) without an fsync: a fresh store reads the counter back."""
    import os

    from schemas.common import clip_to_wire
    from shared.estimation.motions import basic_motions

    synced: list = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd) or real(fd))
    sim = SimulatorHandlers(AgentStore(tmp_path), lambda *event: None)
    _call(simulator_contract, sim, "other_create", {"other": "o1", "kind": "simulated", "params": {"mass": 4.8, "d": 4}})
    assert len(synced) == 1
    wire = clip_to_wire(basic_motions()[0])
    for _ in range(3):
        _call(simulator_contract, sim, "other_ask", {"other": "o1", "kind": "open", "clips": [wire]})
    assert len(synced) == 1  # the answers' counter writes: not synced
    assert AgentStore(tmp_path).other("o1")[1].asked == 3
    assert sorted(p.name for p in (tmp_path / "others").iterdir()) == ["o1.json"]  # no temporary file left
    again = SimulatorHandlers(AgentStore(tmp_path), lambda *event: None)  # a restarted simulator goes on counting
    _call(simulator_contract, again, "other_ask", {"other": "o1", "kind": "open", "clips": [wire]})
    assert AgentStore(tmp_path).other("o1")[1].asked == 4 and len(synced) == 1
