"""Something computed once for a key and kept: the self's regressors in the estimator, a body's
torques of a motion in the simulator."""

from __future__ import annotations

import threading
from collections import OrderedDict
from concurrent.futures import Future
from typing import Any


class Once:
    """A value computed once per key: requests asking for the same key at once wait for one
    answer; a failed one is asked again next time; past ``limit`` keys the least recently asked
    are forgotten."""

    def __init__(self, limit: int = 4096):
        self.table: OrderedDict[Any, Future] = OrderedDict()
        self.lock = threading.Lock()
        self.limit = limit

    def once(self, key, compute, timeout: float | None = None):
        with self.lock:
            kept = self.table.get(key)
            mine = kept is None
            fut: Future = Future() if kept is None else kept
            if mine:
                self.table[key] = fut
                while len(self.table) > self.limit:
                    self.table.popitem(last=False)
            else:
                self.table.move_to_end(key)
        if mine:
            try:
                fut.set_result(compute())
            except BaseException as e:
                with self.lock:
                    self.table.pop(key, None)
                fut.set_exception(e)
                raise
        return fut.result(timeout=timeout)
