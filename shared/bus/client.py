"""The client helper: one request, one reply or one clear error, always within a timeout.

``Client.request("pss", "recognize", {...})`` returns the decoded reply map or raises:

* :class:`RemoteError` with the service's stable code (``bad_request``, ``not_found``, ...);
* :class:`Unavailable` when nothing answered: "service pss is not running (start it with
  `make up`)" when its liveliness token is absent, or a timeout message when it is alive
  but did not answer in time;
* :class:`Unavailable` when there is no router: "the cluster is not running".
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time

from shared.bus.codec import DEFAULT_MAX_PAYLOAD, pack, unpack
from shared.bus.config import Settings, client_config
from shared.errors import BadInput, Forbidden, MirrorcoachError, Unavailable

__all__ = ["Client", "RemoteError", "Unavailable"]


class RemoteError(MirrorcoachError):
    """An error a service replied with; ``code`` is the service's stable code."""

    def __init__(self, code: str, message: str, details: dict | None = None):
        super().__init__(message, **(details or {}))
        self.code = code


def _may_run_longer(service: str, verb: str, timeout: float) -> str:
    """What to say when a verb's contract lets it run longer than the client waited."""
    limit = _verb_limit(service, verb)
    if limit is None or limit <= timeout:
        return ""
    return (f"; it may still be working: {service}/{verb} may run up to {limit:g} s (its time limit), so "
            f"wait longer with --timeout {limit:g}")


class _Watch:
    """Ends a request's wait (its Zenoh cancellation token) at ``MIRRORCOACH_TIMEOUT``, or, when
    the verb's contract lets it run longer, at the verb's time limit or as soon as the service is
    no longer there to answer (looked at every ``EVERY_S`` past ``MIRRORCOACH_TIMEOUT``). The
    client's one :class:`_Watcher` thread keeps the time of every request's watch: a request
    starts no thread of its own (starting one cost a request a scheduler slice on a busy machine)."""

    EVERY_S = 2.0

    def __init__(self, client: Client, service: str, verb: str, timeout: float):
        self.client, self.service, self.verb = client, service, verb
        self.timeout = timeout  # grows to the verb's limit once MIRRORCOACH_TIMEOUT has passed
        self.longest = max(timeout, client.settings.time_limit, 600.0) + 30.0
        self.stopped = False
        self._extended = False  # past MIRRORCOACH_TIMEOUT, waiting up to the verb's limit

    def start(self):
        import zenoh

        self.token = zenoh.CancellationToken()
        self._t0 = time.monotonic()
        self.client._watcher.add(self, self._t0 + self.timeout)
        return self.token

    def stop(self) -> None:
        if not self.stopped:
            self.stopped = True
            self.client._watcher.stopped()

    def due(self, now: float) -> float | None:
        """The watch's time came (the watcher calls it): end the wait, or the next time to look."""
        if not self._extended:
            limit = _verb_limit(self.service, self.verb)  # read only now: schemas load numpy (a slow start)
            if limit is None or limit <= self.timeout:
                self.token.cancel()
                return None
            self.timeout, self._extended = limit + 10.0, True
            return now + self.EVERY_S
        if now - self._t0 >= self.timeout or not self._still_there():
            self.token.cancel()
            return None
        return now + self.EVERY_S

    def _still_there(self) -> bool:
        if self.client.settings.identity is None:
            from shared.bus.pidfiles import local_state

            state, _ = local_state(self.client.settings, self.service)
            if state in ("frozen", "restarting"):
                return False
        try:
            return self.service in self.client.alive(timeout=1.0)
        except MirrorcoachError:
            return False


class _Watcher:
    """One thread per client for the watches of all its requests: a heap of their next times.
    A finished request's entry is dropped when its time comes, or all at once when finished ones
    outnumber the running (so the heap stays about as large as the requests in flight). Looking
    whether a service is still there (past ``MIRRORCOACH_TIMEOUT`` only) asks the router for up
    to 1 s, and the other watches wait that long."""

    def __init__(self) -> None:
        self._order = itertools.count()
        self._heap: list = []
        self._running = 0
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._closed = False

    def add(self, watch: _Watch, when: float) -> None:
        with self._cond:
            heapq.heappush(self._heap, (when, next(self._order), watch))
            self._running += 1
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="request-watch", daemon=True)
                self._thread.start()
            self._cond.notify()

    def stopped(self) -> None:
        with self._cond:
            self._running -= 1
            if len(self._heap) > 64 and len(self._heap) > 2 * self._running:
                self._heap = [e for e in self._heap if not e[2].stopped]
                heapq.heapify(self._heap)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed:
                    while self._heap and self._heap[0][2].stopped:
                        heapq.heappop(self._heap)
                    wait = self._heap[0][0] - time.monotonic() if self._heap else None
                    if wait is not None and wait <= 0:
                        break
                    self._cond.wait(wait)
                if self._closed:
                    return
                _, _, watch = heapq.heappop(self._heap)
            nxt = watch.due(time.monotonic())  # outside the lock: it may ask the router (up to 1 s)
            if nxt is None:  # the wait was ended: the watch is done
                watch.stop()
                continue
            with self._cond:
                if not watch.stopped:
                    heapq.heappush(self._heap, (nxt, next(self._order), watch))


def _verb_limit(service: str, verb: str) -> float | None:
    """The time limit of a verb that does not wait for a person (``None``: unknown or waits)."""
    try:
        from schemas import CONTRACTS

        ep = CONTRACTS[service].ENDPOINTS[verb]
    except (ImportError, KeyError):
        return None
    return None if ep.waits else float(ep.time_limit_s)


class Client:
    """A Zenoh client session for requests, liveliness and event subscriptions."""

    def __init__(self, settings: Settings | None = None, connect_timeout_s: float = 3.0, arrays: str = "numpy"):
        """``arrays="lists"``: replies' arrays as nested lists, so that a short command never
        imports numpy (``mirrorcoach space recognize``)."""
        import zenoh

        self.arrays = arrays
        self.settings = settings or Settings()
        try:
            self._session: zenoh.Session | None = zenoh.open(client_config(self.settings, wait=False,
                                                                           connect_timeout_s=connect_timeout_s))
        except zenoh.ZError:
            ident = self.settings.identity
            if ident is not None:
                raise Unavailable(f"cannot reach the cluster's router at {self.settings.router} as {ident.name!r} "
                                  f"(TLS): the router is down or unreachable, or it refused this identity's "
                                  f"certificate (not from the cluster's CA, or expired)", router=self.settings.router,
                                  identity=ident.name) from None
            raise Unavailable(f"the cluster is not running (no router at {self.settings.router}; start it with `make up`)",
                              router=self.settings.router) from None
        self._subs: list = []
        self._watcher = _Watcher()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._watcher.close()
        for s in self._subs:
            s.undeclare()
        self._subs.clear()
        if self._session is not None:
            self._session.close()
            self._session = None

    @property
    def session(self):
        """The open Zenoh session (closed by :meth:`close`: a request after it is refused)."""
        if self._session is None:
            raise Unavailable("this client is closed", cause="closed")
        return self._session

    # ------------------------------------------------------------------ requests
    def request_raw(self, service: str, verb: str, payload: bytes, timeout: float | None = None) -> dict:
        """Send ``payload``; the decoded reply map. Without ``timeout``, the wait is
        ``MIRRORCOACH_TIMEOUT``, extended to the verb's own time limit when its contract allows it
        to work longer (a large build): past ``MIRRORCOACH_TIMEOUT`` a watchdog looks every 2 s
        whether the service is still there (frozen, restarting, gone: the wait ends at once)."""
        watch = None
        if timeout is None:
            timeout = self.settings.timeout
            watch = _Watch(self, service, verb, timeout)
        if len(payload) > self.settings.max_payload:  # the router would drop it after 64 MiB: say so now
            raise BadInput(f"the request is {len(payload) / 2**20:.1f} MiB; services accept at most "
                           f"{self.settings.max_payload / 2**20:.0f} MiB (MIRRORCOACH_MAX_PAYLOAD)",
                           size=len(payload), limit=self.settings.max_payload)
        ident = self.settings.identity
        if ident is not None and ident.role == "dashboard":  # the router would drop it; say why now
            raise Forbidden(f"identity {ident.name!r} has the dashboard role: it may only watch events, not call "
                            f"{service}/{verb}", identity=ident.name, role=ident.role)
        t0 = time.monotonic()
        if watch is None:
            replies = self.session.get(self.settings.key(service, verb), payload=payload, timeout=timeout)
        else:  # Zenoh waits for the longest a verb may run; the watchdog ends the wait earlier
            replies = self.session.get(self.settings.key(service, verb), payload=payload,
                                       timeout=watch.longest, cancellation_token=watch.start())
        try:
            reply = self._first_reply(service, verb, replies)
        finally:
            if watch is not None:
                watch.stop()
                timeout = watch.timeout  # what the wait came to be: the verb's limit, or the default
        if reply is not None:
            return reply
        raise self._no_answer(service, verb, timeout, time.monotonic() - t0, len(payload))

    def _first_reply(self, service: str, verb: str, replies) -> dict | None:
        """The first reply, checked; a remote error raised; ``None`` when none came."""
        for r in replies:
            if r.ok is not None:
                return self._checked(service, verb, unpack(r.ok.payload.to_bytes(), arrays=self.arrays))
            raw = r.err.payload.to_bytes()
            if raw == b"Timeout":  # Zenoh's own reply when nothing answered in time
                break
            try:
                err = unpack(raw)
                raise RemoteError(str(err.get("code", "internal")), str(err.get("message", "")), err.get("details") or {})
            except RemoteError:
                raise
            except MirrorcoachError:
                raise RemoteError("internal", f"{service} sent an unreadable error: {raw[:200]!r}") from None
        return None

    def _checked(self, service: str, verb: str, reply) -> dict:
        """A reply checked against its contract like any request (defaults filled in): a reply
        that does not match (an old or wrong service, or one answering in its place) is an error
        that says so, never a KeyError further on. With ``arrays="lists"`` (a command that starts
        without numpy, which the contracts need) only its being a map is checked."""
        problem = None if isinstance(reply, dict) else f"a reply is a map, got {type(reply).__name__}"
        if problem is None and self.arrays == "numpy":
            from schemas import CONTRACTS

            contract = CONTRACTS.get(service)
            ep = None if contract is None else contract.ENDPOINTS.get(verb)
            try:
                reply = reply if ep is None else ep.reply.validate(reply)
            except BadInput as e:
                problem = e.message
        if problem is not None:
            raise RemoteError("internal", f"the reply of {service}/{verb} does not match its contract ({problem}): "
                                          f"an older or wrong {service}, or something answering in its place",
                              {"service": service, "verb": verb})
        return reply

    def _router_listens(self) -> bool:
        """Whether a new session reaches the router now (this session notices a dead router
        only when its link times out)."""
        import zenoh

        try:
            zenoh.open(client_config(self.settings, wait=False, connect_timeout_s=1.0)).close()
            return True
        except zenoh.ZError:
            return False

    def _no_answer(self, service: str, verb: str, timeout: float, waited: float, size: int = 0) -> Unavailable:
        """Why nothing answered, named: the router is gone, the service is
        frozen, restarting, not running, or alive but slower than the timeout."""
        from shared.bus.pidfiles import local_state

        where = {"service": service, "router": self.settings.router}
        if self.settings.identity is not None:  # deployed: no local pid files to read; the tokens say it all
            alive = service in self.alive(timeout=1.0)
            if not list(self.session.info.routers_zid()):
                return Unavailable(f"lost the link to the cluster's router at {self.settings.router} while waiting for "
                                   f"{service}/{verb}; retry when the link is back", cause="router_down", **where)
            if not alive:
                return Unavailable(f"service {service} is not reachable: no instance on any host holds its liveliness "
                                   f"token (not running, or its host is down or cut off); retry when it is back",
                                   cause="not_running", **where)
            return Unavailable(f"service {service} did not answer {verb} within {timeout:g} s (its host or link may "
                               f"have failed mid-request; a standby takes over within seconds); retry",
                               cause="timeout", timeout=timeout, **where)
        if not list(self.session.info.routers_zid()) or not self._router_listens():
            return Unavailable(f"lost the connection to the cluster's router at {self.settings.router} while waiting "
                               f"for {service} (the router stopped or was killed; `make status` shows it, the "
                               f"supervisor restarts it)", cause="router_down", **where)
        state, detail = local_state(self.settings, service)
        if state == "frozen":
            return Unavailable(f"service {service} is frozen ({detail}); it cannot answer until it is continued "
                               f"(kill -CONT) or restarted", cause="frozen", **where)
        alive = service in self.alive(timeout=1.0)
        if not alive and state == "restarting":
            return Unavailable(f"service {service} is restarting ({detail}); retry in a few seconds",
                               cause="restarting", **where)
        if not alive and state == "running":  # started again by its supervisor, not on the bus yet
            return Unavailable(f"service {service} is starting ({detail}, not yet on the bus); retry in a few seconds",
                               cause="restarting", **where)
        if not alive:
            return Unavailable(f"service {service} is not running (start it with `make up`)", cause="not_running",
                               **where)
        if waited >= 0.9 * timeout and size > DEFAULT_MAX_PAYLOAD:  # a router set lower drops it unread, silently
            return Unavailable(f"service {service} did not answer {verb} within {timeout:g} s: the request was "
                               f"{size / 2**20:.0f} MiB, more than the {DEFAULT_MAX_PAYLOAD / 2**20:.0f} MiB a cluster "
                               f"accepts by default; a router whose MIRRORCOACH_MAX_PAYLOAD is lower than this "
                               f"client's drops it unread", cause="oversize", timeout=timeout, size=size, **where)
        if waited >= 0.9 * timeout:
            more = _may_run_longer(service, verb, timeout)
            return Unavailable(f"service {service} did not answer {verb} within {timeout:g} s{more}", cause="timeout",
                               timeout=timeout, **where)
        return Unavailable(f"service {service} gave no answer to {verb} (it may have restarted meanwhile); retry",
                           cause="no_answer", **where)

    def request(self, service: str, verb: str, message: dict | None = None, timeout: float | None = None) -> dict:
        """Send ``message`` to ``<prefix>/<service>/<verb>``; the decoded reply map."""
        return self.request_raw(service, verb, pack(message or {}), timeout)

    # ------------------------------------------------------------------ liveliness and events
    def alive(self, timeout: float = 2.0) -> set[str]:
        """Names of the services whose liveliness token is declared."""
        out = set()
        for r in self.session.liveliness().get(self.settings.key("alive", "*"), timeout=timeout):
            if r.ok is not None:
                out.add(str(r.ok.key_expr).rsplit("/", 1)[-1])
        return out

    def subscribe(self, key: str, callback) -> None:
        """Call ``callback(key, message)`` for every event on ``<prefix>/<key>`` (may use ``*``/``**``)."""
        def on_sample(sample):
            try:
                callback(str(sample.key_expr), unpack(sample.payload.to_bytes()))
            except MirrorcoachError:
                pass

        self._subs.append(self.session.declare_subscriber(self.settings.key(key), on_sample))
