"""Coaching trials as one tidy table: one row per trial, the same columns for
simulated runs (``reproduce ch4 ch5 ch6`` writes ``tidy.csv``) and for studies with people
(``mirrorcoach study export``), so the report's statistics read both the same way
(:func:`matrix`, :func:`shared.reproduce.coaching_report.case_tables`).

Columns: ``world`` (``simulated`` or ``people``), ``family`` (the learner family; empty for
people), ``target``, ``condition`` (``case 1`` ... ``case 8``, or another group), ``unit`` (a
learner or participant), ``trial`` (1-based), ``d_p`` (eq. 4.4), ``alpha`` (shown), ``adverb``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from shared.errors import BadInput

COLUMNS = ("world", "family", "target", "condition", "unit", "trial", "d_p", "alpha", "adverb")


def write(rows: list[dict], path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if r.get(k) is None else r.get(k) for k in COLUMNS})
    return path


def read(path: Path) -> list[dict]:
    """The rows of a tidy CSV; a file with other columns or a bad number is refused by name."""
    path = Path(path)
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise BadInput(f"{path}: not a coaching table (missing columns {', '.join(missing)})")
            rows = []
            for n, r in enumerate(reader, start=2):
                try:
                    rows.append({**r, "trial": int(r["trial"]), "d_p": float(r["d_p"]),
                                 "alpha": float(r["alpha"]) if r["alpha"] else None, "adverb": r["adverb"] or None})
                except ValueError:
                    raise BadInput(f"{path}, line {n}: trial, d_p and alpha must be numbers") from None
    except OSError as e:
        raise BadInput(f"{path}: cannot read ({e.strerror or e})") from None
    return rows


def matrix(rows: list[dict], condition: str, **where) -> np.ndarray:
    """``d_il`` of one condition: units x trials, units in order of appearance; only units with
    every trial of the condition's longest unit (a participant who stopped early is left out)."""
    by: dict[str, dict[int, float]] = {}
    for r in rows:
        if r["condition"] == condition and all(r.get(k) == v for k, v in where.items()):
            by.setdefault(r["unit"], {})[r["trial"]] = r["d_p"]
    if not by:
        return np.zeros((0, 0))
    n = max(len(v) for v in by.values())
    full = [v for v in by.values() if sorted(v) == list(range(1, n + 1))]
    return np.array([[v[t] for t in range(1, n + 1)] for v in full])


def conditions(rows: list[dict], **where) -> list[str]:
    seen: dict[str, None] = {}
    for r in rows:
        if all(r.get(k) == v for k, v in where.items()):
            seen.setdefault(r["condition"], None)
    return list(seen)
