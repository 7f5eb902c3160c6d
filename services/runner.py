"""Start one service process: logging, settings, a clear exit on a bad configuration.

A service runs its requests in a pool of worker threads (``MIRRORCOACH_WORKERS``); the native
thread pools of BLAS and OpenMP would compete with them on small matrices (one recognition:
8.4 ms with two BLAS threads, 6.5 ms with one). Those pools read their size when their library
loads, and some load late (scikit-learn's OpenMP at the first calibration), so a limit set
with ``threadpoolctl`` before the imports misses them: the environment says one thread before
anything numeric is imported, ``threadpool_limits(1)`` holds the pools loaded by then, and the
service logs what ``threadpool_info()`` reports before it serves (a service that loads a pool
late imports its library in ``make_service``, so that the line shows it).
"""

from __future__ import annotations

import os

#: the environment variables native thread pools read when they load
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")
for _var in THREAD_VARS:  # before numpy, scipy or scikit-learn load a pool
    os.environ.setdefault(_var, "1")

import importlib  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402

from shared.bus.budget import service_allocator  # noqa: E402
from shared.errors import MirrorcoachError  # noqa: E402

ALLOCATOR = service_allocator()  # before any worker thread: memory a large request freed goes back to the system

log = logging.getLogger("mirrorcoach.runner")


def native_threads() -> dict[str, int]:
    """Every native thread pool loaded in this process and its size (``threadpool_info``)."""
    from threadpoolctl import threadpool_info

    out: dict[str, int] = {}
    for pool in threadpool_info():
        key = f"{pool['internal_api']}:{os.path.basename(pool['filepath'])}"
        out[key] = int(pool["num_threads"])
    return out


def main(name: str, module: str) -> int:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format=f"%(asctime)s {name} %(levelname)s %(message)s")
    try:
        from shared.bus.config import Settings

        svc = importlib.import_module(module).make_service(Settings())
    except MirrorcoachError as e:
        print(f"error: {e.message}", file=sys.stderr)
        return 2
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)  # the pools the service's imports loaded, whatever the environment said
    log.info("%s", ALLOCATOR)
    log.info("native thread pools: %s", ", ".join(f"{k} {v}" for k, v in sorted(native_threads().items())) or "none")
    return svc.run()
