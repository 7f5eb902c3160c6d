"""How far real people are from one another by the balance tests (``python -m bench.balance``).

The coach calls an emphatic motion less balanced than its target when more of its frames are
off balance (by the static, the centre-of-pressure or the simulated tracking test) where the target is not (``shared.coaching.feasibility.off_balance_share``) than a
tolerance. This chooses that tolerance on performances we know were feasible: real takes of
one motion by one person (HDM05 actors bd and bk, every class, up to 4 takes each, resampled to
the coach's 30 fps), each judged against each other take as if it were the target, frames
matched by dynamic time warping (aeon's DTW on root-relative joint positions). The tolerance per
test is the 95th percentile of those shares: a real take passes against another real take in
95 % of pairs. Actor dg is left out: the emphasis benchmark (``bench.emphasis``) reports on dg's
targets. Writes ``bench/results/balance.*``.
"""

from __future__ import annotations

import itertools
from collections import defaultdict

import numpy as np

from bench.common import parse_args, write_results

ACTORS = ("bd", "bk")
TAKES = 4
KINDS = {"outside_runs": "centre of gravity (static)", "dynamic_runs": "centre of pressure (dynamic)",
         "tracking_runs": "a helping hand in a simulation (tracking controller)"}


def _features(clip) -> np.ndarray:
    pos = clip.positions()
    rel = (pos - pos[:, :1]).reshape(len(pos), -1)
    return ((rel - rel.mean(axis=0)) / (rel.std(axis=0) + 1e-6)).T  # (channels, time) for aeon


def _match(path, n: int) -> np.ndarray:
    """The target's frame for each of the motion's ``n`` frames (the first on the warping path)."""
    out = np.full(n, -1)
    for i_t, i_m in path:
        if out[i_m] < 0:
            out[i_m] = i_t
    return out


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    from aeon.distances import dtw_alignment_path

    from shared.bodies.human import human_body
    from shared.bodies.tracking import perform_tracked
    from shared.coaching.feasibility import off_balance_share
    from shared.io import load_clip

    groups = defaultdict(list)
    for f in sorted((args.hdm05 / "amc").glob("*/*.amc")):
        actor = f.name.split("_")[1]
        if actor in ACTORS and len(groups[(actor, f.parent.name)]) < TAKES:
            groups[(actor, f.parent.name)].append(f)
    shares = {k: defaultdict(list) for k in KINDS}
    bodies = {}
    for (actor, label), files in sorted(groups.items()):
        takes = []
        for f in files:
            clip = load_clip(f).resample(30.0)
            body = bodies.setdefault(clip.skeleton.to_json(), human_body(clip.skeleton))
            takes.append((clip, perform_tracked(body, clip)[1], _features(clip)))
        for (_, t_rep, t_x), (m_clip, m_rep, m_x) in itertools.permutations(takes, 2):
            path, _ = dtw_alignment_path(t_x, m_x)
            match = _match(path, m_clip.n_frames)
            for kind in KINDS:
                shares[kind][label].append(off_balance_share(m_rep, t_rep, kind, match))
        print(f"{actor} {label}: {len(takes)} takes")
    res = {"actors": list(ACTORS), "pairs": sum(len(v) for v in shares["outside_runs"].values()), "tests": {}}
    md = ["# Balance tests on real takes against one another (`python -m bench.balance`)", "",
          __doc__.split("\n\n")[1].replace("\n", " "), "",
          "| test | pairs | median share | 90th percentile | 95th percentile (the tolerance) | worst class (95th) |",
          "|---|---|---|---|---|---|"]
    for kind, what in KINDS.items():
        allv = np.concatenate([np.asarray(v) for v in shares[kind].values()])
        per_class = {c: float(np.percentile(v, 95)) for c, v in shares[kind].items()}
        worst = max(per_class, key=per_class.get)
        res["tests"][kind] = {"median": float(np.median(allv)), "p90": float(np.percentile(allv, 90)),
                              "tolerance": float(np.percentile(allv, 95)), "per_class_p95": per_class}
        md.append(f"| {what} | {len(allv)} | {np.median(allv):.3f} | {np.percentile(allv, 90):.3f} | "
                  f"**{np.percentile(allv, 95):.3f}** | {worst} {per_class[worst]:.3f} |")
    write_results(args.out, "balance", res, md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
