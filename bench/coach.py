"""``make bench`` (coach part): one coaching trial through the bus (5 repetitions in; the
emphatic motion, alpha and adverb out; feasibility check on) against the 300 ms target, and 20
concurrent sessions (throughput and 95th-percentile latency). Writes ``bench/results/coach.*``."""

from __future__ import annotations

import time

from bench.common import concurrent, parse_args, private_cluster, stats, write_results


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    from schemas.common import clip_to_wire
    from shared.agents.learner import SimulatedLearner, population
    from shared.bus.client import Client
    from shared.io import find_clips, load_clip

    files = find_clips([args.hdm05 / "amc" / "squat1Reps"])
    target = load_clip(next(f for f in files if "_bd_" in f.name))
    learner = SimulatedLearner("bench", target.resample(30), population(1, 0)[0])
    attempts = [clip_to_wire(a) for a in learner.imitate(target.resample(30))]
    res: dict = {}
    with private_cluster("benchcoach") as s, Client(s) as c:
        c.request("coach", "start", {"session": "one", "target": clip_to_wire(target), "replace": True})
        c.request("coach", "attempt", {"session": "one", "clips": attempts})  # warm-up
        ts = []
        for _ in range(15):
            t0 = time.perf_counter()
            r = c.request("coach", "attempt", {"session": "one", "clips": attempts})
            ts.append(time.perf_counter() - t0)
        res["trial"] = stats(ts)
        res["trial_in_service_ms"] = 1e3 * r["seconds"]
        for i in range(20):
            c.request("coach", "start", {"session": f"c{i}", "target": clip_to_wire(target), "replace": True})
        res["concurrent_20"] = concurrent(
            lambda i: c.request("coach", "attempt", {"session": f"c{i}", "clips": attempts}, timeout=300), 20, 3)
    cc = res["concurrent_20"]
    print(f"one coaching trial through the bus: {res['trial']['median_ms']:.0f} ms median (p95 {res['trial']['p95_ms']:.0f}); "
          f"20 concurrent sessions: {cc['throughput_per_s']:.1f} trials/s, p95 {cc['p95_ms']:.0f} ms")
    write_results(args.out, "coach", res, [
        "# Coach benchmark (`make bench`, bench/coach.py)", "",
        "A squat target (HDM05, actor bd); an attempt of 5 repetitions by a simulated learner; the feasibility check on.", "",
        "| what | measured | target |", "|---|---|---|",
        f"| one coaching trial through the bus (attempt in, emphatic motion and adverb out) | "
        f"{res['trial']['median_ms']:.0f} ms (p95 {res['trial']['p95_ms']:.0f}) | <= 300 ms |",
        f"| of which inside the coach service | {res['trial_in_service_ms']:.0f} ms | - |",
        f"| 20 concurrent sessions | {cc['throughput_per_s']:.1f} trials/s, p95 {cc['p95_ms']:.0f} ms, median "
        f"{cc['median_ms']:.0f} ms | reported |",
    ])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
