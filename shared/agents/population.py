"""A population of simulated others whose bodies differ as real bodies do.

The thesis's other is the self scaled in mass (thesis 3.3.3), so every torque is exactly a
multiple of the self's; it says so itself (3.3.5, 3.4.4) and leaves uneven bodies open (7.2).
Every other here has its own mass (uniform 3.0-7.2 kg) and, by ``kind``:

==========  =====================================================================================
mass        nothing else: the thesis's proportional other (the reference)
links       upper arm and forearm 1.15-1.5x as long
payload     0.05-0.3 kg held in the right hand
shares      upper arm and forearm each carry 0.6-1.6x their usual share of the mass
damping     viscous damping 0.02-0.08 N m s/rad at every arm joint and the knee
friction    Coulomb friction 0.01-0.05 N m at every arm joint and the knee
joints      no shoulder roll (the self imitates it by not using its own, thesis 3.3.5), arm links
            0.9-1.2x as long
legs        the shin carries 1.5-2.5x its share, and is 1.0-1.4x as long
mixed       links, payload, shares, damping and friction at once
==========  =====================================================================================

**Outside the estimator's model** (:data:`OUTSIDE_KINDS`): bodies and transmissions the
body estimator's rigid-body regressor has no column for. They are reported, never tuned on: the
estimator's settings were chosen on the kinds above only. Joint springs and rotor inertia have
columns in its extended model class (:data:`shared.estimation.body.EXTENSIONS`, fit only when
the answers call for it, chosen on the kinds above and the development kinds), and stay outside
the thesis's and the space estimator's model.

==========  =====================================================================================
springs     a joint spring at every felt joint, 0.05-0.3 N m/rad, rest angle -30..30 degrees
armature    rotor inertia 0.005-0.03 kg m^2 at every felt joint
gears       each joint's torque felt through a gear of ratio 0.6-1.6, efficiency 0.6-0.9 (driving
            feels tau / eta, back-driven tau eta)
coupling    tendon-like: 0.2-0.6 of the elbow's torque felt at the shoulder pitch, 0.1-0.3 back
stribeck    Stribeck friction: sliding 0.01-0.05 N m, static 1.5-3x that, Stribeck speed 0.05-0.3 rad/s
fatigue     everything felt 0.5-2 % heavier per question asked so far (strength falling)
fused       another joint layout: the elbow fused, bent at 20-70 degrees (the self sees that the
            elbow does not move and imitates it by holding its own at 0, as for a missing joint;
            the bend it cannot write down), the conversation about the shoulder
==========  =====================================================================================

**Development kinds** (:data:`DEVELOPMENT_KINDS`), outside the model as well, on which what
handles a body outside the model (the residual correction, :mod:`shared.estimation.correction`)
was chosen, so that the kinds above stay unseen: ``drag`` (quadratic drag 0.005-0.03 N m s^2/rad^2
at every joint) and ``bias`` (a constant -0.05..0.05 N m at every joint).

Each draw comes from ``default_rng([seed, kind index, i])``: the population replays exactly. The
body estimator's settings were chosen on the population of seed 13; reports use seed 2026.
"""

from __future__ import annotations

import numpy as np

from shared.errors import BadInput

KINDS = ("mass", "links", "payload", "shares", "damping", "friction", "joints", "legs", "mixed")
#: kinds outside the body estimator's model (module docstring): reported, never tuned on
OUTSIDE_KINDS = ("springs", "armature", "gears", "coupling", "stribeck", "fatigue", "fused")
#: kinds outside the model too, kept for choosing what handles a body outside the model (the
#: residual correction's design): never reported as the outside population's result
DEVELOPMENT_KINDS = ("drag", "bias")
ALL_KINDS = KINDS + OUTSIDE_KINDS + DEVELOPMENT_KINDS
#: each kind's place in the draws' seed: the order the kinds were added in, so that a new kind
#: leaves every other kind's others as they were
_DRAW_ORDER = KINDS + OUTSIDE_KINDS[:-1] + DEVELOPMENT_KINDS + ("fused",)
ARM = ("shoulder_pitch", "shoulder_roll", "elbow")
ALL = ARM + ("knee",)


def _body(kind: str, r: np.random.Generator) -> dict:
    body: dict = {}
    if kind in ("links", "mixed"):
        body["lengths"] = {"upper": 0.10 * r.uniform(1.15, 1.5), "fore": 0.10 * r.uniform(1.15, 1.5)}
    if kind in ("payload", "mixed"):
        body["payload"] = float(r.uniform(0.05, 0.3))
    if kind in ("shares", "mixed"):
        body["shares"] = {"upper_arm": 0.07 * r.uniform(0.6, 1.6), "forearm": 0.06 * r.uniform(0.6, 1.6)}
    if kind in ("damping", "mixed"):
        body["damping"] = {j: float(r.uniform(0.02, 0.08)) for j in ALL}
    if kind in ("friction", "mixed"):
        body["friction"] = {j: float(r.uniform(0.01, 0.05)) for j in ALL}
    if kind == "joints":
        body["missing"] = ["shoulder_roll"]
        body["lengths"] = {"upper": 0.10 * r.uniform(0.9, 1.2), "fore": 0.10 * r.uniform(0.9, 1.2)}
    if kind == "legs":
        body["shares"] = {"shin": 0.10 * r.uniform(1.5, 2.5)}
        body["lengths"] = {"shin": 0.11 * r.uniform(1.0, 1.4)}
    if kind == "springs":
        body["stiffness"] = {j: float(r.uniform(0.05, 0.3)) for j in ALL}
        body["rest"] = {j: float(r.uniform(-30.0, 30.0)) for j in ALL}
    if kind == "armature":
        body["armature"] = {j: float(r.uniform(0.005, 0.03)) for j in ALL}
    if kind == "fused":
        body["fused"] = {"elbow": float(-r.uniform(20.0, 70.0))}
    for group in ("lengths", "shares"):
        if group in body:
            body[group] = {k: float(v) for k, v in body[group].items()}
    return body


def _transmission(kind: str, r: np.random.Generator) -> dict | None:
    if kind == "gears":
        return {"gear": {j: float(r.uniform(0.6, 1.6)) for j in ALL}, "efficiency": float(r.uniform(0.6, 0.9))}
    if kind == "coupling":
        return {"coupling": {"elbow>shoulder_pitch": float(r.uniform(0.2, 0.6)),
                             "shoulder_pitch>elbow": float(r.uniform(0.1, 0.3))}}
    if kind == "stribeck":
        out = {}
        for j in ALL:
            fc = float(r.uniform(0.01, 0.05))
            out[j] = [fc, fc * float(r.uniform(1.5, 3.0)), float(r.uniform(0.05, 0.3))]
        return {"stribeck": out}
    if kind == "fatigue":
        return {"fatigue": float(r.uniform(0.005, 0.02))}
    if kind == "drag":
        return {"drag": {j: float(r.uniform(0.005, 0.03)) for j in ALL}}
    if kind == "bias":
        return {"bias": {j: float(r.uniform(-0.05, 0.05)) for j in ALL}}
    return None


#: answers like people's (:func:`people_answers`)
PEOPLE = {"gamma": (0.7, 1.4), "drift": (-0.005, 0.005), "noise": (0.1, 0.3), "dont_know": (0.05, 0.15)}


def people_answers(n: int, seed: int = 2026) -> list[dict]:
    """``n`` ways of answering like people (``OtherParams`` fields), drawn per other: own word
    boundaries ``gamma`` U(0.7, 1.4) (the same g worded ``g_max (g / g_max)^gamma``), drifting by
    U(-0.5, 0.5) % per question, 10-30 % of answers one word off, 5-15 % "I don't know"."""
    out = []
    for i in range(n):
        r = np.random.default_rng([seed, 99, i])
        out.append({k: float(r.uniform(lo, hi)) for k, (lo, hi) in PEOPLE.items()})
    return out


def seen_still(other: dict) -> list[str]:
    """The joints an other's body does not move (missing or fused): the self sees that and imitates
    it by holding its own at 0 (thesis 3.3.5); the angle a fused joint is bent at it does not know."""
    body = other.get("body") or {}  # BodySpec.welded's rule on the dict: drawing others does not load MuJoCo
    return list(body.get("missing", [])) + [j for j in body.get("fused", {}) if j not in body.get("missing", [])]


def population(kind: str, n: int = 10, seed: int = 2026, **params) -> list[dict]:
    """``n`` others' parameters (``OtherParams`` fields) of one ``kind``; ``params`` (rule, d,
    g_max, noise, ...) are the same for all of them."""
    if kind not in ALL_KINDS:
        raise BadInput(f"unknown population kind {kind!r}; one of {', '.join(ALL_KINDS)}", field="kind")
    if not 1 <= n <= 1000:
        raise BadInput(f"a population has 1 to 1000 others, got {n}", field="n")
    out = []
    for i in range(n):
        r = np.random.default_rng([seed, _DRAW_ORDER.index(kind), i])
        mass = float(r.uniform(3.0, 7.2))
        body = _body(kind, r)
        joints = [j for j in params.get("joints", ARM) if j not in seen_still({"body": body})]
        t = _transmission(kind, r)
        out.append({**params, "mass": mass, "body": body, "kind": kind, "joints": joints,
                    "seed": int(params.get("seed", 0)) + i, **({"transmission": t} if t else {})})
    return out


def people_population(kind: str, n: int = 10, seed: int = 2026, **params) -> list[dict]:
    """:func:`population` answering like people (:func:`people_answers`, drawn from the same
    ``seed``), each other's answers seeded apart from the population's plain others (``seed + 500``)."""
    return [{**p, **a, "seed": p["seed"] + 500}
            for p, a in zip(population(kind, n, seed, **params), people_answers(n, seed))]
