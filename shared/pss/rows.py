"""Arrays that grow by rows without copying what they hold: a space of thousands of
proto-symbols adds one clip at a time, and each add extends stacks of every proto-symbol's
HMM (tens to hundreds of MB at 3,000). :func:`appended` writes the new rows into spare rows kept
after the old ones and returns a view of the longer array, sharing the buffer; the old array
still sees only its own rows. A second extension of the same array (two spaces added to one)
cannot write the rows the first took: it copies into a new buffer, as a full one does."""

from __future__ import annotations

import threading
import weakref

import numpy as np

_USED: dict[int, int] = {}  # id of a live buffer -> rows taken (the entry goes with the buffer)
_LOCK = threading.Lock()


def _spare(n: int) -> int:
    return n + max(64, n // 16)


def spare(shape: tuple, dtype=float) -> np.ndarray:
    """An empty array of ``shape`` whose buffer keeps spare rows after it, so that its first
    :func:`appended` writes in place instead of copying it."""
    buf = np.empty((_spare(shape[0]),) + tuple(shape[1:]), dtype=dtype)
    with _LOCK:
        _USED[id(buf)] = shape[0]
    weakref.finalize(buf, _USED.pop, id(buf), None)
    return buf[:shape[0]]


def appended(array: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``np.concatenate([array, rows])``, writing into ``array``'s spare rows when they are
    its own to write (a sixteenth of its length kept spare, at least 64 rows)."""
    rows = np.asarray(rows, dtype=array.dtype)
    n, k = len(array), len(rows)
    buf = array.base
    with _LOCK:
        mine = (buf is not None and _USED.get(id(buf)) == n and len(buf) >= n + k
                and array.__array_interface__["data"][0] == buf.__array_interface__["data"][0])
        if mine:
            _USED[id(buf)] = n + k
    if not mine:
        out = spare((n + k,) + array.shape[1:], array.dtype)
        out[:n] = array
        out[n:] = rows
        return out
    assert buf is not None  # (mine: the array's own base)
    buf[n:n + k] = rows
    return buf[:n + k]


def padded(matrix: np.ndarray, size: int) -> np.ndarray:
    """A symmetric ``matrix`` in the top left of a ``size`` x ``size`` one, the rest zero
    (written once: zeros then a copy wrote 72 MB twice at 3,000 proto-symbols)."""
    n = len(matrix)
    out = np.empty((size, size))
    out[:n, :n] = matrix
    out[n:] = 0.0
    out[:n, n:] = 0.0
    return out
