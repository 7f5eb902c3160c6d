"""Closed (comparative) questions: identify the other's conversion rule (thesis 3.4, eq. 3.11-3.20).

* :func:`design_thesis_pairs` builds the thesis's motion pairs on the self's body with
  ``scipy.optimize``: m1/m2 with equal mean torque (f1) and different maxima; m4 bending all
  four joints at once to the same peak torque ``a``; m3 moving them one after another to peaks
  ``(3.0a, 0.4a, 0.4a, 0.2a)`` (eq. 3.17-3.20), and reports how close the achieved torques are.
* :func:`identify_thesis` asks them in the thesis's order (fig. 3.11). Its answers are
  predicted from the self's own torques, right only when the other's body is the self's scaled
  in mass (thesis 3.4.4).
* :func:`identify_bodies` goes beyond the thesis: for any set of candidate rules it
  predicts every answer from bodies the other may have (:func:`candidate_bodies`), keeps a
  posterior over rule and body together, and asks the pair of :func:`identification_motions`
  that tells most, until one rule is sure.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq, least_squares

from shared.digest import array_digest
from shared.errors import BadInput
from shared.estimation.motions import ALL, FPS
from shared.estimation.symbols import f_conv
from shared.motion.clip import Clip

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


def identification_motions(design: dict) -> list[Clip]:
    """The motions :func:`identify_bodies` pairs up: 12 seeded random motions of the four
    joints, the 4 basic motions and the thesis's designed m1-m4."""
    from shared.estimation.motions import basic_motions, unknown_motions

    return unknown_motions(12, joints=ALL) + basic_motions(ALL) + [design[k] for k in ("m1", "m2", "m3", "m4")]


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


# ---------------------------------------------------------------------------- uneven bodies
#: the comparison noise the self allows for when it weighs answers (an answer other than the
#: predicted one, either of the two others equally likely)
ANSWER_NOISE = 0.1
#: how inconsistent the other may be, weighed together with rule and body when no single noise is
#: given: from nearly consistent to answering at random (2/3: every answer equally likely), equally
#: likely before the first answer
NOISE_LEVELS = (0.05, 0.1, 0.2, 0.35, 2 / 3)
CONFIDENCE = 0.999
#: how often one pair may be asked: a noisy other answers the same question differently, so a
#: repeated pair still tells (chosen on the in-model and development kinds of seed 13, 20 % noise:
#: 3 repeats took the lowest rate from 29/30 to 30/30 and the questions from 9-10 to 8-9)
REPEATS = 3
#: questions at most (seed 13, f1-f4 with the noise levels weighed: 60 took every in-model kind to
#: 30/30 at 0, 10 and 20 % noise, 40 left the development kinds 1-6 short; since the bodies the self
#: thinks possible hold the extended model class (:func:`plausible_bodies`)
#: 60 left one heavier-legs other at 20 % noise short (99.9 % not reached) and 90 took every
#: in-model kind to 30/30 again (10 others at each noise), the development kinds to 30/30 (drag) and 28/30 (bias);
#: 2026-12-07, seeds 13 and 14 (in-model and development kinds, 10 others each at 0, 10 and 20 % noise): 90 left
#: one biased other of seed 14 at 20 % noise short (99.9 % reached after 92 questions), 100, 120 and 150 none, the
#: same 2 wrong rules of seed 13's biased others at every cap; the smallest of them)
MAX_QUESTIONS = 100
BODY_SAMPLES = 1024


def body_samples(theta: np.ndarray, cov: np.ndarray | None, n: int = BODY_SAMPLES, seed: int = 0) -> np.ndarray:
    """Bodies the answers so far allow: the estimate and ``n - 1`` draws from the Gaussian
    approximation of its uncertainty (:meth:`shared.estimation.body.BodyEstimate.covariance`),
    clipped at 0 (no negative mass, damping or friction)."""
    theta = np.asarray(theta, float)
    if cov is None or n <= 1:
        return theta[None]
    cov = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    r = np.random.default_rng(seed)
    draws = theta + r.standard_normal((n - 1, len(theta))) @ root.T
    return np.vstack([theta, np.clip(draws, 0.0, None)])


ANSWERS = (">", "<", "equal")


def g_bodies(c: Candidate, y: np.ndarray, bodies: np.ndarray, torques: np.ndarray | None = None) -> np.ndarray:
    """``c.g`` of one motion (self regressor ``y``, T x J x P) on many bodies (N x P) at once;
    ``torques``: ``|y theta|`` (T x J x N: the bodies last, so every reduction over time and
    joints runs along whole rows of bodies, 2-5 times faster than along a strided axis) when
    already computed for these bodies (:func:`body_torques`)."""
    a = body_torques(y, bodies) if torques is None else torques
    if c.weights is not None:
        a = a * np.asarray(c.weights, float)[None, :, None]
    if c.rule == "f1":
        return a.mean(axis=(0, 1))
    if c.rule == "f2":
        return a.max(axis=0).sum(axis=0)
    if c.rule == "f3":
        return a.sum(axis=1).max(axis=0)
    if c.rule == "f4":
        return a.max(axis=(0, 1))
    if c.rule == "eq3.8":
        return a.sum(axis=1).mean(axis=0)
    raise BadInput(f"unknown conversion rule {c.rule!r}")


def body_torques(y: np.ndarray, bodies: np.ndarray) -> np.ndarray:
    """``|y theta|`` of one motion (T x J x P) on many bodies (N x P): T x J x N."""
    if y.shape[-1] != bodies.shape[-1]:
        raise BadInput(f"a regressor of {y.shape[-1]} columns and bodies of {bodies.shape[-1]}: rule identification's "
                       "bodies are in the columns of regressors with offsets (self_regressor(..., offsets=True))")
    return np.abs(y.reshape(-1, y.shape[-1]) @ bodies.T).reshape(*y.shape[:2], -1)


def predicted_answers(g_first: np.ndarray, g_second: np.ndarray, jnd: float) -> np.ndarray:
    """Index into ``ANSWERS`` of the comparison (eq. 3.11-3.12, :func:`shared.estimation.symbols.compare`)
    of two motions whose ``g`` are ``g_first`` and ``g_second`` (arrays: one per body)."""
    a, b = np.asarray(g_first, float), np.asarray(g_second, float)
    equal = np.abs(a - b) <= jnd * np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-12)
    return np.where(equal, 2, np.where(a > b, 0, 1))


_TABLES: OrderedDict = OrderedDict()  # identify_bodies' prediction tables, the last two (12-35 MB each)
_TABLES_LOCK = threading.Lock()


def _prediction_tables(candidates, names, regressors, bodies, jnd):
    """Every pair of motions, each candidate's and body's predicted answer to it (pairs, C, N) and
    the same one-hot (C, pairs x answers, N): computed once per process for the same candidates,
    motions, bodies and ``jnd`` (every identification without open answers has the same ones,
    those of the bodies the self thinks possible)."""
    seen: dict = {}
    for array in [regressors[m] for m in names] + [bodies[c.name] for c in candidates]:
        if id(array) not in seen:  # (the candidates share the prior's bodies)
            seen[id(array)] = array_digest(array)
    key = (jnd, tuple(names), tuple((c.rule, c.weights) for c in candidates),
           tuple(seen[id(regressors[m])] for m in names), tuple(seen[id(bodies[c.name])] for c in candidates))
    with _TABLES_LOCK:
        if key in _TABLES:
            _TABLES.move_to_end(key)
            return _TABLES[key]
    g = {}
    for m in names:
        shared: dict = {}  # candidates whose bodies are the same (no open answers yet) share the torques
        rows = []
        for c in candidates:
            body = seen[id(bodies[c.name])]
            if body not in shared:
                shared[body] = body_torques(regressors[m], bodies[c.name])
            rows.append(g_bodies(c, regressors[m], bodies[c.name], shared[body]))
        g[m] = np.array(rows)
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    preds = np.array([predicted_answers(g[a], g[b], jnd) for a, b in pairs], dtype=np.int8)  # (pairs, C, N)
    # whether each body predicts each answer of each pair: (C, pairs x answers, N)
    onehot = (preds.transpose(1, 0, 2)[:, :, None, :] == np.arange(3)[None, None, :, None]).astype(float)
    onehot = onehot.reshape(len(candidates), -1, preds.shape[2])
    for a in (preds, onehot):
        a.flags.writeable = False
    with _TABLES_LOCK:
        _TABLES[key] = (pairs, preds, onehot)
        while len(_TABLES) > 2:
            _TABLES.popitem(last=False)
    return pairs, preds, onehot


def identify_bodies(candidates: list[Candidate], motions: list[Clip], regressors: dict[str, np.ndarray],
                    bodies: dict[str, np.ndarray], ask_compare: Callable[[Clip, Clip], str], jnd: float = 0.05,
                    noise: float | None = None, confidence: float = CONFIDENCE, max_questions: int = MAX_QUESTIONS,
                    repeats: int = REPEATS) -> dict:
    """Identify the other's rule when its body is not the self's.

    Each candidate's answer about a pair of motions is predicted from the **estimated body**,
    not the self's: ``bodies[c.name]`` are bodies the open answers allow under that rule
    (:func:`candidate_bodies`), and a motion's torques on a body are its self regressor times
    the body. The self keeps a posterior over (rule, body, noise) together: every (candidate,
    body, noise level) starts equally likely; an answer other than the one that pair predicts
    has probability ``noise`` (either other answer equally likely). Without a given ``noise``
    the levels are :data:`NOISE_LEVELS`, up to answering at random: an other whose answers are
    chance keeps every rule in doubt instead of lending one a lucky run. It asks the pair of motions whose answer
    is expected to tell most about the rule (mutual information; a pair at most ``repeats``
    times, each answer weighed on its own), and stops when one rule holds
    ``confidence`` of the posterior, after ``max_questions``, or when no pair tells anything.

    Returns ``{"rule", "questions", "remaining", "reason", "posterior"}`` like :func:`identify`.
    """
    if not candidates:
        raise BadInput("no candidate rules")
    names = [m.name for m in motions]
    by_name = {m.name: m for m in motions}
    pairs, preds, onehot = _prediction_tables(candidates, names, regressors, bodies, jnd)
    n_bodies = preds.shape[2]
    levels = np.array(NOISE_LEVELS if noise is None else (noise,), float)
    w = np.full((len(candidates), n_bodies, len(levels)), 1.0 / (len(candidates) * n_bodies * len(levels)))
    times = np.zeros(len(pairs), int)  # how often each pair was asked
    asked: list[dict] = []
    reason = "identified"

    def rule_posterior():
        return w.sum(axis=(1, 2))

    while rule_posterior().max() < confidence:
        if len(asked) >= max_questions:
            reason = f"not sure after {max_questions} questions (best {rule_posterior().max():.0%})"
            break
        post = rule_posterior()
        # P(answer | rule, pair) = sum over noise levels e of P(e | rule) (e / 2) + (1 - 3 e / 2) P(predicted answer, e | rule, pair)
        per_level = w.sum(axis=1)  # (C, E)
        t = (per_level @ (levels / 2))[None, :, None] / np.maximum(post[None, :, None], 1e-300)
        # the levels summed before the bodies: one product over the bodies, (C, pairs x answers)
        hit = np.matmul(onehot, (w @ (1 - 1.5 * levels))[..., None])[..., 0]
        t = t + hit.reshape(len(candidates), len(pairs), 3).transpose(1, 0, 2) / np.maximum(post[None, :, None], 1e-300)
        p_ans = np.einsum("c,pca->pa", post, t)
        info = np.einsum("c,pca->p", post, t * np.log(np.maximum(t, 1e-12) / np.maximum(p_ans[:, None, :], 1e-12)))
        info[times >= repeats] = -np.inf
        best = int(np.argmax(info))
        if info[best] <= 1e-6:
            reason = "no pair of motions tells the remaining rules apart"
            break
        a, b = pairs[best]
        answer = ask_compare(by_name[a], by_name[b])
        if answer not in ANSWERS:
            reason = f"the answer {answer!r} is not a comparison"
            break
        k = ANSWERS.index(answer)
        w = w * np.where((preds[best] == k)[..., None], 1 - levels, levels / 2)
        w /= w.sum()
        post = rule_posterior()
        asked.append({"pair": f"{a}|{b}", "answer": answer,
                      "posterior": {c.name: round(float(p), 4) for c, p in zip(candidates, post)}})
        times[best] += 1
    post = rule_posterior()
    k = int(post.argmax())
    chance = float(w[..., levels > 0.5].sum()) if asked else 0.0
    if post[k] < confidence and chance > 0.5:
        reason = f"the other's comparisons look like chance ({chance:.0%} sure after {len(asked)} questions)"
    return {"rule": candidates[k] if post[k] >= confidence else None, "questions": asked, "chance": chance,
            "remaining": [c.name for c, p in zip(candidates, post) if p > 0.01], "reason": reason,
            "posterior": {c.name: float(p) for c, p in zip(candidates, post)}}


#: the extended model class in the bodies the self thinks possible (:func:`plausible_bodies`): the
#: mean spring stiffness (N m/rad) and rotor inertia (kg m^2) whose torques on the self's basic
#: motions are on average as large as the prior's damping's (mean 0.03 N m s/rad at their mean joint
#: speed of 0.6 rad/s: 0.018 N m; their mean joint angle is 0.3 rad, acceleration 2 rad/s^2), and
#: the largest rest angle (rad) of a spring
PLAUSIBLE_SPRING, PLAUSIBLE_ARMATURE, PLAUSIBLE_REST = 0.06, 0.009, 0.5
#: ... and the largest bend (rad) of a forearm whose weight lies off its line (the first moments
#: ahead and behind, :data:`shared.estimation.body.LINK_EXTENSIONS`): a right angle, the most the
#: class can hold (bent further, the forearm's first moment along its line turns negative, and every
#: parameter is >= 0). It was 45 degrees (set once, knowing the fused kind's 20-70); widened after the
#: report showed fused others bent 51-68 degrees identified wrong without noise, checked on seed 13's
#: in-model and development kinds (328 of 330 against 327, 2 % more questions): docs/chapter3.md
PLAUSIBLE_BEND = np.pi / 2


def plausible_bodies(joints, n: int, seed: int = 0) -> np.ndarray:
    """``n`` bodies (rows of theta) the self thinks possible before any answer: each moving
    link's mass ``exp(N(0, 0.5))`` and length ``exp(N(0, 0.2))`` times its own (gravity part
    mass x length, inertial part mass x length^2, a longer upper arm carrying the forearm
    further out: the elbow point mass), and, each with probability 1/2, a payload in the hand
    (exponential, mean 0.1 kg), damping (mean 0.03 N m s/rad) and friction (mean 0.02 N m) at
    every joint, and the extended model class (:data:`shared.estimation.body.EXTENSIONS`):
    springs at every joint (exponential stiffness, mean ``PLAUSIBLE_SPRING``, each with a rest
    angle uniform within ``PLAUSIBLE_REST`` of the self's) and rotor inertia (mean
    ``PLAUSIBLE_ARMATURE``), and with probability 1/2 a forearm bent off its line by up to
    ``PLAUSIBLE_BEND`` (its first moment turned ahead or behind, its mass at the elbow kept; drawn
    from a second stream, so the bodies' other draws are those of before). The first row is the
    self. The overall scale does not matter to comparisons."""
    from shared.bodies.robot import LINK_SHARE
    from shared.estimation.body import LINKS, SELF_MASS, bend_forearm, column_names, theta_self

    names = column_names(joints, offsets=True)
    r = np.random.default_rng(seed)
    bends = np.random.default_rng([seed, 1])
    out = np.zeros((n, len(names)))
    own = theta_self(joints)  # the self has no first moment off its links' lines: its columns are a prefix
    out[0, :len(own)] = own
    col = {name: k for k, name in enumerate(names)}
    for i in range(1, n):
        mass = {link: float(np.exp(r.normal(0.0, 0.5))) for link in LINKS}
        length = {link: float(np.exp(r.normal(0.0, 0.2))) for link in LINKS}
        for link in LINKS:
            if f"{link}.gravity" in col:
                out[i, col[f"{link}.gravity"]] = mass[link] * length[link]
                out[i, col[f"{link}.inertial"]] = mass[link] * length[link] ** 2
        if "elbow_mass" in col:  # the forearm's mass carried (length - 1) upper arms further out, about
            forearm_kg = mass["forearm"] * LINK_SHARE["forearm"] * SELF_MASS
            out[i, col["elbow_mass"]] = max(length["upper_arm"] - 1.0, 0.0) * forearm_kg
        if "hand_mass" in col and r.random() < 0.5:
            out[i, col["hand_mass"]] = r.exponential(0.1)
        for kind, mean in (("damping", 0.03), ("friction", 0.02)):
            if r.random() < 0.5:
                for j in joints:
                    out[i, col[f"{kind}.{j}"]] = r.exponential(mean)
        if r.random() < 0.5:  # springs, k (q - q0) = k q - k q0: the rest angle's torque on rest_up or rest_down
            for j in joints:
                k, q0 = r.exponential(PLAUSIBLE_SPRING), r.uniform(-PLAUSIBLE_REST, PLAUSIBLE_REST)
                out[i, col[f"spring.{j}"]] = k
                out[i, col[f"rest_down.{j}" if q0 > 0 else f"rest_up.{j}"]] = k * abs(q0)
        if r.random() < 0.5:
            for j in joints:
                out[i, col[f"armature.{j}"]] = r.exponential(PLAUSIBLE_ARMATURE)
        if "ahead.forearm" in col and bends.random() < 0.5:
            bend_forearm(out[i], col, bends.uniform(-PLAUSIBLE_BEND, PLAUSIBLE_BEND), mass["forearm"])
    return out


@lru_cache(maxsize=16)
def _plausible(joints: tuple[str, ...], n: int) -> np.ndarray:
    """:func:`plausible_bodies` of a joint set, drawn once per process (the same seed: the same
    bodies; 1,024 of them take a quarter of a second of Python, asked for by every identification
    without open answers)."""
    out = plausible_bodies(list(joints), n)
    out.flags.writeable = False
    return out


def candidate_bodies(language, shared: list[np.ndarray], answers: list[tuple[str, np.ndarray, int]],
                     candidates: list[Candidate], scale: float = 1.0, n: int = BODY_SAMPLES) -> dict[str, np.ndarray]:
    """Per candidate rule, the bodies the other's open answers allow if it converts with that
    rule: a :class:`shared.estimation.body.BodyEstimate` fitted to ``answers`` (key, regressor,
    k) in ``language`` with the candidate's rule, and :func:`body_samples` of what it leaves
    uncertain. Without answers every candidate gets the same bodies, those the self thinks
    possible (:func:`plausible_bodies`). Either are in the columns of regressors with ``offsets``
    (:func:`shared.estimation.body.self_regressor`)."""
    from dataclasses import replace

    from shared.estimation.body import BodyEstimate, column_names

    if not answers:  # nothing known of this other yet: the bodies the self thinks possible, for every rule
        prior = _plausible(tuple(language.joints), n).copy()
        return {c.name: prior for c in candidates}
    out = {}
    wide = len(column_names(language.joints, offsets=True))  # the prior's columns, first moments off the lines too
    for c in candidates:
        lang = replace(language, rule=c.rule, weights=None if c.weights is None else list(c.weights))
        b = BodyEstimate(lang, shared)
        b.start(scale)
        for key, y, k in answers:
            b.add(key, y, k)
        b.fit()
        samples = body_samples(b.theta, b.covariance(), n, seed=0)  # none off the lines: zeros there
        out[c.name] = np.pad(samples, ((0, 0), (0, wide - samples.shape[1])))
    return out
