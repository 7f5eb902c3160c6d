"""The mirrorcoach CLI as a user runs it: a real subprocess, real files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from shared.io import load_clip

SQUAT = "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc"


def run(*args):
    return subprocess.run([sys.executable, "-m", "shared.cli", *map(str, args)], capture_output=True, text=True, timeout=300)


def test_clip_info_and_convert(bundled, tmp_path):
    r = run("clip", "info", bundled / SQUAT, "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["frames"] == 140 and info["fps"] == 120 and info["channels"] == 62 and info["label"] == "squat1Reps"
    r = run("clip", "convert", bundled / SQUAT, tmp_path / "s.bvh", "--fps", "30")
    assert r.returncode == 0, r.stderr
    b = load_clip(tmp_path / "s.bvh")
    assert b.fps == 30 and b.n_frames == 36


def test_a_group_command_runs_alone_as_it_runs_in_the_whole_application(bundled):
    """``mirrorcoach GROUP ...`` builds that group's commands only (start-up time); it answers
    as the whole application does, root options still go through the whole application, and a
    group shows no shell-completion options (the root has none)."""
    from typer.testing import CliRunner

    from shared.cli.app import _group_of, app

    alone = run("clip", "info", bundled / SQUAT, "--json")
    whole = CliRunner().invoke(app, ["clip", "info", str(bundled / SQUAT), "--json"])
    assert alone.returncode == whole.exit_code == 0 and json.loads(alone.stdout) == json.loads(whole.stdout)
    assert _group_of(["clip", "info"]) is not None and _group_of(["--units", "cm", "clip"]) is None
    assert _group_of(["up"]) is None and _group_of([]) is None  # a root command, the root's help
    helped = run("offline", "--help")
    assert helped.returncode == 0 and "mirrorcoach offline" in helped.stdout and "recognize" in helped.stdout
    assert "--install-completion" not in helped.stdout
    rooted = run("--units", "m", "clip", "info", bundled / SQUAT, "--json")
    assert rooted.returncode == 0 and json.loads(rooted.stdout)["frames"] == 140
    lone = run("sim", "--help")  # a group of one command stays a group (typer would run the command)
    assert lone.returncode == 0 and "perform" in lone.stdout and "Usage: mirrorcoach sim [OPTIONS] COMMAND" in lone.stdout
    wrong = run("offline", "nosuch")
    assert wrong.returncode == 2 and "No such command" in wrong.stderr and "Traceback" not in wrong.stderr


def test_a_group_imports_only_the_module_that_adds_it(bundled):
    """``mirrorcoach GROUP ...`` imports the module that adds GROUP and no other command module
    (start-up time); the table it goes by names, for every module, the groups that module adds,
    and the whole application still has every group."""
    from shared.cli.app import COMMAND_MODULES, OWN_GROUPS

    def groups_after(code: str) -> list[str]:
        r = subprocess.run([sys.executable, "-c", "from shared.cli.app import app\n" + code +
                            "\nprint(' '.join(sorted(g.name for g in app.registered_groups)))"],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return r.stdout.split()

    assert groups_after("") == sorted(OWN_GROUPS)
    for name, groups in COMMAND_MODULES.items():
        added = set(groups_after(f"import shared.cli.{name}")) - set(OWN_GROUPS)
        # command modules share helpers through shared.cli.common, never each other: a module adds its own alone
        assert added == set(groups), (name, added)
    every = set(groups_after("from shared.cli.app import register\nregister()"))
    assert every == set(OWN_GROUPS) | {g for gs in COMMAND_MODULES.values() for g in gs}

    probe = ("import atexit, sys\n"
             "atexit.register(lambda: print('loaded', *sorted(m for m in sys.modules if m.startswith('shared.cli.'))))\n"
             "from shared.cli.entry import main\n"
             "sys.argv = ['mirrorcoach'] + sys.argv[1:]\n"
             "main()\n")

    def loaded(*args) -> set[str]:
        r = subprocess.run([sys.executable, "-c", probe, *map(str, args)], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return set(r.stdout.splitlines()[-1].split()[1:])

    always = {"shared.cli.app", "shared.cli.common", "shared.cli.entry"}
    assert loaded("clip", "info", bundled / SQUAT, "--json") == always
    assert loaded("space", "--help") == always | {"shared.cli.cluster"}
    assert {f"shared.cli.{m}" for m in COMMAND_MODULES} <= loaded("--help")


def test_the_command_runs_with_the_collector_on_and_its_imports_frozen(bundled):
    """The entry point imports without the cyclic garbage collector (start-up time) but a
    command runs with it on, and what the imports made is frozen out of its passes; imported
    as a library, the command line leaves the collector as it found it."""
    import gc

    from shared.cli import lasting_imports

    probe = ("import atexit, gc, sys\n"
             "atexit.register(lambda: print('collector', gc.isenabled(), gc.get_freeze_count() > 1000))\n"
             "from shared.cli.entry import main\n"
             "sys.argv = ['mirrorcoach'] + sys.argv[1:]\n"
             "main()\n")
    r = subprocess.run([sys.executable, "-c", probe, "clip", "info", str(bundled / SQUAT), "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[0])["frames"] == 140
    assert r.stdout.splitlines()[-1] == "collector True True"
    before = gc.isenabled()
    try:
        with lasting_imports():
            assert not gc.isenabled()
        assert gc.isenabled() == before and gc.get_freeze_count() > 0
        gc.disable()
        with lasting_imports():
            pass
        assert not gc.isenabled()
    finally:
        gc.unfreeze()
        (gc.enable if before else gc.disable)()


@pytest.mark.slow
def test_space_build_recognize_generate(bundled, tmp_path):
    space = tmp_path / "s.npz"
    r = run("offline", "build", space, bundled / "amc/squat1Reps", bundled / "amc/kickLFront1Reps")
    assert r.returncode == 0, r.stderr
    held = next((bundled / "amc/squat1Reps").glob("HDM_dg_*.amc"))
    r = run("offline", "recognize", space, held, "--json")
    assert r.returncode == 0, r.stderr
    rec = json.loads(r.stdout)
    assert rec["label"] == "squat1Reps" and rec["known"] and 0.0 <= rec["confidence"] <= 1.0
    names = [n["name"] for n in rec["nearest"]]
    r = run("offline", "recognize", space, held)  # for a person: the class and its confidence first
    assert r.returncode == 0 and r.stdout.startswith("squat1Reps   (confidence "), r.stdout
    assert "point in the space" in r.stdout and names[0] in r.stdout
    r = run("offline", "generate", space, "--mix", f"{names[0]}=3", "--mix", f"{names[1]}=-2", "--out", tmp_path / "e.bvh")
    assert r.returncode == 0, r.stderr
    assert np.all(np.isfinite(load_clip(tmp_path / "e.bvh").data))
    # files not held (each read when needed): the same space
    r = run("offline", "build", tmp_path / "lazy.npz", bundled / "amc/squat1Reps", bundled / "amc/kickLFront1Reps",
            "--hold-mb", "0")
    assert r.returncode == 0, r.stderr
    from shared.pss.space import ONE_EXAMPLE_POSE_FLOOR, ProtoSymbolSpace

    a, b = ProtoSymbolSpace.load(space), ProtoSymbolSpace.load(tmp_path / "lazy.npz")
    assert b.names == a.names and np.allclose(b.distances, a.distances, rtol=1e-10) and np.allclose(b.points, a.points)
    # a space for other styles: the pose floor saved with it, recognition reads it; none by default
    r = run("offline", "build", tmp_path / "styles.npz", bundled / "amc/squat1Reps", bundled / "amc/kickLFront1Reps",
            "--pose-floor", "0.03")
    assert r.returncode == 0, r.stderr
    assert ProtoSymbolSpace.load(tmp_path / "styles.npz").params.recognition_pose_floor == 0.03
    assert a.params.recognition_pose_floor is None
    r = run("offline", "recognize", tmp_path / "styles.npz", held, "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["label"] == "squat1Reps", r.stderr
    # one clip per motion: the floor such a space recognises other styles best with, unless 0 says none
    ones = [next((bundled / "amc" / m).glob("HDM_bd_*.amc")) for m in ("squat1Reps", "kickLFront1Reps")]
    r = run("offline", "build", tmp_path / "one.npz", *ones)
    assert r.returncode == 0, r.stderr
    assert 'never answers "none of these" (too few known motions to calibrate its tests on)' in r.stdout  # says so
    assert ProtoSymbolSpace.load(tmp_path / "one.npz").params.recognition_pose_floor == ONE_EXAMPLE_POSE_FLOOR
    r = run("offline", "build", tmp_path / "zero.npz", *ones, "--pose-floor", "0")
    assert r.returncode == 0, r.stderr
    assert ProtoSymbolSpace.load(tmp_path / "zero.npz").params.recognition_pose_floor is None
    r = run("offline", "build", tmp_path / "bad.npz", *ones, "--pose-floor", "-1")
    assert r.returncode == 2 and "Traceback" not in r.stderr and not (tmp_path / "bad.npz").exists()


def test_errors_are_one_line_without_traceback(bundled, tmp_path):
    cases = [
        ("clip", "info", tmp_path / "missing.amc"),
        ("clip", "convert", bundled / SQUAT, tmp_path / "no/such/dir/x.bvh"),
        ("clip", "convert", bundled / SQUAT, tmp_path / "x.txt"),
        ("offline", "recognize", tmp_path / "nospace.npz", bundled / SQUAT),
        ("offline", "recognize", tmp_path / "garbage.npz", bundled / SQUAT),
        ("offline", "generate", tmp_path / "nospace.npz", "--point", "a,b", "--out", tmp_path / "g.bvh"),
        ("--units", "furlong", "clip", "info", bundled / SQUAT),
        ("--up", "x", "clip", "info", tmp_path / "s.bvh"),
        ("--translations", "both", "clip", "info", tmp_path / "s.bvh"),
    ]
    r = run("clip", "convert", bundled / SQUAT, tmp_path / "s.bvh")
    assert r.returncode == 0, r.stderr
    (tmp_path / "garbage.npz").write_bytes(bytes(range(256)) * 8)  # no archive: numpy took it for a pickle
    for args in cases:
        r = run(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.startswith("error: ") and "Traceback" not in r.stderr, (args, r.stderr)
        assert "pickle" not in r.stderr, (args, r.stderr)  # never advice to load a file unsafely


def test_every_study_verb_on_a_folder_that_is_no_study_says_so(bundled, tmp_path):
    """Before it asks anything of the cluster or the source, each verb says the folder is not a
    study and how to start one (`study run` said only that target.npz was missing)."""
    folder = tmp_path / "nostudy"
    folder.mkdir()
    for args in (("run", folder, "--source", "tcp://127.0.0.1:9"), ("next", folder), ("report", folder),
                 ("redo", folder), ("attempt", folder, bundled / SQUAT, "--participant", "P01"),
                 ("seat", folder, "--coach", "C1"), ("export", folder, "--out", tmp_path / "trials.csv")):
        r = run("study", *args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        assert r.stderr.startswith(f"error: {folder} is not a study") and "study init" in r.stderr, (args, r.stderr)


def test_help_explains_the_arguments_as_well_as_the_options():
    """An argument's help text is in `--help` (with click 8.5 and typer 0.19 it was dropped: the
    Arguments panel listed their names and types only)."""
    r = run("study", "run", "--help")
    assert r.returncode == 0, r.stderr
    assert "The study's folder" in r.stdout and "The live source" in r.stdout, r.stdout
    r = run("space", "build", "--help")
    assert r.returncode == 0 and "Name of the space" in r.stdout and "Clip files or folders" in r.stdout, r.stdout


def test_every_command_and_every_parameter_has_its_help():
    """`--help` explains each command, argument and option of the whole application (35 had none:
    `--json`, `--replace`, the names of estimates, learners and sessions, `coach run`'s policy)."""
    import click
    import typer.main

    from shared.cli.app import app, register

    register()
    missing = []

    def walk(cmd, path):
        if isinstance(cmd, click.Group):
            for name, sub in cmd.commands.items():
                walk(sub, [*path, name])
            return
        if not cmd.help:
            missing.append((" ".join(path), "the command itself"))
        missing.extend((" ".join(path), p.name) for p in cmd.params if not getattr(p, "help", None))

    walk(typer.main.get_command(app), [])
    assert not missing, missing


def test_a_port_out_of_range_is_refused_before_anything_listens(bundled):
    """`capture serve --port 99999` ended in socket's OverflowError traceback."""
    for port in ("99999", "-5"):
        r = run("capture", "serve", bundled / SQUAT, "--port", port)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert "not in the range" in r.stderr and "65535" in r.stderr, r.stderr


def test_schemas_prints_every_contract():
    from schemas import CONTRACTS

    r = run("schemas")
    assert r.returncode == 0, r.stderr
    for name, mod in CONTRACTS.items():
        for verb in mod.ENDPOINTS:
            assert f"## {name}/{verb}:" in r.stdout
    assert "reply_err" in r.stdout and "bad_request" in r.stdout
    assert "limit    stops at a safe point after 600 s" in r.stdout and "limit    waits for a person" in r.stdout
    r = run("schemas", "nosuch")
    assert r.returncode == 2 and r.stderr.startswith("error: no service")


def test_the_dashboard_opens_the_viewer_on_loopback_only(tmp_path):
    """`make dashboard` started the viewer listening on 0.0.0.0:9876. The viewer cannot
    start on this machine without a GPU or Mesa's Vulkan driver, so a `rerun` on PATH records the
    command line the CLI gives it (analytics first, then the recording)."""
    import os
    import time

    home = tmp_path / "home"
    (home / "recordings").mkdir(parents=True)
    (home / "recordings" / "x.rrd").write_bytes(b"")
    (home / "recordings" / "latest.rrd").symlink_to("x.rrd")
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    (bin_ / "rerun").write_text(f"#!/bin/sh\necho \"$@\" >> {tmp_path / 'argv'}\n")
    (bin_ / "rerun").chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_}:{os.environ['PATH']}", "DISPLAY": ":99", "MIRRORCOACH_HOME": str(home)}
    r = subprocess.run([sys.executable, "-m", "shared.cli", "dashboard"], env=env, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    for _ in range(50):
        if (tmp_path / "argv").exists() and len((tmp_path / "argv").read_text().splitlines()) == 2:
            break
        time.sleep(0.1)
    first, second = (tmp_path / "argv").read_text().splitlines()
    assert first == "analytics disable"
    assert second.startswith("--bind 127.0.0.1 --port auto ") and second.endswith("recordings/x.rrd")


def test_study_aeu_fits_thresholds_from_a_coach_seat_and_a_study_uses_them(bundled, tmp_path):
    """A coach-seat log (as `study seat` appends it): `study aeu` fits the thresholds and names
    the coach left out; `study init --aeu1 FOLDER` plans case 7 with them, no scale needed."""
    from shared.reports.study import append, load, policy

    seat = tmp_path / "seat"
    seat.mkdir()
    append(seat, {"event": "plan", "plan": {"participants": {}, "cases": [], "trials": 2, "seed": 0, "study": "s",
                                            "target": "t", "design": "-"}})
    words = ("a little more", "more", "much more")
    for d in np.linspace(10, 100, 24):
        append(seat, {"event": "seat", "coach": "c1", "d_p": float(d), "adverb": words[int(d > 40) + int(d > 70)]})
        append(seat, {"event": "seat", "coach": "back", "d_p": float(d), "adverb": words[2 - int(d > 40) - int(d > 70)]})
    r = run("study", "aeu", seat, "--json")
    assert r.returncode == 0, r.stderr
    fit = json.loads(r.stdout)
    assert fit["coaches"] == ["c1"] and "back" in fit["excluded"] and fit["agreement"] == 1.0
    r = run("study", "aeu", seat)
    assert "left out back: adverbs run backwards" in r.stdout
    study = tmp_path / "study"
    r = run("study", "init", study, "--target", bundled / SQUAT, "--participants", "2", "--cases", "3,7", "--seed", "1",
            "--aeu1", seat)
    assert r.returncode == 0, r.stderr
    p = load(study)
    assert policy(p, "P01", 7) == {"kind": "aeu1", "alpha": 2.0, "thresholds": fit["thresholds"]}
    r = run("study", "init", tmp_path / "s8", "--target", bundled / SQUAT, "--participants", "2", "--cases", "8",
            "--seed", "1")
    assert r.returncode == 2 and "study aeu" in r.stderr


def test_a_reply_that_breaks_its_contract_is_an_error_not_a_traceback(tmp_path):
    """Something answering `pss/list` in the service's place with a reply its contract does not
    allow: the client refuses the reply and the CLI says so in one line."""
    import time

    import zenoh

    from shared.bus.codec import pack
    from shared.bus.config import client_config
    from tests.conftest import REPO, cluster_env, running, settings_of

    env = cluster_env(tmp_path / "home")
    with running(env):
        s = settings_of(env)
        session = zenoh.open(client_config(s))
        try:
            impostor = session.declare_queryable(s.key("pss", "list"), lambda q: q.reply(q.key_expr, pack({"spaces": 7})))
            deadline = time.monotonic() + 30  # the impostor reachable through the router, however slow the machine
            while time.monotonic() < deadline and not any(x.ok is not None for x in session.get(s.key("pss", "list"),
                                                                                                  timeout=1.0)):
                time.sleep(0.05)
            r = subprocess.run([sys.executable, "-m", "shared.cli", "space", "list"], capture_output=True, text=True,
                               env=env, cwd=REPO, timeout=120)
            impostor.undeclare()
        finally:
            session.close()
    assert r.returncode != 0 and "does not match its contract" in r.stderr and "Traceback" not in r.stderr, r.stderr


def _signal_state(pid: int) -> str:
    """What the kernel says of a process's signals and where it waits (for a failure's message)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            lines = [ln.strip() for ln in f if ln.startswith(("State", "SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt"))]
        with open(f"/proc/{pid}/wchan") as f:
            return "; ".join(lines + [f"wchan {f.read()}"])
    except OSError as e:
        return f"(no /proc state: {e})"


def test_ctrl_c_in_a_command_says_it_was_interrupted(tmp_path):
    """Ctrl-C while a command works ends it with exit 130 and says "interrupted" on stderr, no
    traceback (typer alone exits 130 without a word). The command is caught inside its work:
    reading a clip from a named pipe nobody writes to yet; a writer can open the pipe once the
    command has opened it for reading (a bounded poll). Should the interrupt be seen only once the
    read returns (a signal taken by a thread other than the one reading: a first try of this test
    did not end in a full run of the suite), the pipe is closed after 20 s: the command must still
    say it was interrupted, not read the empty pipe, and the wait is reported."""
    import errno
    import os
    import signal
    import time

    pipe = tmp_path / "take.bvh"
    os.mkfifo(pipe)
    p = subprocess.Popen([sys.executable, "-m", "shared.cli", "clip", "info", str(pipe)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # as a terminal's Ctrl-C finds it
    writer, state = None, None
    try:
        deadline = time.monotonic() + 120
        while writer is None:
            try:
                writer = os.open(pipe, os.O_WRONLY | os.O_NONBLOCK)
            except OSError as e:
                assert e.errno == errno.ENXIO, e  # no reader yet
                assert p.poll() is None and time.monotonic() < deadline, p.communicate(timeout=10)
                time.sleep(0.02)
        p.send_signal(signal.SIGINT)
        try:
            out, err = p.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            state = _signal_state(p.pid)
            os.close(writer)
            writer = None
            out, err = p.communicate(timeout=60)
    finally:
        if writer is not None:
            os.close(writer)
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, (p.returncode, err, state)
    assert err.strip() == "interrupted" and "Traceback" not in err, (err, state)
    if state is not None:
        print(f"the interrupt was seen only once the pipe closed: {state}")
