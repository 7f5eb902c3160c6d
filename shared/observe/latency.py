"""The cluster's request latencies as one table: requests, failures and percentiles per service
and verb (the dashboard's ``cluster/latency``). Free of rerun: the dashboard logs :meth:`markdown`."""

from __future__ import annotations

import time
from collections import deque

import numpy as np

KEPT = 500  # the newest requests per service and verb the percentiles are of
EVERY_S = 1.0  # the table is written again at most this often (and on close)


class LatencyTable:
    """Counts since the observer started (a new recording carries them on)."""

    def __init__(self) -> None:
        self.stats: dict[tuple[str, str], dict] = {}
        self.due, self.written_at = False, float("-inf")

    def add(self, service: str, verb: str, ms: float, failed: bool) -> None:
        st = self.stats.setdefault((service, verb), {"n": 0, "failed": 0, "ms": deque(maxlen=KEPT)})
        st["n"] += 1
        st["failed"] += int(failed)
        st["ms"].append(float(ms))
        self.due = True

    def ready(self) -> bool:
        """Requests came since the table was written, and ``EVERY_S`` has passed."""
        return self.due and time.monotonic() - self.written_at >= EVERY_S

    def markdown(self) -> str:
        """The table (marks it written)."""
        self.due, self.written_at = False, time.monotonic()
        rows = ["| service | verb | requests | failed | median ms | p95 ms | max ms |", "|---|---|--:|--:|--:|--:|--:|"]
        for (service, verb), st in sorted(self.stats.items()):
            ms = np.asarray(st["ms"])
            rows.append(f"| {service} | {verb} | {st['n']} | {st['failed']} | {np.median(ms):.1f} | "
                        f"{np.percentile(ms, 95):.1f} | {ms.max():.1f} |")
        return "\n".join(rows) + f"\n\nPercentiles of each verb's newest {KEPT} requests; requests and failures of all."
