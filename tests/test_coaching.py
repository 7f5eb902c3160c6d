"""Coaching in the library: policies, residual and body-part emphasis, a local session."""

from __future__ import annotations

import numpy as np
import pytest

from shared.agents.learner import LearnerParams, SimulatedLearner, population
from shared.coaching.local import LocalCoachPorts
from shared.coaching.parts import error_shares, partial_emphasis
from shared.coaching.policies import (
    Calibration,
    Policy,
    fit_emu1,
    fit_emu1_corrected,
    fit_nb,
    predict_nb,
    projection_distance,
    simulated_coach_demonstrations,
    table_adverb,
)
from shared.coaching.session import Session, check_attempts, ratio, residual_emphasis, start, trial
from shared.errors import BadInput


@pytest.fixture(scope="module")
def squat(bundled):
    from shared.io import load_clip

    return load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc").resample(30)


def test_table_4_1_and_fixed_policies():
    assert [table_adverb(a) for a in (0.0, 1.5, 2.0, 2.5, 1.2, 3.0)] == [None, "a little more", "more", "much more",
                                                                         "a little more", "much more"]
    assert Policy("fixed", alpha=0.0, adverb=None).choose(10.0) == (0.0, None)  # case 1
    assert Policy("fixed", alpha=0.0, adverb="more like this").choose(10.0) == (0.0, "more like this")  # case 2
    assert Policy("fixed", alpha=2.0, adverb="table").choose(10.0) == (2.0, "more")  # case 4
    with pytest.raises(BadInput):
        Policy("fixed", alpha=9.0).check()
    with pytest.raises(BadInput):
        Policy("nb").check()


def test_aeu_models_use_an_explicit_calibration():
    cal = Calibration.fit([10.0, 20.0, 30.0])
    assert cal.thesis_units(20.0) == pytest.approx(147.5)
    aeu1 = Policy("aeu1", calibration=cal.scale)
    aeu2 = Policy("aeu2", calibration=cal.scale)
    # thesis units 130 / 165 (AEU-1) and 160 / 180 (AEU-2), table 5.2
    assert [aeu1.choose(d)[1] for d in (17.0, 20.0, 23.0)] == ["a little more", "more", "much more"]
    assert [aeu2.choose(d)[1] for d in (20.0, 23.0, 25.0)] == ["a little more", "more", "much more"]
    with pytest.raises(BadInput):
        Calibration.fit([])
    # the separating calibration: on a population's trials, each model says every adverb
    d = np.random.default_rng(0).lognormal(3.0, 0.4, 500)
    sep = Calibration.separating(d)
    for kind in ("aeu1", "aeu2"):
        shares = sep.shares(d, kind)
        assert min(shares.values()) > 0.1, (kind, shares)  # AEU-2's middle band is narrow (160-180)
    first = Calibration.fit(d[:20] * 1.8)  # the first trials' median: later, closer trials say "a little more"
    assert first.shares(d)["a little more"] > 0.75


def test_emu1_and_its_correction_recover_a_coachs_alpha():
    d_p = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_emu1(d_p, 1.8 * d_p) == pytest.approx(2.8)  # eq. 5.5: 1 + slope
    assert projection_distance([0, 0], [-1, 0], [2, 5]) == pytest.approx(2.0)  # only the part along x_p -> x_t
    corrected, plain = fit_emu1_corrected(simulated_coach_demonstrations(200, alpha=1.8, off_line=0.5, seed=3))
    assert abs(corrected - 2.8) < abs(plain - 2.8)  # off-line errors inflate d_s, not d_h
    assert corrected == pytest.approx(2.8, abs=0.15)


def test_naive_bayes_adverbs_match_scikit_learn():
    from sklearn.naive_bayes import GaussianNB

    rng = np.random.default_rng(0)
    x = np.vstack([rng.normal([10, 1], 1, (20, 2)), rng.normal([20, 2], 1, (20, 2)), rng.normal([30, 3], 1, (20, 2))])
    y = ["a little more"] * 20 + ["more"] * 20 + ["much more"] * 20
    params = fit_nb(x, y)
    ref = GaussianNB().fit(x, y)
    probe = rng.uniform([5, 0], [35, 4], (50, 2))
    assert [predict_nb(params, *p) for p in probe] == list(ref.predict(probe))
    assert Policy("nb", nb=params).check().choose(30.0, 3.0) == (2.0, "much more")


def test_residual_emphasis_is_the_target_at_alpha_zero_and_parts_are_ranked(squat):
    ports = LocalCoachPorts()
    ports.build("s", squat)
    g_t = ports.generate("s", {"target": 1.0})
    assert np.allclose(residual_emphasis(squat, g_t, g_t).data, squat.data)
    learner = SimulatedLearner("l", squat, LearnerParams(deviation={"legs": {"scale": 0.5, "offset": 0.0}}))
    attempts = learner.imitate(squat)
    shares = error_shares(squat, attempts)
    assert max(shares, key=shares.get) == "legs" and sum(shares.values()) == pytest.approx(1.0)
    part = partial_emphasis(squat, attempts[0], "legs")
    arm = squat.channels.index("rhumerus.rx")
    leg = squat.channels.index("rfemur.rx")
    assert np.array_equal(part.data[:, arm], squat.data[:, arm]) and not np.array_equal(part.data[:, leg], squat.data[:, leg])


def test_a_local_session_coaches_and_refuses_bad_attempts(squat):
    ports = LocalCoachPorts(squat.skeleton)
    s = Session("t", squat, Policy("fixed", alpha=2.0, adverb="table"))
    start(s, ports)
    learner = SimulatedLearner("l", squat, population(4, 0)[3])
    demo, adverb = squat, None
    for _ in range(4):
        rec, demo = trial(s, learner.imitate(demo, adverb), ports)
        adverb = rec.adverb
        assert rec.alpha == 2.0 and 0.0 <= rec.alpha_shown <= 2.0 and rec.feasibility
        assert demo.channels == squat.channels
    r = ratio([s.d()])
    assert r[0] == 1.0 and len(r) == 4 and np.all(np.isfinite(r)) and np.allclose(r * s.d()[0], s.d())
    with pytest.raises(BadInput, match="lacks"):
        check_attempts(s, [squat.with_data(squat.data[:, :10], channels=squat.channels[:10],
                                           groups={"motion": squat.channels[:10]})])
    with pytest.raises(BadInput, match="too short"):
        check_attempts(s, [squat.frames(0, 5)])
    from shared.reports.evaluation import on_studio_skeleton

    with pytest.raises(BadInput, match=r"lacks \d+ of the target's channels.*it is on another skeleton, 0 of the 31"):
        check_attempts(s, [on_studio_skeleton(squat)])  # the coach compares joint angles: one skeleton
    assert len(s.trials) == 4


def test_the_coach_says_when_nothing_could_be_checked(squat):
    from shared.agents.learner import SimulatedLearner, population

    s = Session("u", squat, Policy("fixed", alpha=2.0, adverb="table"))
    ports = LocalCoachPorts(None)  # no simulator body for this target
    start(s, ports)
    rec, _ = trial(s, SimulatedLearner("l", squat, population(4, 0)[1]).imitate(squat, None), ports)
    assert rec.feasibility.startswith("not checked: joint limits and balance")
    s2 = Session("v", squat, Policy("fixed", alpha=2.0, adverb="table"))
    ports2 = LocalCoachPorts(squat.skeleton)  # an ASF body: limits and feet, both checked
    start(s2, ports2)
    rec2, _ = trial(s2, SimulatedLearner("l", squat, population(4, 0)[1]).imitate(squat, None), ports2)
    assert "not checked" not in rec2.feasibility


def test_sub_goal_coaching_plans_parts_by_error_and_moves_on(squat):
    """Thesis 4.6 / 7.3: sub-goals are the first attempt with the worst parts set to the
    target's, in order of error; the coach moves on after SUBGOAL_TRIALS trials at most."""
    from shared.agents.learner import LearnerParams, SimulatedLearner, body_part
    from shared.coaching.parts import rotation_channels
    from shared.coaching.session import SUBGOAL_TRIALS, subgoal_motion

    ports = LocalCoachPorts(squat.skeleton)
    s = Session("sg", squat, Policy("fixed", alpha=1.0, adverb=None, subgoal=True), check=False)
    start(s, ports)
    learner = SimulatedLearner("l", squat, LearnerParams(
        family="copy", noise=0.3, deviation={"arms": {"scale": 0.5, "offset": 8.0}, "legs": {"scale": 0.8, "offset": 3.0}}))
    first = learner.imitate(squat)
    shares = error_shares(squat, first)
    demo = None
    goals = []
    for k in range(5):
        rec, demo = trial(s, first if k == 0 else learner.imitate(demo), ports)
        goals.append(rec.goal)
    order = s.subgoals["order"]
    assert order == [p for p in sorted(shares, key=shares.get, reverse=True) if shares[p] >= 0.1] and len(order) >= 2
    assert goals[0] == s.subgoals["goals"][0]["name"] and s.subgoals["goals"][0]["parts"] == order[:1]
    assert all(g["name"] in ports.points(s.space) for g in s.subgoals["goals"])  # proto-symbols in the space
    names = [g["name"] for g in s.subgoals["goals"]] + ["target"]
    idx = [names.index(g) for g in goals]
    assert idx == sorted(idx) and all(idx.count(i) <= SUBGOAL_TRIALS for i in set(idx[:-1]))
    assert idx[-1] == len(names) - 1  # it reached the target within 5 trials
    mid = subgoal_motion(squat, first, order[:1])
    rot = set(rotation_channels(squat))
    worst = [c for c in rot if body_part(c) == order[0]]
    rest = [c for c in rot if body_part(c) == order[1]]
    assert np.allclose(mid.select(worst), squat.select(worst))
    assert not np.allclose(mid.select(rest), squat.select(rest))
    with pytest.raises(BadInput, match="not both"):
        Policy("fixed", body_part=True, subgoal=True).check()


def test_an_infeasible_emphatic_motion_is_made_feasible_where_it_can_be(squat):
    """Joint angles beyond their limits are held at them, channel by channel; phases where the
    centre of gravity leaves the support go back to the target, the rest keeps its emphasis;
    the repaired motion passes the check and the reply says what was changed."""
    from shared.coaching.feasibility import make_feasible, outside_frames, worse_than_target

    ports = LocalCoachPorts(squat.skeleton)
    target_report, _ = ports.perform(squat)
    perform = lambda c: ports.perform(c)[0]  # noqa: E731
    # 1. one knee bent 60 degrees past its limit in the middle third
    k = squat.channels.index("rtibia.rx")
    data = squat.data.copy()
    n = squat.n_frames
    mid = slice(n // 3, 2 * n // 3)
    report = perform(squat.with_data(data))
    assert worse_than_target(report, target_report, squat) is None
    over = max(float(squat.column("rtibia.rx").max()), 170.0) + 60.0
    data[mid, k] = over
    bent = squat.with_data(data)
    report = perform(bent)
    assert "rtibia.rx" in (worse_than_target(report, target_report, squat) or "")
    fixed, changes = make_feasible(squat, bent, report, target_report, squat, perform)
    assert worse_than_target(perform(fixed), target_report, squat) is None and "rtibia.rx" in changes[0]
    others = [i for i in range(len(squat.channels)) if i != k]
    np.testing.assert_array_equal(fixed.data[:, others], bent.data[:, others])  # nothing else touched
    # 2. the whole body leaning over (the root pitched 40 degrees) in the middle third only
    data = squat.data.copy()
    r = squat.channels.index(f"{squat.skeleton.root.name}.rx")
    ramp = np.clip(np.sin(np.linspace(-np.pi / 2, 3 * np.pi / 2, n)), 0, 1)  # 0 at both ends, 1 in the middle
    data[:, r] += 40.0 * ramp
    lean = squat.with_data(data)
    report = perform(lean)
    assert "centre of " in (worse_than_target(report, target_report, squat) or "")  # of gravity or of pressure: off balance
    fixed, changes = make_feasible(squat, lean, report, target_report, squat, perform)
    after = perform(fixed)
    assert worse_than_target(after, target_report, squat) is None and any("balance" in c for c in changes), changes
    outside = outside_frames(report, n)
    kept = ~outside & (np.abs(fixed.data[:, r] - lean.data[:, r]) < 1e-9)
    assert kept.sum() > 0.3 * n  # the emphasis stays where the balance held


def test_a_session_shows_the_repaired_emphasis_instead_of_lowering_alpha(bundled):
    """The target the issue found alpha 0 on every trial (a squat of actor dg): the policy's
    alpha is shown, made feasible, and the record says how much of the emphasis was kept."""
    from shared.io import load_clip

    target = load_clip(sorted((bundled / "amc/squat1Reps").glob("*.amc"))[-1]).resample(30)
    ports = LocalCoachPorts(target.skeleton)
    s = Session("f", target, Policy("fixed", alpha=2.0, adverb="table"))
    start(s, ports)
    learner = SimulatedLearner("l", target, population(2, 0)[0])
    demo, adverb = target, None
    for _ in range(3):
        rec, demo = trial(s, learner.imitate(demo, adverb), ports)
        adverb = rec.adverb
        assert rec.alpha_shown == 2.0 and not rec.alpha_reduced, rec.feasibility
        assert rec.emphasis_kept is None or (0.0 < rec.emphasis_kept <= 1.0 and "made feasible" in rec.feasibility)


def test_aeu_thresholds_are_fitted_from_coaches_and_backward_coaches_left_out():
    from shared.coaching.policies import ADVERBS, fit_aeu

    rng = np.random.default_rng(0)
    rows = []
    for coach in ("c1", "c2"):  # adverbs rise with the error: cuts at 40 and 70
        for d in rng.uniform(10, 100, 30):
            rows.append({"coach": coach, "d_p": float(d), "adverb": ADVERBS[int(d > 40) + int(d > 70)]})
    for d in rng.uniform(10, 100, 30):  # c3 says "much more" for small errors
        rows.append({"coach": "c3", "d_p": float(d), "adverb": ADVERBS[2 - int(d > 40) - int(d > 70)]})
    rows += [{"coach": "c4", "d_p": 50.0, "adverb": "more"}] * 3  # one adverb only
    fit = fit_aeu(rows)
    assert fit["coaches"] == ["c1", "c2"] and set(fit["excluded"]) == {"c3", "c4"}
    assert "backwards" in fit["excluded"]["c3"] and fit["agreement"] == 1.0
    t1, t2 = fit["thresholds"]
    assert 30 < t1 <= 41 and 65 < t2 <= 71
    p = Policy.from_dict({"kind": "aeu1", "alpha": 2.0, "thresholds": [t1, t2]})
    assert [p.choose(d)[1] for d in (20.0, 55.0, 90.0)] == list(ADVERBS)
    with pytest.raises(BadInput, match="at least 3 answers"):
        fit_aeu([r for r in rows if r["coach"] in ("c3", "c4")])
    with pytest.raises(BadInput, match="thresholds"):
        Policy.from_dict({"kind": "aeu1", "thresholds": [50.0, 10.0]})


def test_a_learner_feels_effort_and_a_demonstration_beyond_its_strength_is_taken_in_part(squat):
    """Thesis 6.5.1 (shared/coaching/effort.py): a learner with a strength feels the target at
    1/strength, answers a word for it, and follows a motion beyond its strength only in part."""
    from shared.coaching.effort import word

    p = population(2, 0)[1]
    strong, weak = (SimulatedLearner(n, squat, LearnerParams(**{**p.__dict__, "strength": s}))
                    for n, s in (("strong", 10.0), ("weak", 1.2)))
    assert strong.felt_effort(squat) == pytest.approx(0.1) and weak.felt_effort(squat) == pytest.approx(1 / 1.2)
    strong.imitate(squat, None)
    weak.imitate(squat, None)
    assert (strong.felt, weak.felt) == (word(0.1), word(1 / 1.2)) == (1, 4)
    # a motion twice as far from the learner as the target: the weak body feels it beyond its strength
    big = squat.with_data(squat.data.copy())
    idx = [squat.channels.index(c) for c in strong.channels]
    big.data[:, idx] = squat.data[:, idx] + 1.5 * (squat.data[:, idx] - squat.data[:, idx].mean(axis=0))
    g = weak.felt_effort(big)
    assert g > 1.0 > strong.felt_effort(big)
    before = weak.memory.copy()
    unlimited = SimulatedLearner("u", squat, LearnerParams(**{**p.__dict__, "strength": None}), memory=before.copy(),
                                 trials=weak.trials, reference=weak.reference)
    weak.imitate(big, None)
    unlimited.imitate(big, None)
    step_weak = np.linalg.norm(weak.memory - before)
    step_free = np.linalg.norm(unlimited.memory - before)
    assert 0 < step_weak < step_free and unlimited.felt is None
    with pytest.raises(BadInput, match="skeleton"):
        SimulatedLearner("n", squat.with_data(squat.data, skeleton=None), LearnerParams(strength=2.0))


def test_the_effort_policy_keeps_the_emphasis_within_what_the_learner_says_it_can_give(squat):
    """Thesis 6.5.1: with the effort policy the coach asks the learner's word after each trial
    (chapter 3's interval estimator) and lowers alpha where the predicted felt effort is beyond
    its strength; the answers it got bound the learner's true scale."""
    from shared.coaching.effort import LANGUAGE

    ports = LocalCoachPorts(squat.skeleton)
    params = LearnerParams(**{**population(2, 0)[1].__dict__, "strength": 1.6})
    runs = {}
    for effort in (False, True):
        s = Session(f"e{effort}", squat, Policy("fixed", alpha=3.0, adverb="table", effort=effort), check=False)
        start(s, ports)
        learner = SimulatedLearner("l", squat, params)
        demo, adverb, felt, truth = squat, None, [], []
        for _ in range(3):
            attempts = learner.imitate(demo, adverb)
            felt.append(learner.felt)
            rec, demo = trial(s, attempts, ports, learner.felt if effort else None)
            adverb = rec.adverb
            truth.append(learner.felt_effort(demo))
        runs[effort] = (s, felt, truth)
    plain, aware = runs[False][0], runs[True][0]
    assert all(t.alpha_shown == 3.0 for t in plain.trials) and all(t.felt is None for t in plain.trials)
    assert [t.felt for t in aware.trials] == runs[True][1]
    lo, hi = aware.effort.interval()
    assert lo <= 1 / 1.6 <= hi  # the learner's true scale is inside what its answers allow
    # where the coach lowered alpha it said why, and what it predicted is within the learner's strength
    for t in aware.trials:
        if t.alpha_reduced:
            assert "of its strength" in t.feasibility and t.alpha_shown < 3.0
        if t.felt_predicted is not None:
            assert t.felt_predicted <= LANGUAGE.g_max or t.alpha_shown == 0.0
    assert any(t.alpha_reduced for t in aware.trials)
    # the coach's prediction of how heavy the next motion will feel is within one word of the truth
    assert all(abs(t.felt_predicted - g) < 1 / LANGUAGE.d for t, g in zip(aware.trials, runs[True][2]))
    assert max(runs[False][2]) > LANGUAGE.g_max  # without the policy, a motion beyond its strength was shown
    with pytest.raises(BadInput, match="does not ask for felt effort"):
        trial(plain, attempts, ports, 2)


def test_a_motion_balanced_in_every_pose_but_too_fast_is_shown_slower(squat):
    """Arms swung fast over a pose held still: the centre of gravity stays over the feet in every
    frame, the centre of pressure the swing needs does not. Its shape is feasible, its speed is
    not: the repair shows the same frames slower (the forces beyond the weight fall with the
    square of the speed) instead of taking the emphasis out, and says so."""
    from shared.coaching.feasibility import TEMPOS, make_feasible, worse_than_target

    ports = LocalCoachPorts(squat.skeleton)
    still = np.repeat(squat.data[10:11], 60, axis=0)

    def swung(hz):
        data = still.copy()
        for arm in ("lhumerus.rx", "rhumerus.rx"):
            data[:, squat.channels.index(arm)] += 30.0 * np.sin(2 * np.pi * hz * np.arange(60) / 30.0)
        return squat.with_data(data)

    target, swing = swung(0.5), swung(2.5)  # the same poses, five times as fast
    target_report, _ = ports.perform(target)
    report, _ = ports.perform(swing)
    assert "centre of pressure" in (worse_than_target(report, target_report, target) or "")
    assert worse_than_target(report, target_report, target, dynamic=False) is None
    fixed, changes = make_feasible(target, swing, report, target_report, target, lambda c: ports.perform(c)[0])
    assert fixed.fps in [target.fps * t for t in TEMPOS] and "of its speed" in changes[0], changes
    np.testing.assert_array_equal(fixed.data, swing.data)  # every frame as it was, shown slower
    assert worse_than_target(ports.perform(fixed)[0], target_report, target) is None


def test_the_balance_tolerance_is_what_real_takes_measure(hdm05, tmp_path):
    """BALANCE_TOLERANCE is the 95th percentile of real takes judged against one another
    (``bench.balance``, actors bd and bk): rerun on the data, the numbers come back."""
    import json

    from bench.balance import main
    from shared.coaching.feasibility import BALANCE_TOLERANCE

    assert main(["--hdm05", str(hdm05), "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "balance.json").read_text())
    assert res["actors"] == ["bd", "bk"] and res["pairs"] > 200
    for kind, tolerance in BALANCE_TOLERANCE.items():
        assert res["tests"][kind]["tolerance"] == pytest.approx(tolerance, abs=0.005), kind


def test_warming_the_coach_loads_every_kernel_a_trials_scoring_runs():
    """In a fresh process, ``warm()`` (run at the coach service's start) leaves nothing for a first
    trial's eq. 6.5 distance to compile or load: the same kernels and machine code after a real one."""
    import subprocess
    import sys

    code = """
import numpy as np
from shared.coaching import session
from shared.pss import hmm

def loaded():
    k = hmm._estep_scaled._compiled
    return None if k is None else sorted(map(str, k.signatures))

assert loaded() is None
session.warm()
before = loaded()
r = np.random.default_rng(1)
session._d_cop(r.normal(size=(90, 3)), r.normal(size=(75, 3)))  # a trial's centres of gravity
assert before and loaded() == before, (before, loaded())
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
