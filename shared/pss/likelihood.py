"""The likelihood of a left-to-right HMM (eq. 2.1-2.3): Gaussian emissions ``log b_i(o_t)``
and the forward / forward-backward recursions in the log domain, as numba kernels with their
numpy references (:func:`shared.compiled.kernel`). :mod:`shared.pss.hmm` holds the model and
its training."""

from __future__ import annotations

import numpy as np

from shared.compiled import kernel
from shared.errors import ModelError

LOG2PI = np.log(2.0 * np.pi)


def as_sequences(sequences, n_features=None) -> list[np.ndarray]:
    if isinstance(sequences, np.ndarray):
        sequences = [sequences]
    seqs = [np.ascontiguousarray(s, dtype=np.float64) for s in sequences]
    for s in seqs:
        if s.ndim != 2:
            raise ModelError(f"a sequence must be frames x features, got shape {s.shape}")
        if n_features is not None and s.shape[1] != n_features:
            raise ModelError(f"sequence has {s.shape[1]} features, the model has {n_features}")
        if not np.all(np.isfinite(s)):
            raise ModelError("sequence contains NaN or Inf")
    return seqs


def emission_logprob(x: np.ndarray, means: np.ndarray, covars: np.ndarray, covariance_type: str) -> np.ndarray:
    """``log b_i(o_t)`` for every frame and state (eq. 2.2), shape (T, N)."""
    if covariance_type == "diag":
        prec = 1.0 / covars
        out = -0.5 * ((x * x) @ prec.T - 2.0 * x @ (means * prec).T + np.sum(means * means * prec, axis=1))
        out -= 0.5 * (np.sum(np.log(covars), axis=1) + x.shape[1] * LOG2PI)
        return out
    t, d = x.shape
    out = np.empty((t, means.shape[0]))
    for i in range(means.shape[0]):
        chol = np.linalg.cholesky(covars[i])
        z = np.linalg.solve(chol, (x - means[i]).T)
        out[:, i] = -0.5 * np.sum(z * z, axis=0) - np.sum(np.log(np.diag(chol))) - 0.5 * d * LOG2PI
    return out


@kernel(cache=True, nogil=True)
def _logaddexp(a, b):
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    if a > b:
        return a + np.log1p(np.exp(b - a))
    return b + np.log1p(np.exp(a - b))


@kernel(cache=True, nogil=True)
def forward_loglik(logb, log_stay, log_move, end_in_last):
    t_len, n = logb.shape
    alpha = np.full(n, -np.inf)
    alpha[0] = logb[0, 0]
    for t in range(1, t_len):
        new = np.empty(n)
        new[0] = alpha[0] + log_stay[0] + logb[t, 0]
        for i in range(1, n):
            new[i] = _logaddexp(alpha[i] + log_stay[i], alpha[i - 1] + log_move[i - 1]) + logb[t, i]
        alpha = new
    if end_in_last:
        return alpha[n - 1], alpha
    m = alpha.max()
    return m + np.log(np.sum(np.exp(alpha - m))), alpha


@kernel(cache=True, nogil=True)
def forward_backward(logb, log_stay, log_move, end_in_last):
    """Banded forward-backward in log space. Returns (loglik, gamma (T,N), xi_stay (N,), xi_move (N,))."""
    t_len, n = logb.shape
    la = np.full((t_len, n), -np.inf)
    lb = np.full((t_len, n), -np.inf)
    la[0, 0] = logb[0, 0]
    for t in range(1, t_len):
        la[t, 0] = la[t - 1, 0] + log_stay[0] + logb[t, 0]
        for i in range(1, n):
            la[t, i] = _logaddexp(la[t - 1, i] + log_stay[i], la[t - 1, i - 1] + log_move[i - 1]) + logb[t, i]
    if end_in_last:
        lb[t_len - 1, n - 1] = 0.0
        loglik = la[t_len - 1, n - 1]
    else:
        for i in range(n):
            lb[t_len - 1, i] = 0.0
        m = la[t_len - 1].max()
        loglik = m + np.log(np.sum(np.exp(la[t_len - 1] - m)))
    for t in range(t_len - 2, -1, -1):
        for i in range(n):
            v = lb[t + 1, i] + log_stay[i] + logb[t + 1, i]
            if i + 1 < n:
                v = _logaddexp(v, lb[t + 1, i + 1] + log_move[i] + logb[t + 1, i + 1])
            lb[t, i] = v
    gamma = np.exp(la + lb - loglik)
    xi_stay = np.zeros(n)
    xi_move = np.zeros(n)
    for t in range(t_len - 1):
        for i in range(n):
            if la[t, i] == -np.inf:
                continue
            xi_stay[i] += np.exp(la[t, i] + log_stay[i] + logb[t + 1, i] + lb[t + 1, i] - loglik)
            if i + 1 < n:
                xi_move[i] += np.exp(la[t, i] + log_move[i] + logb[t + 1, i + 1] + lb[t + 1, i + 1] - loglik)
    return loglik, gamma, xi_stay, xi_move


def _log_step(prev, log_stay, log_move):
    """One banded transition in log space: ``log(a_ii p_i + a_(i-1)i p_(i-1))`` per state."""
    new = prev + log_stay
    new[1:] = np.logaddexp(new[1:], prev[:-1] + log_move[:-1])
    return new


@forward_loglik.numpy
def _forward_loglik_numpy(logb, log_stay, log_move, end_in_last):
    n = logb.shape[1]
    alpha = np.full(n, -np.inf)
    alpha[0] = logb[0, 0]
    for t in range(1, logb.shape[0]):
        alpha = _log_step(alpha, log_stay, log_move) + logb[t]
    if end_in_last:
        return alpha[n - 1], alpha
    m = alpha.max()
    return m + np.log(np.sum(np.exp(alpha - m))), alpha


@forward_backward.numpy
def _forward_backward_numpy(logb, log_stay, log_move, end_in_last):
    t_len, n = logb.shape
    la = np.full((t_len, n), -np.inf)
    lb = np.full((t_len, n), -np.inf)
    la[0, 0] = logb[0, 0]
    for t in range(1, t_len):
        la[t] = _log_step(la[t - 1], log_stay, log_move) + logb[t]
    if end_in_last:
        lb[t_len - 1, n - 1] = 0.0
        loglik = la[t_len - 1, n - 1]
    else:
        lb[t_len - 1] = 0.0
        m = la[t_len - 1].max()
        loglik = m + np.log(np.sum(np.exp(la[t_len - 1] - m)))
    for t in range(t_len - 2, -1, -1):
        nxt = lb[t + 1] + logb[t + 1]
        lb[t] = nxt + log_stay
        lb[t, :-1] = np.logaddexp(lb[t, :-1], nxt[1:] + log_move[:-1])
    gamma = np.exp(la + lb - loglik)
    with np.errstate(invalid="ignore"):
        stay_terms = np.exp(la[:-1] + log_stay + logb[1:] + lb[1:] - loglik)
        move_terms = np.exp(la[:-1, :-1] + log_move[:-1] + logb[1:, 1:] + lb[1:, 1:] - loglik)
    xi_stay = np.nansum(np.where(np.isfinite(la[:-1]), stay_terms, 0.0), axis=0)
    xi_move = np.zeros(n)
    xi_move[:-1] = np.nansum(np.where(np.isfinite(la[:-1, :-1]), move_terms, 0.0), axis=0)
    return loglik, gamma, xi_stay, xi_move
