"""Emphasis made feasible instead of removed (beyond the thesis: its coach lowered alpha).

An emphatic motion is checked against the target on a body built from the target's skeleton
(the simulator's ``perform`` report): :func:`worse_than_target` says why it is less feasible
than the target itself, or nothing; :func:`make_feasible` repairs it where it can be (joint
angles held at their limits, the feet kept where the target stands, shown slower where only
its speed fails, the emphasis taken out of one body part at a time in the phases off balance);
:func:`emphasis_kept` says how much of the emphasis the repair kept. Bus-free: the caller gives
``perform`` and ``plant`` (the coach's ports).
"""

from __future__ import annotations

import numpy as np

from shared.motion.clip import Clip

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
#: 12.5 % / 6.4 % of their frames (static, centre of pressure, tracking), a tenth of the pairs by 24-33 %.
#: Actor dg, whose targets bench.emphasis reports on, is not among them.
BALANCE_TOLERANCE = {"outside_runs": 0.56, "dynamic_runs": 0.43, "tracking_runs": 0.32}


def worse_than_target(report: dict, target_report: dict, target: Clip, dynamic: bool = True) -> str | None:
    """Why an emphatic motion is less feasible than the target itself, or None: a joint goes
    more than ``LIMIT_TOLERANCE`` past both its limit and the target's own extreme (real mocap
    already exceeds the ASF limits), or more of its frames than ``BALANCE_TOLERANCE`` are off
    balance where the target's are not: the centre of gravity outside the support or (with
    ``dynamic``) the centre of pressure the motion needs, or the simulated body needing a hand
    (the tracking test, when the reports have it)."""
    failed = failing_test(report, target_report, target, dynamic)
    return None if failed is None else failed[1]


def failing_test(report: dict, target_report: dict, target: Clip, dynamic: bool = True) -> tuple[str, str] | None:
    """:func:`worse_than_target`'s first failing test, as (``"limits"`` or the support report's
    runs it counted: ``outside_runs``, ``dynamic_runs``, ``tracking_runs``; the sentence)."""
    worst = None
    for c, v in report["joint_limit_violations"].items():
        lo, hi = v["limits"]
        if c in target.channels:
            lo, hi = min(lo, float(target.column(c).min())), max(hi, float(target.column(c).max()))
        over = max(lo - v["min"], v["max"] - hi)
        if over > LIMIT_TOLERANCE and (worst is None or over > worst[1]):
            worst = (c, over)
    if worst:
        return "limits", f"{worst[0]} goes {worst[1]:.0f} degrees past its limit and past the target's own range"
    s, ts = report["support"], target_report["support"]
    if s.get("checked") and ts.get("checked"):
        share = off_balance_share(report, target_report, "outside_runs")
        if share > BALANCE_TOLERANCE["outside_runs"]:
            return "outside_runs", f"the centre of gravity leaves the support on {share:.0%} of the frames where the target's does not"
    if dynamic and s.get("dynamic_checked") and ts.get("dynamic_checked"):
        share = off_balance_share(report, target_report, "dynamic_runs")
        if share > BALANCE_TOLERANCE["dynamic_runs"]:
            return "dynamic_runs", (f"the ground reaction it needs acts outside the feet (centre of pressure) or pulls on "
                                    f"{share:.0%} of the frames where the target's does not: it would tip over")
    if dynamic and s.get("tracking_checked") and ts.get("tracking_checked"):
        share = off_balance_share(report, target_report, "tracking_runs")
        if share > BALANCE_TOLERANCE["tracking_runs"]:
            return "tracking_runs", (f"a tracking controller in a simulation with a floor follows it only with a helping "
                                     f"hand of more than {s['help_limit']:.0%} of its weight on {share:.0%} of the frames "
                                     "where the target needs none: it would fall")
    return None


def off_balance_share(report: dict, target_report: dict, kind: str, match: np.ndarray | None = None) -> float:
    """The share of a motion's frames off balance by one test (``outside_runs``: the centre of
    gravity outside the support; ``dynamic_runs``: the centre of pressure it needs;
    ``tracking_runs``: the simulated body needing a hand) where the
    target, at the matched frame, is not: ``match[t]`` is the target's frame for the motion's
    frame ``t`` (by default both spread evenly over the same time)."""
    n, n_t = int(report["frames"]), int(target_report["frames"])
    if match is None:
        match = np.linspace(0, n_t - 1, n).round().astype(int)
    mine = outside_frames(report, n, kind)
    theirs = outside_frames(target_report, n_t, kind)[match]
    return float(np.mean(mine & ~theirs)) if n else 0.0


def outside_frames(report: dict, n: int, kind: str = "outside_runs") -> np.ndarray:
    """Frames (n,) the report found off balance: the centre of gravity outside the support
    (``outside_runs``, static), the centre of pressure outside it (``dynamic_runs``) or a
    helping hand needed by the tracking controller (``tracking_runs``, simulated)."""
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
    3. the tempo: where only the dynamic tests fail (the centre of pressure, the simulated body's
       helping hand: the pose is balanced, its speed is not), the motion is shown slower, at the
       fastest of ``TEMPOS`` that passes (or the slowest);
    4. per phase: where the balance fails and the target's does not (the centre of gravity, or
       the centre of pressure the motion needs, outside the support; the simulated body needing a
       hand), the demonstration blends back to the base motion (the target, or the sub-goal), with
       0.2 s ramps; widened twice if that is not enough.

    Returns the repaired motion (on ``demo``'s frames) and what was changed, one phrase per
    change; the caller checks the result (:func:`worse_than_target`) and lowers alpha only if it still fails."""
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
    from shared.coaching.parts import BODY_PARTS, body_part

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
    target_bad = {kind: outside_frames(target_report, target.n_frames, kind)[grid]
                  for kind in ("outside_runs", "dynamic_runs", "tracking_runs")}
    parts = np.array([body_part(c) for c in demo.channels])
    taken: dict[str, float] = {}  # body part (or "all") -> share of the frames its emphasis was taken from

    def off_balance(report) -> np.ndarray:
        bad = np.zeros(n, bool)  # off balance where the target is not, by each test
        for kind, t_bad in target_bad.items():
            bad |= outside_frames(report, n, kind) & ~t_bad
        return bad

    def phases(bad: np.ndarray, widen: int) -> np.ndarray:
        w = _centred(bad.astype(float), np.ones(2 * widen * ramp + 1)) > 0  # widened phases
        kernel = np.hanning(2 * ramp + 1)
        return np.clip(_centred(w.astype(float), kernel / kernel.sum()), 0.0, 1.0)

    rep = perform(fixed)
    failed = failing_test(rep, target_report, target)
    if failed is not None and worse_than_target(rep, target_report, target, dynamic=False) is None:
        for tempo in TEMPOS:
            slower = fixed.with_data(fixed.data, fps=demo.fps * tempo)
            slower_rep = perform(slower)
            if worse_than_target(slower_rep, target_report, target) is None or tempo == TEMPOS[-1]:
                fixed, rep = slower, slower_rep
                changes.append(f"shown at {tempo:.0%} of its speed (at its own, " + (
                    "a simulated body would need a helping hand to follow it)" if failed[0] == "tracking_runs"
                    else "the ground would have to push outside the feet)"))
                break
    # first the body part whose emphasis, taken out of the phases off balance, helps most (the
    # others keep theirs); then, if the balance still fails, every part in ever wider phases
    for step in range(len(BODY_PARTS) + 5):
        if worse_than_target(rep, target_report, target) is None or not (rep.get("support") or {}).get("checked"):
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


def emphasis_kept(base: Clip, demo: Clip, fixed: Clip) -> float:
    """The RMS of the repaired motion's difference from the base over the emphatic one's."""
    n = min(base.n_frames, demo.n_frames, fixed.n_frames)
    chans = [c for c in (base.group("motion") or base.channels) if c in demo.channels]
    idx = [demo.channels.index(c) for c in chans]
    b = base.resample(demo.fps).data[:n][:, [base.channels.index(c) for c in chans]] if base.n_frames != demo.n_frames \
        else base.data[:n][:, [base.channels.index(c) for c in chans]]
    full = np.sqrt(np.mean((demo.data[:n][:, idx] - b) ** 2))
    return float(np.sqrt(np.mean((fixed.data[:n][:, idx] - b) ** 2)) / full) if full > 0 else 1.0
