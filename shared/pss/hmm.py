"""Left-to-right continuous HMMs: the proto-symbols of the thesis (eq. 2.1, 2.2).

A proto-symbol ``lambda = {a_ij, b_i}`` is a left-to-right HMM with one Gaussian output per
state (the single-Gaussian case of eq. 2.1 that the thesis uses for synthesis, ch. 4.3.1),
trained by Baum-Welch on one or several repetitions of a motion.

Choices the thesis leaves open, made here:

* topology: state ``i`` may stay or move to ``i + 1`` only; every sequence starts in state 0
  (``pi = 1``) and, by default, ends in the last state, so that every state stands for a part
  of the motion (a model whose last states are never reached is what makes hmmlearn write NaN);
* initialisation by uniform segmentation of every repetition into ``n_states`` parts (not
  k-means): state means and variances from the segments, stay probabilities from the segment
  lengths;
* a variance floor applied after every M-step (hmmlearn does not apply ``min_covar`` in its
  M-step), so no state degenerates on a nearly constant channel;
* convergence: the log-likelihood gain per frame falls below ``tol``; reported on the model.

Two trainers give the same model: ``backend="banded"`` (default) exploits the band structure
with a numba forward-backward of cost ``O(T N)`` (scaled probabilities over all repetitions at
once, the log-domain pass where scaling underflows) plus one BLAS product each for the emissions
and the M-step; ``backend="hmmlearn"``
is the library reference (``GaussianHMM`` with the same initialisation and the floor applied
after fitting). Tests check that both reach the same log-likelihood.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from shared.compiled import kernel
from shared.deadline import check_time
from shared.digest import array_digest
from shared.errors import ModelError
from shared.once import Once
from shared.pss.likelihood import LOG2PI, as_sequences, emission_logprob, forward_backward, forward_loglik


@dataclass
class LeftToRightHMM:
    """A trained proto-symbol. ``stay[i]`` is ``a_ii``; ``a_{i,i+1} = 1 - a_ii``."""

    means: np.ndarray  # (N, D)
    covars: np.ndarray  # (N, D) diagonal or (N, D, D) full
    stay: np.ndarray  # (N,)
    covariance_type: str = "diag"
    n_iter: int = 0
    converged: bool = False
    log_likelihood: float = float("nan")
    n_frames: int = 0
    history: list[float] = field(default_factory=list)

    @property
    def n_states(self) -> int:
        return self.means.shape[0]

    @property
    def n_features(self) -> int:
        return self.means.shape[1]

    def expected_durations(self) -> np.ndarray:
        """Expected stay in each state, in frames: ``1 / (1 - a_ii)`` (the time domain of ch. 4.3.1)."""
        return 1.0 / np.maximum(1.0 - self.stay, 1e-9)

    def transmat(self) -> np.ndarray:
        n = self.n_states
        a = np.diag(self.stay.astype(float))
        a[np.arange(n - 1), np.arange(1, n)] = 1.0 - self.stay[:-1]
        a[-1, -1] = 1.0
        return a

    def variances(self) -> np.ndarray:
        """Per-state variances (N, D): the diagonal of full covariances."""
        if self.covariance_type == "full":
            return np.einsum("nii->ni", self.covars)
        return self.covars

    def marginal(self, features: np.ndarray) -> LeftToRightHMM:
        """The same HMM seen on a subset of its output features (for association, eq. 2.8)."""
        f = np.asarray(features)
        cov = self.covars[:, f][:, :, f] if self.covariance_type == "full" else self.covars[:, f]
        return LeftToRightHMM(self.means[:, f], cov, self.stay.copy(), self.covariance_type)

    def prefix(self, k: int) -> LeftToRightHMM:
        """The first ``k`` states (the start of the motion)."""
        return LeftToRightHMM(self.means[:k], self.covars[:k], self.stay[:k].copy(), self.covariance_type)

    def is_valid(self) -> bool:
        ok = np.all(np.isfinite(self.means)) and np.all(np.isfinite(self.covars)) and np.all(np.isfinite(self.stay))
        return bool(ok and np.all(self.variances() > 0) and np.all((self.stay >= 0) & (self.stay < 1)))

    def _log_transitions(self) -> tuple[np.ndarray, np.ndarray]:
        return np.log(np.maximum(self.stay, 1e-300)), np.log(np.maximum(1.0 - self.stay, 1e-300))

    def posteriors(self, sequence, end_in_last: bool = True) -> np.ndarray:
        """State posteriors ``gamma_t(i)`` of one sequence (T, N), forward-backward."""
        x = as_sequences([sequence], self.n_features)[0]
        logb = emission_logprob(x, self.means, self.covars, self.covariance_type)
        _, gamma, _, _ = forward_backward(np.ascontiguousarray(logb), *self._log_transitions(), end_in_last)
        return gamma

    def log_likelihood_of(self, sequences, end_in_last: bool = True) -> float:
        """Total log-likelihood of the sequences (forward algorithm)."""
        seqs = as_sequences(sequences, self.n_features)
        total = 0.0
        for x in seqs:
            logb = emission_logprob(x, self.means, self.covars, self.covariance_type)
            ll, _ = forward_loglik(logb, *self._log_transitions(), end_in_last)
            total += ll
        return float(total)

    def progress(self, sequence) -> np.ndarray:
        """Posterior of the state at the last frame when the sequence need not end in the last
        state: how far through the motion a partial observation is (eq. 2.8, missing frames)."""
        x = as_sequences([sequence], self.n_features)[0]
        logb = emission_logprob(x, self.means, self.covars, self.covariance_type)
        _, alpha_last = forward_loglik(logb, *self._log_transitions(), False)
        p = np.exp(alpha_last - alpha_last.max())
        return p / p.sum()


#: frames x features above which the diagonal fit computes its emissions and statistics on the
#: frames in blocks of CHUNK_FRAMES instead of stacking ``[x, x*x]`` once (a 100,000-frame clip's
#: recognition: the fit's peak 197 -> 94 MB, the recognition's 242 -> 141 MB); below it the
#: numbers are exactly those of the stacked form
CHUNKED_ABOVE = 2**22
CHUNK_FRAMES = 4096


def uniform_segmentation(seqs: list[np.ndarray], n_states: int, var_floor: float, covariance_type: str):
    """Initial parameters: every repetition cut into ``n_states`` equal parts (as
    ``np.array_split`` cuts: the first ``T mod N`` parts one frame longer)."""
    d = seqs[0].shape[1]

    def states_of(t: int) -> np.ndarray:  # np.array_split's parts of t frames, without splitting
        q, r = divmod(t, n_states)
        return np.repeat(np.arange(n_states), np.where(np.arange(n_states) < r, q + 1, q))

    state = np.concatenate([states_of(len(x)) for x in seqs])
    x_all = np.vstack(seqs)
    onehot = np.zeros((len(x_all), n_states))
    onehot[np.arange(len(x_all)), state] = 1.0
    lengths = onehot.sum(axis=0)
    means = (onehot.T @ x_all) / lengths[:, None]
    if covariance_type == "diag":
        covars = (onehot.T @ (x_all * x_all)) / lengths[:, None] - means * means
        covars = np.maximum(covars, var_floor)
    else:
        parts = [x_all[state == i] for i in range(n_states)]
        covars = np.array([np.cov(p.T, bias=True).reshape(d, d) if len(p) > 1 else np.zeros((d, d)) for p in parts])
        covars = covars + var_floor * np.eye(d)
    mean_len = np.maximum(lengths / len(seqs), 1.0)
    stay = 1.0 - 1.0 / np.maximum(mean_len, 1.0 + 1e-6)
    return means, covars, np.clip(stay, 0.0, 0.999)


def fit_hmm(
    sequences,
    n_states: int,
    *,
    covariance_type: str = "diag",
    var_floor: float = 0.01,
    n_iter: int = 30,
    tol: float = 1e-3,
    backend: str = "banded",
    end_in_last: bool = True,
    likelihood: bool = True,
) -> LeftToRightHMM:
    """Train a left-to-right HMM on one or several repetitions (Baum-Welch, eq. 2.1-2.2).

    Parameters
    ----------
    sequences : array (T, D) or list of arrays
        Feature frames of one or several repetitions of one motion.
    n_states : int
        Number of states; every repetition needs at least ``n_states`` frames.
    covariance_type : {"diag", "full"}
    var_floor : float
        Lower bound on every output variance (full: added to the diagonal), applied after each M-step.
    tol : float
        Convergence when the log-likelihood gain per frame is below ``tol``.
    backend : {"banded", "hmmlearn"}
        Our banded Baum-Welch (numba), or hmmlearn's trainer with the same start, floor and
        topology (the reference it is tested against).
    end_in_last : bool
        Whether every repetition must end in the last state.
    likelihood : bool
        Whether to score the repetitions under the final parameters (one more forward pass; a
        motion's HMM that is only compared by eq. 2.4, recognition's, leaves it NaN).

    Returns
    -------
    LeftToRightHMM
        Means, covariances and staying probabilities, with the iterations, whether they
        converged and the final log-likelihood.

    References
    ----------
    L. R. Rabiner, "A tutorial on hidden Markov models and selected applications in speech
    recognition", Proc. IEEE 77(2), 1989.
    """
    if covariance_type not in ("diag", "full"):
        raise ModelError(f"covariance_type must be 'diag' or 'full', got {covariance_type!r}")
    if n_states < 1:
        raise ModelError("n_states must be at least 1")
    seqs = as_sequences(sequences)
    if not seqs:
        raise ModelError("no sequence to train on")
    d = seqs[0].shape[1]
    if any(s.shape[1] != d for s in seqs):
        raise ModelError("repetitions have different numbers of features")
    short = min(len(s) for s in seqs)
    if short < n_states:
        raise ModelError(f"a repetition has {short} frames, fewer than the {n_states} HMM states; use fewer states or a longer clip",
                         frames=short, states=n_states)
    check_time()  # a request past its time limit stops before each model (shared.deadline)
    means, covars, stay = uniform_segmentation(seqs, n_states, var_floor, covariance_type)
    n_frames = sum(len(s) for s in seqs)
    if backend == "hmmlearn":
        model = _fit_hmmlearn(seqs, means, covars, stay, covariance_type, var_floor, n_iter, tol * n_frames, likelihood)
    elif backend == "banded":
        model = _fit_banded(seqs, means, covars, stay, covariance_type, var_floor, n_iter, tol * n_frames, end_in_last,
                            likelihood)
    else:
        raise ModelError(f"unknown backend {backend!r}")
    model.n_frames = n_frames
    if not model.is_valid():
        raise ModelError("HMM training produced invalid parameters (NaN or non-positive variance); the clip is too short or degenerate for this many states")
    return model


TRAINED_CACHE_BYTES = 16 * 2**20  # the models fit_hmm_once keeps per process, at most
#: (sequences, settings) -> model: the most recently used kept within TRAINED_CACHE_BYTES
_TRAINED = Once(limit=1 << 20, max_bytes=TRAINED_CACHE_BYTES, largest=TRAINED_CACHE_BYTES,
                size=lambda m: m.means.nbytes + m.covars.nbytes + m.stay.nbytes)


def fit_hmm_once(sequences, n_states: int, **settings) -> LeftToRightHMM:
    """:func:`fit_hmm`, each distinct (sequences, ``n_states``, settings) trained once per process;
    a copy of the model is returned. Baum-Welch is deterministic: the same bytes and settings give
    the same model. Association uses it: the estimator's spaces of one language encode their
    motions alike and associate the same motions over and over; the last
    :data:`TRAINED_CACHE_BYTES` of models are kept."""
    seqs = as_sequences(sequences)
    key = (array_digest(*seqs), int(n_states), tuple(sorted(settings.items())))
    model = _TRAINED.once(key, lambda: fit_hmm(seqs, n_states, **settings))
    return replace(model, means=model.means.copy(), covars=model.covars.copy(), stay=model.stay.copy(),
                   history=list(model.history))


def _floor(covars, var_floor, covariance_type):
    if covariance_type == "diag":
        return np.maximum(covars, var_floor)
    d = covars.shape[1]
    out = covars.copy()
    idx = np.arange(d)
    out[:, idx, idx] = np.maximum(out[:, idx, idx], var_floor)
    # keep positive definite: add a ridge where the smallest eigenvalue is below the floor
    for i in range(out.shape[0]):
        w = np.linalg.eigvalsh(out[i]).min()
        if w < var_floor * 1e-3:
            out[i] += (var_floor * 1e-3 - w) * np.eye(d)
    return out


def _stay_from_occupancy(frames_in_state: float, n_sequences: int) -> float:
    """``a_ii`` whose expected stay ``1 / (1 - a_ii)`` is the state's frames per repetition."""
    d = max(float(frames_in_state) / max(n_sequences, 1), 1.0)
    return float(np.clip(1.0 - 1.0 / d, 0.0, 0.999))


@kernel(cache=True, nogil=True)
def _estep_scaled(logb, bounds, stay, end_in_last):
    """E-step over every repetition at once, in the scaled probability domain (Rabiner's
    scaling, with each frame's emissions shifted by their largest reachable value).

    Returns (ok, loglik, gamma (T, N), xi_stay (N,), xi_move (N,)). ``ok`` is False when a
    scale factor underflowed; the caller then falls back to the log-domain ``forward_backward``.
    """
    t_all, n = logb.shape
    gamma = np.zeros((t_all, n))
    xs = np.zeros(n)
    xm = np.zeros(n)
    total = 0.0
    move = 1.0 - stay
    for k in range(bounds.shape[0] - 1):
        lo = bounds[k]
        t_len = bounds[k + 1] - lo
        a = np.zeros((t_len, n))
        b = np.zeros((t_len, n))  # shifted emissions exp(logb - m_t)
        c = np.zeros(t_len)
        # t = 0: only state 0
        b[0, 0] = 1.0
        a[0, 0] = 1.0
        c[0] = 1.0
        total += logb[lo, 0]
        pred = np.empty(n)
        for t in range(1, t_len):
            m = -np.inf
            pred[0] = a[t - 1, 0] * stay[0]
            for i in range(1, n):
                pred[i] = a[t - 1, i] * stay[i] + a[t - 1, i - 1] * move[i - 1]
            for i in range(n):
                if pred[i] > 0.0 and logb[lo + t, i] > m:
                    m = logb[lo + t, i]
            s = 0.0
            for i in range(n):
                b[t, i] = np.exp(logb[lo + t, i] - m)
                a[t, i] = pred[i] * b[t, i]
                s += a[t, i]
            if not (s > 0.0) or not np.isfinite(s):
                return False, -np.inf, gamma, xs, xm
            for i in range(n):
                a[t, i] /= s
            c[t] = s
            total += m + np.log(s)
        # backward pass: beta is rescaled to max 1 at every frame and gamma_t, xi_t are
        # normalised per frame (both sum to 1), so nothing overflows whatever alpha_T is
        beta = np.zeros(n)
        if end_in_last:
            if not (a[t_len - 1, n - 1] > 0.0):
                return False, -np.inf, gamma, xs, xm
            total += np.log(a[t_len - 1, n - 1])
            beta[n - 1] = 1.0
        else:
            beta[:] = 1.0
        s = 0.0
        for i in range(n):
            s += a[t_len - 1, i] * beta[i]
        for i in range(n):
            gamma[lo + t_len - 1, i] = a[t_len - 1, i] * beta[i] / s
        nb = np.empty(n)
        ws = np.empty(n)
        wm = np.zeros(n)
        for t in range(t_len - 2, -1, -1):
            s = 0.0
            top = 0.0
            for i in range(n):
                ws[i] = stay[i] * b[t + 1, i] * beta[i]
                nb[i] = ws[i]
                if i + 1 < n:
                    wm[i] = move[i] * b[t + 1, i + 1] * beta[i + 1]
                    nb[i] += wm[i]
                s += a[t, i] * nb[i]
                if nb[i] > top:
                    top = nb[i]
            if not (s > 0.0) or not np.isfinite(s):
                return False, -np.inf, gamma, xs, xm
            for i in range(n):
                gamma[lo + t, i] = a[t, i] * nb[i] / s
                xs[i] += a[t, i] * ws[i] / s
                if i + 1 < n:
                    xm[i] += a[t, i] * wm[i] / s
                beta[i] = nb[i] / top
    return True, total, gamma, xs, xm


@_estep_scaled.numpy
def _estep_scaled_numpy(logb, bounds, stay, end_in_last):
    t_all, n = logb.shape
    gamma = np.zeros((t_all, n))
    xs, xm = np.zeros(n), np.zeros(n)
    total = 0.0
    move = 1.0 - stay
    for k in range(len(bounds) - 1):
        lo, hi = int(bounds[k]), int(bounds[k + 1])
        t_len = hi - lo
        a = np.zeros((t_len, n))
        b = np.zeros((t_len, n))
        b[0, 0] = a[0, 0] = 1.0
        total += logb[lo, 0]
        for t in range(1, t_len):
            pred = a[t - 1] * stay
            pred[1:] += a[t - 1, :-1] * move[:-1]
            reach = logb[lo + t][pred > 0.0]
            m = reach.max() if reach.size else -np.inf
            b[t] = np.exp(logb[lo + t] - m)
            a[t] = pred * b[t]
            s = a[t].sum()
            if not (s > 0.0) or not np.isfinite(s):
                return False, -np.inf, gamma, xs, xm
            a[t] /= s
            total += m + np.log(s)
        if end_in_last:
            if not (a[t_len - 1, n - 1] > 0.0):
                return False, -np.inf, gamma, xs, xm
            total += np.log(a[t_len - 1, n - 1])
            beta = np.zeros(n)
            beta[n - 1] = 1.0
        else:
            beta = np.ones(n)
        g = a[t_len - 1] * beta
        gamma[hi - 1] = g / g.sum()
        for t in range(t_len - 2, -1, -1):
            ws = stay * b[t + 1] * beta
            wm = np.zeros(n)
            wm[:-1] = move[:-1] * b[t + 1, 1:] * beta[1:]
            nb = ws + wm
            s = a[t] @ nb
            if not (s > 0.0) or not np.isfinite(s):
                return False, -np.inf, gamma, xs, xm
            gamma[lo + t] = a[t] * nb / s
            xs += a[t] * ws / s
            xm += a[t] * wm / s
            beta = nb / nb.max()
    return True, total, gamma, xs, xm


def _estep(logb_all, bounds, stay, end_in_last):
    """E-step: scaled (fast) path, log-domain path for the repetitions where scaling underflows."""
    ok, ll, gamma, xs, xm = _estep_scaled(logb_all, bounds, stay, end_in_last)
    if ok:
        return ll, gamma, xs, xm
    log_stay, log_move = np.log(np.maximum(stay, 1e-300)), np.log(np.maximum(1.0 - stay, 1e-300))
    n = logb_all.shape[1]
    gamma = np.empty_like(logb_all)
    xs, xm, ll = np.zeros(n), np.zeros(n), 0.0
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        lk, g, s_, m_ = forward_backward(np.ascontiguousarray(logb_all[lo:hi]), log_stay, log_move, end_in_last)
        ll += lk
        gamma[lo:hi] = g
        xs += s_
        xm += m_
    return ll, gamma, xs, xm


def _fit_banded(seqs, means, covars, stay, covariance_type, var_floor, n_iter, tol_total, end_in_last, likelihood=True):
    """Baum-Welch with the banded E-step. For diagonal covariances the frames are stacked once
    as ``z = [x, x*x]`` so the emissions (eq. 2.2) and the M-step's sufficient statistics are a
    single matrix product each; a long recording (``CHUNKED_ABOVE``) in blocks of frames."""
    n, d = means.shape
    history: list[float] = []
    converged = False
    x_all = np.vstack(seqs) if len(seqs) > 1 else np.asarray(seqs[0], float)
    bounds = np.cumsum([0] + [len(s) for s in seqs]).astype(np.int64)
    diag = covariance_type == "diag"
    chunked = diag and x_all.size > CHUNKED_ABOVE  # a long recording: [x, x*x] would triple its memory
    if diag and not chunked:
        z = np.hstack([x_all, x_all * x_all])
    it = 0
    for it in range(1, n_iter + 1):  # noqa: B007 (the count is read after the loop)
        if diag:
            prec = 1.0 / covars
            w = np.vstack([(means * prec).T, -0.5 * prec.T])
            const = -0.5 * (np.sum(means * means * prec, axis=1) + np.sum(np.log(covars), axis=1) + d * LOG2PI)
            if chunked:
                logb_all = np.empty((len(x_all), n))
                for a in range(0, len(x_all), CHUNK_FRAMES):
                    xa = x_all[a:a + CHUNK_FRAMES]
                    logb_all[a:a + CHUNK_FRAMES] = xa @ w[:d] + (xa * xa) @ w[d:] + const
            else:
                logb_all = z @ w + const
        else:
            logb_all = emission_logprob(x_all, means, covars, covariance_type)
        ll, gamma, xs, xm = _estep(np.ascontiguousarray(logb_all), bounds, stay, end_in_last)
        if not np.isfinite(ll):
            raise ModelError("a repetition has zero likelihood under the model (it cannot pass through every state)")
        history.append(float(ll))
        # M-step
        occ = gamma.sum(axis=0)
        occ_safe = np.maximum(occ, 1e-12)
        if diag:
            if chunked:
                squares = sum(gamma[a:a + CHUNK_FRAMES].T @ (x_all[a:a + CHUNK_FRAMES] * x_all[a:a + CHUNK_FRAMES])
                              for a in range(0, len(x_all), CHUNK_FRAMES))
                stats = np.hstack([gamma.T @ x_all, squares]) / occ_safe[:, None]
            else:
                stats = (gamma.T @ z) / occ_safe[:, None]
            means = np.ascontiguousarray(stats[:, :d])  # its own (N, D): a view kept the whole (N, 2D) alive
            covars = stats[:, d:] - means * means
        else:
            means = (gamma.T @ x_all) / occ_safe[:, None]
            covars = np.empty((n, d, d))
            for i in range(n):
                xc = x_all - means[i]
                covars[i] = (xc * gamma[:, i:i + 1]).T @ xc / occ_safe[i]
        covars = _floor(covars, var_floor, covariance_type)
        denom = xs + xm
        stay = np.where(denom > 0, xs / np.maximum(denom, 1e-300), stay)
        # the last state has no exit transition to count: its expected stay is its occupancy
        # per repetition (every repetition ends there), d = 1 / (1 - a_NN)
        stay[-1] = _stay_from_occupancy(occ[-1], len(seqs))
        stay = np.clip(stay, 0.0, 0.999)
        if len(history) > 1 and history[-1] - history[-2] < tol_total:
            converged = True
            break
    model = LeftToRightHMM(means, covars, stay, covariance_type, n_iter=it, converged=converged,
                           history=history)
    if likelihood:
        model.log_likelihood = model.log_likelihood_of(seqs, end_in_last)
    return model


def _fit_hmmlearn(seqs, means, covars, stay, covariance_type, var_floor, n_iter, tol_total, likelihood=True):
    import logging

    from hmmlearn.hmm import GaussianHMM

    logging.getLogger("hmmlearn.base").setLevel(logging.ERROR)  # it logs non-monotone steps of its own
    n = means.shape[0]
    m = GaussianHMM(n_components=n, covariance_type=covariance_type, init_params="", params="stmc",
                    n_iter=n_iter, tol=tol_total, min_covar=var_floor, implementation="log")
    m.startprob_ = np.eye(n)[0]
    a = np.diag(stay)
    a[np.arange(n - 1), np.arange(1, n)] = 1.0 - stay[:-1]
    a[-1, -1] = 1.0
    m.transmat_ = a
    m.means_ = means
    m.covars_ = covars
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m.fit(np.vstack(seqs), [len(s) for s in seqs])
    x_all, lengths = np.vstack(seqs), [len(s) for s in seqs]
    cov = m._covars_ if covariance_type == "diag" else m.covars_
    cov = _floor(np.array(cov), var_floor, covariance_type)
    st = np.diag(m.transmat_).copy()
    if np.all(np.isfinite(m.means_)):  # hmmlearn's last state is absorbing: a_NN from its occupancy
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            occ = m.predict_proba(x_all, lengths).sum(axis=0)
        st[-1] = _stay_from_occupancy(occ[-1], len(seqs))
    model = LeftToRightHMM(np.array(m.means_), cov, np.clip(st, 0.0, 0.999), covariance_type,
                           n_iter=m.monitor_.iter, converged=bool(m.monitor_.converged),
                           history=[float(v) for v in m.monitor_.history])
    if likelihood and model.is_valid():
        model.log_likelihood = float(m.score(x_all, lengths))
    return model
