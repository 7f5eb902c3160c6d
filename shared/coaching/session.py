"""A coaching session and one trial of it (thesis fig. 4.3, eq. 4.3-4.5), against ports.

Ports (the coach service wires them to the bus; tests can wire them to local objects):

* ``build(space, target)`` a space holding the target as proto-symbol ``target``;
* ``add_attempt(space, name, attempts)`` the attempt's repetitions as one proto-symbol;
* ``distance(space, a, b)`` eq. 2.4 between two proto-symbols;
* ``points(space)`` every proto-symbol's point;
* ``generate(space, mix)`` the motion of a weighted mix of proto-symbols;
* ``perform(clip)`` the simulator's feasibility report and centre-of-gravity trajectory on a
  body built from the target's skeleton;
* ``plant(clip, reference)`` the clip with its feet where the reference stands on them
  (:func:`shared.bodies.stance.plant_feet`; unchanged without a body);
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
balance no worse than the target's, within tolerances: see :mod:`shared.coaching.feasibility`) and alpha is lowered to
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

import re
import time
from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np

from shared.coaching.effort import EffortEstimate
from shared.coaching.feasibility import MIN_KEPT, emphasis_kept, make_feasible, worse_than_target
from shared.coaching.parts import error_shares, partial_emphasis
from shared.coaching.policies import Policy, table_adverb
from shared.errors import BadInput, Unavailable
from shared.motion.clip import Clip
from shared.motion.skeleton import other_skeleton

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
    def perform(self, clip: Clip, track: bool = True) -> tuple[dict, np.ndarray]: ...
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
            raise BadInput(f"attempt {a.name!r} lacks {len(missing)} of the target's channels, e.g. {missing[:3]}"
                           + (other_skeleton(session.target.skeleton, a.skeleton) or " (a different skeleton?)"),
                           field="clips")
        if a.duration < 0.3 or a.n_frames < 10:
            raise BadInput(f"attempt {a.name!r} is too short ({a.n_frames} frames, {a.duration:.2f} s); "
                           "at least 10 frames and 0.3 s", field="clips")


def _d_cop(target_cog: np.ndarray, attempt_cog: np.ndarray) -> float:
    """6.5: HMM distance between the centre-of-gravity trajectories of target and attempt
    (left-to-right HMMs of 6 states on the CoG in centimetres)."""
    from shared.pss.distance import hmm_distance
    from shared.pss.hmm import fit_hmm

    n = max(2, min(6, len(target_cog) // 3, len(attempt_cog) // 3))
    a = fit_hmm([100.0 * target_cog], n, var_floor=0.05)
    b = fit_hmm([100.0 * attempt_cog], n, var_floor=0.05)
    return float(hmm_distance(a, b))


def warm() -> None:
    """Load the compiled kernels a trial's scoring runs (:func:`_d_cop`'s HMMs and eq. 2.4) once, at
    the coach service's start: the first trial of a live study paid 0.4-0.6 s for them (numba's
    import and its cached machine code) after the person's fifth repetition."""
    r = np.random.default_rng(0)
    _d_cop(r.random((12, 3)), r.random((12, 3)))


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
    from shared.coaching.parts import body_part, rotation_channels, to_phase

    chans = list(target.group("motion") or target.channels)
    mean = np.mean([to_phase(a, chans, target.n_frames) for a in attempts], axis=0)
    out = target.data.copy()
    keep = set(rotation_channels(target))
    for k, c in enumerate(chans):
        if not (c in keep and body_part(c) in parts):
            out[:, target.channels.index(c)] = mean[:, k]
    return target.with_data(out, name="subgoal_" + "_".join(parts))


def attempt_name(number: int) -> str:
    """The proto-symbol of trial ``number``'s attempt in the session's space."""
    return f"attempt{number}"


def attempt_number(name: str) -> int | None:
    """The trial whose attempt a proto-symbol is (its name as :func:`attempt_name` gives it, the
    coach service's suffix after it), or None."""
    m = re.match(r"attempt(\d+)", name)
    return int(m.group(1)) if m else None


def _goal(session: Session, attempts: list[Clip], name: str, number: int, ports: CoachPorts) -> tuple[str, Clip]:
    """The goal of this trial under sub-goal coaching (module docstring): plans the sub-goals on
    the first trial, then moves on when the current one is reached or has had its trials."""
    plan = session.subgoals
    if plan is None:
        shares = error_shares(session.target, attempts)
        order = [p for p in sorted(shares, key=shares.__getitem__, reverse=True) if shares[p] >= SUBGOAL_MIN_SHARE]
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


def _once_per_clip(compute):
    """``compute(clip)``, computed once per clip (kept with the clip, so its id is never reused)."""
    seen: dict[int, tuple[Clip, object]] = {}

    def of(clip: Clip):
        if id(clip) not in seen:
            seen[id(clip)] = (clip, compute(clip))
        return seen[id(clip)][1]

    return of


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
    name = attempt_name(number)
    ports.add_attempt(session.space, name, attempts)
    d_p = ports.distance(session.space, "target", name)
    d_cop = None
    if session.target_cog is not None:
        _, cog = ports.perform(attempts[0], track=False)  # its centre of gravity only
        d_cop = _d_cop(session.target_cog, cog)
    alpha, adverb = session.policy.choose(d_p, d_cop, session.learner)
    shares = error_shares(session.target, attempts)
    part = max(shares, key=shares.__getitem__) if session.policy.body_part else None
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

    def effort(demo: Clip) -> float:
        e = ports.effort(demo)
        if e is None:  # (a session with an effort estimate has a learner with a body)
            raise Unavailable("the learner's body cannot tell the demonstration's effort", cause="no_body")
        return float(e)

    # a clip checked, then repaired, is asked about again: each is performed once
    report_of, effort_of = _once_per_clip(lambda c: ports.perform(c)[0]), _once_per_clip(effort)

    def why_not(demo: Clip) -> str | None:
        if session.check and session.target_report:
            worse = worse_than_target(report_of(demo), session.target_report, session.target)
            if worse is not None:
                return worse
        return session.effort.beyond(effort_of(demo)) if session.effort is not None else None

    def repair(demo: Clip) -> tuple[Clip, float, list[str]] | None:
        """``demo`` made feasible (:func:`make_feasible`) with the share of its emphasis kept and
        what changed, or None when it still fails or keeps less than ``MIN_KEPT``."""
        if not session.check or not session.target_report:
            return None  # only the simulator's check is repaired; felt effort is met by a lower alpha
        fixed, changes = make_feasible(base, demo, report_of(demo), session.target_report, session.target,
                                       report_of, lambda c: ports.plant(c, base))
        share = emphasis_kept(base, demo, fixed) if changes else 0.0
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
            lo, hi = 0, len(grid) - 1
            best: tuple | None = None
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
