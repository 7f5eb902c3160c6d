"""Closed (comparative) questions: identify the other's conversion rule (thesis 3.4, eq. 3.11-3.20).

* :func:`design_thesis_pairs` builds the thesis's motion pairs on the self's body with
  ``scipy.optimize``: m1/m2 with equal mean torque (f1) and different maxima; m4 bending all
  four joints at once to the same peak torque ``a``; m3 moving them one after another to peaks
  ``(3.0a, 0.4a, 0.4a, 0.2a)`` (eq. 3.17-3.20), and reports how close the achieved torques are.
* :func:`identify` goes beyond the thesis: for any set of candidate rules it picks, from a pool
  of motion pairs the self can perform, the pair whose predicted answers split the remaining
  candidates best (smallest expected number left), asks, keeps the candidates consistent with
  the answer, and repeats until one is left: N questions can separate up to 3^N rules.

A candidate's answer is predicted from the self's own torques: for bodies that differ by a
mass scale every rule is homogeneous, so the comparison is the same for the other (thesis
3.4.4). Predictions within the just-noticeable difference's grey zone are not trusted: a pair
is only used when every remaining candidate's answer is clear (ratio within ``jnd/2`` of 1
for ``equal``, at least ``2 jnd`` away for ``>``/``<``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import brentq, least_squares

from shared.clip import Clip
from shared.errors import BadInput
from shared.estimation.motions import ALL, FPS
from shared.symbols import f_conv

THESIS_PEAKS = (3.0, 0.4, 0.4, 0.2)  # (alpha, beta, gamma, omega) / a, eq. 3.20
M3_ORDER = ("knee", "shoulder_pitch", "shoulder_roll", "elbow")  # the thesis's m3: squat, pitch, roll, elbow


@dataclass(frozen=True)
class Candidate:
    """A candidate conversion rule: a rule name and optional per-joint weights."""

    rule: str
    weights: tuple[float, ...] | None = None

    @property
    def name(self) -> str:
        return self.rule if self.weights is None else f"{self.rule}[{','.join(f'{w:g}' for w in self.weights)}]"

    def g(self, tau: np.ndarray) -> float:
        return f_conv(tau, self.rule, 1.0, None if self.weights is None else list(self.weights))


THESIS_CANDIDATES = [Candidate(r) for r in ("f1", "f2", "f3", "f4")]


def weighted_candidates() -> list[Candidate]:
    """f1-f4, each with equal weights, the knee doubled, and the shoulder pitch doubled: 12 rules."""
    out = []
    for r in ("f1", "f2", "f3", "f4"):
        out += [Candidate(r), Candidate(r, (1.0, 1.0, 1.0, 2.0)), Candidate(r, (2.0, 1.0, 1.0, 1.0))]
    return out


def predict(c: Candidate, tau_a: np.ndarray, tau_b: np.ndarray, jnd: float) -> str | None:
    """The clear answer candidate ``c`` gives about (a, b), or None in the grey zone."""
    ga, gb = c.g(tau_a), c.g(tau_b)
    r = ga / max(gb, 1e-12)
    if abs(r - 1) <= jnd / 2:
        return "equal"
    if abs(r - 1) >= 2 * jnd:
        return ">" if r > 1 else "<"
    return None


# ---------------------------------------------------------------------------- the thesis's pairs
def _bump(n: int, centre: float, width: float) -> np.ndarray:
    t = np.linspace(0, 1, n)
    return np.exp(-0.5 * ((t - centre) / width) ** 2)


def _clip(name: str, angles: dict[str, np.ndarray]) -> Clip:
    n = len(next(iter(angles.values())))
    return Clip(np.column_stack([angles.get(j, np.zeros(n)) for j in ALL]), list(ALL), FPS, name=name, label=name)


SIGN = {"shoulder_pitch": 1.0, "shoulder_roll": 1.0, "elbow": -1.0, "knee": 1.0}


def design_thesis_pairs(perform_self: Callable[[Clip], np.ndarray], a: float = 0.03) -> dict:
    """m1..m4 on the self's body (see module docstring). ``perform_self`` returns the torques
    (T x 4, joints in ``ALL`` order). Returns the clips and a report of design against achieved."""
    n = 121

    def peaks(clip):
        return np.abs(perform_self(clip)).max(axis=0)

    # m4: all joints bend and stretch together, every peak torque = a
    def m4_of(amp):
        b = _bump(n, 0.5, 0.12)
        return _clip("m4", {j: SIGN[j] * amp[i] * b for i, j in enumerate(ALL)})

    fit4 = least_squares(lambda amp: (peaks(m4_of(amp)) - a) / a, x0=np.full(4, 20.0), bounds=(0.0, 150.0))
    m4 = m4_of(fit4.x)
    # m3: one joint after another (knee, pitch, roll, elbow), peaks (3.0, 0.4, 0.4, 0.2) a
    target = {j: p * a for j, p in zip(M3_ORDER, THESIS_PEAKS)}

    def m3_of(amp):
        return _clip("m3", {j: SIGN[j] * amp[i] * _bump(n, 0.14 + 0.24 * i, 0.05) for i, j in enumerate(M3_ORDER)})

    want3 = np.array([target[j] for j in ALL])
    order = [ALL.index(j) for j in M3_ORDER]
    fit3 = least_squares(lambda amp: (peaks(m3_of(amp))[order] - want3[order]) / a, x0=np.full(4, 20.0),
                         bounds=(0.0, 150.0))
    m3 = m3_of(fit3.x)
    # m1/m2: the same mean torque (f1), different maxima: a long low hold against a short high one
    hold = np.clip(np.linspace(0, 1, n) * 8, 0, 1) * np.clip((1 - np.linspace(0, 1, n)) * 8, 0, 1)
    m1 = _clip("m1", {"shoulder_pitch": 20.0 * hold})
    short = _bump(n, 0.5, 0.12)
    f1_target = f_conv(perform_self(m1), "f1")

    def m2_of(amp):
        return _clip("m2", {"shoulder_pitch": amp * short})

    amp2 = brentq(lambda x: f_conv(perform_self(m2_of(x)), "f1") - f1_target, 5.0, 120.0, xtol=1e-6)
    m2 = m2_of(amp2)
    t1, t2, t3, t4 = (perform_self(m) for m in (m1, m2, m3, m4))
    report = {
        "a": a,
        "m4_peaks": (np.abs(t4).max(axis=0)).tolist(), "m4_design": [a] * 4,
        "m3_peaks": (np.abs(t3).max(axis=0)).tolist(), "m3_design": want3.tolist(),
        "m1_m2_f1": [f_conv(t1, "f1"), f_conv(t2, "f1")],
        "m1_m2_f4": [f_conv(t1, "f4"), f_conv(t2, "f4")],
        "thesis_values": {r: [f_conv(t3, r), f_conv(t4, r)] for r in ("f2", "f3", "f4")},
        "max_relative_error": float(max(np.max(np.abs(np.abs(t4).max(axis=0) - a) / a),
                                        np.max(np.abs(np.abs(t3).max(axis=0) - want3) / want3))),
    }
    return {"m1": m1, "m2": m2, "m3": m3, "m4": m4, "report": report}


# ---------------------------------------------------------------------------- automatic identification
@dataclass
class Pair:
    name: str
    first: Clip
    second: Clip
    tau_first: np.ndarray
    tau_second: np.ndarray


def pair_pool(motions: list[Clip], perform_self: Callable[[Clip], np.ndarray], designed: list[tuple[Clip, Clip]] = ()) -> list[Pair]:
    """Every ordered-once pair of ``motions`` plus the ``designed`` pairs, with the self's torques."""
    tau = {m.name: perform_self(m) for m in motions}
    out = [Pair(f"{a.name}|{b.name}", a, b, perform_self(a), perform_self(b)) for a, b in designed]
    for i, a in enumerate(motions):
        for b in motions[i + 1:]:
            out.append(Pair(f"{a.name}|{b.name}", a, b, tau[a.name], tau[b.name]))
    return out


def best_pair(candidates: list[Candidate], pool: list[Pair], jnd: float) -> tuple[Pair, dict] | None:
    """The pair whose clear answers split ``candidates`` best, and each candidate's answer."""
    best = None
    for p in pool:
        answers = {}
        for c in candidates:
            a = predict(c, p.tau_first, p.tau_second, jnd)
            if a is None:
                break
            answers[c] = a
        else:
            groups = {}
            for a in answers.values():
                groups[a] = groups.get(a, 0) + 1
            if len(groups) < 2:
                continue
            expected = sum(v * v for v in groups.values()) / len(candidates)
            if best is None or expected < best[0]:
                best = (expected, p, answers)
    return None if best is None else (best[1], best[2])


def identify(candidates: list[Candidate], pool: list[Pair], ask_compare: Callable[[Clip, Clip], str],
             jnd: float = 0.05, max_questions: int = 10) -> dict:
    """Ask comparative questions until one candidate is left (see module docstring).

    Returns ``{"rule": Candidate | None, "questions": [...], "remaining": [...], "reason": str}``.
    """
    if not candidates:
        raise BadInput("no candidate rules")
    left = list(candidates)
    asked = []
    reason = "identified"
    while len(left) > 1:
        if len(asked) >= max_questions:
            reason = f"stopped after {max_questions} questions"
            break
        choice = best_pair(left, [p for p in pool if p.name not in {q['pair'] for q in asked}], jnd)
        if choice is None:
            reason = "no pair of motions separates the remaining rules"
            break
        pair, predicted = choice
        answer = ask_compare(pair.first, pair.second)
        asked.append({"pair": pair.name, "answer": answer,
                      "predicted": {c.name: a for c, a in predicted.items()}})
        keep = [c for c in left if predicted[c] == answer]
        if not keep:
            reason = f"no candidate rule explains the answer {answer!r} to {pair.name}; the other contradicts every rule"
            break
        left = keep
    return {"rule": left[0] if len(left) == 1 and reason == "identified" else None,
            "questions": asked, "remaining": [c.name for c in left], "reason": reason}


def identify_thesis(pairs: dict, ask_compare: Callable[[Clip, Clip], str]) -> dict:
    """The thesis's own flow (fig. 3.11): ask m1 vs m2 ('equal' -> f1), then m3 vs m4
    ('equal' -> f2, '<' -> f3, '>' -> f4)."""
    first = ask_compare(pairs["m1"], pairs["m2"])
    questions = [{"pair": "m1|m2", "answer": first}]
    if first == "equal":
        return {"rule": Candidate("f1"), "questions": questions, "reason": "identified"}
    second = ask_compare(pairs["m3"], pairs["m4"])
    questions.append({"pair": "m3|m4", "answer": second})
    rule = {"equal": "f2", "<": "f3", ">": "f4"}.get(second)
    return {"rule": Candidate(rule) if rule else None, "questions": questions,
            "reason": "identified" if rule else f"unexpected answer {second!r}"}
