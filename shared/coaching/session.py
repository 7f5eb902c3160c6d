"""A coaching session and one trial of it (thesis fig. 4.3, eq. 4.3-4.5), against ports.

Ports (the coach service wires them to the bus; tests can wire them to local objects):

* ``build(space, target)`` a space holding the target as proto-symbol ``target``;
* ``add_attempt(space, name, attempts)`` the attempt's repetitions as one proto-symbol;
* ``distance(space, a, b)`` eq. 2.4 between two proto-symbols;
* ``points(space)`` every proto-symbol's point;
* ``generate(space, mix)`` the motion of a weighted mix of proto-symbols;
* ``perform(clip)`` the simulator's feasibility report and centre-of-gravity trajectory on a
  body built from the target's skeleton;
* ``effort(clip)`` the clip's effort on that body (:func:`shared.coaching.effort.effort`), or
  None without a body.

**Felt effort** (thesis 6.5.1; policy ``effort``, :mod:`shared.coaching.effort`): the learner's
word for how heavy the last demonstration felt comes with its attempt; chapter 3's interval
estimator turns the answers into the learner's scale, and an emphatic motion it would feel
beyond its strength is lowered like an infeasible one (with or without the simulator's check).

One trial: the attempt (5 repetitions) becomes ``x_p``; ``d_p = |x_t - x_p|`` (eq. 4.4, the
HMM distance); the policy picks alpha and the adverb; the emphatic motion is generated from
``x_s = x_t + alpha (x_t - x_p)`` (eq. 4.3: weights ``1 + alpha`` on the target and
``-alpha`` on the attempt); optionally only the body part with the largest share of the error
is emphasised (by default the emphasis is applied to the real target, see
:func:`residual_emphasis`; ``mode="thesis"`` shows ``F_gen(x_s)`` itself); the simulator checks it (no new joint-limit violations against the target's own,
balance no worse than the target's, within tolerances: see ``_worse``) and alpha is lowered to
the largest value of the grid 0.25, 0.5, ... that passes (found by bisection).

**Sub-goal coaching** (thesis 4.6, 7.3; policy ``subgoal``): on the first trial the coach ranks
the body parts by their share of the error (:func:`shared.coaching.parts.error_shares`, parts
under ``SUBGOAL_MIN_SHARE`` left out) and sets intermediate proto-symbols in the space: sub-goal
``k`` is the learner's first attempt with the ``k`` worst parts replaced by the target's
(:func:`subgoal_motion`); the last goal is the target. Each trial emphasises towards the
current goal, ``x_s = x_g + alpha (x_g - x_p)``, applied to the goal's motion (residual form).
The coach moves to the next goal when the attempt has covered ``SUBGOAL_ADVANCE`` of its
distance to the goal since the goal was set, or after ``SUBGOAL_TRIALS`` trials on it.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np

from shared.clip import Clip
from shared.coaching.effort import EffortEstimate
from shared.coaching.parts import error_shares, partial_emphasis
from shared.coaching.policies import Policy, table_adverb
from shared.errors import BadInput

ALPHA_STEP = 0.25
SUBGOAL_MIN_SHARE = 0.1  # a body part with less of the error gets no sub-goal of its own
SUBGOAL_ADVANCE = 0.5  # share of the distance to a goal to cover before the next goal
SUBGOAL_TRIALS = 2  # trials on one goal at most


class CoachPorts(Protocol):
    def build(self, space: str, target: Clip) -> None: ...
    def add_attempt(self, space: str, name: str, attempts: list[Clip]) -> None: ...
    def distance(self, space: str, a: str, b: str) -> float: ...
    def points(self, space: str) -> dict[str, np.ndarray]: ...
    def generate(self, space: str, mix: dict[str, float]) -> Clip: ...
    def perform(self, clip: Clip) -> tuple[dict, np.ndarray]: ...
    def plant(self, clip: Clip, reference: Clip) -> tuple[Clip, dict]: ...
    def effort(self, clip: Clip) -> float | None: ...


@dataclass
class Trial:
    number: int
    d_p: float
    alpha: float  # what the policy chose
    alpha_shown: float  # after the feasibility check
    adverb: str | None
    feasible: bool
    alpha_reduced: bool
    feasibility: str
    part: str | None
    shares: dict
    d_cop: float | None
    x_t: list
    x_p: list
    x_s: list
    seconds: float = 0.0
    goal: str = "target"  # the proto-symbol emphasised towards (a sub-goal, or the target)
    emphasis_kept: float | None = None  # share of the emphatic motion's difference from the base kept by the repair
    felt: int | None = None  # the learner's word for the last demonstration's effort (effort policy)
    felt_predicted: float | None = None  # estimated felt effort of the motion shown next (share of its strength)


@dataclass
class Session:
    name: str
    target: Clip
    policy: Policy
    learner: str | None = None  # a simulated learner's name, or None for a person
    trials: list[Trial] = field(default_factory=list)
    mode: str = "residual"  # "residual": target + F_gen(x_s) - F_gen(x_t); "thesis": F_gen(x_s)
    check: bool = True  # the simulator's feasibility check (off reproduces the thesis's conditions)
    target_report: dict | None = None
    target_cog: np.ndarray | None = None
    subgoals: dict | None = None  # sub-goal coaching's plan (see module docstring)
    effort: EffortEstimate | None = None  # what the coach knows of the learner's felt effort (effort policy)

    @property
    def space(self) -> str:
        return f"coach-{self.name}"

    def d(self) -> list[float]:
        """``d_il`` of this session's learner over its trials (eq. 4.4)."""
        return [t.d_p for t in self.trials]


def check_attempts(session: Session, attempts: list[Clip]) -> None:
    """An attempt must carry the target's motion channels, enough frames and finite values."""
    if not attempts:
        raise BadInput("an attempt needs at least one repetition", field="clips")
    need = session.target.group("motion") or session.target.channels
    for a in attempts:
        missing = [c for c in need if c not in a.channels]
        if missing:
            raise BadInput(f"attempt {a.name!r} lacks {len(missing)} of the target's channels, e.g. {missing[:3]} "
                           "(a different skeleton?)", field="clips")
        if a.duration < 0.3 or a.n_frames < 10:
            raise BadInput(f"attempt {a.name!r} is too short ({a.n_frames} frames, {a.duration:.2f} s); "
                           "at least 10 frames and 0.3 s", field="clips")


MIN_KEPT = 0.5  # a repair that keeps less of the emphasis than this lowers alpha instead
#: the speeds (shares of the target's) a demonstration may be shown at when only its dynamics fail:
#: the forces a motion needs beyond its weight scale with its accelerations, by the square of the
#: speed (Hollerbach 1984, "Dynamic scaling of manipulator trajectories"), its shape not at all
TEMPOS = (0.8, 0.65, 0.5)
LIMIT_TOLERANCE = 10.0  # degrees past max(limit, the target's own extreme) before a channel counts
#: the share of its frames a motion may be off balance where the target is not, per test
#: (:func:`off_balance_share`): the 95th percentile of real takes of one motion by one person judged
#: against one another (HDM05 actors bd and bk, 226 pairs matched by DTW; ``python -m bench.balance``,
#: bench/results/balance.md). The tests are that coarse: two real takes differ by a median 4.5 % /
#: 12.5 % of their frames, a tenth of the pairs by more than 30 %. Actor dg, whose targets
#: bench.emphasis reports on, is not among them.
BALANCE_TOLERANCE = {"outside_runs": 0.56, "dynamic_runs": 0.43}


def _worse(report: dict, target_report: dict, target: Clip, dynamic: bool = True) -> str | None:
    """Why an emphatic motion is less feasible than the target itself, or None: a joint goes
    more than ``LIMIT_TOLERANCE`` past both its limit and the target's own extreme (real mocap
    already exceeds the ASF limits), or more of its frames than ``BALANCE_TOLERANCE`` are off
    balance where the target's are not: the centre of gravity outside the support or (with
    ``dynamic``) the centre of pressure the motion needs."""
    worst = None
    for c, v in report["joint_limit_violations"].items():
        lo, hi = v["limits"]
        if c in target.channels:
            lo, hi = min(lo, float(target.column(c).min())), max(hi, float(target.column(c).max()))
        over = max(lo - v["min"], v["max"] - hi)
        if over > LIMIT_TOLERANCE and (worst is None or over > worst[1]):
            worst = (c, over)
    if worst:
        return f"{worst[0]} goes {worst[1]:.0f} degrees past its limit and past the target's own range"
    s, ts = report["support"], target_report["support"]
    if s.get("checked") and ts.get("checked"):
        share = off_balance_share(report, target_report, "outside_runs")
        if share > BALANCE_TOLERANCE["outside_runs"]:
            return f"the centre of gravity leaves the support on {share:.0%} of the frames where the target's does not"
    if dynamic and s.get("dynamic_checked") and ts.get("dynamic_checked"):
        share = off_balance_share(report, target_report, "dynamic_runs")
        if share > BALANCE_TOLERANCE["dynamic_runs"]:
            return (f"the ground reaction it needs acts outside the feet (centre of pressure) or pulls on {share:.0%} "
                    "of the frames where the target's does not: it would tip over")
    return None


def off_balance_share(report: dict, target_report: dict, kind: str, match: np.ndarray | None = None) -> float:
    """The share of a motion's frames off balance by one test (``outside_runs``: the centre of
    gravity outside the support; ``dynamic_runs``: the centre of pressure it needs) where the
    target, at the matched frame, is not: ``match[t]`` is the target's frame for the motion's
    frame ``t`` (by default both spread evenly over the same time)."""
    n, n_t = int(report["frames"]), int(target_report["frames"])
    if match is None:
        match = np.linspace(0, n_t - 1, n).round().astype(int)
    mine = _outside_frames(report, n, kind)
    theirs = _outside_frames(target_report, n_t, kind)[match]
    return float(np.mean(mine & ~theirs)) if n else 0.0


def _outside_frames(report: dict, n: int, kind: str = "outside_runs") -> np.ndarray:
    """Frames (n,) the report found off balance: the centre of gravity outside the support
    (``outside_runs``, static) or the centre of pressure outside it (``dynamic_runs``)."""
    out = np.zeros(n, bool)
    for a, b in (report.get("support") or {}).get(kind) or []:
        out[max(a, 0):min(b, n)] = True
    return out


def make_feasible(base: Clip, demo: Clip, report: dict, target_report: dict, target: Clip,
                  perform, plant=None) -> tuple[Clip, list[str]]:
    """Repair an emphatic motion the body cannot perform, keeping the emphasis where it is
    possible instead of lowering alpha for the whole motion (``perform(clip) -> report``):

    1. per channel: each joint angle held within ``LIMIT_TOLERANCE / 2`` of its limit (or of the
       target's own extreme, when the target goes further);
    2. the stance: ``plant(clip) -> (clip, what changed)``, if given, puts the feet where the
       target stands on them, under the body as the target's are, by the root's height and the
       legs' angles (:func:`shared.bodies.stance.plant_feet`); after every later change too;
    3. the tempo: where only the centre of pressure fails (the pose is balanced, its speed is
       not), the motion is shown slower, at the fastest of ``TEMPOS`` that passes (or the slowest);
    4. per phase: where the balance fails and the target's does not (the centre of gravity, or
       the centre of pressure the motion needs, outside the support), the demonstration blends back to the base motion (the target, or the sub-goal), with 0.2 s
       ramps; widened twice if that is not enough.

    Returns the repaired motion (on ``demo``'s frames) and what was changed, one phrase per
    change; the caller checks the result (``_worse``) and lowers alpha only if it still fails."""
    base = base.resample(demo.fps) if base.n_frames != demo.n_frames else base
    n = min(base.n_frames, demo.n_frames)
    out = demo.data[:n].copy()
    ref = base.data[:n]
    changes = []
    clamped = []
    for c, v in report.get("joint_limit_violations", {}).items():
        if c not in demo.channels:
            continue
        lo, hi = v["limits"]
        if c in target.channels:
            lo, hi = min(lo, float(target.column(c).min())), max(hi, float(target.column(c).max()))
        k = demo.channels.index(c)
        before = out[:, k].copy()
        out[:, k] = np.clip(out[:, k], lo - LIMIT_TOLERANCE / 2, hi + LIMIT_TOLERANCE / 2)
        if not np.array_equal(before, out[:, k]):
            clamped.append(c)
    if clamped:
        changes.append(f"{len(clamped)} joint angle(s) held at their limits ({', '.join(clamped[:4])}"
                       + (", ..." if len(clamped) > 4 else "") + ")")
    from shared.agents.learner import BODY_PARTS, body_part

    planted: dict[int, tuple[Clip, dict]] = {}  # what planting changed, by the clip it made

    def placed(clip: Clip) -> Clip:
        if plant is None:
            return clip
        clip, info = plant(clip)
        planted[id(clip)] = (clip, info)
        return clip

    fixed = placed(demo.with_data(np.vstack([out, demo.data[n:]])))
    out = fixed.data[:n].copy()
    ramp = max(1, int(round(0.2 * demo.fps)))
    grid = np.linspace(0, target.n_frames - 1, n).round().astype(int)
    target_bad = {kind: _outside_frames(target_report, target.n_frames, kind)[grid]
                  for kind in ("outside_runs", "dynamic_runs")}
    parts = np.array([body_part(c) for c in demo.channels])
    taken: dict[str, float] = {}  # body part (or "all") -> share of the frames its emphasis was taken from

    def off_balance(report) -> np.ndarray:
        bad = np.zeros(n, bool)  # off balance where the target is not, by each test
        for kind, t_bad in target_bad.items():
            bad |= _outside_frames(report, n, kind) & ~t_bad
        return bad

    def phases(bad: np.ndarray, widen: int) -> np.ndarray:
        w = _centred(bad.astype(float), np.ones(2 * widen * ramp + 1)) > 0  # widened phases
        kernel = np.hanning(2 * ramp + 1)
        return np.clip(_centred(w.astype(float), kernel / kernel.sum()), 0.0, 1.0)

    rep = perform(fixed)
    if _worse(rep, target_report, target) is not None and _worse(rep, target_report, target, dynamic=False) is None:
        for tempo in TEMPOS:
            slower = fixed.with_data(fixed.data, fps=demo.fps * tempo)
            slower_rep = perform(slower)
            if _worse(slower_rep, target_report, target) is None or tempo == TEMPOS[-1]:
                fixed, rep = slower, slower_rep
                changes.append(f"shown at {tempo:.0%} of its speed (the faster motion needs the ground to push "
                               "outside the feet)")
                break
    # first the body part whose emphasis, taken out of the phases off balance, helps most (the
    # others keep theirs); then, if the balance still fails, every part in ever wider phases
    for step in range(len(BODY_PARTS) + 5):
        if _worse(rep, target_report, target) is None or not (rep.get("support") or {}).get("checked"):
            break
        bad = off_balance(rep)
        if not bad.any():
            break
        if step < len(BODY_PARTS):
            w = phases(bad, 1)
            tries = []
            for part in BODY_PARTS:
                if part in taken:
                    continue
                mask = (parts == part).astype(float)
                trial_clip = placed(fixed.with_data(np.vstack([out - w[:, None] * mask[None, :] * (out - ref),
                                                               demo.data[n:]])))
                trial_out = trial_clip.data[:n]
                trial_rep = perform(trial_clip)
                tries.append((int(off_balance(trial_rep).sum()), part, trial_out, trial_clip, trial_rep))
            if not tries:
                continue
            count, part, trial_out, trial_clip, trial_rep = min(tries, key=lambda x: x[0])
            if count >= int(bad.sum()):  # no part alone helps: go on to every part
                taken.setdefault("parts tried", 0.0)
                continue
            out, fixed, rep = trial_out, trial_clip, trial_rep
            taken[part] = float(np.mean(w > 0.5))
        else:
            w = phases(bad, step - len(BODY_PARTS) + 1)
            fixed = placed(fixed.with_data(np.vstack([out - w[:, None] * (out - ref), demo.data[n:]])))
            out = fixed.data[:n].copy()
            rep = perform(fixed)
            taken["all"] = max(taken.get("all", 0.0), float(np.mean(w > 0.5)))
    taken.pop("parts tried", None)
    info = planted.get(id(fixed), (None, {}))[1]
    if info.get("planted"):
        changes.append(f"the feet kept where the target stands, under the body (hips moved up to "
                       f"{100 * info['root_height_change_m']:.0f} cm, leg joints up to {info['leg_angle_change_deg']:.0f} "
                       "degrees)")
    if taken:
        changes.append("the emphasis taken out where the body would lose its balance: " + ", ".join(
            f"{'every part' if part == 'all' else part} on {share:.0%} of the frames" for part, share in taken.items()))
    return fixed, changes


def _centred(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``x`` convolved with ``kernel``, centred, as long as ``x`` (whichever is longer)."""
    full = np.convolve(x, kernel, mode="full")
    start = (len(kernel) - 1) // 2
    return full[start:start + len(x)]


def _emphasis_kept(base: Clip, demo: Clip, fixed: Clip) -> float:
    """The RMS of the repaired motion's difference from the base over the emphatic one's."""
    n = min(base.n_frames, demo.n_frames, fixed.n_frames)
    chans = [c for c in (base.group("motion") or base.channels) if c in demo.channels]
    idx = [demo.channels.index(c) for c in chans]
    b = base.resample(demo.fps).data[:n][:, [base.channels.index(c) for c in chans]] if base.n_frames != demo.n_frames \
        else base.data[:n][:, [base.channels.index(c) for c in chans]]
    full = np.sqrt(np.mean((demo.data[:n][:, idx] - b) ** 2))
    return float(np.sqrt(np.mean((fixed.data[:n][:, idx] - b) ** 2)) / full) if full > 0 else 1.0


def _d_cop(target_cog: np.ndarray, attempt_cog: np.ndarray) -> float:
    """6.5: HMM distance between the centre-of-gravity trajectories of target and attempt
    (left-to-right HMMs of 6 states on the CoG in centimetres)."""
    from shared.pss.distance import hmm_distance
    from shared.pss.hmm import fit_hmm

    n = max(2, min(6, len(target_cog) // 3, len(attempt_cog) // 3))
    a = fit_hmm([100.0 * target_cog], n, var_floor=0.05)
    b = fit_hmm([100.0 * attempt_cog], n, var_floor=0.05)
    return float(hmm_distance(a, b))


def _wrap(deg: np.ndarray) -> np.ndarray:
    return (deg + 180.0) % 360.0 - 180.0


def _rotation_residual(target: Clip, gs: np.ndarray, gt: np.ndarray, chans: list[str], seq: str) -> dict:
    """A joint's emphasis as a rotation, not as Euler differences (an Euler triple can flip to
    its twin ``(a + 180, 180 - b, c + 180)``, and the generated motions of two points may sit
    on different twins: per channel, the difference of a hip's triples reached 200 degrees
    where the rotations differ by a few): ``M = M_target M_gt^-1 M_gs``, then the Euler triple
    of ``M`` nearest to the target's, frame by frame."""
    from scipy.spatial.transform import Rotation

    axes = [a for a in seq.lower() if f"r{a}" in [c.split(".")[-1] for c in chans]]
    order = [next(i for i, c in enumerate(chans) if c.endswith(f".r{a}")) for a in axes]
    seq_used = "".join(axes).upper() if seq.isupper() else "".join(axes)
    t_ang = np.stack([target.column(chans[i]) for i in order], axis=1)
    r = (Rotation.from_euler(seq_used, t_ang, degrees=True)
         * Rotation.from_euler(seq_used, gt[:, order], degrees=True).inv()
         * Rotation.from_euler(seq_used, gs[:, order], degrees=True))
    e = r.as_euler(seq_used, degrees=True)
    if len(axes) == 3:  # the twin solution of a Tait-Bryan triple; keep the nearer
        twin = np.column_stack([e[:, 0] + 180.0, 180.0 - e[:, 1], e[:, 2] + 180.0])
        near = lambda x: np.abs(_wrap(x - t_ang)).sum(axis=1)  # noqa: E731
        e = np.where((near(twin) < near(e))[:, None], twin, e)
    e = t_ang + _wrap(e - t_ang)  # on the target's branch
    return {chans[i]: e[:, k] for k, i in enumerate(order)}


def residual_emphasis(target: Clip, generated_s: Clip, generated_t: Clip) -> Clip:
    """``theta_t + (F_gen(x_s) - F_gen(x_t))`` on the target's frames (beyond the thesis).

    ``F_gen`` returns motions in a canonical frame (heading 0 and the start at the origin, the
    features being turn-invariant) with generation error; the difference of two generations
    from the same space keeps the emphasis and cancels both, so alpha = 0 shows the target
    exactly. A joint with three rotation channels (the root's orientation, a hip, a shoulder)
    is combined as a rotation (:func:`_rotation_residual`); the angles of joints with fewer
    are differences wrapped to (-180, 180]."""
    grid = np.linspace(0, 1, target.n_frames)
    out = target.data.copy()
    sk = target.skeleton
    root = sk.root.name if sk is not None else None
    chans = [c for c in (target.group("motion") or target.channels)
             if c in generated_s.channels and c in generated_t.channels]

    def resampled(clip, c):
        return np.interp(grid, np.linspace(0, 1, clip.n_frames), clip.column(c))

    balls = {}  # joint -> (its three rotation channels, its Euler order)
    for j in sk.joints if sk is not None else []:
        rot = [f"{j.name}.r{a}" for a in (j.euler or "xyz").lower()]
        if all(c in chans for c in rot):
            balls[j.name] = (rot, j.euler or "xyz")
    in_balls = {c for rot, _ in balls.values() for c in rot}
    for c in chans:
        if c in in_balls:
            continue
        s, t = resampled(generated_s, c), resampled(generated_t, c)
        diff = s - t if c.split(".")[-1].startswith("t") else _wrap(s - t)
        out[:, target.channels.index(c)] += diff
    for rot, seq in balls.values():
        gs = np.column_stack([resampled(generated_s, c) for c in rot])
        gt = np.column_stack([resampled(generated_t, c) for c in rot])
        for c, v in _rotation_residual(target, gs, gt, rot, seq).items():
            out[:, target.channels.index(c)] = v
    return target.with_data(out, name=generated_s.name)


def subgoal_motion(target: Clip, attempts: list[Clip], parts: list[str]) -> Clip:
    """An intermediate motion: the attempts' mean (on the target's frames) with ``parts``' joint
    rotations taken from the target; everything else (the root's path, other parts) is the
    attempt's."""
    from shared.agents.learner import body_part, to_phase
    from shared.coaching.parts import rotation_channels

    chans = list(target.group("motion") or target.channels)
    mean = np.mean([to_phase(a, chans, target.n_frames) for a in attempts], axis=0)
    out = target.data.copy()
    keep = set(rotation_channels(target))
    for k, c in enumerate(chans):
        if not (c in keep and body_part(c) in parts):
            out[:, target.channels.index(c)] = mean[:, k]
    return target.with_data(out, name="subgoal_" + "_".join(parts))


def _goal(session: Session, attempts: list[Clip], name: str, number: int, ports: CoachPorts) -> tuple[str, Clip]:
    """The goal of this trial under sub-goal coaching (module docstring): plans the sub-goals on
    the first trial, then moves on when the current one is reached or has had its trials."""
    plan = session.subgoals
    if plan is None:
        shares = error_shares(session.target, attempts)
        order = [p for p in sorted(shares, key=shares.get, reverse=True) if shares[p] >= SUBGOAL_MIN_SHARE]
        goals = []
        # names new on every try (a trial cut short is sent again, its proto-symbols already in the
        # space) and the same in every run (reports repeat bit for bit): the space's size says which try
        tries = len(ports.points(session.space))
        for k in range(1, len(order)):
            clip = subgoal_motion(session.target, attempts, order[:k])
            gname = f"subgoal{k}-{tries}"
            ports.add_attempt(session.space, gname, [clip])
            goals.append({"name": gname, "parts": order[:k], "data": clip.data.tolist()})
        plan = session.subgoals = {"order": order, "goals": goals, "current": 0, "since": number, "start": None}
    while True:
        c = plan["current"]
        last = c >= len(plan["goals"])
        goal = "target" if last else plan["goals"][c]["name"]
        d = ports.distance(session.space, goal, name)
        if plan["start"] is None:
            plan["start"], plan["since"] = d, number
        reached = d <= (1.0 - SUBGOAL_ADVANCE) * plan["start"] or number - plan["since"] >= SUBGOAL_TRIALS
        if last or not reached:
            break
        plan["current"], plan["start"] = c + 1, None
    base = session.target if last else session.target.with_data(np.asarray(plan["goals"][c]["data"], float), name=goal)
    return goal, base


def start(session: Session, ports: CoachPorts) -> None:
    """Build the session's space and the target's reference report."""
    ports.build(session.space, session.target)
    session.target_report, session.target_cog = ports.perform(session.target)
    if session.policy.effort:
        e = ports.effort(session.target)
        if e is None or not e > 0:
            raise BadInput("the effort policy feels motions on a body built from the target's skeleton, and this "
                           "target has none (or no effort on it)", field="policy")
        session.effort = EffortEstimate(float(e), last=1.0)  # the first motion shown is the target


def trial(session: Session, attempts: list[Clip], ports: CoachPorts, felt: int | None = None) -> tuple[Trial, Clip]:
    """One trial (see module docstring). Returns the record and the motion to show next.
    ``felt``: the learner's word for the last demonstration's effort (effort policy)."""
    t0 = time.perf_counter()
    check_attempts(session, attempts)
    if felt is not None:
        if session.effort is None:
            raise BadInput(f"session {session.name!r} does not ask for felt effort (start it with the effort policy)",
                           field="felt")
        session.effort.add(felt)
    number = len(session.trials) + 1
    name = f"attempt{number}"
    ports.add_attempt(session.space, name, attempts)
    d_p = ports.distance(session.space, "target", name)
    d_cop = None
    if session.target_cog is not None:
        _, cog = ports.perform(attempts[0])
        d_cop = _d_cop(session.target_cog, cog)
    alpha, adverb = session.policy.choose(d_p, d_cop, session.learner)
    shares = error_shares(session.target, attempts)
    part = max(shares, key=shares.get) if session.policy.body_part else None
    goal, base = _goal(session, attempts, name, number, ports) if session.policy.subgoal else ("target", session.target)
    g_goal = ports.generate(session.space, {goal: 1.0}) if session.mode == "residual" and alpha > 0 else None

    def show(a: float) -> Clip:
        if a <= 0:
            return base
        demo = ports.generate(session.space, {goal: 1.0 + a, name: -a})
        if g_goal is not None:
            demo = residual_emphasis(base, demo, g_goal)
        if part is not None:
            demo = partial_emphasis(base.resample(demo.fps), demo, part)
        return demo

    efforts: dict[int, tuple[Clip, float]] = {}  # the clip is kept with its effort: its id cannot be reused

    def effort_of(demo: Clip) -> float:
        if id(demo) not in efforts:
            efforts[id(demo)] = (demo, float(ports.effort(demo)))
        return efforts[id(demo)][1]

    def why_not(demo: Clip) -> str | None:
        if session.check and session.target_report:
            report, _ = ports.perform(demo)
            worse = _worse(report, session.target_report, session.target)
            if worse is not None:
                return worse
        return session.effort.beyond(effort_of(demo)) if session.effort is not None else None

    def repair(demo: Clip) -> tuple[Clip, float, list[str]] | None:
        """``demo`` made feasible (:func:`make_feasible`) with the share of its emphasis kept and
        what changed, or None when it still fails or keeps less than ``MIN_KEPT``."""
        if not session.check or not session.target_report:
            return None  # only the simulator's check is repaired; felt effort is met by a lower alpha
        fixed, changes = make_feasible(base, demo, ports.perform(demo)[0], session.target_report, session.target,
                                       lambda c: ports.perform(c)[0], lambda c: ports.plant(c, base))
        share = _emphasis_kept(base, demo, fixed) if changes else 0.0
        return (fixed, share, changes) if share >= MIN_KEPT and why_not(fixed) is None else None

    shown, reduced, kept = alpha, False, None
    demo = show(alpha)
    if alpha <= 0:
        reason = "no emphasis"
    elif not session.check and session.effort is None:
        reason = "not checked (the session was started without the check)"
    else:
        first = why_not(demo)
        unchecked = (session.target_report or {}).get("not_checked") or []
        reason = "feasible" + (f" (not checked: {'; '.join(unchecked)})" if unchecked else "")
        if not session.check:
            reason = "within the learner's strength (balance and joint limits not checked: the session was started " \
                     "without the check)"
        elif session.target_report is None or (session.target_report.get("feasible") is None and "not_checked" in
                                               session.target_report):
            reason = "not checked: " + ("; ".join(unchecked) or "no simulator body for this target")
        if first is not None:
            # made feasible where it is not, the emphasis kept elsewhere (make_feasible)
            repaired = repair(demo)
            if repaired is not None:
                demo, kept, changes = repaired
                reason = f"alpha {alpha:g} made feasible ({first}): {'; '.join(changes)}; {kept:.0%} of the emphasis kept"
                first = None
        if first is not None:
            # the largest alpha on the grid 0.25, 0.5, ... below the policy's that is feasible,
            # or made feasible keeping at least MIN_KEPT of its emphasis, by bisection
            # (feasibility falls with alpha): log2 checks instead of one per step
            reduced = True
            grid = [round(ALPHA_STEP * k, 6) for k in range(1, int(np.ceil(alpha / ALPHA_STEP - 1e-9)))]
            lo, hi, best = 0, len(grid) - 1, None
            while lo <= hi:
                mid = (lo + hi) // 2
                candidate = show(grid[mid])
                if why_not(candidate) is None:
                    best, lo = (grid[mid], candidate, None, []), mid + 1
                    continue
                fixed = repair(candidate)
                if fixed is not None:
                    best, lo = (grid[mid], *fixed), mid + 1
                else:
                    hi = mid - 1
            shown, demo, kept, changes = best if best is not None else (0.0, base, None, [])
            reason = f"alpha {alpha:g} infeasible ({first}); lowered to {shown:g}" + (
                f", made feasible: {'; '.join(changes)}; {kept:.0%} of its emphasis kept" if changes else "")
    if reduced and adverb is not None and session.policy.adverb == "table":
        adverb = table_adverb(shown)
    predicted = None
    if session.effort is not None:
        e = effort_of(demo)
        predicted = session.effort.predicted(e) if session.effort.answers else None
        session.effort.last = session.effort.g_self(e)  # what the learner's next answer is about
    pts = ports.points(session.space)
    x_t, x_p = pts["target"], pts[name]
    x_g = pts.get(goal, x_t)
    x_s = x_g + shown * (x_g - x_p)
    rec = Trial(number, float(d_p), float(alpha), float(shown), adverb, not reduced, reduced, reason, part,
                shares, d_cop, x_t.tolist(), x_p.tolist(), x_s.tolist(), time.perf_counter() - t0, goal, kept,
                felt, predicted)
    session.trials.append(rec)
    return rec, demo.with_data(demo.data, name=f"{session.name}_emphatic{number}")


def session_to_dict(s: Session) -> dict:
    return {"name": s.name, "policy": s.policy.to_dict(), "learner": s.learner, "mode": s.mode, "check": s.check,
            "trials": [asdict(t) for t in s.trials], "target_report": s.target_report, "subgoals": s.subgoals,
            "target_cog": None if s.target_cog is None else np.asarray(s.target_cog).tolist(),
            "effort": None if s.effort is None else s.effort.to_dict()}


def ratio(sessions_d: list[list[float]]) -> np.ndarray:
    """``R_l = mean_i d_il / d_i1`` (eq. 4.5) over learners' ``d`` sequences."""
    d = np.asarray(sessions_d, float)
    return np.mean(d / d[:, :1], axis=0)
