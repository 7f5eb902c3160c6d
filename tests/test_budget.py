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
