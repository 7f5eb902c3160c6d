"""The capture service as a real process on a real router (services/capture, schemas/capture.py):
takes recorded from a live BVH source over loopback TCP and from clips replayed through the same
path, frames published as they arrive, repetitions found, every refusal a coded error."""

import time

import numpy as np
import pytest

from schemas.common import clip_from_wire, clip_to_wire
from shared.bus.client import RemoteError
from shared.capture.stream import ReplaySource
from shared.capture.takes import join, score
from shared.io import load_clip


@pytest.fixture(scope="module")
def squats(bundled):
    files = sorted((bundled / "amc/squat1Reps").glob("HDM_bk_*.amc"))
    return [load_clip(f).resample(30.0) for f in files[:2]]


def _wait_done(c, take: str, timeout: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        info = c.request("capture", "status", {"take": take})
        if info["state"] != "recording":
            return info
        time.sleep(0.1)
    raise AssertionError(f"take {take} still recording after {timeout} s")


@pytest.mark.slow
def test_a_replayed_take_is_recorded_published_and_cut(capture_service, client_of, squats):
    """Three squats joined with rests, replayed through a loopback TCP port by the service: every
    frame arrives on the bus in order, the take is kept, and its three repetitions are found where
    they are (the target another squat of the same performer)."""
    env, _ = capture_service
    c = client_of(env)
    blocks, takes = [], []
    c.subscribe("events/capture/frames", lambda k, m: blocks.append(m) if m["take"] == "t1" else None)
    c.subscribe("events/capture/take", lambda k, m: takes.append(m) if m["take"] == "t1" else None)
    time.sleep(0.3)
    take, truth = join([squats[1]] * 3, seed=4)
    started = c.request("capture", "record", {"take": "t1", "replay": [clip_to_wire(take)]})
    assert started["state"] == "recording" and started["source"] == "replay of 1 clip(s)"
    info = _wait_done(c, "t1")
    assert info["state"] == "done" and info["frames"] == take.n_frames and info["dropped"] == 0, info
    deadline = time.monotonic() + 10
    while (not takes or takes[-1]["state"] == "recording") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [t["state"] for t in takes] == ["recording", "done"]
    data = np.vstack([b["data"] for b in sorted(blocks, key=lambda b: b["first"])])
    assert [b["first"] for b in blocks] == sorted(b["first"] for b in blocks)  # in order
    assert data.shape[0] == take.n_frames and blocks[0]["fps"] == pytest.approx(30.0)
    recorded = clip_from_wire(c.request("capture", "clip", {"take": "t1"})["clip"])
    assert recorded.n_frames == take.n_frames and np.allclose(data, recorded.data, atol=1e-3)
    seg = c.request("capture", "segment", {"take": "t1", "target": clip_to_wire(squats[0]), "expected": 3})
    found = [(r["start"], r["end"]) for r in seg["repetitions"]]
    assert score(found, truth)["f1"] == 1.0 and seg["verdict"] == "3 repetition(s) found", seg
    assert len(seg["clips"]) == 3 and all(x["channels"] == recorded.channels for x in seg["clips"])
    assert "t1" in [t["take"] for t in c.request("capture", "list", {})["takes"]]


@pytest.mark.slow
def test_a_live_source_the_service_connects_to_and_a_take_stopped_on_request(capture_service, client_of, squats):
    """A source outside the service (as a capture suit is), streaming without end: the take ends
    when asked, its frames kept; a take ends by itself once the expected repetitions are seen."""
    env, _ = capture_service
    c = client_of(env)
    with ReplaySource(squats[0], loop=True, connections=1) as src:
        c.request("capture", "record", {"take": "live", "source": src.address, "seconds": 60})
        deadline = time.monotonic() + 30  # frames arriving, however slow the machine
        while c.request("capture", "status", {"take": "live"})["frames"] <= 10 and time.monotonic() < deadline:
            time.sleep(0.1)
        info = c.request("capture", "stop", {"take": "live"})
    assert info["state"] == "done" and info["ended"] == "stopped on request" and info["frames"] > 10, info
    take, _ = join([squats[1]] * 2, seed=5)
    with ReplaySource(take, connections=1, hold=True) as src:
        c.request("capture", "record", {"take": "two", "source": src.address, "seconds": 60,
                                        "target": clip_to_wire(squats[0]), "expected": 2})
        info = _wait_done(c, "two")
    assert info["state"] == "done" and info["ended"] == "2 repetitions seen", info
    # cut as it was found while recording, and again from the file for another count
    seen = c.request("capture", "segment", {"take": "two", "target": clip_to_wire(squats[0]), "expected": 2})
    again = c.request("capture", "segment", {"take": "two", "target": clip_to_wire(squats[0]), "expected": 3})
    assert seen["verdict"] == "2 repetition(s) found" and len(seen["clips"]) == 2
    assert again["verdict"] == "fewer repetitions than expected: 2 found, 3 expected"
    assert [r["start"] for r in seen["repetitions"]] == pytest.approx([r["start"] for r in again["repetitions"]], abs=0.02)


@pytest.mark.slow
def test_a_take_recorded_with_other_motions_is_cut_with_them(capture_service, client_of, squats):
    """The other motions a take is recorded with are its cut's cohort when the cut names none:
    a take of the very squat given as another motion holds no repetition of the target (nearer
    to that motion), while the same take recorded without it holds both; the recorded motions
    are not used for another target."""
    env, _ = capture_service
    c = client_of(env)
    take, truth = join([squats[1]] * 2, seed=6)
    for name, background in (("told", [clip_to_wire(squats[1])]), ("plain", [])):
        c.request("capture", "record", {"take": name, "replay": [clip_to_wire(take)],
                                        "target": clip_to_wire(squats[0]), "expected": 2, "background": background})
        assert _wait_done(c, name)["state"] == "done"
    told = c.request("capture", "segment", {"take": "told", "target": clip_to_wire(squats[0]), "expected": 2})
    assert told["repetitions"] == [] and "nearer to another motion" in told["verdict"], told["verdict"]
    plain = c.request("capture", "segment", {"take": "plain", "target": clip_to_wire(squats[0]), "expected": 2})
    assert score([(r["start"], r["end"]) for r in plain["repetitions"]], truth)["f1"] == 1.0, plain["verdict"]
    other = c.request("capture", "segment", {"take": "told", "target": clip_to_wire(squats[1]), "expected": 2})
    assert len(other["repetitions"]) == 2, other["verdict"]


@pytest.mark.slow
def test_a_space_of_the_pss_service_names_another_performers_repetitions(capture_service, client_of, bundled):
    """bk's kicks against bd's kick: the cohort check finds none (their closest stretch costs more
    than its largest first cost: tests/test_segmentation.py), a space the pss service holds (bd's
    and dg's motions) names each a kick through the bus: the take ends once its four are seen, and
    its cut (the space it was recorded with, by default) finds them where they are; a take of
    squats holds none. A space or label the service cannot use (one that models torques a take
    does not have) is refused before recording."""
    env, _ = capture_service
    c = client_of(env)
    classes = ["elbowToKnee1RepsLelbowStart", "kickLFront1Reps", "rotateArmsBothBackward1Reps", "squat1Reps"]

    def clips(performer, cls):
        return [load_clip(f) for f in sorted((bundled / "amc" / cls).glob(f"HDM_{performer}_*.amc"))]

    space = [clip_to_wire(x) for p in ("bd", "dg") for k in classes for x in clips(p, k)]
    c.request("pss", "build", {"space": "moves", "clips": space, "replace": True}, timeout=120)
    target = clip_to_wire(clips("bd", "kickLFront1Reps")[0])
    take, truth = join(clips("bk", "kickLFront1Reps") * 2, seed=7)
    with ReplaySource(take, connections=1, hold=True, speed=4.0) as src:  # a source that goes on after the take
        c.request("capture", "record", {"take": "kicks", "source": src.address, "seconds": 120, "target": target,
                                        "expected": 4, "space": "moves"})
        info = _wait_done(c, "kicks", timeout=120)
    assert info["state"] == "done" and info["ended"] == "4 repetitions seen", info
    cut = c.request("capture", "segment", {"take": "kicks", "target": target, "expected": 4}, timeout=120)
    assert score([(r["start"], r["end"]) for r in cut["repetitions"]], truth)["f1"] == 1.0, cut["verdict"]
    assert all(r["cohort"] < 1.0 for r in cut["repetitions"])
    plain = c.request("capture", "segment", {"take": "kicks", "target": target, "expected": 4,
                                             "background": [clip_to_wire(clips("dg", "squat1Reps")[0])]}, timeout=120)
    assert len(plain["repetitions"]) == 4  # the space it was recorded with still decides
    squats, _ = join(clips("bk", "squat1Reps") * 2, seed=8)
    c.request("capture", "record", {"take": "squats", "replay": [clip_to_wire(squats)]})
    _wait_done(c, "squats")
    none = c.request("capture", "segment", {"take": "squats", "target": target, "space": "moves"}, timeout=120)
    assert none["repetitions"] == [] and none["verdict"].startswith("not the target"), none["verdict"]
    from shared.bodies.arm import with_arm_torques

    felt = [clip_to_wire(with_arm_torques(x)) for k in classes[:2] for x in clips("bd", k)]
    c.request("pss", "build", {"space": "felt", "clips": felt, "replace": True}, timeout=120)
    for msg, want in (({"space": "nowhere"}, "not_found"), ({"space": "moves", "label": "jump"}, "bad_request"),
                      ({"space": "felt"}, "bad_request")):  # a space of torques no take has
        with pytest.raises(RemoteError) as e:
            c.request("capture", "record", {"take": "refused", "replay": [clip_to_wire(take)], "target": target,
                                            "expected": 4, **msg})
        assert e.value.code == want, e.value.message
    with pytest.raises(RemoteError, match="holds no motion 'jump'"):
        c.request("capture", "segment", {"take": "kicks", "target": target, "space": "moves", "label": "jump"})


def test_refusals_are_coded_errors(capture_service, client_of, squats, tmp_path):
    env, _ = capture_service
    c = client_of(env)

    def code(verb, msg):
        with pytest.raises(RemoteError) as e:
            c.request("capture", verb, msg)
        return e.value.code, e.value.message

    assert code("status", {"take": "nope"})[0] == "not_found"
    assert code("record", {"take": "x"}) == ("bad_request", "give either source (tcp://HOST:PORT) or replay (clips)")
    assert code("record", {"take": "x", "source": "localhost"})[0] == "bad_request"
    assert code("record", {"take": "x", "source": "tcp://127.0.0.1:9", "replay": [clip_to_wire(squats[0])]})[0] == \
        "bad_request"
    assert code("record", {"take": "x", "replay": [clip_to_wire(squats[0])], "expected": 2})[0] == "bad_request"
    assert code("record", {"take": "x", "replay": [clip_to_wire(squats[0])], "expected": 2,
                           "target": clip_to_wire(squats[0], with_skeleton=False)}) == \
        ("bad_request", "the target needs its skeleton to find its repetitions")
    # nothing listens on the port: the take fails with the reason, never hangs
    c.request("capture", "record", {"take": "gone", "source": "tcp://127.0.0.1:9"})
    info = _wait_done(c, "gone")
    assert info["state"] == "failed" and "no live source" in info["error"], info
    assert code("clip", {"take": "gone"})[0] == "conflict"
    c.request("capture", "record", {"take": "once", "replay": [clip_to_wire(squats[0])]})
    _wait_done(c, "once")
    assert code("record", {"take": "once", "replay": [clip_to_wire(squats[0])]})[0] == "conflict"
    again = c.request("capture", "record", {"take": "once", "replay": [clip_to_wire(squats[0])], "replace": True})
    assert again["state"] == "recording"
    _wait_done(c, "once")


@pytest.mark.slow
def test_the_cli_records_a_take_on_the_service_and_cuts_it_into_files(capture_service, squats, tmp_path):
    """`capture take --replay` and `capture cut --out` as a user runs them: the take and each
    repetition written as files `study attempt` takes; a bad option pair is a message, not a
    traceback."""
    import subprocess
    import sys

    from shared.io import save_clip
    from tests.conftest import REPO

    env, _ = capture_service
    take, truth = join([squats[1]] * 2, seed=6)
    save_clip(take, tmp_path / "take.bvh")
    save_clip(squats[0], tmp_path / "target.bvh")

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "shared.cli", *args], cwd=REPO, env=env, capture_output=True,
                              text=True, timeout=300)

    r = cli("capture", "take", "cli1", "--replay", str(tmp_path / "take.bvh"), "--idle", "5")
    assert r.returncode == 0 and "cli1: done" in r.stdout, r.stdout + r.stderr
    r = cli("capture", "cut", "cli1", "--target", str(tmp_path / "target.bvh"), "--expected", "2",
            "--out", str(tmp_path / "reps"))
    assert r.returncode == 0 and "2 repetition(s) found" in r.stdout, r.stdout + r.stderr
    assert load_clip(tmp_path / "reps/take.bvh").n_frames == take.n_frames
    reps = [load_clip(tmp_path / f"reps/rep{k}.bvh") for k in (1, 2)]
    assert all(abs(rep.duration - squats[1].duration) < 0.3 for rep in reps)
    r = cli("capture", "take", "cli2", "--target", str(tmp_path / "target.bvh"), "--replay", str(tmp_path / "take.bvh"))
    assert r.returncode != 0 and "--target and --expected go together" in r.stderr and "Traceback" not in r.stderr
    r = cli("capture", "takes")
    assert r.returncode == 0 and "cli1: done" in r.stdout


def test_a_replay_of_several_clips_is_one_take_of_all_of_them(capture_service, client_of, squats):
    env, _ = capture_service
    c = client_of(env)
    c.request("capture", "record", {"take": "both", "replay": [clip_to_wire(s) for s in squats]})
    info = _wait_done(c, "both")
    assert info["state"] == "done" and info["frames"] == sum(s.n_frames for s in squats) and info["reconnects"] == 1, info


def test_ctrl_c_while_the_cli_waits_for_a_take_ends_it(capture_service, client_of, squats):
    """`capture take` waiting on a source that never stops: Ctrl-C ends the take on the service
    (it went on recording up to --seconds) and shows it, its frames kept."""
    import signal
    import subprocess
    import sys

    from tests.conftest import REPO

    env, _ = capture_service
    c = client_of(env)
    with ReplaySource(squats[0], connections=1, hold=True) as src:
        run = subprocess.Popen([sys.executable, "-m", "shared.cli", "capture", "take", "ctrlc", "--source", src.address,
                                "--seconds", "600"], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if c.request("capture", "status", {"take": "ctrlc"})["frames"] > 0:
                    break
            except RemoteError:  # not asked for yet
                pass
            time.sleep(0.1)
        run.send_signal(signal.SIGINT)  # (the command takes Ctrl-C as its own before it asks for the take)
        out, err = run.communicate(timeout=60)
    assert run.returncode == 0 and "ctrlc: done" in out and "stopped on request" in out, out + err
    info = c.request("capture", "status", {"take": "ctrlc"})
    assert info["state"] == "done" and info["frames"] > 0, info
