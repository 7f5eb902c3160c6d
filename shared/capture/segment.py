"""Repetitions of the target motion found in one continuous take (thesis 4.5.1: "segmented into
meaningful portions by the author subjectively").

**Features.** Both clips are read as the position features of a proto-symbol space built on the
target (:class:`shared.pss.features.MotionFeatures`, group ``position``): every joint and end
site in the body's heading frame, in body lengths, and the root's height, so where the person
stands or faces and how tall they are do not enter (the root's rates and up vector, noisy at
rest, are left out). Each point weighs the square root of its bone's length (a knee counts more
than a finger: a hand has seven points where a leg has four). Both are resampled to ``FPS``.

**Movements and rests.** A frame rests when its joints move slower than ``REST_SHARE`` of the
target's mean speed (the displacement over ``SMOOTH`` seconds, so the jitter of a pose held still
cancels); a rest lasts at least ``REST_MIN``. The stretches between rests are the movements; a
repetition spans one to ``MAX_JOIN`` consecutive movements (a motion may pause inside).

**Shapes and postures.** A stretch is compared as a shape (:func:`shape`): its mean pose taken
away (where a person holds the body) and its spread scaled to one (how large they make the
motion), so a person's posture and amplitude, which differ from the demonstration's, do not
decide alone; the distance of the two mean poses (in the target's spreads) is added with the
weight ``POSTURE`` (a squat and a reach to the floor have much the same shape, not the same
posture). A stretch smaller than ``MIN_AMPLITUDE`` of the target's spread (a shift of weight, a
step into the next pose) is no repetition. Two motions of tempos the DTW's slopes cannot join
are compared at the nearest tempo they can (they used to be infinitely far apart, so a stretch
no other motion could join passed the cohort check below with a ratio of 0).

**Alignment.** Each movement (or run of movements) is aligned with the whole target by dynamic
time warping with the symmetric steps of slope 1/2 to 2 (:func:`shared.capture.align.subsequence_dtw`, a numba
kernel; (1, 1) weighted 2, (1, 2) and (2, 1) weighted 3, so a cost divided by ``n + L`` is a mean
per-frame distance), its ends free within ``SLACK`` seconds of the movement's ends (the way from
a rest into the first pose is movement, not the motion). A movement longer than twice the
target (repetitions without a rest between) gives every end's best stretch inside it.

**Decision.** Candidates are taken in order of their cost against the target (:func:`shared.capture.align.global_dtw`
of the two shapes plus the postures' distance), overlapping none taken by more than ``OVERLAP``,
while the cost is at most ``MAX_COST`` and at most ``COHORT`` times the cost against the nearest
of the other motions (the ``background`` clips), so a motion near the target because it is near
everything is not cut. **The person's own repetitions** then find the others (``OWN``): once a
repetition is taken, the take holds the target, and a stretch not yet taken is one more when it
is nearer to the target than to any other motion with a cost up to ``SECOND_COST``, or at most
``OWN`` times as far from the person's repetition most like the target as the taken ones are,
and nearer to that one than to any other motion (a person repeats their own way of doing the
motion, which differs from the demonstration's). Each repetition's **confidence** is how far its
cohort ratio is below ``COHORT``. The result says whether the take holds the expected number of
repetitions, fewer, more, or none: a different motion. The settings are a :class:`Settings`.

**Where the rests mislead** (``Settings.refine``, ``Settings.fill``): a person's rest can move
faster than ``REST_SHARE`` of the target's speed (a slow gesture, a swaying stance) and a pause
inside the motion slower, so a rest's ends can lie off the repetition's, or two repetitions and
the rest between them read as one movement. Once repetitions are taken (the take holds the
target), each is moved to the stretch around it (within half the target's length) where the
whole target aligns best without the rests (:func:`shared.capture.align.best_stretches`: every end's best start by
:func:`shared.capture.align.subsequence_dtw`, the take read in that repetition's own mean and spread), when it costs
at most ``REFINE`` of the repetition's cost and passes the same ratio; and when fewer than
expected were found, the take between them is searched the same way (read in the mean and spread
of the person's repetition most like the target), a stretch there passing as a first repetition
would or as near the person's own. Neither runs on a take where nothing was taken, so a take of
another motion is cut no more than before. (Searching the whole take without its rests from the
start cut 9 stretches of a jog as sneaking on the tuning takes: a part of a cyclic motion is
like many things.)

**With a proto-symbol space** (``space``: a space holding the target's motion and others, read
here or asked through the pss service; thesis eq. 2.6): the space decides instead of the cohort
when it holds at least ``SPACE_EXAMPLES`` (2) examples of the target's motion; a space that holds
it once knows nothing of how far a repetition may lie from it, so other motions given (the
``background``) then decide by the cohort check, and without them the space still does (a note
says which).
A stretch is a repetition when its cost against the target is at most ``SPACE_COST`` (the own
repetitions' limits as above) and the space, abstracting the stretch into an HMM, finds the
target's motion nearer than any other (:class:`shared.capture.naming.Named`: the recognition
distance (eq. 2.4) to the target's nearest proto-symbol over that to the nearest other's, at
most ``SPACE_RATIO``); a repetition's confidence is how far that ratio is below its limit. The
target's motion in the space is its label, a given one, or what the space recognises the target
as (said in a note). Another performer's hops and kicks, whose first repetitions cost more than
``MAX_COST`` against the target (1.08 and 1.14) and which a larger one would not tell from other
motions by the cohort (the hops' cohort ratios 0.90-0.99; larger costs cut 4-8 stretches of other
motions on the tuning takes), are named by a space of two other performers' motions.

The settings were chosen by ``bench.segmentation`` on tuning takes only (HDM05 performers bd and
bk, each one's takes against the other's targets, the other motions of the target's performer;
performer dg never seen there; ``REST_SHARE`` 0.1-0.25 and ``SLACK`` 0.4-0.9 s were tried there
too): the largest F1 among the settings that cut the fewest repetitions from takes of other
motions. They are reported on takes they were not chosen on (performer dg, a game studio's
styles, a CMU performance): ``bench/results/segmentation.json``. Measured there, no take of another
motion cut on any of them given the other motions (22 stretches given none; before the postures, the
minimum amplitude, the tempo fix and the own repetitions: 6, 3, 1, 3 cut); another performer's
repetitions (dg's takes, bk's targets) F1 0.82 with a median boundary error of 83 ms (every
repetition of 9 classes found, none of dg's hops and kicks: their first repetition costs more than
``MAX_COST``; was 0.92 with 6 cuts); the same performer's F1 0.98 (79 ms); a CMU performance read
from its two unit conventions F1 1.00 (17 ms); a game studio's styles of one gesture against its
'normal' style F1 0.19 (517 ms: styles as far apart as 'feminine' and 'giant', not one person's repetitions);
the studio's files with one performer's repetitions (each gesture's own clip, time-warped, five
styles) F1 1.00, 0-33 ms (0.94-1.00 before ``refine`` and ``fill``, which were chosen on the
tuning takes and nine other styles of the studio: mean F1 0.910 -> 0.974 there, no cut).
Goals (F1 0.95, 100 ms, no other motion cut): met on the same performer's, the studio's own-clip
and the CMU takes; the F1 across performers and styles is not.

With a space, chosen on the same tuning takes each with a space of its targets' performer
(``SPACE_GRID`` of ``bench.segmentation``; ``SPACE_COST`` 1.1 and 1.15 tie there, F1 0.926 with no
cut, and the tie goes to the larger: a rule written after both were reported, below) and reported
on dg's takes: with a space of bd and bk F1 1.00, median boundary error 92 ms, no other motion cut
(with bk's space alone, as tuned: the same); the same performer 0.99; the game studio's styles
0.14 (the studio's space: its 'normal' clips and two styles of each content). CMU's windows with a
space of one 2-second clip per window, all of one dance: F1 1.00 but 4 stretches of other windows
cut while the space decided (it named them window0 where the cohort check refused them); since
``SPACE_EXAMPLES`` (written after that report, for it: the tuning spaces hold 2-12 examples of every
motion, so the choice above is unchanged) the cohort decides there. At ``SPACE_COST`` 1.1 dg's
kicks (costs 1.13-1.14) are not found: F1 0.91 across performers.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from shared.capture.align import best_stretches, distances, global_dtw, subsequence_dtw
from shared.capture.naming import SPACE_RATIO, Named, SpaceNamer, target_label
from shared.deadline import check_time
from shared.errors import BadInput
from shared.motion.clip import Clip, time_normalised

FPS = 30.0  # both clips are compared at this rate
SPEEDS = (0.5, 2.0)  # a repetition lasts this many times the target's duration (the steps' slopes)
OVERLAP = 0.2  # a repetition may overlap one already taken by this share of its length
COHORT = 0.9  # a stretch's cost against the target / against the nearest other motion, at most
MAX_COST = 0.95  # a stretch's cost against the target (as shapes: a mean distance in spreads), at most
MAX_CHECKS = 64  # stretches checked against the other motions, at most (bounded work)
REST_SHARE = 0.15  # a frame rests when its speed is below this share of the target's mean speed
REST_MIN = 0.3  # seconds: a rest lasts at least this long (a shorter pause belongs to the motion)
SMOOTH = 0.3  # seconds: the speed is a displacement over this window
MAX_JOIN = 4  # a repetition spans this many stretches of movement at most (pauses inside a motion)
SLACK = 0.6  # seconds a repetition's ends may lie from its stretch of movement's ends
AMPLITUDE_FLOOR = 0.25  # a stretch smaller than this share of the target's spread is not scaled up further
ROOT_TERMS = 6  # the position group's last columns left out: the root's up vector, velocities and yaw rate
READ_BLOCK = 4096  # a take's features and speed are read in blocks of this many frames (bounded memory)
MIN_AMPLITUDE = 0.4  # a stretch smaller than this share of the target's spread is no repetition
POSTURE = 0.25  # the weight of the mean poses' distance in a comparison (Settings.posture)
OWN = 1.5  # the person's own repetitions find the others (Settings.own; 0: off)
SECOND_COST = 1.4  # once the take holds the target, a stretch's cost against it, at most (with OWN on)
SPACE_COST = 1.15  # with a proto-symbol space, a first repetition's cost against the target, at most (Settings.space_cost)
#: the space decides only when it holds at least this many examples (proto-symbols) of the target's motion;
#: with fewer, and other motions given, the cohort check decides (module docstring)
SPACE_EXAMPLES = 2
REFINE = 0.5  # a repetition moved to a stretch around it that costs at most this share of its cost (Settings.refine)
FILL = True  # fewer repetitions than expected: the take between them searched without its rests (Settings.fill)
REST_AFTER = 0.2  # seconds of take after the last expected repetition before a live take ends (until_repeated)


@dataclass
class Repetition:
    start: float  # seconds from the take's start
    end: float
    cost: float  # DTW cost against the target, both as shapes (a mean distance per frame, in spreads)
    confidence: float
    cohort: float | None = None  # the ratio it passed: its cost against the target / against the nearest other
    # motion, or with a proto-symbol space its recognition distance to the target's motion / to the nearest other

    def to_dict(self) -> dict:
        return {k: None if v is None else round(v, 4) for k, v in asdict(self).items()}


@dataclass
class Segmentation:
    repetitions: list[Repetition]
    expected: int | None
    cohort: float
    refused: float | None = None  # the lowest cohort ratio of a stretch refused (how close the next one came)
    notes: list[str] = field(default_factory=list)
    closest: float | None = None  # the lowest cost of a stretch against the target (None: no stretch to compare)
    max_cost: float = MAX_COST  # the largest cost of a first repetition
    space: str | None = None  # the target's motion in the proto-symbol space that decided (None: the cohort did)

    @property
    def verdict(self) -> str:
        """What was found, and when nothing was, the test every movement failed."""
        n = len(self.repetitions)
        if n == 0:
            if self.closest is None:
                return "not the target: no movement in the take is as long and as large as a repetition of it"
            if self.closest > self.max_cost:
                return (f"not the target: the movement most like it differs from it by {self.closest:.2f}, more than a "
                        f"first repetition may ({self.max_cost:g})")
            if self.space is not None:
                return (f"not the target: the space names every movement like it another motion than {self.space!r} "
                        f"(at best {self.refused or 0.0:.2f} of the distance to the nearest other, at most {self.cohort:g})")
            return (f"not the target: every movement like it is nearer to another motion (at best "
                    f"{self.refused or 0.0:.2f} of the distance, at most {self.cohort:g})")
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
                "cohort": self.cohort, "verdict": self.verdict, "notes": list(self.notes), "space": self.space,
                "refused": None if self.refused is None else round(self.refused, 4),
                "closest": None if self.closest is None else round(self.closest, 4)}


def _positions(features, clip: Clip) -> np.ndarray:
    """The clip's joints in the body's heading frame and the root's height, in body lengths (the
    position group's z-scores undone, its root rates and up vector left out)."""
    x = features.positions(clip) * features.position_scale + features.position_mean  # (another studio's skeleton too)
    return np.ascontiguousarray(x[:, :-ROOT_TERMS])


class Reader:
    """The target's feature map, built once: reads any clip on the target's skeleton as the
    position features (module docstring), weighted, at ``fps``; ``target`` its own, read once."""

    def __init__(self, target: Clip, fps: float = FPS):
        from shared.pss.features import MotionFeatures

        if target.skeleton is None:
            raise BadInput("segmentation needs clips with a skeleton (AMC, BVH or NPZ from them)", field="clip")
        self.feats = MotionFeatures.for_clips([target], sensor=False)
        if not self.feats.has_position:
            raise BadInput("the target's skeleton gives no joint positions to compare", field="target")
        self.fps, self.w = fps, np.sqrt(_weights(self.feats))
        self.target = self.read(target)

    def read(self, clip: Clip) -> np.ndarray:
        if clip.skeleton is None:
            raise BadInput("segmentation needs clips with a skeleton (AMC, BVH or NPZ from them)", field="clip")
        clip = clip.resample(self.fps)
        edges = list(range(0, clip.n_frames, READ_BLOCK)) + [clip.n_frames]
        if len(edges) > 2 and edges[-1] - edges[-2] < 16:  # no block too short for the features' rates
            del edges[-2]
        return np.concatenate([_positions(self.feats, clip.frames(s, e)) for s, e in zip(edges, edges[1:])]) * self.w


def features_of(target: Clip, clips: list[Clip], fps: float = FPS) -> list[np.ndarray]:
    """The position features (module docstring) of the target and each clip, at ``fps``, all
    read on the target's skeleton."""
    reader = Reader(target, fps)
    return [reader.target, *(reader.read(c) for c in clips)]


def _weights(feats) -> np.ndarray:
    """Each column's weight: its point's bone length over the body's height (a finger's point
    weighs less than a knee's), one for the root's height."""
    sk = feats.skeleton
    lengths = {j.name: float(np.linalg.norm(j.offset)) for j in sk.joints}
    lengths.update({f"{j.name}.end": float(np.linalg.norm(j.end)) for j in sk.joints if j.end is not None})
    names = feats.position_feature_names[:-ROOT_TERMS - 1]
    bones = [lengths.get(n[4:n.index(")")], 0.0) for n in names]
    w = np.asarray(bones) / max(max(bones), 1e-9)
    return np.append(w, 1.0)


def _spread(x: np.ndarray) -> float:
    """The mean distance of a stretch's frames from its mean pose."""
    return float(np.mean(np.linalg.norm(x - x.mean(axis=0), axis=1)))


def shape(x: np.ndarray, floor: float = 1e-6) -> np.ndarray:
    """A stretch as a shape: its mean pose taken away (where a person holds the body) and its
    spread scaled to one (how large they make the motion), the spread floored at ``floor``."""
    y = x - x.mean(axis=0)
    return y / max(_spread(y), floor)


def speed(x: np.ndarray, fps: float) -> np.ndarray:
    """Per-frame speed of the body's joints (body lengths per second): the displacement over
    ``SMOOTH`` seconds centred on the frame, so the jitter of a pose held still cancels while a
    movement does not."""
    h = max(int(round(SMOOTH * fps / 2)), 1)
    out = np.empty(len(x))
    for k in range(0, len(x), READ_BLOCK):  # in blocks: a long take's differences are not held whole
        idx = np.arange(k, min(k + READ_BLOCK, len(x)))
        lo, hi = np.clip(idx - h, 0, len(x) - 1), np.clip(idx + h, 0, len(x) - 1)
        out[idx] = np.linalg.norm(x[hi] - x[lo], axis=1) / np.maximum(hi - lo, 1) * fps
    return out


def movements(b: np.ndarray, level: float, fps: float) -> list[tuple[int, int]]:
    """The stretches of ``b`` between rests, (start, end) in frames (end exclusive): a rest is a run
    of frames slower than ``level`` lasting at least ``REST_MIN`` (or touching the take's ends)."""
    still = np.concatenate([[False], speed(b, fps) < level, [False]])
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    min_rest = max(int(round(REST_MIN * fps)), 1)
    rests = [(int(s), int(e)) for s, e in zip(edges[::2], edges[1::2])
             if e - s >= min_rest or s == 0 or e == len(b)]
    out, prev = [], 0
    for s, e in rests:
        if s > prev:
            out.append((prev, s))
        prev = e
    if prev < len(b):
        out.append((prev, len(b)))
    return out


def _aligned(a: np.ndarray, b: np.ndarray, s: int, e: int, slack: int, floor: float) -> list[tuple[int, int]]:
    """Where the whole target aligns best with the movement ``b[s:e]`` (both as shapes, the
    movement's mean and spread used for the frames around it): stretches starting within
    ``slack`` frames of ``s`` and ending within ``slack`` of ``e``; for a movement longer than
    the target's slowest repetition (repetitions without a rest between), every end's best
    stretch inside it. (start, end exclusive) in frames."""
    lo, hi = max(s - slack, 0), min(e + slack, len(b))
    part = b[s:e]
    window = (b[lo:hi] - part.mean(axis=0)) / max(_spread(part), floor)
    cost = distances(a, window)
    n = len(a)
    several = e - s > SPEEDS[1] * n + 2 * slack  # several repetitions in one movement: start anywhere
    if not several:
        cost[0, s + slack - lo + 1:] = np.inf  # the target's first frame within slack of the start
    acc, start = subsequence_dtw(cost)
    norm = np.where(np.isfinite(acc), acc / (n + np.arange(hi - lo) - start + 1), np.inf)
    if several:
        return [(lo + int(start[j]), lo + int(j) + 1) for j in np.flatnonzero(np.isfinite(norm))]
    ends = np.arange(hi - lo)
    ok = np.isfinite(norm) & (ends >= e - slack - lo - 1)
    if not ok.any():
        return []
    j = int(np.argmin(np.where(ok, norm, np.inf)))
    return [(lo + int(start[j]), lo + j + 1)]


@dataclass(frozen=True)
class Settings:
    """How a take is cut (module docstring): chosen by ``bench.segmentation`` on tuning takes."""

    cohort: float = COHORT  # a stretch's cost against the target / against the nearest other motion, at most
    max_cost: float = MAX_COST  # the first repetition's cost against the target, at most
    posture: float = POSTURE  # the weight of the mean poses' distance (in the template's spreads) in a cost
    own: float = OWN  # the person's own repetitions find the others within this many times their mutual cost (0: off)
    second_cost: float = SECOND_COST  # with ``own`` on, the others' cost against the target, at most
    min_amplitude: float = MIN_AMPLITUDE  # a stretch smaller than this share of the target's spread is no repetition
    space_cost: float = SPACE_COST  # with a proto-symbol space, the first repetition's cost against the target, at most
    space_ratio: float = SPACE_RATIO  # with a space, its distance ratio (target's motion / nearest other), at most
    refine: float = REFINE  # a repetition moved to a stretch around it costing at most this share of its cost (0: off)
    fill: bool = FILL  # fewer repetitions than expected: the take between them searched without its rests


class _Template:
    """A motion a stretch is compared with: its shape (:func:`shape`), its mean pose and spread."""

    def __init__(self, x: np.ndarray, floor: float = 1e-6, posture: float = 0.0):
        self.shape, self.mean, self.spread = shape(x, floor), x.mean(axis=0), max(_spread(x), floor)
        self.posture = posture

    def cost(self, stretch: _Template) -> float:
        """The distance of a stretch from this motion: the DTW cost of their shapes (a stretch of a
        tempo the slopes cannot join resampled to the nearest they can) plus ``posture`` times the
        distance of their mean poses in this motion's spreads (where the body is held tells a
        squat from a reach to the floor when their shapes agree)."""
        other = stretch.shape
        n, m = len(self.shape), len(other)
        if not (n + 1) // 2 < m < 2 * n - 1:  # tempos the slopes cannot join: the other's resampled to the nearest they can
            other = time_normalised(other, int(np.clip(m, (n + 1) // 2 + 1, 2 * n - 2)))
        c = global_dtw(distances(self.shape, other))
        return c + self.posture * float(np.linalg.norm(self.mean - stretch.mean)) / self.spread if self.posture else c


def _find(a: np.ndarray, b: np.ndarray, others: list[np.ndarray], how: Settings, fps: float,
          by_space: Named | None = None, expected: int | None = None):
    """Repetitions of the target ``a`` among the movements of the take ``b`` (module docstring):
    (start, end exclusive, cost, ratio) in frames, the lowest ratio refused and the lowest cost of
    any stretch. The ratio is the cohort's (cost against the target / against the nearest other
    motion, at most ``how.cohort``) or, with a proto-symbol space (``by_space``), the space's
    (:class:`shared.capture.naming.Named`, below 1), which then decides instead of the cohort."""
    spread = _spread(a)
    floor = AMPLITUDE_FLOOR * spread
    moves = movements(b, REST_SHARE * float(np.mean(speed(a, fps))), fps)
    target = _Template(a, posture=how.posture)
    cohort_templates = [_Template(o, posture=how.posture) for o in others]
    slack = int(round(SLACK * fps))
    n = len(a)
    stretches = set()
    for i in range(len(moves)):
        check_time()  # a long take is long work: a request stops here past its time limit
        for k in range(i, min(i + MAX_JOIN, len(moves))):
            s, e = moves[i][0], moves[k][1]
            if k > i and e - s > SPEEDS[1] * n + 2 * slack:
                break
            if e - s + 2 * slack >= SPEEDS[0] * n:
                stretches.update(_aligned(target.shape, b, s, e, slack, floor))
    scored = _score(a, b, stretches, target, floor, how)
    near: dict[tuple[int, int], float] = {}

    def nearest(s: int, e: int, stretch: _Template) -> float:
        """The stretch's cost against the nearest other motion (each stretch compared once)."""
        if (s, e) not in near:
            near[s, e] = max(min((o.cost(stretch) for o in cohort_templates), default=np.inf), 1e-12)
        return near[s, e]

    def ratio(s: int, e: int, stretch: _Template, c: float) -> float:
        """The stretch's ratio when its cost against the target (or the person's own repetition) is ``c``."""
        return by_space.ratio(s, e) if by_space is not None else c / nearest(s, e, stretch)

    limit = how.cohort if by_space is None else by_space.limit
    first = how.max_cost if by_space is None else how.space_cost
    cands = []  # (cost, start, end, ratio, template)
    for c, s, e, stretch in scored:
        if not c <= first:
            break
        cands.append((c, s, e, ratio(s, e, stretch, c), stretch))
    taken = _greedy(cands, [x[0] for x in cands], lambda x: x[3] <= limit)
    if taken and how.own:
        taken += _own(taken, scored, ratio, limit, how)
        if how.refine > 0:
            taken = _refined(a, b, taken, target, floor, how, ratio, limit)
        if how.fill and expected is not None and len(taken) < expected:
            # a stretch between them passes as a first repetition would (``first``) or near the person's own
            taken += _own(taken, _between(a, b, taken, target, floor, how), ratio, limit, replace(how, second_cost=first))
    refused = min((x[3] for x in cands if x[3] > limit), default=None)
    return sorted((x[1], x[2], x[0], x[3]) for x in taken), refused, (scored[0][0] if scored else None)


def _score(a: np.ndarray, b: np.ndarray, stretches, target: _Template, floor: float, how: Settings) -> list:
    """The stretches a repetition may be (as long as the DTW's slopes allow, as large as
    ``min_amplitude``), each with its cost against the target, lowest first, the ``MAX_CHECKS``
    lowest: (cost, start, end, template). Only their templates are kept: a take of 100,000 frames has
    about 100,000 stretches, whose templates held together took one segmentation to 5.6 GB."""
    n, scored = len(a), []
    for k, (s, e) in enumerate(stretches):
        if k % 1000 == 999:
            check_time()
        if not SPEEDS[0] * n <= e - s <= SPEEDS[1] * n:
            continue
        if _spread(b[s:e]) < how.min_amplitude * target.spread:  # a shift of weight, a step into the next pose
            continue
        scored.append((target.cost(_Template(b[s:e], floor, how.posture)), s, e))
    return [(c, s, e, _Template(b[s:e], floor, how.posture)) for c, s, e in sorted(scored)[:MAX_CHECKS]]


def _refined(a: np.ndarray, b: np.ndarray, taken: list, target: _Template, floor: float, how: Settings,
             ratio, limit: float) -> list:
    """Each repetition taken moved to the stretch around it (within half the target's length of
    its ends; :func:`shared.capture.align.best_stretches`, the take read in the repetition's own mean and spread) that costs
    least against the target, when it costs at most ``how.refine`` of the repetition's cost, passes
    the same ratio (at most ``limit``; one check a repetition) and overlaps no other repetition by more than ``OVERLAP``: the ends a rest gave
    are only as good as the rest (a person's rest can move faster than ``REST_SHARE`` of the
    target's speed, and a pause inside the motion be slower)."""
    w, out = len(a) // 2, list(taken)
    for k in np.argsort([x[0] for x in taken], kind="stable"):
        check_time()
        c, s, e, _, stretch = out[k]
        lo, hi = max(s - w, 0), min(e + w, len(b))
        others = [y for i, y in enumerate(out) if i != k]
        for cost, s2, e2, moved in _score(a, b, best_stretches(target.shape, b, lo, hi, stretch.mean, stretch.spread),
                                          target, floor, how):
            if cost > how.refine * c:
                break
            if any(min(e2, y[2]) - max(s2, y[1]) > OVERLAP * (e2 - s2) for y in others):
                continue
            r = ratio(s2, e2, moved, cost)  # (one check a repetition: with a space, each is an HMM's training)
            if r <= limit:
                out[k] = (cost, s2, e2, r, moved)
            break
    return out


def _between(a: np.ndarray, b: np.ndarray, taken: list, target: _Template, floor: float, how: Settings) -> list:
    """Stretches of the take between the repetitions taken, found without its rests (a person's
    rests can move faster than ``REST_SHARE`` of the target's speed, and a pause inside the motion
    slower; :func:`shared.capture.align.best_stretches`), the take read in the mean and spread of the person's repetition most
    like the target."""
    n = len(a)
    anchor = min(taken, key=lambda x: x[3])[4]
    spans, prev, stretches = sorted((x[1], x[2]) for x in taken), 0, []
    for s, e in [*spans, (len(b), len(b))]:
        if s - prev >= SPEEDS[0] * n:
            check_time()
            stretches += best_stretches(target.shape, b, prev, s, anchor.mean, anchor.spread)
        prev = max(prev, e)
    return _score(a, b, stretches, target, floor, how)


def _own(taken: list, scored: list, ratio, limit: float, how: Settings) -> list:
    """Once the take holds the target (a repetition taken), the others are looked for more widely
    among the ``scored`` stretches (bounded: ``MAX_CHECKS``): one not yet taken is a repetition
    when it is nearer to the target than to any other motion (by the cohort ratio) with a cost up
    to ``second_cost``, or when it is at most ``own`` times as far from the person's repetition
    most like the target as the other taken ones are on average (as ``max_cost`` when there are
    none) and nearer to that one than to any other motion (with a space: and the space names it
    the target's motion). Its ratio (``ratio(s, e, stretch, cost)``, at most ``limit``) is the one
    it passed. The repetitions found this way, none overlapping another or a taken one."""
    anchor = min(taken, key=lambda x: x[3])
    own = anchor[4]
    ref = [own.cost(x[4]) for x in taken if x is not anchor]
    own_limit = how.own * (float(np.mean(ref)) if ref else how.max_cost)
    extra = []
    for c, s, e, stretch in scored:
        if any(min(e, y[2]) - max(s, y[1]) > OVERLAP * (e - s) for y in taken):
            continue
        d = own.cost(stretch)
        if c > how.second_cost and d > own_limit:
            continue
        passed = min(ratio(s, e, stretch, c) if c <= how.second_cost else np.inf,
                     ratio(s, e, stretch, d) if d <= own_limit else np.inf)
        if passed <= limit:
            extra.append((c, s, e, passed, stretch, min(c, d)))
    return [x[:5] for x in _greedy(extra, [x[5] for x in extra], lambda x: True)]


def _greedy(cands: list, key: list[float], accept) -> list:
    """Candidates taken in the order of ``key`` if ``accept``-ed and overlapping none taken by
    more than ``OVERLAP`` of their length."""
    taken: list[tuple] = []
    for k in np.argsort(key, kind="stable"):
        x = cands[k]
        if not accept(x):
            continue
        s, e = x[1], x[2]
        if any(min(e, y[2]) - max(s, y[1]) > OVERLAP * (e - s) for y in taken):
            continue
        taken.append(x)
    return taken


def segment(take: Clip, target: Clip, expected: int | None = 5, background: list[Clip] | None = None,
            settings: Settings | None = None, fps: float = FPS, reader: Reader | None = None,
            space=None, label: str | None = None, named: dict | None = None) -> Segmentation:
    """The repetitions of ``target`` in ``take`` (module docstring); ``background``: other
    motions a stretch must be nearer to the target than (the cohort check); ``settings``: the
    defaults (:class:`Settings`) unless given; ``reader``: the target's :class:`Reader` when the
    caller has one (checks of a growing take). ``space``: a proto-symbol space (or a namer like
    :class:`shared.capture.naming.SpaceNamer`) holding the target's motion (``label``, or
    :func:`shared.capture.naming.target_label`) and others: a stretch is a repetition when the
    space's nearest motion for it is the target's (instead of the cohort check, the
    ``background`` then not used, when the space holds ``SPACE_EXAMPLES`` examples of the
    target's motion or no background is given; else the cohort check decides); ``named``: the
    space's ratios of the take's stretches kept by the caller across checks of a growing take."""
    how = settings or Settings()
    if take.n_frames < 2 or target.n_frames < 2:
        raise BadInput("the take and the target need at least two frames each")
    if expected is not None and expected < 1:
        raise BadInput(f"expected repetitions must be at least 1, got {expected}", field="expected")
    reader = reader or Reader(target, fps)
    a, b, *others = reader.target, *(reader.read(c) for c in [take, *(background or [])])
    if _spread(a) < 1e-6:
        raise BadInput("the target does not move: nothing to find", field="target")
    others = [o for o in others if len(o) > 1 and _spread(o) > 1e-6]
    by_space, notes = None, []
    if space is not None:
        namer = space if hasattr(space, "nearest") else SpaceNamer(space)
        name, note = target_label(namer, target, label)
        notes += [note] if note else []
        named_by = Named(namer, name, take, fps, how.space_ratio, named)  # (checks the space holds it and another)
        examples = sum(1 for lab in namer.labels if lab == name)
        if examples >= SPACE_EXAMPLES or not others:
            by_space, others = named_by, []
        else:
            notes.append(f"the space holds {examples} example of {name!r}, too few to tell how far a repetition may "
                         f"lie from it: the other motions given decide (the cohort check)")
    taken, best_refused, closest = _find(a, b, others, how, fps, by_space, expected)
    limit = how.cohort if by_space is None else by_space.limit
    reps = [Repetition(float(s / fps), float(e / fps), float(c), max(0.0, 1.0 - float(ratio) / limit), float(ratio))
            for s, e, c, ratio in taken]
    return Segmentation(reps, expected, limit, best_refused, notes=notes, closest=closest,
                        max_cost=how.max_cost if by_space is None else how.space_cost,
                        space=None if by_space is None else by_space.label)


#: a growing take's checks (:func:`until_repeated`): the defaults without ``fill``, which runs only when fewer than
#: expected are found (a check that finds them all finds what the whole cut would), not at every check
CHECKS = Settings(fill=False)


def until_repeated(target: Clip, expected: int, rest_after: float = REST_AFTER, background: list[Clip] | None = None,
                   space=None, label: str | None = None):
    """A check for :func:`shared.capture.stream.record`'s ``until``: the take ends once the
    ``expected`` repetitions of ``target`` are seen, with ``rest_after`` seconds of take after the
    last (a person done repeating, on a source that never stops). While the take's last
    ``rest_after`` seconds move (the person is still repeating) the check costs only their
    speed; the take is cut only once its end rests. The check keeps the take it last cut and what
    it found as ``enough.last`` (clip, segmentation) when that holds the expected repetitions: when it
    ends the take, that is the whole take, already cut. ``space``, ``label``: as :func:`segment`'s."""
    reader = Reader(target)
    level = REST_SHARE * float(np.mean(speed(reader.target, FPS)))
    named: dict = {}  # the space's ratios of the take's stretches, kept from check to check

    def enough(clip: Clip) -> str | None:
        if clip.duration < 1.0:
            return None
        tail = clip.frames(max(clip.n_frames - int(round((rest_after + SMOOTH) * clip.fps)) - 1, 0))
        v = speed(reader.read(tail), FPS)
        # a frame's speed spans SMOOTH / 2 either side: the last rest_after - SMOOTH / 2 of it rest
        if len(v) and v[-max(int(round((rest_after - SMOOTH / 2) * FPS)), 1):].max() >= level:
            return None
        seen = segment(clip, target, expected=expected, background=background, reader=reader, space=space, label=label,
                       named=named, settings=CHECKS)
        complete = len(seen.repetitions) >= expected
        enough.last = (clip, seen) if complete else None  # type: ignore[attr-defined]
        if complete and clip.duration - seen.repetitions[-1].end >= rest_after:
            return f"{len(seen.repetitions)} repetitions seen"
        return None

    enough.last = None  # type: ignore[attr-defined]
    return enough
