"""Repetitions found in joined takes (shared/capture/segment.py), against their true boundaries.

    python -m bench.segmentation --hdm05 ../shared/data/hdm05 --bandai ../shared/data/bandai1 --out bench/results

Takes are real clips of one performer joined with rests (:func:`shared.capture.takes.join`).

* **Chosen on** (tuning): HDM05 performer bd's takes, targets of performer bk, other motions
  (the cohort) of performer dg. The cohort ratio is chosen there: the largest F1 among the
  values that cut no take of another motion into repetitions (the fewest cuts if none does).
* **Reported on**: performer dg's takes, targets of bk, cohort of bd (cross-performer); dg's
  takes with dg's own first clip as the target (the same performer); and the game studio's
  dataset (bandai1: five styles of one content joined, the target its 'normal' style, the
  cohort the other contents' 'normal' clips).

Scored: F1 of repetitions (a match overlaps its true repetition by half its union), the median
error of matched boundaries, and how many repetitions were cut from takes of other motions.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from shared.capture import segment as seg
from shared.capture.takes import join, score
from shared.io import load_clip

COHORTS = (0.7, 0.77, 0.84, 0.9, 1.0)


def _hdm05(root: Path, performer: str, cls: str) -> list[Path]:
    return sorted((root / "amc" / cls).glob(f"HDM_{performer}_*.amc"))


def run_set(takes: dict, targets: dict, cohort_of: dict, cohort: float) -> dict:
    """Every target against every take: F1 and boundary errors on its own class, cuts on others."""
    rows, cuts, errors, seconds = {}, 0, [], []
    for ct, target in targets.items():
        for ck, (take, truth) in takes.items():
            t = time.perf_counter()
            s = seg.segment(take, target, background=cohort_of[ct], cohort=cohort)
            seconds.append(time.perf_counter() - t)
            found = [(r.start, r.end) for r in s.repetitions]
            if ck == ct:
                sc = score(found, truth)
                rows[ct] = {"f1": sc["f1"], "found": sc["found"], "true": sc["true"], "verdict": s.verdict}
                errors += sc["boundary_errors"]
            else:
                cuts += len(found)
    f1 = float(np.mean([r["f1"] for r in rows.values()])) if rows else 0.0
    return {"f1": f1, "median_boundary_error_ms": float(np.median(errors) * 1000) if errors else None,
            "other_motion_cuts": cuts, "classes": rows, "seconds_per_take": float(np.median(seconds))}


def hdm05_set(root: Path, take_perf: str, target_perf: str, cohort_perf: str, own: bool = False):
    classes = sorted(p.name for p in (root / "amc").iterdir() if p.is_dir())
    takes, targets, cohort_of = {}, {}, {}
    for c in classes:
        files = _hdm05(root, take_perf, c)
        tfiles = _hdm05(root, target_perf, c)
        if len(files) < 2 or not tfiles:
            continue
        reps = files[1:6] if own else files[:5]
        takes[c] = join([load_clip(f) for f in reps], seed=len(c))
        targets[c] = load_clip(tfiles[0])
    for c in targets:
        cohort_of[c] = [load_clip(_hdm05(root, cohort_perf, o)[min(1, len(_hdm05(root, cohort_perf, o)) - 1)])
                        for o in targets if o != c and _hdm05(root, cohort_perf, o)]
    return takes, targets, cohort_of


def bandai_set(root: Path):
    bvh = root / "bvh"
    contents = ["bow", "bye", "byebye", "dash", "guide", "run", "walk-back", "walk-left", "walk-right"]
    takes, targets, cohort_of = {}, {}, {}
    for c in contents:
        files = sorted(f for f in bvh.glob(f"dataset-1_{c}_*_001.bvh") if "_normal_" not in f.name)
        normal = bvh / f"dataset-1_{c}_normal_001.bvh"
        if len(files) < 5 or not normal.exists():
            continue
        takes[c] = join([load_clip(f) for f in files[:5]], seed=len(c))
        targets[c] = load_clip(normal)
    for c in targets:
        cohort_of[c] = [targets[o] for o in targets if o != c]
    return takes, targets, cohort_of


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hdm05", type=Path, default=Path("../shared/data/hdm05"))
    ap.add_argument("--bandai", type=Path, default=Path("../shared/data/bandai1"))
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    tuning = hdm05_set(args.hdm05, "bd", "bk", "dg")
    sweep = {c: run_set(*tuning, cohort=c) for c in COHORTS}
    clean = [c for c in COHORTS if sweep[c]["other_motion_cuts"] == 0]
    chosen = max(clean, key=lambda c: sweep[c]["f1"]) if clean else min(COHORTS, key=lambda c: sweep[c]["other_motion_cuts"])
    print(f"tuning (bd takes, bk targets): " + ", ".join(f"cohort {c}: F1 {v['f1']:.2f}, cuts {v['other_motion_cuts']}"
                                                          for c, v in sweep.items()) + f"; chosen {chosen}", flush=True)
    report = {"cross-performer (dg takes, bk targets)": run_set(*hdm05_set(args.hdm05, "dg", "bk", "bd"), cohort=chosen),
              "same performer (dg takes, dg's own first clip)": run_set(*hdm05_set(args.hdm05, "dg", "dg", "bd", own=True),
                                                                       cohort=chosen)}
    if (args.bandai / "bvh").exists():
        report["bandai1 (five styles joined, target 'normal')"] = run_set(*bandai_set(args.bandai), cohort=chosen)
    for k, v in report.items():
        print(f"{k}: F1 {v['f1']:.2f}, median boundary error {v['median_boundary_error_ms']} ms, "
              f"other-motion cuts {v['other_motion_cuts']}, {v['seconds_per_take']:.2f} s a take", flush=True)
    out = {"chosen_cohort": chosen, "tuning": sweep, "report": report, "seconds": time.perf_counter() - t0}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "segmentation.json").write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
