"""``make bench`` (simulator part, the targets to report):

* ``perform`` on a 300-frame human clip (the first 300 frames of an HDM05 clip at 120 fps, 62 channels, a 70 kg body
  from its actor's skeleton): the library alone, and through the bus (simulator service);
* 100 learner imitations (one learner, 100 trials of a squat, library and through the bus).

Writes ``bench/results/sim.json`` and ``bench/results/sim.md``.
"""

from __future__ import annotations

import time

from bench.common import parse_args, private_cluster, stats, write_results


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)

    from schemas.common import clip_to_wire
    from shared.agents.learner import SimulatedLearner, population
    from shared.bodies.body import perform
    from shared.bodies.human import human_body
    from shared.bus.client import Client
    from shared.io import find_clips, load_clip

    files = find_clips([args.hdm05 / "amc"])
    clip = next(c for c in (load_clip(f) for f in files if "_bd_" in f.name) if c.n_frames >= 300).frames(0, 300)
    squat = load_clip(next(f for f in files if "_bd_" in f.name and "squat" in f.name)).resample(30)
    body = human_body(clip.skeleton, 70.0)
    res: dict = {"clip": {"name": clip.name, "frames": clip.n_frames, "channels": len(clip.channels)}}

    perform(body, clip)
    ts = []
    for _ in range(10):
        t0 = time.perf_counter()
        perform(body, clip)
        ts.append(time.perf_counter() - t0)
    res["perform_library"] = stats(ts)
    t0 = time.perf_counter()
    human_body(clip.skeleton, 70.0)
    res["build_human_body_ms"] = 1e3 * (time.perf_counter() - t0)

    learner = SimulatedLearner("bench", squat, population(1, 0)[0])
    t0 = time.perf_counter()
    for _ in range(100):
        learner.imitate(squat)
    res["imitations_100_library_s"] = time.perf_counter() - t0

    with private_cluster("benchsim") as s, Client(s) as c:
        req = {"skeleton": clip.skeleton.to_json(), "clip": clip_to_wire(clip, with_skeleton=False)}
        c.request("simulator", "perform", req)  # builds and caches the body
        ts = []
        for _ in range(10):
            t0 = time.perf_counter()
            c.request("simulator", "perform", req)
            ts.append(time.perf_counter() - t0)
        res["perform_bus"] = stats(ts)
        c.request("simulator", "learner_create", {"learner": "bench", "target": clip_to_wire(squat)})
        demo = clip_to_wire(squat, with_skeleton=False)
        t0 = time.perf_counter()
        for _ in range(100):
            c.request("simulator", "learner_imitate", {"learner": "bench", "demonstration": demo})
        res["imitations_100_bus_s"] = time.perf_counter() - t0

    print(f"perform, {clip.n_frames}-frame human clip: library {res['perform_library']['median_ms']:.0f} ms, "
          f"bus {res['perform_bus']['median_ms']:.0f} ms (median); 100 imitations: library "
          f"{res['imitations_100_library_s']:.2f} s, bus {res['imitations_100_bus_s']:.2f} s")
    md = [
        "# Simulator benchmark (`make bench`, bench/sim.py)", "",
        f"Clip {clip.name}: {clip.n_frames} frames at {clip.fps:g} fps, {len(clip.channels)} channels; 70 kg body "
        "from the actor's ASF (built once and cached by the service). Medians of 10 runs.", "",
        "| what | measured |", "|---|---|",
        f"| perform (inverse dynamics, centre of gravity, feasibility), library | {res['perform_library']['median_ms']:.0f} ms "
        f"(p95 {res['perform_library']['p95_ms']:.0f}) |",
        f"| perform through the bus (simulator service) | {res['perform_bus']['median_ms']:.0f} ms (p95 {res['perform_bus']['p95_ms']:.0f}) |",
        f"| building the human body (MjSpec compile) | {res['build_human_body_ms']:.0f} ms |",
        f"| 100 learner imitations (squat, 5 repetitions each), library | {res['imitations_100_library_s']:.2f} s |",
        f"| 100 learner imitations through the bus (state saved after each) | {res['imitations_100_bus_s']:.2f} s |",
    ]
    write_results(args.out, "sim", res, md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
