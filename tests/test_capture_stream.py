"""Live motion capture: BVH over a real TCP socket on loopback (shared/capture/stream.py)."""

import os
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from shared.capture.stream import ReplaySource, parse_source, record
from shared.capture.takes import score
from shared.errors import BadInput
from shared.io import load_clip, save_clip


@pytest.fixture(scope="module")
def squat(bundled):
    clip = load_clip(sorted((bundled / "amc/squat1Reps").glob("*.amc"))[0]).resample(30.0)
    return clip.frames(0, 60)  # 2 s


def _as_bvh(clip, tmp_path):
    path = tmp_path / "ref.bvh"
    save_clip(clip, path)
    return load_clip(path)


def test_a_replayed_clip_arrives_whole(squat, tmp_path):
    """Every frame of a clip served as a live stream is recorded, as the file the clip writes."""
    with ReplaySource(squat, speed=4.0, connections=1) as src:
        take = record(src.address, tmp_path / "take.bvh", seconds=30, idle=1.0)
    ref = _as_bvh(squat, tmp_path)
    assert take.frames == squat.n_frames and take.dropped == 0 and take.reconnects == 0
    assert take.clip.channels == ref.channels and take.clip.fps == pytest.approx(30.0)
    assert np.allclose(take.clip.data, ref.data, atol=1e-4)
    assert take.ended.startswith("no frame for") or "stopped" in take.ended
    # the frame lines waited in a file beside the take, not in memory: the take is the BVH file
    # the clip writes (the same frame lines) and nothing else is left in the folder
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ref.bvh", "take.bvh"]
    ref_text, take_text = (tmp_path / "ref.bvh").read_text(), (tmp_path / "take.bvh").read_text()
    assert take_text.split("MOTION")[1].splitlines()[3:] == ref_text.split("MOTION")[1].splitlines()[3:]


def test_skipped_frames_a_stopped_source_and_a_reconnect_are_reported(squat, tmp_path):
    with ReplaySource(squat, skip=set(range(20, 30)), connections=1) as src:
        take = record(src.address, tmp_path / "gaps.bvh", seconds=30, idle=1.0)
    assert take.frames == squat.n_frames - 10 and take.skipped >= 8
    assert any("missing after frame 20" in e for e in take.events), take.events
    with ReplaySource(squat, speed=4.0, stop_after=30, connections=2) as src:
        take = record(src.address, tmp_path / "again.bvh", seconds=30, idle=1.0, reconnect=1)
    assert take.reconnects == 1 and any("reconnected after frame 30" in e for e in take.events)
    assert take.frames == 30 + 30  # the source stopped after 30 frames both times
    with ReplaySource(squat, speed=4.0, stop_after=30, connections=1) as src:
        take = record(src.address, tmp_path / "gone.bvh", seconds=30, idle=1.0, reconnect=1, connect_timeout=0.5)
    assert take.frames == 30 and "did not come back" in take.ended


def test_a_skeleton_change_ends_the_take(squat, cmu, tmp_path):
    other = load_clip(cmu / "scaled_131_01.bvh").frames(0, 10)
    with ReplaySource(squat, speed=4.0, stop_after=25, switch=other, connections=1) as src:
        take = record(src.address, tmp_path / "switch.bvh", seconds=30, idle=1.0)
    assert take.frames == 25 and take.ended == "the skeleton changed"
    assert any("skeleton changed after frame 25" in e for e in take.events)


def _raw_server(payload: bytes):
    srv = socket.create_server(("127.0.0.1", 0))

    def serve():
        conn, _ = srv.accept()
        with conn:
            conn.sendall(payload)
        srv.close()

    threading.Thread(target=serve, daemon=True).start()
    return f"tcp://127.0.0.1:{srv.getsockname()[1]}"


def test_malformed_lines_are_dropped_and_counted_and_a_headerless_stream_needs_its_skeleton(squat, tmp_path):
    save_clip(squat, tmp_path / "skeleton.bvh")
    text = (tmp_path / "skeleton.bvh").read_text().splitlines()
    motion = text.index("MOTION")
    header, rows = text[:motion + 1], text[motion + 3:]
    bad = [rows[0], "1 2 x", "1 2 3", rows[1], "", rows[2]]
    source = _raw_server(("\n".join(header + ["Frames: 0", "Frame Time: 0.0333333"] + bad) + "\n").encode())
    take = record(source, tmp_path / "bad.bvh", seconds=10, idle=1.0)
    assert take.frames == 3 and take.dropped == 2 and sum("malformed" in e for e in take.events) == 2
    source = _raw_server(("\n".join(rows[:5]) + "\n").encode())
    with pytest.raises(BadInput, match="skeleton"):
        record(source, tmp_path / "x.bvh", seconds=10, idle=1.0)
    source = _raw_server(("\n".join(rows[:5]) + "\n").encode())
    take = record(source, tmp_path / "y.bvh", seconds=10, idle=1.0, skeleton=tmp_path / "skeleton.bvh")
    assert take.frames == 5 and take.clip.fps == pytest.approx(30.0)


def test_bad_sources_are_refused_clearly(tmp_path):
    for bad in ("localhost", "tcp://host:port", "tcp://:80", "tcp://h:70000"):
        with pytest.raises(BadInput, match="tcp://HOST:PORT"):
            parse_source(bad)
    free = socket.create_server(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()
    with pytest.raises(BadInput, match="no live source"):
        record(f"tcp://127.0.0.1:{port}", tmp_path / "none.bvh", seconds=1, connect_timeout=0.5)
    with pytest.raises(BadInput, match="how long"):
        record(f"tcp://127.0.0.1:{port}", tmp_path / "none.bvh")


@pytest.mark.slow
def test_from_a_live_stream_to_repetition_files_on_the_command_line(bundled, tmp_path):
    """`capture serve` plays a take as a live source on a loopback port, `capture record` records
    it, `capture segment` cuts it into rep files that `study attempt` takes: no file cut by hand."""
    import json
    import subprocess
    import sys

    from shared.capture.takes import join

    squats = sorted((bundled / "amc/squat1Reps").glob("HDM_bd_*.amc"))
    take, truth = join([load_clip(f) for f in squats] * 2, seed=4)  # four repetitions of one performer
    save_clip(take.resample(30.0), tmp_path / "joined.bvh")
    cmd = [sys.executable, "-m", "shared.cli"]
    server = subprocess.Popen(cmd + ["capture", "serve", str(tmp_path / "joined.bvh"), "--port", "0", "--speed", "8"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        address = server.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:"), server.stderr.read()
        r = subprocess.run(cmd + ["capture", "record", str(tmp_path / "take.bvh"), "--source", address, "--seconds", "60",
                                  "--idle", "1", "--json"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        rec = json.loads(r.stdout)
        assert rec["frames"] == load_clip(tmp_path / "joined.bvh").n_frames and rec["dropped"] == 0
    finally:
        server.terminate()
        server.wait(timeout=10)
    r = subprocess.run(cmd + ["capture", "segment", str(tmp_path / "take.bvh"), "--target", str(squats[0]),
                              "--expected", "4", "--out", str(tmp_path / "reps"), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    # with neither other motions nor a space, the command says what only the first cost can tell
    assert "note: no --background or --space" in r.stderr and "may be cut into repetitions" in r.stderr, r.stderr
    out = json.loads(r.stdout)
    assert len(out["files"]) == len(out["repetitions"]) >= 3 and all(Path(f).exists() for f in out["files"])
    assert all(load_clip(f).n_frames > 10 for f in out["files"])
    r = subprocess.run(cmd + ["capture", "record", str(tmp_path / "x.txt"), "--source", address, "--seconds", "1"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "error:" in r.stderr and "Traceback" not in r.stderr


def test_capture_segment_says_which_test_failed_and_takes_a_larger_first_cost(bundled, tmp_path):
    """Another performer's kicks against a kick farther from them than the default first cost:
    the command says so with the number (exit 1); with ``--max-cost`` above it, the kicks are
    cut (exit 0); a negative one is refused by the command line (exit 2)."""
    import json
    import subprocess
    import sys

    from shared.capture.takes import join

    kicks = sorted((bundled / "amc/kickLFront1Reps").glob("HDM_bd_*.amc"))
    target = next((bundled / "amc/kickLFront1Reps").glob("HDM_bk_*.amc"))
    take, truth = join([load_clip(f) for f in kicks] * 2, seed=3)
    save_clip(take, tmp_path / "kicks.bvh")
    cmd = [sys.executable, "-m", "shared.cli", "capture", "segment", str(tmp_path / "kicks.bvh"), "--target", str(target),
           "--expected", "4"]
    r = subprocess.run(cmd + ["--json"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    far = json.loads(r.stdout)
    assert far["repetitions"] == [] and far["closest"] > 0.95
    assert far["verdict"] == (f"not the target: the movement most like it differs from it by {far['closest']:.2f}, "
                              "more than a first repetition may (0.95)")
    r = subprocess.run(cmd + ["--max-cost", f"{far['closest'] + 0.1:.2f}", "--json"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert score([(x["start"], x["end"]) for x in json.loads(r.stdout)["repetitions"]], truth)["f1"] == 1.0
    r = subprocess.run(cmd + ["--max-cost", "-1"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_capture_segment_with_a_space_file_finds_what_the_cohort_cannot(bundled, tmp_path):
    """bk's kicks against bd's kick (the cohort finds none: tests/test_segmentation.py) with a space
    file of bd's and dg's motions: every repetition cut, the space's motion in the answer (exit 0);
    a label the space does not hold, or a label without a space, is refused in a sentence (exit 2)."""
    import json
    import subprocess
    import sys

    from shared.capture.takes import join
    from shared.pss.space import ProtoSymbolSpace

    classes = ["elbowToKnee1RepsLelbowStart", "kickLFront1Reps", "rotateArmsBothBackward1Reps", "squat1Reps"]
    files = {p: [f for k in classes for f in sorted((bundled / "amc" / k).glob(f"HDM_{p}_*.amc"))] for p in ("bd", "bk", "dg")}
    space = ProtoSymbolSpace.build([load_clip(f) for f in files["bd"] + files["dg"]], sensor=False).save(tmp_path / "moves")
    take, truth = join([load_clip(f) for f in files["bk"] if "kick" in f.name] * 2, seed=7)
    save_clip(take, tmp_path / "kicks.bvh")
    target = next(f for f in files["bd"] if "kick" in f.name)
    cmd = [sys.executable, "-m", "shared.cli", "capture", "segment", str(tmp_path / "kicks.bvh"), "--target", str(target),
           "--expected", "4"]
    r = subprocess.run(cmd + ["--space", str(space), "--json"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    found = json.loads(r.stdout)
    assert found["space"] == "kickLFront1Reps" and found["verdict"] == "4 repetition(s) found"
    assert score([(x["start"], x["end"]) for x in found["repetitions"]], truth)["f1"] == 1.0
    for extra, said in ((["--space", str(space), "--label", "jump"], "holds no motion 'jump'"),
                        (["--label", "kickLFront1Reps"], "give the space too")):
        r = subprocess.run(cmd + extra, capture_output=True, text=True, timeout=300)
        assert r.returncode == 2 and said in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_the_adverb_is_said_into_a_file_of_its_length_and_not_silent(tmp_path):
    from shared.capture import speech

    if not speech.available():
        if os.environ.get("CI") == "true":  # `make test` installs it there: a CI without it is a broken set-up
            pytest.fail("espeak-ng is missing under CI")
        pytest.skip("espeak-ng is not installed here (make test installs it under CI)")
    short = speech.speak("more", tmp_path / "more.wav")
    long = speech.speak("a little more, much more like this", tmp_path / "long.wav")
    assert short.path.exists() and 0.2 < short.seconds < 2.0 and short.rms > 0.01
    assert long.seconds > short.seconds + 0.5  # the adverb's length, not a fixed sound
    assert speech.measure(short.path) == (short.seconds, short.rms)
    with pytest.raises(BadInput, match="nothing"):
        speech.speak("   ", tmp_path / "none.wav")
    aloud = speech.speak("more", tmp_path / "aloud.wav", play=True)  # played, or says why not: never a failure
    assert aloud.played != bool(aloud.note) and aloud.seconds == pytest.approx(short.seconds)


def test_a_source_that_never_stops_ends_a_take_when_asked(squat, tmp_path):
    """A suit keeps streaming while the person stands still: the take ends when ``until`` says
    so (checked every quarter second of frames). A check's own time is not taken for frames the
    source skipped: each check here takes 0.3 s (9 frame times), and fewer than 8 frames in all
    are counted missing (without that, 9 or more per check)."""
    looks = []

    def enough(clip):
        looks.append(clip.n_frames)
        time.sleep(0.3)
        return "enough frames" if clip.n_frames >= 45 else None

    with ReplaySource(squat, speed=2.0, connections=1, hold=True) as src:
        take = record(src.address, tmp_path / "held.bvh", seconds=30, idle=1.0, until=enough)
    assert take.ended == "enough frames" and take.frames == 48 and take.skipped < 8, take.events
    assert looks and all(b - a == looks[1] - looks[0] for a, b in zip(looks, looks[1:]))


def test_a_stream_that_stops_being_bvh_keeps_the_frames_it_sent(squat, tmp_path):
    from shared.capture.stream import MAX_LINE

    save_clip(squat, tmp_path / "ref.bvh")
    text = (tmp_path / "ref.bvh").read_text().splitlines()
    motion = text.index("MOTION")
    payload = "\n".join(text[:motion + 1] + ["Frames: 0", "Frame Time: 0.0333333"] + text[motion + 3:motion + 8])
    source = _raw_server((payload + "\n" + "1" * (MAX_LINE + 10)).encode())
    take = record(source, tmp_path / "cut.bvh", seconds=10, idle=1.0)
    assert take.frames == 5 and take.ended == "the stream stopped being BVH" and take.clip.n_frames == 5
