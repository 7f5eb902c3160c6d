"""``make bench`` (chapter 3 part): one conversation set through the bus (4 shared motions and
4 probes: dialogue -> simulator, pss associate, pss rebuild, the body fit, state saved), and the
full ``reproduce ch3`` run over the uneven population (target under 3 minutes). Writes
``bench/results/ch3.{json,md}``."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench.common import parse_args, private_cluster, stats, write_results


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
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
        t0 = time.perf_counter()
        run(c, Path(tempfile.mkdtemp(prefix="mc-ch3-")), echo=lambda *a: None)
        res["reproduce_ch3_s"] = time.perf_counter() - t0
    print(f"one conversation set {res['conversation_set']['median_ms']:.0f} ms; reproduce ch3 {res['reproduce_ch3_s']:.0f} s")
    write_results(args.out, "ch3", res, [
        "# Chapter 3 benchmark (`make bench`, bench/ch3.py)", "",
        "| what | measured | target |", "|---|---|---|",
        f"| one conversation set through the bus (4 questions + 4 probes, associate, rebuild, body fit, save) | "
        f"{res['conversation_set']['median_ms']:.0f} ms (p95 {res['conversation_set']['p95_ms']:.0f}) | - |",
        f"| full `reproduce ch3` (9 in-model and 6 outside kinds x 10 others, 6 sets, people-like answers, identification, d = 4-8, rules, noise) | "
        f"{res['reproduce_ch3_s']:.0f} s | < 180 s |",
    ])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
