"""The memory budget (``shared/bus/budget.py``) with real threads: a request that does not fit
beside the ones in progress waits for them and then runs; one that can never fit is refused at
once; one that waits past the budget's patience is told the service is busy."""

from __future__ import annotations

import threading

import pytest

from shared.bus.budget import MB, MemoryBudget
from shared.errors import BadInput, Unavailable


def budget(available_mb: float, **kw) -> MemoryBudget:
    b = MemoryBudget("svc", 1000, **kw)
    b.baseline = int((1000 - available_mb) * MB)
    return b


def test_a_request_waits_for_memory_held_by_another_and_then_runs():
    b = budget(100)
    order, holding, release = [], threading.Event(), threading.Event()

    def first():
        with b.reserve(70 * MB, "first"):
            order.append("first runs")
            holding.set()
            release.wait(10)
            order.append("first done")

    def second():
        holding.wait(10)
        with b.reserve(70 * MB, "second"):
            order.append("second runs")

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    holding.wait(10)
    threading.Timer(0.3, release.set).start()
    for t in threads:
        t.join(10)
    assert order == ["first runs", "first done", "second runs"], order
    assert b.reserved == 0


def test_two_requests_that_fit_together_run_together():
    b = budget(100)
    with b.reserve(40 * MB, "a"), b.reserve(40 * MB, "b"):
        assert b.reserved == 80 * MB


def test_a_request_that_can_never_fit_is_refused_at_once():
    b = budget(100)
    with pytest.raises(BadInput) as e, b.reserve(80 * MB, "pss/generate", own_held=30 * MB):
        pass
    assert e.value.details["cause"] == "too_large" and "needs about 80 MB" in e.value.message
    assert b.reserved == 0


def test_memory_held_by_payloads_in_flight_counts_and_a_long_wait_is_unavailable():
    held = {"bytes": 60 * MB}
    b = budget(100, wait_s=0.2, held=lambda: held["bytes"])
    with pytest.raises(Unavailable) as e, b.reserve(50 * MB, "pss/recognize"):
        pass
    assert e.value.details["cause"] == "memory" and "busy" in e.value.message
    held["bytes"] = 10 * MB
    with b.reserve(50 * MB, "pss/recognize"):
        assert b.reserved == 50 * MB


_FREED = """
import ctypes, sys
from shared.bus.budget import service_allocator
print(service_allocator(), file=sys.stderr)
import numpy as np

class MallInfo2(ctypes.Structure):  # glibc's mallinfo2: hblkhd, the bytes in blocks mapped on their own
    _fields_ = [(f, ctypes.c_size_t) for f in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                               "fsmblks", "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
np.ones(1 << 20)  # 8 MB made and freed: glibc's own threshold rises to its size
a = np.ones(1 << 20)  # the next one
print(libc.mallinfo2().hblkhd / 2**20)
"""


def test_a_services_large_blocks_go_back_to_the_system_when_freed():
    """A service maps blocks of ``MMAP_THRESHOLD`` or more on their own (``service_allocator``),
    so they go back to the system when freed: with glibc's rising threshold, once a large block
    had been freed the next ones came from the heap, where a block freed between small live ones
    stays resident (the simulator grew a round of large questions after another).
    ``MALLOC_MMAP_THRESHOLD_`` in the environment wins: set above the block, it comes from the heap."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}

    def mapped_mb(extra: dict) -> tuple[float, str]:
        r = subprocess.run([sys.executable, "-c", _FREED], capture_output=True, text=True, cwd=repo,
                           env={**env, **extra}, timeout=120)
        assert r.returncode == 0, r.stderr
        return float(r.stdout.split()[-1]), r.stderr.strip()

    mapped, said = mapped_mb({})
    assert mapped >= 8.0 and said == "allocator: one arena, blocks of 1024 KB or more mapped on their own", (mapped, said)
    mapped, said = mapped_mb({"MALLOC_MMAP_THRESHOLD_": str(64 << 20)})
    assert mapped < 1.0 and "as MALLOC_MMAP_THRESHOLD_ says (67108864)" in said, (mapped, said)
