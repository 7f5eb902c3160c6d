"""The chapter-3 symbols and simulated others; the simulated learners of chapters 4-6."""

from __future__ import annotations

import numpy as np
import pytest

from shared.agents.learner import FAMILIES, LearnerParams, SimulatedLearner, population, to_phase
from shared.agents.other import OtherParams, SimulatedOther
from shared.errors import BadInput
from shared.estimation.symbols import WORDS, compare, f_conv, f_div, index_of, word
from shared.motion.clip import Clip


def _bump(n, centre, width, peak):
    t = np.arange(n)
    return peak * np.exp(-0.5 * ((t - centre) / width) ** 2)


@pytest.mark.parametrize("a", [1.0, 0.5])
def test_the_thesis_m3_m4_example_identifies_f2_f3_f4(a):
    """m4 bends all 4 joints at once with equal peaks a; m3 moves them one after another with
    peaks (3a, 0.4a, 0.4a, 0.2a) (eq. 3.17-3.19): f2 4a vs 4a, f3 3a vs 4a, f4 3a vs a."""
    n = 400
    m4 = np.column_stack([_bump(n, 200, 20, a)] * 4)
    m3 = np.column_stack([_bump(n, c, 12, p * a) for c, p in zip((50, 150, 250, 350), (3.0, 0.4, 0.4, 0.2))])
    assert f_conv(m3, "f2") == pytest.approx(4 * a, rel=1e-3) and f_conv(m4, "f2") == pytest.approx(4 * a, rel=1e-3)
    assert f_conv(m3, "f3") == pytest.approx(3 * a, rel=1e-3) and f_conv(m4, "f3") == pytest.approx(4 * a, rel=1e-3)
    assert f_conv(m3, "f4") == pytest.approx(3 * a, rel=1e-3) and f_conv(m4, "f4") == pytest.approx(a, rel=1e-3)
    answers = {r: compare(f_conv(m3, r), f_conv(m4, r)) for r in ("f2", "f3", "f4")}
    assert answers == {"f2": "equal", "f3": "<", "f4": ">"}


def test_m1_m2_equal_means_identify_f1():
    n = 300
    m1 = np.full((n, 4), 0.5)
    m2 = np.zeros((n, 4))
    m2[:150] = 1.0  # twice the torque for half the time: same mean, larger maxima
    assert compare(f_conv(m1, "f1"), f_conv(m2, "f1")) == "equal"
    assert all(compare(f_conv(m1, r), f_conv(m2, r)) == "<" for r in ("f2", "f3", "f4"))


def test_eq_3_8_and_bins_and_words():
    tau = np.array([[1.0, -2.0, 0.5], [0.0, 1.0, -1.0]])
    assert f_conv(tau, "eq3.8", tau_max=2.0) == pytest.approx(((3.5 + 2.0) / 2) / 2.0)
    assert [f_div(g, 4) for g in (-1, 0, 0.24, 0.25, 0.74, 0.99, 1.0, 7)] == [1, 1, 1, 2, 3, 4, 4, 4]
    assert WORDS[2] == ("light", "heavy") and WORDS[4] == ("light", "bit light", "bit heavy", "heavy")
    assert WORDS[6][0] == "very light" and WORDS[6][-1] == "very heavy" and len(WORDS[8]) == 8
    for d in WORDS:
        assert [index_of(word(k, d), d) for k in range(1, d + 1)] == list(range(1, d + 1))
    with pytest.raises(BadInput, match="the words are"):
        index_of("featherweight", 4)
    with pytest.raises(BadInput):
        f_conv(tau, "f9")


def _arm_motion(amplitude=60.0, n=90):
    t = np.linspace(0, 3, n)
    data = np.column_stack([amplitude * (1 - np.cos(t)), 10 * np.sin(t), -30 - 20 * np.sin(2 * t), np.zeros(n)])
    return Clip(data, ["shoulder_pitch", "shoulder_roll", "elbow", "knee"], 30.0, name=f"raise{amplitude:g}")


def test_a_heavier_other_feels_heavier_and_answers_reproducibly():
    light = SimulatedOther("r1", OtherParams(mass=2.4, d=8, tau_max=1.0, g_max=1.0))
    heavy = SimulatedOther("r2", OtherParams(mass=4.8, d=8, tau_max=1.0, g_max=1.0))
    m = _arm_motion()
    assert heavy.g(m) == pytest.approx(2 * light.g(m), rel=1e-9)
    k_light, k_heavy = index_of(light.answer_open(m), 8), index_of(heavy.answer_open(m), 8)
    assert k_heavy > k_light
    assert heavy.answer_compare(_arm_motion(80), _arm_motion(20)) == ">"
    assert heavy.answer_compare(_arm_motion(20), _arm_motion(80)) == "<"
    assert heavy.answer_compare(m, m) == "equal"
    back = SimulatedOther.from_dict(heavy.to_dict())
    assert back.reveal() == heavy.reveal() and back.answer_open(m) == heavy.answer_open(m)
    assert heavy.reveal()["mass"] == 4.8 and heavy.reveal()["rule"] == "eq3.8"


def test_answer_noise_is_one_bin_off_at_the_set_rate():
    clean = SimulatedOther("c", OtherParams(d=8, noise=0.0))
    noisy = SimulatedOther("n", OtherParams(d=8, noise=0.3, seed=11))
    m = _arm_motion(45)
    k = index_of(clean.answer_open(m), 8)
    got = [index_of(noisy.answer_open(m), 8) for _ in range(200)]
    off = np.array(got) - k
    assert set(np.unique(off)) <= {-1, 0, 1}
    assert 0.2 < np.mean(off != 0) < 0.4
    again = SimulatedOther("n", OtherParams(d=8, noise=0.3, seed=11))
    assert [index_of(again.answer_open(m), 8) for _ in range(200)] == got


def test_an_other_can_answer_like_a_person():
    """An other may answer like a person: its own word boundaries (gamma), drifting with the questions, and "I don't know",
    which the dialogue's parser understands as no word."""
    from shared.estimation.symbols import DONT_KNOW, parse_answer

    m = _arm_motion(45)
    plain = SimulatedOther("p", OtherParams(d=8, g_max=1.0))
    g = plain.g(m)
    assert 0 < g < 1
    for gamma in (0.5, 2.0):
        own = SimulatedOther("o", OtherParams(d=8, g_max=1.0, gamma=gamma))
        assert index_of(own.answer_open(m), 8) == f_div(g ** gamma, 8, 1.0)
    drifting = SimulatedOther("d", OtherParams(d=8, g_max=1.0, drift=0.05))
    words = [index_of(drifting.answer_open(m), 8) for _ in range(30)]
    assert words[0] == f_div(g, 8, 1.0) and words[-1] > words[0] and words == sorted(words)
    unsure = SimulatedOther("u", OtherParams(d=8, dont_know=0.5, seed=2))
    said = [unsure.answer_open(m) for _ in range(200)]
    assert 0.35 < np.mean([a == "I don't know" for a in said]) < 0.65
    assert {parse_answer(a, "open", 8) for a in said} - set(WORDS[8]) == {DONT_KNOW}
    for text in ("I don't know", "not sure", "No idea!", "hard to say"):
        assert parse_answer(text, "open", 4) == DONT_KNOW
    with pytest.raises(BadInput):
        OtherParams(gamma=9.0).check()


def test_bad_other_parameters_are_refused():
    for bad in ({"rule": "f7"}, {"d": 3}, {"joints": ["tail"]}, {"noise": 1.5}, {"tau_max": 0.0},
                {"weights": [1.0, 2.0]}, {"mass": 1e5}):
        with pytest.raises(BadInput):
            SimulatedOther("x", OtherParams(**bad))


# ---------------------------------------------------------------------------- learners
@pytest.fixture(scope="module")
def squat(bundled):
    from shared.io import load_clip

    return load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc").resample(30)


def _emphatic(learner, attempts, alpha):
    """x_t + alpha (x_t - x_p) in joint space: a stand-in for the PSS's emphatic motion."""
    tp = learner.target_phase
    p = np.mean([to_phase(a, learner.channels) for a in attempts], axis=0)
    d = tp + alpha * (tp - p)
    grid = np.linspace(0, 1, 60)
    return Clip(np.column_stack([np.interp(grid, np.linspace(0, 1, len(d)), d[:, c]) for c in range(d.shape[1])]),
                learner.channels, 30.0, name="demo")


def _rms(x, mask):
    return float(np.sqrt(np.mean(x[:, mask.astype(bool)] ** 2)))


@pytest.mark.slow
def test_the_thesis_family_follows_its_documented_rule(squat):
    """One trial moves the memory by min(gain a (1 + o_s x), 1) P(D - m) (module docstring): the
    model as written, not whether emphasis helps."""
    p = population(1, seed=3)[0]
    learner = SimulatedLearner("l", squat, p)
    m0, tp, mask = learner.memory.copy(), learner.target_phase, learner._imitated
    learner.imitate(squat)  # first shown: the reference, x = 0
    expected = m0 + min(p.gain, 1.0) * learner.perceive((tp - m0) * mask)
    assert np.allclose(learner.memory, expected)
    m1 = learner.memory.copy()
    demo = _emphatic(learner, [learner.target.with_data(learner.target.data)], 1.0)  # 2 x_t - m
    d = to_phase(demo, learner.channels)
    x = min(_rms(d - tp, mask) / _rms(tp - m1, mask), 5.0)
    a = 1.0 + p.adverb_sensitivity * 0.2
    learner.imitate(demo, "more")
    assert np.allclose(learner.memory, m1 + min(p.gain * a * (1 + p.overshoot * x), 1.0) * learner.perceive((d - m1) * mask))
    below = SimulatedLearner("l", squat, p)  # a difference under the perception threshold is not seen
    small = below.memory + 0.5 * p.threshold * mask
    before = below.memory.copy()
    below.imitate(_phase_clip(below, small))
    assert np.array_equal(below.memory, before)


def _phase_clip(learner, phase):
    grid = np.linspace(0, 1, 60)
    return Clip(np.column_stack([np.interp(grid, np.linspace(0, 1, len(phase)), phase[:, c]) for c in range(phase.shape[1])]),
                learner.channels, 30.0, name="demo")


def test_the_error_based_family_corrects_towards_what_it_is_shown_from_its_own_performance(squat):
    """m <- m0 + A (m - m0) + clip(gain a_r, 0, 1) P(D - p), p its last performance; the target is
    never read: shown the same motions, learners of two different targets with the same habit
    move the same way."""
    p = population(1, seed=4, family="error_based")[0]
    learner = SimulatedLearner("l", squat, p)
    habit, mask = learner.memory.copy(), learner._imitated
    other_target = squat.with_data(squat.data + 7.0)  # a different target, the same habit and channels
    twin = SimulatedLearner("t", other_target, p, memory=habit.copy())
    twin._initial = lambda: habit.copy()
    for demo, adverb in ((squat, None), (_phase_clip(learner, learner.memory + 12.0 * mask), "much more")):
        performed = learner.performed()
        assert np.allclose(performed, twin.performed())
        a = 1.0 + p.adverb_response * (1.35 - 1.0) if adverb else 1.0
        expected = habit + p.retention * (learner.memory - habit) + np.clip(p.gain * a, 0, 1) * learner.perceive(
            (to_phase(demo, learner.channels) - performed) * mask)
        learner.imitate(demo, adverb)
        twin.imitate(demo, adverb)
        assert np.allclose(learner.memory, expected) and np.allclose(twin.memory, learner.memory)


@pytest.mark.parametrize("response", [-1.2, 1.2])
def test_an_error_based_learner_s_adverb_can_hurt_as_well_as_help(squat, response):
    """The adverb response is drawn per learner in [-1.5, 1.5] (some of each sign in a
    population); "much more" then leaves a learner with r < 0 further from the target after a
    trial than no word does, and one with r > 0 closer."""
    drawn = [q.adverb_response for q in population(40, seed=0, family="error_based")]
    assert min(drawn) < -0.5 and max(drawn) > 0.5
    p = population(1, seed=4, family="error_based")[0]
    p.adverb_response, p.noise = response, 0.0
    errors = {}
    for adverb in (None, "much more"):
        learner = SimulatedLearner("l", squat, p)
        learner.imitate(squat, adverb)
        errors[adverb] = learner.error()
    assert (errors["much more"] > errors[None]) == (response < 0)
    assert abs(errors["much more"] - errors[None]) > 0.01


def test_the_two_rate_family_follows_smith_et_al_2006(squat):
    """x_f <- 0.59 x_f + 0.21 e, x_s <- 0.992 x_s + 0.02 e, m = m0 + x_f + x_s; words ignored;
    the fast state survives a save and load of the learner."""
    from shared.agents.learner import TWO_RATE

    p = population(1, seed=6, family="two_rate")[0]
    learner = SimulatedLearner("l", squat, p)
    habit, mask = learner.memory.copy(), learner._imitated
    xf, xs = np.zeros_like(habit), np.zeros_like(habit)
    for adverb in (None, "much more", None):
        e = learner.perceive((to_phase(squat, learner.channels) - learner.performed()) * mask)
        xf, xs = TWO_RATE["A_f"] * xf + TWO_RATE["B_f"] * e, TWO_RATE["A_s"] * xs + TWO_RATE["B_s"] * e
        learner.imitate(squat, adverb)
        assert np.allclose(learner.memory, habit + xf + xs) and np.allclose(learner.fast, xf)
    assert TWO_RATE == {"A_f": 0.59, "B_f": 0.21, "A_s": 0.992, "B_s": 0.02}


def test_the_null_families_copy_or_step_and_ignore_words(squat):
    """copy: the memory becomes what it saw; fixed_step: a step of ``step`` degrees RMS in the
    direction of the difference, blind to its size: a demonstration m + k (D - m), k >= 1, with
    a difference that is not uniform over channels (some far below any threshold), moves it
    exactly as D does; neither hears adverbs."""
    p = population(1, seed=5, family="copy")[0]
    learner = SimulatedLearner("l", squat, p)
    mask = learner._imitated.astype(bool)
    demo = _phase_clip(learner, learner.memory + 20.0)
    learner.imitate(demo, "much more")
    assert np.allclose(learner.memory[:, mask], to_phase(demo, learner.channels)[:, mask])
    q = population(1, seed=5, family="fixed_step")[0]
    base = SimulatedLearner("l", squat, q)
    rng = np.random.default_rng(0)
    # per channel: large, small (1 degree, below the population's thresholds) or none
    shape = rng.choice([30.0, 1.0, 0.0], size=base.memory.shape[1]) * base._imitated
    direction = shape * np.sin(np.linspace(0, np.pi, base.memory.shape[0]))[:, None]
    moved = []
    for k, adverb in ((1.0, None), (2.5, "much more"), (6.0, "a little more")):
        s = SimulatedLearner("l", squat, q)
        start = s.memory.copy()
        s.imitate(Clip(start + k * direction, s.channels, 30.0, name="demo"), adverb)  # on the phase axis itself
        moved.append(s.memory - start)
        assert _rms(moved[-1], s._imitated) == pytest.approx(q.step, rel=1e-6)
    for m in moved[1:]:  # the same step, channel by channel
        np.testing.assert_allclose(m, moved[0], atol=1e-9)
    near = SimulatedLearner("l", squat, q)  # a difference shorter than the step: all the way
    goal = near.memory + 0.5 * q.step * near._imitated
    near.imitate(_phase_clip(near, goal))
    assert _rms(near.memory - goal, near._imitated) < 0.05 * q.step


def test_families_share_the_population_draws_and_replicates_get_fresh_noise(squat):
    fams = [population(3, seed=2, family=f) for f in FAMILIES]
    assert all(a.gain == b.gain and a.deviation == b.deviation and a.seed == b.seed for pop in fams[1:]
               for a, b in zip(fams[0], pop))
    again = population(3, seed=2, replicate=1)
    assert all(a.gain == b.gain and a.seed != b.seed for a, b in zip(fams[0], again))
    one, two = (SimulatedLearner("l", squat, pop[0]).imitate(squat) for pop in (fams[0], again))
    assert not np.allclose(one[0].data, two[0].data)
    with pytest.raises(BadInput, match="family"):
        population(2, family="oracle")
    from schemas.simulator import FAMILIES as WIRE

    assert WIRE == FAMILIES


def test_attempts_are_five_seeded_repetitions(squat):
    pop = population(12, seed=1)
    learner = SimulatedLearner("l", squat, pop[0])
    a1 = learner.imitate(squat)
    assert len(a1) == 5 and all(a.channels == squat.channels and np.all(np.isfinite(a.data)) for a in a1)
    assert not np.allclose(a1[0].data, a1[1].data)  # motor noise differs between repetitions
    twin = SimulatedLearner("l", squat, pop[0])
    assert all(np.array_equal(x.data, y.data) for x, y in zip(a1, twin.imitate(squat)))
    assert learner.reveal()["trials"] == 1 and learner.reveal()["gain"] == pop[0].gain
    with pytest.raises(BadInput, match="adverb"):
        learner.imitate(squat, "way more")
    with pytest.raises(BadInput, match="lacks"):
        learner.imitate(_arm_motion())


def test_no_demonstration_brings_a_fixed_step_learner_closer_than_the_target(squat):
    """The null world as documented: emphatic demonstrations x_t + alpha (x_t - x_p) (eq. 4.3 on
    the phase axis, x_p the learner's own performance) never leave a fixed_step learner's
    memory closer to the target than showing the target does, trial after trial."""
    for q in population(4, seed=9, family="fixed_step"):
        q.noise = 0.0
        errors = {}
        for alpha in (0.0, 0.5, 1.0, 2.0, 3.0):
            learner = SimulatedLearner("l", squat, q)
            target = learner.target_phase
            errors[alpha] = []
            for _ in range(4):
                shown = target + alpha * (target - learner.performed())
                learner.imitate(Clip(shown, learner.channels, 30.0, name="demo"))
                errors[alpha].append(learner.error())
        for alpha in (0.5, 1.0, 2.0, 3.0):
            assert all(e >= e0 - 1e-6 for e, e0 in zip(errors[alpha], errors[0.0])), (q.step, alpha, errors)


def test_the_report_s_word_against_the_target_alone_is_computed_from_the_numbers():
    """Holm-adjusted paired tests of every condition against case 1: a condition clearly lower
    is named; in a world where nothing differs, none is."""
    from shared.reproduce.coaching_report import against_target, holm, null_sentence

    np.testing.assert_allclose(holm([0.01, 0.04, 0.03, 0.005]), [0.03, 0.06, 0.06, 0.02])
    rng = np.random.default_rng(0)
    base = 1.0 + rng.uniform(0, 0.2, size=(12, 4))
    base[:, 0] = 1.0

    def world(lower: float) -> dict:
        same = base.tolist()
        better = (base - lower * np.linspace(0, 1, 4)).tolist()
        return {"cases": {1: same, 2: same, 3: better, 4: same, 5: same, 6: same, 7: same, 8: same},
                "sweep": {"0|none": same, "2|none": better}, "subgoal": {"d": same}, "body_part": {"d": same},
                "nb": {"d": None}, "feasibility": {"d": same}}

    rows = {r["condition"]: r for r in against_target(world(0.3))}
    assert rows["case 3: alpha 2, no adverb"]["word"] == "holds" and rows["alpha 2"]["word"] == "holds"
    assert rows["case 2: alpha 0 + 'more like this'"]["word"] == "not lower" and "naive Bayes" not in rows
    assert "on squat, 2 of 11 conditions ended lower" in null_sentence("thesis", {"squat": world(0.3)})
    assert "on squat, none of 11 conditions ended lower" in null_sentence("copy", {"squat": world(0.0)})


def test_naive_bayes_across_tasks_is_reported_against_the_own_task():
    from shared.reproduce.coaching_report import nb_transfer_lines

    rng = np.random.default_rng(1)
    own = 1.0 + rng.uniform(0, 0.05, size=(10, 4))
    own[:, 0] = 1.0
    worse = own + np.linspace(0, 0.3, 4)
    results = {"nb_transfer": {"thesis": {"squat>throw": {"d": worse.tolist(), "own_d": own.tolist()},
                                          "throw>squat": {"d": None, "own_d": own.tolist(), "why": "one adverb"}}}}
    text = "\n".join(nb_transfer_lines(results))
    assert "| thesis | squat -> throw |" in text and "+0.300 (own task lower: holds" in text
    assert "| thesis | throw -> squat | - | - | not run: one adverb |" in text


def test_every_learner_family_has_a_sensitivity_sweep_of_its_own_parameters():
    from dataclasses import fields

    from shared.agents.learner import LearnerParams
    from shared.reproduce.coaching_stats import SENSITIVITY

    assert set(SENSITIVITY) == set(FAMILIES)
    names = {f.name for f in fields(LearnerParams)}
    assert all(set(params) <= names for params in SENSITIVITY.values())


def test_every_swept_parameter_changes_what_its_family_does(squat):
    """A sensitivity row whose parameter the family ignores would be three identical rows."""
    from dataclasses import asdict

    from shared.reproduce.coaching_stats import SENSITIVITY

    base = population(1, 0)[0]
    demo = squat.with_data(squat.data * 1.2)
    for family, params in SENSITIVITY.items():
        for name, values in params.items():
            outs = []
            for v in (values[0], values[-1]):
                learner = SimulatedLearner("l", squat, LearnerParams(**{**asdict(base), "family": family, name: v}))
                learner.imitate(squat, None)  # the target first, as a session shows it (the overshoot's reference)
                outs.append(np.concatenate([a.data.ravel() for a in learner.imitate(demo, None)]))
            assert not np.allclose(outs[0], outs[1]), (family, name)
