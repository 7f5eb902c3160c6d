"""Split-conformal calibration (Vovk, Gammerman & Shafer 2005): thresholds that a new score of
the kind calibrated on exceeds with a known probability, and p-values of new scores. The
open-set tests of recognition calibrate on these (:mod:`shared.pss.recognition`)."""

from __future__ import annotations

import numpy as np

KNOWN_QUANTILE = 0.98


def conformal_threshold(scores, q: float) -> float:
    """The split-conformal bound: the ``ceil((n + 1) q)``-th smallest of ``n`` calibration
    scores, so that a new score of the same kind exceeds it with probability at most ``1 - q``
    (Vovk et al. 2005); ``inf`` (never reject) when there are too few scores for that level."""
    s = np.sort(np.asarray(scores, float))
    k = int(np.ceil((len(s) + 1) * q))
    return float(s[k - 1]) if 1 <= k <= len(s) else np.inf


def conformal_p_value(scores, score: float, larger_is_unusual: bool = True) -> float:
    """The split-conformal p-value of a new ``score``: ``(1 + #{calibration scores at least as
    unusual}) / (n + 1)``, the chance that a motion of the kind calibrated on looks at least this
    unusual (Vovk et al. 2005; :func:`conformal_threshold` rejects where it is at most about
    ``1 - q``). 1 without calibration scores."""
    s = np.asarray(scores, float)
    if not len(s):
        return 1.0
    beyond = int(np.sum(s >= score)) if larger_is_unusual else int(np.sum(s <= score))
    return (1 + beyond) / (len(s) + 1)
