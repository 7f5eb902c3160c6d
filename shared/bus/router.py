"""``python -m shared.bus.router``: the embedded Zenoh router (a router-mode session on the
loopback endpoint; no zenohd binary is needed). Runs until SIGTERM or SIGINT."""

from __future__ import annotations

import logging
import signal
import sys
import threading


def main() -> int:
    import zenoh

    from shared.bus.config import Settings, router_config
    from shared.errors import MirrorcoachError

    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s router %(levelname)s %(message)s")
    try:
        settings = Settings()
        session = zenoh.open(router_config(settings))
    except MirrorcoachError as e:
        print(f"error: {e.message}", file=sys.stderr)
        return 2
    except zenoh.ZError as e:
        print(f"error: cannot listen on {settings.router}: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    logging.info("router listening on %s", settings.router)
    while not stop.wait(0.5):
        pass
    session.close()
    logging.info("router stopped")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
