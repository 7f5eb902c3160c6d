"""A service whose own saved files are damaged (a disk's fault, an edit by hand) starts, lists
them as damaged, answers about them with what is wrong and what to do, and keeps the files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import cluster_env, running, state_files


def _trillion_element_npz(path) -> None:
    """An NPZ whose array header declares 10^12 elements in a few bytes (numpy would allocate them)."""
    import zipfile

    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000, 1000000), }"
    header += " " * (63 - (10 + len(header)) % 64) + "\n"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("header.npy", b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + b"\0" * 64)


def test_damaged_saved_files_are_listed_and_answered_never_fatal(tmp_path, client_of):
    from shared.bus.client import RemoteError

    env = cluster_env(tmp_path / "home")
    data = tmp_path / "home" / "data"
    for folder in ("simulator/others", "simulator/learners", "estimator", "coach", "capture", "pss"):
        (data / folder).mkdir(parents=True)
    (data / "simulator/learners/bad.npz").write_bytes(b"not an archive")
    (data / "simulator/others/broken.json").write_text("{")
    (data / "simulator/others/odd.json").write_text(json.dumps({"kind": "simulated", "name": "odd",
                                                                  "params": {"rule": "no such rule"}}))
    _trillion_element_npz(data / "estimator/e1.npz")
    (data / "coach/s1.json").write_text("[1, 2")
    (data / "capture/t1.json").write_text(json.dumps({"take": "t1", "state": "done"}))  # its other fields lost
    (data / "pss/sp1.npz").write_bytes(b"PK\x03\x04 a zip cut short")
    before = state_files(env)

    with running(env, "simulator", "estimator", "coach", "capture", "pss") as procs:  # all start (and stay) alive
        c = client_of(env)
        agents = c.request("simulator", "list", {})
        damaged = {(d["kind"], d["name"]): d["message"] for d in agents["damaged"]}
        assert set(damaged) == {("learner", "bad"), ("other", "broken"), ("other", "odd")}
        assert agents["others"] == agents["learners"] == []
        bad, broken, odd = damaged["learner", "bad"], damaged["other", "broken"], damaged["other", "odd"]
        assert "not an NPZ archive" in bad and str(data / "simulator/learners/bad.npz") in bad
        assert "no such rule" in odd and "JSONDecodeError" in broken
        estimates = c.request("estimator", "list", {})
        assert estimates["estimates"] == [] and [d["name"] for d in estimates["damaged"]] == ["e1"]
        assert "declares an array of shape" in estimates["damaged"][0]["message"]
        assert "JSONDecodeError" in c.request("coach", "list", {})["damaged"][0]["message"]
        takes = c.request("capture", "list", {})
        assert takes["takes"] == [] and takes["damaged"][0]["name"] == "t1" and "missing" in takes["damaged"][0]["message"]
        spaces = c.request("pss", "list", {})  # one space file that cannot be read no longer fails the whole list
        assert spaces["spaces"] == [] and [(d["name"], "not a space file" in d["message"]) for d in spaces["damaged"]] == \
            [("sp1", True)]

        for argv, line in [(["agents"], "learner  bad"), (["coach", "list"], "coaching session s1"),
                           (["capture", "takes"], "take     t1"), (["space", "list"], "space    sp1"),
                           (["estimator", "list"], "estimate e1")]:  # as a user sees them
            out = subprocess.run([sys.executable, "-m", "shared.cli", *argv], env=env, capture_output=True, text=True,
                                 timeout=120)
            assert out.returncode == 0 and any(x.startswith(line) and "DAMAGED: " in x for x in out.stdout.splitlines()), \
                (argv, out.stdout, out.stderr)

        as_json = subprocess.run([sys.executable, "-m", "shared.cli", "capture", "takes", "--json"], env=env,
                                 capture_output=True, text=True, timeout=120)
        assert [(t["take"], t["state"]) for t in json.loads(as_json.stdout)] == [("t1", "damaged")]

        for service, verb, req, file in [("simulator", "learner_reveal", {"learner": "bad"}, "bad.npz"),
                                         ("simulator", "other_reveal", {"other": "broken"}, "broken.json"),
                                         ("estimator", "info", {"estimate": "e1"}, "e1.npz"),
                                         ("coach", "state", {"session": "s1"}, "s1.json"),
                                         ("capture", "status", {"take": "t1"}, "t1.json")]:
            with pytest.raises(RemoteError) as e:
                c.request(service, verb, req, timeout=60)
            assert e.value.code == "bad_request", (verb, e.value.code, e.value.message)
            assert file in e.value.message and "the file is kept as it is" in e.value.message, e.value.message
            assert "allow_pickle" not in e.value.message  # numpy's advice to load it unsafely is never passed on
        assert state_files(env) == before  # nothing was changed or lost

        # a new one of the same name only when asked to replace it; deleting removes the damaged file
        with pytest.raises(RemoteError) as e:
            c.request("simulator", "other_create", {"other": "broken"})
        assert e.value.code == "conflict" and "cannot be read" in e.value.message
        assert c.request("simulator", "delete", {"other": "broken"})["deleted"] == "broken"
        assert not (data / "simulator/others/broken.json").exists()
        c.request("simulator", "other_create", {"other": "broken"})
        c.request("simulator", "other_create", {"other": "odd", "replace": True})
        agents = c.request("simulator", "list", {})
        assert [o["other"] for o in agents["others"]] == ["broken", "odd"] and [d["name"] for d in agents["damaged"]] == ["bad"]
        shown = subprocess.run([sys.executable, "-m", "shared.cli", "agents"], env=env, capture_output=True, text=True,
                               timeout=120).stdout.splitlines()
        assert [line.split()[:3] for line in shown] == [["other", "broken", "simulated"], ["other", "odd", "simulated"],
                                                        ["learner", "bad", "DAMAGED:"]]
        assert c.request("estimator", "delete", {"estimate": "e1"})["deleted"]
        for service in ("simulator", "estimator", "coach", "capture", "pss"):
            assert procs.procs[service].poll() is None
            assert "Traceback" not in procs.log(service), service
        assert "cannot be read from its file" in procs.log("simulator")  # said in the log at start


def test_reading_back_a_saved_file_names_what_is_wrong(tmp_path):
    from shared.errors import DamagedFile, NotFound
    from shared.io.saved import read_back

    good = tmp_path / "good.npz"
    np.savez(good, header=np.array("{}"), memory=np.zeros(3))
    with read_back(good, "learner", "good", npz=True), np.load(good) as z:
        assert z["memory"].shape == (3,)
    _trillion_element_npz(tmp_path / "huge.npz")
    with pytest.raises(DamagedFile, match="declares an array of shape"), read_back(tmp_path / "huge.npz", "learner",
                                                                                    "huge", npz=True):
        np.load(tmp_path / "huge.npz")["header"]
    with pytest.raises(DamagedFile, match="KeyError"), read_back(good, "learner", "good", npz=True):
        np.load(good)["no such array"]
    with pytest.raises(NotFound, match="no take 'gone'"), read_back(tmp_path / "gone.json", "take", "gone"):
        (tmp_path / "gone.json").read_text()
    # JSON nested past the parser's recursion, a count of 1e999: damaged too, not a service that cannot start
    from shared.agents.store import AgentStore

    (tmp_path / "agents" / "others").mkdir(parents=True)
    (tmp_path / "agents" / "others" / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (tmp_path / "agents" / "others" / "huge.json").write_text(json.dumps({"kind": "simulated", "name": "huge",
                                                                         "params": {}}).replace("{", '{"asked": 1e999, ', 1))
    store = AgentStore(tmp_path / "agents")
    assert {k: e.why.split(":")[0] for k, e in store.damaged.items()} == {("other", "deep"): "RecursionError",
                                                                         ("other", "huge"): "OverflowError"}
