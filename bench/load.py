"""``make bench``: the cluster under load ("Limits under load").

A deployed cluster on loopback (TLS with mutual authentication and access control, the way it
runs across hosts; ``--plain`` for the loopback default), each service its own process:

1. **recognition**: ``--clients`` (200) concurrent clients, each its own Zenoh session, send
   recognitions of a real clip for ``--seconds`` (60);
2. **coaching trials**: ``--clients`` concurrent clients, each with its own coaching session of a
   simulated learner, run one trial after another for ``--seconds``;
3. **memory**: each service's resident memory after a warm-up and after ``--requests`` (10,000)
   more recognitions; the goal is growth under 10 %.

Every request is bounded (a timeout); a saturated service answers ``unavailable`` at once
(its queue is bounded, ``MIRRORCOACH_QUEUE``), counted apart from other errors. Throughput,
p50/p95/p99 of the answered requests and the errors go to ``bench/results/load.{json,md}``.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from bench.common import parse_args, write_results

REPO = Path(__file__).resolve().parent.parent
SERVICES = ("pss", "simulator", "coach")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def cluster(plain: bool, queue: int | None = None):
    """Router and services as separate processes (each service keeping at most ``queue``
    requests waiting, if given); yields (client Settings, {service: pid})."""
    home = Path(tempfile.mkdtemp(prefix="mc-bench-load-"))
    port = _free_port()
    saved = dict(os.environ)
    base = {k: v for k, v in os.environ.items() if not k.startswith("MIRRORCOACH_")}
    base["MIRRORCOACH_HOME"] = str(home)
    if queue is not None:
        base["MIRRORCOACH_QUEUE"] = str(queue)
    envs = {}
    if plain:
        for n in ("router", "cli", *SERVICES):
            envs[n] = {**base, "MIRRORCOACH_ROUTER": f"tcp/127.0.0.1:{port}"}
    else:
        from shared.bus.deploy import init

        init(home / "deploy", [f"router=127.0.0.1:{port}"], [*SERVICES, "cli"])
        for n in ("router", "cli", *SERVICES):
            envs[n] = {**base, "MIRRORCOACH_DEPLOY": str(home / "deploy" / n)}
    procs = {}
    logs = home / "logs"
    logs.mkdir()
    try:
        for n in ("router", *SERVICES):
            module = "shared.bus.router" if n == "router" else f"services.{n}"
            procs[n] = subprocess.Popen([sys.executable, "-m", module], env=envs[n], cwd=REPO,
                                        stdout=subprocess.DEVNULL, stderr=open(logs / f"{n}.log", "w"))  # noqa: SIM115 (the child holds it)
        os.environ.clear()
        os.environ.update(envs["cli"])
        from shared.bus.client import Client
        from shared.bus.config import Settings

        s = Settings()
        deadline = time.monotonic() + 90
        with Client(s, connect_timeout_s=30) as c:
            while not set(SERVICES) <= c.alive() and time.monotonic() < deadline:  # bounded
                time.sleep(0.5)
            if not set(SERVICES) <= c.alive():
                raise SystemExit(f"the cluster did not start; see {logs}")
        yield s, {n: p.pid for n, p in procs.items()}
    finally:
        for p in procs.values():
            p.terminate()
        for p in procs.values():
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        os.environ.clear()
        os.environ.update(saved)


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def load(settings, clients: int, seconds: float, call, setup=None) -> dict:
    """``clients`` threads, each its own session (``setup(client, i)`` once), calling
    ``call(client, i, state)`` until ``seconds`` have passed; outcomes and latencies."""
    from shared.bus.client import Client, RemoteError, Unavailable

    lock = threading.Lock()
    lat: list[float] = []
    refused: list[float] = []  # seconds until a saturated service said so
    errors: dict[str, int] = {}
    barrier = threading.Barrier(clients)
    t_start = [0.0]

    def count(kind: str) -> None:
        with lock:
            errors[kind] = errors.get(kind, 0) + 1

    def worker(i: int) -> None:
        try:
            c = Client(settings, connect_timeout_s=60.0)
        except Unavailable:
            count("no_session")
            barrier.abort()
            return
        with c:
            state = setup(c, i) if setup else None
            try:
                barrier.wait(timeout=600)
            except threading.BrokenBarrierError:
                pass
            with lock:
                if not t_start[0]:
                    t_start[0] = time.perf_counter()
            end = t_start[0] + seconds
            while time.perf_counter() < end:
                t0 = time.perf_counter()
                try:
                    call(c, i, state)
                    with lock:
                        lat.append(time.perf_counter() - t0)
                except Unavailable as e:
                    count(f"unavailable ({e.details.get('cause', '?')})")
                except RemoteError as e:
                    count(f"{e.code} ({e.details.get('cause', '')})" if e.code == "unavailable" else e.code)
                    if e.details.get("cause") == "saturated":
                        with lock:
                            refused.append(time.perf_counter() - t0)

    t0 = time.perf_counter()
    with ThreadPoolExecutor(clients) as pool:
        list(pool.map(worker, range(clients)))
    wall = time.perf_counter() - (t_start[0] or t0)
    a = 1e3 * np.asarray(lat) if lat else np.zeros(1)
    return {"clients": clients, "seconds": wall, "answered": len(lat), "throughput_per_s": len(lat) / wall,
            "p50_ms": float(np.percentile(a, 50)), "p95_ms": float(np.percentile(a, 95)),
            "p99_ms": float(np.percentile(a, 99)), "errors": errors,
            "saturated_p99_ms": float(np.percentile(1e3 * np.asarray(refused), 99)) if refused else None}


def main(argv=None) -> int:
    def extra(ap):
        ap.add_argument("--clients", type=int, default=200)
        ap.add_argument("--seconds", type=float, default=60.0)
        ap.add_argument("--requests", type=int, default=10_000, help="recognitions between the two memory readings")
        ap.add_argument("--plain", action="store_true", help="the loopback default (no TLS) instead of deployed mode")

    args = parse_args(__doc__, argv, extra=extra)
    from schemas.common import clip_to_wire
    from shared.bus.client import Client
    from shared.io import find_clips, load_clip

    files = find_clips([args.hdm05 / "amc"])
    train = [load_clip(f) for f in files if "_bd_" in f.name]
    probe = clip_to_wire(load_clip(next(f for f in files if "_dg_" in f.name)), with_skeleton=False)
    target = clip_to_wire(load_clip(next(f for f in files if "_bd_squat" in f.name)))
    mode = "plain TCP on loopback" if args.plain else "deployed: TLS (mutual authentication) + access control, loopback"
    res: dict = {"mode": mode, "clients": args.clients, "seconds": args.seconds}
    with cluster(args.plain) as (s, pids):
        with Client(s) as c:
            c.request("pss", "build", {"space": "load", "clips": [clip_to_wire(x) for x in train]}, timeout=300)
        at_start = {n: rss_mb(p) for n, p in pids.items()}

        def recognize(c, i, _):
            c.request("pss", "recognize", {"space": "load", "clips": [probe]}, timeout=30)

        print(f"recognition: {args.clients} clients for {args.seconds:g} s ({mode}) ...", flush=True)
        res["recognition"] = load(s, args.clients, args.seconds, recognize)
        print(_line(res["recognition"]), flush=True)

        def start(c, i):
            name = f"load{i}"
            c.request("coach", "start", {"session": name, "target": target, "learner": name, "index": i % 12},
                      timeout=600)
            return name

        def trial(c, i, session):
            c.request("coach", "run", {"session": session, "trials": 1}, timeout=120)

        print(f"coaching trials: {args.clients} clients, each its own session, for {args.seconds:g} s ...", flush=True)
        res["coaching"] = load(s, args.clients, args.seconds, trial, setup=start)
        print(_line(res["coaching"]), flush=True)

        # memory: a warm-up, then --requests recognitions from 50 clients
        print(f"memory: {args.requests} recognitions ...", flush=True)
        n_clients = 50
        per = int(np.ceil(args.requests / n_clients))

        def burst(k):
            with Client(s, connect_timeout_s=60) as c:
                for _ in range(k):
                    try:
                        c.request("pss", "recognize", {"space": "load", "clips": [probe]}, timeout=60)
                    except Exception:  # counted by the phases above; here only memory matters
                        pass

        with ThreadPoolExecutor(n_clients) as pool:
            list(pool.map(burst, [max(1, 1000 // n_clients)] * n_clients))  # warm-up
        before = {n: rss_mb(p) for n, p in pids.items()}
        t0 = time.perf_counter()
        with ThreadPoolExecutor(n_clients) as pool:
            list(pool.map(burst, [per] * n_clients))
        after = {n: rss_mb(p) for n, p in pids.items()}
        res["memory"] = {"requests": per * n_clients, "seconds": time.perf_counter() - t0, "before_mb": before,
                         "after_mb": after, "growth": {n: after[n] / before[n] - 1 for n in before},
                         "at_start_mb": at_start}
    # saturation: the same recognitions against a pss that keeps at most 8 requests waiting
    with cluster(args.plain, queue=8) as (s, pids):
        with Client(s) as c:
            c.request("pss", "build", {"space": "load", "clips": [clip_to_wire(x) for x in train]}, timeout=300)
        print(f"saturation: {args.clients} clients against a queue of 8 for 20 s ...", flush=True)
        res["saturation"] = load(s, args.clients, 20.0, recognize)
        print(_line(res["saturation"]), flush=True)
    growth = res["memory"]["growth"]
    met = all(g < 0.10 for g in growth.values())
    md = ["# The cluster under load", "",
          f"`python -m bench.load` ({mode}; {os.cpu_count()} cores). Each client is its own Zenoh session; every "
          f"request has a timeout; a saturated service answers `unavailable` at once (bounded queue).", "",
          "| load | clients | seconds | answered | throughput | p50 | p95 | p99 | errors |",
          "|---|---|---|---|---|---|---|---|---|"]
    for key, what in (("recognition", "recognition (pss)"), ("coaching", "coaching trials (coach, pss, simulator)"),
                      ("saturation", "recognition, pss queue 8 (`MIRRORCOACH_QUEUE=8`)")):
        r = res[key]
        errs = ", ".join(f"{k} {v}" for k, v in sorted(r["errors"].items())) or "none"
        md.append(f"| {what} | {r['clients']} | {r['seconds']:.0f} | {r['answered']} | {r['throughput_per_s']:.1f} /s | "
                  f"{r['p50_ms']:.0f} ms | {r['p95_ms']:.0f} ms | {r['p99_ms']:.0f} ms | {errs} |")
    sat = res["saturation"]
    if sat["saturated_p99_ms"] is not None:
        hung = sum(v for k, v in sat["errors"].items() if "timeout" in k)
        md += ["", f"Saturated: {sat['errors'].get('unavailable (saturated)', 0)} requests were told `unavailable` "
                   f"(cause `saturated`) at once, p99 {sat['saturated_p99_ms']:.0f} ms; "
                   + ("none waited for its timeout." if not hung else f"{hung} waited for their timeout.")]
    m = res["memory"]
    md += ["", f"Memory over {m['requests']} recognitions ({m['seconds']:.0f} s, 50 clients), after the two loads above "
               f"and a warm-up of 1,000 (at start: the cluster with its space built, before any load):", "",
           "| process | at start | before | after | growth |", "|---|---|---|---|---|"]
    md += [f"| {n} | {m['at_start_mb'][n]:.0f} MB | {m['before_mb'][n]:.0f} MB | {m['after_mb'][n]:.0f} MB | "
           f"{100 * growth[n]:+.1f} % |" for n in growth]
    md += ["", f"Goal (growth under 10 % for every process): {'met' if met else 'missed'}."]
    write_results(args.out, "load" if not args.plain else "load_plain", res, md)
    return 0


def _line(r: dict) -> str:
    return (f"  {r['answered']} answered in {r['seconds']:.0f} s: {r['throughput_per_s']:.1f} /s, p50 {r['p50_ms']:.0f} ms, "
            f"p95 {r['p95_ms']:.0f} ms, p99 {r['p99_ms']:.0f} ms; errors {r['errors'] or 'none'}")


if __name__ == "__main__":
    raise SystemExit(main())
