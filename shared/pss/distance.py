"""Distances between proto-symbols: the Bhattacharyya distance (eq. 2.3) and the HMM
distance built from it (eq. 2.4).

``BD(p, q) = 1/8 (mu_p - mu_q)^T S^-1 (mu_p - mu_q) + 1/2 ln( det S / sqrt(det S_p det S_q) )``
with ``S = (S_p + S_q) / 2``, and ``d(lambda_1, lambda_2) = sum_i sqrt(BD_i)`` over
corresponding states, so both HMMs need the same number of states. Diagonal and full
covariances are supported; the diagonal case is vectorised over whole spaces.
"""

from __future__ import annotations

import numpy as np

from shared.errors import ModelError
from shared.pss.hmm import LeftToRightHMM


def bhattacharyya(mu_p, var_p, mu_q, var_q) -> np.ndarray:
    """Eq. 2.3 for Gaussians. ``var`` is either variances (..., D) (diagonal) or covariance
    matrices (..., D, D) (full), chosen by the number of dimensions of ``var`` relative to ``mu``."""
    mu_p, mu_q = np.asarray(mu_p, float), np.asarray(mu_q, float)
    var_p, var_q = np.asarray(var_p, float), np.asarray(var_q, float)
    diff = mu_p - mu_q
    if var_p.ndim == mu_p.ndim:  # diagonal
        s = 0.5 * (var_p + var_q)
        term1 = 0.125 * np.sum(diff * diff / s, axis=-1)
        term2 = 0.5 * np.sum(np.log(s) - 0.5 * (np.log(var_p) + np.log(var_q)), axis=-1)
        return np.maximum(term1 + term2, 0.0)
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


def hmm_distance(a: LeftToRightHMM, b: LeftToRightHMM) -> float:
    """Eq. 2.4: ``sum_i sqrt(BD(b_1i, b_2i))``."""
    _check(a, b)
    return float(np.sum(np.sqrt(bhattacharyya(a.means, a.covars, b.means, b.covars))))


def distances_to(model: LeftToRightHMM, models: list[LeftToRightHMM]) -> np.ndarray:
    """Eq. 2.4 from one HMM to many (vectorised for diagonal covariances)."""
    if not models:
        return np.zeros(0)
    for m in models:
        _check(model, m)
    mu = np.stack([m.means for m in models])
    cov = np.stack([m.covars for m in models])
    bd = bhattacharyya(model.means[None], model.covars[None], mu, cov)
    return np.sum(np.sqrt(bd), axis=1)


def distance_matrix(models: list[LeftToRightHMM]) -> np.ndarray:
    """Symmetric matrix of eq. 2.4 distances with a zero diagonal."""
    n = len(models)
    out = np.zeros((n, n))
    for i in range(n - 1):
        out[i, i + 1:] = distances_to(models[i], models[i + 1:])
    return out + out.T
