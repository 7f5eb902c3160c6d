"""Multidimensional scaling: proto-symbols as points of a Euclidean space (thesis ch. 2.5).

The space minimises the stress ``S^2 = sum_{i<j} (f_ij - d_ij)^2`` between the HMM distances
``f_ij`` (eq. 2.4) and the Euclidean distances ``d_ij`` of the points. Metric SMACOF
(majorisation with the Guttman transform) started from classical (Torgerson) MDS; the
out-of-sample placement of a new motion (eq. 2.6) minimises the same stress over the one new
point with every existing point fixed. scikit-learn's ``smacof`` is the reference the tests
compare with; this implementation exists because the out-of-sample step needs the same
majorisation with fixed points, which scikit-learn does not offer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.compiled import kernel
from shared.errors import BadInput


@dataclass
class Embedding:
    points: np.ndarray
    stress: float  # raw stress sum_{i<j} (f_ij - d_ij)^2
    stress1: float  # Kruskal's normalised stress sqrt(S^2 / sum f_ij^2)
    n_iter: int
    converged: bool


def raw_stress(f: np.ndarray, x: np.ndarray) -> float:
    """``sum_{i<j} (f_ij - |x_i - x_j|)^2``, in one compiled pass (no N x N temporary)."""
    return float(_guttman_step(np.ascontiguousarray(f, dtype=float), np.ascontiguousarray(x, dtype=float))[1])


ROWS = 512  # rows of an N x N matrix taken at once by the checks below (no N x N temporary)


def classical_mds(f: np.ndarray, dim: int) -> np.ndarray:
    """Torgerson scaling: the top eigenvectors of the double-centred squared distances
    ``B = -1/2 J F^2 J``, centred in place on one N x N array and only the ``dim`` largest
    eigenpairs solved (scipy's ``eigh``, MRRR): 3,000 proto-symbols held 6 N x N arrays before.
    Each eigenvector's sign is fixed (its largest component positive), whatever the solver."""
    from scipy.linalg import eigh

    f = np.asarray(f, dtype=float)
    n = len(f)
    b = f * f
    row = b.mean(axis=1)
    b -= row[:, None]
    b -= row[None, :]
    b += row.mean()
    b *= -0.5
    k = min(dim, n)
    w, v = eigh(b, subset_by_index=[n - k, n - 1], overwrite_a=True, check_finite=False)
    del b
    order = np.argsort(w)[::-1]
    w, v = w[order], v[:, order]
    v *= np.where(v[np.argmax(np.abs(v), axis=0), np.arange(k)] < 0, -1.0, 1.0)
    x = v * np.sqrt(np.maximum(w, 0.0))
    if x.shape[1] < dim:
        x = np.hstack([x, np.zeros((n, dim - x.shape[1]))])
    return x


def pair_squares(f: np.ndarray) -> float:
    """``sum_{i<j} f_ij^2`` of a symmetric matrix with a zero diagonal, ``ROWS`` rows at a time."""
    return sum(float(np.sum(f[a:a + ROWS] ** 2)) for a in range(0, len(f), ROWS)) / 2


def _valid_distances(f: np.ndarray) -> bool:
    """Symmetric (to ``np.allclose``'s tolerance), non-negative, zero diagonal: checked
    ``ROWS`` rows at a time."""
    for a in range(0, len(f), ROWS):
        rows, cols = f[a:a + ROWS], f[:, a:a + ROWS].T
        if not np.allclose(rows, cols) or np.any(rows < 0):
            return False
    return not np.any(np.diag(f) != 0)


def smacof(f: np.ndarray, dim: int, *, init: np.ndarray | None = None, max_iter: int = 3000, eps: float = 1e-9) -> Embedding:
    """Metric MDS minimising ``sum (f_ij - d_ij)^2`` (the criterion of ch. 2.5).

    Parameters
    ----------
    f : array (n, n)
        Symmetric, non-negative distances with a zero diagonal (eq. 2.4 between proto-symbols).
    dim : int
        Dimension of the space.
    init : array (n, dim), optional
        The start (default: classical MDS).
    max_iter, eps : int, float
        Guttman iterations at most, and the relative decrease of stress that ends them.

    Returns
    -------
    Embedding
        The points, the raw stress, Kruskal's stress-1, the iterations and whether they converged.

    References
    ----------
    J. de Leeuw, "Applications of convex analysis to multidimensional scaling", in Recent
    Developments in Statistics, 1977 (SMACOF); I. Borg, P. Groenen, Modern Multidimensional
    Scaling, 2nd ed., Springer, 2005.
    """
    f = np.asarray(f, dtype=float)
    n = len(f)
    if f.shape != (n, n):
        raise BadInput("MDS needs a symmetric, non-negative distance matrix with a zero diagonal")
    if not np.all(np.isfinite(f)):
        raise BadInput("MDS distance matrix contains NaN or Inf")
    if not _valid_distances(f):
        raise BadInput("MDS needs a symmetric, non-negative distance matrix with a zero diagonal")
    if dim < 1:
        raise BadInput("dimension must be at least 1")
    x = classical_mds(f, dim) if init is None else np.array(init, dtype=float)
    if n < 2:
        return Embedding(x, 0.0, 0.0, 0, True)
    total = pair_squares(f) or 1.0
    f = np.ascontiguousarray(f)
    x = np.ascontiguousarray(x)
    step, stress = _guttman_step(f, x)  # the Guttman transform of x and the stress at x
    converged = False
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is read after the loop)
        x = step
        step, new = _guttman_step(f, x)
        if stress - new < eps * total:
            stress = new
            converged = True
            break
        stress = new
    x = x - x.mean(axis=0)
    return Embedding(x, stress, float(np.sqrt(stress / total)), it, converged)


@kernel(cache=True, nogil=True)
def _guttman_step(f, x):
    """One SMACOF iteration in one pass over the pairs, with no N x N temporary: the stress
    ``sum_{i<j} (f_ij - d_ij)^2`` at ``x`` and the Guttman transform ``B(x) x / n``
    (``b_ij = -f_ij / d_ij``, ``b_ii = -sum_j b_ij``)."""
    n, dim = x.shape
    out = np.zeros((n, dim))
    stress = 0.0
    diff = np.empty(dim)
    for i in range(n - 1):
        for j in range(i + 1, n):
            d2 = 0.0
            for c in range(dim):
                diff[c] = x[i, c] - x[j, c]
                d2 += diff[c] * diff[c]
            d = np.sqrt(d2)
            stress += (f[i, j] - d) ** 2
            if d > 1e-12:
                r = f[i, j] / d
                for c in range(dim):
                    out[i, c] += r * diff[c]
                    out[j, c] -= r * diff[c]
    return out / n, stress


@kernel(cache=True, nogil=True)
def _stress_and_update(points, f, x):
    """Stress ``sum_i (f_i - |x - x_i|)^2`` at ``x`` and the Guttman update
    ``mean_i (x_i + f_i (x - x_i) / |x - x_i|)``."""
    n, dim = points.shape
    stress = 0.0
    new = np.zeros(dim)
    for i in range(n):
        d = 0.0
        for c in range(dim):
            d += (x[c] - points[i, c]) ** 2
        d = np.sqrt(d)
        stress += (f[i] - d) ** 2
        for c in range(dim):
            u = (x[c] - points[i, c]) / d if d > 1e-12 else 0.0
            new[c] += points[i, c] + f[i] * u
    return stress, new / n


@kernel(cache=True, nogil=True)
def _guttman_point(points, f, starts, max_iter, eps):
    """Guttman iterations for one free point from every start, until the stress stops
    falling by ``eps`` (relative); the best point of each start and its stress."""
    x = starts.copy()
    s = np.empty(len(starts))
    for k in range(len(starts)):
        xk = starts[k].copy()
        sk, new = _stress_and_update(points, f, xk)
        for _ in range(max_iter):
            sc, new_c = _stress_and_update(points, f, new)
            done = sk - sc < eps * (1.0 + sc)
            if sc <= sk:
                xk, sk, new = new, sc, new_c
            if done:
                break
        x[k] = xk
        s[k] = sk
    return x, s


@_guttman_point.numpy
def _guttman_point_numpy(points, f, starts, max_iter, eps):
    def stress_and_update(x):  # every start at once: (K, dim) -> (K,), (K, dim)
        diff = x[:, None, :] - points[None]
        d = np.sqrt((diff * diff).sum(axis=2))
        u = np.where(d[..., None] > 1e-12, diff / np.where(d > 1e-12, d, 1.0)[..., None], 0.0)
        return ((f - d) ** 2).sum(axis=1), (points[None] + f[None, :, None] * u).mean(axis=1)

    x = starts.copy()
    s, new = stress_and_update(x)
    active = np.ones(len(x), bool)
    for _ in range(max_iter):
        if not active.any():
            break
        sc, new_c = stress_and_update(new)
        done = s - sc < eps * (1.0 + sc)
        better = active & (sc <= s)
        x[better], s[better], new[better] = new[better], sc[better], new_c[better]
        active &= ~done
    return x, s


def place_point(points: np.ndarray, f: np.ndarray, *, max_iter: int = 50, eps: float = 1e-9) -> tuple[np.ndarray, float]:
    """Out-of-sample embedding (eq. 2.6): the point ``x`` minimising
    ``sum_i (f_i - |x - x_i|)^2`` with the space's points ``x_i`` fixed.

    Guttman majorisation for one free point, from several starts (the nearest proto-symbol,
    the inverse-distance centroid and their mirror images); returns the best point and its stress.

    Parameters
    ----------
    points : array (n, dim)
        The space's points, fixed.
    f : array (n,)
        The new motion's eq. 2.4 distances to each of them.

    Returns
    -------
    point : array (dim,)
    stress : float
        ``sum_i (f_i - |x - x_i|)^2`` at the point.
    """
    points = np.asarray(points, float)
    f = np.asarray(f, float)
    if len(points) != len(f):
        raise BadInput("one distance per proto-symbol is needed")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise BadInput("distances must be finite and non-negative")
    n, dim = points.shape
    if n == 1:
        x = points[0].copy()
        x[0] += f[0]
        return x, 0.0
    w = 1.0 / np.maximum(f, 1e-12)
    centroid = (w[:, None] * points).sum(axis=0) / w.sum()
    nearest = points[np.argmin(f)]
    spread = points.std(axis=0).mean() or 1.0
    nudge = np.sin(np.arange(1.0, dim + 1.0))  # off the proto-symbol itself (|x - x_i| = 0), the same every call
    starts = [nearest + 1e-3 * spread * nudge, centroid,
              2 * centroid - nearest, centroid + 0.5 * (centroid - points.mean(axis=0))]

    x, s = _guttman_point(np.ascontiguousarray(points), np.ascontiguousarray(f), np.stack(starts), max_iter, eps)
    b = int(np.argmin(s))
    return x[b], float(s[b])
