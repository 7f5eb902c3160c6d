"""The simulated test on real takes (``python -m bench.tracking``; ``shared/bodies/tracking.py``).

Every HDM05 take (actors bd, bk, dg; 30 fps) followed by the tracking controller on a simulated
floor: the share of its frames that needed a helping hand of more than ``HELP`` of the weight,
and, with the hand limited to ``HANDS`` of the weight in turn, whether the body fell before the end. The same for the
game studio's 'normal' clips and the CMU performance (other studios' skeletons). Also the time
one clip takes. Nothing here is chosen: the balance tolerance comes from ``bench.balance``.
Writes ``bench/results/tracking.*``.
"""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from bench.common import parse_args, write_results

HANDS = (0.1, 0.3, 1.0)  # the helping hand limited to these shares of the weight: does the body fall?


def _one(path: Path) -> dict:
    from shared.bodies.body import qpos_trajectory
    from shared.bodies.human import human_body
    from shared.bodies.tracking import track, tracking_model
    from shared.io import load_clip

    clip = load_clip(path)
    clip = clip.resample(30.0) if clip.fps > 31 else clip
    body = human_body(clip.skeleton)
    model = tracking_model(body)
    q = qpos_trajectory(body, clip)
    t0 = time.perf_counter()
    free = track(body, q, clip.fps, model)
    seconds = time.perf_counter() - t0
    fell = {str(h): track(body, q, clip.fps, model, hand=h)["fell"] for h in HANDS}
    return {"file": path.name, "frames": clip.n_frames, "helped": free["frames_helped"] / clip.n_frames,
            "mean_help": free["mean_help"], "fell": fell, "ms": 1000 * seconds}


def main(argv=None) -> int:
    args = parse_args(__doc__, argv, extra=lambda ap: (
        ap.add_argument("--bandai", type=Path, default=Path("../shared/data/bandai1")),
        ap.add_argument("--cmu", type=Path, default=Path("../shared/data/cmu"))))
    from shared.bodies.tracking import HELP

    groups: dict[str, list] = defaultdict(list)
    for f in sorted((args.hdm05 / "amc").glob("*/*.amc")):
        groups[f"HDM05 {f.parent.name}"].append(_one(f))
        print(groups[f"HDM05 {f.parent.name}"][-1], flush=True)
    for f in sorted((args.bandai / "bvh").glob("dataset-1_*_normal_001.bvh")):
        groups["bandai1 'normal' (every content)"].append(_one(f))
    if (args.cmu / "131_01.bvh").exists():
        groups["CMU 131_01"].append(_one(args.cmu / "131_01.bvh"))
    rows = []
    for name, takes in groups.items():
        rows.append({"group": name, "takes": len(takes), "median_helped": float(np.median([t["helped"] for t in takes])),
                     "max_helped": float(max(t["helped"] for t in takes)),
                     "median_mean_help": float(np.median([t["mean_help"] for t in takes])),
                     "fell": {str(h): sum(t["fell"][str(h)] is not None for t in takes) for h in HANDS},
                     "ms": float(np.median([t["ms"] for t in takes]))})
    hdm = [t for k, v in groups.items() if k.startswith("HDM05") for t in v]
    res = {"help_limit": HELP, "rows": rows, "takes": {k: v for k, v in groups.items()},
           "hdm05_fell": {str(h): sum(t["fell"][str(h)] is not None for t in hdm) for h in HANDS}, "hdm05_takes": len(hdm),
           "ms_median": float(np.median([t["ms"] for t in hdm]))}
    md = ["# The simulated test on real takes (`python -m bench.tracking`)", "",
          __doc__.split("\n\n")[1].replace("\n", " "), "",
          f"| takes | n | frames needing a hand > {HELP:.0%} of the weight: median (worst) | mean help (median) | "
          f"fell with the hand limited to {' / '.join(f'{h:.0%}' for h in HANDS)} of the weight | ms a clip (median) |",
          "|---|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r['group']} | {r['takes']} | {r['median_helped']:.0%} ({r['max_helped']:.0%}) | "
                  f"{r['median_mean_help']:.0%} | {' / '.join(str(r['fell'][str(h)]) for h in HANDS)} of {r['takes']} | "
                  f"{r['ms']:.0f} |")
    md += ["", f"With the hand limited to {' / '.join(f'{h:.0%}' for h in HANDS)} of the weight, "
               f"{' / '.join(str(res['hdm05_fell'][str(h)]) for h in HANDS)} of {res['hdm05_takes']} real HDM05 "
               "takes fall: this controller cannot keep a person's balance through every take, so the coach's check "
               "compares the help a demonstration needs with the help its target needs (frames needing a hand where "
               "the target's do not, against the tolerance of `bench.balance`), never falling against not falling."]
    write_results(args.out, "tracking", res, md)
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
