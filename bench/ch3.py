"""``make bench`` (chapter 3 part): one conversation set through the bus (4 shared motions and
4 probes: dialogue -> simulator, pss associate, pss rebuild, the body fit, state saved), and the
full ``reproduce ch3`` run over the uneven population (target under 3 minutes), with the CPU
seconds each process of the cluster spent on it: their sum over the machine's cores is the
shortest the run could take with every core busy all the time. Writes
``bench/results/ch3.{json,md}``."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from bench.common import parse_args, private_cluster, stats, write_results


def cpu_seconds(s) -> dict[str, float]:
    """User + system CPU seconds so far of every running process of the cluster (its pid files)
    and of this one (``bench``)."""
    from shared.bus.pidfiles import cpu_seconds as of_pid
    from shared.bus.pidfiles import read_pid

    out = {}
    for f in sorted(s.run_dir.glob("*.pid")):
        pid = read_pid(f)
        spent = None if pid is None or f.stem == "supervisor" else of_pid(pid)
        if spent is not None:
            out[f.stem] = spent
    t = os.times()
    out["bench"] = t.user + t.system
    return out


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    from shared.agents.population import KINDS, OUTSIDE_KINDS
    from shared.bus.client import Client
    from shared.reproduce.ch3 import run

    res: dict = {}
    with private_cluster("benchch3") as s, Client(s) as c:
        c.request("simulator", "other_create", {"other": "r2", "params": {"d": 6, "g_max": 0.6}, "replace": True})
        c.request("estimator", "start", {"estimate": "r2", "other": "r2", "d": 6, "replace": True})
        ts = []
        for _ in range(10):
            t0 = time.perf_counter()
            c.request("estimator", "converse", {"estimate": "r2", "sets": 1})
            ts.append(time.perf_counter() - t0)
        res["conversation_set"] = stats(ts)
        before = cpu_seconds(s)
        t0 = time.perf_counter()
        run(c, Path(tempfile.mkdtemp(prefix="mc-ch3-")), echo=lambda *a: None)
        res["reproduce_ch3_s"] = time.perf_counter() - t0
        after = cpu_seconds(s)
    cpu = {k: round(v - before.get(k, 0.0), 1) for k, v in sorted(after.items(), key=lambda kv: -kv[1])}
    cores = os.cpu_count() or 1
    total = sum(cpu.values())
    res.update(cpu_s=cpu, cpu_total_s=total, cores=cores, all_cores_busy_s=total / cores,
               cores_busy=total / res["reproduce_ch3_s"])
    print(f"one conversation set {res['conversation_set']['median_ms']:.0f} ms; reproduce ch3 {res['reproduce_ch3_s']:.0f} s; "
          f"CPU {total:.0f} s ({', '.join(f'{k} {v:.0f}' for k, v in cpu.items())}) on {cores} cores")
    write_results(args.out, "ch3", res, [
        "# Chapter 3 benchmark (`make bench`, bench/ch3.py)", "",
        "| what | measured | target |", "|---|---|---|",
        f"| one conversation set through the bus (4 questions + 4 probes, associate, rebuild, body fit, save) | "
        f"{res['conversation_set']['median_ms']:.0f} ms (p95 {res['conversation_set']['p95_ms']:.0f}) | - |",
        f"| full `reproduce ch3` ({len(KINDS)} in-model and {len(OUTSIDE_KINDS)} outside kinds x 10 others, 6 sets, people-like "
        "answers, identification, d = 4-8, rules, noise) | "
        f"{res['reproduce_ch3_s']:.0f} s | < 180 s |",
        f"| its CPU, every process of the cluster and the bench | {total:.0f} s: "
        + ", ".join(f"{k} {v:.0f}" for k, v in cpu.items()) + " | - |",
        f"| the same CPU spread over all {cores} cores (the shortest the run could be as it computes now) | "
        f"{total / cores:.0f} s (the run kept {res['cores_busy']:.2f} cores busy on average) | < 180 s |",
    ])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
