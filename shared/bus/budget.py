"""A service's memory budget: requests are admitted by their estimated working memory.

Each process gets ``MIRRORCOACH_MEMORY_MB`` (default 1536, below the systemd unit's
``MemoryMax=2G`` and the compose file's 2 GB). What the process holds once it is ready (its
code, its caches) is its baseline; requests share the rest. A request's cost is estimated
before its work starts (a multiple of its payload, or the verb's own estimate declared with
``Service.cost``: frames x features for ``pss generate``; measured by ``python -m
bench.budget``); it runs when its cost fits beside the requests in progress, waits for memory
(bounded) when it does not fit now, and is refused up front when it can never fit.
After a large request is answered the C allocator is asked to return freed memory to the system
(``malloc_trim``), and services allocate from one arena with a fixed mmap threshold
(:func:`service_allocator`): freed blocks otherwise stay in the worker threads' arenas, and a
reply's buffers are freed only once it is sent (trimming before that left one reply's size held:
40-370 MB).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from shared.errors import BadInput, Unavailable

log = logging.getLogger("mirrorcoach.budget")
MB = 2**20
#: a request whose estimate is above this is followed by a trim of the allocator's free memory
TRIM_ABOVE = 16 * MB
_libc: Any = None  # glibc (ctypes.CDLL) once loaded; False: not glibc
M_ARENA_MAX = -8  # glibc's mallopt parameters
M_MMAP_THRESHOLD = -3
#: blocks of at least this many bytes are mapped on their own and unmapped when freed. glibc's own
#: threshold starts at 128 KB and rises to the largest block freed (up to 32 MB), after which such
#: blocks come from the heap, where a trim cannot return what smaller live blocks sit between:
#: the simulator answering four comparisons of two 900,000-frame motions at once grew 140 -> 168 ->
#: 182 -> 196 -> 223 -> 236 -> 236 -> 250 MB over 7 rounds of them (each round the same requests);
#: with this threshold 140 -> 143 -> 144 -> 144 -> 145 -> 146 MB over 5
MMAP_THRESHOLD = 1 << 20


def rss_bytes() -> int:
    """This process's resident memory (0 where /proc is missing)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _glibc():
    global _libc
    if _libc is None:
        try:
            _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            _libc.malloc_trim.argtypes = [ctypes.c_size_t]
            _libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        except (OSError, AttributeError):  # not glibc: its allocator manages itself
            _libc = False
    return _libc


def trim() -> None:
    """Return the allocator's free memory to the system (glibc's ``malloc_trim``; elsewhere nothing)."""
    if _glibc():
        _libc.malloc_trim(0)


def mallopt(param: int, value: int) -> bool:
    """Set glibc's malloc ``param`` (``M_ARENA_MAX``, ``M_MMAP_THRESHOLD``) to ``value``; False
    where the C library is not glibc or refuses."""
    return bool(_glibc()) and _libc.mallopt(param, value) == 1


def service_allocator() -> str:
    """A service's allocator, set before its worker threads start (glibc's ``mallopt``); what was
    done. Every thread allocates from one arena (``M_ARENA_MAX``): with an arena per worker
    thread, four large requests at once left 50-80 MB in arenas that a trim could not return;
    with one, memory went back to its level (the workers hold the GIL for most of their work, so
    they rarely wait for the allocator). Blocks of :data:`MMAP_THRESHOLD` or more are mapped on
    their own (``M_MMAP_THRESHOLD``), unless ``MALLOC_MMAP_THRESHOLD_`` in the environment says
    otherwise."""
    if not mallopt(M_ARENA_MAX, 1):
        return "allocator as the C library makes it (not glibc)"
    if os.environ.get("MALLOC_MMAP_THRESHOLD_"):
        return f"allocator: one arena, mmap threshold as MALLOC_MMAP_THRESHOLD_ says ({os.environ['MALLOC_MMAP_THRESHOLD_']})"
    mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)
    return f"allocator: one arena, blocks of {MMAP_THRESHOLD // 1024} KB or more mapped on their own"


class MemoryBudget:
    """``total_mb`` for the whole process; requests share what the baseline leaves."""

    def __init__(self, service: str, total_mb: float, wait_s: float = 60.0, held=lambda: 0):
        """``held()``: bytes the requests in flight hold outside their reservations (their payloads,
        as received and decoded, while they wait for memory)."""
        self.service = service
        self.held = held
        self.total = int(total_mb * MB)
        self.wait_s = wait_s
        self.baseline = 0
        self.reserved = 0
        self._cond = threading.Condition()
        self.measure_baseline()

    def measure_baseline(self) -> None:
        """What the process holds now (call once it is ready: modules loaded, caches warm)."""
        self.baseline = rss_bytes()

    @property
    def available(self) -> int:
        return max(0, self.total - self.baseline)

    @contextmanager
    def reserve(self, cost: float, what: str, own_held: int = 0):
        """Hold ``cost`` bytes of the budget while the block runs; wait (at most ``wait_s``) while
        others hold too much; refuse at once a cost that can never fit (``own_held``: what this
        request holds outside its reservation, its payload)."""
        cost = int(max(0.0, cost))
        if cost + own_held > self.available:
            raise BadInput(f"{what} needs about {cost / MB:.0f} MB of working memory; {self.service}'s budget leaves "
                           f"{self.available / MB:.0f} MB for requests (MIRRORCOACH_MEMORY_MB={self.total / MB:.0f}, "
                           f"{self.baseline / MB:.0f} MB held by the service itself): send less at once (a shorter "
                           f"clip, fewer clips or frames) or raise MIRRORCOACH_MEMORY_MB",
                           cause="too_large", needed_mb=round(cost / MB), available_mb=round(self.available / MB))
        deadline = time.monotonic() + self.wait_s
        with self._cond:
            if self.reserved + cost + self.held() > self.available:
                log.info("%s waits for memory: needs %.0f MB, %.0f MB held by requests in progress of %.0f MB", what,
                         cost / MB, (self.reserved + self.held()) / MB, self.available / MB)
            while self.reserved + cost + self.held() > self.available:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise Unavailable(f"{self.service} is busy: {self.reserved / MB:.0f} MB of its "
                                      f"{self.available / MB:.0f} MB are held by requests in progress and {what} needs "
                                      f"{cost / MB:.0f} MB; retry later", cause="memory", service=self.service)
                self._cond.wait(left)
            self.reserved += cost
        try:
            yield
        finally:
            with self._cond:
                self.reserved -= cost
                self._cond.notify_all()

    @staticmethod
    def give_back(cost: float) -> None:
        """After a large request is answered (its reply sent and freed, not only made): cycles
        holding arrays (a traceback's frames) collected, then the allocator's free memory returned."""
        if cost > TRIM_ABOVE:
            gc.collect()
            trim()
