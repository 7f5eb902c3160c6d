"""A digest of arrays' values, the key of anything computed from them alone (per-process caches)."""

from __future__ import annotations

import numpy as np


def array_digest(*arrays) -> bytes:
    """16 bytes from the arrays' shapes and values (as float64): equal for equal arrays, whatever
    object holds them."""
    import hashlib  # imported when first used: OpenSSL's bindings cost a one-clip command 3 ms

    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=float)
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.digest()
