"""``python -m services.observer``: log the cluster's events to rerun until SIGTERM."""

import logging
import sys

from services.observer.service import Observer

if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s observer %(levelname)s %(message)s")
    raise SystemExit(Observer().run())
