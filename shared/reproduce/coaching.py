"""``mirrorcoach reproduce ch4 ch5 ch6``: the coaching experiments of chapters 4-6, rerun on the
cluster with a seeded population of **simulated learners** (not people) and real HDM05 targets
(a squat and the basketball throw, standing in for the thesis's tennis swing and medicine-ball
throw). Every session runs through the coach service (pss for spaces and generation, the
simulator for learners and feasibility).

Every experiment runs once per learner family (``shared/agents/learner.py``): the
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
from pathlib import Path

import numpy as np

from schemas.common import clip_to_wire
from shared.bus.client import RemoteError
from shared.coaching.policies import ADVERBS, SWEEP
from shared.reproduce.coaching_report import write_report
from shared.reproduce.coaching_stats import (
    CASES,
    NB_TRAIN_SEED,
    SENSITIVITY,
    SENSITIVITY_ALPHAS,
    STRENGTH,
    STRENGTH_SEED,
    TARGETS,
    int_keys,
    r4_of,
    r_l,
    tidy_rows,
)
from shared.reproduce.stopping import stopping, worker_pool
from shared.reproduce.tidy import write


def target_clip(hdm05: Path, label: str):
    from shared.io import find_clips, load_clip

    files = [f for f in find_clips([hdm05 / "amc" / label]) if "_bd_" in f.name]
    if not files:
        raise FileNotFoundError(f"no HDM05 clip of {label} by actor bd under {hdm05}")
    return load_clip(files[0])


class Experiment:
    def __init__(self, client, target, name: str, learners: int, seed: int = 0, trials: int = 4, workers: int = 4,
                 echo=print, family: str = "thesis"):
        self.c, self.target, self.name = stopping(client), target, name  # Ctrl-C: stopping.py
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
        with worker_pool(self.c, self.workers) as pool:
            return list(pool.map(lambda i: self.session(tag, i, policy_of(i), check,
                                                        **({"params": params_of(i)} if params_of else {}), **kw),
                                 range(self.learners)))

    @staticmethod
    def d(infos: list[dict]) -> np.ndarray:
        return np.array([[t["d_p"] for t in info["trials"]] for info in infos])


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
            labels.append(max(gains, key=gains.__getitem__))
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
            out[f"{param}={v:g}"] = {f"{a:g}": r4_of(Experiment.d(ex.group(
                f"{param[:4]}{v:g}-a{a:g}".replace(".", "_"), lambda i, a=a: {"kind": "fixed", "alpha": a, "adverb": None},
                params={param: v}))).tolist() for a in SENSITIVITY_ALPHAS}
    echo(f"  sensitivity {family}: {ex.count} coaching trials")
    return out


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
                row["d"] = Experiment.d(ex.group(f"nbx-{a}", lambda i, nb=nb: nb["policy"])).tolist()
            except RemoteError as e:
                row["d"], row["why"] = None, e.message
            out[f"{a}>{b}"] = row
    echo(f"  {family}: naive Bayes across tasks done")
    return out


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
    write(tidy_rows(int_keys(json.loads((out / "results.json").read_text()))), out / "tidy.csv")
    path = write_report(out, int_keys(json.loads((out / "results.json").read_text())), time.perf_counter() - t0)
    echo(f"wrote {path} in {time.perf_counter() - t0:.0f} s")
    return path
