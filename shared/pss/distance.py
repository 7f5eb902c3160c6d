"""Distances between proto-symbols: the Bhattacharyya distance (eq. 2.3) and the HMM
distance built from it (eq. 2.4).

``BD(p, q) = 1/8 (mu_p - mu_q)^T S^-1 (mu_p - mu_q) + 1/2 ln( det S / sqrt(det S_p det S_q) )``
with ``S = (S_p + S_q) / 2``, and ``d(lambda_1, lambda_2) = sum_i sqrt(BD_i)`` over
corresponding states, so both HMMs need the same number of states. Diagonal and full
covariances are supported. :func:`bhattacharyya` is the numpy reference; the diagonal
case over whole spaces runs in :func:`_diag_hmm_distances` (numba, one pass, the log of a
determinant taken once per 32 channels as the log of their product: 1 ms for 127
proto-symbols x 13 states x 237 channels against 19 ms in numpy).
"""

from __future__ import annotations

import copy

import numpy as np

from shared.compiled import kernel
from shared.errors import ModelError
from shared.pss.hmm import LeftToRightHMM
from shared.pss.rows import appended, spare


def bhattacharyya_terms(mu_p, var_p, mu_q, var_q) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2.3 for diagonal Gaussians, channel by channel: the mean term
    ``1/8 (mu_p - mu_q)_d^2 / s_d`` and the covariance term ``1/2 ln(s_d / sqrt(v_pd v_qd))``
    (each (..., D)); :func:`bhattacharyya` sums them."""
    mu_p, mu_q = np.asarray(mu_p, float), np.asarray(mu_q, float)
    var_p, var_q = np.asarray(var_p, float), np.asarray(var_q, float)
    diff = mu_p - mu_q
    s = 0.5 * (var_p + var_q)
    return 0.125 * diff * diff / s, 0.5 * (np.log(s) - 0.5 * (np.log(var_p) + np.log(var_q)))


def bhattacharyya(mu_p, var_p, mu_q, var_q, weights=None) -> np.ndarray:
    """Eq. 2.3 for Gaussians. ``var`` is either variances (..., D) (diagonal) or covariance
    matrices (..., D, D) (full), chosen by the number of dimensions of ``var`` relative to ``mu``.

    ``weights`` (D,), diagonal only: each channel's share of the mean term,
    ``1/8 sum_d w_d (mu_p - mu_q)_d^2 / s_d`` (recognition's channel weights,
    :func:`shared.pss.recognition.channel_weights`); ``None`` is eq. 2.3 itself."""
    mu_p, mu_q = np.asarray(mu_p, float), np.asarray(mu_q, float)
    var_p, var_q = np.asarray(var_p, float), np.asarray(var_q, float)
    diff = mu_p - mu_q
    if var_p.ndim == mu_p.ndim:  # diagonal
        mean, cov = bhattacharyya_terms(mu_p, var_p, mu_q, var_q)
        w = 1.0 if weights is None else np.asarray(weights, float)
        return np.maximum(np.sum(w * mean + cov, axis=-1), 0.0)
    if weights is not None:
        raise ModelError("channel weights need diagonal covariances")
    s = 0.5 * (var_p + var_q)
    sol = np.linalg.solve(s, diff[..., None])[..., 0]
    term1 = 0.125 * np.sum(diff * sol, axis=-1)
    _, ld = np.linalg.slogdet(s)
    _, ldp = np.linalg.slogdet(var_p)
    _, ldq = np.linalg.slogdet(var_q)
    return np.maximum(term1 + 0.5 * (ld - 0.5 * (ldp + ldq)), 0.0)


def _check(a: LeftToRightHMM, b: LeftToRightHMM):
    if a.n_states != b.n_states:
        raise ModelError(f"HMM distance needs equal state counts, got {a.n_states} and {b.n_states}")
    if a.n_features != b.n_features:
        raise ModelError(f"HMMs have different output sizes ({a.n_features} and {b.n_features})")
    if a.covariance_type != b.covariance_type:
        raise ModelError("HMMs have different covariance types")


def hmm_distance(a: LeftToRightHMM, b: LeftToRightHMM, weights=None) -> float:
    """Eq. 2.4: ``sum_i sqrt(BD(b_1i, b_2i))`` (with channel ``weights``, see :func:`bhattacharyya`).

    Parameters
    ----------
    a, b : LeftToRightHMM
        Two proto-symbols with as many states and features.
    weights : array (n_features,), optional
        Weights of the channels on the mean term of the Bhattacharyya distance.

    Returns
    -------
    float
        The sum over states of the square roots of the states' Bhattacharyya distances.

    References
    ----------
    A. Bhattacharyya, "On a measure of divergence between two statistical populations defined by
    their probability distributions", Bull. Calcutta Math. Soc. 35, 1943. T. Inamura, I. Toshima,
    H. Tanie, Y. Nakamura, "Embodied symbol emergence based on mimesis theory", IJRR 23(4), 2004.
    """
    _check(a, b)
    return float(np.sum(np.sqrt(bhattacharyya(a.means, a.covars, b.means, b.covars, weights))))


@kernel(cache=True, nogil=True, fastmath=True)
def _diag_hmm_distances(mu1, var1, logdet1, mu, var, logdet, w):
    """Eq. 2.4 from one diagonal HMM (S, D) to N of them (N, S, D); ``logdet`` = per-state
    sums of log variances, ``w`` (D,) the channel weights of the mean term (ones: eq. 2.4).
    Per state, one pass over the channels for the mean term (a loop the compiler vectorises)
    keeps the averaged variances, whose log is then taken once per 32 channels."""
    n_models, n_states, n_dims = mu.shape
    out = np.zeros(n_models)
    v = np.empty(n_dims)
    for n in range(n_models):
        total = 0.0
        for s in range(n_states):
            a, b, m1, m2 = var1[s], var[n, s], mu1[s], mu[n, s]
            maha = 0.0
            for d in range(n_dims):
                v[d] = 0.5 * (a[d] + b[d])
                diff = m1[d] - m2[d]
                maha += w[d] * diff * diff / v[d]
            logdet_mean = 0.0
            for d0 in range(0, n_dims, 32):
                end = min(d0 + 32, n_dims)
                prod = 1.0
                for d in range(d0, end):
                    prod *= v[d]
                if 1e-300 < prod < 1e300:
                    logdet_mean += np.log(prod)
                else:  # out of range for one product: log by log
                    for d in range(d0, end):
                        logdet_mean += np.log(v[d])
            bd = 0.125 * maha + 0.5 * logdet_mean - 0.25 * (logdet1[s] + logdet[n, s])
            total += np.sqrt(max(bd, 0.0))
        out[n] = total
    return out


@_diag_hmm_distances.numpy
def _diag_hmm_distances_numpy(mu1, var1, logdet1, mu, var, logdet, w):
    v = 0.5 * (var1 + var)
    maha = np.einsum("nsd,d->ns", (mu1 - mu) ** 2 / v, w)
    bd = 0.125 * maha + 0.5 * np.log(v).sum(axis=2) - 0.25 * (logdet1 + logdet)
    return np.sqrt(np.maximum(bd, 0.0)).sum(axis=1)


def _stack(models: list[LeftToRightHMM], f=slice(None), ceiling: float | None = None, floor=None):
    """Means, variances (raised to ``floor``, one value per feature of ``f``, then capped at
    ``ceiling``) and per-state log-determinants of diagonal HMMs seen on features ``f``, stacked
    with spare rows (:func:`shared.pss.rows.spare`): a bank's first extension (a clip added to
    its space) writes in place."""
    shape = (len(models),) + models[0].means[:, f].shape
    means, var, logdet = spare(shape), spare(shape), spare(shape[:2])
    for i, m in enumerate(models):
        _check(m, models[0])
        means[i], var[i] = m.means[:, f], m.covars[:, f]
    if floor is not None:
        np.maximum(var, floor, out=var)
    if ceiling is not None:
        np.minimum(var, ceiling, out=var)
    np.sum(np.log(var), axis=2, out=logdet)
    return means, var, logdet


class ModelBank:
    """Many HMMs of one space stacked for eq. 2.4 against a new one (built once, reused)."""

    def __init__(self, models: list[LeftToRightHMM], weights=None):
        self.models = models
        self.diag = bool(models) and all(m.covariance_type == "diag" for m in models)
        if self.diag:
            self.means, self.vars, self.logdet = _stack(models)
        self._weigh(weights)

    def _weigh(self, weights) -> None:
        """Channel ``weights`` on eq. 2.3's mean term (``None``: eq. 2.4 itself)."""
        self.weights = None if weights is None else np.ascontiguousarray(weights, dtype=float)
        if self.weights is not None and self.models and not self.diag:
            raise ModelError("channel weights need diagonal covariances")
        if self.diag:
            n_features = self.means.shape[2]
            if self.weights is not None and self.weights.shape != (n_features,):
                raise ModelError(f"{self.weights.size} channel weights for HMMs of {n_features} channels")
            self._kernel_weights = np.ones(n_features) if self.weights is None else self.weights

    @classmethod
    def of(cls, models: list[LeftToRightHMM], features=None, ceiling: float | None = None, floor=None) -> ModelBank:
        """The bank of ``models`` seen on ``features`` (all when None; as
        :meth:`LeftToRightHMM.marginal` sees them), diagonal variances raised to ``floor`` (one
        value per feature seen) and capped at ``ceiling``.
        Stacked directly, and the bank's own models are views of its stacked arrays: the HMMs
        on those features exist once (a list of marginal HMMs and their stack held them twice,
        0.3 GB at 3,000 game-studio proto-symbols)."""
        if not models or not all(m.covariance_type == "diag" for m in models):
            return cls(models if features is None else [m.marginal(features) for m in models])
        f = slice(None) if features is None else np.asarray(features)
        if isinstance(f, np.ndarray) and len(f) and np.array_equal(f, np.arange(f[0], f[0] + len(f))):
            f = slice(int(f[0]), int(f[0]) + len(f))  # a run of features: sliced, not gathered (10x faster)
        bank = cls.__new__(cls)
        bank.diag = True
        bank.means, bank.vars, bank.logdet = _stack(models, f, ceiling, floor)
        bank.models = [LeftToRightHMM(bank.means[i], bank.vars[i], m.stay, "diag") for i, m in enumerate(models)]
        bank._weigh(None)
        return bank

    def weighted(self, weights) -> ModelBank:
        """The same HMMs (the same arrays, not copied) with channel ``weights``."""
        out = copy.copy(self)
        out._weigh(weights)
        return out

    def extended(self, models: list[LeftToRightHMM]) -> ModelBank:
        """This bank with ``models`` after its own: the stacked arrays grow into spare rows
        (:func:`shared.pss.rows.appended`), so adding one HMM to a bank of 3,000 does not copy
        the 3,000 (0.2 s each)."""
        more = ModelBank(list(models))
        if not self.diag or not models or not more.diag or more.means.shape[1:] != self.means.shape[1:]:
            return ModelBank(self.models + list(models), self.weights)
        out = copy.copy(self)
        out.models = self.models + list(models)
        out.means, out.vars, out.logdet = (appended(a, b) for a, b in ((self.means, more.means), (self.vars, more.vars),
                                                                       (self.logdet, more.logdet)))
        return out

    def distances(self, model: LeftToRightHMM, start: int = 0) -> np.ndarray:
        """Eq. 2.4 from ``model`` to the bank's HMMs from ``start`` on."""
        if start:
            if not self.diag:
                return ModelBank(self.models[start:]).distances(model)
            if start >= len(self.models):
                return np.zeros(0)
        if not self.models:
            return np.zeros(0)
        _check(model, self.models[0])
        if not self.diag:
            for m in self.models[1:]:
                _check(model, m)
            mu = np.stack([m.means for m in self.models])
            cov = np.stack([m.covars for m in self.models])
            return np.sum(np.sqrt(bhattacharyya(model.means[None], model.covars[None], mu, cov)), axis=1)
        if self.means.shape[1:] != model.means.shape:
            raise ModelError(f"HMMs have different shapes ({self.means.shape[1:]} and {model.means.shape})")
        var1 = np.ascontiguousarray(model.covars, dtype=float)
        return _diag_hmm_distances(np.ascontiguousarray(model.means, dtype=float), var1, np.log(var1).sum(axis=1),
                                   self.means[start:], self.vars[start:], self.logdet[start:], self._kernel_weights)


def distances_to(model: LeftToRightHMM, models: list[LeftToRightHMM] | ModelBank) -> np.ndarray:
    """Eq. 2.4 from one HMM to many."""
    bank = models if isinstance(models, ModelBank) else ModelBank(models)
    return bank.distances(model)


def distance_matrix(models: list[LeftToRightHMM] | ModelBank, weights=None) -> np.ndarray:
    """Symmetric matrix of eq. 2.4 distances (with channel ``weights``) with a zero diagonal,
    between ``models`` or a bank's (with its own weights unless ``weights`` are given).

    Parameters
    ----------
    models : list of LeftToRightHMM or ModelBank
    weights : array (n_features,), optional

    Returns
    -------
    array (n, n)
    """
    if isinstance(models, ModelBank):
        bank = models if weights is None else models.weighted(weights)
    else:
        bank = ModelBank(models, weights)
    n = len(bank.models)
    out = np.zeros((n, n))
    for i in range(n - 1):
        out[i, i + 1:] = bank.distances(bank.models[i], start=i + 1)
    for i in range(n - 1):  # the lower triangle from the upper, without a second N x N
        out[i + 1:, i] = out[i, i + 1:]
    return out


def bank_parameters(bank: ModelBank, start: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The means and covariances of a bank's HMMs from ``start`` on, stacked (a diagonal bank's
    own arrays; full covariances stacked here)."""
    if bank.diag:
        return bank.means[start:], bank.vars[start:]
    ms = bank.models[start:]
    return np.stack([m.means for m in ms]), np.stack([m.covars for m in ms])
