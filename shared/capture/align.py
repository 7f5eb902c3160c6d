"""Aligning a whole target with a stretch of a take (dynamic time warping), for
:mod:`shared.capture.segment`: the symmetric steps of slope 1/2 to 2 ((1, 1) weighted 2, (1, 2)
and (2, 1) weighted 3, so a cost divided by ``n + L`` is a mean per-frame distance), as numba
kernels tested against their Python source."""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist

from shared.compiled import kernel


@kernel(cache=True, nogil=True)
def subsequence_dtw(cost):
    """Open-begin, open-end DTW of the target (rows) against the take (columns) on a cost matrix
    ``cost`` (n, m): per end column, the accumulated cost of the best alignment of the whole
    target ending there and the column where it starts."""
    n, m = cost.shape
    # three rows kept (a step reaches two rows back): memory of the take's length, not n times it
    acc = np.full((3, m), np.inf)
    start = np.zeros((3, m), np.int64)
    for j in range(m):
        acc[0, j] = 2.0 * cost[0, j]
        start[0, j] = j
    for i in range(1, n):
        r, r1, r2 = i % 3, (i - 1) % 3, (i - 2) % 3
        acc[r, 0], start[r, 0] = np.inf, 0
        for j in range(1, m):
            c = cost[i, j]
            best = acc[r1, j - 1] + 2.0 * c
            s = start[r1, j - 1]
            if j >= 2:
                two = acc[r1, j - 2] + 2.0 * cost[i, j - 1] + c
                if two < best:
                    best, s = two, start[r1, j - 2]
            if i >= 2:
                down = acc[r2, j - 1] + 2.0 * cost[i - 1, j] + c
                if down < best:
                    best, s = down, start[r2, j - 1]
            acc[r, j] = best
            start[r, j] = s
    last = (n - 1) % 3
    return acc[last].copy(), start[last].copy()


@kernel(cache=True, nogil=True)
def global_dtw(cost):
    """DTW with fixed ends and the same steps as :func:`subsequence_dtw`, divided by ``n + m``
    (a mean per-frame distance); infinite when the slopes cannot join the ends."""
    n, m = cost.shape
    acc = np.full((n, m), np.inf)
    acc[0, 0] = 2.0 * cost[0, 0]
    for i in range(1, n):
        for j in range(1, m):
            c = cost[i, j]
            best = acc[i - 1, j - 1] + 2.0 * c
            if j >= 2:
                two = acc[i - 1, j - 2] + 2.0 * cost[i, j - 1] + c
                if two < best:
                    best = two
            if i >= 2:
                down = acc[i - 2, j - 1] + 2.0 * cost[i - 1, j] + c
                if down < best:
                    best = down
            acc[i, j] = best
    return acc[n - 1, m - 1] / (n + m)


def distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances of every frame of ``a`` (rows) to every frame of ``b`` (columns):
    scipy's ``cdist`` (no target x take x features differences held: a movement of 20,000 frames
    held 1.1 GB of them at once)."""
    return cdist(a, b)


def best_stretches(a: np.ndarray, b: np.ndarray, lo: int, hi: int, mean: np.ndarray, spread: float) -> list[tuple[int, int]]:
    """Stretches of ``b[lo:hi]`` (read as ``(b - mean) / spread``) where the whole target ``a``
    (a shape) aligns best, found without the take's rests: every end's best start
    (:func:`subsequence_dtw`), kept where the mean cost per frame is lowest within a quarter of
    the target's length. (start, end exclusive) in frames."""
    n = len(a)
    acc, start = subsequence_dtw(distances(a, (b[lo:hi] - mean) / spread))
    norm = np.where(np.isfinite(acc), acc / (n + np.arange(hi - lo) - start + 1), np.inf)
    w = max(n // 4, 1)
    pad = np.concatenate([np.full(w, np.inf), norm, np.full(w, np.inf)])
    low = np.min(np.lib.stride_tricks.sliding_window_view(pad, 2 * w + 1), axis=1)
    return [(lo + int(start[j]), lo + int(j) + 1) for j in np.flatnonzero(np.isfinite(norm) & (norm <= low))]
