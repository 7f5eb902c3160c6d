"""``mirrorcoach reproduce ch3``: chapter 3 of the thesis, rerun on the cluster.

Everything goes through the services: simulated others on the simulator, questions through the
dialogue service, the estimator's conversation sets, spaces on pss. The ground truth for
evaluation (the other's real torques) comes from performing the motions on the other's own body
(the parameters this run gave it, :class:`shared.agents.other.SimulatedOther`); the estimator
never sees them.

Sections:

* **the uneven population** (the default): 10 others of every kind of
  :mod:`shared.agents.population` (link lengths, payloads, mass shares, damping, friction, a
  missing joint, heavier legs, all at once, and the thesis's proportional other), each estimated
  by the thesis's eq. 3.5, the interval estimator and the body estimator, then its rule
  identified with and without answer noise;
* fig. 3.6-3.8 (d = 4, 6, 8, the thesis's proportional 4.8 kg other, every set);
* fig. 3.14/3.15 with the thesis's roles: d = 5, the other converts with f4, the self identifies
  it (or does not and keeps eq. 3.8); d = 7, the other uses f2 (the caption's f0 read as the
  chapter's eq. 3.8, the self's default);
* the error under answer noise.

Every verdict word in the report is computed from the numbers (:func:`verdict`).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from schemas.common import clip_from_wire, clip_to_wire
from shared.agents.other import OtherParams, SimulatedOther
from shared.agents.population import KINDS, OUTSIDE_KINDS, people_population, population, seen_still
from shared.estimation.conversation import Language, evaluate, hold
from shared.estimation.motions import ALL, ARM, basic_motions, unknown_motions
from shared.reproduce.ch3_report import (
    FAST,
    G_MAX,
    G_MAX_RULES,
    METHODS,
    OTHERS,
    SETS,
    WORKERS,
    write_report,
)
from shared.reproduce.stopping import stopping, worker_pool


class Ch3:
    def __init__(self, client, out: Path, sets: int = SETS, echo=print, others: int = OTHERS, kinds=KINDS,
                 population_seed: int = 2026):
        self.c, self.out, self.sets, self.echo = stopping(client), Path(out), sets, echo  # Ctrl-C: stopping.py
        self.others, self.kinds, self.population_seed = others, list(kinds), population_seed
        self.out.mkdir(parents=True, exist_ok=True)
        self._truth: dict = {}
        self._lock = threading.Lock()  # the population runs WORKERS others at a time

    # ------------------------------------------------------------------ helpers
    def truth(self, name: str, params: dict, motions, joints) -> list[np.ndarray]:
        """The other's real torques: its own body performing the motions (evaluation only)."""
        other = None
        out = []
        # a tiring other feels as it does now, after every question it was asked
        asked = (self.c.request("simulator", "other_reveal", {"other": name})["asked"]
                 if (params.get("transmission") or {}).get("fatigue") else 0)
        for m in motions:
            key = (name, m.name, tuple(joints), asked)
            if key not in self._truth:
                other = other or SimulatedOther(name, OtherParams(**params), asked=asked)  # its body, built once
                tau = other.feel(m).copy()
                with self._lock:
                    self._truth[key] = tau
            out.append(self._truth[key])
        return out

    def estimates(self, name: str, motions, method: str, joints) -> list[np.ndarray]:
        """The estimator's torques for each motion: four requests in flight (each waits on the
        bus: the space's estimates on pss), each of a quarter of the motions."""
        def some(ms):
            r = self.c.request("estimator", "estimate_many", {"estimate": name, "clips": [clip_to_wire(m) for m in ms],
                                                               "method": method})
            return [clip_from_wire(e["clip"]).select([f"tau.{j}" for j in joints]) for e in r["estimates"]]

        parts = [list(motions)[k::4] for k in range(4)]
        with worker_pool(self.c, 4) as pool:
            done = list(pool.map(some, [p for p in parts if p]))
        out: list = [None] * len(motions)  # back in the motions' order
        for k, est in enumerate(done):
            out[k::4] = est
        return out

    def new_other(self, name: str, **params) -> dict:
        self.c.request("simulator", "other_create", {"other": name, "params": params, "replace": True})
        with self._lock:
            for k in [k for k in self._truth if k[0] == name]:
                del self._truth[k]
        return params

    def start(self, name: str, other: str, **req) -> dict:
        return self.c.request("estimator", "start", {"estimate": name, "other": other, "replace": True, **req})

    def score(self, name: str, params: dict, lang: Language, motions: dict, methods=METHODS) -> dict:
        """Eq. 3.9 error, match and distance per method and motion group; motions the other
        feels nothing of (g = 0: it cannot make them) are left out and counted."""
        row: dict[str, Any] = {}
        for k, ms in motions.items():
            truth = self.truth(name, params, ms, lang.joints)
            keep = [i for i, t in enumerate(truth) if lang.g(t) > 1e-9]
            row[f"{k}_left_out"] = len(ms) - len(keep)
            for method in methods:
                est = self.estimates(name, [ms[i] for i in keep], method, lang.joints)
                row[f"{method}_{k}"] = evaluate(lang, [truth[i] for i in keep], est)
                if method == "body" and k == "unknown":  # the symbol match at every density (fig. 3.7)
                    row["body_unknown_match"] = {d: evaluate(Language(d=d, g_max=lang.g_max, joints=lang.joints),
                                                             [truth[i] for i in keep], est)["match"] for d in (4, 6, 8)}
        return row

    def curve(self, name: str, params: dict, lang: Language, motions: dict, methods=METHODS) -> dict:
        """Metrics after 0..sets conversation sets (the estimate must be started)."""
        rows, stopped, model, asked = [], None, None, 0
        for s in range(self.sets + 1):
            if s:
                r = self.c.request("estimator", "converse", {"estimate": name, "sets": 1})
                stopped, model = r.get("stopped"), r.get("model")
                asked = r["info"]["answers"]
            # questions so far: the thesis estimator reads the shared motions' answers (4 a set), the
            # body estimator every answer (probes too)
            rows.append({"set": s, "questions": {"thesis": 4 * s, "body": asked, "space": 4 * s},
                         **self.score(name, params, lang, motions, methods)})
            if stopped:
                break
        return {"rows": rows, "stopped": stopped, "model": model}

    # ------------------------------------------------------------------ sections
    def one_other(self, kind: str, i: int, p: dict) -> dict:
        """One other of the population: a whole conversation, then every estimator's error."""
        joints_all = "knee" in p["joints"]
        name = f"ch3-{kind}-{i}"
        missing = seen_still(p)  # a fused joint is imitated as a missing one: its bend is not seen
        self.new_other(name, **p)
        lang = Language(d=6, g_max=G_MAX, joints=p["joints"], missing=missing)
        self.start(name, name, d=6, g_max=G_MAX, joints=p["joints"], missing=missing)
        shared = basic_motions(ALL if joints_all else ARM)
        motions = {"known": [hold(m, missing) for m in shared],
                   "unknown": [hold(m, missing) for m in unknown_motions(10, joints=ALL if joints_all else ARM)]}
        # at equal numbers of questions: the body estimator reads every answer (probes too); after half
        # the sets it has read as many as the thesis and space estimators after all of them
        half = self.sets // 2
        asked = 0
        if half:
            asked = self.c.request("estimator", "converse", {"estimate": name, "sets": half}, timeout=3600)["info"]["answers"]
        equal = {"questions": asked, "thesis_questions": 4 * self.sets,
                 **self.score(name, p, lang, {"unknown": motions["unknown"]}, ("body",))}
        r = self.c.request("estimator", "converse", {"estimate": name, "sets": self.sets - half}, timeout=3600)
        row = self.score(name, p, lang, motions)
        # the unknown motions played FAST times faster: where speed-dependent terms (damping,
        # armature, friction) weigh more than on the motions the conversation shared; the body
        # estimator's goal (the others' errors there were never reported: a third of the scoring)
        fast = [m.with_data(m.data, fps=m.fps * FAST, name=f"{m.name}_x{FAST:g}") for m in motions["unknown"]]
        row.update(self.score(name, p, lang, {"unknown_fast": fast}, ("body",)))
        row.update(mass=p["mass"], body=p["body"], sets=r["info"]["sets_done"], stopped=r.get("stopped"), equal=equal,
                   questions=r["info"]["answers"], model=r.get("model"), dont_know=r["info"].get("dont_know", 0))
        self.c.request("estimator", "delete", {"estimate": name})
        self.c.request("simulator", "delete", {"other": name})
        return row

    def uneven(self, kinds=None) -> dict:
        """Every kind of other, 10 each; the three estimators after the sets
        (``WORKERS`` others at a time: the services are separate processes). ``kinds``: these
        instead of the run's (the kinds outside the estimator's model)."""
        res = {}
        kinds = self.kinds if kinds is None else kinds
        # heavier legs matter only to a conversation about the knee
        tasks = [(kind, i, p) for kind in kinds for i, p in enumerate(population(
            kind, self.others, seed=self.population_seed, d=6, g_max=G_MAX, joints=list(ALL) if kind == "legs" else list(ARM)))]
        # every kind's others in one pool: WORKERS conversations always in flight (a pool per kind
        # waited for its slowest other before the next kind began); each kind said once it is done
        with worker_pool(self.c, WORKERS) as pool:
            futures = [(task[0], pool.submit(self.one_other, *task)) for task in tasks]
            for kind in kinds:
                rows = [f.result() for k, f in futures if k == kind]
                res[kind] = rows
                e = {m: (np.mean([r[f"{m}_known"]["error"] for r in rows]),
                         np.mean([r[f"{m}_unknown"]["error"] for r in rows])) for m in METHODS}
                self.echo(f"  {kind}: " + ", ".join(f"{m} {k:.1%} / {u:.1%}" for m, (k, u) in e.items())
                          + " (known / unknown)")
        return res

    def people(self, kinds=("mass", "mixed")) -> dict:
        """In-model others answering like people (:func:`people_answers`: own and
        drifting word boundaries, 10-30 % inconsistent answers, "I don't know"); the conversation
        goes on through all of it."""
        res = {}
        pops = {}
        for kind in kinds:
            pops[kind] = people_population(kind, self.others, seed=self.population_seed, d=6, g_max=G_MAX,
                                           joints=list(ARM))
        with worker_pool(self.c, WORKERS) as pool:  # both kinds in one pool (see uneven)
            futures = {kind: [pool.submit(self.one_other, f"people-{kind}", i, p) for i, p in enumerate(pop)]
                       for kind, pop in pops.items()}
            for kind, pop in pops.items():
                rows = [f.result() for f in futures[kind]]
                for row, p in zip(rows, pop):
                    row["answering"] = {k: p[k] for k in ("gamma", "drift", "noise", "dont_know")}
                res[kind] = rows
                self.echo(f"  people-like answers, {kind}: " + ", ".join(
                    f"{m} {np.mean([r[f'{m}_unknown']['error'] for r in rows]):.1%}" for m in METHODS) + " (unknown)")
        return res

    def identification(self, kinds=None) -> dict:
        """Rule identification over the population: per kind, 10 others (f1-f4 in turn), without
        noise and with 10 % answer noise; the thesis's pairs (fig. 3.11, predicted from the self)
        and the automatic method (predicted from the estimated body). The 12 weighted rules on the
        proportional kind. ``kinds``: these instead of the run's (with the kinds outside the model)."""
        from shared.estimation.rules import THESIS_CANDIDATES, weighted_candidates

        table = {}
        plans = [(kind, "thesis", THESIS_CANDIDATES) for kind in (self.kinds if kinds is None else kinds)]
        plans += [(kind, "weighted", weighted_candidates()) for kind in ("mass",) if kind in self.kinds]
        # the weighted rules without noise only: a doubled joint weight and a doubled link feel alike;
        # 20 % inconsistent answers (answers like people's): the auto method only
        configs = [(kind, cset, cands, noise, method) for kind, cset, cands in plans
                   for noise in ((0.0, 0.1, 0.2) if cset == "thesis" else (0.0,))
                   for method in (("thesis", "auto") if cset == "thesis" and noise < 0.2 else ("auto",))]

        def one(config, i, p):
            kind, cset, cands, noise, method = config
            c = cands[i % len(cands)]
            name = f"ch3-id-{kind}-{cset}-{method}-{int(100 * noise)}-{i}"
            p = {**p, "rule": c.rule, "weights": None if c.weights is None else list(c.weights),
                 "noise": noise, "seed": 1000 * int(100 * noise) + i}
            self.new_other(name, **p)
            self.start(name, name, joints=p["joints"], missing=seen_still(p),
                       g_max=G_MAX_RULES, probes=0)
            r = self.c.request("estimator", "identify_rule", {"estimate": name, "method": method,
                                                              "apply": False, "candidates": cset})
            self.c.request("estimator", "delete", {"estimate": name})
            self.c.request("simulator", "delete", {"other": name})
            return r.get("rule") == c.name, len(r["questions"]), r["reason"]

        # every configuration's others in one pool (see uneven); each kind said once it is done
        with worker_pool(self.c, WORKERS) as pool:
            futures = [(config, [pool.submit(one, config, i, p) for i, p in enumerate(population(
                config[0], max(self.others, len(config[2])), seed=self.population_seed, joints=list(ALL),
                g_max=G_MAX_RULES))]) for config in configs]
            for kind, cset, _ in plans:
                for (k, cs, _, noise, method), fs in futures:
                    if (k, cs) != (kind, cset):
                        continue
                    results = [f.result() for f in fs]
                    ok, n = sum(h for h, _, _ in results), len(results)
                    questions = sum(q for _, q, _ in results)
                    reasons: dict = {}
                    for hit, _, reason in results:
                        if not hit:
                            why = "a wrong rule identified" if reason == "identified" else reason
                            reasons[why] = reasons.get(why, 0) + 1
                    table[f"{kind}|{cset}|{method}|{noise:g}"] = {
                        "kind": kind, "candidates": cset, "method": method, "noise": noise, "rate": ok / n,
                        "trials": n, "questions": questions / n, "failures": reasons}
                self.echo(f"  {kind} ({cset}): " + ", ".join(
                    f"{v['method']} noise {v['noise']:.0%} {v['rate']:.0%} ({v['questions']:.1f} q)"
                    for k, v in table.items() if k.startswith(f"{kind}|{cset}|")))
        return table

    def open_questions(self) -> dict:
        """Fig. 3.6-3.8: error, match ratio, symbol distance against sets; d = 4, 6, 8."""
        res = {}
        known, unknown = basic_motions(ARM), unknown_motions(10, joints=ARM)

        def one(d):
            name = f"ch3-d{d}"
            params = self.new_other(name, mass=4.8, d=d, g_max=G_MAX)
            self.start(name, name, d=d, g_max=G_MAX)
            return self.curve(name, params, Language(d=d, g_max=G_MAX), {"known": known, "unknown": unknown})

        with worker_pool(self.c, 3) as pool:  # three others of their own: at once
            curves = dict(zip((4, 6, 8), pool.map(one, (4, 6, 8))))
        for d in (4, 6, 8):
            res[d] = curves[d]
            last = res[d]["rows"][-1]
            self.echo(f"  d={d}: after {last['set']} sets " + ", ".join(
                f"{m} {last[f'{m}_known']['error']:.1%} / {last[f'{m}_unknown']['error']:.1%}" for m in METHODS))
        return res

    def rules(self) -> dict:
        """Fig. 3.14/3.15 with the thesis's roles: the other's rule identified (right) or not
        (the self keeps eq. 3.8: wrong); d = 5 with f4 and d = 7 with f2."""
        unknown = unknown_motions(10, joints=ALL)
        out = {}

        def one(d, rule):  # the estimates of one d ask the same other in turn (its answers follow its questions)
            other = f"ch3-{rule}"
            params = self.new_other(other, mass=4.8, d=d, g_max=G_MAX_RULES, rule=rule, joints=list(ALL))
            # right: identified; wrong: the self keeps eq. 3.8 (the caption's f0); at d = 5 also the
            # other reading of the roles: the self assumes f2 and the other does not use it
            for label, assumed in (("right", None), ("wrong", "eq3.8")) + ((("wrong-f2", "f2"),) if rule != "f2" else ()):
                name = f"ch3-{label}-d{d}"
                self.start(name, other, d=d, g_max=G_MAX_RULES, joints=list(ALL), rule=assumed or "eq3.8")
                ident = None
                if label == "right":
                    ident = self.c.request("estimator", "identify_rule", {"estimate": name})
                lang = Language(d=d, g_max=G_MAX_RULES, joints=list(ALL), rule=rule)
                out[f"{label}|{d}"] = {"d": d, "rule": rule, "assumed": ident and ident.get("rule") or assumed,
                                       "identified": ident and ident.get("rule"),
                                       "questions": ident and ident["questions"], "design": ident and ident.get("design"),
                                       **self.curve(name, params, lang, {"unknown": unknown})}

        with worker_pool(self.c, 2) as pool:  # the two d's: two others of their own, at once
            list(pool.map(one, (5, 7), ("f4", "f2")))
        # the same order of keys as one d after the other
        out = {f"{label}|{d}": out[f"{label}|{d}"] for d in (5, 7) for label in ("right", "wrong", "wrong-f2")
               if f"{label}|{d}" in out}
        for d, rule in ((5, "f4"), (7, "f2")):
            r, w = out[f"right|{d}"]["rows"][-1], out[f"wrong|{d}"]["rows"][-1]
            self.echo(f"  d={d}, other uses {rule}: identified {out[f'right|{d}']['identified']}; unknown-motion error "
                      f"right rule {r['thesis_unknown']['error']:.1%} (body {r['body_unknown']['error']:.1%}), wrong rule "
                      f"{w['thesis_unknown']['error']:.1%} (body {w['body_unknown']['error']:.1%})")
        return out

    def robustness(self) -> dict:
        """Error after the sets under answer noise (d = 6, the proportional other)."""
        known, unknown = basic_motions(ARM), unknown_motions(10, joints=ARM)
        lang = Language(d=6, g_max=G_MAX)

        def one(noise):
            name = f"ch3-noise{int(noise * 100)}"
            params = self.new_other(name, mass=4.8, d=6, g_max=G_MAX, noise=noise, seed=7)
            self.start(name, name, d=6, g_max=G_MAX)
            return self.curve(name, params, lang, {"known": known, "unknown": unknown})

        with worker_pool(self.c, 2) as pool:  # two others of their own: at once
            return dict(zip((0.1, 0.2), pool.map(one, (0.1, 0.2))))


def run(client, out: Path, sets: int = SETS, echo=print, others: int = OTHERS, kinds=KINDS, outside: bool = True) -> Path:
    """Every section; ``others`` of every kind in ``kinds`` of the population, and as many of
    every kind outside the estimators' model (``outside``)."""
    import json

    t0 = time.perf_counter()
    ch = Ch3(client, out, sets, echo, others, kinds)
    res: dict = {"seconds": {}}

    def section(key, title, work):
        echo(title)
        t = time.perf_counter()
        res[key] = work()
        res["seconds"][key] = round(time.perf_counter() - t, 1)

    section("uneven", f"others whose bodies differ: {len(ch.kinds)} kinds x {others}", ch.uneven)
    if outside:
        section("outside", f"others outside the estimators' model (never tuned on): {len(OUTSIDE_KINDS)} kinds x {others}",
                lambda: ch.uneven(OUTSIDE_KINDS))
    section("people", "others answering like people: own and drifting words, 10-30 % inconsistent, \"I don't know\"",
            ch.people)
    section("identification", "rule identification over the population",
            lambda: ch.identification(ch.kinds + (list(OUTSIDE_KINDS) if outside else [])))
    section("open", "fig. 3.6-3.8: open questions, d = 4, 6, 8", ch.open_questions)
    section("rules", "fig. 3.14/3.15: right rule versus wrong rule, d = 5 and 7", ch.rules)
    section("robustness", "answer noise", ch.robustness)
    # raw numbers, before plotting (the section times apart: the same seed gives the same file)
    (Path(out) / "results.json").write_text(json.dumps({k: v for k, v in res.items() if k != "seconds"}, indent=1,
                                                       default=str))
    path = write_report(Path(out), res, time.perf_counter() - t0, ch)
    echo(f"wrote {path} in {time.perf_counter() - t0:.0f} s")
    return path
