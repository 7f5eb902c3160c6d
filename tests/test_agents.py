"""The chapter-3 symbols and simulated others; the simulated learners of chapters 4-6."""

from __future__ import annotations

import numpy as np
import pytest

from shared.agents.learner import SimulatedLearner, population, to_phase
from shared.agents.other import OtherParams, SimulatedOther
from shared.clip import Clip
from shared.errors import BadInput
from shared.symbols import WORDS, compare, f_conv, f_div, index_of, word


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


def _coach(params, target, alpha, trials=4, adverb=None):
    """Trial 1 shows the target; trials 2-4 the emphatic motion. R = final error / initial."""
    learner = SimulatedLearner("l", target, params)
    e0 = learner.error()
    att = learner.imitate(target)
    for _ in range(trials - 1):
        att = learner.imitate(_emphatic(learner, att, alpha) if alpha else target, adverb)
    return learner.error() / e0


def test_the_learner_population_behaves_as_the_coaching_experiments_need(squat):
    pop = population(12, seed=0)
    alphas = [0.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 4.0]
    r = np.array([[_coach(p, squat, a) for a in alphas] for p in pop])
    target_only, moderate, too_much = r[:, 0], r[:, 2], r[:, -1]
    print(f"\nR after 4 trials (mean over 12 simulated learners): target only {target_only.mean():.2f}, "
          f"alpha 1.5 {moderate.mean():.2f}, alpha 4 {too_much.mean():.2f}")
    assert np.all(target_only < 1.0) and target_only.mean() > 0.4  # repeating the target: slow progress
    assert np.mean(moderate < target_only) >= 0.9 and moderate.mean() < 0.5 * target_only.mean()  # emphasis helps
    assert np.mean(too_much > moderate) >= 0.9 and np.median(too_much) > 1.0  # too much makes them worse
    best = [alphas[1:7][j] for j in r[:, 1:7].argmin(axis=1)]  # EMU-Model 2's sweep
    assert len(set(best)) >= 3, best  # the best alpha differs between learners


def test_adverbs_help_and_attempts_are_five_seeded_repetitions(squat):
    pop = population(12, seed=1)
    plain = np.array([_coach(p, squat, 2.0) for p in pop])
    more = np.array([_coach(p, squat, 2.0, adverb="a little more") for p in pop])
    assert np.mean(more != plain) == 1.0
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
