"""``make bench``: the largest valid requests at once, against each service's memory budget.

Four clients at once each send the largest request the contract allows in practice: a
recognition of a 100,000-frame clip (62 channels, 47 MB on the wire, near the 64 MiB payload
limit) to pss, a generation of 100,000 frames, and the simulator's inverse dynamics of its first
40,000 frames on a human body (the largest whose reply, twice the request, fits the limit).
Measured on a private cluster: the peak resident memory of the service while they run
(``VmHWM``, reset before), the answers (a request the
budget cannot take now waits for memory; one it can never take is refused up front), and the
resident memory after them against the level before (memory returned), with the space's
recognition caches and the simulator's MuJoCo already loaded by one short request each.

Writes ``bench/results/budget.json`` and ``bench/results/budget.md``.
"""

from __future__ import annotations

import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from bench.common import parse_args, private_cluster, write_results
from bench.memory import cluster_pids, rss_mb, status_mb


PERFORM_FRAMES = 40_000


def peak_mb(pid: int) -> float:
    return status_mb(pid, "VmHWM")


def reset_peak(pid: int) -> None:
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # the kernel's peak RSS starts again from now


def main(argv=None) -> int:
    def extra(ap):
        ap.add_argument("--frames", type=int, default=100_000)
        ap.add_argument("--clients", type=int, default=4)

    args = parse_args(__doc__, argv, extra=extra)
    from schemas.common import clip_to_wire
    from shared.bus.client import Client, RemoteError, Unavailable
    from shared.io import find_clips, load_clip

    files = find_clips([args.hdm05 / "amc"])
    train = [load_clip(f).resample(30) for f in files if "_bd_" in f.name][:20]
    base = load_clip(next(f for f in files if "_dg_" in f.name))
    big = base.with_data(np.tile(base.data, (args.frames // base.n_frames + 1, 1))[: args.frames], name="long")
    wire = clip_to_wire(big, with_skeleton=False)
    res: dict = {"frames": args.frames, "clients": args.clients, "runs": []}
    with private_cluster("budget") as s:
        with Client(s) as c:
            c.request("pss", "build", {"space": "budget", "clips": [clip_to_wire(x) for x in train]}, timeout=300)
            # one short recognition first: the space's recognition caches (kept while the space is
            # loaded) are part of the level memory returns to, not of what a request holds
            c.request("pss", "recognize", {"space": "budget", "clips": [clip_to_wire(train[0])]})
            # and one short inverse dynamics: MuJoCo and the human body are loaded on first use
            c.request("simulator", "perform", {"skeleton": base.skeleton.to_json(),
                                               "clip": clip_to_wire(base, with_skeleton=False)})
        res["budget_mb"] = s.memory_mb
        # inverse dynamics adds every joint's torques: its reply is about twice its request, so the
        # largest valid perform is about 40,000 frames (100,000 would be refused as too large a reply)
        human = {"skeleton": base.skeleton.to_json(),
                 "clip": clip_to_wire(big.with_data(big.data[:PERFORM_FRAMES]), with_skeleton=False)}
        runs = 2 * (("pss", "recognize", {"space": "budget", "clips": [wire]}),
                    ("pss", "generate", {"space": "budget", "mix": {train[0].name: 1.0}, "frames": args.frames}))
        runs += (("simulator", "perform", human),)
        for service, verb, message in runs:
            pid = cluster_pids(s)[service]
            time.sleep(2.0)
            before = rss_mb(pid)
            reset_peak(pid)

            def one(_):
                t0 = time.perf_counter()
                try:
                    with Client(s, connect_timeout_s=30.0) as c:
                        c.request(service, verb, message, timeout=600)
                    return "ok", time.perf_counter() - t0
                except (RemoteError, Unavailable) as e:
                    return f"{getattr(e, 'code', 'unavailable')}: {str(e)[:120]}", time.perf_counter() - t0

            t0 = time.perf_counter()
            with ThreadPoolExecutor(args.clients) as pool:
                answers = list(pool.map(one, range(args.clients)))
            seconds = time.perf_counter() - t0
            time.sleep(3.0)
            after = rss_mb(pid)
            with Client(s) as c:  # one small request after them: what the last large message left held
                c.request(service, "list", {})
            time.sleep(1.0)
            row = {"service": service, "verb": verb, "after_small_mb": rss_mb(pid),
                   "answers": dict(Counter(a for a, _ in answers)), "seconds": seconds,
                   "longest_s": max(t for _, t in answers), "rss_before_mb": before, "peak_mb": peak_mb(pid),
                   "rss_after_mb": after}
            row["returned"] = row["rss_after_mb"] <= 1.10 * before
            row["under_budget"] = row["peak_mb"] <= res["budget_mb"]
            res["runs"].append(row)
            print(f"{service}/{verb}: {row['answers']} in {seconds:.1f} s; {before:.0f} MB before, peak "
                  f"{row['peak_mb']:.0f} MB (budget {res['budget_mb']:g} MB), {after:.0f} MB after, "
                  f"{row['after_small_mb']:.0f} MB after a small request")
    md = ["# The largest valid requests at once, against the memory budget", "",
          f"`python -m bench.budget`: {args.clients} clients at once, each one request of {args.frames:,} frames "
          f"(62 channels; the simulator's {PERFORM_FRAMES:,}, the largest whose reply fits the payload limit); "
          f"each service's budget `MIRRORCOACH_MEMORY_MB` = {res['budget_mb']:g} (the systemd unit's "
          "`MemoryMax` and the compose limit are 2 GB). After each run, one small request (`list`).", "",
          "| service/verb | answers | seconds (longest) | RSS before | peak | after | after a small request | "
          "under budget | returned (<= +10 %) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in res["runs"]:
        md.append(f"| {r['service']}/{r['verb']} | {', '.join(f'{k}: {v}' for k, v in r['answers'].items())} | "
                  f"{r['seconds']:.0f} ({r['longest_s']:.0f}) | {r['rss_before_mb']:.0f} MB | {r['peak_mb']:.0f} MB | "
                  f"{r['rss_after_mb']:.0f} MB | {r['after_small_mb']:.0f} MB | {'yes' if r['under_budget'] else 'NO'} | "
                  f"{'yes' if r['returned'] else 'NO'} |")
    write_results(args.out, "budget", res, md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
