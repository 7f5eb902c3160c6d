"""How a space's build grows with its number of clips, and what adding one clip costs.

Clips: the game studio's 174 BVH files (``../shared/data/bandai1``, CC BY-NC 4.0: see its
SOURCE.md), each also played 0.80-1.20x as fast (a time warp: a new clip of the same motion) until
there are N. For each N, in a fresh process: the library's build with recognition's decision
(calibration, discriminant ratio, novelty model) and the save, its wall time and the process's
peak memory (clips included), then two more clips added one by one without rebuilding the rest
through the store, as ``space add`` does (:meth:`ProtoSymbolSpace.added`, its decision fitted
again, a journal entry written beside the space's file), and the first by a rebuild. The
growth exponent is the slope of log time against log N.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import parse_args, write_results

SPEEDS = (1.0, 0.9, 1.1, 0.8, 1.2, 0.85, 1.15, 0.95, 1.05, 0.82, 1.18, 0.88, 1.12, 0.93, 1.07, 0.84, 1.16, 0.97)


class Warped:
    """N clips from the studio's files and their time warps, each made when it is taken (none
    kept beyond the 174 files): the space is built as ``offline build`` builds one from files,
    each clip read twice (:class:`shared.io.LazyClips`), not held."""

    def __init__(self, base: list, n: int):
        if n > len(base) * len(SPEEDS):
            raise SystemExit(f"at most {len(base) * len(SPEEDS)} clips from {len(base)} files and {len(SPEEDS)} speeds")
        self.base, self.n = base, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int):
        if not 0 <= i < self.n:
            raise IndexError(i)
        speed, c = SPEEDS[i // len(self.base)], self.base[i % len(self.base)]
        return c if speed == 1.0 else c.with_data(c.data, fps=c.fps * speed, name=f"{c.name}-x{speed:g}").resample(c.fps)


def clips_of(folder: Path, n: int) -> Warped:
    from shared.io import load_clip

    return Warped([load_clip(f) for f in sorted(folder.glob("*.bvh"))], n)


def one(folder: Path, n: int) -> dict:
    """Run in its own process: build N clips, add one, report."""
    from shared.pss.space import ProtoSymbolSpace
    from shared.pss.store import SpaceStore

    warped = clips_of(folder, n + 2)
    extra, second = warped[n + 1], warped[n]
    clips = Warped(warped.base, n)
    with tempfile.TemporaryDirectory() as tmp:
        store = SpaceStore(tmp)  # as the pss service keeps spaces
        t0 = time.perf_counter()
        space = ProtoSymbolSpace.build(clips)
        built = time.perf_counter()
        store.commit("s", space)  # recognition's decision is fitted here
        saved = time.perf_counter()
        peak_build = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        adds = []
        for clip in (extra, second):  # what `space add` does: placed, decision refitted, a journal entry
            t1 = time.perf_counter()
            before = store.get("s")
            store.append("s", before.added([clip]), len(before.symbols))
            adds.append(time.perf_counter() - t1)
        t2 = time.perf_counter()
        space.rebuilt(add=[extra]).save(Path(tmp) / "r.npz")
        rebuilt = time.perf_counter() - t2
    return {"clips": n, "frames": int(sum(sum(s.n_frames) for s in space.symbols)),  # at the space's rate
            "build_s": built - t0,
            "decision_and_save_s": saved - built, "total_s": saved - t0, "add_one_s": adds[0], "add_next_s": adds[1],
            "add_one_by_rebuild_s": rebuilt, "peak_mb": peak_build,
            "peak_with_adds_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main(argv=None) -> int:
    if argv is None and len(sys.argv) > 2 and sys.argv[1] == "--one":
        print(json.dumps(one(Path(sys.argv[2]), int(sys.argv[3]))))
        return 0
    args = parse_args(__doc__, argv, extra=lambda ap: ap.add_argument(
        "--sizes", default="250,500,1000,2000,3000", help="Numbers of clips, comma-separated."))
    folder = args.hdm05.parent / "bandai1" / "bvh"
    rows = []
    for n in (int(v) for v in args.sizes.split(",")):
        r = subprocess.run([sys.executable, "-m", "bench.scale", "--one", str(folder), str(n)], capture_output=True,
                           text=True, check=True)
        rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    ns = np.array([r["clips"] for r in rows], float)
    slope = float(np.polyfit(np.log(ns), np.log([r["total_s"] for r in rows]), 1)[0]) if len(rows) > 1 else float("nan")
    res = {"rows": rows, "exponent": slope}
    md = ["# A space's build against its number of clips (`python -m bench.scale`)", "",
          "The game studio's 174 files and their time warps (0.80-1.20x), each clip made when the build takes it "
          "(as `offline build` reads its files above `--hold-mb`: twice, never all held); each size in a fresh "
          "process; peak memory is the process's up to the saved space, the 174 files included (the adds after it "
          "hold two spaces at once). "
          "The adds go through the store as `space add` does (a journal entry beside the space's file); each "
          "extends the stacks the build kept (into their spare rows: the first add as the next).", "",
          "| clips | frames | build (HMMs, distances, MDS) | decision and save | total | peak memory | add one clip "
          "(placed, decision refitted, journal entry): first / next | add one clip by a rebuild |",
          "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r['clips']} | {r['frames']} | {r['build_s']:.1f} s | {r['decision_and_save_s']:.1f} s | "
                  f"{r['total_s']:.1f} s | {r['peak_mb']:.0f} MB | {r['add_one_s']:.2f} / {r['add_next_s']:.2f} s | "
                  f"{r['add_one_by_rebuild_s']:.1f} s |")
    md += ["", f"Time grows as N^{slope:.2f} over these sizes (slope of log total time against log N)."]
    write_results(args.out, "scale", res, md)
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
