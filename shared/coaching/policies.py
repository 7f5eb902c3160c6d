"""How much to emphasise and which adverb to say (thesis ch. 4-6).

Every policy answers ``choose(d_p, d_cop, learner) -> (alpha, adverb)`` for the emphatic point
``x_s = x_t + alpha (x_t - x_p)`` (eq. 4.3):

* ``fixed``: a constant alpha with no adverb, a constant adverb ("more like this", case 2) or
  Table 4.1's adverb for the alpha (cases 1-4);
* ``aeu1`` / ``aeu2`` (table 5.2): the adverb from ``d_p`` thresholds 130/165 (beginners) or
  160/180 (experienced), in the thesis's units: our distances are mapped to them by an explicit
  :class:`Calibration`, never assumed to agree;
* ``emu1``: ``alpha = 1 + slope`` of the regression of ``d_s`` on ``d_p`` over observed coach
  demonstrations (eq. 5.3-5.5); ``emu1c`` the corrected form on ``d_h``, the distance from
  ``x_t`` to the projection of ``x_s`` on the line through ``x_p`` and ``x_t`` (eq. 5.8, 5.9).
  Note the thesis's two alphas: eq. 5.3 defines ``alpha = (d_p + d_s) / d_p``, which is
  ``1 +`` eq. 4.3's alpha (``d_s = alpha_4.3 d_p``); the thesis reads eq. 5.5's values near 1 as
  "almost no emphasis" accordingly. The policies emphasise with eq. 4.3, so an EMU-1 policy uses
  ``alpha_4.3 = alpha_5.5 - 1``;
* ``emu2``: a per-learner alpha picked from a sweep of {1.25, ..., 2.50} (fig. 5.7, 5.8);
* ``nb``: the adverb from a naive Bayes classifier (scikit-learn ``GaussianNB``) over
  ``(d_p, d_cop)``, trained on logged trials (eq. 6.6);

and any of them can emphasise one body part at a time (``body_part``, beyond the thesis) or
coach through sub-goals (``subgoal``, thesis 4.6 and 7.3; :mod:`shared.coaching.session`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from shared.deadline import check_time
from shared.errors import BadInput

TABLE_4_1 = {1.5: "a little more", 2.0: "more", 2.5: "much more"}
ADVERBS = ("a little more", "more", "much more")
SWEEP = (1.25, 1.5, 1.75, 2.0, 2.25, 2.5)
AEU_THRESHOLDS = {"aeu1": (130.0, 165.0), "aeu2": (160.0, 180.0)}
KINDS = ("fixed", "aeu1", "aeu2", "emu1", "emu1c", "emu2", "nb")


def table_adverb(alpha: float) -> str | None:
    """Table 4.1: 1.5 / 2.0 / 2.5 -> "a little more" / "more" / "much more"; other alphas take
    the nearest row; no emphasis, no adverb."""
    if alpha <= 0:
        return None
    return TABLE_4_1[min(TABLE_4_1, key=lambda a: abs(a - alpha))]


@dataclass
class Calibration:
    """Our distance (eq. 2.4 between HMMs of our features) -> the thesis's units: ``thesis =
    scale * ours``. Two fits:

    * :meth:`separating` (the default of ``reproduce``): the scale under which AEU-Model
      1's and 2's thresholds best separate the population's trials, the largest mean entropy of
      the two models' three-adverb splits of every trial's ``d_p`` (a calibration that makes a
      model say one adverb almost always tests nothing);
    * :meth:`fit`: the median first-trial ``d_p`` lands on 147.5, the centre of AEU-Model 1's
      middle band (130, 165] (later trials are closer, so they mostly fall under 130).
    """

    scale: float = 1.0
    reference: float = 147.5
    method: str = "first-trial median"

    @classmethod
    def fit(cls, first_trial_dp) -> Calibration:
        d = cls._positive(first_trial_dp)
        return cls(scale=float(147.5 / np.median(d)))

    @classmethod
    def separating(cls, trial_dp) -> Calibration:
        d = cls._positive(trial_dp)
        lo, hi = min(min(t) for t in AEU_THRESHOLDS.values()), max(max(t) for t in AEU_THRESHOLDS.values())
        scales = np.exp(np.linspace(np.log(lo / np.max(d)), np.log(hi / np.min(d)), 400))
        score = [np.mean([_entropy(cls(s).shares(d, k)) for k in AEU_THRESHOLDS]) for s in scales]
        best = float(scales[int(np.argmax(score))])
        return cls(scale=best, reference=float(best * np.median(d)), method="separating (largest mean entropy)")

    @staticmethod
    def _positive(d):
        d = np.asarray(d, float)
        if d.size == 0 or not np.all(np.isfinite(d)) or np.any(d <= 0):
            raise BadInput("calibration needs positive distances")
        return d

    def thesis_units(self, d_p: float) -> float:
        return self.scale * d_p

    def shares(self, d_p, kind: str = "aeu1") -> dict[str, float]:
        """The share of ``d_p`` values each adverb of AEU-Model ``kind`` would be said for."""
        t = self.scale * np.asarray(d_p, float)
        lo, hi = AEU_THRESHOLDS[kind]
        return {ADVERBS[0]: float(np.mean(t <= lo)), ADVERBS[1]: float(np.mean((t > lo) & (t <= hi))),
                ADVERBS[2]: float(np.mean(t > hi))}


def _entropy(shares: dict) -> float:
    p = np.array([v for v in shares.values() if v > 0])
    return float(-(p * np.log(p)).sum())


def best_alpha(final_error: dict) -> float:
    """EMU-Model 2 (fig. 5.8): the alpha of a sweep ``{alpha: final error}`` that ended lowest."""
    if not final_error:
        raise BadInput("EMU-Model 2 needs a sweep: {alpha: final error}")
    return float(min(final_error, key=final_error.__getitem__))


def fit_aeu(rows) -> dict:
    """AEU thresholds from human coaches (thesis 5.3.3, table 5.2, fitted instead of assumed):
    ``rows`` are coach-seat answers ``{"coach", "d_p", "adverb"}``. A coach is left out when
    their adverbs run backwards or carry no order: the Spearman correlation (scipy.stats) between
    the ``d_p`` they judged and the adverb's rank ("a little more" < "more" < "much more") is not
    above 0, or they said fewer than two different adverbs. The thresholds ``t1 <= t2`` (our
    units) are the cuts between the included answers' ``d_p`` that the most answers agree with
    ("a little more" for ``d_p <= t1``, "more" up to ``t2``, "much more" above; a cut halfway
    between two neighbouring answers)."""
    from scipy.stats import spearmanr

    rank = {a: i for i, a in enumerate(ADVERBS)}
    rows = [r for r in rows if r.get("adverb") in rank and np.isfinite(r.get("d_p", np.nan))]
    included, excluded = [], {}
    for coach in sorted({r["coach"] for r in rows}):
        mine = [r for r in rows if r["coach"] == coach]
        said = {r["adverb"] for r in mine}
        if len(said) < 2:
            excluded[coach] = f"said only {', '.join(sorted(said))}"
            continue
        rho = float(spearmanr([r["d_p"] for r in mine], [rank[r["adverb"]] for r in mine]).statistic)
        if not rho > 0:
            excluded[coach] = f"adverbs run backwards or carry no order (Spearman rho {rho:+.2f})"
            continue
        included.append(coach)
    use = [r for r in rows if r["coach"] in included]
    if len(use) < 3:
        raise BadInput("AEU thresholds need at least 3 answers from coaches whose adverbs rise with the error"
                       + (f" (left out: {'; '.join(f'{c}: {w}' for c, w in excluded.items())})" if excluded else ""))
    d = np.array([r["d_p"] for r in use], float)
    y = np.array([rank[r["adverb"]] for r in use])
    values = np.unique(d)
    cuts = np.concatenate([[values[0] - 1.0], (values[:-1] + values[1:]) / 2, [values[-1] + 1.0]])
    best = (-1, 0.0, 0.0)
    for i, t1 in enumerate(cuts):
        for t2 in cuts[i:]:
            agree = int(np.sum(np.where(d <= t1, 0, np.where(d <= t2, 1, 2)) == y))
            if agree > best[0]:
                best = (agree, float(t1), float(t2))
    return {"thresholds": [max(best[1], 0.0), max(best[2], 0.0)], "agreement": best[0] / len(use), "answers": len(use),
            "coaches": included, "excluded": excluded}


def fit_emu1(d_p, d_s) -> float:
    """EMU-Model 1: ``alpha = 1 + slope`` of the least-squares line ``d_s = a d_p + b`` (eq. 5.5)."""
    d_p, d_s = np.asarray(d_p, float), np.asarray(d_s, float)
    if d_p.size < 2 or d_p.shape != d_s.shape:
        raise BadInput("EMU-Model 1 needs at least two (d_p, d_s) pairs")
    slope, _ = np.polyfit(d_p, d_s, 1)
    return float(1.0 + slope)


def projection_distance(x_t, x_p, x_s) -> float:
    """``d_h`` (eq. 5.8): distance from ``x_t`` to the projection of ``x_s`` on the line
    through ``x_p`` and ``x_t``, on the far side from ``x_p`` when positive."""
    x_t, x_p, x_s = (np.asarray(v, float) for v in (x_t, x_p, x_s))
    u = x_t - x_p
    n = np.linalg.norm(u)
    if n == 0:
        raise BadInput("x_t and x_p coincide: no line to project on")
    return float(np.dot(x_s - x_t, u / n))


def fit_emu1_corrected(points) -> tuple[float, float]:
    """EMU-Model 1 corrected (eq. 5.9): regress ``d_h`` on ``d_p`` over demonstrations
    ``(x_t, x_p, x_s)``. Returns (alpha, alpha of the uncorrected model on the same data)."""
    dp, ds, dh = [], [], []
    for x_t, x_p, x_s in points:
        dp.append(float(np.linalg.norm(np.asarray(x_t) - np.asarray(x_p))))
        ds.append(float(np.linalg.norm(np.asarray(x_s) - np.asarray(x_t))))
        dh.append(projection_distance(x_t, x_p, x_s))
    return fit_emu1(dp, dh), fit_emu1(dp, ds)


def simulated_coach_demonstrations(n: int = 40, alpha: float = 1.8, off_line: float = 0.35, seed: int = 0, dim: int = 3):
    """Demonstrations of a **simulated** expert coach (the thesis observed a human one): for a
    learner at ``x_p``, the coach shows ``x_s = x_t + alpha (x_t - x_p)`` plus an error of
    relative size ``off_line`` perpendicular-ish to the line (coaches do not emphasise exactly
    along it). Returns a list of ``(x_t, x_p, x_s)``."""
    r = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        check_time()
        x_t = np.zeros(dim)
        x_p = r.normal(size=dim) * r.uniform(0.5, 2.0)
        d = np.linalg.norm(x_p)
        x_s = x_t + alpha * (x_t - x_p) + off_line * d * alpha * r.normal(size=dim) / np.sqrt(dim)
        out.append((x_t, x_p, x_s))
    return out


@dataclass
class Policy:
    """A coaching policy (see module docstring); ``to_dict``/``from_dict`` for the bus."""

    kind: str = "fixed"
    alpha: float = 2.0
    adverb: str | None = "table"  # fixed: None, "table" or a literal adverb
    calibration: float = 1.0  # aeu: thesis units per our unit
    per_learner: dict = field(default_factory=dict)  # emu2: learner -> alpha
    nb: dict | None = None  # nb: GaussianNB parameters
    thresholds: list | None = None  # aeu: (t1, t2) in our units fitted from human coaches (fit_aeu)
    body_part: bool = False  # emphasise the worst body part only
    subgoal: bool = False  # coach through intermediate proto-symbols, worst body part first (session.py)
    effort: bool = False  # ask the learner's felt effort and keep emphasis within its strength (effort.py, 6.5.1)

    def check(self) -> Policy:
        if self.kind not in KINDS:
            raise BadInput(f"policy kind must be one of {', '.join(KINDS)}, got {self.kind!r}", field="kind")
        if not (np.isfinite(self.alpha) and 0.0 <= self.alpha <= 5.0):
            raise BadInput(f"alpha must be in [0, 5], got {self.alpha}", field="alpha")
        if self.kind == "fixed" and self.adverb not in (None, "table", *ADVERBS, "more like this"):
            raise BadInput(f"adverb must be none, 'table' or one of {', '.join(ADVERBS)}, 'more like this'", field="adverb")
        if self.body_part and self.subgoal:
            raise BadInput("choose body_part or subgoal, not both", field="subgoal")
        if self.thresholds is not None and (len(self.thresholds) != 2 or not 0 <= self.thresholds[0] <= self.thresholds[1]):
            raise BadInput(f"AEU thresholds must be two increasing distances, got {self.thresholds}", field="thresholds")
        if self.kind == "nb" and not self.nb:
            raise BadInput("a naive Bayes policy needs a trained classifier (policy_fit)", field="nb")
        return self

    def choose(self, d_p: float, d_cop: float | None = None, learner: str | None = None) -> tuple[float, str | None]:
        k = self.kind
        if k == "fixed":
            adverb = table_adverb(self.alpha) if self.adverb == "table" else self.adverb
            return self.alpha, adverb
        if k in AEU_THRESHOLDS:
            lo, hi = AEU_THRESHOLDS[k] if self.thresholds is None else self.thresholds
            t = self.calibration * d_p if self.thresholds is None else d_p
            return self.alpha, ADVERBS[0] if t <= lo else ADVERBS[1] if t <= hi else ADVERBS[2]
        if k in ("emu1", "emu1c"):
            return self.alpha, table_adverb(self.alpha) if self.adverb == "table" else self.adverb
        if k == "emu2":
            a = float(self.per_learner.get(learner, self.alpha))
            return a, table_adverb(a) if self.adverb == "table" else self.adverb
        # nb
        if not self.nb:
            raise BadInput("a naive Bayes policy needs a trained classifier (policy_fit)", field="nb")
        return self.alpha, predict_nb(self.nb, d_p, d_cop if d_cop is not None else 0.0)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Policy:
        known = {k: v for k, v in d.items()
                 if k in cls.__dataclass_fields__ and (v is not None or k in ("adverb", "nb", "thresholds"))}
        return cls(**known).check()


def fit_nb(features, labels) -> dict:
    """Naive Bayes over ``(d_p, d_cop)`` (eq. 6.6, scikit-learn ``GaussianNB``): the parameters,
    so the policy travels as plain numbers."""
    from sklearn.naive_bayes import GaussianNB

    x = np.asarray(features, float)
    y = np.asarray(labels)
    if x.ndim != 2 or x.shape[1] != 2 or len(x) != len(y) or len(set(y)) < 2:
        raise BadInput("naive Bayes needs (d_p, d_cop) rows and at least two different adverbs as labels")
    m = GaussianNB().fit(x, y)
    return {"classes": [str(c) for c in m.classes_], "theta": m.theta_.tolist(), "var": m.var_.tolist(),
            "prior": m.class_prior_.tolist()}


def predict_nb(params: dict, d_p: float, d_cop: float) -> str:
    """``V_NB = argmax_V P(V) prod_i P(a_i | V)`` with Gaussian ``P(a_i | V)`` (eq. 6.6)."""
    theta, var, prior = (np.asarray(params[k], float) for k in ("theta", "var", "prior"))
    x = np.array([d_p, d_cop], float)
    ll = np.log(prior) - 0.5 * np.sum(np.log(2 * np.pi * var) + (x - theta) ** 2 / var, axis=1)
    return params["classes"][int(np.argmax(ll))]
