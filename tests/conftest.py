"""Shared fixtures: the real HDM05 data (``../shared/data/hdm05``, or the bundled subset)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_HDM05 = Path(os.environ.get("MIRRORCOACH_HDM05", REPO.parent / "shared" / "data" / "hdm05"))
BUNDLED_HDM05 = REPO / "data" / "hdm05"


@pytest.fixture(scope="session")
def hdm05() -> Path:
    """The full HDM05 dev data (11 classes, actors bd, bk, dg)."""
    if not (SHARED_HDM05 / "amc").is_dir():
        pytest.fail(f"HDM05 data not found at {SHARED_HDM05}; set MIRRORCOACH_HDM05")
    return SHARED_HDM05


@pytest.fixture(scope="session")
def cmu() -> Path:
    """The CMU BVH sample in two unit conventions (``../shared/data/cmu``, see its SOURCE.md)."""
    path = SHARED_HDM05.parent / "cmu"
    if not (path / "131_01.bvh").is_file():
        pytest.fail(f"the CMU BVH sample is not at {path}")
    return path


@pytest.fixture(scope="session")
def dev_clips(hdm05):
    from shared.io import find_clips, load_clip

    return [load_clip(f) for f in find_clips([hdm05 / "amc"])]


@pytest.fixture(scope="session")
def dev_split(dev_clips):
    """The issue's split: learn from actors bd and bk, test on actor dg."""
    train = [c for c in dev_clips if "_dg_" not in c.name]
    test = [c for c in dev_clips if "_dg_" in c.name]
    return train, test


@pytest.fixture(scope="session")
def dev_space(dev_split):
    from shared.pss.space import ProtoSymbolSpace

    return ProtoSymbolSpace.build(dev_split[0], dim=3)


@pytest.fixture(scope="session")
def blender() -> str:
    """Blender, the real client of our BVH files: a skip where it is not installed, a failure
    under CI, which installs it (`make test` with CI=true)."""
    import shutil

    path = shutil.which("blender")
    if path is None:
        if os.environ.get("CI") == "true":
            pytest.fail("Blender is not installed in CI (`make test` installs Debian's blender when CI=true)")
        pytest.skip("Blender is not installed (Debian: apt-get install blender; `make test` installs it when CI=true)")
    return path


@pytest.fixture(scope="session")
def bundled() -> Path:
    return BUNDLED_HDM05


# ---------------------------------------------------------------------------- bad skeletons
def chain_skeleton(n: int) -> str:
    """A person-sized skeleton of ``n`` joints in one chain, as JSON."""
    import numpy as np

    from shared.motion.skeleton import Joint, Skeleton

    joints = [Joint("j0", -1, np.zeros(3), ["tx", "ty", "tz", "rx", "ry", "rz"])]
    joints += [Joint(f"j{i}", i - 1, np.array([0.0, 1.7 / n, 0.0]), ["rx", "ry", "rz"]) for i in range(1, n)]
    return Skeleton("chain", joints, unit_m=1.0).to_json()


def cycle_skeleton(skeleton) -> str:
    """``skeleton`` as JSON with joints 1 and 3 each other's parent."""
    import json

    d = json.loads(skeleton.to_json())
    d["joints"][1]["parent"], d["joints"][3]["parent"] = 3, 1
    return json.dumps(d)


# ---------------------------------------------------------------------------- real processes
def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cluster_env(home: Path, **extra) -> dict:
    """Environment of a private cluster: its own loopback port, prefix and home."""
    env = dict(os.environ)
    env.update({"MIRRORCOACH_ROUTER": f"tcp/127.0.0.1:{free_port()}", "MIRRORCOACH_HOME": str(home),
                "MIRRORCOACH_PREFIX": f"t{os.getpid()}x{free_port()}", "MIRRORCOACH_TIMEOUT": "300"})
    env.update({k: str(v) for k, v in extra.items()})
    return env


def settings_of(env: dict):
    from shared.bus.config import Settings

    return Settings(router=env["MIRRORCOACH_ROUTER"], prefix=env["MIRRORCOACH_PREFIX"],
                    home=Path(env["MIRRORCOACH_HOME"]), timeout=float(env["MIRRORCOACH_TIMEOUT"]))


class Processes:
    """Real router and service processes of a test, stopped (SIGTERM, then SIGKILL) at the end."""

    def __init__(self, env: dict):
        self.env = env
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs = Path(env["MIRRORCOACH_HOME"]) / "test-logs"
        self.logs.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, module: str):
        import subprocess
        import sys

        with open(self.logs / f"{name}.log", "ab") as out:
            self.procs[name] = subprocess.Popen([sys.executable, "-m", module], env=self.env, stdout=out,
                                                stderr=subprocess.STDOUT, cwd=REPO)
        return self.procs[name]

    def wait_alive(self, services: set[str], timeout: float = 120.0):
        import time

        from shared.bus.client import Client, Unavailable

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for n, p in self.procs.items():
                if p.poll() is not None:
                    raise AssertionError(f"{n} exited with {p.returncode}: {self.log(n)[-2000:]}")
            try:
                with Client(settings_of(self.env), connect_timeout_s=1.0) as c:
                    if services <= c.alive(timeout=1.0):
                        return
            except Unavailable:
                pass
            time.sleep(0.2)
        raise AssertionError(f"{services} not alive after {timeout} s")

    def log(self, name: str) -> str:
        return (self.logs / f"{name}.log").read_text(errors="replace")

    def stop(self):
        import subprocess

        for p in reversed(list(self.procs.values())):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


def state_files(env) -> dict:
    """Every file under a cluster's data folder: path -> sha256 (a refused request changes none)."""
    import hashlib

    root = Path(env["MIRRORCOACH_HOME"]) / "data"
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*"))
            if p.is_file()}


def assert_refused(client, procs: Processes, cases) -> None:
    """Every case ``(name, service, verb, message, code)`` (message: a map, or raw bytes) gets a
    ``reply_err`` with that stable code, a readable message and no traceback; the service
    stays up."""
    from schemas.common import ERROR
    from shared.bus.client import RemoteError
    from shared.bus.codec import pack

    for name, service, verb, msg, code in cases:
        with pytest.raises(RemoteError) as e:
            client.request_raw(service, verb, msg if isinstance(msg, bytes) else pack(msg), timeout=60)
        err = ERROR.validate({"code": e.value.code, "message": e.value.message, "details": e.value.details})
        assert err["code"] == code, (name, e.value.code, e.value.message)
        assert e.value.message and "Traceback" not in e.value.message, name
        assert procs.procs[service].poll() is None, f"{service} died on: {name}"
    for service in {c[1] for c in cases}:
        assert "Traceback" not in procs.log(service), service


def kill_during(env: dict, procs: Processes, service: str, module: str, request, ready, timeout: float = 120.0):
    """Run ``request(client)`` in a thread; once ``ready()`` is true, SIGKILL ``service`` and
    start it again. Returns the exception the request ended with (it must end, not hang)."""
    import os
    import signal
    import threading
    import time

    from shared.bus.client import Client

    errors = []

    def run():
        try:
            with Client(settings_of(env)) as c:
                request(c)
        except Exception as e:  # the service is killed under it
            errors.append(e)

    t = threading.Thread(target=run)
    t.start()
    deadline = time.monotonic() + timeout
    while not ready() and time.monotonic() < deadline:
        time.sleep(0.005)
    assert ready(), f"{service} never got far enough to be killed"
    os.kill(procs.procs[service].pid, signal.SIGKILL)
    procs.procs[service].wait()
    t.join(timeout=timeout)
    assert not t.is_alive(), f"the request to the killed {service} hung"
    procs.start(service, module)
    procs.wait_alive({service})
    return errors[0] if errors else None


def running(env: dict, *services: str):
    """A router and ``services`` (names under ``services/``) as real processes of ``env``, alive;
    use as ``with running(env, "pss") as procs:`` (stopped at the end)."""
    from contextlib import contextmanager

    @contextmanager
    def run():
        procs = Processes(env)
        procs.start("router", "shared.bus.router")
        for name in services:
            procs.start(name, f"services.{name}")
        try:
            procs.wait_alive(set(services))
            yield procs
        finally:
            procs.stop()

    return run()


def _serve(tmp_path_factory, *services: str, **env_extra):
    env = cluster_env(tmp_path_factory.mktemp("home"), **env_extra)
    with running(env, *services) as procs:
        yield env, procs


@pytest.fixture(scope="module")
def pss_service(tmp_path_factory):
    """A real router and a real pss service process on a free loopback port; yields
    (env, Processes). The payload limit is 8 MB so the over-size case is cheap to send."""
    yield from _serve(tmp_path_factory, "pss", MIRRORCOACH_MAX_PAYLOAD=8_000_000)


@pytest.fixture(scope="module")
def simulator_service(tmp_path_factory):
    """A real router and a real simulator service process; yields (env, Processes)."""
    yield from _serve(tmp_path_factory, "simulator")


@pytest.fixture(scope="module")
def chapter3_services(tmp_path_factory):
    """Router, pss, simulator, dialogue and estimator as real processes; yields (env, Processes)."""
    yield from _serve(tmp_path_factory, "pss", "simulator", "dialogue", "estimator")


@pytest.fixture(scope="module")
def coach_services(tmp_path_factory):
    """Router, pss, simulator and coach as real processes; yields (env, Processes)."""
    yield from _serve(tmp_path_factory, "pss", "simulator", "coach")


@pytest.fixture(scope="module")
def capture_service(tmp_path_factory):
    """A real router, a real capture service process and the pss service it asks for a space's word;
    yields (env, Processes)."""
    yield from _serve(tmp_path_factory, "capture", "pss")


@pytest.fixture
def client_of():
    """``client_of(env)``: a Client of that cluster, closed at the end of the test."""
    from shared.bus.client import Client

    made = []

    def make(env):
        made.append(Client(settings_of(env)))
        return made[-1]

    yield make
    for c in made:
        c.close()
