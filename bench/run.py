"""``make bench``: speed of the PSS core on this machine (with its targets).

* one trial = 5 repetitions of a ~200-frame clip with all HDM05 angle channels: HMM training
  (target <= 50 ms), banded trainer and hmmlearn reference;
* recognition of a clip against a 200-clip space (<= 5 ms in the library), stage by
  stage, with BLAS limited to one thread as in the services;
* building a 200-clip space (target <= 30 s);
* how recognition and training grow with the number of clips, frames and channels.

The 200-clip space is the 188 HDM05 dev clips plus 12 of them time-stretched by 10 %.
Writes ``bench/results/pss.json`` and ``bench/results/pss.md``.
"""

from __future__ import annotations

import platform
import statistics
import time

import numpy as np

from bench.common import parse_args, write_results
from shared.io import find_clips, load_clip
from shared.pss.hmm import fit_hmm
from shared.pss.space import ProtoSymbolSpace


def _time(fn, repeat: int) -> dict:
    fn()  # warm-up (numba compile, caches)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * statistics.median(ts), "p95_ms": 1e3 * float(np.percentile(ts, 95)), "n": repeat}


def _stages(space, clips) -> dict:
    """Median ms per clip of each stage of ``space.recognize`` (same calls, timed one by one)."""
    from shared.pss.space import GEOMETRY_GROUPS

    p, f = space.params, space.features
    geo, pos = f.group_indices(GEOMETRY_GROUPS), f.group_indices(space.recognition_groups)
    t = {k: [] for k in ("resample", "encode", "HMM of the clip", "distances", "decision and eq. 2.6 placement", "total")}
    for c in clips[:3] + clips:  # the first three warm up
        t0 = time.perf_counter()
        r = c.resample(p.fps)
        t1 = time.perf_counter()
        x = f.encode(r)
        t2 = time.perf_counter()
        h = fit_hmm([x], p.n_states, var_floor=p.var_floor, n_iter=p.n_iter)
        t3 = time.perf_counter()
        d = space.bank_on(GEOMETRY_GROUPS).distances(h.marginal(geo))
        dr = space.recognition_bank().distances(h.marginal(pos))
        t4 = time.perf_counter()
        space._place(h, d, 5, dr)
        t5 = time.perf_counter()
        for k, a, b in (("resample", t0, t1), ("encode", t1, t2), ("HMM of the clip", t2, t3), ("distances", t3, t4),
                        ("decision and eq. 2.6 placement", t4, t5), ("total", t0, t5)):
            t[k].append(b - a)
    return {k: 1e3 * statistics.median(v[3:]) for k, v in t.items()}


def _stretch(clip, factor):
    c = clip.resample(clip.fps * factor)
    c.fps = clip.fps
    c.name = f"{clip.name}-x{factor:g}"
    return c


def _fit_decision(space) -> None:
    """What the pss service fits before it saves a new space: recognition's calibration, discriminant
    ratio and novelty model (:mod:`shared.pss.recognition`; otherwise fitted on first recognition)."""
    _ = space.calibration, space.discriminant, space.novelty_model  # properties that fit on first use


def main(argv=None) -> int:
    from threadpoolctl import threadpool_limits

    args = parse_args(__doc__, argv)
    threadpool_limits(1)  # as the services run (services/runner.py)
    clips = [load_clip(f) for f in find_clips([args.hdm05 / "amc"])]
    res: dict = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()}}

    # ---- one trial: 5 repetitions of a ~200-frame motion, all angle channels
    space1 = ProtoSymbolSpace.build(clips[:2], n_states=15)
    feats = space1.features
    kicks = sorted((c for c in clips if c.label == "kickLFront1Reps"), key=lambda c: abs(c.n_frames - 200))[:5]
    reps = [feats.encode(c, ("motion",)) for c in kicks]  # at 120 fps: ~200 frames each, the angle channels
    full = [feats.encode(c) for c in kicks]  # with the position group a space models for recognition
    trial = {"frames": [len(r) for r in reps], "features": reps[0].shape[1], "states": 15,
             "features_with_positions": full[0].shape[1]}
    for backend in ("banded", "hmmlearn"):
        trial[backend] = _time(lambda backend=backend: fit_hmm(reps, 15, backend=backend), 10 if backend == "banded" else 3)
    trial["banded_with_positions"] = _time(lambda: fit_hmm(full, 15), 10)
    res["trial_training"] = trial
    print(f"HMM training, one trial {trial['frames']} frames x {trial['features']} features: "
          f"banded {trial['banded']['median_ms']:.1f} ms, hmmlearn {trial['hmmlearn']['median_ms']:.1f} ms")

    # ---- 200-clip space: build and recognise
    extra = [_stretch(c, 1.1) for c in clips[::16][:12]]
    db = clips + extra
    t0 = time.perf_counter()
    space = ProtoSymbolSpace.build(db, dim=3)
    t1 = time.perf_counter()
    _fit_decision(space)
    decision_s = time.perf_counter() - t1
    build_s = time.perf_counter() - t0
    probe = next(c for c in clips if c.label == "squat1Reps" and "_dg_" in c.name)
    rec = _time(lambda: space.recognize(probe), 20)
    res["recognition_stages"] = _stages(space, [c for c in clips if "_dg_" in c.name])
    print("recognition stages (ms per clip, 61 dg clips): "
          + ", ".join(f"{k} {v:.2f}" for k, v in res["recognition_stages"].items()))
    res["space200"] = {"clips": len(db), "build_s": build_s, "decision_s": decision_s,
                       "stress1": space.embedding.stress1, "recognize": rec, "probe_frames_120fps": probe.n_frames}
    print(f"200-clip space: build {build_s:.1f} s (its decision {decision_s:.1f} s); "
          f"recognition {rec['median_ms']:.1f} ms median, {rec['p95_ms']:.1f} ms p95")

    # ---- growth
    growth = {"clips": [], "frames": [], "channels": []}
    for n in (25, 50, 100, 200):
        sub = db[:n]
        t0 = time.perf_counter()
        sp = ProtoSymbolSpace.build(sub, dim=3, n_states=space.params.n_states)
        _fit_decision(sp)
        b = time.perf_counter() - t0
        r = _time(lambda sp=sp: sp.recognize(probe), 10)
        growth["clips"].append({"n": n, "build_s": b, "recognize_ms": r["median_ms"]})
    base = feats.encode(kicks[0])
    for frames in (100, 200, 400, 800):
        x = np.vstack([base] * (frames // len(base) + 1))[:frames]
        growth["frames"].append({"n": frames, "train_ms": _time(lambda x=x: fit_hmm([x], 15), 5)["median_ms"]})
    for d in (20, 60, 119):
        x = base[:, :d]
        growth["channels"].append({"n": d, "train_ms": _time(lambda x=x: fit_hmm([x] * 5, 15), 5)["median_ms"]})
    res["growth"] = growth

    lines = [
        "# PSS core benchmark (`make bench`)", "",
        f"Python {res['machine']['python']}, 2-core machine. Medians of repeated runs after a warm-up.", "",
        "| what | measured | target |", "|---|---|---|",
        f"| HMM training, one trial (5 x {trial['frames'][0]}-ish frames x {trial['features']} features, 15 states), banded | "
        f"{trial['banded']['median_ms']:.1f} ms | <= 50 ms |",
        f"| same, hmmlearn reference | {trial['hmmlearn']['median_ms']:.1f} ms | - |",
        f"| same trial with the position group too ({trial['features_with_positions']} features, what a space now trains) | "
        f"{trial['banded_with_positions']['median_ms']:.1f} ms | - |",
        f"| recognition against a {len(db)}-clip space | {rec['median_ms']:.1f} ms (p95 {rec['p95_ms']:.1f}) | <= 5 ms |",
        *[f"| recognition stage: {k} (61 dg clips, {len(space.symbols) - 0}-clip space) | {v:.2f} ms | - |"
          for k, v in res["recognition_stages"].items()],
        f"| building a {len(db)}-clip space, with recognition's decision (of which the calibration, discriminant "
        f"ratio and novelty model) | {build_s:.1f} s (decision {decision_s:.1f} s) | <= 30 s |", "",
        "## Growth", "", "| clips | build with its decision (s) | recognition (ms) |", "|---|---|---|",
        *[f"| {g['n']} | {g['build_s']:.2f} | {g['recognize_ms']:.1f} |" for g in growth["clips"]], "",
        "| frames (one sequence, 119 features, 15 states) | training (ms) |", "|---|---|",
        *[f"| {g['n']} | {g['train_ms']:.1f} |" for g in growth["frames"]], "",
        "| features (5 repetitions, 15 states) | training (ms) |", "|---|---|",
        *[f"| {g['n']} | {g['train_ms']:.1f} |" for g in growth["channels"]], "",
    ]
    write_results(args.out, "pss", res, lines)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
