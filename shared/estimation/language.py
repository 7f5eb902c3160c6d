"""The words self and other share (thesis 3.3.2): a :class:`Language` (density ``d``, range,
the conversion rule ``F_conv`` and division ``F_div`` of :mod:`shared.estimation.symbols`), the interval
method's scale from answers (eq. 3.4), and the error measures of an estimate (eq. 3.9, 3.10).
Nothing here asks a question: :mod:`shared.estimation.conversation` does."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from shared.estimation.symbols import f_conv, f_div


@dataclass
class Language:
    """What the words mean, shared by self and other: density ``d``, the range ``[0, g_max]``
    split into bins, ``tau_max``, the joints felt, and the conversion rule the self assumes
    (eq. 3.8 unless identified otherwise)."""

    d: int = 4
    g_max: float = 1.0
    tau_max: float = 1.0
    joints: list[str] = field(default_factory=lambda: ["shoulder_pitch", "shoulder_roll", "elbow"])
    rule: str = "eq3.8"
    weights: list[float] | None = None
    missing: list[str] = field(default_factory=list)  # joints the other lacks: the self imitates without them

    def g(self, tau: np.ndarray) -> float:
        return f_conv(tau, self.rule, self.tau_max, self.weights)

    def k(self, tau: np.ndarray) -> int:
        return f_div(self.g(tau), self.d, self.g_max)

    def bounds(self, k: int) -> tuple[float, float]:
        """The g-interval of bin k (the first and last bins are open-ended)."""
        lo = self.g_max * (k - 1) / self.d if k > 1 else 0.0
        hi = self.g_max * k / self.d if k < self.d else np.inf
        return lo, hi


# ---------------------------------------------------------------------------- the interval method
def _scale_bounds(answers, language: Language) -> tuple[list[float], list[float]]:
    lows, highs = [], []
    for g_self, k in answers:
        lo, hi = language.bounds(k)
        g = max(g_self, 1e-12)
        lows.append(lo / g)
        highs.append(hi / g)
    return lows, highs


def scale_interval(answers, language: Language) -> tuple[float, float]:
    """The values of ``s`` (``g_other = s g_self``) that every answer ``(g_self, k)`` allows: the
    other's word ``k`` puts ``s g_self`` in bin ``k`` (eq. 3.4). Empty (lo > hi) when they contradict."""
    if not answers:
        return 0.0, np.inf
    lows, highs = _scale_bounds(answers, language)
    return max(lows), min(highs)


def scale_of(answers, language: Language) -> float:
    """The interval estimator's ``s`` (module docstring) from answers ``(g_self, k)``: the middle
    of :func:`scale_interval`; with only "heavier than" bounds the tightest plus half a bin; with
    contradictory answers (noise) the ``s`` that violates the bounds least. Needs a rule
    homogeneous of degree 1 in the torques (eq. 3.8, f1-f4 all are)."""
    if not answers:
        return 1.0
    lows, highs = _scale_bounds(answers, language)
    lo, hi = max(lows), min(highs)
    if lo <= hi:
        if np.isinf(hi):
            return lo + 0.5 * language.g_max / language.d / max(max(g for g, _ in answers), 1e-12)
        return 0.5 * (lo + hi)
    cands = np.unique(np.r_[lows, [h for h in highs if np.isfinite(h)]])
    return float(cands[np.argmin(_violations(cands, lows, highs))])


def _violations(xs: np.ndarray, lows, highs) -> np.ndarray:
    """How far each ``x`` lies outside every answer's bounds, summed over the answers in
    their order (a running sum: the same numbers as adding them one by one, so the same
    ``x`` wins a tie)."""
    lo, hi = np.asarray(lows, float)[None, :], np.asarray(highs, float)[None, :]
    x = np.asarray(xs, float)[:, None]
    return np.cumsum(np.maximum(0.0, lo - x) + np.maximum(0.0, x - hi), axis=1)[:, -1]


# ---------------------------------------------------------------------------- evaluation
def evaluate(language: Language, true_torques: list[np.ndarray], estimated: list[np.ndarray],
             true_language: Language | None = None) -> dict:
    """Eq. 3.9 error ``mean |g - g_hat| / g``, the symbol match ratio and the symbol distance
    ``mean |k - k_hat| / (d - 1)`` (eq. 3.10). ``g`` uses the other's true rule
    (``true_language``, default the same as the self's)."""
    truth = true_language or language
    g = np.array([truth.g(t) for t in true_torques])
    g_hat = np.array([truth.g(t) for t in estimated])
    k = np.array([truth.k(t) for t in true_torques])
    k_hat = np.array([truth.k(t) for t in estimated])
    return {"error": float(np.mean(np.abs(g - g_hat) / np.maximum(g, 1e-12))),
            "match": float(np.mean(k == k_hat)),
            "distance": float(np.mean(np.abs(k - k_hat)) / (truth.d - 1))}
