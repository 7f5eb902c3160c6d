"""Something computed once for a key and kept: the self's regressors in the estimator, a body's
torques of a motion in the simulator."""

from __future__ import annotations

import sys
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # concurrent.futures costs a one-clip command 3 ms to import: imported at the first once()
    from concurrent.futures import Future


def nbytes(value) -> int:
    """About how many bytes ``value`` holds: an array's data, a tuple's or list's items summed,
    anything else its own size."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (tuple, list)):
        return sum(nbytes(v) for v in value)
    return sys.getsizeof(value)


class Once:
    """A value computed once per key: requests asking for the same key at once wait for one
    answer; a failed one is asked again next time; past ``limit`` keys or ``max_bytes`` of kept
    values the least recently asked are forgotten, and a value larger than ``largest`` (by default
    ``max_bytes / 16``) is answered but not kept (a few huge requests would otherwise hold the
    process's memory after them, and push out the many small values asked again and again)."""

    def __init__(self, limit: int = 4096, max_bytes: int = 256 << 20, largest: int | None = None,
                 size: Callable[[Any], int] | None = None):
        """``largest``: the largest value kept (default ``max_bytes / 16``); ``size``: a value's
        bytes (default :func:`nbytes`)."""
        self.largest = max_bytes // 16 if largest is None else largest
        self.size = size or nbytes
        self.table: OrderedDict[Any, Future] = OrderedDict()
        self.sizes: dict[Any, int] = {}  # kept values' bytes, by key (a value being computed: not yet)
        self.kept_bytes = 0
        self.lock = threading.Lock()
        self.limit = limit
        self.max_bytes = max_bytes

    def clear(self) -> None:
        with self.lock:
            self.table.clear()
            self.sizes.clear()
            self.kept_bytes = 0

    def _forget(self, key) -> None:
        self.table.pop(key, None)
        self.kept_bytes -= self.sizes.pop(key, 0)

    def once(self, key, compute, timeout: float | None = None):
        from concurrent.futures import Future

        with self.lock:
            kept = self.table.get(key)
            mine = kept is None
            fut: Future = Future() if kept is None else kept
            if mine:
                self.table[key] = fut
                while len(self.table) > self.limit:
                    self._forget(next(iter(self.table)))
            else:
                self.table.move_to_end(key)
        if mine:
            try:
                value = compute()
            except BaseException as e:
                with self.lock:
                    if self.table.get(key) is fut:
                        self._forget(key)
                fut.set_exception(e)
                raise
            fut.set_result(value)  # those waiting for it have it even if it is not kept
            size = self.size(value)
            with self.lock:
                if self.table.get(key) is fut:
                    if size > self.largest:
                        self._forget(key)
                    else:
                        self.sizes[key] = size
                        self.kept_bytes += size
                        while self.kept_bytes > self.max_bytes:
                            self._forget(next(iter(self.table)))
        return fut.result(timeout=timeout)
