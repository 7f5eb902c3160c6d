"""Motion generation from any point of the space (eq. 2.7, 4.1, 4.2).

Three steps, each a choice the thesis leaves open, made and written down here:

1. **Weights of a point** (``point_weights``). A point ``x`` is written as an affine
   combination ``x = sum_i c_i x_i`` of proto-symbol points with ``sum_i c_i = 1``; weights may
   be negative, which is what extrapolation (the emphatic point of eq. 4.3) needs. Default:
   the exact combination (``sum c_i x_i = x``) of smallest locality-weighted norm
   ``sum_i (d_i / d_min)^4 c_i^2``, ``d_i`` the distance of proto-symbol ``i`` to ``x``, so
   near proto-symbols carry the weight (least squares where ``x`` is outside the proto-symbols'
   affine hull). A point on a proto-symbol gets that proto-symbol alone; the external dividing
   point ``x_t + alpha (x_t - x_p)`` of two proto-symbols gets ``(1 + alpha, -alpha)``.
   ``method="inverse_distance"`` is convex, weights ``(d_min / d_i)^4`` normalised (the
   mimesis model's inverse-distance rule with the same locality), which can only interpolate;
   chapter 3's association uses it, where a motion outside the hull must not be extrapolated.
2. **Synthesis of an HMM** (``combine``): state means ``sum c_i mu_i``; covariances combined
   in the log domain, ``exp(sum c_i log Sigma_i)`` (log-Euclidean), which stays positive
   definite for any weights, including extrapolation, and returns ``Sigma`` itself when every
   model has the same ``Sigma`` (``variance_rule="mimesis"`` uses ``sum c_i^2 sigma_i^2``);
   transitions combined **in the time domain**: expected stays ``1/(1 - a_ii)`` combined
   linearly and floored at one frame, then turned back into ``a_ii``.
3. **Trajectory** (``generate``): ``monte_carlo`` follows the thesis (state paths sampled from
   the transitions, outputs sampled from the state Gaussians, every sample normalised in time
   and averaged; defaults as the mimesis code: 10 state paths x 30 output sequences), then a
   light Gaussian smoothing; ``expected`` is deterministic: each state mean at the centre of its
   expected stay, joined by a shape-preserving cubic (PCHIP), so the path is smooth.
"""

from __future__ import annotations

import numpy as np

from shared.errors import BadInput
from shared.pss.hmm import LeftToRightHMM

#: the power of :func:`distance_weights` (chosen on nested splits of HDM05's performers: docs/pss.md,
#: "Association across performers")
DISTANCE_POWER = 8


def distance_weights(d, power: float = DISTANCE_POWER) -> np.ndarray:
    """Convex weights ``(d_min / d_i)^power`` (summing to 1) from a motion's eq. 2.4 distances
    ``d`` to every proto-symbol, the distances recognition labels it by (not its point's in the
    low-dimensional space, where eq. 2.6's placement moves it): the nearest proto-symbols take
    (almost) all, several about as near share. All on one proto-symbol at distance 0."""
    d = np.asarray(d, float).ravel()
    if d.size == 0 or not np.all(np.isfinite(d)) or np.any(d < 0):
        raise BadInput("distances must be finite and non-negative, one per proto-symbol")
    if d.min() <= 0.0:
        c = np.zeros(d.size)
        c[np.argmin(d)] = 1.0
        return c
    w = (d.min() / d) ** power
    return w / w.sum()


def point_weights(points: np.ndarray, x: np.ndarray, *, method: str = "affine", k: int | None = None,
                  reg: float = 1.0) -> np.ndarray:
    """Weights ``c`` (summing to 1) with ``sum_i c_i x_i ~ x`` (eq. 4.2's ``beta x_i + gamma x_j``).

    Parameters
    ----------
    points : array (n, dim)
        The proto-symbols' points.
    x : array (dim,)
        The point to reproduce.
    method : {"affine", "inverse_distance"}
        Exact reproduction with the locality-weighted smallest norm (weights may be negative:
        extrapolation), or convex weights ``(d_min / d_i)^4`` (the point stays among the known
        patterns).
    k : int, optional
        Only the ``k`` nearest proto-symbols take part (affine).
    reg : float
        Ridge on the affine system, relative to its trace.

    Returns
    -------
    array (n,)
        The weights; all on one proto-symbol when ``x`` is on its point.
    """
    points = np.asarray(points, float)
    x = np.asarray(x, float).ravel()
    n, dim = points.shape
    if x.shape != (dim,):
        raise BadInput(f"point must have {dim} coordinates, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise BadInput("point contains NaN or Inf")
    d = np.linalg.norm(points - x, axis=1)
    scale = float(np.mean(np.linalg.norm(points - points.mean(axis=0), axis=1))) or 1.0
    c = np.zeros(n)
    if d.min() <= 1e-9 * scale:
        c[np.argmin(d)] = 1.0
        return c
    if method == "inverse_distance":
        # convex weights (d_min / d_i)^4, the same locality as the affine weights below: a
        # point next to a proto-symbol takes (almost) only it, a point between several blends them
        return distance_weights(d, power=4)
    if method != "affine":
        raise BadInput(f"unknown weighting {method!r} (distance, affine or inverse_distance)")
    # exact reproduction sum c_i x_i = x, sum c_i = 1, with the locality-weighted smallest
    # norm sum (d_i / d_min)^4 c_i^2: far proto-symbols get small weights
    idx = np.argsort(d)[: (n if k is None else min(max(k, 1), n))]
    a = np.vstack([points[idx].T, np.ones(len(idx))])
    b = np.concatenate([x, [1.0]])
    winv = (d[idx].min() / d[idx]) ** 4
    m = (a * winv) @ a.T
    lam = np.linalg.lstsq(m + reg * 1e-6 * np.trace(m) / len(m) * np.eye(len(m)), b, rcond=None)[0]
    sol = winv * (a.T @ lam)
    c[idx] = sol / sol.sum()
    return c


def _spd_log(c: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(c)
    return (v * np.log(np.maximum(w, 1e-300))[..., None, :]) @ np.swapaxes(v, -1, -2)


def _spd_exp(c: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(c)
    return (v * np.exp(w)[..., None, :]) @ np.swapaxes(v, -1, -2)


def combine(models: list[LeftToRightHMM], weights, *, variance_rule: str = "log", var_floor: float = 1e-6) -> LeftToRightHMM:
    """Synthesise the HMM of a weighted combination of proto-symbols (ch. 4.3.1, eq. 4.2).

    Parameters
    ----------
    models : list of LeftToRightHMM
        Proto-symbols with as many states and features.
    weights : array (len(models),)
        Weights summing to 1; negative weights extrapolate (an emphatic motion, eq. 4.3).
    variance_rule : {"log", "mimesis"}
        How variances combine: weighted in the log domain (matrix log for full covariances:
        stays positive definite under negative weights), or by the squared weights (the sum of
        independent weighted outputs); floored at ``var_floor`` either way.

    Returns
    -------
    LeftToRightHMM
        Means and variances combined state by state; staying probabilities from the weighted
        expected durations of the states.
    """
    c = np.asarray(weights, float)
    if len(models) != len(c):
        raise BadInput("one weight per proto-symbol is needed")
    if not np.all(np.isfinite(c)):
        raise BadInput("weights contain NaN or Inf")
    if abs(c.sum() - 1.0) > 1e-6:
        raise BadInput(f"weights must sum to 1 (they sum to {c.sum():.6g})")
    used = [(w, m) for w, m in zip(c, models) if w != 0.0]
    ref = used[0][1]
    for _, m in used:
        if (m.n_states, m.n_features, m.covariance_type) != (ref.n_states, ref.n_features, ref.covariance_type):
            raise BadInput("proto-symbols of one space must share state count, output size and covariance type")
    w = np.array([u[0] for u in used])
    mus = np.stack([u[1].means for u in used])
    covs = np.stack([u[1].covars for u in used])
    means = np.tensordot(w, mus, axes=1)
    full = ref.covariance_type == "full"
    if variance_rule == "log":
        if full:
            covars = _spd_exp(np.tensordot(w, _spd_log(covs), axes=1))
        else:
            covars = np.exp(np.tensordot(w, np.log(covs), axes=1))
    elif variance_rule == "mimesis":
        covars = np.tensordot(w * w, covs, axes=1)
    else:
        raise BadInput(f"unknown variance rule {variance_rule!r} (log or mimesis)")
    if full:
        idx = np.arange(covars.shape[1])
        covars = 0.5 * (covars + np.swapaxes(covars, 1, 2))
        covars[:, idx, idx] = np.maximum(covars[:, idx, idx], var_floor)
    else:
        covars = np.maximum(covars, var_floor)
    durations = np.tensordot(w, np.stack([u[1].expected_durations() for u in used]), axes=1)
    durations = np.maximum(durations, 1.0)
    stay = 1.0 - 1.0 / durations
    return LeftToRightHMM(means, covars, np.clip(stay, 0.0, 0.999), ref.covariance_type)


def expected_trajectory(model: LeftToRightHMM, n_frames: int | None = None) -> np.ndarray:
    """Deterministic generation: state means at the centres of their expected stays, joined
    by a PCHIP cubic; ``n_frames`` defaults to the expected total duration."""
    dur = model.expected_durations()
    total = float(dur.sum())
    n_frames = max(2, int(round(total))) if n_frames is None else int(n_frames)
    if model.n_states == 1:
        return np.repeat(model.means, n_frames, axis=0)
    edges = np.concatenate([[0.0], np.cumsum(dur)])
    centres = 0.5 * (edges[:-1] + edges[1:]) / total
    t = (np.arange(n_frames) + 0.5) / n_frames
    t = np.clip(t, centres[0], centres[-1])
    from scipy.interpolate import PchipInterpolator  # here, not at import: recognition never generates

    return PchipInterpolator(centres, model.means, axis=0)(t)


def monte_carlo_trajectory(model: LeftToRightHMM, n_frames: int | None = None, *, n_paths: int = 10,
                           n_outputs: int = 30, seed: int = 0, smooth: float = 1.0) -> np.ndarray:
    """The thesis's generation (ch. 2.5, steps 1-6): sample state paths from the transitions
    and outputs from the state Gaussians, normalise every sample in time and average them."""
    rng = np.random.default_rng(seed)
    dur = model.expected_durations()
    n_frames = max(2, int(round(dur.sum()))) if n_frames is None else int(n_frames)
    n, d = model.n_states, model.n_features
    chol = None
    if model.covariance_type == "full":
        chol = np.linalg.cholesky(model.covars)
    acc = np.zeros((n_frames, d))
    grid = np.linspace(0.0, 1.0, n_frames)
    for _ in range(n_paths):
        # stays are geometric: P(stay = k) = a_ii^(k-1) (1 - a_ii), k >= 1
        stays = rng.geometric(np.clip(1.0 - model.stay, 1e-6, 1.0))
        path = np.repeat(np.arange(n), stays)
        length = len(path)
        src = np.linspace(0.0, 1.0, length) if length > 1 else np.zeros(1)
        mu = model.means[path]
        summed = np.zeros((length, d))  # the outputs of one path share its time normalisation, which is
        for _ in range(n_outputs):  # linear: summed first, normalised once (30x less work, same result)
            z = rng.standard_normal((length, d))
            if chol is None:
                summed += mu + z * np.sqrt(model.covars[path])
            else:
                summed += mu + np.einsum("tij,tj->ti", chol[path], z)
        if length == 1:
            acc += summed
        else:
            pos = np.interp(grid, src, np.arange(length))
            lo = np.floor(pos).astype(int)
            hi = np.minimum(lo + 1, length - 1)
            frac = (pos - lo)[:, None]
            acc += (1 - frac) * summed[lo] + frac * summed[hi]
    out = acc / (n_paths * n_outputs)
    if smooth > 0:
        from scipy.ndimage import gaussian_filter1d

        out = gaussian_filter1d(out, smooth, axis=0, mode="nearest")
    return out


def generate(model: LeftToRightHMM, n_frames: int | None = None, *, method: str = "expected", seed: int = 0,
             n_paths: int = 10, n_outputs: int = 30) -> np.ndarray:
    """Feature frames generated from a proto-symbol (eq. 2.7 / 4.1).

    Parameters
    ----------
    model : LeftToRightHMM
        A proto-symbol, or one synthesised by :func:`combine`.
    n_frames : int, optional
        Frames of the result (default: the model's expected duration).
    method : {"expected", "monte_carlo"}
        Each state's mean held for its expected duration, or the mean of ``n_paths`` sampled
        state paths with ``n_outputs`` outputs each.
    seed : int
        The seed of the sampled paths.

    Returns
    -------
    array (n_frames, n_features)
    """
    if n_frames is not None and n_frames < 2:
        raise BadInput("a generated motion needs at least 2 frames")
    if method == "expected":
        return expected_trajectory(model, n_frames)
    if method == "monte_carlo":
        return monte_carlo_trajectory(model, n_frames, n_paths=n_paths, n_outputs=n_outputs, seed=seed)
    raise BadInput(f"unknown generation method {method!r} (expected or monte_carlo)")
