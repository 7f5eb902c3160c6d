"""On real processes: a full disk and time limits.

For the full disk the cluster's home is a 40 MiB tmpfs the test mounts (skipped, saying why,
where it cannot mount one); the disk is filled by a plain file."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import time
import uuid

import numpy as np
import pytest

from schemas.common import clip_to_wire
from shared.estimation.motions import unknown_motions
from tests.conftest import cluster_env, running, state_files


@pytest.fixture
def small_disk(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=40m,mode=0700", "tmpfs", str(home)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a 40 MiB tmpfs for the full-disk test (needs CAP_SYS_ADMIN): {r.stderr.strip()}")
    try:
        yield home
    finally:
        subprocess.run(["umount", "-l", str(home)], capture_output=True)


def fill(folder, leave: int = 0) -> int:
    """Fill the file system of ``folder`` until at most ``leave`` bytes are free; returns bytes written."""
    path, written = folder / f"filler-{uuid.uuid4().hex[:6]}", 0
    with open(path, "wb", buffering=0) as f:
        for chunk in (1 << 20, 1 << 12, 1):
            while os.statvfs(folder).f_bavail * os.statvfs(folder).f_frsize > leave + chunk or (leave == 0 and chunk == 1):
                try:
                    written += f.write(b"\0" * chunk)
                except OSError as e:
                    assert e.errno == errno.ENOSPC
                    break
    return written


def test_a_full_disk_is_unavailable_and_leaves_no_half_state(small_disk, bundled, client_of):
    from shared.bus.client import RemoteError
    from shared.io import find_clips, load_clip

    env = cluster_env(small_disk)
    with running(env, "pss", "simulator", "dialogue") as procs:
        c = client_of(env)
        clips = [clip_to_wire(load_clip(f)) for f in find_clips([bundled / "amc"])[:4]]
        c.request("pss", "build", {"space": "keep", "clips": clips[:2]})
        c.request("simulator", "other_create", {"other": "r2", "params": {"d": 6}})
        motion = clip_to_wire(unknown_motions(1)[0])
        ask = {"dialogue": "chat", "other": "r2", "d": 6, "clip": motion}
        c.request("dialogue", "ask_open", ask)
        transcript = c.request("dialogue", "transcript", {"dialogue": "chat"})
        assert len(transcript["lines"]) == 2 and transcript["damaged"] == 0
        filler = small_disk / "filler"
        filler.mkdir()

        def refused(service, verb, req):
            with pytest.raises(RemoteError) as e:
                c.request(service, verb, req, timeout=120)
            assert e.value.code == "unavailable" and e.value.details.get("cause") == "disk_full", e.value.message
            assert "disk is full" in e.value.message
            assert procs.procs[service].poll() is None

        # room for the operation's marker, not for the space: the build fails when it commits
        fill(filler, leave=16 << 10)
        files = state_files(env)
        refused("pss", "build", {"space": "new", "clips": clips[2:]})
        assert state_files(env) == files  # no marker, no half space
        assert c.request("pss", "list")["interrupted"] == []
        # no room at all: the marker cannot be written either, and a transcript line goes whole or not at all
        fill(filler)
        refused("pss", "build", {"space": "keep", "clips": clips[2:], "replace": True})
        refused("dialogue", "ask_open", ask)  # the other could not keep its answer: it keeps none
        chat = "dialogue/chat.jsonl"
        assert {k: v for k, v in state_files(env).items() if k != chat} == {k: v for k, v in files.items() if k != chat}
        lines = [json.loads(x) for x in (small_disk / "data" / chat).read_text().split("\n")[:-1]]
        assert len(lines) in (2, 4)  # whole lines only; the question put and not answered, if the disk took it
        if len(lines) == 4:
            assert [x["kind"] for x in lines[2:]] == ["question", "note"] and "disk is full" in lines[3]["text"]
        pss = c.request("pss", "list")
        assert pss["interrupted"] == [] and [s["space"] for s in pss["spaces"]] == ["keep"]
        assert c.request("pss", "recognize", {"space": "keep", "clips": clips[:1]})["nearest"]

        # space again: everything works, and nothing that failed left a trace
        for f in filler.iterdir():
            f.unlink()
        c.request("dialogue", "ask_open", ask)
        c.request("pss", "build", {"space": "new", "clips": clips[2:]})
        t = c.request("dialogue", "transcript", {"dialogue": "chat"})
        assert [x["kind"] for x in t["lines"][-2:]] == ["question", "answer"] and t["damaged"] == 0
        n = len(t["lines"])
        assert not list((small_disk / "data").rglob("*.pending.json"))
        # a line an older version left torn (no newline) is left out and counted, and never swallows the next
        with open(small_disk / "data" / "dialogue" / "chat.jsonl", "ab") as f:
            f.write(json.dumps(t["lines"][0]).encode()[:40])
        t = c.request("dialogue", "transcript", {"dialogue": "chat"})
        assert len(t["lines"]) == n and t["damaged"] == 1
        c.request("dialogue", "ask_open", ask)
        t = c.request("dialogue", "transcript", {"dialogue": "chat"})
        assert len(t["lines"]) == n + 2 and t["damaged"] == 1 and np.all([x["dialogue"] == "chat" for x in t["lines"]])
        for name in ("pss", "dialogue"):
            assert "Traceback" not in procs.log(name), procs.log(name)[-3000:]


def test_an_empty_marker_is_no_interrupted_space(tmp_path, dev_split):
    """An older version's marker the full disk left empty: written before any work, so nothing
    was interrupted; the space beside it is intact."""
    from shared.pss.space import ProtoSymbolSpace
    from shared.pss.store import SpaceStore

    store = SpaceStore(tmp_path)
    store.commit("a", ProtoSymbolSpace.build(dev_split[0][:3], dim=2))
    (tmp_path / "a.pending.json").write_bytes(b"")
    (tmp_path / "b.pending.json").write_text(json.dumps({"operation": "add", "started": 1.0}))
    store = SpaceStore(tmp_path)
    assert [x["space"] for x in store.interrupted()] == ["b"]
    assert store.get("a").symbols and not (tmp_path / "a.pending.json").exists()


def test_an_interrupted_replace_beside_an_intact_space_is_said_once(tmp_path, dev_split, caplog):
    """A replace (or an add) killed half-way leaves the space as it was: the next start says so
    in the log and lists the space without an INTERRUPTED line; a first build that never
    finished stays listed until it is built or deleted."""
    from shared.pss.space import ProtoSymbolSpace
    from shared.pss.store import SpaceStore

    store = SpaceStore(tmp_path)
    store.commit("kept", ProtoSymbolSpace.build(dev_split[0][:3], dim=2))
    (tmp_path / "kept.pending.json").write_text(json.dumps({"operation": "build", "started": 1.0}))
    (tmp_path / "never.pending.json").write_text(json.dumps({"operation": "build", "started": 1.0}))
    with caplog.at_level("WARNING", logger="mirrorcoach.pss"):
        store = SpaceStore(tmp_path)
    assert [x["space"] for x in store.interrupted()] == ["never"] and store.names() == ["kept"]
    assert "space 'kept': a build started before the service last stopped never finished" in caplog.text
    assert [x["space"] for x in SpaceStore(tmp_path).interrupted()] == ["never"]  # said once: the marker is gone


def test_a_standby_leaves_the_leaders_write_in_progress_and_recovers_when_it_leads(tmp_path, dev_split):
    """Deployed, a standby pss opens the store both hosts mount while the leader writes: it must
    not clear the leader's temporary file or marker (CI once lost a build that way: the rename
    found no file). When it starts to lead it clears what is old enough to be a dead process's
    and leaves a temporary file written moments ago (a stepped-down leader's write finishing)."""
    import os
    import time

    from shared.pss import store as store_module
    from shared.pss.space import ProtoSymbolSpace
    from shared.pss.store import SpaceStore

    leader = SpaceStore(tmp_path)
    leader.commit("a", ProtoSymbolSpace.build(dev_split[0][:3], dim=2))
    writing = tmp_path / ".b.npz.in_progress"
    writing.write_bytes(b"half")
    (tmp_path / "a.pending.json").write_text(json.dumps({"operation": "add", "started": 1.0}))
    standby = SpaceStore(tmp_path, recover=False)
    assert writing.exists() and (tmp_path / "a.pending.json").exists()
    dead = tmp_path / ".c.npz.killed"
    dead.write_bytes(b"half")
    old = time.time() - store_module.TAKE_OVER_GRACE_S - 1
    os.utime(dead, (old, old))
    standby.take_over()
    assert not dead.exists() and writing.exists()  # the old one was a dead process's; the young one may finish
    assert not (tmp_path / "a.pending.json").exists() and standby.get("a").symbols  # the space as it was
    SpaceStore(tmp_path)  # a single instance's start clears every temporary file
    assert not writing.exists()


def test_a_line_the_full_disk_cut_is_taken_back(small_disk):
    """The disk takes the first part of a line (the file's last page has room) and refuses the
    rest: the file is cut back to where it was, and the error is raised."""
    from shared.io.atomic import append_line, read_lines

    path = small_disk / "t.jsonl"
    append_line(path, "first")
    fill(small_disk)
    with pytest.raises(OSError) as e:
        append_line(path, "x" * 100_000)
    assert e.value.errno == errno.ENOSPC
    assert path.read_bytes() == b"first\n" and read_lines(path) == (["first"], 0)


def test_a_request_past_its_time_limit_stops_and_changes_nothing(tmp_path, bundled, client_of):
    """Time limits. A build of 12 clips under a 1 ms limit (its clips alone take longer to read) stops before its next HMM
    (``unavailable``, cause ``time_limit``), writes nothing, and the service answers the next
    request at once."""
    from shared.bus.client import RemoteError
    from shared.io import find_clips, load_clip

    env = cluster_env(tmp_path / "home", MIRRORCOACH_TIME_LIMIT=0.001)
    with running(env, "pss") as procs:
        c = client_of(env)
        clips = [clip_to_wire(load_clip(f)) for f in find_clips([bundled / "amc"])[:12]]
        files = state_files(env)
        with pytest.raises(RemoteError) as e:
            c.request("pss", "build", {"space": "big", "clips": clips}, timeout=120)
        assert e.value.code == "unavailable" and e.value.details["cause"] == "time_limit", e.value.message
        assert "pss/build passed its time limit of 0.001 s" in e.value.message and "nothing was changed" in e.value.message
        assert state_files(env) == files
        assert c.request("pss", "list")["spaces"] == [] and c.request("pss", "list")["interrupted"] == []
    assert "Traceback" not in procs.log("pss")


def test_library_code_is_limited_only_inside_a_request():
    from shared.coaching.policies import simulated_coach_demonstrations
    from shared.deadline import TimeLimit, time_limit

    assert len(simulated_coach_demonstrations(n=100)) == 100  # no request, no limit
    with time_limit(0.0, "coach/policy_fit"), pytest.raises(TimeLimit) as e:
        simulated_coach_demonstrations(n=10)
    assert e.value.code == "unavailable" and e.value.details["cause"] == "time_limit"
    with time_limit(60.0, "coach/policy_fit"):
        assert len(simulated_coach_demonstrations(n=10)) == 10
    from shared.deadline import completed

    with time_limit(0.0, "coach/run"), pytest.raises(TimeLimit) as e:  # a stop deep inside a step
        completed("3 of 5 trial(s) completed and kept")
        simulated_coach_demonstrations(n=10)
    assert e.value.message.endswith("stopped; 3 of 5 trial(s) completed and kept")
    with time_limit(0.0, "pss/build"), pytest.raises(TimeLimit) as e:  # a new request starts with nothing kept
        simulated_coach_demonstrations(n=10)
    assert e.value.message.endswith("nothing was changed")


@pytest.mark.slow
def test_a_coaching_run_past_its_time_limit_keeps_the_trials_it_completed(tmp_path, bundled, client_of):
    """The coach's limit (only the coach's) stops a 50-trial run between trials: the reply says
    how many were completed and kept, the session holds exactly those, and it goes on. The limit
    is set in work, not in seconds of a machine that may be loaded: eight times the longest of a
    cold and a warm trial on this machine now (measured first under a generous limit; the coach
    then restarted with it)."""
    from shared.bus.client import RemoteError
    from shared.io import load_clip
    from tests.conftest import Processes

    env = cluster_env(tmp_path / "home")
    procs = Processes(env)
    procs.start("router", "shared.bus.router")
    for name in ("pss", "simulator"):
        procs.start(name, f"services.{name}")
    squat = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc")

    def start_coach(limit: float) -> None:
        procs.env = {**env, "MIRRORCOACH_TIME_LIMIT": f"{limit:g}"}
        procs.start("coach", "services.coach")
        procs.wait_alive({"pss", "simulator", "coach"})

    try:
        c = client_of(env)
        start_coach(300.0)
        c.request("coach", "start", {"session": "measure", "target": clip_to_wire(squat), "learner": "measure"})
        longest = 0.0
        for _ in range(2):  # a cold trial, then a warm one
            t0 = time.monotonic()
            c.request("coach", "run", {"session": "measure", "trials": 1}, timeout=300)
            longest = max(longest, time.monotonic() - t0)
        old = procs.procs.pop("coach")
        old.terminate()
        old.wait(timeout=60)
        start_coach(max(2.0, 8 * longest))
        session = "long"
        c.request("coach", "start", {"session": session, "target": clip_to_wire(squat), "learner": "slow"})
        with pytest.raises(RemoteError) as e:
            c.request("coach", "run", {"session": session, "trials": 50}, timeout=600)
        assert e.value.code == "unavailable" and e.value.details["cause"] == "time_limit", e.value.message
        done = int(e.value.message.split("stopped; ")[1].split(" of 50")[0])
        assert 0 < done < 50 and "completed and kept" in e.value.message
        assert len(c.request("coach", "state", {"session": session})["trials"]) == done
        r = c.request("coach", "run", {"session": session, "trials": 1})
        assert len(r["trials"]) == done + 1
    finally:
        procs.stop()
    assert "Traceback" not in procs.log("coach")


def test_listing_interrupted_spaces_while_writers_finish(tmp_path):
    """A marker removed by a finishing writer between the listing's glob and its read is an
    operation that finished, not an internal error (seen in `reproduce ch4`: pss/list failed
    with FileNotFoundError while coach sessions were adding attempts)."""
    import threading

    from shared.pss.store import SpaceStore

    store = SpaceStore(tmp_path / "spaces")
    stop = threading.Event()

    def writer(k):
        n = 0
        while not stop.is_set() and n < 20_000:
            with store.writing(f"w{k}", "add"):
                store._marker(f"w{k}").unlink()  # as commit() does when the write is done
            n += 1

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    try:
        for _ in range(3000):
            assert all(r["space"].startswith("w") for r in store.interrupted())
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=30)
    (tmp_path / "spaces" / "gone.pending.json").write_text("[1, 2]")  # a marker of another shape: still listed
    assert [r["space"] for r in store.interrupted()] == ["gone"]


def test_a_service_stopping_while_a_worker_still_publishes_ends_cleanly(tmp_path):
    """A request past the stop grace may still publish events while ``stop()`` undeclares the
    publishers: the service stops without an error and the late events are dropped."""
    import threading
    import time

    from shared.bus.runtime import Service
    from tests.conftest import Processes, settings_of

    env = cluster_env(tmp_path / "home")
    procs = Processes(env)
    procs.start("router", "shared.bus.router")
    try:
        for _ in range(5):
            svc = Service("probe", {}, settings=settings_of(env), stop_grace_s=0.0).start()
            errors, sent, go = [], [0], threading.Event()

            def late_worker():
                go.set()
                try:
                    for _ in range(200_000):  # bounded: far more than the stop takes
                        svc.publish("requests", {"service": "probe", "requests": [["x", 1.0, "ok"]]})
                        sent[0] += 1
                        if svc._session is None:
                            break
                except Exception as e:  # noqa: BLE001 - what the test looks for
                    errors.append(e)

            t = threading.Thread(target=late_worker)
            t.start()
            go.wait(5)
            deadline = time.monotonic() + 10
            while sent[0] < 100 and not errors and time.monotonic() < deadline:
                time.sleep(0.001)
            assert sent[0] >= 100 and not errors, errors  # it was publishing when the stop came
            svc.stop()
            t.join(30)
            assert not t.is_alive() and not errors, errors
    finally:
        procs.stop()
