"""The PSS math with known answers and against its library references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, stats

from shared.errors import BadInput, ModelError
from shared.pss.distance import bhattacharyya, distance_matrix, hmm_distance
from shared.pss.hmm import LeftToRightHMM, fit_hmm, uniform_segmentation
from shared.pss.mds import classical_mds, place_point, raw_stress, smacof
from shared.pss.synthesis import (
    combine,
    distance_weights,
    expected_trajectory,
    monte_carlo_trajectory,
    point_weights,
)


def _numeric_bd(m1, s1, m2, s2):
    """-ln of the Bhattacharyya coefficient, by numerical integration (eq. 2.3, first line)."""
    f = lambda x: np.sqrt(stats.norm.pdf(x, m1, s1) * stats.norm.pdf(x, m2, s2))  # noqa: E731
    lo, hi = min(m1 - 12 * s1, m2 - 12 * s2), max(m1 + 12 * s1, m2 + 12 * s2)
    bc, _ = integrate.quad(f, lo, hi, limit=200, points=[m1, m2])
    return -np.log(bc)


@pytest.mark.parametrize("m1, s1, m2, s2", [(0, 1, 0, 1), (0, 1, 1, 1), (0, 1, 3, 2), (-2, 0.3, 1, 1.5), (5, 4, 4.5, 0.5)])
def test_bhattacharyya_1d_matches_numerical_integration(m1, s1, m2, s2):
    closed = bhattacharyya(np.array([m1]), np.array([s1**2]), np.array([m2]), np.array([s2**2]))
    assert closed == pytest.approx(_numeric_bd(m1, s1, m2, s2), abs=1e-8)
    full = bhattacharyya(np.array([m1]), np.array([[s1**2]]), np.array([m2]), np.array([[s2**2]]))
    assert full == pytest.approx(closed, abs=1e-12)


def test_full_and_diagonal_agree_and_full_sees_correlation():
    rng = np.random.default_rng(0)
    mu1, mu2 = rng.normal(size=4), rng.normal(size=4)
    v1, v2 = rng.uniform(0.5, 2, 4), rng.uniform(0.5, 2, 4)
    assert bhattacharyya(mu1, np.diag(v1), mu2, np.diag(v2)) == pytest.approx(bhattacharyya(mu1, v1, mu2, v2))
    c = np.array([[1.0, 0.9], [0.9, 1.0]])
    assert bhattacharyya(np.zeros(2), c, np.zeros(2), np.eye(2)) > 0.05


def _random_hmm(rng, n=5, d=3, full=False):
    cov = rng.uniform(0.2, 1.0, (n, d))
    if full:
        a = rng.normal(size=(n, d, d)) * 0.3
        cov = np.einsum("nij,nkj->nik", a, a) + np.eye(d)
    return LeftToRightHMM(rng.normal(size=(n, d)), cov, rng.uniform(0.5, 0.9, n), "full" if full else "diag")


@pytest.mark.parametrize("full", [False, True])
def test_hmm_distance_zero_identical_symmetric(full):
    rng = np.random.default_rng(1)
    a, b, c = (_random_hmm(rng, full=full) for _ in range(3))
    assert hmm_distance(a, a) == pytest.approx(0, abs=1e-7)
    assert hmm_distance(a, b) == pytest.approx(hmm_distance(b, a))
    assert hmm_distance(a, b) > 0
    f = distance_matrix([a, b, c])
    assert np.allclose(f, f.T) and np.all(np.diag(f) == 0)
    manual = sum(np.sqrt(bhattacharyya(a.means[i], a.covars[i], b.means[i], b.covars[i])) for i in range(5))
    assert hmm_distance(a, b) == pytest.approx(manual)  # eq. 2.4: sum over states of sqrt(BD)


def test_weighted_distance_bank_matches_reference_and_ones_are_eq_2_4():
    rng = np.random.default_rng(5)
    models = [_random_hmm(rng, d=6) for _ in range(5)]
    w = rng.uniform(0.0, 3.0, 6)
    f = distance_matrix(models, w)
    for i in range(5):
        for j in range(5):
            assert f[i, j] == pytest.approx(hmm_distance(models[i], models[j], w), abs=1e-9)
    manual = sum(np.sqrt(max(0.125 * np.sum(w * (a - b) ** 2 / (0.5 * (va + vb)))
                             + 0.5 * np.sum(np.log(0.5 * (va + vb)) - 0.5 * (np.log(va) + np.log(vb))), 0))
                 for a, b, va, vb in zip(models[0].means, models[1].means, models[0].covars, models[1].covars))
    assert f[0, 1] == pytest.approx(manual, rel=1e-9)
    assert np.allclose(distance_matrix(models, np.ones(6)), distance_matrix(models))
    with pytest.raises(ModelError, match="channel weights"):
        distance_matrix(models, np.ones(4))


def test_distance_matrix_on_some_features_is_the_marginals_matrix():
    """A bank stacked on some features (no marginal HMM per model, ModelBank.of) gives the
    marginal HMMs' own eq. 2.4 matrix, with and without channel weights."""
    from shared.pss.distance import ModelBank

    rng = np.random.default_rng(7)
    models = [_random_hmm(rng, d=6) for _ in range(7)]
    for idx in (np.array([0, 2, 3, 5]), np.array([1, 2, 3])):  # gathered, and a run (sliced)
        marg = [m.marginal(idx) for m in models]
        bank = ModelBank.of(models, idx)
        assert np.allclose(distance_matrix(bank), distance_matrix(marg), rtol=1e-12, atol=0)
        w = rng.uniform(0.0, 3.0, len(idx))
        assert np.allclose(distance_matrix(bank, w), distance_matrix(marg, w), rtol=1e-12, atol=0)
        with pytest.raises(ModelError, match="channel weights"):
            distance_matrix(bank, np.ones(6))


def test_an_extended_bank_is_the_bank_of_all_its_models_even_when_two_extend_one():
    """Extending writes into spare rows shared with the bank it extends; a second extension of
    the same bank (two spaces added to one) must not overwrite the first's rows."""
    from shared.pss.distance import ModelBank

    rng = np.random.default_rng(8)
    models = [_random_hmm(rng, d=6) for _ in range(5)]
    a, b, c = (_random_hmm(rng, d=6) for _ in range(3))
    base = ModelBank(models, np.linspace(0.5, 2, 6))
    first = base.extended([a])
    again = first.extended([b])  # into first's spare rows
    other = first.extended([c])  # first extended twice: c must not take b's row
    probe = _random_hmm(rng, d=6)
    for bank, ms in ((first, models + [a]), (again, models + [a, b]), (other, models + [a, c])):
        ref = ModelBank(ms, np.linspace(0.5, 2, 6))
        assert np.array_equal(bank.distances(probe), ref.distances(probe))
        assert np.array_equal(bank.distances(probe, start=3), ref.distances(probe, start=3))
    assert np.array_equal(base.distances(probe), ModelBank(models, np.linspace(0.5, 2, 6)).distances(probe))
    # a bank stacked by ModelBank.of keeps spare rows: its first extension writes in place
    stacked = ModelBank.of(models, np.array([1, 2, 3]))
    grown = stacked.extended([a.marginal(np.array([1, 2, 3]))])
    assert grown.means.base is stacked.means.base and grown.vars.base is stacked.vars.base
    ref = ModelBank([m.marginal(np.array([1, 2, 3])) for m in models + [a]])
    assert np.array_equal(grown.distances(probe.marginal(np.array([1, 2, 3]))),
                          ref.distances(probe.marginal(np.array([1, 2, 3]))))


def test_channel_weights_favour_channels_that_separate_classes_not_performers():
    """Channel 0 tells the classes apart, channel 1 the performers, channel 2 never varies."""
    from shared.pss.recognition import channel_weights

    rng = np.random.default_rng(6)
    means, labels, perf = [], [], []
    for cls, c0 in (("a", 0.0), ("b", 3.0)):
        for who, c1 in (("p", 0.0), ("q", 3.0)):
            for _ in range(3):
                means.append(np.stack([c0 + rng.normal(0, 0.1, 4), c1 + rng.normal(0, 0.1, 4), np.zeros(4)], axis=1))
                labels.append(cls)
                perf.append(who)
    means = np.array(means)
    w = channel_weights(means, np.full(means.shape, 0.1), labels, perf)
    assert w[0] > 3 * w[1] and w[2] == 0 and w.mean() == pytest.approx(1.0)
    assert np.all(channel_weights(means, np.full(means.shape, 0.1), ["a"] * len(labels), perf) == 1.0)  # one class


def test_hmm_distance_needs_equal_state_counts():
    rng = np.random.default_rng(2)
    with pytest.raises(ModelError, match="state"):
        hmm_distance(_random_hmm(rng, 4), _random_hmm(rng, 5))


def _repetitions(rng, n_reps=3, d=4, base_len=60):
    """Repetitions of a smooth motion with random timing and noise."""
    out = []
    for _ in range(n_reps):
        t = np.linspace(0, 1, base_len + rng.integers(-10, 10)) ** rng.uniform(0.8, 1.25)
        x = np.column_stack([t, t * t, np.sin(np.pi * t), np.cos(0.5 * np.pi * t)][:d])
        out.append(x + 0.05 * rng.normal(size=x.shape))
    return out


def test_banded_training_matches_hmmlearn_log_likelihood():
    rng = np.random.default_rng(3)
    reps = _repetitions(rng)
    ours = fit_hmm(reps, 6, backend="banded", end_in_last=False, tol=1e-6, n_iter=100)
    ref = fit_hmm(reps, 6, backend="hmmlearn", tol=1e-6, n_iter=100)
    assert ours.converged and ref.converged
    ll_ours = ours.log_likelihood_of(reps, end_in_last=False)
    ll_ref = ref.log_likelihood_of(reps, end_in_last=False)
    # same model family, same start: ours reaches at least the reference's optimum
    assert (ll_ours - ll_ref) / sum(len(r) for r in reps) > -0.01
    # our forward algorithm agrees with hmmlearn's scorer on the same parameters (hmmlearn's
    # last state is absorbing, so compare with a_NN = 1)
    from hmmlearn.hmm import GaussianHMM

    m = GaussianHMM(6, "diag", init_params="")
    m.startprob_, m.transmat_, m.means_, m.covars_ = np.eye(6)[0], ref.transmat(), ref.means, ref.covars
    absorbing = LeftToRightHMM(ref.means, ref.covars, np.r_[ref.stay[:-1], 1.0])
    assert m.score(np.vstack(reps), [len(r) for r in reps]) == pytest.approx(
        absorbing.log_likelihood_of(reps, end_in_last=False), rel=1e-9)


@pytest.mark.parametrize("end_in_last", [True, False])
def test_scaled_estep_matches_the_log_domain_forward_backward(end_in_last):
    from shared.pss.hmm import _estep, _estep_scaled
    from shared.pss.likelihood import forward_backward as _forward_backward

    rng = np.random.default_rng(7)
    n, lens = 5, [40, 33, 57]
    logb = rng.normal(scale=30.0, size=(sum(lens), n))  # emissions hundreds of nats apart
    stay = rng.uniform(0.5, 0.95, size=n)
    bounds = np.cumsum([0] + lens).astype(np.int64)
    ok, ll, gamma, xs, xm = _estep_scaled(logb, bounds, stay, end_in_last)
    assert ok
    ref_ll, ref_xs, ref_xm = 0.0, np.zeros(n), np.zeros(n)
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        lk, g, s_, m_ = _forward_backward(np.ascontiguousarray(logb[lo:hi]), np.log(stay), np.log(1 - stay), end_in_last)
        ref_ll += lk
        ref_xs += s_
        ref_xm += m_
        np.testing.assert_allclose(gamma[lo:hi], g, atol=1e-9)
    assert ll == pytest.approx(ref_ll, rel=1e-10)
    np.testing.assert_allclose(xs, ref_xs, rtol=1e-8)
    np.testing.assert_allclose(xm, ref_xm, rtol=1e-8)
    if end_in_last:
        # the last state's emission at the last frame is 1e6 nats below the others: exp()
        # underflows after scaling, the scaled pass says so and _estep takes the log domain
        logb[lens[0] - 1, n - 1] = -1e6
        assert not _estep_scaled(logb, bounds, stay, True)[0]
        ll2, gamma2, _, _ = _estep(logb, bounds, stay, True)
        assert np.isfinite(ll2) and ll2 < ll - 9e5
        np.testing.assert_allclose(gamma2.sum(axis=1), 1.0, atol=1e-9)


def test_training_is_left_to_right_floored_and_reports_convergence():
    rng = np.random.default_rng(4)
    reps = _repetitions(rng)
    reps[0][:, 0] = 1.0  # a constant channel must not collapse its variance
    m = fit_hmm(reps, 5, var_floor=0.01)
    a = m.transmat()
    assert np.allclose(np.triu(a, 2), 0) and np.allclose(np.tril(a, -1), 0) and np.allclose(a.sum(1), 1)
    assert m.covars.min() >= 0.01 - 1e-12
    assert m.converged and 1 <= m.n_iter <= 30 and m.history == sorted(m.history)
    full = fit_hmm(reps, 4, covariance_type="full")
    assert full.is_valid() and np.all(np.linalg.eigvalsh(full.covars) > 0)


def test_a_model_trained_once_is_the_model_trained_anew_and_its_copy_is_the_callers(monkeypatch):
    """``fit_hmm_once``: the same sequences and settings give :func:`fit_hmm`'s model, trained
    once (the second call trains nothing) and handed out as a copy; other settings or other
    bytes train again; the models kept stay within their byte budget."""
    from shared.pss import hmm as hmm_module

    rng = np.random.default_rng(6)
    reps = _repetitions(rng)
    trained = []
    real = hmm_module.fit_hmm
    monkeypatch.setattr(hmm_module, "fit_hmm", lambda *a, **k: trained.append(1) or real(*a, **k))
    kept = hmm_module._TRAINED
    monkeypatch.setattr(hmm_module, "_TRAINED", hmm_module.Once(max_bytes=kept.max_bytes, largest=kept.largest,
                                                                size=kept.size))  # (this test's models only)
    first = hmm_module.fit_hmm_once(reps, 5, var_floor=0.01)
    reference = real(reps, 5, var_floor=0.01)
    for name in ("means", "covars", "stay"):
        assert np.array_equal(getattr(first, name), getattr(reference, name))
    first.means[:] = 0.0  # the caller's copy: the model kept is not touched
    again = hmm_module.fit_hmm_once([r.copy() for r in reps], 5, var_floor=0.01)
    assert len(trained) == 1 and np.array_equal(again.means, reference.means)
    hmm_module.fit_hmm_once(reps, 5, var_floor=0.02)
    hmm_module.fit_hmm_once([reps[0] + 1e-9] + reps[1:], 5, var_floor=0.01)
    assert len(trained) == 3
    monkeypatch.setattr(hmm_module, "_TRAINED", hmm_module.Once(max_bytes=1, largest=1, size=kept.size))  # nothing fits
    hmm_module.fit_hmm_once(reps, 4)
    hmm_module.fit_hmm_once(reps, 4)
    assert len(trained) == 5 and hmm_module._TRAINED.kept_bytes <= 1


def test_training_refuses_bad_input():
    rng = np.random.default_rng(5)
    with pytest.raises(ModelError, match="fewer than"):
        fit_hmm(rng.normal(size=(4, 3)), 5)
    bad = rng.normal(size=(20, 3))
    bad[3, 1] = np.nan
    with pytest.raises(ModelError, match="NaN"):
        fit_hmm(bad, 3)
    with pytest.raises(ModelError):
        fit_hmm([rng.normal(size=(20, 3)), rng.normal(size=(20, 4))], 3)


def test_mds_recovers_a_euclidean_configuration_and_matches_sklearn():
    rng = np.random.default_rng(6)
    x = rng.normal(size=(25, 3))
    f = np.linalg.norm(x[:, None] - x[None], axis=2)
    emb = smacof(f, 3)
    assert emb.stress1 < 1e-4
    assert raw_stress(f, classical_mds(f, 3)) < 1e-8
    # a non-Euclidean distance matrix: our SMACOF reaches at least scikit-learn's stress
    from sklearn.manifold import smacof as sk_smacof

    g = f + rng.uniform(0, 0.5, f.shape)
    g = np.triu(g, 1) + np.triu(g, 1).T
    ours = smacof(g, 2)
    sk_x, _ = sk_smacof(g, n_components=2, init=classical_mds(g, 2), n_init=1, metric=True, max_iter=3000, eps=1e-9,
                        normalized_stress=False)
    assert ours.stress <= raw_stress(g, sk_x) * 1.001
    # Torgerson's textbook form (J = I - 1/n, -1/2 J F^2 J, every eigenpair): the same points up to
    # each axis's sign, and every sign fixed so that the axis's largest component is positive
    n = len(g)
    j = np.eye(n) - 1.0 / n
    w, v = np.linalg.eigh(-0.5 * j @ (g * g) @ j)
    ref = v[:, ::-1][:, :2] * np.sqrt(w[::-1][:2])
    x2 = classical_mds(g, 2)
    assert np.allclose(np.abs(x2), np.abs(ref), atol=1e-9)
    assert np.all(x2[np.argmax(np.abs(x2), axis=0), [0, 1]] > 0)


def test_out_of_sample_point_is_placed_without_moving_the_others():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(30, 3))
    new = np.array([0.3, -0.2, 0.5])
    f = np.linalg.norm(x - new, axis=1)
    p, stress = place_point(x, f)
    assert np.allclose(p, new, atol=1e-4) and stress < 1e-8
    with pytest.raises(BadInput):
        place_point(x, f[:-1])


def test_out_of_sample_point_matches_scipy_minimisation_on_noisy_distances():
    from scipy.optimize import minimize

    rng = np.random.default_rng(9)
    x = rng.normal(size=(40, 3)) * 5
    for trial in range(5):
        f = np.abs(np.linalg.norm(x - rng.normal(size=3) * 3, axis=1) + rng.normal(scale=1.5, size=40))
        p, stress = place_point(x, f)
        assert stress == pytest.approx(raw_stress_point := float(np.sum((f - np.linalg.norm(x - p, axis=1)) ** 2)))
        obj = lambda q: np.sum((f - np.linalg.norm(x - q, axis=1)) ** 2)  # noqa: E731
        best = min((minimize(obj, s0, method="Nelder-Mead", options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 20000})
                    for s0 in rng.normal(size=(8, 3)) * 5), key=lambda r: r.fun)
        assert raw_stress_point <= best.fun * (1 + 1e-6) + 1e-9, trial


def test_weights_interpolate_extrapolate_and_pick_proto_symbols():
    pts = np.array([[0.0, 0.0], [1.0, 0.0]])
    alpha = 2.0
    x_s = pts[1] + alpha * (pts[1] - pts[0])  # eq. 4.3 with x_t = pts[1], x_p = pts[0]
    assert point_weights(pts, x_s) == pytest.approx([-alpha, 1 + alpha], abs=1e-4)
    rng = np.random.default_rng(8)
    many = rng.normal(size=(15, 3))
    for x in (many[4], 0.5 * (many[2] + many[9]), many[3] + 2 * (many[3] - many[5])):
        c = point_weights(many, x)
        assert c.sum() == pytest.approx(1) and np.allclose(c @ many, x, atol=1e-3)
    assert point_weights(many, many[4]) == pytest.approx(np.eye(15)[4])
    c = point_weights(many, 0.5 * (many[2] + many[9]), method="inverse_distance")
    assert c.sum() == pytest.approx(1) and np.all(c >= 0)


def test_combination_keeps_variances_positive_and_durations_in_time_domain():
    rng = np.random.default_rng(9)
    a, b = _random_hmm(rng), _random_hmm(rng)
    same = combine([a, a], [0.3, 0.7])
    assert np.allclose(same.means, a.means) and np.allclose(same.covars, a.covars) and np.allclose(same.stay, a.stay)
    ext = combine([a, b], [3.0, -2.0])  # alpha = 2 extrapolation
    assert np.all(ext.covars > 0)
    assert np.allclose(ext.means, 3 * a.means - 2 * b.means)
    want = np.maximum(3 * a.expected_durations() - 2 * b.expected_durations(), 1.0)
    assert np.allclose(ext.expected_durations(), want, rtol=1e-6, atol=1e-3)
    fa, fb = _random_hmm(rng, full=True), _random_hmm(rng, full=True)
    fext = combine([fa, fb], [3.0, -2.0])
    assert np.all(np.linalg.eigvalsh(fext.covars) > 0)
    with pytest.raises(BadInput, match="sum to 1"):
        combine([a, b], [0.5, 0.6])


def test_generation_is_smooth_seeded_and_follows_the_states():
    rng = np.random.default_rng(10)
    m = fit_hmm(_repetitions(rng, n_reps=4), 8)
    det = expected_trajectory(m)
    assert len(det) == int(round(m.expected_durations().sum()))
    mc1 = monte_carlo_trajectory(m, len(det), seed=3)
    mc2 = monte_carlo_trajectory(m, len(det), seed=3)
    mc3 = monte_carlo_trajectory(m, len(det), seed=4)
    assert np.array_equal(mc1, mc2) and not np.array_equal(mc1, mc3)
    data_rough = np.mean([np.mean(np.diff(r, 2, axis=0) ** 2) for r in _repetitions(rng)])
    for traj in (det, mc1):
        assert np.mean(np.diff(traj, 2, axis=0) ** 2) < data_rough  # smoother than the noisy data
    # both generations pass near every state mean, in order
    for traj in (det, mc1):
        hits = [int(np.argmin(np.linalg.norm(traj - mu, axis=1))) for mu in m.means]
        assert hits == sorted(hits)
    assert np.abs(det - mc1).mean() < 0.2


def test_channel_weights_kernel_equals_the_numpy_reference():
    """The compiled pair sums against eq. 2.3's terms computed pair by pair in numpy."""
    from shared.pss.distance import bhattacharyya_terms
    from shared.pss.recognition import channel_weights

    rng = np.random.default_rng(3)
    n, states, dim = 14, 4, 6
    mu, var = rng.normal(size=(n, states, dim)), rng.uniform(0.05, 2.0, size=(n, states, dim))
    labels = np.array(list("aabbccaabbccab"))
    for perf in (np.array(["p", "q"] * 7), None):
        within, between = np.zeros(dim), np.zeros(dim)
        nw = nb = 0
        for i in range(n - 1):
            for j in range(i + 1, n):
                mean, cov = bhattacharyya_terms(mu[i], var[i], mu[j], var[j])
                t = (mean + cov).sum(axis=0)
                if labels[i] == labels[j] and (perf is None or perf[i] != perf[j]):
                    within, nw = within + t, nw + 1
                elif labels[i] != labels[j]:
                    between, nb = between + t, nb + 1
        w = np.sqrt((between / nb + 1e-9) / (within / nw + 1e-9))
        assert np.allclose(channel_weights(mu, var, labels, perf), w / w.mean(), rtol=1e-10)


def _kernel_both_ways(kernel, *args):
    """A kernel's numba result and its numpy twin's, on the same arguments."""
    assert kernel.twin is not None
    return kernel.compiled()(*args), kernel.twin(*args)


@pytest.mark.parametrize("end_in_last", [True, False])
def test_numpy_twins_of_the_hmm_kernels_match_numba(end_in_last):
    from shared.pss import hmm, likelihood

    rng = np.random.default_rng(3)
    logb = rng.normal(-20.0, 6.0, size=(90, 7))
    bounds = np.array([0, 25, 58, 90], dtype=np.int64)
    stay = rng.uniform(0.5, 0.95, 7)
    log_stay, log_move = np.log(stay), np.log(1.0 - stay)
    a, b = _kernel_both_ways(hmm._estep_scaled, logb, bounds, stay, end_in_last)
    assert a[0] and b[0]
    for x, y in zip(a[1:], b[1:]):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)
    a, b = _kernel_both_ways(likelihood.forward_backward, logb[:40], log_stay, log_move, end_in_last)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)
    a, b = _kernel_both_ways(likelihood.forward_loglik, logb, log_stay, log_move, end_in_last)
    np.testing.assert_allclose(a[0], b[0], rtol=1e-12)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-12)
    # a repetition that cannot reach the last state: both say so the same way
    short = np.array([0, 3], dtype=np.int64)
    if end_in_last:
        assert not _kernel_both_ways(hmm._estep_scaled, logb[:3], short, stay, True)[1][0]


def test_numpy_twins_of_distance_placement_and_kinematics_match_numba(hdm05):
    from shared.motion import kinematics
    from shared.pss import distance, mds

    rng = np.random.default_rng(4)
    mu, var = rng.normal(size=(30, 5, 40)), rng.uniform(0.05, 2.0, size=(30, 5, 40))
    args = (mu[0], var[0], np.log(var[0]).sum(axis=1), mu, var, np.log(var).sum(axis=2), rng.uniform(0.5, 2.0, 40))
    a, b = _kernel_both_ways(distance._diag_hmm_distances, *args)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-6)  # atol: the kernel's fastmath on a model and itself
    tiny = var * 1e-12  # 32 channels' product below 1e-300: the kernel's logs taken one by one
    args = (mu[0], tiny[0], np.log(tiny[0]).sum(axis=1), mu, tiny, np.log(tiny).sum(axis=2), np.ones(40))
    a, b = _kernel_both_ways(distance._diag_hmm_distances, *args)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-5)  # (the log-determinants ~1e3: sqrt of their rounding)
    pts = rng.normal(size=(40, 3))
    f = np.linalg.norm(pts - [0.3, -0.2, 0.5], axis=1) + rng.uniform(0, 0.1, 40)
    starts = np.stack([pts[0] + 1e-3, pts.mean(axis=0), -pts[0]])
    a, b = _kernel_both_ways(mds._guttman_point, pts, f, starts, 50, 1e-9)
    np.testing.assert_allclose(a[0], b[0], atol=1e-9)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-9)
    # forward kinematics of a real skeleton and real angles (every Euler order HDM05 uses)
    from shared.io import load_clip

    clip = load_clip(sorted((hdm05 / "amc").glob("*/*.amc"))[0])
    k = clip.skeleton._fk_arrays(tuple(clip.channels), True)
    padded = np.concatenate([clip.data[:50], np.zeros((50, 1))], axis=1)
    ang = np.ascontiguousarray(np.deg2rad(padded[:, k["cols"]]))
    trans = np.ascontiguousarray(padded[:, k["tcols"]])
    fk = (ang, k["axes"], k["intrinsic"], k["pre"], k["parent"], k["offset"], trans, k["end_joint"], k["end_offset"])
    a, b = _kernel_both_ways(kinematics.fk_positions, *fk)
    np.testing.assert_allclose(a, b, atol=1e-9)
    a, b = _kernel_both_ways(kinematics.local_rotations, *fk[:4])
    np.testing.assert_allclose(a, b, atol=1e-12)
    # Euler triples on either branch, jumping by whole turns: the same continuous choice
    tb = rng.uniform(-180, 180, size=(200, 3)).cumsum(axis=0) * 0.05
    tb[::7] = tb[::7] * [1, -1, 1] + 180.0
    a, b = _kernel_both_ways(kinematics.continuous_tait_bryan, tb, np.zeros(3))
    np.testing.assert_allclose(a, b, atol=1e-9)
    # angles with no continuity at all: every kind of step of the twins' chain (set, kept, flipped)
    jumps = rng.uniform(-180, 180, size=(500, 3))
    a, b = _kernel_both_ways(kinematics.continuous_tait_bryan, jumps, np.array([10.0, 170.0, -40.0]))
    np.testing.assert_allclose(a, b, atol=1e-9)
    following = np.array([[0, 0], [1, 1], [0, 1], [1, 0], [1, 0], [0, 1], [1, 1], [1, 0]])
    for c0 in (0, 1):
        chain = [c0]
        for row in following:
            chain.append(int(row[chain[-1]]))
        assert kinematics._two_state_chain(c0, following).tolist() == chain


def test_offline_recognize_runs_without_numba_and_answers_as_the_compiled_path(tmp_path, hdm05):
    """The one-shot command uses the numpy twins (numba is never imported) and shows the same
    label, confidence and nearest proto-symbols as the library's compiled path."""
    import json
    import subprocess
    import sys

    from shared.io import load_clip
    from shared.pss.space import ProtoSymbolSpace

    files = sorted((hdm05 / "amc").glob("*/*.amc"))
    train = [f for f in files if "_bd_" in f.name][::3]
    probe = next(f for f in files if "_dg_" in f.name)
    space = ProtoSymbolSpace.build([load_clip(f) for f in train])
    space.save(tmp_path / "s.npz")
    want = space.recognize(load_clip(probe))
    code = ("import sys; sys.argv = ['mirrorcoach', 'offline', 'recognize', sys.argv[1], sys.argv[2], '--json'];"
            "from shared.cli.app import main\ntry:\n    main()\nexcept SystemExit:\n    pass\n"
            "print('numba imported' if 'numba' in sys.modules else 'no numba', file=sys.stderr)")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "s.npz"), str(probe)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "no numba" in r.stderr
    got = json.loads(r.stdout)
    assert got.get("label") == want.label and got["nearest_label"] == want.nearest_label
    assert got["confidence"] == pytest.approx(want.confidence, abs=1e-9)
    assert [n["name"] for n in got["nearest"]] == [n for n, _, _ in want.nearest]
    np.testing.assert_allclose([n["distance"] for n in got["nearest"]], [d for _, _, d in want.nearest], rtol=1e-9)


def test_a_long_recording_is_fitted_in_blocks_of_frames_to_the_same_model(monkeypatch):
    """A long recording's diagonal fit works on blocks of frames instead of ``[x, x*x]`` whole
    (memory); the model is the stacked form's to rounding."""
    from shared.pss import hmm

    rng = np.random.default_rng(4)
    x = np.concatenate([rng.normal(k, 1.0 + 0.2 * k, size=(700, 5)) for k in range(4)])
    stacked = hmm.fit_hmm([x], 4, covariance_type="diag", var_floor=1e-3, n_iter=15)
    monkeypatch.setattr(hmm, "CHUNKED_ABOVE", 0)
    monkeypatch.setattr(hmm, "CHUNK_FRAMES", 256)  # blocks that do not divide the 2,800 frames
    blocks = hmm.fit_hmm([x], 4, covariance_type="diag", var_floor=1e-3, n_iter=15)
    np.testing.assert_allclose(blocks.means, stacked.means, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(blocks.covars, stacked.covars, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(blocks.stay, stacked.stay, rtol=1e-9, atol=1e-12)
    assert blocks.n_iter == stacked.n_iter


def test_distance_weights_are_convex_and_as_documented():
    """(d_min / d_i)^8 over the eq. 2.4 distances, normalised; a proto-symbol at distance 0 takes all."""
    w = distance_weights([1.0, 2.0, 4.0])
    assert w == pytest.approx(np.array([1.0, 2.0**-8, 4.0**-8]) / (1 + 2.0**-8 + 4.0**-8))
    assert distance_weights([3.0, 0.0, 1.0]).tolist() == [0.0, 1.0, 0.0]
    assert distance_weights([2.0, 2.0]).tolist() == [0.5, 0.5]
    for bad in ([], [1.0, np.nan], [-1.0, 2.0]):
        with pytest.raises(BadInput, match="finite and non-negative"):
            distance_weights(bad)


def test_the_first_segmentation_cuts_as_array_split_does():
    """The uniform start of Baum-Welch: each repetition in equal parts, the first ``T mod N`` one
    frame longer, exactly as ``np.array_split`` cuts (the means of each part)."""
    rng = np.random.default_rng(5)
    for lengths, n in (([15], 15), ([16, 29], 13), ([96], 15), ([40, 41, 57], 7)):
        seqs = [rng.normal(size=(t, 3)) for t in lengths]
        means, _, _ = uniform_segmentation(seqs, n, 0.01, "diag")
        parts = [np.array_split(x, n) for x in seqs]
        want = np.array([np.vstack([ps[i] for ps in parts]).mean(axis=0) for i in range(n)])
        np.testing.assert_allclose(means, want, rtol=1e-12, atol=1e-12)
