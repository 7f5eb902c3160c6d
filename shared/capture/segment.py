"""Repetitions of the target motion found in one continuous take (thesis 4.5.1: "segmented into
meaningful portions by the author subjectively").

**Features.** Both clips are read as the position features of a proto-symbol space built on the
target (:class:`shared.pss.features.MotionFeatures`, group ``position``): every joint and end
site in the body's heading frame, in body lengths, and the root's height, swing and velocity,
so where the person stands or faces and how tall they are do not enter. Unlike a space's
z-scores, every channel keeps the same unit (body lengths), so a joint the target barely moves
is not magnified. Both are resampled to ``FPS``.

**Subsequence alignment** (:func:`subsequence_dtw`, a numba kernel): dynamic time warping of the
whole target against any stretch of the take (open begin and end; the symmetric steps with a
slope between 1/2 and 2: (1, 1) weighted 2, (1, 2) and (2, 1) weighted 3, so the cost divided by
``n + L`` is a mean per-frame distance, ``L`` the stretch's length, and every stretch lasts half
to twice the target). For every frame where a stretch may end, the
best stretch ending there and its normalised cost; a stretch must last ``SPEEDS`` times the
target's duration (a person may be slower or faster than the demonstration).

**Repetitions** are taken greedily: the stretch of lowest cost, then the next that overlaps no
repetition taken (or refused) by more than ``OVERLAP`` of its length, while the cost (measured
against the target's own spread, the mean distance of its frames from its mean pose) is below
``THRESHOLD``. Each stretch is then checked against a **cohort** of other motions (those given as
``background``, and standing still in the target's first or last pose): it is a repetition only
if its cost against the target is at most ``COHORT`` times its cost against the nearest other
motion (DTW with fixed ends, :func:`global_dtw`), so a rest or another motion is not cut into
repetitions because it happens to be near the target. ``COHORT`` was chosen by
``bench.segmentation`` on the tuning takes (HDM05 performer bd, targets of performer bk, cohort
of dg: the largest F1 with the fewest cuts of other motions) and is reported on takes it was not
chosen on. Each repetition's **confidence** is how far its cost is below the threshold and its
cohort ratio below twice ``COHORT``. The result says whether the take holds the expected number
of repetitions, fewer, more, or none: a different motion.

**The person's own template** (``SELF_TEMPLATE``): the repetition found that is most like the
target (lowest cohort ratio) becomes the template for a second search, since a person's
repetitions are nearer to each other than to another body's demonstration; its result stands
when it finds that repetition again. Chosen on the tuning takes (F1 0.35 -> 0.41 at the same one
cut of another motion).

Measured (``bench/results/segmentation.json``): the same performer's repetitions are found with
F1 0.80 and a median boundary error of 125 ms; another performer's with F1 0.56 (258 ms, 4
stretches of other motions cut); a game studio's styles of one content, F1 0.04. The goals (F1 >= 0.95, 100 ms, no other motion ever
cut) are not met: a person's repetitions differ from another person's demonstration more than
raw joint positions can tell from another motion.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from shared.clip import Clip
from shared.compiled import kernel
from shared.errors import BadInput

FPS = 30.0  # both clips are compared at this rate
SPEEDS = (0.5, 2.0)  # a repetition lasts this many times the target's duration (the steps' slopes)
OVERLAP = 0.2  # a repetition may overlap one already taken by this share of its length
THRESHOLD = 2.5  # cost / the target's spread above which a stretch is not the target
COHORT = 0.7  # a stretch's cost against the target / against the nearest other motion, at most
MAX_CHECKS = 64  # stretches checked against the other motions, at most (bounded work)
SELF_TEMPLATE = True  # find the other repetitions with the person's own repetition most like the target


@kernel(cache=True, nogil=True)
def subsequence_dtw(cost):
    """Open-begin, open-end DTW of the target (rows) against the take (columns) on a cost matrix
    ``cost`` (n, m): per end column, the accumulated cost of the best alignment of the whole
    target ending there and the column where it starts."""
    n, m = cost.shape
    inf = np.inf
    acc = np.full((n, m), inf)
    start = np.zeros((n, m), np.int64)
    for j in range(m):
        acc[0, j] = 2.0 * cost[0, j]
        start[0, j] = j
    for i in range(1, n):
        for j in range(1, m):
            c = cost[i, j]
            best = acc[i - 1, j - 1] + 2.0 * c
            s = start[i - 1, j - 1]
            if j >= 2:
                two = acc[i - 1, j - 2] + 2.0 * cost[i, j - 1] + c
                if two < best:
                    best, s = two, start[i - 1, j - 2]
            if i >= 2:
                down = acc[i - 2, j - 1] + 2.0 * cost[i - 1, j] + c
                if down < best:
                    best, s = down, start[i - 2, j - 1]
            acc[i, j] = best
            start[i, j] = s
    return acc[n - 1].copy(), start[n - 1].copy()


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


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.sqrt(np.maximum(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=-1), 0.0)))


@dataclass
class Repetition:
    start: float  # seconds from the take's start
    end: float
    cost: float  # normalised DTW cost / the target's spread
    confidence: float
    cohort: float | None = None  # the cost against the target / against the nearest other motion

    def to_dict(self) -> dict:
        return {k: None if v is None else round(v, 4) for k, v in asdict(self).items()}


@dataclass
class Segmentation:
    repetitions: list[Repetition]
    expected: int | None
    threshold: float
    best_other: float | None = None  # the lowest cost of a stretch not taken (how close the next one came)
    notes: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        n = len(self.repetitions)
        if n == 0:
            return "not the target: no stretch of the take is close enough to it"
        if self.expected is None or n == self.expected:
            return f"{n} repetition(s) found"
        return f"{'fewer' if n < self.expected else 'more'} repetitions than expected: {n} found, {self.expected} expected"

    def cut(self, take: Clip) -> list[Clip]:
        """The repetitions as clips cut from ``take`` (at its own frame rate)."""
        out = []
        for k, r in enumerate(self.repetitions, 1):
            part = take.frames(int(round(r.start * take.fps)), int(round(r.end * take.fps)))
            out.append(part.with_data(part.data, name=f"rep{k}"))
        return out

    def to_dict(self) -> dict:
        return {"repetitions": [r.to_dict() for r in self.repetitions], "expected": self.expected,
                "threshold": self.threshold, "verdict": self.verdict, "notes": list(self.notes),
                "best_other": None if self.best_other is None else round(self.best_other, 4)}


def _positions(features, clip: Clip) -> np.ndarray:
    """The clip's position features in body lengths (the space's z-scores undone)."""
    x = features.encode(clip, ("position",))[:, features.feature_indices("position")]
    return x * features.position_scale + features.position_mean


def features_of(target: Clip, clips: list[Clip], fps: float = FPS) -> list[np.ndarray]:
    """The position features (module docstring) of the target and each clip, at ``fps``, all
    read on the target's skeleton."""
    from shared.pss.features import MotionFeatures

    if target.skeleton is None or any(c.skeleton is None for c in clips):
        raise BadInput("segmentation needs clips with a skeleton (AMC, BVH or NPZ from them)", field="clip")
    feats = MotionFeatures.for_clips([target], sensor=False)
    if not feats.has_position:
        raise BadInput("the target's skeleton gives no joint positions to compare", field="target")
    # velocities beside the positions were tried (weight 0.3 s): with the cohort check they turned
    # away nearly every repetition across performers (HDM05 dg takes, bk targets)
    return [_positions(feats, c.resample(fps)) for c in [target, *clips]]


def _spread(x: np.ndarray) -> float:
    return float(np.mean(np.linalg.norm(x - x.mean(axis=0), axis=1)))


def _find(a: np.ndarray, b: np.ndarray, others: list, threshold: float, cohort: float):
    """Stretches of ``b`` that are repetitions of ``a`` (module docstring): (start, end, cost,
    cohort ratio) in frames, and the lowest cost of a stretch not taken."""
    spread = _spread(a)
    others = others + [(np.repeat(a[k:k + 1], len(a), axis=0), spread) for k in (0, len(a) - 1)]
    n, m = len(a), len(b)
    acc, start = subsequence_dtw(_distances(a, b))
    length = np.arange(m) - start + 1
    norm = np.where(np.isfinite(acc), acc / (n + length) / spread, np.inf)
    taken: list[tuple[int, int, float, float]] = []
    refused: list[tuple[int, int]] = []  # stretches the cohort check found nearer another motion
    best_other = None
    checks = 0
    for j in np.argsort(norm, kind="stable"):
        c = float(norm[j])
        if not np.isfinite(c) or c > threshold:
            best_other = c if np.isfinite(c) else best_other
            break
        s = int(start[j])
        span = j - s + 1
        if any(min(j, e) - max(s, b0) + 1 > OVERLAP * span for b0, e, *_ in taken + refused):
            continue
        checks += 1
        if checks > MAX_CHECKS:
            break
        stretch = b[s:j + 1]
        nearest = min(global_dtw(_distances(o, stretch)) / sp for o, sp in others)
        ratio = c / max(nearest, 1e-12)
        if ratio > cohort:
            refused.append((s, int(j)))
            best_other = c if best_other is None else best_other
            continue
        taken.append((s, int(j), c, ratio))
    return sorted(taken), best_other


def segment(take: Clip, target: Clip, expected: int | None = 5, background: list[Clip] | None = None,
            threshold: float = THRESHOLD, cohort: float = COHORT, fps: float = FPS) -> Segmentation:
    """The repetitions of ``target`` in ``take`` (module docstring); ``background``: other
    motions a stretch must be nearer to the target than (the cohort check)."""
    if take.n_frames < 2 or target.n_frames < 2:
        raise BadInput("the take and the target need at least two frames each")
    if expected is not None and expected < 1:
        raise BadInput(f"expected repetitions must be at least 1, got {expected}", field="expected")
    background = list(background or [])
    a, b, *others = features_of(target, [take, *background], fps)
    if _spread(a) < 1e-6:
        raise BadInput("the target does not move: nothing to find", field="target")
    others = [(o, _spread(o)) for o in others if len(o) > 1 and _spread(o) > 1e-6]
    taken, best_other = _find(a, b, others, threshold, cohort)
    if SELF_TEMPLATE and taken:
        # the person's own repetition most like the target becomes the template: their other
        # repetitions are nearer to it than to the demonstration of another body
        s0, e0, *_ = min(taken, key=lambda t: t[3])
        seed = b[s0:e0 + 1]
        if _spread(seed) > 1e-6:
            own, _ = _find(seed, b, others, threshold, cohort)
            if any(s <= s0 + OVERLAP * (e0 - s0) and e >= e0 - OVERLAP * (e0 - s0) for s, e, *_ in own):
                taken = own
    reps = []
    for s_, e, c, ratio in taken:
        conf = min(1.0 - c / threshold, 1.0 - ratio / (2 * cohort))
        reps.append(Repetition(s_ / fps, (e + 1) / fps, c, max(0.0, conf), ratio))
    return Segmentation(reps, expected, threshold, best_other)
