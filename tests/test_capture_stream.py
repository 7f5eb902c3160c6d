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


def test_the_recorders_own_work_is_not_taken_for_frames_the_source_skipped(squat, tmp_path):
    """A recorder busy with a frame (the capture service publishing it on the bus) reads the lines
    that came meanwhile at once: only the time it waited for the source is a silence, so a busy
    recorder says no frame missing (measured between the lines it read: 5 per pause), and frames
    the source really leaves out are still said missing."""
    def busy_at(frames):
        def busy(index, values, frame_time):
            if index in frames:
                time.sleep(0.2)  # 6 frame times at 30 fps
        return busy

    with ReplaySource(squat, connections=1) as src:
        take = record(src.address, tmp_path / "busy.bvh", seconds=30, idle=1.0, on_frame=busy_at({5, 11, 17, 23, 29}))
    assert take.frames == squat.n_frames and take.skipped == 0, take.events
    # busy before the source leaves frames 20-29 out (0.33 s; a pause over the gap would hide part of it, as
    # much as the machine is slow)
    with ReplaySource(squat, skip=set(range(20, 30)), connections=1) as src:
        take = record(src.address, tmp_path / "busy_gaps.bvh", seconds=30, idle=1.0, on_frame=busy_at({5, 11}))
    assert take.frames == squat.n_frames - 10 and take.skipped >= 8, take.events
    assert any("missing after frame 20" in e for e in take.events), take.events


def test_joined_takes_are_one_performers_clips_in_turn_and_refuse_two_skeletons(bundled):
    """`capture serve --repetitions`' takes: the clips in groups, the last wrapping round, each
    joined as :func:`join` joins them (the same rests for the same clips); clips of two performers
    in one take are refused before anything plays."""
    from shared.capture.takes import JoinedTakes, join

    bd = [load_clip(f) for f in sorted((bundled / "amc/squat1Reps").glob("HDM_bd_*.amc"))]
    bk = [load_clip(f) for f in sorted((bundled / "amc/squat1Reps").glob("HDM_bk_*.amc"))]
    takes = JoinedTakes(bd + bd[:1], 2)
    assert len(takes) == 2 and [c.name for c in takes.group(1)] == [bd[0].name, bd[0].name]
    take, bounds = takes.joined(1)
    again, same = join(takes.group(1), seed=1)
    assert np.array_equal(take.data, again.data) and bounds == same and len(bounds) == 2
    assert takes[0].n_frames == takes.joined(0)[0].n_frames > sum(c.n_frames for c in bd)  # rests between them
    assert len(JoinedTakes(bd + bk, 2)) == 2  # each performer's clips a take of their own
    with pytest.raises(BadInput, match="take 1 would join .*HDM_bk.*, of other bones: .* one performer's"):
        JoinedTakes(bd + bk, 3)  # (the same channels, another body)
    with pytest.raises(BadInput, match="has other bones than"):
        join([bd[0], bk[0]])
    with pytest.raises(BadInput, match="at least 1"):
        JoinedTakes(bd, 0)


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


def test_lines_held_back_and_sent_together_are_late_not_missing(squat, tmp_path):
    """A source whose network stack holds small writes back sends a burst of frames every few
    frame times (Nagle's algorithm against delayed acknowledgements: about 40 ms): those frames
    came, late; only a silence the burst after it does not make up is frames skipped."""
    save_clip(squat, tmp_path / "skeleton.bvh")
    text = (tmp_path / "skeleton.bvh").read_text().splitlines()
    motion = text.index("MOTION")
    header, rows = text[:motion + 1], text[motion + 3:]
    dt = 1 / 30

    def bursts(conn, skip=()):
        conn.sendall(("\n".join(header + ["Frames: 0", f"Frame Time: {dt}"]) + "\n").encode())
        t0 = time.monotonic()
        for start in range(0, len(rows), 6):  # 6 frames (0.2 s) at once, when the last of them is due
            time.sleep(max(t0 + (start + 5) * dt - time.monotonic(), 0))
            part = [r for i, r in enumerate(rows[start:start + 6], start) if i not in skip]
            if part:
                conn.sendall(("\n".join(part) + "\n").encode())

    for skip, missing in (((), 0), (set(range(12, 24)), 12)):  # two whole bursts left out: 0.4 s, 12 frames
        srv = socket.create_server(("127.0.0.1", 0))

        def serve(srv=srv, skip=skip):
            conn, _ = srv.accept()
            with conn:
                bursts(conn, skip)
            srv.close()

        threading.Thread(target=serve, daemon=True).start()
        take = record(f"tcp://127.0.0.1:{srv.getsockname()[1]}", tmp_path / "bursts.bvh", seconds=30, idle=1.0)
        assert take.frames == len(rows) - len(skip), take.events
        assert abs(take.skipped - missing) <= 2, take.events  # (not 5 per burst, as between the lines read)
        assert bool(skip) == any("missing after frame 12" in e for e in take.events), take.events


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
    """`capture serve --repetitions` plays one performer's clips joined with rests as a live source
    on a loopback port (a trial's take without a suit, its true repetitions printed), `capture
    record` records it, `capture segment` cuts it into rep files that `study attempt` takes: no
    file made or cut by hand."""
    import json
    import re
    import subprocess
    import sys

    from shared.capture.takes import JoinedTakes

    squats = sorted((bundled / "amc/squat1Reps").glob("HDM_bd_*.amc"))
    files = [str(f) for f in squats] * 2  # four repetitions of one performer
    cmd = [sys.executable, "-m", "shared.cli"]
    server = subprocess.Popen(cmd + ["capture", "serve", *files, "--repetitions", "4", "--port", "0", "--speed", "8"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        address = server.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:"), server.stderr.read()
        r = subprocess.run(cmd + ["capture", "record", str(tmp_path / "take.bvh"), "--source", address, "--seconds", "60",
                                  "--idle", "1", "--json"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        rec = json.loads(r.stdout)
    finally:
        server.terminate()
        _, said = server.communicate(timeout=10)
    take, truth = JoinedTakes([load_clip(f) for f in files], 4).joined(0)  # what was served, as the library joins it
    assert rec["frames"] == take.n_frames and rec["dropped"] == 0 and rec["skipped"] == 0, rec
    assert "as 1 take(s) of 4 repetitions" in said, said
    printed = [(float(a), float(b)) for a, b in re.findall(r"HDM_bd_squat1Reps_\d+_120 ([\d.]+)-([\d.]+) s", said)]
    assert printed == [(round(a, 2), round(b, 2)) for a, b in truth], said
    (tmp_path / "reps").mkdir()
    for name in ("rep7.bvh", "rep12.bvh", "rep_kept.bvh", "notes.txt"):  # an earlier cut's repetitions, and files of the user's
        (tmp_path / "reps" / name).write_text("from before\n")
    r = subprocess.run(cmd + ["capture", "segment", str(tmp_path / "take.bvh"), "--target", str(squats[0]),
                              "--expected", "4", "--out", str(tmp_path / "reps"), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    # the earlier cut's repetitions are gone (a glob rep*.bvh took them with this take's), the user's files kept
    assert "removed rep7.bvh, rep12.bvh from" in r.stderr, r.stderr
    assert not (tmp_path / "reps/rep7.bvh").exists() and not (tmp_path / "reps/rep12.bvh").exists()
    assert (tmp_path / "reps/rep_kept.bvh").exists() and (tmp_path / "reps/notes.txt").exists()
    # with neither other motions nor a space, the command says what only the first cost can tell
    assert "note: no --background or --space" in r.stderr and "may be cut into repetitions" in r.stderr, r.stderr
    out = json.loads(r.stdout)
    assert len(out["files"]) == len(out["repetitions"]) >= 3 and all(Path(f).exists() for f in out["files"])
    assert score([(x["start"], x["end"]) for x in out["repetitions"]], truth)["f1"] >= 0.85, (out["repetitions"], truth)
    assert all(load_clip(f).n_frames > 10 for f in out["files"])
    r = subprocess.run(cmd + ["capture", "record", str(tmp_path / "x.txt"), "--source", address, "--seconds", "1"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "error:" in r.stderr and "Traceback" not in r.stderr


def test_ctrl_c_ends_a_take_recorded_on_the_command_line_and_keeps_it(squat, tmp_path):
    """`capture record` from a source that never stops: Ctrl-C ends the take and writes it with
    the frames so far (they were lost: the file is written when the take ends)."""
    import signal
    import subprocess
    import sys

    with ReplaySource(squat, connections=1, hold=True) as src:
        run = subprocess.Popen([sys.executable, "-m", "shared.cli", "capture", "record", str(tmp_path / "take.bvh"),
                                "--source", src.address, "--seconds", "600"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60  # until frames are coming in (the rows beside the take, as they arrive)
        while time.monotonic() < deadline and not any(f.stat().st_size for f in tmp_path.glob(".rows-*.part")):
            time.sleep(0.1)
        run.send_signal(signal.SIGINT)
        out, err = run.communicate(timeout=60)
    assert run.returncode == 0 and "stopped on request" in out and "Traceback" not in err, out + err
    take = load_clip(tmp_path / "take.bvh")
    assert take.n_frames == int(out.split()[0]) >= 1, out


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


def test_the_live_benchmarks_verdict_is_computed_per_case_and_an_unmeasured_case_is_not_met():
    """bench.live's goal words: met on a case only where every trial of both runs was ready within
    1 s; a case one run did not measure is missed and said so (it counted as met before)."""
    from bench.live import _verdict

    both = {1: [0.5, 0.7], 2: [0.9], 3: [1.4], 4: [0.8]}
    assert _verdict(both, both) == "Goal (1 s): met on case(s) 1, 2, 4; **missed** on case(s) 3 (longest 1.40 s)."
    assert _verdict({k: [0.5] for k in (1, 2, 3, 4)}, {k: [0.9] for k in (1, 2, 3, 4)}) == \
        "Goal (1 s): **met** on every case."
    assert "missed** on case(s) 4 (not measured in every run: case(s) 4)" in _verdict({1: [0.5], 2: [0.5], 3: [0.5]},
                                                                                     {k: [0.5] for k in (1, 2, 3, 4)})
    assert _verdict({k: [2.0] for k in (1, 2, 3, 4)}, {k: [0.5] for k in (1, 2, 3, 4)}).startswith(
        "Goal (1 s): **missed** on every case (longest 2.00 s)")
