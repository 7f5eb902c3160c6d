"""How a recognised motion gets its label: the decision on top of ``F_recog`` (eq. 2.6).

The thesis recognises a motion by its point in the space. Measured on HDM05 (the
recognition report, ``reports/recognition/report.md``), the label is best decided before the point: by the eq.
2.4 distance between the motion's HMM and every proto-symbol *on the position channel group*
(:mod:`shared.pss.features`), nearest proto-symbol first. The same report measures the
alternatives this module does not use on the same distances (k-NN with k = 3 and 5, a
logistic regression on per-class distances, :func:`shared.reports.evaluation.pss_alternatives`) and
the nearest point of the 3-D space; none did better. Where every class holds two or more
proto-symbols, the label also weighs the :class:`DiscriminantRatio`'s distance to each class's
mean (:func:`nearest_class`): on HDM05 it changes no label, on a game studio's styles it takes
the closed set from 68.6 to 79.1 % (MiniRocket 76.7 %; ``bench/results/styles.md``).

The distance is eq. 2.4 with **channel weights** on the mean term (:func:`channel_weights`,
a Fisher ratio per channel from the space's own proto-symbols): a joint coordinate that
differs between classes more than between performers of one class counts more. Measured on
HDM05 leave-one-actor-out (the recognition report): the same 100 % closed-set accuracy, and the held-out
class's clips stand out more (nearest / second class ratio: AUC 0.93 -> 0.95; out-of-class
rejection at 5 % in-class rejection 62 -> 74 %).

On top of the label:

* **confidence**: a softmax over the classes of ``-d_c / T`` where ``d_c`` is the distance to
  the nearest proto-symbol of class ``c``; the temperature ``T`` maximises the likelihood of
  the space's own proto-symbols recognised *across performers* (each proto-symbol against the
  proto-symbols of other performers, a performer being the skeleton its clips came with; plain
  leave-one-out when the space has only one performer; a space of one clip per motion, with
  nothing to fit it on, takes :data:`ONE_EXAMPLE_TEMPERATURE` of its median distance). A motion
  the open set rejects keeps at most its *credibility* as confidence: the smallest of the tests' split-conformal p-values
  (:func:`conformal_p_value`), how often the space's own known motions (the calibration) look
  at least as unusual, so the confidence falls on motions the space does not hold (about
  ``1 - known_quantile`` and below where a test rejects) instead of staying the softmax's
  share among the classes it does. Where the label weighs the discriminant (every class with
  two proto-symbols or more: :func:`nearest_class`), the softmax reads the label's own score in
  eq. 2.4's units (:func:`shared.pss.confidence.label_distances`) at the same temperature, so
  the label is its most likely class; eq. 2.4's softmax alone gave a label the discriminant
  moved off eq. 2.4's nearest class a small share. Chosen on the game studio's half split's 8
  training styles (leave one style out, 88 clips, 84 % right; the softmax's share before the
  open set, against the closed-set label): mean confidence 0.31 -> 0.76, calibration error
  0.53 -> 0.11, the true class's negative log-likelihood 1.45 -> 0.56 (a
  temperature of its own fitted across performers on that score: 0.22, 0.67). Reported on the
  half split's 7 held-out styles (``bench/results/styles.md``): mean confidence 0.42 -> 0.78 at
  79 % right (as shown 77 %), calibration error 0.35 -> 0.07, but wrong labels at 0.5 or more 1
  -> 7 of 17 (on the choice clips it ranks right above wrong about as before: AUROC 0.63 ->
  0.65); HDM05's splits (``reports/recognition/report.md``) the same to within 0.03;
* **open set** ("none of these"): a motion is unknown when any of three tests says so.

  1. *Too far*, measured in its label's class's own spread: the distance over the class's
     scale (the median of its proto-symbols' nearest same-class distances across performers)
     above the ``known_quantile`` quantile of the calibration's same ratios (normalised
     nonconformity scores, Papadopoulos et al. 2008), so a class whose performers differ much
     tolerates a farther newcomer than one whose performers agree. Each calibration score is
     divided by its class's scale computed without it, as a new motion's scale never
     contains the motion itself.
  2. *Not clearly nearer to one class than to the next*: the :class:`DiscriminantRatio`, the
     distance to the nearest class mean over the distance to the second in a shrinkage LDA
     of the proto-symbols' HMMs, above the same quantile of the space's own ratios under an
     LDA of the other performers. Spaces written before it (and the DTW peer) take the same
     ratio on the eq. 2.4 class distances instead (``Calibration.ratio_threshold``).
  3. The :class:`NoveltyModel`'s margin (a ridge classifier on the same HMMs): an unknown
     motion that resembles several known classes at once.

  All bounds are split-conformal (:func:`conformal_threshold`): a space with fewer than
  ``1 / (1 - known_quantile) - 1`` calibration proto-symbols (49 at the default 0.98) never
  rejects by them, because its own motions cannot say how far a new performer may be.
  Measured on HDM05 with every class held out in turn (``reports/recognition/report.md``,
  ``make bench``): 90.4 % of unknown clips rejected at 2.8 % of known ones (per test performer
  bd / bk / dg: 88.7 / 92.3 / 90.2 % and 0.5 / 3.5 / 4.3 %; with the novelty model at 0.95,
  93.6 / 3.5 %; 91.0 % and 3.1 % before the discriminant's features were scaled by their
  within-class spread, 90.3 / 92.3 / 90.2 % and 0.5 / 4.6 / 4.3 %). The eq. 2.4 ratio in place of the discriminant ratio gave 89.4 / 4.3 %,
  and one spread for all classes 87.2 / 4.9 % (earlier features). The class spreads and the
  discriminant ratio were chosen after seeing these splits; the ratio keeps the level the eq.
  2.4 ratio had.

The distance rule is computed from the space's distances, the discriminant ratio and the
novelty model from its proto-symbols' HMMs; all lazily, once per space object, and saved with
the space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.compiled import kernel
from shared.pss.confidence import (
    DISCRIMINANT_WEIGHT,
    class_distances,
    fitted_temperature,
    label_distances,
    nearest_class,
    softmax_confidence,
)
from shared.pss.conformal import KNOWN_QUANTILE, conformal_p_value, conformal_threshold
from shared.pss.discriminant import DiscriminantRatio
from shared.pss.novelty import NOVELTY_QUANTILE, NoveltyModel, hmm_features
from shared.pss.symbol import one_clip_per_motion

__all__ = ["decide", "can_reject", "open_set_text", "rejected_by", "Decision", "TESTS", "calibrate", "Calibration",
           "channel_weights", "class_distances", "softmax_confidence", "DiscriminantRatio", "NoveltyModel", "hmm_features", "NOVELTY_QUANTILE",
           "conformal_threshold", "conformal_p_value", "KNOWN_QUANTILE", "DISCRIMINANT_WEIGHT", "nearest_class"]


def channel_weights(means: np.ndarray, covars: np.ndarray, labels, performers) -> np.ndarray:
    """Per-channel weights of the recognition distance (see module docstring).

    ``means``, ``covars``: the proto-symbols' diagonal state parameters (N, S, D). For every
    channel ``d``, ``B_d`` is the mean over pairs of proto-symbols of different classes, and
    ``W_d`` over pairs of one class from different performers (any two of one class when the
    space has one performer), of eq. 2.3's per-channel terms summed over states; the weight
    is ``sqrt(B_d / W_d)``, scaled to mean 1, and 0 for a channel that never varies.
    All ones (eq. 2.4 itself) when the space has no same-class pair or only one class."""
    mu = np.ascontiguousarray(means, dtype=float)
    var = np.ascontiguousarray(covars, dtype=float)
    n, _, dim = mu.shape
    labels = np.asarray(labels)
    perf = np.asarray(performers) if performers is not None and len(performers) == n else np.array([""] * n)
    across = len(set(perf)) > 1
    lab_id = np.unique(labels, return_inverse=True)[1].astype(np.int64)
    perf_id = np.unique(perf, return_inverse=True)[1].astype(np.int64)
    within, between, n_within, n_between = _channel_pair_sums(mu, var, lab_id, perf_id, across)
    if not n_within or not n_between:
        return np.ones(dim)
    within /= n_within
    between /= n_between
    w = np.where(within > 1e-12, np.sqrt((between + 1e-9) / (within + 1e-9)), 0.0)
    return w / w.mean() if w.mean() > 0 else np.ones(dim)


@kernel(cache=True, nogil=True)
def _channel_pair_sums(mu, var, label, perf, across):
    """Over every pair of proto-symbols, eq. 2.3's per-channel terms summed over states
    (:func:`shared.pss.distance.bhattacharyya_terms`), added up separately for pairs of one
    class (from different performers when ``across``) and pairs of different classes; one
    pass, no N x N x D temporary (the numpy reference took 6.7 s for 1,000 proto-symbols)."""
    n, n_states, dim = mu.shape
    within = np.zeros(dim)
    between = np.zeros(dim)
    n_within = 0
    n_between = 0
    logv = np.log(var)
    for i in range(n - 1):
        for j in range(i + 1, n):
            if label[i] == label[j]:
                if across and perf[i] == perf[j]:
                    continue
                acc = within
                n_within += 1
            else:
                acc = between
                n_between += 1
            for s in range(n_states):
                for d in range(dim):
                    v = 0.5 * (var[i, s, d] + var[j, s, d])
                    diff = mu[i, s, d] - mu[j, s, d]
                    acc[d] += 0.125 * diff * diff / v + 0.5 * (np.log(v) - 0.5 * (logv[i, s, d] + logv[j, s, d]))
    return within, between, n_within, n_between


@dataclass
class Calibration:
    """What the decision learnt from the space's own proto-symbols."""

    classes: list[str]
    temperature: float
    threshold: float  # nearest class distance above which a motion is "none of these"
    ratio_threshold: float  # nearest / second-nearest class distance above which it is too
    n_calibration: int  # proto-symbols that had a same-class proto-symbol of another performer
    scheme: str  # "across performers" or "leave one out"
    # per class (in ``classes`` order), the scale its distances are divided by before the
    # threshold; None in files written before it (their threshold is on raw distances)
    class_scales: list[float] | None = None
    # the distance rule's calibration scores (distance over class scale), for the credibility of a
    # rejected motion; None in files written before it
    scores: list[float] | None = None


#: The confidence temperature of a space of one clip per motion (one proto-symbol for most motions,
#: :func:`shared.pss.symbol.one_clip_per_motion`), as a share of its median distance: such a space has
#: no rows (or two) to fit one on. Chosen by the likelihood of the true class on one-clip spaces kept
#: apart from the reports (the game studio's 8 training styles, each alone recognising the other 7;
#: HDM05's bd and bk each other's clips: optimum 0.112; ``bench.styles --choose``); docs/pss.md, step 3.
ONE_EXAMPLE_TEMPERATURE = 0.11


def calibrate(recognition_distances: np.ndarray, labels: list[str], performers: list[str],
              known_quantile: float = KNOWN_QUANTILE) -> Calibration:
    """Fit the confidence temperature and the open-set threshold (see module docstring)."""
    d = np.asarray(recognition_distances, float)
    labels_a = np.asarray(labels)
    perf = np.asarray(performers) if performers and len(performers) == len(labels) else None
    classes = sorted(set(labels))
    across = perf is not None and len(set(perf)) > 1
    # per proto-symbol, its class distances to the others (not itself; across performers: not
    # its own performer's), in blocks of rows so that no second N x N matrix is held
    label_id = np.array([classes.index(x) for x in labels_a])
    all_dc = np.empty((len(labels_a), len(classes)))
    for lo in range(0, len(labels_a), 512):
        block = d[lo:lo + 512].copy()
        rows_i = np.arange(lo, min(lo + 512, len(labels_a)))
        block[rows_i - lo, rows_i] = np.inf
        if across and perf is not None:
            block[perf[rows_i][:, None] == perf[None, :]] = np.inf
        for k in range(len(classes)):
            cols = label_id == k
            all_dc[lo:lo + 512, k] = block[:, cols].min(axis=1) if cols.any() else np.inf
    keep = np.isfinite(all_dc[np.arange(len(labels_a)), label_id])
    dc_all = all_dc[keep]
    y = label_id[keep]
    near = dc_all[np.arange(len(y)), y]
    # each row's own class against the nearest other class (rows with another class in reach)
    other = dc_all.copy()
    other[np.arange(len(y)), y] = np.inf
    nearest_other = other.min(axis=1)
    reach = np.isfinite(nearest_other)
    ratios = list(near[reach] / np.maximum(nearest_other[reach], 1e-12))
    scheme = "across performers" if across else "leave one out"
    one_clip = one_clip_per_motion(labels_a)
    if one_clip or not len(y):  # nothing (or a class or two) to fit a temperature on: borrowed
        scale = float(np.median(d[np.triu_indices(len(d), 1)])) if len(d) > 1 else 1.0
        temperature = ONE_EXAMPLE_TEMPERATURE * max(scale, 1e-6)
        scheme = "one proto-symbol per motion" if one_clip else "no class of two performers"
        if not len(y):
            return Calibration(classes, temperature, np.inf, np.inf, 0, scheme)
    else:
        temperature = fitted_temperature(dc_all, y, float(np.median(near)) or 1.0)
    # each calibration score divided by its class's spread without itself, as a new motion's is
    # divided by a spread it had no part in
    own = _class_spreads_without_each(near, y)
    threshold = conformal_threshold(near / own, known_quantile)
    ratio_threshold = conformal_threshold(ratios, known_quantile) if ratios else np.inf
    return Calibration(classes, temperature, threshold, ratio_threshold, len(y), scheme,
                       [_class_spread(near, y, k) for k in range(len(classes))], [float(v) for v in near / own])


def _class_spreads_without_each(nearest_same: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """:func:`_class_spread` of each row's class without that row, for every row at once: the
    median of a sorted pool with one value taken out is one of its middle order statistics."""
    out = np.empty(len(nearest_same))

    def medians_without(values: np.ndarray) -> np.ndarray:  # median of values without each one
        order = np.argsort(values, kind="stable")
        srt = values[order]
        m = len(values) - 1  # the pool left
        rank = np.empty(len(values), int)
        rank[order] = np.arange(len(values))

        def at(j):  # the j-th smallest of the pool without the value of rank r
            return np.where(j < rank, srt[np.minimum(j, len(srt) - 1)], srt[np.minimum(j + 1, len(srt) - 1)])

        if m % 2:
            res = at(np.full(len(values), m // 2))
        else:
            res = 0.5 * (at(np.full(len(values), m // 2 - 1)) + at(np.full(len(values), m // 2)))
        return res

    everyone = medians_without(nearest_same) if len(nearest_same) > 1 else np.array([np.nan])
    for k in np.unique(truth):
        rows = np.flatnonzero(truth == k)
        if len(rows) > 1:
            out[rows] = medians_without(nearest_same[rows])
        else:  # the class's only row: the median over every other row
            out[rows] = everyone[rows] if len(nearest_same) > 1 else 1.0
    return np.maximum(out, 1e-12)


def _class_spread(nearest_same: np.ndarray, truth: np.ndarray, k: int, skip: int | None = None) -> float:
    """Class ``k``'s spread: the median of its calibration proto-symbols' nearest same-class
    distances across performers (without calibration row ``skip``); the median over every row
    (but ``skip``) for a class without any, 1 when there is none at all."""
    keep = np.ones(len(nearest_same), bool)
    if skip is not None:
        keep[skip] = False
    mine = keep & (truth == k)
    pool = nearest_same[mine] if mine.any() else nearest_same[keep]
    return max(float(np.median(pool)), 1e-12) if len(pool) else 1.0


@dataclass
class Decision:
    label: str | None  # None: "none of these" (open-set rejection)
    nearest_label: str  # the nearest class (:func:`nearest_class`), the label unless the open set rejects
    confidence: float  # calibrated probability of nearest_label among the space's classes; for a motion the
    # tests reject, at most its credibility (the chance a known motion looks this unusual)
    novelty: float  # the largest of the tests' (> 1: unknown)
    distance_novelty: float = 0.0  # the eq. 2.4 rule's: distance / threshold (and, without a
    # discriminant ratio, the eq. 2.4 ratio / its threshold)
    model_novelty: float = 0.0  # the novelty model's: threshold / margin (0 without a model)
    ratio_novelty: float = 0.0  # the discriminant ratio's: ratio / threshold (0 without one)
    # the smallest conformal p-value of the tests (:func:`conformal_p_value`): how often the
    # space's own known motions look at least this unusual (1 where no test has scores)
    credibility: float = 1.0


#: the open-set tests by the names a rejection gives them (:func:`rejected_by`)
TESTS = ("distance", "ratio", "model")


def rejected_by(d: Decision) -> list[str]:
    """Which of the open-set tests said "none of these" (each novelty above 1): ``distance``
    (farther from its nearest class than the space's known motions are), ``ratio`` (not
    clearly nearer to one class than to the next), ``model`` (the novelty model finds it
    between classes)."""
    return [name for name, v in zip(TESTS, (d.distance_novelty, d.ratio_novelty, d.model_novelty)) if v > 1.0]


def can_reject(cal: Calibration, discriminant: DiscriminantRatio | None, novelty_model: NoveltyModel | None) -> bool:
    """Whether any of :func:`decide`'s open-set tests can say "none of these": each is
    split-conformal and has no bound (never rejects) without enough known motions to calibrate on."""
    def bounds(t) -> bool:  # as :func:`decide` reads a threshold
        return bool(np.isfinite(t) and t > 0)

    return (bounds(cal.threshold) or bounds(discriminant.threshold if discriminant is not None else cal.ratio_threshold)
            or (novelty_model is not None and bounds(novelty_model.threshold)))


def open_set_text(cal: Calibration, n_classes: int, ratio_on_distances: bool, without_model: bool,
                  rejects: bool) -> str:
    """How a space says "none of these", for its summary: the tests it has (``ratio_on_distances``:
    a file written before the discriminant ratio; ``without_model``: without the novelty model),
    and whether they can reject at all (:func:`can_reject`)."""
    if n_classes <= 1:
        tests = " alone (one class: no other class to be nearer to)"
    else:
        tests = (" with the ratio on eq. 2.4 distances (a file written before the discriminant ratio)"
                 if ratio_on_distances else ", the discriminant ratio") + (
            " (without the novelty model: a file written before it, or built without the open set)"
            if without_model else " or the novelty model")
    return ("none of these: the distance rule"
            + (" (one spread for all classes: a file written before the class spreads)"
               if cal.n_calibration and not cal.class_scales else "") + tests
            + ("" if rejects else f"; it never rejects: {cal.n_calibration} known motions to calibrate on, too few"))


def decide(distances: np.ndarray, labels: list[str], cal: Calibration, novelty_model: NoveltyModel | None = None,
           features: np.ndarray | None = None, discriminant: DiscriminantRatio | None = None) -> Decision:
    """Label, calibrated confidence and open-set verdict of one motion. The motion is "none of
    these" when any test says so: the eq. 2.4 distance in its class's spread; whether it is
    clearly nearer to one class than to the next (by the :class:`DiscriminantRatio` given the
    motion's :func:`hmm_features`, else by the eq. 2.4 ratio: spaces written before it and the
    DTW peer); and, given a :class:`NoveltyModel` and the features, the model's margin.

    Parameters
    ----------
    distances : array (n_proto_symbols,)
        The motion's eq. 2.4 distances on the recognition group.
    labels : list of str
        The proto-symbols' classes.
    cal : Calibration
        The space's calibration across performers (:func:`calibrate`).
    novelty_model, features, discriminant : optional
        The fitted open-set tests and the motion's :func:`hmm_features` they read.

    Returns
    -------
    Decision
        ``label`` (``None``: "none of these"), ``nearest_label``, ``confidence``, ``novelty``
        and each test's own novelty.
    """
    dc = class_distances(np.asarray(distances, float), np.asarray(labels), cal.classes)
    order = np.argsort(dc)
    scores = dc  # what the label and its confidence read: eq. 2.4, or the label's own score
    ratio, p_ratio = 0.0, 1.0
    if discriminant is not None and features is not None:
        own = discriminant.centre_distances(features)[0]  # once, for the label and the ratio test
        if discriminant.smallest_class >= 2:  # its smallest is nearest_class's label
            scores = label_distances(dc, discriminant.class_distances(features, cal.classes, own))
        ratio, p_ratio = discriminant.judged(features, own)
    k = int(np.argmin(scores))
    p = softmax_confidence(scores, cal.temperature)
    model, p_model = (novelty_model.judged(features) if novelty_model is not None and features is not None
                      else (0.0, 1.0))
    distance = 0.0
    credibility = [p_model, p_ratio]
    if np.isfinite(cal.threshold) and cal.threshold > 0:
        scale = cal.class_scales[k] if cal.class_scales else 1.0
        distance = float(dc[k] / scale / cal.threshold)
        credibility.append(conformal_p_value(cal.scores or [], float(dc[k] / scale)))
    if (discriminant is None or features is None) and len(dc) > 1 and np.isfinite(cal.ratio_threshold) \
            and np.isfinite(dc[order[1]]) and cal.ratio_threshold > 0:
        distance = max(distance, float(dc[k] / max(dc[order[1]], 1e-12) / cal.ratio_threshold))
    novelty = max(distance, model, ratio)
    known = novelty <= 1.0
    # a motion the tests call "none of these" is the nearest class with at most its credibility
    confidence = float(p[k]) if known else min(float(p[k]), min(credibility))
    return Decision(cal.classes[k] if known else None, cal.classes[k], confidence, novelty, distance, model, ratio,
                    min(credibility))
