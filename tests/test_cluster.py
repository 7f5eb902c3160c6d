"""End to end on a real local cluster: ``mirrorcoach up`` (supervisor, router, pss), the CLI
as a user runs it, a crash in the middle of a build, ``mirrorcoach down``."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from schemas.common import clip_to_wire
from tests.conftest import REPO, cluster_env, settings_of

pytestmark = pytest.mark.slow  # end-to-end: real clusters and processes (make test-quick leaves them out)


def cli(env, *args, timeout=300):
    return subprocess.run([sys.executable, "-m", "shared.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=REPO, timeout=timeout)


@pytest.fixture
def cluster(tmp_path):
    env = cluster_env(tmp_path / "home")
    try:
        r = cli(env, "up", "--wait", "120")
        assert r.returncode == 0, r.stdout + r.stderr
        yield env
    finally:
        r = cli(env, "down")
        assert r.returncode == 0, r.stdout + r.stderr
    logs = Path(env["MIRRORCOACH_HOME"]) / "logs"
    assert "service pss stopped" in (logs / "pss.log").read_text()  # SIGTERM: a clean stop, session closed
    assert "router stopped" in (logs / "router.log").read_text()


def _connects_as_nobody(family, address) -> bool | None:
    """Whether uid ``nobody`` can connect to ``address`` (a forked child drops to it); None when
    this process cannot change uid (not root)."""
    import pwd
    import socket

    if os.geteuid() != 0:
        return None
    nobody = pwd.getpwnam("nobody")
    pid = os.fork()
    if pid == 0:  # the child: another user of this machine
        code = 3
        try:
            os.setgroups([])
            os.setgid(nobody.pw_gid)
            os.setuid(nobody.pw_uid)
            with socket.socket(family, socket.SOCK_STREAM) as sock:
                sock.settimeout(2.0)
                try:
                    sock.connect(address)
                    code = 0
                except OSError:
                    code = 1
        finally:
            os._exit(code)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0


def test_the_default_cluster_is_closed_to_other_users(tmp_path, bundled):
    """`up` without MIRRORCOACH_ROUTER: the router listens on a socket in the 0700 home, 0600; the
    CLI works through it. A router killed with SIGKILL leaves its socket file: the supervisor's
    new router replaces it and the cluster answers again. Another local user (uid nobody) cannot
    connect to the socket, where a TCP port on 127.0.0.1 lets them in."""
    import socket

    from shared.bus.config import default_router, socket_path

    env = cluster_env(tmp_path / "home")
    del env["MIRRORCOACH_ROUTER"]
    endpoint = default_router(tmp_path / "home")  # the home's socket (or the user's, for a deep home)
    sock = socket_path(endpoint)
    try:
        r = cli(env, "up")
        assert r.returncode == 0 and endpoint in r.stdout + r.stderr, r.stdout + r.stderr
        assert (tmp_path / "home").stat().st_mode & 0o777 == 0o700 and sock.stat().st_mode & 0o077 == 0
        assert cli(env, "space", "list").returncode == 0
        router = int((tmp_path / "home" / "run" / "router.pid").read_text().split()[0])
        os.kill(router, signal.SIGKILL)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            time.sleep(1.0)
            if cli(env, "space", "list").returncode == 0:
                break
        assert cli(env, "space", "list").returncode == 0, (tmp_path / "home" / "logs" / "router.log").read_text()[-2000:]
        # another user: only root can become one (CI runs as root; elsewhere this part says why it skips)
        tcp = socket.create_server(("127.0.0.1", 0))
        with tcp:
            seen = _connects_as_nobody(socket.AF_INET, ("127.0.0.1", tcp.getsockname()[1]))
            if seen is None:
                pytest.skip("not root: cannot run a client as another user here (the socket's modes and its "
                            "recovery after kill -9 were checked)")
            assert seen is True  # the check can fail: a loopback port is open to another user
        assert _connects_as_nobody(socket.AF_UNIX, str(sock)) is False
    finally:
        cli(env, "down")


def test_cli_end_to_end_on_the_cluster(cluster, bundled, tmp_path):
    env = cluster
    st = cli(env, "status", "--json")
    assert st.returncode == 0, st.stderr
    assert {r["name"]: r["alive"] for r in json.loads(st.stdout)} == {"supervisor": True, "router": True, "pss": True,
                                                                      "simulator": True, "dialogue": True,
                                                                      "estimator": True, "coach": True,
                                                                      "capture": True, "observer": True}

    amc = bundled / "amc"
    train = [p for p in sorted(amc.glob("*/*.amc")) if "_dg_" not in p.name]
    r = cli(env, "space", "build", "moves", *train, "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["n_proto_symbols"] == len(train) and len(info["labels"]) == 4
    logs = Path(env["MIRRORCOACH_HOME"]) / "logs"
    for svc in ("pss", "simulator", "estimator", "coach", "dialogue"):  # request workers: one native thread each
        line = next(ln for ln in (logs / f"{svc}.log").read_text().splitlines() if "native thread pools:" in ln)
        pools = dict(p.rsplit(" ", 1) for p in line.split("native thread pools: ", 1)[1].split(", ") if p != "none")
        assert all(n == "1" for n in pools.values()), line
        if svc == "pss":  # BLAS and scikit-learn's OpenMP are both loaded there
            assert any(k.startswith("openmp:") for k in pools) and any(k.startswith("openblas:") for k in pools), line

    held = next((amc / "squat1Reps").glob("HDM_dg_*.amc"))
    r = cli(env, "space", "recognize", "moves", held, "--json")
    assert r.returncode == 0, r.stderr
    rec = json.loads(r.stdout)
    assert rec["label"] == "squat1Reps" and len(rec["point"]) == 3 and rec["nearest"][0]["label"] == "squat1Reps"
    # the command sends the files unread and starts without numpy (its start-up, docs/cli.md); the
    # service reads the AMC with the ASF the command found beside it, and a BVH alike
    probe = ("import sys; from shared.cli.app import main; sys.argv = ['mirrorcoach'] + sys.argv[1:]\n"
             "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
             "print('numpy imported' if 'numpy' in sys.modules else 'no numpy', file=sys.stderr)")
    r = subprocess.run([sys.executable, "-c", probe, "space", "recognize", "moves", str(held), "--json"], capture_output=True,
                       text=True, env=env, cwd=REPO, timeout=120)
    assert r.returncode == 0 and "no numpy" in r.stderr, r.stderr
    assert json.loads(r.stdout)["label"] == "squat1Reps"
    from shared.io import load_clip, save_clip

    save_clip(load_clip(held), tmp_path / "held.bvh")
    r = cli(env, "space", "recognize", "moves", tmp_path / "held.bvh", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["label"] == "squat1Reps", r.stderr
    (tmp_path / "lonely").mkdir()
    (tmp_path / "lonely" / "x.amc").write_bytes(held.read_bytes())
    for args, says in (((tmp_path / "nothere.bvh",), "no such file"), ((tmp_path / "lonely" / "x.amc",), "no skeleton found"),
                       ((tmp_path / "held.bvh", "--skeleton", tmp_path / "none.asf"), None)):
        r = cli(env, "space", "recognize", "moves", *args)
        if says is None:  # --skeleton is for AMC files: a BVH carries its own (the option is ignored)
            assert r.returncode == 0, r.stderr
            continue
        assert r.returncode == 2 and r.stderr.startswith("error: ") and says in r.stderr and "Traceback" not in r.stderr

    squat = next(p["name"] for p in info["proto_symbols"] if p["label"] == "squat1Reps")
    kick = next(p["name"] for p in info["proto_symbols"] if p["label"] == "kickLFront1Reps")
    for out, mix in ((tmp_path / "mid.bvh", [f"{squat}=0.5", f"{kick}=0.5"]), (tmp_path / "emph.bvh", [f"{squat}=3", f"{kick}=-2"])):
        r = cli(env, "space", "generate", "moves", *sum((["--mix", m] for m in mix), []), "--out", out)
        assert r.returncode == 0, r.stderr
        from shared.io import load_clip

        assert load_clip(out).n_frames > 10
    r = cli(env, "space", "generate", "moves", "--point", ",".join(map(str, rec["point"])), "--out", tmp_path / "p.bvh")
    assert r.returncode == 0, r.stderr
    # association (eq. 2.8): the rest of a held-out squat from its first 60 %, and whether it extrapolates
    whole = load_clip(held)
    save_clip(whole.frames(0, int(0.6 * whole.n_frames)), tmp_path / "start.npz")
    r = cli(env, "space", "associate", "moves", tmp_path / "start.npz", "--missing", "frames", "--out",
            tmp_path / "rest.bvh", "--json")
    assert r.returncode == 0, r.stderr
    a = json.loads(r.stdout)
    assert a["label"] == "squat1Reps" and 0 < a["progress"] < 1 and a["reach"] > 0 and a["extrapolating"] is False
    assert load_clip(tmp_path / "rest.bvh").n_frames > 10
    r = cli(env, "space", "associate", "moves", tmp_path / "start.npz")  # this space has no sensor channels
    assert r.returncode == 2 and "no sensor channels" in r.stderr and "Traceback" not in r.stderr, r.stderr
    # a clip added without rebuilding the rest: the other points stay where they were
    r = cli(env, "space", "add", "moves", held, "--json")
    assert r.returncode == 0, r.stderr
    grown = json.loads(r.stdout)
    assert grown["n_proto_symbols"] == info["n_proto_symbols"] + 1
    assert np.allclose(np.array(grown["points"])[:-1], np.array(info["points"]))
    r = cli(env, "space", "add", "moves", held)  # its name is taken now
    assert r.returncode == 2 and "already has a proto-symbol" in r.stderr and "Traceback" not in r.stderr, r.stderr

    r = cli(env, "space", "list")
    assert r.returncode == 0 and "moves" in r.stdout
    r = cli(env, "space", "show", "moves")
    assert r.returncode == 0 and squat in r.stdout
    # errors are one line, exit 2, no traceback
    for args in (("space", "show", "nothere"), ("space", "build", "../x", train[0]), ("space", "generate", "moves", "--out", tmp_path / "x.bvh")):
        r = cli(env, *args)
        assert r.returncode == 2 and r.stderr.startswith("error: ") and "Traceback" not in r.stderr, (args, r.stderr)
    # what the cluster keeps (spaces, logs, pid files, recordings) is its user's alone
    home = Path(env["MIRRORCOACH_HOME"])
    shared_with_others = [str(p) for p in [home, *home.rglob("*")] if not p.is_symlink() and p.stat().st_mode & 0o077]
    assert not shared_with_others and (home / "data" / "pss" / "moves.npz").exists(), shared_with_others
    r = cli(env, "space", "delete", "moves")
    assert r.returncode == 0
    assert "no spaces" in cli(env, "space", "list").stdout


def test_simulator_cli_on_the_cluster(cluster, bundled, tmp_path):
    from shared.io import load_clip

    env = cluster
    amc = bundled / "amc/kickLFront1Reps/HDM_bd_kickLFront1Reps_001_120.amc"
    r = cli(env, "sim", "perform", bundled / "asf/HDM_bd.asf", amc, "--out", tmp_path / "k.npz", "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["body"]["kind"] == "human" and "feasible" in rep["report"]
    performed = load_clip(tmp_path / "k.npz")
    assert "tau.lfemur.rx" in performed.group("sensor") and "cog.y" in performed.group("sensor")
    r = cli(env, "clip", "convert", tmp_path / "k.npz", tmp_path / "k.bvh")  # it kept its body: it becomes BVH again
    assert r.returncode == 0, r.stderr
    a, b = load_clip(amc), load_clip(tmp_path / "k.bvh")  # a BVH lists the joints depth first
    rows = [b.skeleton.index(j.name) for j in a.skeleton.joints]
    assert np.abs(b.positions()[:, rows] - a.positions()[:, :len(rows)]).max() < 1e-4
    r = cli(env, "sim", "perform", "self", amc, "--out", tmp_path / "k.bvh")
    assert r.returncode == 2 and ".npz" in r.stderr
    r = cli(env, "sim", "perform", bundled / "asf/HDM_bd.asf", amc, "--out", tmp_path / "k.npz", "--track")
    assert r.returncode == 0 and "tracked on a simulated floor: a helping hand" in r.stdout, r.stdout + r.stderr

    # a person in the other's seat: one CLI asks, another answers
    motion = tmp_path / "raise.npz"
    from shared.io import save_clip
    from shared.motion.clip import Clip

    t = np.linspace(0, 3, 90)
    save_clip(Clip(np.column_stack([60 * (1 - np.cos(t)), 10 * np.sin(t), -30 - 20 * np.sin(2 * t), 0 * t]),
                   ["shoulder_pitch", "shoulder_roll", "elbow", "knee"], 30.0, name="raise"), motion)
    assert cli(env, "other", "create", "alice", "--person").returncode == 0
    asker = subprocess.Popen([sys.executable, "-m", "shared.cli", "other", "ask", "alice", str(motion), "--timeout", "60"],
                             env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        r = cli(env, "other", "answer", "alice", "--answer", "bit heavy", "--wait", "30", "--folder", tmp_path / "q")
        assert r.returncode == 0 and "sent: bit heavy" in r.stdout, r.stdout + r.stderr
        out, err = asker.communicate(timeout=60)
    finally:
        if asker.poll() is None:
            asker.kill()
    assert asker.returncode == 0 and out.strip() == "bit heavy", err
    assert list((tmp_path / "q").glob("*_1.npz"))


@pytest.mark.slow
def test_chapter3_from_the_cli(cluster, tmp_path):
    env = cluster
    assert cli(env, "other", "create", "r2", "--d", "6").returncode == 0
    r = cli(env, "estimator", "start", "r2", "r2", "--d", "6")
    assert r.returncode == 0 and "0 set(s)" in r.stdout, r.stderr
    r = cli(env, "estimator", "converse", "r2", "--sets", "2")
    assert r.returncode == 0 and "2 set(s)" in r.stdout, r.stderr
    r = cli(env, "dialogue", "transcript", "r2")
    assert r.returncode == 0 and "How heavy did that feel?" in r.stdout and "(k = " in r.stdout
    # an uneven other from the population: its body is hidden until revealed
    assert cli(env, "other", "create", "u", "--d", "6", "--kind", "joints", "--index", "2").returncode == 0
    revealed = json.loads(cli(env, "other", "reveal", "u").stdout)
    assert revealed["params"]["kind"] == "joints" and revealed["params"]["body"]["missing"] == ["shoulder_roll"]
    r = cli(env, "estimator", "start", "u", "u", "--d", "6", "--missing", "shoulder_roll", "--probes", "2")
    assert r.returncode == 0 and "0 set(s)" in r.stdout, r.stderr
    r = cli(env, "estimator", "converse", "u", "--sets", "1")
    assert r.returncode == 0 and "1 set(s)" in r.stdout and "body estimate from 6 answer(s)" in r.stdout, r.stdout + r.stderr
    r = cli(env, "other", "create", "bad", "--kind", "giants")
    assert r.returncode != 0 and "unknown population kind 'giants'" in r.stdout + r.stderr and "Traceback" not in r.stderr
    # a kind outside the estimators' model: a tiring other (its transmission drawn too), whose answers drift
    assert cli(env, "other", "create", "tired", "--d", "6", "--kind", "fatigue", "--population-seed", "7").returncode == 0
    assert json.loads(cli(env, "other", "reveal", "tired").stdout)["params"]["transmission"]["fatigue"] > 0
    assert cli(env, "estimator", "start", "tired", "tired", "--d", "6").returncode == 0
    r = cli(env, "estimator", "converse", "tired", "--sets", "6")
    assert r.returncode == 0 and "model check: outside what I can model" in r.stdout and "grow heavier" in r.stdout, r.stdout
    # the kinds outside the estimators' model are left out (two thirds of the run: their rule identification;
    # the section runs the same code as the in-model kinds', and test_uneven.py tests the kinds themselves)
    r = cli(env, "reproduce", "ch3", "--out", tmp_path / "rep", "--sets", "1", "--others", "1", "--kinds", "mass",
            "--no-outside", timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    report = (tmp_path / "rep/ch3/report.md").read_text()
    for fig in ("fig3_6.png", "fig3_7.png", "fig3_8.png", "fig3_14_15.png"):
        assert fig in report and (tmp_path / "rep/ch3" / fig).stat().st_size > 10_000
    assert "simulated agents" in report and "| 6 |" in report
    # the same seed again on the same (now used) cluster: the same numbers, bit for bit
    r = cli(env, "reproduce", "ch3", "--out", tmp_path / "again", "--sets", "1", "--others", "1", "--kinds",
            "mass", "--no-outside", timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "again/ch3/results.json").read_bytes() == (tmp_path / "rep/ch3/results.json").read_bytes()
    assert sorted(json.loads((tmp_path / "rep/ch3/results.json").read_text())) == [
        "identification", "open", "people", "robustness", "rules", "uneven"]
    # Ctrl-C stops the run: the conversations not started are dropped, those in flight end at their next
    # request (it ran the first section's 30 others to their end before: 86 s for the full run's 90), so
    # the conversations in flight are left unfinished and the later ones never start. (Ctrl-C as a terminal
    # sends it: a test run in the background, as CI's may be, inherits SIGINT ignored.) SIGTERM (kill,
    # timeout) the same.
    from shared.bus.client import Client
    from shared.reproduce.ch3_report import WORKERS

    def runs(c) -> list[dict]:  # the population's conversations the estimator holds (its others are ch3-KIND-i)
        return [e for e in c.request("estimator", "list", {})["estimates"]
                if e["estimate"].startswith(("ch3-mass-", "ch3-links-", "ch3-payload-"))]

    with Client(settings_of(env)) as c:
        assert runs(c) == []  # (the runs above finished every population conversation and deleted it)
        for sig in (signal.SIGINT, signal.SIGTERM):
            p = subprocess.Popen([sys.executable, "-m", "shared.cli", "reproduce", "ch3", "--out", str(tmp_path / "stopped"),
                                  "--others", "10", "--kinds", "mass,links,payload", "--no-outside"], env=env, cwd=REPO,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
            try:
                for _ in range(600):  # until the pool's first conversations have begun (a bounded wait)
                    if runs(c) or p.poll() is not None:
                        break
                    time.sleep(0.1)
                p.send_signal(sig)
                rest = p.communicate(timeout=300)[0]
                assert p.returncode == 130 and "interrupted: " in rest, (sig, p.returncode, rest)
                assert "payload:" not in rest and "rule identification" not in rest, rest
                # the conversations in flight were stopped unfinished; no more than the pool holds had begun
                left = runs(c)
                assert 1 <= len(left) <= WORKERS, (sig, left)
                for e in left:
                    c.request("estimator", "delete", {"estimate": e["estimate"]})
            finally:
                if p.poll() is None:
                    p.kill()


def test_coaching_from_the_cli(cluster, bundled, tmp_path):
    env = cluster
    squat = bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc"
    mine = sorted((bundled / "amc/squat1Reps").glob("HDM_bk_*.amc"))
    r = cli(env, "coach", "run", "--learner", "sim1", "--target", squat, "--trials", "4", "--index", "2")
    assert r.returncode == 0 and "trial 4:" in r.stdout, r.stdout + r.stderr
    # what each trial changed and why, whole (a long one under its trial's line)
    state = json.loads(cli(env, "coach", "show", r.stdout.split()[1].rstrip(":"), "--json").stdout)
    assert len(state["trials"]) == 4 and all(" ".join(t["feasibility"].split()) in " ".join(r.stdout.split())
                                             for t in state["trials"]), r.stdout
    r = cli(env, "coach", "start", "--target", squat, "--person")
    assert r.returncode == 0, r.stderr
    session = r.stdout.strip()
    out = tmp_path / "emph"
    r = cli(env, "coach", "attempt", session, *mine, "--json", "--out", out)
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    assert {"alpha", "adverb", "d_p", "file"} <= set(j) and j["d_p"] > 0
    from shared.io import load_clip

    emph = load_clip(j["file"])
    assert emph.n_frames > 10 and emph.fps == 120  # written at the rate the attempt was recorded at
    r = cli(env, "coach", "show", session)
    assert r.returncode == 0 and "trial 1: d_p" in r.stdout
    r = cli(env, "coach", "attempt", session, bundled / "amc/squat1Reps", "--out", out)  # a folder is not a clip
    assert r.returncode == 2 and r.stderr.startswith("error: ")


def test_the_dashboard_recording_holds_what_the_cluster_did(cluster, bundled, tmp_path):
    from shared.bus.client import Client
    from shared.observe.recording import read

    env = cluster
    s = settings_of(env)
    # malformed events on every topic the observer draws (it died on each and
    # every restart opened a new recording): refused one by one, in the log, and it goes on
    import msgpack

    with Client(s) as c:
        for payload in (msgpack.packb(5), b"\xc1\xc1", msgpack.packb({"session": 3}), msgpack.packb([1, 2])):
            for topic in ("coach/trial", "coach/session", "pss/space", "estimator/progress", "dialogue/transcript"):
                c.session.put(s.key("events", *topic.split("/")), payload)
    squat = bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc"
    assert cli(env, "coach", "run", "--learner", "obs", "--target", squat, "--trials", "3", "--session", "watched",
               ).returncode == 2  # --session continues an existing session only
    r = cli(env, "coach", "start", "--target", squat, "--learner", "obs", "--session", "watched")
    assert r.returncode == 0, r.stderr
    assert cli(env, "coach", "run", "--learner", "obs", "--session", "watched", "--trials", "3").returncode == 0
    with Client(s) as c:
        c.request("simulator", "other_create", {"other": "o", "params": {"d": 6, "g_max": 0.6}})
        c.request("estimator", "start", {"estimate": "watch", "other": "o", "d": 6})
        c.request("estimator", "converse", {"estimate": "watch", "sets": 2})
        lines = len(c.request("dialogue", "transcript", {"dialogue": "watch"})["lines"])
    assert cli(env, "down").returncode == 0  # the observer flushes its recording on SIGTERM
    rec = s.home / "recordings" / "latest.rrd"
    assert len(list((s.home / "recordings").glob("2*.rrd"))) == 1  # one observer run: never restarted
    log = (s.home / "logs" / "observer.log").read_text()
    assert log.count("refused event on") == 20 and "Traceback" not in log and "(20 refused)" in log
    data = read(rec)
    paths = set(data)
    for p in ("/sessions/watched/d_p", "/sessions/watched/alpha", "/sessions/watched/now", "/sessions/watched/coaching",
              "/sessions/watched/space/path", "/sessions/watched/space/emphatic", "/sessions/watched/body/target",
              "/sessions/watched/body/attempt", "/sessions/watched/body/emphatic", "/sessions/watched/overlay/emphatic",
              "/sessions/watched/curves/rfemur.rx/emphatic", "/estimates/watch/scale", "/estimates/watch/transcript",
              "/estimates/watch/space/proto_symbols/points", "/readme", "/cluster/latency"):
        assert p in paths, p
    # a bar per trial so far, on each trial's block; the playing trial's bar apart
    bars = [r for r in data["/sessions/watched/d_p"] if r.get("BarChart:values") is not None]
    assert [r["trial"] for r in bars] == [1, 2, 3]
    assert [len(r["BarChart:values"][0]["buffer"]) for r in bars] == [1, 2, 3]
    assert [r["trial"] for r in data["/sessions/watched/d_p/now"] if r.get("BarChart:values") is not None] == [1, 2, 3]
    path = data["/sessions/watched/space/path"][-1]["LineStrips2D:strips"][0]
    assert len(path) == 3  # the attempts' path across the trials
    scale = [r for r in data["/estimates/watch/scale"] if r.get("BarChart:values") is not None]
    assert [int(r["set"]) for r in scale] == [1, 2] and all(int(r["playback"]) == 0 for r in scale)  # on set, and at playback 0
    assert abs(scale[-1]["BarChart:values"][0]["buffer"][-1] - 2.0) < 0.1
    transcript = [r for r in data["/estimates/watch/transcript"] if r.get("TextLog:text")]
    assert len(transcript) == lines and {r["set"] for r in transcript} == {1, 2}  # each line on its own set
    assert "| coach | run | " in data["/cluster/latency"][-1]["TextDocument:text"][0]
    # every motion of a trial has the same number of frames on the playback timeline: they play in step
    frames = {role: sorted({r["playback"] for r in data[f"/sessions/watched/body/{role}"] if r.get("trial") == 2})
              for role in ("target", "attempt", "emphatic")}
    assert frames["target"] == frames["attempt"] == frames["emphatic"] and len(frames["target"]) > 10


def test_up_fails_fast_and_names_the_cause_when_the_router_port_is_taken(tmp_path):
    """A foreign program on the router's port made `up` wait its whole timeout
    and then blame the services."""
    import socket

    with socket.socket() as foreign:
        foreign.bind(("127.0.0.1", 0))
        foreign.listen()
        port = foreign.getsockname()[1]
        env = cluster_env(tmp_path / "home", MIRRORCOACH_ROUTER=f"tcp/127.0.0.1:{port}")
        r = cli(env, "up", "--wait", "120")
    assert r.returncode != 0 and f"port 127.0.0.1:{port} is in use" in r.stdout + r.stderr, r.stdout + r.stderr
    # nothing was started, so nothing was waited for (the cause is found before the supervisor)
    assert not (tmp_path / "home" / "run" / "supervisor.pid").exists()
    assert "starting the cluster" not in r.stdout


def _cluster_processes(env) -> list[int]:
    """Pids of every live process of this test's cluster (its unique prefix in the environment)."""
    mark = f"MIRRORCOACH_PREFIX={env['MIRRORCOACH_PREFIX']}".encode()
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            if mark in (d / "environ").read_bytes().split(b"\0") and (d / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                pids.append(int(d.name))
        except OSError:
            continue
    return pids


def _wait_gone(env, timeout=60.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while (left := _cluster_processes(env)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def test_the_supervisor_owns_its_children(tmp_path):
    """Kill -9 of the supervisor once orphaned all its children, `up` then started
    duplicates and said "cluster up", and two `up` at once ran 12 services."""
    from shared.bus.cluster import load_plan

    env = cluster_env(tmp_path / "home")
    n = 1 + len(load_plan())  # the supervisor, the router and every service of shared/bus/cluster.toml
    try:
        assert cli(env, "up").returncode == 0
        assert len(_cluster_processes(env)) == n
        sup = int((tmp_path / "home/run/supervisor.pid").read_text().split()[0])
        os.kill(sup, signal.SIGKILL)
        assert _wait_gone(env) == [], "children outlived their supervisor"
        r = cli(env, "up")
        assert r.returncode == 0 and "cluster up" in r.stdout, r.stdout + r.stderr
        assert len(_cluster_processes(env)) == n
        assert cli(env, "down").returncode == 0
        assert _wait_gone(env) == []
        # two `up` at the same time: one supervisor, one set of services, both commands succeed
        ups = [subprocess.Popen([sys.executable, "-m", "shared.cli", "up"], env=env, cwd=REPO, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT) for _ in range(2)]
        outs = [u.communicate(timeout=300)[0] for u in ups]
        assert [u.returncode for u in ups] == [0, 0], outs
        assert len(_cluster_processes(env)) == n, outs
        assert cli(env, "status").returncode == 0
    finally:
        cli(env, "down")
    assert _wait_gone(env) == []


def test_the_router_limits_its_malloc_arenas_unless_the_environment_says(cluster):
    """With glibc's default malloc arenas the router's resident memory climbed 41 -> 95 MB over
    10,000 client sessions (``bench.memory``): it asks for ``MALLOC_ARENAS`` when it starts,
    however it is started (the supervisor, systemd, a container); ``MALLOC_ARENA_MAX`` wins."""
    from shared.bus.router import MALLOC_ARENAS

    log = (Path(cluster["MIRRORCOACH_HOME"]) / "logs" / "router.log").read_text()
    assert f"malloc arenas at most {MALLOC_ARENAS}" in log, log[-2000:]
    code = "from shared.bus.router import limit_malloc_arenas; print(limit_malloc_arenas())"
    env = {**cluster, "MALLOC_ARENA_MAX": "2"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=REPO, timeout=60)
    assert r.stdout.strip() == "malloc arenas as MALLOC_ARENA_MAX says (2)", r.stdout + r.stderr


def test_every_service_sets_its_allocator_before_it_serves(cluster):
    """Each service answering requests, however it is started, allocates from one arena and maps large
    blocks on their own (``service_allocator``), and says so in its log."""
    from shared.bus.budget import MMAP_THRESHOLD
    from shared.bus.cluster import load_plan
    from shared.bus.deploy import SERVICES

    logs = Path(cluster["MIRRORCOACH_HOME"]) / "logs"
    assert set(SERVICES) <= {p.name for p in load_plan()}  # every service answering requests is in the cluster's plan
    for name in SERVICES:  # (the observer answers no requests)
        log = (logs / f"{name}.log").read_text()
        assert f"allocator: one arena, blocks of {MMAP_THRESHOLD // 1024} KB or more mapped on their own" in log, (
            name, log[-2000:])


def test_a_reused_pid_is_never_taken_for_the_supervisor(tmp_path):
    """Another process's pid in the pid file made `up` refuse for 120 s and
    `down` signal that unrelated process."""
    env = cluster_env(tmp_path / "home")
    run = tmp_path / "home/run"
    run.mkdir(parents=True)
    stranger = subprocess.Popen(["sleep", "600"])
    try:
        for content in (f"{stranger.pid}", f"{stranger.pid} 1"):  # an old-style file; a wrong start time
            (run / "supervisor.pid").write_text(content)
            (run / "coach.pid").write_text(content)
            r = cli(env, "down")
            assert r.returncode == 0 and "not running" in r.stdout, r.stdout + r.stderr
            assert stranger.poll() is None, "down signalled an unrelated process"
        (run / "supervisor.pid").write_text(f"{stranger.pid} 1")
        r = cli(env, "up")
        assert r.returncode == 0 and "starting the cluster" in r.stdout and "already running" not in r.stdout, r.stdout
        assert cli(env, "down").returncode == 0
        assert stranger.poll() is None
    finally:
        stranger.kill()
        cli(env, "down")
    assert _wait_gone(env) == []


def _wait_dead(pid: int, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
        st = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] if Path(f"/proc/{pid}").exists() else "X"
        if st == "Z":
            return
        time.sleep(0.05)


def test_requests_in_flight_share_their_clients_one_watch_thread(cluster, dev_split):
    """A request without a timeout of its own is watched by its client's one watcher thread (the
    wait ended at MIRRORCOACH_TIMEOUT or the verb's limit), not by a thread it starts: three
    builds in flight at once, one 'request-watch' thread."""
    from concurrent.futures import ThreadPoolExecutor

    from shared.bus.client import Client

    clips = [clip_to_wire(x.resample(30)) for x in dev_split[0][:14]]
    seen = []
    with Client(settings_of(cluster)) as c, ThreadPoolExecutor(3) as pool:
        futures = [pool.submit(c.request, "pss", "build", {"space": f"watched{i}", "clips": clips, "replace": True})
                   for i in range(3)]
        while not all(f.done() for f in futures):
            seen.append(sum(t.name == "request-watch" for t in threading.enumerate()))
            time.sleep(0.005)
        assert all(f.result()["n_proto_symbols"] == 14 for f in futures)
    assert seen and max(seen) == 1, seen


@pytest.mark.slow
def test_a_long_request_is_waited_for_and_a_frozen_service_noticed(cluster, dev_split):
    """Without --timeout the client waits MIRRORCOACH_TIMEOUT, extended to the verb's own limit
    when its contract allows more (a build of seconds with the timeout at 1 s is answered), and
    past it a watchdog notices a service frozen mid-request within seconds, not at 600 s."""
    from shared.bus.client import Client, Unavailable

    env = cluster
    s = settings_of(env)
    s.timeout = 1.0
    with Client(s) as c:
        for n in (14, 28, len(dev_split[0])):  # a build that outlasts the client's 1 s three times over here
            clips = [clip_to_wire(x.resample(30)) for x in dev_split[0][:n]]
            t0 = time.monotonic()
            info = c.request("pss", "build", {"space": "long", "clips": clips, "covariance_type": "full",
                                              "replace": True})
            took = time.monotonic() - t0
            assert info["n_proto_symbols"] == n  # answered although it took longer than MIRRORCOACH_TIMEOUT
            if took > 3.0:
                break
        assert took > 1.0, took
        c.request("pss", "delete", {"space": "long"})  # else the same request keeps the space it built
        outcome = {}

        def build():
            try:
                c.request("pss", "build", {"space": "long", "clips": clips, "covariance_type": "full", "replace": True})
                outcome["ok"] = True
            except Unavailable as e:
                outcome["error"] = e

        t = threading.Thread(target=build)
        t.start()
        marker = Path(env["MIRRORCOACH_HOME"]) / "data" / "pss" / "long.pending.json"
        deadline = time.monotonic() + 60
        while not marker.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(1.5)  # past the client's 1 s: only the watchdog keeps the wait going
        pid = int((Path(env["MIRRORCOACH_HOME"]) / "run" / "pss.pid").read_text().split()[0])
        os.kill(pid, signal.SIGSTOP)
        try:
            t0 = time.monotonic()
            t.join(timeout=120)
            noticed = time.monotonic() - t0
        finally:
            os.kill(pid, signal.SIGCONT)
    assert "error" in outcome, outcome  # (the build takes more than 3 s: it cannot have ended in 1.5 s)
    assert outcome["error"].details["cause"] == "frozen" and noticed < 30, (outcome, noticed)


@pytest.mark.slow
def test_no_answer_names_its_cause(tmp_path):
    """The message "service X is not running (start it with `make up`)" came also when
    the router died, the service was frozen or restarting."""
    from shared.bus.client import Client, Unavailable

    env = cluster_env(tmp_path / "home")
    run = tmp_path / "home/run"
    pid = lambda name: int((run / f"{name}.pid").read_text().split()[0])  # noqa: E731

    def cause(c, service="pss"):
        with pytest.raises(Unavailable) as e:
            c.request(service, "list", timeout=3)
        return e.value.details.get("cause"), e.value.message

    try:
        assert cli(env, "up").returncode == 0
        with Client(settings_of(env)) as c:
            os.kill(pid("pss"), signal.SIGSTOP)
            try:
                got, msg = cause(c)
                assert got == "frozen" and "frozen" in msg, msg
                # `status` says so too once the frozen process's token has lapsed (not DOWN)
                deadline, row = time.monotonic() + 30, None
                while time.monotonic() < deadline:
                    row = next(x for x in json.loads(cli(env, "status", "--json").stdout) if x["name"] == "pss")
                    if not row["alive"]:
                        break
                    time.sleep(1.0)
                assert row is not None and not row["alive"] and row["state"] == "frozen", row
                assert "FROZEN" in cli(env, "status").stdout
            finally:
                os.kill(pid("pss"), signal.SIGCONT)
            deadline = time.monotonic() + 60  # a process frozen past its lease links to the router again
            while "pss" not in c.alive() and time.monotonic() < deadline:
                time.sleep(0.5)
            assert "spaces" in c.request("pss", "list", timeout=60)
            sup = pid("supervisor")
            os.kill(sup, signal.SIGSTOP)  # hold the restart, so the cause stays what it is
            try:
                victim = pid("pss")
                os.kill(victim, signal.SIGKILL)
                _wait_dead(victim)
                deadline = time.monotonic() + 30
                while "pss" in c.alive(timeout=1.0) and time.monotonic() < deadline:
                    time.sleep(0.1)
                got, msg = cause(c)
                assert got == "restarting" and "restarting" in msg, msg
                os.kill(pid("router"), signal.SIGKILL)
                _wait_dead(pid("router"))
                got, msg = cause(c, "simulator")
                assert got == "router_down" and "router" in msg, msg
            finally:
                os.kill(sup, signal.SIGCONT)
        r = cli(env, "up")  # the supervisor brings router and pss back
        assert r.returncode == 0, r.stdout
        r = cli(env, "space", "list")
        assert r.returncode == 0, r.stderr
    finally:
        cli(env, "down")


def test_cli_says_when_the_cluster_is_not_running(tmp_path, bundled):
    env = cluster_env(tmp_path / "home")
    r = cli(env, "space", "list")
    assert r.returncode == 2 and "not running" in r.stderr and "make up" in r.stderr
    r = cli(env, "status")
    assert r.returncode == 1 and "DOWN" in r.stdout


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_sigkill_during_a_build_leaves_other_spaces_intact(cluster, dev_split, bundled):
    from shared.bus.client import Client, RemoteError, Unavailable
    from shared.io import find_clips, load_clip

    env = cluster
    s = settings_of(env)
    data = s.data_dir("pss")
    small = [load_clip(f) for f in find_clips([bundled / "amc"]) if "_dg_" not in f.name]
    probe = next(load_clip(f) for f in find_clips([bundled / "amc"]) if "_dg_" in f.name)
    with Client(s) as c:
        c.request("pss", "build", {"space": "keep", "clips": [clip_to_wire(x) for x in small]})
        before = _sha(data / "keep.npz")
        point = c.request("pss", "recognize", {"space": "keep", "clips": [clip_to_wire(probe)]})["point"]

    big = [clip_to_wire(x.resample(30)) for x in dev_split[0][::3]]
    outcome = {}

    def build():
        try:
            with Client(s) as c2:
                outcome["reply"] = c2.request("pss", "build", {"space": "doomed", "clips": big, "covariance_type": "full"})
        except (RemoteError, Unavailable) as e:
            outcome["error"] = e

    t = threading.Thread(target=build)
    t.start()
    marker = data / "doomed.pending.json"
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert marker.exists(), "the build never started"
    pid = int((s.run_dir / "pss.pid").read_text().split()[0])
    os.kill(pid, signal.SIGKILL)
    t.join(timeout=120)
    assert not t.is_alive(), "the client of the killed build hung"
    assert "error" in outcome and outcome["error"].code == "unavailable", outcome

    # the supervisor restarts pss; then list and recognize work, 'keep' is untouched
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        new = (s.run_dir / "pss.pid").read_text().split() if (s.run_dir / "pss.pid").exists() else []
        if new and int(new[0]) != pid:
            break
        time.sleep(0.1)
    assert int((s.run_dir / "pss.pid").read_text().split()[0]) != pid, "pss was not restarted"
    with Client(s) as c:
        deadline = time.monotonic() + 60
        while "pss" not in c.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        listed = c.request("pss", "list")
        assert [x["space"] for x in listed["spaces"]] == ["keep"]
        assert listed["interrupted"] == [{"space": "doomed", "operation": "build",
                                          "started": listed["interrupted"][0]["started"]}]
        again = c.request("pss", "recognize", {"space": "keep", "clips": [clip_to_wire(probe)]})
        assert (again["point"] == point).all()
        assert _sha(data / "keep.npz") == before
        assert not list(data.glob(".*.npz.*")), "a half-written temporary file was left behind"
        # building it again clears the report
        c.request("pss", "build", {"space": "doomed", "clips": [clip_to_wire(x) for x in small[:3]]})
        assert c.request("pss", "list")["interrupted"] == []
    log = (s.log_dir / "supervisor.log").read_text()
    assert "pss exited with code -9; restarting" in log


@pytest.mark.slow
def test_a_study_with_scripted_participants_and_a_coach_seat(cluster, bundled, tmp_path):
    """`mirrorcoach study` runs fig. 4.3 / Table 4.2 with people's own attempts
    (here: scripted participants sending real HDM05 squats), counterbalanced and seeded, keeps a
    trial whose log line a kill lost, and exports the tidy table the report reads."""
    from shared.reproduce.tidy import matrix, read

    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    target, mine = squats[0], squats[1:]
    study = tmp_path / "study"
    r = cli(env, "study", "init", study, "--target", target, "--participants", "2", "--cases", "1,3", "--seed", "7",
            "--trials", "2")
    assert r.returncode == 0, r.stderr
    orders = [line.split("cases ")[1] for line in r.stdout.splitlines() if line.strip().startswith("P0")]
    assert sorted(orders) == ["1 -> 3", "3 -> 1"]  # counterbalanced: each order once
    assert cli(env, "study", "init", study, "--target", target, "--participants", "2", "--seed", "7").returncode == 2
    k = 0
    while True:
        r = cli(env, "study", "next", study, "--json")
        assert r.returncode == 0, r.stderr
        step = json.loads(r.stdout)
        if step.get("done"):
            break
        assert Path(step["show"]).exists()
        r = cli(env, "study", "attempt", study, mine[k % len(mine)], mine[(k + 1) % len(mine)], "--participant",
                step["participant"])
        assert r.returncode == 0, r.stderr
        k += 1
        if k == 3:  # a kill after the coach kept the trial, before the log line was whole
            log = study / "log.jsonl"
            text = log.read_text()
            log.write_text(text[: text.rstrip("\n").rfind("\n") + 1] + '{"event": "tri')
    assert k == 8  # 2 participants x 2 cases x 2 trials
    events = [json.loads(x) for x in (study / "log.jsonl").read_text().splitlines() if x.startswith('{"event":"')]
    assert sum(e.get("recovered_from_coach", False) for e in events) == 1
    r = cli(env, "study", "export", study, "--out", tmp_path / "trials.csv")
    assert r.returncode == 0, r.stderr
    rows = read(tmp_path / "trials.csv")
    assert len(rows) == 8 and {r["world"] for r in rows} == {"people"}
    assert matrix(rows, "case 3").shape == (2, 2) and np.all(matrix(rows, "case 1") > 0)
    # the coach seat: a person types adverbs (a wrong word is asked again)
    from shared.bus.client import Client  # noqa: F401  (the seat runs through the CLI only)

    answers = ["more", str(mine[0]), "way more", "much more", str(tmp_path / "none.bvh"), str(mine[1]), "a little more", ""]
    r = subprocess.run([sys.executable, "-m", "shared.cli", "study", "seat", str(study), "--coach", "c1", "--count",
                        "3", "--demonstrate"], input="\n".join(answers) + "\n", capture_output=True, text=True,
                       env=env, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "one of:" in r.stderr and "cannot read" in r.stderr and "3 attempts judged" in r.stdout
    seat = [e for e in (json.loads(x) for x in (study / "log.jsonl").read_text().splitlines()) if e["event"] == "seat"]
    assert [e["adverb"] for e in seat] == ["more", "much more", "a little more"] and all(e["d_p"] > 0 for e in seat)
    assert [("d_s" in e) for e in seat] == [True, True, False] and seat[0]["d_s"] > 0 and len(seat[0]["x_s"]) >= 2
    r = cli(env, "study", "report", study)
    assert r.returncode == 0, r.stderr
    text = (study / "report.md").read_text()
    assert "Coach seat" in text and "Table 4.3" in text and "not enough units" in text  # 2 cases of table 4.3 only
    assert "| c1 | 2 |" in text and all((study / f"fig5_{k}.png").stat().st_size > 5000 for k in (4, 5, 6))
    r = cli(env, "study", "attempt", study, mine[0], "--participant", "P09")
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "P09" in r.stderr
    # a new study in a folder of the same name takes none of the old study's trials from the coach
    shutil.rmtree(study)
    assert cli(env, "study", "init", study, "--target", target, "--participants", "2", "--cases", "1,3", "--seed",
               "7", "--trials", "2").returncode == 0
    step = json.loads(cli(env, "study", "next", study, "--json").stdout)
    assert step["trial"] == 1 and step["show"].endswith("target.bvh")


@pytest.mark.slow
def test_reproduce_coaching_reports_a_null_world_honestly(cluster, tmp_path):
    """A world that does not agree with the method: learners that copy what they see. The
    report's words are computed, so emphasis must not come out as helping there, every
    trial is in tidy.csv, and the same seed gives the same numbers. No sensitivity sweep (`--sensitivity-learners 0`:
    nothing here reads it, and it was a fifth of the test's time) and two learners per group (three took 100 s)."""
    from shared.reproduce.tidy import read

    env = cluster
    r = cli(env, "reproduce", "ch4", "--out", tmp_path / "rep", "--learners", "2", "--targets", "squat", "--families",
            "copy", "--sensitivity-learners", "0", timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    text = (tmp_path / "rep/ch4-6/report.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| Emphasis (case 3"))
    assert "holds" not in row and ("reversed" in row or "not lower" in row), row
    # the list of findings that hold is the table's rows whose every cell says holds
    table = [line for line in text.split("## Which findings hold")[1].split("Findings that hold")[0].splitlines()
             if line.startswith("| ") and not line.startswith("| finding") and not line.startswith("| Best alpha")]
    held = [line.split(" | ")[0][2:] for line in table if all(c.strip().startswith("holds")
                                                              for c in line.strip(" |").split(" | ")[1:])]
    listed = text.split("Findings that hold on every target, per family:")[1].split("##")[0]
    assert f"- `copy`: {'; '.join(held) if held else 'none'}" in listed, (held, listed)
    # the null world against the target alone: the sentence is computed from results.json
    from shared.reproduce.coaching_report import null_sentence

    results = json.loads((tmp_path / "rep/ch4-6/results.json").read_text())
    results["families"]["copy"]["squat"]["cases"] = {int(k): v for k, v in
                                                     results["families"]["copy"]["squat"]["cases"].items()}
    sentence = null_sentence("copy", results["families"]["copy"])
    assert f"- {sentence}" in text and "none of" in sentence, sentence
    rows = read(tmp_path / "rep/ch4-6/tidy.csv")
    cases = {r["condition"] for r in rows}
    assert {f"case {c}" for c in range(1, 9)} <= cases and {"sub-goal", "body part"} <= cases
    assert len([r for r in rows if r["condition"] == "case 3"]) == 2 * 4
    # the estimator in the loop (6.5.1): the strength-limited learners said how heavy each motion felt
    assert {"effort with", "effort without"} <= cases and "The estimator in the loop (6.5.1)" in text
    effort = results["families"]["copy"]["squat"]["effort"]
    assert all(1 <= k <= 4 for row in effort["felt"] for k in row) and effort["trials"] == 2 * 4
    assert any(p is not None for row in effort["predicted"] for p in row)
    for fig in ("fig6_1", "fig6_2", "fig6_5", "fig6_6", "fig6_7"):
        assert (tmp_path / f"rep/ch4-6/copy_squat_{fig}.png").stat().st_size > 5000
    # the same seed again on the same (now used) cluster: the same numbers and trials, bit for bit
    r = cli(env, "reproduce", "ch4", "--out", tmp_path / "again", "--learners", "2", "--targets", "squat", "--families",
            "copy", "--sensitivity-learners", "0", timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    for name in ("results.json", "tidy.csv"):
        assert (tmp_path / "again/ch4-6" / name).read_bytes() == (tmp_path / "rep/ch4-6" / name).read_bytes(), name
    r = cli(env, "reproduce", "ch4", "--out", tmp_path / "rep", "--families", "oracle")
    assert r.returncode == 2 and "oracle" in r.stderr and "Traceback" not in r.stderr
    # the effort policy with a simulated learner that has no strength is refused before anything is made
    squat = next((REPO / "data/hdm05/amc/squat1Reps").glob("*.amc"))
    r = cli(env, "coach", "start", "--target", squat, "--learner", "weak", "--effort")
    assert r.returncode == 2 and "strength" in r.stderr and "Traceback" not in r.stderr
    assert "weak" not in cli(env, "coach", "list").stdout


def test_a_study_trial_from_a_live_take_cut_and_said_aloud(cluster, bundled, tmp_path):
    """A participant's repetitions arrive as one take over a live stream (a replay source on a
    real loopback socket), are cut automatically, and the trial goes on with the adverb said
    into a sound file beside the next demonstration: no file chosen or cut by hand."""
    from shared.capture import speech
    from shared.capture.stream import ReplaySource, record
    from shared.capture.takes import join
    from shared.io import load_clip

    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    target, bd = squats[0], [s for s in squats if "_bd_" in s.name]
    study = tmp_path / "study"
    r = cli(env, "study", "init", study, "--target", target, "--participants", "1", "--cases", "2", "--trials", "2",
            "--seed", "3")
    assert r.returncode == 0, r.stderr
    joined, _ = join([load_clip(f) for f in bd] * 2, seed=5)
    with ReplaySource(joined.resample(30.0), speed=8.0, connections=1) as src:
        take = record(src.address, tmp_path / "take.bvh", seconds=60, idle=1.0)
    assert take.frames > 0 and take.dropped == 0
    r = cli(env, "study", "attempt", study, "--take", take.path, "--expected", "4", "--participant", "P01")
    assert r.returncode == 0, r.stderr
    assert "repetition(s) found" in r.stderr or "repetitions than expected" in r.stderr, r.stderr
    assert 'say "more like this"' in r.stdout, r.stdout
    shown = Path(r.stdout.split("next: show ")[1].split(" and say")[0])
    assert shown.exists()
    if speech.available():
        wav = shown.with_suffix(".wav")
        seconds, rms = speech.measure(wav)
        assert 0.3 < seconds < 5.0 and rms > 0.01
    r = cli(env, "study", "attempt", study, "--participant", "P01")
    assert r.returncode == 2 and "not both" in r.stderr


@pytest.mark.slow
def test_a_whole_study_runs_live_from_replayed_takes(cluster, bundled, tmp_path):
    """`study run` with a live source: 2 participants x 2 cases x 2 trials, each trial's take
    recorded from the stream, cut, scored and logged, without a file chosen by hand; the study's
    export is the same table as with `study attempt`."""
    from shared.capture.stream import ReplaySource
    from shared.capture.takes import join
    from shared.io import load_clip
    from shared.reproduce.tidy import read

    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    bd = [load_clip(s) for s in squats if "_bd_" in s.name]
    study = tmp_path / "study"
    r = cli(env, "study", "init", study, "--target", squats[0], "--participants", "2", "--cases", "1,2", "--trials",
            "2", "--seed", "5")
    assert r.returncode == 0, r.stderr
    takes = [join(bd * 2, seed=k)[0].resample(30.0) for k in range(8)]
    # the source never stops on its own (a suit streams the person standing still after the take):
    # each take ends once its 4 repetitions are seen
    with ReplaySource(takes, speed=8.0, connections=8, hold=True) as src:
        r = cli(env, "study", "run", study, "--source", src.address, "--expected", "4", "--idle", "0.5", timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "nothing left" in r.stdout and r.stdout.count("recording from") == 8
    assert r.stderr.count("4 repetitions seen") == 8, r.stderr
    assert len(list((study / "takes").glob("*.bvh"))) == 8
    r = cli(env, "study", "export", study, "--out", tmp_path / "trials.csv")
    assert r.returncode == 0, r.stderr
    rows = read(tmp_path / "trials.csv")
    assert len(rows) == 8 and {r["world"] for r in rows} == {"people"}
    # a second study with the same participants (in a folder of the same name) records takes of its own on the
    # capture service: the first study's are not recorded over (they are named with each study's id)
    again = tmp_path / "again" / "study"
    r = cli(env, "study", "init", again, "--target", squats[0], "--participants", "2", "--cases", "1,2", "--trials",
            "2", "--seed", "5")
    assert r.returncode == 0, r.stderr
    with ReplaySource(takes[:1], speed=8.0, connections=1, hold=True) as src:
        r = cli(env, "study", "run", again, "--source", src.address, "--expected", "4", "--idle", "0.5", "--steps", "1",
                timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    r = cli(env, "capture", "takes", "--json")
    assert r.returncode == 0, r.stderr
    names = [t["take"] for t in json.loads(r.stdout)]
    first, second = (json.loads((f / "log.jsonl").read_text().splitlines()[0])["plan"]["study"] for f in (study, again))
    assert first != second, first
    assert sum(n.startswith(f"study-{first}-") for n in names) == 8, names
    assert sum(n.startswith(f"study-{second}-") for n in names) == 1, names


@pytest.mark.slow
def test_a_live_take_is_redone_and_a_participant_skipped_on_request(cluster, bundled, tmp_path):
    """While `study run` records, `study redo` from another terminal records the take again (the
    person stood still: the first take is never scored) and `study skip` leaves a participant for
    a later run (the other participant's trials go on); the trials done are logged as any other."""
    from shared.capture.stream import ReplaySource
    from shared.capture.takes import join
    from shared.io import load_clip

    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    bd = [load_clip(s).resample(30.0) for s in squats if "_bd_" in s.name]
    study = tmp_path / "study"
    r = cli(env, "study", "init", study, "--target", squats[0], "--participants", "2", "--cases", "2", "--trials", "2",
            "--seed", "5")
    assert r.returncode == 0, r.stderr
    still = bd[0].with_data(np.repeat(bd[0].data[:1], 60, axis=0))  # a person standing, streamed without end
    take, _ = join(bd * 2, seed=1)
    lines: list[str] = []
    with ReplaySource([still, take, still, take, take], connections=5, hold=True, speed=4.0) as src:
        run = subprocess.Popen([sys.executable, "-m", "shared.cli", "study", "run", str(study), "--source", src.address,
                                "--expected", "4", "--idle", "5"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, env=env, cwd=REPO)
        reader = threading.Thread(target=lambda: lines.extend(run.stdout), daemon=True)
        reader.start()

        def wait_for(text: str, timeout: float = 120.0) -> None:
            deadline = time.monotonic() + timeout
            while not any(text in x for x in lines) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert any(text in x for x in lines), "".join(lines)

        wait_for("P01, case 2, trial 1: recording")
        time.sleep(2.0)
        assert cli(env, "study", "redo", study).returncode == 0
        wait_for("redone on request")
        wait_for("P01, case 2, trial 2: recording")
        time.sleep(2.0)
        assert cli(env, "study", "skip", study).returncode == 0
        assert run.wait(timeout=120) == 0, "".join(lines)
        reader.join(timeout=10)
    out = "".join(lines)
    assert "P01: skipped on request" in out and "nothing left in this run (P01 skipped" in out, out
    assert out.count("4 repetitions seen") == 3 and out.count("redone on request") == 1, out
    assert sorted(p.name for p in (study / "takes").glob("*.bvh")) == ["P01_case2_trial1_2.bvh", "P02_case2_trial1_1.bvh",
                                                                       "P02_case2_trial2_1.bvh"]
    step = json.loads(cli(env, "study", "next", study, "--json").stdout)
    assert (step["participant"], step["trial"]) == ("P01", 2), step


def test_ctrl_c_during_a_live_take_stops_it_and_the_run_starts_again(cluster, bundled, tmp_path):
    """Ctrl-C while `study run` records stops the take on the capture service too (it would go on
    recording a suit that streams on, and the run started again would be refused: "is being
    recorded"); the run started again records the trial."""
    from shared.capture.stream import ReplaySource
    from shared.capture.takes import join
    from shared.io import load_clip

    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    bd = [load_clip(s).resample(30.0) for s in squats if "_bd_" in s.name]
    study = tmp_path / "study"
    assert cli(env, "study", "init", study, "--target", squats[0], "--participants", "1", "--cases", "2", "--trials",
               "2", "--seed", "5").returncode == 0
    still = bd[0].with_data(np.repeat(bd[0].data[:1], 60, axis=0))  # a person standing, streamed without end
    with ReplaySource([still, join(bd * 2, seed=1)[0]], connections=2, hold=True, speed=4.0) as src:
        run = subprocess.Popen([sys.executable, "-m", "shared.cli", "study", "run", str(study), "--source", src.address,
                                "--expected", "4", "--idle", "5"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, env=env, cwd=REPO)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not [t for t in json.loads(cli(env, "capture", "takes", "--json").stdout)
                                                   if t["state"] == "recording" and t["frames"] > 0]:
            time.sleep(0.2)
        run.send_signal(signal.SIGINT)
        out, _ = run.communicate(timeout=60)
        assert run.returncode != 0 and "interrupted" in out and "Traceback" not in out, out
        takes = json.loads(cli(env, "capture", "takes", "--json").stdout)
        assert [t["state"] for t in takes if "P01_case2_trial1" in t["take"]] == ["done"], takes
        r = cli(env, "study", "run", study, "--source", src.address, "--expected", "4", "--idle", "5", "--steps", "1",
                timeout=300)
    assert r.returncode == 0 and "P01, case 2, trial 1: d_p" in r.stdout, r.stdout + r.stderr
    assert r.stderr.count("4 repetitions seen") == 1, r.stderr


def test_coach_live_runs_trials_from_a_live_source(cluster, bundled, tmp_path):
    """`coach live`: a new person session started on the target, two trials whose takes come from a
    source that never stops (each ends once its repetitions are seen); each trial's demonstration
    and spoken adverb are written to the session's folder, its take kept, the trials on the coach."""
    from shared.capture import speech
    from shared.capture.stream import ReplaySource
    from shared.capture.takes import join
    from shared.io import load_clip

    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    bd = [load_clip(s).resample(30.0) for s in squats if "_bd_" in s.name]
    takes = [join(bd * 2, seed=k)[0] for k in range(2)]
    with ReplaySource(takes, connections=2, hold=True, speed=8.0) as src:
        r = cli(env, "coach", "live", "live1", "--target", squats[0], "--source", src.address, "--trials", "2",
                "--expected", "4", "--out", tmp_path / "live", timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "started session live1" in r.stderr and r.stderr.count("4 repetitions seen") == 2, r.stderr
    assert "trial 1: d_p" in r.stdout and "trial 2: d_p" in r.stdout, r.stdout
    shown = sorted(p.name for p in (tmp_path / "live").glob("live1_trial*.bvh"))
    assert shown == ["live1_trial2.bvh", "live1_trial3.bvh"]
    assert sorted(p.name for p in (tmp_path / "live/takes").glob("*.bvh")) == ["live1_trial1_1.bvh", "live1_trial2_1.bvh"]
    if speech.available():
        assert len(list((tmp_path / "live").glob("live1_trial*.wav"))) == 2
    from shared.bus.client import Client

    with Client(settings_of(env)) as c:
        assert len(c.request("coach", "state", {"session": "live1"})["trials"]) == 2
    r = cli(env, "coach", "live", "nope", "--target", squats[0], "--source", "tcp://127.0.0.1:9", "--trials", "1",
            "--out", tmp_path / "x")
    assert r.returncode != 0 and "no live source" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_coach_live_with_a_space_naming_the_repetitions(cluster, bundled, tmp_path):
    """`coach live --space`: a space built on the pss service from two other performers' motions
    names the person's repetitions (bk's kicks against bd's kick, which the cohort check misses:
    tests/test_segmentation.py); the trial's take ends once its four are seen. A space the
    cluster does not hold is refused in a sentence before any take is recorded."""
    from shared.capture.stream import ReplaySource
    from shared.capture.takes import join
    from shared.io import load_clip

    env = cluster
    amc = sorted((bundled / "amc").glob("*/*.amc"))
    r = cli(env, "space", "build", "live-moves", *[f for f in amc if "_bk_" not in f.name], "--replace", timeout=300)
    assert r.returncode == 0, r.stderr
    kick = next(f for f in amc if "_bd_kick" in f.name)
    bk = [load_clip(f).resample(30.0) for f in amc if "_bk_kick" in f.name]
    with ReplaySource([join(bk * 2, seed=7)[0]], connections=1, hold=True, speed=4.0) as src:
        r = cli(env, "coach", "live", "live2", "--target", kick, "--source", src.address, "--trials", "1",
                "--expected", "4", "--space", "live-moves", "--out", tmp_path / "live", timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "4 repetitions seen" in r.stderr and "trial 1: d_p" in r.stdout, r.stderr
    r = cli(env, "coach", "live", "live3", "--target", kick, "--source", "tcp://127.0.0.1:9", "--trials", "1",
            "--space", "nowhere", "--out", tmp_path / "x")
    assert r.returncode != 0 and "nowhere" in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.slow
def test_a_study_sweeps_alpha_per_person_and_feeds_emu2(cluster, bundled, tmp_path):
    """Thesis 5.4.1 with people: `--cases sweep` plans each participant's alpha sweep (without
    and with the adverb, counterbalanced like any case), `study emu2` picks each one's alpha that
    ended lowest, and a second study's cases 5 and 6 coach with those alphas."""
    env = cluster
    squats = sorted((bundled / "amc/squat1Reps").glob("*.amc"))
    target, mine = squats[0], squats[1:]
    sweep = tmp_path / "sweep"
    r = cli(env, "study", "init", sweep, "--target", target, "--participants", "1", "--cases", "sweep", "--seed", "3",
            "--trials", "2")
    assert r.returncode == 0, r.stderr
    k = 0
    while True:
        step = json.loads(cli(env, "study", "next", sweep, "--json").stdout)
        if step.get("done"):
            break
        # the second trial's attempt depends on the case: the participant "responds" to some alphas better
        clip = mine[0] if step["trial"] == 1 else mine[1 + (step["case"] % 3)]
        r = cli(env, "study", "attempt", sweep, clip, "--participant", step["participant"])
        assert r.returncode == 0, r.stderr
        k += 1
    assert k == 14 * 2
    from shared.reports.study import SWEEP_CASES, load, read_log, trials_of

    events = read_log(sweep)
    done = trials_of(events)
    want = []
    for adverb in (None, "table"):
        ratio = {a: done[("P01", c)][1]["d_p"] / done[("P01", c)][0]["d_p"] for c, (a, adv) in SWEEP_CASES.items()
                 if adv == adverb}
        want.append(min(ratio, key=ratio.get))
    got = json.loads(cli(env, "study", "emu2", sweep, "--json").stdout)
    assert got == {"P01": want}
    follow = tmp_path / "emu2"
    r = cli(env, "study", "init", follow, "--target", target, "--participants", "1", "--cases", "5,6", "--seed", "3",
            "--trials", "2", "--emu2", sweep)
    assert r.returncode == 0, r.stderr
    assert load(follow)["emu2"] == {"P01": want}
    r = cli(env, "study", "report", sweep)
    assert r.returncode == 0, r.stderr
    text = (sweep / "report.md").read_text()
    assert "## Alpha sweep" in text and f"P01 {want[0]:g} / {want[1]:g}" in text and (sweep / "fig5_7.png").exists()
    r = cli(env, "study", "init", tmp_path / "bad", "--target", target, "--participants", "1", "--cases", "1,swep",
            "--seed", "3")
    assert r.returncode == 2 and "'swep'" in r.stderr


def test_a_process_cpu_seconds_are_the_kernels():
    """bench.ch3 counts each cluster process's CPU from its pid file (shared.bus.pidfiles.cpu_seconds):
    the same seconds the process sees of itself, and none for a process that is gone."""
    from shared.bus.pidfiles import cpu_seconds

    sum(i * i for i in range(2_000_000))  # some CPU of our own
    mine, t = cpu_seconds(os.getpid()), os.times()
    assert mine is not None and mine > 0 and abs(mine - (t.user + t.system)) <= 0.05, (mine, t)
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    assert cpu_seconds(gone.pid) is None
