"""The local cluster: ``mirrorcoach up``, ``down`` and ``status`` (``make up|down|status``).

``up`` starts a detached supervisor (``python -m shared.bus.cluster supervise``) that runs the
router and every service of ``shared/bus/cluster.toml`` as child processes, each logging to
``$MIRRORCOACH_HOME/logs/<name>.log``, and restarts any that exits (back-off 0.5 s doubling to
10 s, reset after 30 s of good running). ``up`` returns once every service's liveliness token
is seen (or says which one is not up and where its log is). ``down`` sends SIGTERM to the
supervisor, which stops the services, then the router, and waits for them.

The supervisor owns its children:

* one supervisor per home: it holds an exclusive ``flock`` on ``run/supervisor.lock`` for its
  whole life (the kernel drops it when the process dies, even by SIGKILL); a second one started
  at the same time finds the lock taken and exits with code 3, and ``up`` then waits for the
  first one's services instead;
* children die with it: each child asks the kernel for SIGTERM when its parent dies
  (``PR_SET_PDEATHSIG``), so a supervisor killed by SIGKILL leaves no orphans; all of them run
  in the supervisor's process group, which ``down`` kills as a last resort;
* pid files hold the pid and the process's start time (``/proc/PID/stat``, field 22), so a pid
  reused by an unrelated process is never taken for ours: ``up`` does not wait for it and
  ``down`` never signals it.
"""

from __future__ import annotations

import argparse
import ctypes
import logging
import os
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shared.bus.config import Settings
from shared.bus.pidfiles import (
    local_state,
    lock_path,
    pid_alive,
    read_pid,
    supervisor_running,
    take_lock,
    write_pid,
)
from shared.errors import MirrorcoachError
from shared.extras import missing

PLAN = Path(__file__).resolve().with_name("cluster.toml")  # package data: the plan travels with the wheel
log = logging.getLogger("mirrorcoach.supervisor")


@dataclass
class Proc:
    name: str
    module: str
    popen: subprocess.Popen | None = None
    started: float = 0.0
    failures: int = 0
    restart_at: float | None = None


def _read_plan(path: Path) -> dict:
    try:
        d = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise MirrorcoachError(f"cannot read the cluster plan {path}: {e}") from None
    for s in d.get("service", []):
        if not {"name", "module"} <= set(s):
            raise MirrorcoachError(f"{path}: every [[service]] needs a name and a module")
    return d


def plan_with_left_out(path: Path = PLAN) -> tuple[list[Proc], list[str]]:
    """Router first, then the services of ``shared/bus/cluster.toml`` whose optional dependency
    (``needs``) is installed; and, for each one left out, why (:mod:`shared.extras`)."""
    d = _read_plan(path)
    procs, left = [Proc("router", d.get("router", {}).get("module", "shared.bus.router"))], []
    for s in d.get("service", []):
        why = missing(s["needs"]) if s.get("needs") else None
        if why is None:
            procs.append(Proc(str(s["name"]), str(s["module"])))
        else:
            left.append(f"{s['name']} is not started: {why}")
    return procs, left


def load_plan(path: Path = PLAN) -> list[Proc]:
    """The processes :func:`plan_with_left_out` starts."""
    return plan_with_left_out(path)[0]


def reap_orphans(s: Settings, plan: list[Proc], echo=print, grace_s: float = 15.0) -> None:
    """Children of a supervisor that died (their pid files, same start time) are stopped:
    they got SIGTERM from the kernel and are finishing; after ``grace_s`` they get SIGKILL."""
    pids = {p.name: read_pid(s.run_dir / f"{p.name}.pid") for p in plan}
    left = {n: pid for n, pid in pids.items() if pid is not None}
    if left:
        echo(f"waiting for {', '.join(sorted(left))} of a supervisor that is gone to stop")
        for pid in left.values():
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace_s
        while any(pid_alive(pid) for pid in left.values()) and time.monotonic() < deadline:
            time.sleep(0.1)
        for name, pid in left.items():
            if pid_alive(pid):
                echo(f"{name} (pid {pid}) did not stop in {grace_s:g} s; killing it")
                os.kill(pid, signal.SIGKILL)
    for p in plan:
        (s.run_dir / f"{p.name}.pid").unlink(missing_ok=True)


_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int):
    """``preexec_fn`` of every child: SIGTERM when the supervisor dies, even by SIGKILL."""
    libc = ctypes.CDLL(None, use_errno=True)  # loaded before the fork: the child only calls it

    def preexec():
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the parent died before prctl: stop now
            os.kill(os.getpid(), signal.SIGTERM)

    return preexec


class Supervisor:
    def __init__(self, settings: Settings, plan: list[Proc]):
        self.s = settings
        self.plan = plan
        self.stopping = False

    def _start(self, p: Proc) -> None:
        self.s.log_dir.mkdir(parents=True, exist_ok=True)
        with open(self.s.log_dir / f"{p.name}.log", "ab") as out:
            p.popen = subprocess.Popen([sys.executable, "-m", p.module], stdout=out, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, env=os.environ.copy(),
                                       preexec_fn=self._preexec)
        p.started = time.monotonic()
        p.restart_at = None
        write_pid(self.s.run_dir / f"{p.name}.pid", p.popen.pid)
        log.info("started %s (pid %d)", p.name, p.popen.pid)

    def run(self) -> int:
        self.s.run_dir.mkdir(parents=True, exist_ok=True)
        lock = take_lock(self.s)
        if lock is None:
            log.error("another supervisor runs this cluster (it holds %s); exiting", lock_path(self.s))
            return 3
        reap_orphans(self.s, self.plan, echo=log.warning)
        write_pid(self.s.run_dir / "supervisor.pid", os.getpid())
        self._preexec = _die_with_parent(os.getpid())
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: setattr(self, "stopping", True))
        try:
            for p in self.plan:
                self._start(p)
            while not self.stopping:
                now = time.monotonic()
                for p in self.plan:
                    if p.restart_at is not None:
                        if now >= p.restart_at:
                            self._start(p)
                        continue
                    assert p.popen is not None  # (started, and not waiting to restart)
                    code = p.popen.poll()
                    if code is None:
                        if now - p.started > 30:
                            p.failures = 0
                        continue
                    delay = min(0.5 * 2 ** p.failures, 10.0)
                    p.failures += 1
                    p.restart_at = now + delay
                    log.warning("%s exited with code %s; restarting in %.1f s (log: %s)", p.name, code, delay,
                                self.s.log_dir / f"{p.name}.log")
                time.sleep(0.1)
        finally:
            self._stop_all()
            (self.s.run_dir / "supervisor.pid").unlink(missing_ok=True)
            os.close(lock)
        return 0

    def _stop_all(self) -> None:
        for p in reversed(self.plan):  # services first, the router last
            if p.popen is None or p.popen.poll() is not None:
                continue
            p.popen.terminate()
            try:
                p.popen.wait(timeout=40)
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop in 40 s; killing it", p.name)
                p.popen.kill()
                p.popen.wait()
            (self.s.run_dir / f"{p.name}.pid").unlink(missing_ok=True)
            log.info("stopped %s", p.name)


# ---------------------------------------------------------------------------- commands
def status(settings: Settings | None = None) -> list[dict]:
    """One row per process of the plan: name, pid (from the supervisor's pid files), alive, and
    its state: alive, frozen (stopped by SIGSTOP), restarting (its supervisor starts it again) or
    down (a process that runs and holds no token on the bus counts as down)."""
    from shared.bus.client import Client, Unavailable

    s = settings or Settings()
    plan = load_plan()
    alive: set[str] = set()
    router_up = False
    try:
        with Client(s, connect_timeout_s=1.0) as c:
            router_up = True
            alive = c.alive(timeout=1.0)
    except Unavailable:
        pass
    rows: list[dict[str, Any]]
    if s.identity is not None:  # deployed: processes live on other hosts; the bus says who is alive
        rows = [{"name": "router", "pid": None, "alive": router_up}]
        for p in plan:
            if p.name != "router":
                rows.append({"name": p.name, "pid": None, "alive": p.name in alive})
        return rows
    rows = [{"name": "supervisor", "pid": read_pid(s.run_dir / "supervisor.pid"), "alive": supervisor_running(s)}]
    rows[0]["state"] = "alive" if rows[0]["alive"] else "down"
    for p in plan:
        up = router_up if p.name == "router" else p.name in alive
        # not alive on the bus: frozen (SIGSTOP), restarting (its supervisor runs) or down, from the pid files
        state = "alive" if up else local_state(s, p.name)[0]
        rows.append({"name": p.name, "pid": read_pid(s.run_dir / f"{p.name}.pid"), "alive": up,
                     "state": "down" if state == "running" else state})
    return rows


def private_home(s: Settings) -> None:
    """The cluster's home (spaces, transcripts, clips, logs, recordings) is its user's alone:
    the folder 0700, and every process of the cluster creates files 0600 (umask 077, set in the
    supervisor, inherited by every service); they were 0644 in 0755 folders."""
    s.home.mkdir(parents=True, exist_ok=True)
    s.home.chmod(0o700)
    for d in (s.run_dir, s.log_dir):
        d.mkdir(parents=True, exist_ok=True)
        d.chmod(0o700)


def router_port_taken(endpoint: str) -> str | None:
    """Why the router could not listen on ``endpoint``, or None when it can: for ``tcp/HOST:PORT``
    a trial bind on the same address, as the router would (SO_REUSEADDR, so connections of a
    cluster just stopped do not count); for a socket, a router answering on it (a file left by a
    killed router is removed when the router starts)."""
    import socket

    from shared.bus.config import parse_endpoint, socket_in_use, socket_path

    sock = socket_path(endpoint)
    if sock is not None:
        if socket_in_use(sock):
            return (f"a router already listens on {sock}: a cluster whose supervisor died left it; stop it "
                    f"(`mirrorcoach down`), or use another MIRRORCOACH_HOME")
        return None
    proto, host, port = parse_endpoint(endpoint)
    if proto != "tcp":
        return None
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as e:
            return (f"the router's port {host}:{port} is in use ({e.strerror}): another program listens there, "
                    f"or a router left by a cluster whose supervisor died; stop it, or choose another port "
                    f"with MIRRORCOACH_ROUTER=tcp/{host}:PORT")
    return None


def up(settings: Settings | None = None, wait_s: float = 60.0, echo=print) -> int:
    from shared.bus.client import Client, Unavailable

    s = settings or Settings()
    if s.identity is not None:
        echo(f"error: MIRRORCOACH_DEPLOY is set ({s.deploy}): a deployed cluster runs each process on its host "
             f"(deploy/README.md: systemd units or compose); `up` starts the loopback cluster only")
        return 2
    plan, left = plan_with_left_out()
    for why in left:
        echo(f"note: {why}")
    private_home(s)
    proc = None
    if supervisor_running(s):
        echo(f"the cluster's supervisor is already running (pid {read_pid(s.run_dir / 'supervisor.pid') or '?'})")
    else:
        reap_orphans(s, plan, echo=echo)  # children of a supervisor killed by SIGKILL
        taken = router_port_taken(s.router)
        if taken:  # fail fast and say why (it waited 120 s, then blamed the services)
            echo(f"error: {taken}")
            return 1
        with open(s.log_dir / "supervisor.log", "ab", opener=lambda f, flags: os.open(f, flags, 0o600)) as out:
            os.chmod(out.fileno(), 0o600)
            proc = subprocess.Popen([sys.executable, "-m", "shared.bus.cluster", "supervise"], stdout=out,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                                    env=os.environ.copy())
        echo(f"starting the cluster on {s.router} (supervisor pid {proc.pid})")
    want = {p.name for p in plan if p.name != "router"}
    deadline = time.monotonic() + wait_s
    alive: set[str] = set()
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            if proc.returncode == 3 and supervisor_running(s):  # another `up` started one first: wait for it
                echo("another supervisor started this cluster at the same time; waiting for its services")
                proc = None
                continue
            echo(f"error: the supervisor exited (code {proc.returncode}); see {s.log_dir / 'supervisor.log'}")
            return 1
        try:
            with Client(s, connect_timeout_s=1.0) as c:
                alive = c.alive(timeout=1.0)
        except Unavailable:
            alive = set()
        if want <= alive:
            echo(f"cluster up: router + {', '.join(sorted(want))}; logs in {s.log_dir}")
            return 0
        time.sleep(0.2)
    missing = sorted(want - alive)
    echo(f"error: not alive after {wait_s:g} s: {', '.join(missing)}; see " +
         ", ".join(str(s.log_dir / f"{m}.log") for m in missing))
    return 1


def running(settings: Settings, services: set[str] | None = None) -> bool:
    """Whether the router answers and every service of the plan (or ``services``) is alive."""
    from shared.bus.client import Client, Unavailable

    want = services if services is not None else {p.name for p in load_plan() if p.name != "router"}
    try:
        with Client(settings, connect_timeout_s=1.0) as c:
            return want <= c.alive()
    except Unavailable:
        return False


def down(settings: Settings | None = None, wait_s: float = 60.0, echo=print) -> int:
    s = settings or Settings()
    if not supervisor_running(s):
        reap_orphans(s, load_plan(), echo=echo)  # a supervisor killed by SIGKILL left them
        echo("the cluster is not running")
        return 0
    sup = read_pid(s.run_dir / "supervisor.pid")
    if sup is None:  # the lock is held, but the pid file does not name a live process of ours
        echo(f"error: a supervisor holds {lock_path(s)} but {s.run_dir / 'supervisor.pid'} does not name it; "
             f"find it with `fuser {lock_path(s)}`")
        return 1
    os.kill(sup, signal.SIGTERM)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        if not pid_alive(sup):
            echo("cluster stopped")
            return 0
        time.sleep(0.1)
    echo(f"the supervisor (pid {sup}) did not stop within {wait_s:g} s; killing its process group; "
         f"see {s.log_dir / 'supervisor.log'}")
    try:
        os.killpg(sup, signal.SIGKILL)  # it leads its own session: its children are in the group
    except ProcessLookupError:
        pass
    return 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m shared.bus.cluster", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=["supervise", "up", "down", "status"])
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s supervisor %(levelname)s %(message)s")
    try:
        if args.command == "supervise":
            os.umask(0o077)  # every file of the cluster is its user's alone (see private_home)
            return Supervisor(Settings(), load_plan()).run()
        if args.command == "up":
            return up()
        if args.command == "down":
            return down()
        for r in status():
            print(f"{r['name']:<12} {'alive' if r['alive'] else 'DOWN':<6} {r['pid'] or '-'}")
        return 0
    except MirrorcoachError as e:
        print(f"error: {e.message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
