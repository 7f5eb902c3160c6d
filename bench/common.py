"""Helpers of the benchmarks: timing statistics and a private local cluster."""

from __future__ import annotations

import os
import signal
import socket
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np


def stats(ts: list[float]) -> dict:
    """Median and 95th percentile in milliseconds of durations in seconds."""
    a = 1e3 * np.asarray(ts)
    return {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "n": len(a)}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def private_cluster(prefix: str):
    """``mirrorcoach up`` on a free loopback port with a temporary home; yields the Settings."""
    home = Path(tempfile.mkdtemp(prefix=f"mc-bench-{prefix}-"))
    os.environ.update({"MIRRORCOACH_ROUTER": f"tcp/127.0.0.1:{_free_port()}", "MIRRORCOACH_HOME": str(home),
                       "MIRRORCOACH_PREFIX": prefix})
    from shared.bus.cluster import down, up
    from shared.bus.config import Settings

    s = Settings()
    previous = signal.signal(signal.SIGTERM, _stop)  # a benchmark stopped with kill stops its cluster too
    try:
        if up(s) != 0:
            raise SystemExit(f"the benchmark cluster did not start; see {s.log_dir}")
        yield s
    finally:
        down(s)
        signal.signal(signal.SIGTERM, previous)


def _stop(*_) -> None:
    raise SystemExit("stopped (SIGTERM)")


def parse_args(doc: str, argv=None, extra=None):
    """``--hdm05`` (required) and ``--out`` (default ``bench/results``, created)."""
    import argparse

    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hdm05", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    if extra is not None:
        extra(ap)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    return args


def write_results(out: Path, name: str, res: dict, markdown: list[str]) -> None:
    """``<name>.json`` and ``<name>.md`` in ``out``."""
    import json

    (out / f"{name}.json").write_text(json.dumps(res, indent=2))
    (out / f"{name}.md").write_text("\n".join(markdown) + "\n")
    print(f"wrote {out / f'{name}.md'}")


def concurrent(call, n: int = 20, rounds: int = 3) -> dict:
    """``call(i)`` for i in 0..n-1 at once, ``rounds`` times: latency statistics of every call
    and the throughput (calls per second of wall time)."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    lat, lock = [], threading.Lock()

    def one(i):
        t0 = time.perf_counter()
        call(i)
        with lock:
            lat.append(time.perf_counter() - t0)

    walls = []
    with ThreadPoolExecutor(n) as pool:
        for _ in range(rounds):
            t0 = time.perf_counter()
            list(pool.map(one, range(n)))
            walls.append(time.perf_counter() - t0)
    return {**stats(lat), "throughput_per_s": n * rounds / sum(walls)}
