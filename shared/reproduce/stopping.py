"""A reproduction stopped promptly: Ctrl-C (or any error) ends the whole run within about one
request, instead of after every conversation already queued.

``reproduce`` runs its simulated others on thread pools (``ThreadPoolExecutor``), and leaving a
pool's ``with`` block waits for every task submitted to it, started or not: Ctrl-C in
``reproduce ch3`` used to return 86 s later, the population's first section quietly run to its
end (measured on this 2-core VM). :func:`worker_pool` cancels the tasks not started when its
block is left by an exception, and the :class:`StoppingClient` the tasks talk through refuses
every request after that, so the tasks in flight end at their next request (each request is
bounded by its own timeout)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

from shared.errors import MirrorcoachError


class RunStopped(MirrorcoachError):
    """A request of a run that is stopping (raised in its worker threads only)."""


class StoppingClient:
    """A bus client (:class:`shared.bus.client.Client`) whose requests fail with
    :class:`RunStopped` once :meth:`stop` was called; everything else is the client's."""

    def __init__(self, client) -> None:
        self._client = client
        self._stopped = threading.Event()

    def request(self, *args, **kwargs):
        if self._stopped.is_set():
            raise RunStopped("the run is stopping")
        return self._client.request(*args, **kwargs)

    def stop(self) -> None:
        self._stopped.set()

    def __getattr__(self, name: str):
        return getattr(self._client, name)


def stopping(client) -> StoppingClient:
    """``client`` as a :class:`StoppingClient` (itself when it is one: nested runs stop together)."""
    return client if isinstance(client, StoppingClient) else StoppingClient(client)


@contextmanager
def worker_pool(client: StoppingClient, workers: int) -> Iterator[ThreadPoolExecutor]:
    """A thread pool of ``workers`` whose block, left by an exception (KeyboardInterrupt
    included), stops ``client`` and cancels the tasks not started before it waits for the
    ones in flight (they end at their next request)."""
    pool = ThreadPoolExecutor(workers)
    try:
        yield pool
    except BaseException:
        client.stop()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
