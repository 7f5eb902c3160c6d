"""Start one service process: logging, settings, a clear exit on a bad configuration."""

from __future__ import annotations

import importlib
import logging
import sys

from shared.errors import MirrorcoachError


def main(name: str, module: str) -> int:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format=f"%(asctime)s {name} %(levelname)s %(message)s")
    # a service runs its requests in a pool of worker threads; BLAS's own threads would compete
    # with them on small matrices (one recognition: 8.4 ms with two BLAS threads, 6.5 ms with one)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    try:
        from shared.bus.config import Settings

        svc = importlib.import_module(module).make_service(Settings())
    except MirrorcoachError as e:
        print(f"error: {e.message}", file=sys.stderr)
        return 2
    return svc.run()
