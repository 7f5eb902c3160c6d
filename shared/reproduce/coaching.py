"""``mirrorcoach reproduce ch4 ch5 ch6``: the coaching experiments of chapters 4-6, rerun on the
cluster with a seeded population of **simulated learners** (not people) and real HDM05 targets
(a squat and the basketball throw, standing in for the thesis's tennis swing and medicine-ball
throw). Every session runs through the coach service (pss for spaces and generation, the
simulator for learners and feasibility).

Every experiment runs once per learner family (``shared/agents/learner.py``, issue 14): the
alpha sweep with and without adverbs (fig. 4.7, 5.7, 6.5), cases 1-4 (table 4.2, fig. 4.8/4.9,
table 4.3), EMU-Model 2 per learner (fig. 5.8) and cases 5, 6 as new sessions with fresh noise
(table 6.2, fig. 6.1, 6.2), cases 7 and 8 with AEU-Model 1 and 2 calibrated to separate the
population's trials (table 6.5, fig. 6.6, 6.7), the naive Bayes adverb trained on another
population (6.5), the feasibility check, and whole-body against body-part against sub-goal
emphasis; then a sensitivity sweep over each family's parameters. Every trial goes to
``tidy.csv`` (:mod:`shared.reproduce.tidy`) and every word of the report is computed.
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

from schemas.common import clip_to_wire
from shared.bus.client import RemoteError
from shared.coaching.policies import ADVERBS, SWEEP
from shared.reproduce.tidy import matrix, write

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


def target_clip(hdm05: Path, label: str):
    from shared.io import find_clips, load_clip

    files = [f for f in find_clips([hdm05 / "amc" / label]) if "_bd_" in f.name]
    if not files:
        raise FileNotFoundError(f"no HDM05 clip of {label} by actor bd under {hdm05}")
    return load_clip(files[0])


class Experiment:
    def __init__(self, client, target, name: str, learners: int, seed: int = 0, trials: int = 4, workers: int = 4,
                 echo=print, family: str = "thesis"):
        self.c, self.target, self.name = client, target, name
        self.learners, self.seed, self.trials, self.workers, self.echo = learners, seed, trials, workers, echo
        self.family = family
        self.wire = clip_to_wire(target)
        self.count = 0

    def session(self, tag: str, i: int, policy: dict, check: bool = False, seed: int | None = None, replicate: int = 0,
                params: dict | None = None) -> dict:
        name = f"{self.name}-{tag}-{i}"
        self.c.request("coach", "start", {"session": name, "target": self.wire, "learner": f"{name}-l", "index": i,
                                          "population_seed": self.seed if seed is None else seed, "policy": policy,
                                          "check": check, "family": self.family, "replicate": replicate,
                                          **({"learner_params": params} if params else {}), "replace": True},
                       timeout=300)
        info = self.c.request("coach", "run", {"session": name, "trials": self.trials}, timeout=600)
        self.count += self.trials
        return info

    def group(self, tag: str, policy_of, check: bool = False, params_of=None, **kw) -> list[dict]:
        """One session per learner of the population (``policy_of(i)`` -> policy; ``params_of(i)``
        -> parameters set on learner ``i``, see ``learner_params``)."""
        with ThreadPoolExecutor(self.workers) as pool:
            return list(pool.map(lambda i: self.session(tag, i, policy_of(i), check,
                                                        **({"params": params_of(i)} if params_of else {}), **kw),
                                 range(self.learners)))

    @staticmethod
    def d(infos: list[dict]) -> np.ndarray:
        return np.array([[t["d_p"] for t in info["trials"]] for info in infos])


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


def run_target(client, target, key: str, learners: int, echo=print, family: str = "thesis") -> dict:
    ex = Experiment(client, target, f"{family}-{key}".replace("_", ""), learners, echo=echo, family=family)
    res: dict = {"learners": learners, "target": target.name, "family": family}
    # ---- alpha sweep with and without adverb (fig. 4.7, 5.7, 6.5; EMU-Model 2's data)
    sweep = {}
    for adverb in (None, "table"):
        for a in (0.0,) + SWEEP:
            tag = f"sw{a:g}{'a' if adverb else ''}".replace(".", "_")
            sweep[(a, adverb)] = Experiment.d(ex.group(tag, lambda i, a=a, adverb=adverb: {"kind": "fixed", "alpha": a,
                                                                                          "adverb": adverb}))
    res["sweep"] = {f"{a:g}|{adv or 'none'}": d.tolist() for (a, adv), d in sweep.items()}
    echo(f"  {family} {key}: alpha sweep done ({ex.count} trials so far)")
    # ---- cases 1-4
    cases = {c: ex.group(f"case{c}", lambda i, p=p: p) for c, (_, p) in CASES.items()}
    # ---- EMU-Model 2: per-learner alpha from the sweep, then new sessions with fresh motor noise
    # (replicate 1): cases 5 and 6 are measured out of sample, not replayed from the sweep
    for c, adverb in ((5, None), (6, "table")):
        names = [f"{ex.name}-case{c}-{i}-l" for i in range(learners)]
        fit = client.request("coach", "policy_fit", {"kind": "emu2", "sweep": {
            k: {str(a): float(r_l(sweep[(a, adverb)])[i, -1]) for a in SWEEP} for i, k in enumerate(names)}})["policy"]
        fit["adverb"] = adverb
        res[f"emu2_{c}"] = [fit["per_learner"][k] for k in names]
        cases[c] = ex.group(f"case{c}", lambda i, p=fit: p, replicate=1)
    res["emu2"] = {"without": res.pop("emu2_5"), "with": res.pop("emu2_6")}
    # ---- cases 7, 8: alpha 2 with AEU-Model 1 / 2 adverbs, calibrated to separate the sweep's trials
    every = np.concatenate([d.ravel() for d in sweep.values()]).tolist()
    for c, kind in ((7, "aeu1"), (8, "aeu2")):
        pol = client.request("coach", "policy_fit", {"kind": kind, "trial_dp": every, "alpha": 2.0})
        res[f"calibration_{kind}"] = pol["fit"]
        cases[c] = ex.group(f"case{c}", lambda i, p=pol["policy"]: p)
    res["cases"] = {c: Experiment.d(v).tolist() for c, v in cases.items()}
    res["adverbs"] = {c: [t["adverb"] for s in v for t in s["trials"][1:]] for c, v in cases.items()}
    echo(f"  {family} {key}: cases 1-8 done ({ex.count} trials so far)")
    # ---- naive Bayes adverb (6.5): trained on another population (seed 1), tested on this one
    logs = {adv: ex.group(f"nb-{adv.replace(' ', '_')}", lambda i, adv=adv: {"kind": "fixed", "alpha": 2.0, "adverb": adv},
                          seed=NB_TRAIN_SEED) for adv in ADVERBS}
    feats, labels = [], []
    for i in range(learners):
        for t in range(ex.trials - 1):
            gains = {adv: logs[adv][i]["trials"][t]["d_p"] - logs[adv][i]["trials"][t + 1]["d_p"] for adv in ADVERBS}
            row = logs[ADVERBS[1]][i]["trials"][t]
            feats.append([row["d_p"], row.get("d_cop") or 0.0])
            labels.append(max(gains, key=gains.get))
    try:
        nb = client.request("coach", "policy_fit", {"kind": "nb", "features": feats, "labels": labels, "alpha": 2.0})
        nb_d = Experiment.d(ex.group("nb", lambda i: nb["policy"]))
        res["nb"] = {"labels": labels, "features": feats, "classes": nb["fit"]["classes"], "d": nb_d.tolist()}
    except RemoteError as e:  # one adverb best everywhere: nothing to classify (computed, reported)
        res["nb"] = {"labels": labels, "features": feats, "classes": sorted(set(labels)), "d": None, "why": e.message}
    # ---- EMU-Model 1 and its correction: a recovery check of the estimator on a simulated coach
    res["emu1"] = client.request("coach", "policy_fit", {"kind": "emu1c", "simulated_coach": {"n": 60, "alpha": 1.8,
                                                                                              "off_line": 0.35, "seed": 1}})["fit"]
    # ---- feasibility check on (the product's default) against off, alpha 2 + adverb
    checked = ex.group("checked", lambda i: CASES[4][1], check=True)
    res["feasibility"] = {"d": Experiment.d(checked).tolist(),
                          "lowered": sum(t["alpha_reduced"] for s in checked for t in s["trials"]),
                          "trials": sum(len(s["trials"]) for s in checked),
                          "alpha_shown": [t["alpha_shown"] for s in checked for t in s["trials"]]}
    # ---- body-part and sub-goal emphasis against whole-body (case 3)
    part = ex.group("part", lambda i: {**CASES[3][1], "body_part": True})
    res["body_part"] = {"d": Experiment.d(part).tolist(), "parts": [t["part"] for s in part for t in s["trials"]]}
    sub = ex.group("subgoal", lambda i: {**CASES[3][1], "subgoal": True})
    res["subgoal"] = {"d": Experiment.d(sub).tolist(), "goals": [[t["goal"] for t in s["trials"]] for s in sub]}
    # ---- the estimator in the loop (6.5.1): learners of limited strength, alpha 2 + adverb, the coach asking
    # their felt effort or not (the same learners, the same motor noise)
    strength = [learner_strength(i) for i in range(learners)]
    groups = {w: ex.group(f"effort{w}", lambda i, w=w: {**CASES[4][1], "effort": w == "with"},
                          params_of=lambda i: {"strength": strength[i]}) for w in ("without", "with")}
    asked = [t for s in groups["with"] for t in s["trials"]]
    res["effort"] = {"strength": strength, **{w: Experiment.d(g).tolist() for w, g in groups.items()},
                     "lowered": sum(t["alpha_reduced"] for t in asked), "trials": len(asked),
                     "alpha_shown": [t["alpha_shown"] for t in asked],
                     "felt": [[t.get("felt") for t in s["trials"]] for s in groups["with"]],
                     "predicted": [[t.get("felt_predicted") for t in s["trials"]] for s in groups["with"]]}
    res["trials_run"] = ex.count
    echo(f"  {family} {key}: done, {ex.count} coaching trials")
    return res


#: the sensitivity sweep: per family, each parameter at three values (the others as drawn)
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


def learner_strength(i: int) -> float:
    """Learner ``i``'s strength in the felt-effort experiment (6.5.1), the same in every family."""
    return round(float(np.random.default_rng([STRENGTH_SEED, i]).uniform(*STRENGTH)), 4)


def sensitivity(client, target, key: str, learners: int, family: str, echo=print) -> dict:
    """R_4 at alpha 0, 1, 2 and 3 (no adverb) with each of the family's parameters set in turn
    to three values: where does emphasis help, and which alpha is best?"""
    ex = Experiment(client, target, f"sens-{family}-{key}".replace("_", ""), learners, echo=echo, family=family)
    out = {}
    for param, values in SENSITIVITY[family].items():
        for v in values:
            out[f"{param}={v:g}"] = {f"{a:g}": _r4(Experiment.d(ex.group(
                f"{param[:4]}{v:g}-a{a:g}".replace(".", "_"), lambda i, a=a: {"kind": "fixed", "alpha": a, "adverb": None},
                params={param: v}))).tolist() for a in SENSITIVITY_ALPHAS}
    echo(f"  sensitivity {family}: {ex.count} coaching trials")
    return out


# ---------------------------------------------------------------------------- tidy rows
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


# ---------------------------------------------------------------------------- report
def _fig(path: Path, title: str, xlabel: str, ylabel: str, series: dict, xticks=None, bars: bool = False) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for k, (label, (xs, ys, err, style)) in enumerate(series.items()):
        if bars:
            ax.bar([label], ys, yerr=err, capsize=4, color=f"C{k}")
        else:
            ax.errorbar(xs, ys, yerr=err, fmt=style, label=label, capsize=3, markersize=4)
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if xticks is not None and not bars:
        ax.set_xticks(xticks)
    ax.grid(alpha=0.3)
    if not bars:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def _r4(d) -> np.ndarray:
    return r_l(np.asarray(d, float))[:, -1]


def _se(x) -> float:
    x = np.asarray(x, float)
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else 0.0


CASE_NAMES = {**{c: n for c, (n, _) in CASES.items()}, 5: "EMU-Model 2 alpha, no adverb (out of sample)",
              6: "EMU-Model 2 alpha + Table 4.1 adverb (out of sample)", 7: "alpha 2 + AEU-Model 1 adverb",
              8: "alpha 2 + AEU-Model 2 adverb"}
#: the case sets of the thesis's tables, and ours beside them
TABLES = {"Table 4.3": ((1, 2, 3, 4), None), "Table 6.2": ((1, 2, 5, 6), (1, 2, 3, 5, 6)),
          "Table 6.5": ((3, 7, 8), (3, 4, 7, 8))}


def case_tables(rows: list[dict], **where) -> list[str]:
    """The thesis's Tukey-Kramer tables from tidy rows (simulated or people), each on the
    thesis's case set and, where ours differs, ours beside it; a table needs every case and at
    least two units per case."""
    have = {c: matrix(rows, f"case {c}", **where) for c in range(1, 9)}
    lines = []
    for title, sets in TABLES.items():
        for which, cases in zip(("thesis's cases", "ours"), sets):
            if cases is None:
                continue
            if not all(have[c].shape[0] >= 2 for c in cases):
                lines += [f"{title} ({which}: cases {', '.join(map(str, cases))}): not enough units in every case.", ""]
                continue
            t = tukey_table({f"case {c}": _r4(have[c]) for c in cases})
            lines += [f"**{title}**, {which} (cases {', '.join(map(str, cases))}):", "", *tukey_markdown(t), ""]
    return lines


FINDINGS = {
    "emphasis": ("Emphasis (case 3, alpha 2) ends lower than the target alone (case 1)", 3, 1),
    "adverb": ("The adverb (case 4) ends lower than emphasis alone (case 3)", 4, 3),
    "emu2": ("EMU-Model 2 with adverb (case 6) ends lower than 'more like this' (case 2), table 6.2", 6, 2),
    "aeu1": ("AEU-Model 1 adverbs (case 7) end lower than none (case 3), table 6.5", 7, 3),
    "aeu2": ("AEU-Model 2 adverbs (case 8) end lower than none (case 3), table 6.5", 8, 3),
    "subgoal": ("Sub-goal coaching ends lower than whole-body emphasis (case 3)", "sub-goal", 3),
    "part": ("Body-part emphasis ends lower than whole-body emphasis (case 3)", "body part", 3),
    "nb": ("The naive Bayes adverb (trained on another population) ends lower than the best fixed case", "nb", "best"),
    "effort": ("Asking the learner's felt effort (6.5.1) ends lower than not asking, learners of limited strength",
               "effort", "not asking"),
}


def _finding(res: dict, key: str) -> dict | None:
    _, a, b = FINDINGS[key]
    cases = {int(c): _r4(d) for c, d in res["cases"].items()}
    effort = res.get("effort") or {}  # absent from runs before the experiment existed
    other = {"sub-goal": res["subgoal"]["d"], "body part": res["body_part"]["d"], "nb": res["nb"]["d"],
             "effort": effort.get("with"), "not asking": effort.get("without")}

    def r4(k):
        return cases[k] if isinstance(k, int) else (None if other[k] is None else _r4(other[k]))

    x = r4(a)
    if x is None:
        return None
    if b == "best":
        best = min(cases, key=lambda c: cases[c].mean())
        out = compare(x, cases[best])
        out["against"] = f"case {best}"
        return out
    y = r4(b)
    return None if y is None else compare(x, y)


def holm(pvalues) -> np.ndarray:
    """Holm's step-down adjustment of ``pvalues`` (one family of comparisons)."""
    p = np.asarray(pvalues, float)
    order = np.argsort(p)
    adj = np.minimum(1.0, (len(p) - np.arange(len(p))) * p[order])
    out = np.empty_like(p)
    out[order] = np.maximum.accumulate(adj)
    return out


def against_target(res: dict) -> list[dict]:
    """Every coaching condition of one family and target against the target alone (case 1,
    the same learners): its R_4 difference, paired p and Holm's p over the conditions; the word
    is computed from Holm's p as :func:`compare`'s is (**holds**: lower, adjusted p < .05)."""
    base = _r4(res["cases"][1])
    groups = {f"case {c}: {CASE_NAMES[int(c)]}": d for c, d in res["cases"].items() if int(c) != 1}
    groups.update({f"alpha {k.split('|')[0]}{'' if k.endswith('none') else ' + adverb'}": d
                   for k, d in res["sweep"].items() if k != "0|none"})
    groups.update({"sub-goal": res["subgoal"]["d"], "body part": res["body_part"]["d"], "naive Bayes": res["nb"]["d"],
                   "alpha 2 + adverb, feasibility checked": res["feasibility"]["d"]})
    rows = [{"condition": name, **compare(_r4(d), base)} for name, d in groups.items() if d is not None]
    for row, p in zip(rows, holm([r["p"] for r in rows])):
        row["p_holm"] = float(p)
        row["word"] = ("holds" if row["diff"] < 0 and p < 0.05 else "reversed" if row["diff"] > 0 and p < 0.05 else
                       "lower, not significant" if row["diff"] < 0 else "not lower")
    return rows


def null_sentence(family: str, per_target: dict) -> str:
    """What the numbers say of one family against the target alone, on every target (computed)."""
    parts = []
    for key, res in per_target.items():
        rows = against_target(res)
        beat = [r for r in rows if r["word"] == "holds"]
        lowest = min(rows, key=lambda r: r["p_holm"] if r["diff"] < 0 else np.inf)
        if beat:
            parts.append(f"on {key}, {len(beat)} of {len(rows)} conditions ended lower than the target alone ("
                         + ", ".join(f"{r['condition']} {r['diff']:+.3f}, Holm p = {r['p_holm']:.3f}" for r in beat[:3])
                         + (", ..." if len(beat) > 3 else "") + ")")
        else:
            parts.append(f"on {key}, none of {len(rows)} conditions ended lower than the target alone (smallest Holm p "
                         f"of a lower one: {lowest['p_holm']:.3f})" if lowest["diff"] < 0 else
                         f"on {key}, none of {len(rows)} conditions ended lower than the target alone (none was lower)")
    return f"`{family}`: " + "; ".join(parts) + "."


def _best_alpha(res: dict, adverb: str = "none") -> float:
    xs = [0.0, *SWEEP]
    return xs[int(np.argmin([_r4(res["sweep"][f"{a:g}|{adverb}"]).mean() for a in xs]))]


def _section(out: Path, family: str, key: str, res: dict) -> list[str]:
    n = res["learners"]
    tag = f"{family}_{key}"
    lines = [f"### {family} learners, {key} ({res['target']}): {n} learners, {res['trials_run']} coaching trials", ""]
    xs = [0.0, *SWEEP]
    series = {}
    for adv, style in (("none", "o-"), ("table", "s--")):
        r4 = [_r4(res["sweep"][f"{a:g}|{adv}"]) for a in xs]
        series[f"{'with' if adv == 'table' else 'without'} adverb"] = (xs, [x.mean() for x in r4], [_se(x) for x in r4], style)
    name = _fig(out / f"{tag}_fig4_7_5_7.png", f"{family}, {key}: R_4 against alpha (fig. 4.7, 5.7)", "alpha",
                "R_4 (mean, s.e.)", series, xs)
    norm = []  # fig. 6.5: d_4 per alpha, each learner's largest scaled to 200
    for a in xs:
        norm.append(np.array([np.asarray(res["sweep"][f"{a:g}|none"], float)[:, -1]]).ravel())
    norm = np.array(norm)
    norm = 200.0 * norm / norm.max(axis=0, keepdims=True)
    fig65 = _fig(out / f"{tag}_fig6_5.png", f"{family}, {key}: d_4 against alpha (fig. 6.5)", "alpha",
                 "d_4, each learner's largest = 200", {"without adverb": (xs, norm.mean(axis=1),
                                                                         [_se(r) for r in norm], "o-")}, xs)
    lines += [f"![sweep]({name}) ![fig. 6.5]({fig65})", "",
              f"Lowest mean R_4 at alpha = {_best_alpha(res):g} without adverb and {_best_alpha(res, 'table'):g} with "
              f"(thesis: {THESIS['sweep']}).", ""]
    cases = {int(c): np.asarray(d, float) for c, d in res["cases"].items()}
    for fig, cs, title in (("fig4_8", (1, 2, 3, 4), "cases 1-4 (fig. 4.8, 4.9)"), ("fig6_1", (1, 2, 5, 6),
                                                                                     "cases 1, 2, 5, 6 (fig. 6.1)"),
                           ("fig6_6", (3, 7, 8), "cases 3, 7, 8 (fig. 6.6)")):
        series = {f"case {c}: {CASE_NAMES[c]}": (list(range(1, cases[c].shape[1] + 1)), r_l(cases[c]).mean(axis=0),
                                                 [_se(v) for v in r_l(cases[c]).T], "o-") for c in cs}
        name = _fig(out / f"{tag}_{fig}.png", f"{family}, {key}: R_l over trials, {title}", "trial", "R_l (mean, s.e.)",
                    series, list(range(1, 5)))
        lines.append(f"![{fig}]({name})")
    for fig, cs, title in (("fig6_2", (1, 2, 5, 6), "fig. 6.2"), ("fig6_7", (3, 7, 8), "fig. 6.7")):
        series = {f"case {c}": ([0], _r4(cases[c]).mean(), _se(_r4(cases[c])), "") for c in cs}
        name = _fig(out / f"{tag}_{fig}.png", f"{family}, {key}: R_4 per case ({title})", "", "R_4 (mean, s.e.)",
                    series, bars=True)
        lines.append(f"![{fig}]({name})")
    lines.append("")
    rows = tidy_rows({"families": {family: {key: res}}})
    lines += case_tables(rows, family=family, target=key)
    emu = res["emu2"]
    name = _fig(out / f"{tag}_fig5_8.png", f"{family}, {key}: EMU-Model 2's alpha per learner (fig. 5.8)", "learner",
                "best alpha of the sweep", {"without adverb": (list(range(n)), emu["without"], None, "o"),
                                            "with adverb": (list(range(n)), emu["with"], None, "s")}, list(range(n)))
    lines += [f"![EMU-2]({name})", "", f"EMU-Model 2's alphas, picked from each learner's sweep, without adverb: "
              f"{emu['without']}; with: {emu['with']} ({len(set(emu['without']))} and {len(set(emu['with']))} different "
              "values). Cases 5 and 6 then ran as new sessions with fresh motor noise.", ""]
    for c, kind in ((7, "aeu1"), (8, "aeu2")):
        said = res["adverbs"][str(c)] if str(c) in res["adverbs"] else res["adverbs"][c]
        cal = res[f"calibration_{kind}"]
        lines.append(f"Case {c} ({kind.upper()}, scale {cal['scale']:.3f} thesis units per ours, {cal['method']}): said "
                     + ", ".join(f"'{a}' {said.count(a)}" for a in ADVERBS) + f" of {len(said)} times.")
    lines.append("")
    nb = res["nb"]
    if nb["d"] is None:
        lines += [f"Naive Bayes: not trained ({nb['why']}).", ""]
    else:
        f = _finding(res, "nb")
        lines += [f"Naive Bayes, trained on {len(nb['labels'])} states of population {NB_TRAIN_SEED} (labels: "
                  + ", ".join(f"{a} {nb['labels'].count(a)}" for a in ADVERBS) + f"), tested on this one: R_4 "
                  f"{_r4(nb['d']).mean():.3f}; the best fixed case, {f['against']}, "
                  f"{_r4(cases[int(f['against'].split()[-1])]).mean():.3f}; difference {f['diff']:+.3f} (p = {f['p']:.3f}, "
                  f"{f['word']}). Every case: " + ", ".join(f"{c} {_r4(cases[c]).mean():.3f}" for c in sorted(cases))
                  + ".", ""]
    fz = res["feasibility"]
    lines += [f"Feasibility check (alpha 2 + adverb): alpha lowered in {fz['lowered']} of {fz['trials']} trials; R_4 "
              f"{_r4(fz['d']).mean():.3f} with the check, {_r4(cases[4]).mean():.3f} without.", ""]
    if res.get("effort"):
        ef, f = res["effort"], _finding(res, "effort")
        lo, hi = min(ef["strength"]), max(ef["strength"])
        lines += [f"The estimator in the loop (6.5.1): learners whose bodies give {lo:.2f}-{hi:.2f} times the target's "
                  "effort, alpha 2 + adverb; the coach asks each learner how heavy the last demonstration felt "
                  f"(chapter 3's interval estimator) and lowers alpha where it predicts more than the learner's strength "
                  f"(in {ef['lowered']} of {ef['trials']} trials). R_4 {_r4(ef['with']).mean():.3f} asking, "
                  f"{_r4(ef['without']).mean():.3f} not asking: {_cell(f)}.", ""]
    parts = res["body_part"]["parts"]
    goals = res["subgoal"]["goals"]
    n_goals = [len(set(g)) for g in goals]
    t = tukey_table({"whole body (case 3)": _r4(cases[3]), "body part": _r4(res["body_part"]["d"]),
                     "sub-goals": _r4(res["subgoal"]["d"])})
    lines += ["Whole-body, body-part and sub-goal emphasis (alpha 2, no adverb). Parts emphasised: "
              + ", ".join(f"{p} {parts.count(p)}" for p in ("arms", "legs", "trunk")) + f"; goals per sub-goal session: "
              f"{min(n_goals)}-{max(n_goals)}.", "", *tukey_markdown(t), ""]
    return lines


def _cell(f: dict | None) -> str:
    return "-" if f is None else f"{f['word']} ({f['diff']:+.3f}, p = {f['p']:.3f})"


def write_report(out: Path, results: dict, seconds: float) -> Path:
    fams = list(results["families"])
    keys = list(next(iter(results["families"].values())))
    lines = ["# Chapters 4-6 reproduced in several learner worlds", "",
             f"**The learners are simulated**, in {len(fams)} famil{'y' if len(fams) == 1 else 'ies'} "
             "(`shared/agents/learner.py`): "
             + ", ".join(f"`{f}`" for f in fams) + ". By construction: `thesis` was built so that emphasis can "
             "help; `error_based` and `two_rate` are state-space models from the motor-learning literature (the second "
             "with Smith et al. 2006's published parameters) that never know the target; `copy` and `fixed_step` are "
             "built as null worlds, where no demonstration can bring a learner closer than the target itself. Whether "
             "the numbers agree is computed below (\"Against the target alone\"). Real HDM05 targets (actor bd) stand in for the thesis's tasks; every session ran through the coach "
             f"service. Generated by `mirrorcoach reproduce ch4 ch5 ch6` in {seconds:.0f} s.", "",
             "Metric: `d_il`, the HMM distance (eq. 2.4) between the target and the attempt's 5 repetitions (eq. 4.4); "
             "`R_l = mean_i d_il / d_i1` (eq. 4.5); 4 trials, the first showing the target. Each finding is a paired "
             "t-test (scipy.stats) on the same learners' R_4; its word is computed: **holds** (lower, p < .05), "
             "**lower, not significant**, **not lower**, **reversed** (higher, p < .05). Every trial is in `tidy.csv`, "
             "the table `mirrorcoach study export` writes for people.", "",
             "## Which findings hold in which learner world", "",
             "| finding | " + " | ".join(f"{f}, {k}" for f in fams for k in keys) + " |",
             "|---|" + "---|" * (len(fams) * len(keys))]
    for key, (text, _, _) in FINDINGS.items():
        lines.append(f"| {text} | " + " | ".join(_cell(_finding(results["families"][f][k], key)) for f in fams for k in keys)
                     + " |")
    lines.append("| Best alpha of the sweep, no adverb (thesis 2.0) | "
                 + " | ".join(f"{_best_alpha(results['families'][f][k]):g}" for f in fams for k in keys) + " |")
    lines.append("")
    holds = {f: [k for k in FINDINGS if all((_finding(results["families"][f][t], k) or {}).get("word") == "holds"
                                             for t in keys)] for f in fams}
    lines += ["Findings that hold on every target, per family:", ""]
    lines += [f"- `{f}`: " + ("; ".join(FINDINGS[k][0] for k in v) if v else "none") for f, v in holds.items()]
    lines += ["", "## Against the target alone", "",
              "Every coaching condition (cases 2-8, each alpha of the sweep with and without adverb, sub-goal, body "
              "part, naive Bayes, the feasibility check) against case 1, the target shown every trial, on the same "
              "learners: paired t-tests on R_4 with Holm's adjustment over the conditions of one family and target. "
              "In a null world none should hold.", ""]
    lines += [f"- {null_sentence(f, results['families'][f])}" for f in fams]
    lines.append("")
    sens = results.get("sensitivity") or {}
    if sens:
        lines += ["## Sensitivity: each family's parameters, one at a time", "",
                  f"R_4 (mean over {results.get('sensitivity_learners', '?')} learners, target "
                  f"{results.get('sensitivity_target', '?')}) at alpha " + ", ".join(f"{a:g}" for a in SENSITIVITY_ALPHAS)
                  + "; the other parameters as drawn.", "",
                  "| family | parameter | " + " | ".join(f"alpha {a:g}" for a in SENSITIVITY_ALPHAS)
                  + " | best alpha | alpha 2 against 0 |", "|---|---|" + "---|" * (len(SENSITIVITY_ALPHAS) + 2)]
        for fam, table in sens.items():
            for setting, by_alpha in table.items():
                means = [np.mean(by_alpha[f"{a:g}"]) for a in SENSITIVITY_ALPHAS]
                f = compare(by_alpha["2"], by_alpha["0"])
                lines.append(f"| {fam} | {setting} | " + " | ".join(f"{m:.3f}" for m in means)
                             + f" | {SENSITIVITY_ALPHAS[int(np.argmin(means))]:g} | {_cell(f)} |")
        lines.append("")
    if results.get("nb_transfer"):
        lines += nb_transfer_lines(results)
    e1 = next(iter(next(iter(results["families"].values())).values()))["emu1"]
    err_c, err_u = abs(e1["alpha_eq5_5_corrected"] - 2.8), abs(e1["alpha_eq5_5_uncorrected"] - 2.8)
    lines += ["## EMU-Model 1 and its correction (eq. 5.5, 5.9): a recovery check", "",
              f"From {e1['n']} demonstrations of a **simulated** coach (eq. 4.3 with alpha 1.8 plus an error off the "
              f"x_p-x_t line), eq. 5.5 gives {e1['alpha_eq5_5_uncorrected']:.2f} and the corrected eq. 5.9 "
              f"{e1['alpha_eq5_5_corrected']:.2f}, against 2.8 (eq. 5.3's alpha is 1 + eq. 4.3's): the correction is "
              f"{'closer' if err_c < err_u else 'not closer'} ({err_c:.2f} against {err_u:.2f} off). The coach is the "
              "model being fitted, so this checks the estimator, not the thesis's claim; EMU-Model 1 from people comes "
              "from `mirrorcoach study seat` demonstrations.", ""]
    lines += ["## Per family and target", ""]
    for fam in fams:
        lines += [f"## Learner family: {fam}", ""]
        for key in keys:
            lines += _section(out, fam, key, results["families"][fam][key])
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def _int_keys(results: dict) -> dict:
    for per_target in results["families"].values():
        for res in per_target.values():
            res["cases"] = {int(c): d for c, d in res["cases"].items()}
    return results


def rewrite(out: Path) -> Path:
    """The report again from ``results.json`` (no new sessions)."""
    import re

    out = Path(out)
    results = _int_keys(json.loads((out / "results.json").read_text()))
    text = (out / "report.md").read_text() if (out / "report.md").exists() else ""
    m = re.search(r"ch6` in (\d+) s", text)
    return write_report(out, results, float(m.group(1)) if m else 0.0)


def nb_across_tasks(client, clips: dict, per_target: dict, learners: int, family: str, echo=print) -> dict:
    """Thesis 6.5 / 6.6: the naive Bayes adverb trained on one task's trials (its ``nb``
    training logs) and used on another task's learners, beside the same learners coached by the
    classifier trained on their own task. Keys ``"A>B"``: trained on A, used on B."""
    out = {}
    for a in per_target:
        for b in per_target:
            if a == b:
                continue
            src, own = per_target[a]["nb"], per_target[b]["nb"]
            row = {"trained_on": a, "used_on": b, "own_d": own["d"]}
            try:
                nb = client.request("coach", "policy_fit", {"kind": "nb", "features": src["features"],
                                                            "labels": src["labels"], "alpha": 2.0})
                ex = Experiment(client, clips[b], f"{family}-{b}".replace("_", ""), learners, echo=echo, family=family)
                row["d"] = Experiment.d(ex.group(f"nbx-{a}", lambda i: nb["policy"])).tolist()
            except RemoteError as e:
                row["d"], row["why"] = None, e.message
            out[f"{a}>{b}"] = row
    echo(f"  {family}: naive Bayes across tasks done")
    return out


def nb_transfer_lines(results: dict) -> list[str]:
    """The report's lines on naive Bayes across tasks (computed)."""
    lines = ["## Naive Bayes across tasks (thesis 6.5, 6.6)", "",
             "The adverb classifier trained on one task's trials and used on another task's learners, against the same "
             "learners coached by the classifier trained on their own task (paired t-test on R_4; the word as above).",
             "", "| family | trained on -> used on | R_4 across tasks | R_4 own task | difference (across - own) |",
             "|---|---|---|---|---|"]
    for fam, pairs in (results.get("nb_transfer") or {}).items():
        for key, row in pairs.items():
            a, b = key.split(">")
            if row.get("d") is None or row.get("own_d") is None:
                lines.append(f"| {fam} | {a} -> {b} | - | - | not run: {row.get('why') or 'the own-task classifier was not trained'} |")
                continue
            x, y = _r4(row["d"]), _r4(row["own_d"])
            f = compare(y, x)  # is the own task's classifier lower than the transferred one?
            lines.append(f"| {fam} | {a} -> {b} | {x.mean():.3f} | {y.mean():.3f} | {x.mean() - y.mean():+.3f} "
                         f"(own task lower: {f['word']}, p = {f['p']:.3f}) |")
    return lines + [""]


def _keep(out: Path, results: dict) -> None:
    """``results.json`` as it stands (written again after every family and sensitivity sweep)."""
    from shared.io.atomic import atomic_write

    text = json.dumps(results, indent=1, default=str).encode()
    atomic_write(out / "results.json", lambda f: f.write(text))


def run(client, hdm05: Path, out: Path, learners: int = 12, targets=("squat", "throw"), families=None,
        sensitivity_learners: int = 8, echo=print) -> Path:
    """Every family on every target, then each family's sensitivity sweep on the first target."""
    from shared.agents.learner import FAMILIES

    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    families = list(families or FAMILIES)
    clips = {key: target_clip(hdm05, TARGETS[key]) for key in targets}
    results: dict = {"families": {}, "sensitivity": {}, "sensitivity_learners": sensitivity_learners,
                     "sensitivity_target": targets[0]}
    for fam in families:
        results["families"][fam] = {}
        for key in targets:
            echo(f"family {fam}, target {key}")
            results["families"][fam][key] = run_target(client, clips[key], key, learners, echo, fam)
        if len(targets) > 1:
            results.setdefault("nb_transfer", {})[fam] = nb_across_tasks(client, clips, results["families"][fam],
                                                                         learners, fam, echo)
        _keep(out, results)  # a run stopped later keeps every family done so far
    if sensitivity_learners:
        for fam in families:
            results["sensitivity"][fam] = sensitivity(client, clips[targets[0]], targets[0], sensitivity_learners, fam,
                                                      echo)
            _keep(out, results)
    (out / "results.json").write_text(json.dumps(results, indent=1, default=str))
    write(tidy_rows(_int_keys(json.loads((out / "results.json").read_text()))), out / "tidy.csv")
    path = write_report(out, _int_keys(json.loads((out / "results.json").read_text())), time.perf_counter() - t0)
    echo(f"wrote {path} in {time.perf_counter() - t0:.0f} s")
    return path
