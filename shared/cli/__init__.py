"""The ``mirrorcoach`` command line (``shared.cli.app``; its entry point ``shared.cli.entry``)."""

from __future__ import annotations

import gc
from contextlib import contextmanager


@contextmanager
def lasting_imports():
    """Imports whose objects last as long as the process: made with the cyclic garbage
    collector off (none of them is garbage) and then frozen out of its later passes
    (``gc.freeze``). A one-clip command's imports otherwise pay ~10 ms of collections
    (``python -m bench.bus``)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was:
            gc.enable()
