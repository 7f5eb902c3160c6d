"""The observer: subscribes to every event of the cluster and logs it to rerun
(``shared.observe.dashboard``). It answers no requests; it declares the liveliness token
``<prefix>/alive/observer`` so ``make up`` waits for it and ``status`` lists it.

Recording: ``$MIRRORCOACH_HOME/recordings/<time>.rrd`` (``latest.rrd`` points to it). With
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

from schemas import CONTRACTS
from schemas.common import clip_from_wire
from shared.bus.config import Settings, client_config
from shared.codec import unpack
from shared.errors import BadInput, MirrorcoachError

log = logging.getLogger("mirrorcoach.observer")


class Observer:
    def __init__(self, settings: Settings | None = None):
        self.s = settings or Settings()
        self.q: queue.Queue = queue.Queue()
        self.stop = threading.Event()
        self.count = 0
        self.refused = 0

    def recording_path(self):
        d = self.s.home / "recordings"
        d.mkdir(parents=True, exist_ok=True)
        path = d / time.strftime("%Y%m%d-%H%M%S.rrd")
        latest = d / "latest.rrd"
        latest.unlink(missing_ok=True)
        latest.symlink_to(path.name)
        return path

    def handle(self, dash, key: str, payload: bytes) -> None:
        parts = key.split("/")
        service, topic = parts[-2], parts[-1]
        ev = unpack(payload)
        if not isinstance(ev, dict):
            raise BadInput(f"an event is a map, got {type(ev).__name__}")
        contract = CONTRACTS.get(service)
        if contract is not None and topic in contract.EVENTS:
            ev = contract.EVENTS[topic].validate(ev)  # what its service declared: anything else is refused here
        if service == "coach" and topic == "session":
            dash.session_started(ev["session"], clip_from_wire(ev["target"]))
        elif service == "coach" and topic == "trial":
            dash.trial(ev, clip_from_wire(ev["attempt"]) if ev.get("attempt") else None,
                       clip_from_wire(ev["emphatic"]) if ev.get("emphatic") else None)
        elif service == "pss" and topic == "space":
            dash.space(ev)
        elif service == "estimator" and topic == "progress":
            dash.progress(ev)
        elif service == "dialogue" and topic == "transcript":
            dash.transcript(ev)
        elif topic == "request":
            dash.request(ev)

    def run(self) -> int:
        import zenoh

        from shared.observe.dashboard import Dashboard

        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self.stop.set())
        path = self.recording_path()
        dash = Dashboard(path, os.environ.get("MIRRORCOACH_RERUN_URL") or None)
        session = zenoh.open(client_config(self.s, wait=True))
        sub = session.declare_subscriber(self.s.key("events", "**"),
                                         lambda sample: self.q.put((str(sample.key_expr), sample.payload.to_bytes())))
        token = session.liveliness().declare_token(self.s.key("alive", "observer"))
        log.info("observer up; recording to %s", path)
        try:
            while not (self.stop.is_set() and self.q.empty()):
                try:
                    key, payload = self.q.get(timeout=0.2)
                except queue.Empty:
                    continue
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
            sub.undeclare()
            token.undeclare()
            session.close()
            dash.close()
            log.info("observer stopped after %d events (%d refused); recording %s", self.count, self.refused, path)
        return 0
