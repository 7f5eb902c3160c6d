"""``make bench``: memory of the cluster under bursts of clients.

Bursts of 200 concurrent clients (100 by default: 20,000 sessions, about 9 minutes), each its
own Zenoh session sending one recognition of a real clip (a request above Zenoh's 3 KB
shared-memory threshold), on a private cluster. After each burst: the bytes in ``/dev/shm`` and the resident memory of
every process of the cluster (router, services, supervisor). The goals: after the second burst,
``/dev/shm`` within 10 % of its level after the first one (before the fix, Zenoh's shared memory
on by default, two bursts left 7.4 GB there); and no process still growing: over the last half of
the bursts each stays within ``LEVEL_OFF`` of its level at the start of that half. The second
burst's growth is reported too: the router's heap climbs over the first few thousand sessions,
and now and then by a few MB later, before it levels off, so one burst against the next (or a
short run's last bursts) cannot tell a warm-up from a leak. With glibc's default malloc arenas
the router levelled off higher (41 -> 87 MB by 3,400 sessions, 95 MB by 10,000); it asks for
``shared.bus.router.MALLOC_ARENAS`` since (62-67 MB after 20,000 sessions in two runs).

Writes ``bench/results/memory.json`` and ``bench/results/memory.md``.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench.common import parse_args, private_cluster, write_results

BURSTS = 100
LEVEL_OFF = 0.10  # over the last half of the bursts, a process grows at most this share (a leak of 0.6 KB per session does more)


def shm_bytes() -> int:
    return sum(p.stat().st_blocks * 512 for p in Path("/dev/shm").rglob("*") if p.is_file())


def status_mb(pid: int, field: str = "VmRSS") -> float:
    """A process's memory figure from /proc (``VmRSS`` resident now, ``VmHWM`` its peak), MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024
    return 0.0


def rss_mb(pid: int) -> float:
    return status_mb(pid, "VmRSS")


def cluster_pids(s) -> dict[str, int]:
    from shared.bus.pidfiles import read_pid

    out = {}
    for f in sorted(s.run_dir.glob("*.pid")):
        pid = read_pid(f)
        if pid is not None:
            out[f.stem] = pid
    return out


def burst(s, probe: dict, n: int) -> int:
    """``n`` clients at once, each its own session, one recognition each; the number that got an answer."""
    from shared.bus.client import Client, RemoteError, Unavailable

    def one(_):
        try:
            with Client(s, connect_timeout_s=30.0) as c:
                return bool(c.request("pss", "recognize", {"space": "mem", "clips": [probe]}, timeout=120)["nearest"])
        except (Unavailable, RemoteError):
            return False

    with ThreadPoolExecutor(n) as pool:
        return sum(pool.map(one, range(n)))


def main(argv=None) -> int:
    def extra(ap):
        ap.add_argument("--clients", type=int, default=200)
        ap.add_argument("--bursts", type=int, default=BURSTS, help="bursts of clients; the goal reads the last "
                        "half (at least 3)")

    args = parse_args(__doc__, argv, extra=extra)
    from schemas.common import clip_to_wire
    from shared.bus.client import Client
    from shared.io import find_clips, load_clip

    files = find_clips([args.hdm05 / "amc"])
    train = [load_clip(f).resample(30) for f in files if "_bd_" in f.name]
    probe = clip_to_wire(load_clip(next(f for f in files if "_dg_" in f.name)), with_skeleton=False)
    res: dict = {"clients": args.clients, "bursts": []}
    shm0 = shm_bytes()
    with private_cluster("mem") as s:
        with Client(s) as c:
            c.request("pss", "build", {"space": "mem", "clips": [clip_to_wire(x) for x in train]})
        for b in range(max(3, args.bursts)):
            t0 = time.perf_counter()
            ok = burst(s, probe, args.clients)
            time.sleep(2.0)  # let sessions close
            pids = cluster_pids(s)
            row = {"answered": ok, "seconds": time.perf_counter() - t0, "shm_mb": (shm_bytes() - shm0) / 2**20,
                   "rss_mb": {n: rss_mb(p) for n, p in pids.items()}}
            res["bursts"].append(row)
            print(f"burst {b + 1}: {ok}/{args.clients} answered in {row['seconds']:.1f} s; /dev/shm +{row['shm_mb']:.1f} MB; "
                  + ", ".join(f"{n} {m:.0f} MB" for n, m in row["rss_mb"].items()))
        res["shared_memory"] = shared_memory_setting(s)
    first, second, last = res["bursts"][0], res["bursts"][1], res["bursts"][-1]
    half = len(res["bursts"]) - max(1, len(res["bursts"]) // 2) - 1  # the burst the last half grows from
    settled = res["bursts"][half]
    late = {n: last["rss_mb"][n] / settled["rss_mb"][n] - 1 for n in settled["rss_mb"] if n in last["rss_mb"]}
    res["growth_last_half"] = late
    late_sessions = args.clients * (len(res["bursts"]) - 1 - half)
    growth = {n: second["rss_mb"][n] / first["rss_mb"][n] - 1 for n in first["rss_mb"] if n in second["rss_mb"]}
    res["growth"] = growth
    sessions = args.clients * (len(res["bursts"]) - 1)
    slope = {n: 1024 * (last["rss_mb"][n] - first["rss_mb"][n]) / sessions for n in first["rss_mb"]
             if n in last["rss_mb"]}
    res["kb_per_session_after_burst_1"] = slope
    shm_ok = second["shm_mb"] <= max(1.1 * first["shm_mb"], 1.0)
    rss_ok = all(g <= LEVEL_OFF for g in late.values())
    md = ["# Memory under bursts of clients", "",
          f"`python -m bench.memory{'' if args.bursts == BURSTS else f' --bursts {args.bursts}'}`: {len(res['bursts'])} bursts of {args.clients} concurrent clients, each its own Zenoh session and one "
          f"recognition; Zenoh shared memory: {res['shared_memory']}.", "",
          "| after burst | answered | /dev/shm added | " + " | ".join(first["rss_mb"]) + " |",
          "|---|---|---|" + "---|" * len(first["rss_mb"])]
    for i, row in enumerate(res["bursts"]):
        md.append(f"| {i + 1} | {row['answered']}/{args.clients} | {row['shm_mb']:.1f} MB | "
                  + " | ".join(f"{row['rss_mb'].get(n, 0):.0f} MB" for n in first["rss_mb"]) + " |")
    md += ["", "Growth from burst 1 to burst 2: " + ", ".join(f"{n} {100 * g:+.1f} %" for n, g in growth.items()),
           "", f"Long run, burst 1 to burst {len(res['bursts'])} ({sessions} more sessions), KB per session: "
               + ", ".join(f"{n} {k:+.1f}" for n, k in slope.items()),
           "", f"The last half, burst {half + 1} to burst {len(res['bursts'])} ({late_sessions} sessions): "
               + ", ".join(f"{n} {100 * g:+.1f} % ({1024 * (last['rss_mb'][n] - settled['rss_mb'][n]) / late_sessions:+.1f} KB "
                           "per session)" for n, g in late.items()),
           "", f"Goals: /dev/shm within 10 % of its level after the first burst: {'met' if shm_ok else 'missed'}; "
               f"no process still growing (over the last half, each within {100 * LEVEL_OFF:g} % of its level at its "
               f"start): {'met' if rss_ok else 'missed'}."]
    write_results(args.out, "memory", res, md)
    return 0


def shared_memory_setting(s) -> str:
    from shared.bus.config import client_config

    return client_config(s).get_json("transport/shared_memory/enabled")


if __name__ == "__main__":
    raise SystemExit(main())
