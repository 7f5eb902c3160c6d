"""How sure a rate of a few trials is: the exact interval reports give beside a goal's verdict."""

from __future__ import annotations


def rate_interval(successes: int, trials: int, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) ``level`` interval of a rate of ``successes`` in ``trials``
    (scipy's ``binomtest``)."""
    from scipy.stats import binomtest

    ci = binomtest(successes, trials).proportion_ci(confidence_level=level, method="exact")
    return float(ci.low), float(ci.high)


def with_interval(successes: int, trials: int) -> str:
    """``"96.9 % of 65 (89.3-99.6 %)"``: a rate, its trials and its exact 95 % interval."""
    lo, hi = rate_interval(successes, trials)
    return f"{100 * successes / trials:.1f} % of {trials} ({100 * lo:.1f}-{100 * hi:.1f} %)"
