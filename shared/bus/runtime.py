"""The service runtime every mirrorcoach process uses.

A :class:`Service` answers the verbs of its contract (``schemas/<service>.py``) on
``<prefix>/<service>/<verb>``:

1. the Zenoh callback only hands the query to a worker pool (callbacks run one at a time,
   DESIGN.md), so a long request never blocks the others;
2. the worker checks the payload size, decodes msgpack (``shared.bus.codec``), validates the
   request against the contract, calls the handler, validates the reply, and replies on the
   query's concrete key;
3. any :class:`~shared.errors.MirrorcoachError` becomes ``reply_err`` with its stable code;
   a request arriving when ``workers + MIRRORCOACH_QUEUE`` requests are in progress or waiting,
   or when the waiting ones hold ``MIRRORCOACH_QUEUE_MB``, gets ``unavailable`` (cause
   ``saturated``) at once instead of queueing without bound; verbs that may
   wait for a person (``Endpoint.waits``) run on a pool of their own (``MIRRORCOACH_WAITING``),
   so questions nobody has answered yet never hold the workers; a full disk
   (``ENOSPC``) becomes ``unavailable`` (cause ``disk_full``); anything else becomes
   ``internal`` (logged with its traceback, never shown to the caller);
4. the query is always finalised (``with query``), so a caller never waits for a timeout.

Deployed across hosts (``MIRRORCOACH_DEPLOY``), several instances of a service may run
on different hosts: exactly one **leads** (declares the queryable and the tokens
``<prefix>/alive/<service>`` and ``<prefix>/leader/<service>/<identity>``), the others stand by
and take over when no leader token is left, which the router drops when the leader's process
dies or its link is silent for the lease (3 s). A leader that loses its router steps down at
once; of two leaders (a healed partition) the one with the smaller name stays. Leadership is
sticky: an instance that comes back stands by. State lives on storage both hosts mount
(``MIRRORCOACH_HOME``): a write is an atomic rename completed before the reply, so whatever a
caller was told is done is on the shared disk when the standby takes over; ``on_promote`` hooks
drop what an instance kept in memory from an earlier term.

The service declares the liveliness token ``<prefix>/alive/<service>``, publishes events on
``<prefix>/events/<service>/<topic>`` (congestion control BLOCK: events are not dropped) and, for
the observer, a ``requests`` event with the answered requests' (verb, milliseconds, code), at most
every :data:`REQUESTS_EVERY_S`. SIGTERM or
SIGINT stops it cleanly: the queryable is undeclared, in-flight requests finish (bounded
wait), ``on_stop`` hooks flush state, and the session is closed.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from schemas.base import Endpoint, Message
from shared.bus.budget import MB, TRIM_ABOVE, MemoryBudget
from shared.bus.codec import pack, unpack
from shared.bus.config import Settings, client_config
from shared.deadline import time_limit
from shared.errors import BadInput, Conflict, MirrorcoachError, NotFound
from shared.io.atomic import DISK_FULL

log = logging.getLogger("mirrorcoach.service")


def error_payload(code: str, message: str, details: dict | None = None) -> bytes:
    safe = {}
    for k, v in (details or {}).items():
        safe[str(k)] = v if isinstance(v, (str, int, float, bool, type(None))) else str(v)
    return pack({"code": code, "message": message, "details": safe})


#: a request's working memory when its service has no estimate of its own: this many times its
#: payload (measured by bench.budget: a recognition peaked at 6x its clip in the library, 3x since
#: its HMM is fitted on blocks of frames; kept with room for the reply and first-use caches)
PAYLOAD_FACTOR = 7
#: every request in flight also holds its payload twice (as received and decoded) outside its
#: reservation, also while it waits for memory
PAYLOAD_HELD = 2
#: a request this slow (or failed) gets a line in its service's log; the others only at DEBUG
SLOW_MS = 1000.0
#: requests go to the observer (its latency table) as one ``requests`` event per service at most
#: every REQUESTS_EVERY_S, or at once when REQUESTS_BATCH are waiting: an event per request was
#: 60 % of the cluster's events in `reproduce ch3` (router, observer and the services' CPU)
REQUESTS_EVERY_S = 0.5
REQUESTS_BATCH = 500


class Service:
    """A named service answering the endpoints of its contract.

    Parameters
    ----------
    name : str
        The service's name (``pss``, ``simulator``, ...): its key segment and liveliness token.
    endpoints : dict verb -> :class:`schemas.base.Endpoint`
    events : dict topic -> :class:`schemas.base.Message`, optional
    workers : int, optional
        Size of the worker pool (concurrent requests); default ``MIRRORCOACH_WORKERS`` (4).
    """

    def __init__(self, name: str, endpoints: dict[str, Endpoint], events: dict[str, Message] | None = None,
                 settings: Settings | None = None, workers: int | None = None, stop_grace_s: float = 30.0):
        self.name = name
        self.endpoints = endpoints
        self.events = events or {}
        self.settings = settings or Settings()
        self.handlers: dict[str, Callable[[dict], dict]] = {}
        self.costs: dict[str, Callable[[dict], float]] = {}
        self.on_stop: list[Callable[[], None]] = []
        self.on_promote: list[Callable[[], None]] = []  # deployed: before this instance starts to lead
        self.leading = False
        self._leader_token: Any = None
        ident = self.settings.identity
        if ident is not None and ident.role != name:
            raise BadInput(f"MIRRORCOACH_DEPLOY={self.settings.deploy} is the identity of {ident.name!r}, a "
                           f"{ident.role}; service {name} needs one of its own (`mirrorcoach deploy init`)")
        self.workers = workers or self.settings.workers
        self.stop_grace_s = stop_grace_s
        self._stop = threading.Event()
        self._pool: ThreadPoolExecutor | None = None
        self._wait_pool: ThreadPoolExecutor | None = None
        self._session: Any = None  # zenoh's Session, queryable, token and publishers once started
        self._queryable: Any = None
        self._token: Any = None
        self._publishers: dict[str, Any] = {}
        self._inflight = 0  # on the workers, running or waiting for one
        self._inflight_bytes = 0
        self._held_bytes: int = 0  # payloads of every request in progress, the waiting verbs' too (the budget)
        self.budget = MemoryBudget(name, self.settings.memory_mb, held=lambda: PAYLOAD_HELD * self._held_bytes)
        self._waiting = 0  # verbs that wait for a person, on their own pool
        self._inflight_lock = threading.Lock()
        self._client: Any = None
        self._client_lock = threading.Lock()
        # a worker may still publish while stop() undeclares the publishers (a request past the
        # stop grace): Zenoh's Python objects refuse being used from two threads at once
        # ("RuntimeError: Already borrowed"), so both take this lock
        self._publish_lock = threading.Lock()
        self._answered = threading.local()  # per worker: the cost of the request it is answering
        self._requests: list[list] = []  # [verb, ms, code] of the requests not yet published
        self._requests_lock = threading.Lock()
        self._requests_timer: threading.Timer | None = None

    def client(self):
        """A client of the cluster for calling other services (opened on first use, closed on stop)."""
        from shared.bus.client import Client

        with self._client_lock:
            if self._client is None:
                self._client = Client(self.settings, connect_timeout_s=10.0)
            return self._client

    # ------------------------------------------------------------------ declaration
    def _declare(self, table: dict, verb: str):
        if verb not in self.endpoints:
            raise ValueError(f"{verb!r} is not a verb of the {self.name} contract")

        def deco(fn):
            table[verb] = fn
            return fn

        return deco

    def handler(self, verb: str):
        """Decorator: ``@service.handler("build") def build(req: dict) -> dict``."""
        return self._declare(self.handlers, verb)

    def cost(self, verb: str):
        """Decorator: ``@service.cost("generate") def _(req: dict) -> float``, the bytes of working
        memory a request of ``verb`` needs (:mod:`shared.bus.budget`), when more than
        ``PAYLOAD_FACTOR`` times its payload (the estimate of every other verb)."""
        return self._declare(self.costs, verb)

    def serve(self, handlers: dict[str, Callable[[dict], dict]],
              costs: dict[str, Callable[[dict], float]] | None = None) -> Service:
        """Register ``handlers`` (verb -> handler, as :meth:`handler` does) and ``costs``
        (verb -> estimate, as :meth:`cost` does) at once: a service whose verbs are methods."""
        for verb, handle in handlers.items():
            self.handler(verb)(handle)
        for verb, estimate in (costs or {}).items():
            self.cost(verb)(estimate)
        return self

    # ------------------------------------------------------------------ life cycle
    def start(self) -> Service:
        import zenoh

        missing = set(self.endpoints) - set(self.handlers)
        if missing:
            raise RuntimeError(f"service {self.name}: no handler for {sorted(missing)}")
        self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix=f"{self.name}-worker")
        if any(ep.waits for ep in self.endpoints.values()):
            self._wait_pool = ThreadPoolExecutor(self.settings.waiting, thread_name_prefix=f"{self.name}-waiting")
        self._session = zenoh.open(client_config(self.settings, wait=True))
        self.budget.measure_baseline()  # the service as it waits: code, caches, its Zenoh session
        for topic in list(self.events) + ["requests"]:
            self._publishers[topic] = self._session.declare_publisher(
                self.settings.key("events", self.name, topic), congestion_control=zenoh.CongestionControl.BLOCK)
        if self.settings.identity is None:
            self._queryable = self._session.declare_queryable(self.settings.key(self.name, "*"), self._on_query)
            self._token = self._session.liveliness().declare_token(self.settings.key("alive", self.name))
            self.leading = True
        else:
            threading.Thread(target=self._leadership, name=f"{self.name}-leadership", daemon=True).start()
        log.info("service %s up on %s (prefix %s); memory: %.0f MB held, %.0f MB of MIRRORCOACH_MEMORY_MB=%.0f for "
                 "requests", self.name, self.settings.router, self.settings.prefix, self.budget.baseline / MB,
                 self.budget.available / MB, self.settings.memory_mb)
        if self.budget.available < 64 * MB:
            log.warning("MIRRORCOACH_MEMORY_MB=%.0f leaves %s only %.0f MB for requests: large ones will be refused",
                        self.settings.memory_mb, self.name, self.budget.available / MB)
        return self

    # ------------------------------------------------------------------ leadership (deployed)
    def _leaders(self) -> list[str]:
        out = []
        for r in self._session.liveliness().get(self.settings.key("leader", self.name, "*"), timeout=1.0):
            if r.ok is not None:
                out.append(str(r.ok.key_expr).rsplit("/", 1)[-1])
        return out

    def _me(self) -> str:
        """This instance's identity (leadership runs only with one: several hosts)."""
        ident = self.settings.identity
        assert ident is not None
        return ident.name

    def _leadership(self, period_s: float = 0.5) -> None:
        """Lead or stand by (module docstring), checked every ``period_s`` until stopped."""
        me = self._me()
        while not self._stop.wait(period_s):
            try:
                connected = bool(list(self._session.info.routers_zid()))
                if self.leading:
                    if not connected:
                        self._step_down("lost the link to the router")
                    elif any(n < me for n in self._leaders() if n != me):
                        self._step_down("another instance leads (a healed partition); the smaller name stays")
                elif connected and not self._leaders():
                    self._lead()
            except Exception:  # a closing session: the loop ends with the stop event
                if not self._stop.is_set():
                    log.exception("leadership check failed")

    def _lead(self) -> None:
        if self._stop.is_set():
            return
        for hook in self.on_promote:
            hook()
        me = self._me()
        self._leader_token = self._session.liveliness().declare_token(self.settings.key("leader", self.name, me))
        self._queryable = self._session.declare_queryable(self.settings.key(self.name, "*"), self._on_query)
        self._token = self._session.liveliness().declare_token(self.settings.key("alive", self.name))
        self.leading = True
        log.warning("service %s: %s leads (answers requests)", self.name, me)

    def _step_down(self, why: str) -> None:
        self.leading = False
        for attr in ("_queryable", "_token", "_leader_token"):
            obj = getattr(self, attr)
            setattr(self, attr, None)
            if obj is not None:
                try:
                    obj.undeclare()
                except Exception:  # the session may already be cut off
                    pass
        log.warning("service %s: %s stands by (%s)", self.name, self._me(), why)

    def run(self) -> int:
        """Start, serve until SIGTERM/SIGINT, stop. Returns the exit code."""
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self._stop.set())
        self.start()
        try:
            while not self._stop.wait(0.5):
                pass
        finally:
            self.stop()
        return 0

    def stop(self) -> None:
        self._stop.set()
        if self._queryable is not None:
            self._queryable.undeclare()
            self._queryable = None
        if self._pool is not None:
            deadline = time.monotonic() + self.stop_grace_s
            while (self._inflight or self._waiting) and time.monotonic() < deadline:
                time.sleep(0.05)
            self._pool.shutdown(wait=False, cancel_futures=True)
            if self._wait_pool is not None:
                self._wait_pool.shutdown(wait=False, cancel_futures=True)
        for hook in self.on_stop:
            try:
                hook()
            except Exception:  # a failing hook must not keep the session open
                log.exception("on_stop hook failed")
        with self._client_lock:
            if self._client is not None:
                self._client.close()
                self._client = None
        for attr in ("_token", "_leader_token"):
            if getattr(self, attr) is not None:
                getattr(self, attr).undeclare()
                setattr(self, attr, None)
        self._publish_requests()  # the last requests' records, before the publishers go
        with self._publish_lock:
            for p in self._publishers.values():
                p.undeclare()
            self._publishers.clear()  # a late publish() finds none and drops its event
        if self._session is not None:
            self._session.close()
            self._session = None
        log.info("service %s stopped", self.name)

    # ------------------------------------------------------------------ events
    def publish(self, topic: str, message: dict) -> None:
        """Publish an event declared in the contract (validated first)."""
        body = self.events[topic].validate(message) if topic in self.events else message
        payload = pack({"v": self.events[topic].version if topic in self.events else 1, **body})
        with self._publish_lock:
            pub = self._publishers.get(topic)
            if pub is not None:
                pub.put(payload)

    # ------------------------------------------------------------------ requests
    def _on_query(self, query) -> None:
        size = len(query.payload) if query.payload is not None else 0
        ep = self.endpoints.get(str(query.key_expr).rsplit("/", 1)[-1])
        waits = ep is not None and ep.waits
        with self._inflight_lock:
            if waits:  # a verb that may wait for a person: its own pool, never the workers
                busy, limit = self._waiting, self.settings.waiting
                full = busy >= limit
            else:
                busy, limit = self._inflight, self.workers + self.settings.queue
                full = busy >= limit or (busy > 0 and self._inflight_bytes + size > self.settings.queue_mb * 2**20)
            if not full:
                self._held_bytes += size
                if waits:
                    self._waiting += 1
                else:
                    self._inflight += 1
                    self._inflight_bytes += size
        if full:
            log.warning("saturated: refused a request (%d in progress or waiting)", busy)
            what = "questions waiting for an answer" if waits else "requests in progress or waiting"
            with query:
                query.reply_err(error_payload(
                    "unavailable", f"service {self.name} is saturated: {busy} {what} (at most {limit}); retry later",
                    {"cause": "saturated", "service": self.name}))
            return
        try:
            pool = self._wait_pool if waits else self._pool
            assert pool is not None  # (started before the queryable; a question waits only where a pool waits)
            pool.submit(self._serve, query, size, waits)
        except RuntimeError:  # pool shut down: we are stopping
            self._done(size, waits)
            with query:
                query.reply_err(error_payload("unavailable", f"service {self.name} is stopping"))

    def _done(self, size: int, waits: bool) -> None:
        with self._inflight_lock:
            self._held_bytes -= size
            if waits:
                self._waiting -= 1
            else:
                self._inflight -= 1
                self._inflight_bytes -= size

    def _serve(self, query, size: int = 0, waits: bool = False) -> None:
        t0 = time.perf_counter()
        verb = str(query.key_expr).rsplit("/", 1)[-1]
        code = "ok"
        try:
            with query:
                try:
                    reply = self.handle(verb, query.payload.to_bytes() if query.payload is not None else b"")
                    query.reply(query.key_expr, reply)
                except MirrorcoachError as e:
                    code = e.code
                    query.reply_err(error_payload(e.code, e.message, e.details))
                except Exception as e:
                    if isinstance(e, OSError) and e.errno in DISK_FULL:  # not a bug, not the caller's
                        code = "unavailable"
                        log.error("%s/%s: the disk is full: %s", self.name, verb, e)
                        query.reply_err(error_payload(
                            "unavailable", f"service {self.name} could not write: the disk is full ({e.strerror}); "
                            f"the request was not completed; free some space and retry",
                            {"cause": "disk_full", "service": self.name}))
                        return
                    code = "internal"  # a bug: log it, tell the caller without a traceback
                    log.error("internal error in %s/%s: %s\n%s", self.name, verb, e, traceback.format_exc())
                    query.reply_err(error_payload("internal", f"{self.name} failed on {verb}: {type(e).__name__}: {e}"))
        finally:
            self._done(size, waits)
            cost, self._answered.cost = getattr(self._answered, "cost", 0.0), 0.0
            if cost > TRIM_ABOVE:  # once the reply and the request are freed (after this call returns)
                later = threading.Timer(0.5, self.budget.give_back, args=(cost,))
                later.daemon = True
                later.start()
            ms = 1e3 * (time.perf_counter() - t0)
            # a line per request only when it failed or was slow (the observer's latency table has
            # them all): a line each was 7 % of pss's CPU in `reproduce ch3`
            log.log(logging.INFO if code != "ok" or ms >= SLOW_MS else logging.DEBUG, "%s %s %.1f ms", verb, code, ms)
            known = verb if verb in self.endpoints else "(unknown verb)"  # a caller cannot mint names
            self._report(known, ms, code)

    def _report(self, verb: str, ms: float, code: str) -> None:
        """Queue a request's record for the next ``requests`` event (:data:`REQUESTS_EVERY_S`)."""
        with self._requests_lock:
            self._requests.append([verb, round(ms, 3), code])
            full = len(self._requests) >= REQUESTS_BATCH
            if not full and self._requests_timer is None:
                self._requests_timer = threading.Timer(REQUESTS_EVERY_S, self._publish_requests)
                self._requests_timer.daemon = True
                self._requests_timer.start()
        if full:
            self._publish_requests()

    def _publish_requests(self) -> None:
        with self._requests_lock:
            batch, self._requests, self._requests_timer = self._requests, [], None
        if batch:
            try:
                self.publish("requests", {"service": self.name, "requests": batch})
            except Exception:  # observability must never break a reply
                pass

    def handle(self, verb: str, payload: bytes) -> bytes:
        """Decode, validate, call, validate the reply, encode (also usable without a bus)."""
        ep = self.endpoints.get(verb)
        if ep is None:
            raise NotFound(f"service {self.name} has no verb {verb!r}; it answers {', '.join(sorted(self.endpoints))}")
        msg = unpack(payload, self.settings.max_payload) if payload else {}
        req = ep.request.validate(msg)
        limit = None if ep.waits else min(ep.time_limit_s, self.settings.time_limit)
        cost = max(PAYLOAD_FACTOR * len(payload), self.costs[verb](req) if verb in self.costs else 0.0)
        self._answered.cost = cost  # given back by _serve once the reply is sent
        # the reply is packed inside the reservation: it costs too
        with self.budget.reserve(cost, f"{self.name}/{verb}", own_held=PAYLOAD_HELD * len(payload)):
            with time_limit(limit, f"{self.name}/{verb}"):
                out = self.handlers[verb](req)
            try:
                out = ep.reply.validate(out)
            except BadInput as e:  # our own reply is off-contract: a bug, not the caller's fault
                raise RuntimeError(f"reply does not match {ep.reply.name}: {e.message}") from None
            reply = pack({"v": ep.reply.version, **out})
        if len(reply) > self.settings.max_payload:  # the router would drop it unread: the caller would wait
            raise BadInput(f"the reply of {self.name}/{verb} is {len(reply) / 2**20:.0f} MiB, more than the "
                           f"{self.settings.max_payload / 2**20:.0f} MiB a message may carry (MIRRORCOACH_MAX_PAYLOAD): "
                           "ask for less at once (a shorter clip, fewer frames)", cause="too_large",
                           size=len(reply), limit=self.settings.max_payload)
        return reply


class OneWriter:
    """One request at a time per key (a session, an estimate): a second one gets ``conflict``
    at once instead of waiting or interleaving. ``with writer(key): ...``"""

    def __init__(self, what: str):
        self.what = what
        self._busy: set[str] = set()
        self._lock = threading.Lock()

    def __call__(self, key: str):
        writer = self

        class _Slot:
            def __enter__(self):
                with writer._lock:
                    if key in writer._busy:
                        raise Conflict(f"{writer.what} {key!r} is busy with another request; try again when it is done",
                                       **{writer.what: key})
                    writer._busy.add(key)

            def __exit__(self, *exc):
                with writer._lock:
                    writer._busy.discard(key)

        return _Slot()
