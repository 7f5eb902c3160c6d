"""The design of ``mirrorcoach reproduce ch4 ch5 ch6`` and the statistics it is read with: the
targets, the thesis's cases (Table 4.2) and numbers, the sensitivity sweeps, ``R_l`` (eq. 4.4),
Tukey's test (scipy.stats), the comparisons of two conditions, and the tidy rows of a run.
:mod:`shared.reproduce.coaching` runs the experiments, :mod:`shared.reproduce.coaching_report`
writes them up."""

from __future__ import annotations

import numpy as np
from scipy import stats

TARGETS = {"squat": "squat1Reps", "throw": "throwBasketball"}
THESIS = {
    "sweep": "alpha = 2.0 gave the lowest imitation error (fig. 4.7); on average 2.0 with and without adverb (fig. 5.7)",
    "cases_1_4": "significant differences between cases 1-3 and 1-4 only: emphasis helps, the adverb's effect unconfirmed (table 4.3)",
    "emu2": "the best alpha varies between subjects (A: 1.5 / 2.0, B: 2.5 / 2.25 without / with adverb, fig. 5.8)",
    "cases_5_6": "significant difference between case 2 and case 6 (EMU-Model 2 alpha with adverb) (table 6.2)",
    "cases_7_8": "cases 7 and 8 (alpha 2 with AEU-Model 1 / 2 adverbs) improved more than case 3, not significantly (table 6.5)",
}
CASES = {1: ("alpha 0, no adverb", {"kind": "fixed", "alpha": 0.0, "adverb": None}),
         2: ("alpha 0 + 'more like this'", {"kind": "fixed", "alpha": 0.0, "adverb": "more like this"}),
         3: ("alpha 2, no adverb", {"kind": "fixed", "alpha": 2.0, "adverb": None}),
         4: ("alpha 2 + adverb (Table 4.1)", {"kind": "fixed", "alpha": 2.0, "adverb": "table"})}


def r_l(d: np.ndarray) -> np.ndarray:
    """Per learner ``d_il / d_i1``; the mean over learners is eq. 4.5's ``R_l``."""
    return d / d[:, :1]


def tukey_table(groups: dict[str, np.ndarray]) -> dict:
    """One-way ANOVA and Tukey-Kramer (p < .05) laid out like the thesis: MSDs above the
    diagonal, |mean differences| below with * where they exceed the MSD."""
    names = list(groups)
    data = [np.asarray(groups[n], float) for n in names]
    anova = stats.f_oneway(*data)
    k = len(data)
    n_total = sum(len(x) for x in data)
    df = n_total - k
    mse = sum(((x - x.mean()) ** 2).sum() for x in data) / df
    q = stats.studentized_range.ppf(0.95, k, df)
    hsd = stats.tukey_hsd(*data)
    table = {}
    for i in range(k):
        for j in range(k):
            if i == j:
                continue
            msd = q * np.sqrt(mse / 2 * (1 / len(data[i]) + 1 / len(data[j])))
            diff = abs(data[i].mean() - data[j].mean())
            table[(i, j)] = {"msd": float(msd), "diff": float(diff), "significant": bool(diff > msd),
                             "p": float(hsd.pvalue[i, j])}
    return {"names": names, "means": [float(x.mean()) for x in data], "anova_F": float(anova.statistic),
            "anova_p": float(anova.pvalue), "pairs": table}


def tukey_markdown(t: dict) -> list[str]:
    names = t["names"]
    head = "| | " + " | ".join(names) + " |"
    lines = [head, "|" + "---|" * (len(names) + 1)]
    for i, a in enumerate(names):
        cells = []
        for j in range(len(names)):
            if i == j:
                cells.append("-")
            elif j > i:
                cells.append(f"{t['pairs'][(i, j)]['msd']:.3f}")
            else:
                p = t["pairs"][(i, j)]
                cells.append(f"{p['diff']:.3f}{'*' if p['significant'] else ''}")
        lines.append(f"| **{a}** | " + " | ".join(cells) + " |")
    lines += ["", "Means of R_4: " + ", ".join(f"{n} {m:.3f}" for n, m in zip(names, t["means"])) +
              f". One-way ANOVA: F = {t['anova_F']:.2f}, p = {t['anova_p']:.3g}. MSDs upper right, |differences| lower "
              "left, * where a difference exceeds its MSD (Tukey-Kramer, p < .05; scipy.stats.tukey_hsd agrees: "
              + ", ".join(f"{names[i]}-{names[j]} p = {v['p']:.3f}" for (i, j), v in t["pairs"].items() if i < j) + ")."]
    return lines


def compare(better: np.ndarray, worse: np.ndarray) -> dict:
    """Did ``better`` (R_4 per learner) come out lower than ``worse``, and is it significant?
    A paired t-test when both are the same learners (scipy.stats), Welch's otherwise."""
    b, w = np.asarray(better, float), np.asarray(worse, float)
    test = stats.ttest_rel(b, w) if len(b) == len(w) else stats.ttest_ind(b, w, equal_var=False)
    p = float(test.pvalue) if np.isfinite(test.pvalue) else 1.0
    diff = float(b.mean() - w.mean())
    word = ("holds" if diff < 0 and p < 0.05 else "reversed" if diff > 0 and p < 0.05 else
            "lower, not significant" if diff < 0 else "not lower")
    return {"diff": diff, "p": p, "word": word}


SENSITIVITY = {"thesis": {"gain": (0.15, 0.3, 0.6), "threshold": (0.0, 3.0, 6.0), "overshoot": (0.0, 0.3, 0.9)},
               "error_based": {"retention": (0.7, 0.9, 1.0), "gain": (0.15, 0.3, 0.6), "threshold": (0.0, 3.0, 6.0)},
               # its rates are the published ones (not varied): what the learner perceives and does is
               "two_rate": {"threshold": (0.0, 3.0, 6.0), "noise": (0.3, 1.0, 3.0)},
               "copy": {"noise": (0.3, 1.0, 3.0)},
               # it has no threshold (its step is blind to the difference's size): its step and its noise
               "fixed_step": {"step": (2.0, 4.0, 8.0), "noise": (0.3, 1.0, 3.0)}}
SENSITIVITY_ALPHAS = (0.0, 1.0, 2.0, 3.0)
NB_TRAIN_SEED = 1
#: the felt-effort experiment's learners: strength U(STRENGTH) x the target's effort, seeded per learner
STRENGTH, STRENGTH_SEED = (1.2, 2.5), 651


def tidy_rows(results: dict) -> list[dict]:
    """Every coaching trial of ``results`` as :mod:`shared.reproduce.tidy` rows."""
    rows = []
    for family, per_target in results["families"].items():
        for key, res in per_target.items():
            groups = {f"case {c}": d for c, d in res["cases"].items()}
            groups.update({"nb": res["nb"]["d"], "body part": res["body_part"]["d"], "sub-goal": res["subgoal"]["d"],
                           "checked": res["feasibility"]["d"]})
            groups.update({f"sweep {k}": d for k, d in res["sweep"].items()})
            groups.update({f"effort {w}": (res.get("effort") or {}).get(w) for w in ("without", "with")})
            for cond, d in groups.items():
                if d is None:
                    continue
                adverbs = res.get("adverbs", {}).get(str(cond.split()[-1])) if cond.startswith("case") else None
                for i, row in enumerate(d):
                    for t, v in enumerate(row):
                        adv = adverbs[i * (len(row) - 1) + t - 1] if adverbs and t > 0 else None
                        rows.append({"world": "simulated", "family": family, "target": key, "condition": cond,
                                     "unit": f"learner {i}", "trial": t + 1, "d_p": v, "alpha": None, "adverb": adv})
    return rows


def r4_of(d) -> np.ndarray:
    return r_l(np.asarray(d, float))[:, -1]


def int_keys(results: dict) -> dict:
    for per_target in results["families"].values():
        for res in per_target.values():
            res["cases"] = {int(c): d for c, d in res["cases"].items()}
    return results
