"""Time limits of requests: every verb declares one in its contract
(``Endpoint.time_limit_s``); the service runtime opens :func:`time_limit` around the handler and
the library's long loops call :func:`check_time` at safe points (before an HMM is trained, between
a session's trials, between conversation sets). Past the limit the request stops there with
:class:`TimeLimit` (``unavailable``, cause ``time_limit``) before it writes anything of the step
it was on: a write verb that stops keeps only what it had completed and saved.

Kept free of the bus: the limit is a context variable, so library code runs unlimited outside a
service and each worker thread has its own.
"""

from __future__ import annotations

import contextvars
import time
from contextlib import contextmanager

from shared.errors import Unavailable

_deadline: contextvars.ContextVar[tuple[float, float, str] | None] = contextvars.ContextVar("deadline", default=None)
_kept: contextvars.ContextVar[str] = contextvars.ContextVar("kept", default="")


class TimeLimit(Unavailable):
    """A request ran past its time limit and stopped at a safe point."""


@contextmanager
def time_limit(seconds: float | None, what: str):
    """Run the block under a limit of ``seconds`` (``None``: none) for the request ``what``."""
    token = _deadline.set(None if seconds is None else (time.monotonic() + seconds, seconds, what))
    kept = _kept.set("")
    try:
        yield
    finally:
        _kept.reset(kept)
        _deadline.reset(token)


def completed(done: str) -> None:
    """Say what the current request has completed and kept so far (an incremental verb, between
    its steps): a stop anywhere later reports it instead of "nothing was changed"."""
    _kept.set(done)


def check_time() -> None:
    """Raise :class:`TimeLimit` when the current request is past its limit, saying what
    :func:`completed` last said was kept."""
    d = _deadline.get()
    if d is not None and time.monotonic() > d[0]:
        done = _kept.get()
        kept = f"; {done}" if done else "; nothing was changed"
        raise TimeLimit(f"{d[2]} passed its time limit of {d[1]:g} s and stopped{kept}", cause="time_limit",
                        limit_s=d[1])
