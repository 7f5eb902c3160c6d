"""The observer: subscribes to the cluster's events it draws (:attr:`Observer.drawers`) and logs them to rerun
(``shared.observe.dashboard``). It answers no requests; it declares the liveliness token
``<prefix>/alive/observer`` so ``make up`` waits for it and ``status`` lists it.

Recording: ``$MIRRORCOACH_HOME/recordings/<time>.rrd`` (``latest.rrd`` points to it); past
``MIRRORCOACH_RECORDING_MB`` it goes on in a new file, and only the newest
``MIRRORCOACH_RECORDINGS`` are kept. With
``MIRRORCOACH_RERUN_URL`` (e.g. ``rerun+http://127.0.0.1:9876/proxy``) it also streams live to
a viewer the user started; it never binds a port itself. The Zenoh callback only queues the
sample; one worker thread decodes and logs, so a slow disk never stalls the bus.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from schemas import CONTRACTS
from schemas.common import clip_from_wire
from shared.bus.codec import unpack
from shared.bus.config import Settings, client_config
from shared.errors import BadInput, MirrorcoachError
from shared.observe.dashboard import MAX_KEPT, Dashboard

log = logging.getLogger("mirrorcoach.observer")


class Observer:
    def __init__(self, settings: Settings | None = None):
        self.s = settings or Settings()
        self.q: queue.Queue = queue.Queue()
        self.stop = threading.Event()
        self.count = 0
        self.refused = 0
        self.spaces: OrderedDict[str, dict] = OrderedDict()
        self.queued_bytes, self.dropped = 0, 0
        self.max_queued = self.s.observer_queue_mb * 2**20
        #: a closed recording's size over its size while open: rerun writes an index of its chunks when
        #: a file is closed (0.6-0.7 of the data in rerun 0.41); measured again at every rotation
        self.closing_growth = 1.75
        self.queued_lock = threading.Lock()
        #: how each event it draws is drawn ("service/topic"; ``*``: every service): what it subscribes to
        self.drawers: dict[str, Callable[[Dashboard, str, dict], None]] = {
            "coach/session": lambda dash, _, ev: dash.session_started(ev["session"], clip_from_wire(ev["target"]),
                                                                      ev.get("learner")),
            "coach/trial": lambda dash, _, ev: dash.trial(
                ev, clip_from_wire(ev["attempt"]) if ev.get("attempt") else None,
                clip_from_wire(ev["emphatic"]) if ev.get("emphatic") else None),
            "pss/space": self._space,
            "estimator/progress": lambda dash, _, ev: dash.progress(ev),
            "dialogue/transcript": lambda dash, _, ev: dash.transcript(ev),
            "capture/take": lambda dash, _, ev: dash.capture_take(ev),
            "*/requests": self._requests,
        }

    def enqueue(self, sample) -> None:
        """The Zenoh callback: queue the event for the drawing thread. Events beyond
        ``MIRRORCOACH_OBSERVER_QUEUE_MB`` waiting (the observer far behind a burst) are dropped and
        counted, so the observer's memory stays bounded; the services never wait for it."""
        payload = sample.payload.to_bytes()
        with self.queued_lock:
            if self.queued_bytes and self.queued_bytes + len(payload) > self.max_queued:  # one is always taken
                self.dropped += 1
                if self.dropped == 1 or self.dropped % 1000 == 0:
                    log.warning("behind: %d event(s) dropped so far (more than %g MiB waiting)", self.dropped,
                                self.max_queued / 2**20)
                return
            self.queued_bytes += len(payload)
        self.q.put((str(sample.key_expr), payload))

    def recording_path(self):
        """A new recording file; ``latest.rrd`` points to it and only the newest
        ``MIRRORCOACH_RECORDINGS`` are kept."""
        d = self.s.home / "recordings"
        d.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path, n = d / f"{stamp}.rrd", 1
        while path.exists():
            path, n = d / f"{stamp}-{n}.rrd", n + 1
        path.touch()
        latest = d / "latest.rrd"
        latest.unlink(missing_ok=True)
        latest.symlink_to(path.name)
        old = sorted((p for p in d.glob("2*.rrd") if p != path), key=lambda p: (p.stat().st_mtime, p.name))
        for p in old[: max(0, len(old) - (self.s.recordings - 1))]:
            p.unlink(missing_ok=True)
            log.info("deleted the old recording %s (MIRRORCOACH_RECORDINGS=%d)", p.name, self.s.recordings)
        return path

    def rotate(self, dash, path):
        """Past ``MIRRORCOACH_RECORDING_MB``: go on in a new recording that starts with what is
        still true, not its history (the newest sessions' targets, the spaces' latest proto-symbols),
        in at most half the limit, so the new file starts small."""
        open_bytes = dash.file_bytes()
        new_path = self.recording_path()
        new = Dashboard(new_path, os.environ.get("MIRRORCOACH_RERUN_URL") or None)
        dash.close()
        if open_bytes:  # what closing added (rerun's index), for the next file's estimate
            self.closing_growth = max(1.0, path.stat().st_size / open_bytes)
        new.continue_from(dash, budget_bytes=self.s.recording_mb * 2**20 / 2 / self.closing_growth,
                          spaces=list(self.spaces.values()))
        log.info("recording %s passed %g MB (%.2f MB closed); recording to %s (%.2f MB carried on)", path.name,
                 self.s.recording_mb, path.stat().st_size / 2**20, new_path.name, new.file_bytes() / 2**20)
        return new, new_path

    def handle(self, dash, key: str, payload: bytes) -> None:
        parts = key.split("/")
        service, topic = parts[-2], parts[-1]
        ev = unpack(payload)
        if not isinstance(ev, dict):
            raise BadInput(f"an event is a map, got {type(ev).__name__}")
        contract = CONTRACTS.get(service)
        if contract is not None and topic in contract.EVENTS:
            ev = contract.EVENTS[topic].validate(ev)  # what its service declared: anything else is refused here
        draw = self.drawers.get(f"{service}/{topic}") or self.drawers.get(f"*/{topic}")
        if draw is not None:
            draw(dash, service, ev)

    def _space(self, dash, service: str, ev: dict) -> None:
        dash.space(ev)
        self.spaces.pop(ev["space"], None)  # the latest state of each space, for the next recording
        if ev["change"] != "deleted" and ev.get("info"):
            self.spaces[ev["space"]] = ev
            while len(self.spaces) > MAX_KEPT:
                self.spaces.popitem(last=False)

    @staticmethod
    def _requests(dash, service: str, ev: dict) -> None:
        """A service's answered requests (``shared.bus.runtime``): one latency table row each."""
        contract = CONTRACTS.get(service)
        if contract is None:  # the entities stay bounded: a service and verb each of the contracts,
            return  # never a caller's
        batch = ev.get("requests")
        if not isinstance(batch, list) or not all(
                isinstance(r, list) and len(r) == 3 and isinstance(r[0], str) and isinstance(r[1], (int, float))
                and not isinstance(r[1], bool) and isinstance(r[2], str) for r in batch):
            raise BadInput("a requests event holds a list of [verb, ms, code]: a text, a number, a text")
        for verb, ms, code in batch:
            dash.request({"service": service, "verb": verb if verb in contract.ENDPOINTS else "unknown_verb",
                          "ms": float(ms), "code": code})

    def run(self) -> int:
        import zenoh

        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self.stop.set())
        path = self.recording_path()
        dash = Dashboard(path, os.environ.get("MIRRORCOACH_RERUN_URL") or None)
        session = zenoh.open(client_config(self.s, wait=True))
        # the topics it draws (not the capture's frames, nor events only services listen to)
        subs = [session.declare_subscriber(self.s.key("events", *topic.split("/")), self.enqueue)
                for topic in self.drawers]
        token = session.liveliness().declare_token(self.s.key("alive", "observer"))
        log.info("observer up; recording to %s", path)
        limit, next_check, start = self.s.recording_mb * 2**20, 0.0, 0
        try:
            while not (self.stop.is_set() and self.q.empty()):
                layout = dash.layout_ready()  # a changed layout goes out at most every LAYOUT_EVERY_S
                if layout or time.monotonic() >= next_check:  # and the file's size, as it will be closed
                    next_check = time.monotonic() + 0.5  # (rerun adds an index), twice a second
                    size = (dash.file_bytes() + (dash.layout_bytes() if layout else 0)) * self.closing_growth
                    if size > limit and size - start > limit / 2:  # (carried state must grow first)
                        dash, path = self.rotate(dash, path)  # the layout goes to the new file
                        start = dash.file_bytes() * self.closing_growth
                    elif layout:
                        dash.send_layout()
                dash.refresh()
                try:
                    key, payload = self.q.get(timeout=0.2)
                except queue.Empty:
                    continue
                with self.queued_lock:
                    self.queued_bytes -= len(payload)
                try:
                    self.handle(dash, key, payload)
                    self.count += 1
                except MirrorcoachError as e:  # a malformed event: said, and skipped
                    self.refused += 1
                    log.warning("refused event on %s: %s", key, e.message)
                except Exception:  # anything else while logging one event never stops the observer
                    self.refused += 1
                    log.exception("could not log the event on %s", key)
        finally:
            for sub in subs:
                sub.undeclare()
            token.undeclare()
            session.close()
            dash.close()
            log.info("observer stopped after %d events (%d refused); %d dropped while behind; recording %s",
                     self.count, self.refused, self.dropped, path)
        return 0
