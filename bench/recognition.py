"""``make bench``: the recognition report with its peers, MiniRocket and DTW, in one
run. Writes ``reports/recognition/`` (report and results) and ``bench/results/recognition.*``.
"""

from __future__ import annotations

from pathlib import Path

from bench.common import parse_args, write_results
from shared.io import find_clips, load_clip
from shared.reports.evaluation import evaluate
from shared.reports.evaluation_report import report_markdown, write_report


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    clips = [load_clip(f) for f in find_clips([args.hdm05 / "amc"])]
    res = evaluate(clips)
    write_report(res, Path("reports/recognition"))
    lines = report_markdown(res).splitlines()
    # the per-clip novelty scores stay in reports/recognition/results.json only
    open_counts = {w: {"rows": [{k: v for k, v in row.items() if k not in ("scores", "novel")} for row in s["rows"]]}
                   for w, s in res.get("open_set", {}).items()}
    write_results(args.out, "recognition", {k: v for k, v in res.items() if k != "splits"} | {"open_set": open_counts} | {
        "accuracy": {w: {m: r["accuracy"] for m, r in s["methods"].items()} for w, s in res["splits"].items()},
        "ms_per_clip": {w: {m: 1e3 * r["seconds_per_clip"] for m, r in s["methods"].items()} for w, s in res["splits"].items()},
    }, lines)
    print("\n".join(lines[:20]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
