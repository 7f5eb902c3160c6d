"""``python -m services.observer``: log the cluster's events to rerun until SIGTERM."""

import logging
import os
import sys

from services.observer.service import Observer

NICE = 10  # the observer's scheduling priority below the services'

if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s observer %(levelname)s %(message)s")
    # drawing yields to the services' work: on a busy machine the dashboard lags (its queue is
    # bounded, MIRRORCOACH_OBSERVER_QUEUE_MB) instead of the requests slowing
    os.nice(NICE)
    raise SystemExit(Observer().run())
