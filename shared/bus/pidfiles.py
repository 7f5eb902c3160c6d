"""A cluster's processes as this host sees them in its pid files, without the supervisor:
which process a pid file names (the pid and its start time), whether a supervisor holds a
home's lock, and what state a process that does not answer is in. The bus's client reads
:func:`local_state` to name why a service is silent; :mod:`shared.bus.cluster` (the supervisor)
writes the files."""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

from shared.bus.config import Settings


def _stat_fields(pid: int) -> list[str] | None:
    """``/proc/PID/stat``'s fields after the command's name (the third field first), or None."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def proc_stat(pid: int) -> tuple[str, str] | None:
    """(state, start time in clock ticks since boot) of a process, or None if there is none."""
    fields = _stat_fields(pid)
    return None if fields is None else (fields[0], fields[19])


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds a process has spent so far, or None if there is none."""
    fields = _stat_fields(pid)
    return None if fields is None else (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def pid_alive(pid: int) -> bool:
    st = proc_stat(pid)
    return st is not None and st[0] not in "ZX"  # a zombie child of ours is not alive


def write_pid(path: Path, pid: int) -> None:
    """``PID STARTTIME``: the start time tells our process from a later one given the same pid."""
    st = proc_stat(pid)
    path.write_text(f"{pid} {st[1] if st else 0}\n")


def read_pid(path: Path) -> int | None:
    """The pid in ``path`` if that very process (same start time) still runs, else None."""
    try:
        number, start = path.read_text().split()
        pid = int(number)
    except (OSError, ValueError):
        return None
    st = proc_stat(pid)
    return pid if st is not None and st[0] not in "ZX" and st[1] == start else None


def lock_path(s: Settings) -> Path:
    return s.run_dir / "supervisor.lock"


def take_lock(s: Settings, tries: int = 20) -> int | None:
    """The supervisor's lock (an open fd, held until the process ends), or None when another
    supervisor holds it. Retries for about a second: ``supervisor_running`` probes it briefly."""
    fd = os.open(lock_path(s), os.O_RDWR | os.O_CREAT, 0o600)
    for _ in range(tries):
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            time.sleep(0.05)
    os.close(fd)
    return None


def supervisor_running(s: Settings) -> bool:
    """Whether a supervisor holds this home's lock (a probe with a shared lock, released at once)."""
    try:
        fd = os.open(lock_path(s), os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


def local_state(s: Settings, name: str) -> tuple[str, str]:
    """What this host knows of a process of the cluster from its pid files: ``("frozen",
    detail)`` (stopped by SIGSTOP or a debugger), ``("running", detail)``, ``("restarting",
    detail)`` (its supervisor runs, the process does not), or ``("down", "")``. Used to name
    the cause when a service does not answer."""
    pid = read_pid(s.run_dir / f"{name}.pid")
    if pid is not None:
        st = proc_stat(pid)
        if st is not None and st[0] in "Tt":
            return "frozen", f"process {pid} is stopped"
        return "running", f"process {pid}"
    if supervisor_running(s):
        return "restarting", f"the supervisor starts it again; its log: {s.log_dir / (name + '.log')}"
    return "down", ""
