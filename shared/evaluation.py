"""Recognition on a train/test split: the PSS against 1-nearest-neighbour DTW.

Both see the same frames: every clip resampled to the space's frame rate and encoded with
the space's turn-invariant features (:mod:`shared.pss.features`). DTW is dtw-python's
symmetric2 step pattern on Euclidean frame distances, normalised by the summed lengths
(``normalizedDistance``); a clip takes the label of the training
clip with the smallest DTW distance.
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from shared.clip import Clip
from shared.pss.space import ProtoSymbolSpace


@dataclass
class RecognitionResult:
    method: str
    accuracy: float
    per_class: dict[str, tuple[int, int]]  # label -> (correct, total)
    seconds_per_clip: float
    predictions: list[str] = field(default_factory=list)


def _summarise(method, truth, pred, seconds) -> RecognitionResult:
    per = defaultdict(lambda: [0, 0])
    for t, p in zip(truth, pred):
        per[t][1] += 1
        per[t][0] += int(t == p)
    acc = float(np.mean([t == p for t, p in zip(truth, pred)])) if truth else float("nan")
    return RecognitionResult(method, acc, {k: tuple(v) for k, v in sorted(per.items())},
                             float(np.mean(seconds)) if seconds else float("nan"), list(pred))


def pss_recognition(space: ProtoSymbolSpace, test: list[Clip], use: str = "distance") -> RecognitionResult:
    """Label of the nearest proto-symbol by eq. 2.4 (``use="distance"``) or by the point in the space."""
    pred, secs = [], []
    for c in test:
        r = space.recognize(c)
        secs.append(r.seconds)
        pred.append(r.label if use == "distance" else r.label_in_space)
    return _summarise(f"PSS nearest proto-symbol ({use})", [c.label for c in test], pred, secs)


def dtw_recognition(space: ProtoSymbolSpace, train: list[Clip], test: list[Clip]) -> RecognitionResult:
    """1-NN DTW baseline (dtw-python) on the same features."""
    from dtw import dtw

    enc = lambda c: space.features.encode(c.resample(space.params.fps), ("motion",))  # noqa: E731
    tr = [(enc(c), c.label) for c in train]
    pred, secs = [], []
    for c in test:
        x = enc(c)
        t0 = time.perf_counter()
        best, label = np.inf, None
        for y, lab in tr:
            d = dtw(x, y, distance_only=True).normalizedDistance
            if d < best:
                best, label = d, lab
        secs.append(time.perf_counter() - t0)
        pred.append(label)
    return _summarise("1-NN DTW (dtw-python)", [c.label for c in test], pred, secs)
