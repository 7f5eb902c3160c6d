"""A simulated *other* (thesis ch. 3): a body of its own, a hidden way of turning torques into
a feeling, and words for it.

The other performs a motion on its own MuJoCo body (:func:`shared.bodies.body.perform`), takes
the torques of its ``joints`` and

* answers an **open question** ("how heavy did that feel?") with a word of Table 3.1:
  ``k = F_div(F_conv(S))`` with its hidden rule, ``tau_max``, ``g_max`` and density ``d``;
  with answer noise ``p``, an answer is one bin off (up or down, at random) with probability ``p``;
* for robustness tests it can misbehave (``behaviour``): answer ``nonsense``, ``contradict``
  itself (a random word each time), or stay ``silent`` (the simulator never answers for it);
* may answer **like a person**: with its own word boundaries (it words ``g`` as
  ``g_max (g / g_max)^gamma``), drifting over the conversation (``drift`` per question asked),
  and "I don't know" with probability ``dont_know``;
* answers a **comparative question** about two motions with ``'>'``, ``'<'`` or ``'equal'``
  (eq. 3.11-3.12), equal within its just-noticeable difference ``jnd``.

Its parameters are hidden: only :meth:`SimulatedOther.reveal` shows them, for evaluation.
Every random draw comes from ``default_rng([seed, question number])``, so a conversation
replays identically.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from shared.bodies.body import perform
from shared.bodies.robot import JOINTS, BodySpec, small_humanoid
from shared.errors import BadInput
from shared.estimation.symbols import RULES, WORDS, compare, f_conv, f_div, word
from shared.motion.clip import Clip
from shared.once import Once

ARM = ["shoulder_pitch", "shoulder_roll", "elbow"]
BEHAVIOURS = ("honest", "nonsense", "contradict", "silent")


@dataclass
class OtherParams:
    """The hidden parameters of a simulated other (defaults: the thesis's R_2)."""

    mass: float = 4.8
    rule: str = "eq3.8"
    weights: list[float] | None = None
    d: int = 4
    tau_max: float = 1.0
    g_max: float = 1.0
    joints: list[str] = field(default_factory=lambda: list(ARM))
    noise: float = 0.0
    jnd: float = 0.05
    seed: int = 0
    behaviour: str = "honest"  # fault injection for robustness tests: honest | nonsense | contradict | silent
    body: dict | None = None  # how its body differs unevenly (BodySpec fields but mass), None: even
    kind: str = ""  # the population kind it was drawn from (shared.agents.population), for reports
    # how its torques become what it feels, beyond a rigid body (None: the torques themselves):
    # gear {joint: ratio}, efficiency (0-1], coupling {"src>dst": c}, stribeck {joint: [F_c, F_s, v_s]}, fatigue,
    # drag {joint: c} (c qd |qd|), bias {joint: N m}
    transmission: dict | None = None
    # answers like people's: its own word boundaries g' = g_max (g / g_max)^gamma, drifting by
    # `drift` per question (g' times 1 + drift * asked), and "I don't know" with probability dont_know
    gamma: float = 1.0
    drift: float = 0.0
    dont_know: float = 0.0

    def body_spec(self) -> BodySpec:
        extra = dict(self.body or {})
        if "mass" in extra:
            raise BadInput("give the other's mass as params.mass, not in params.body", field="body")
        try:
            return BodySpec(mass=self.mass, **extra).check()
        except TypeError as e:
            raise BadInput(f"bad body description: {e}", field="body") from None

    def check(self) -> OtherParams:
        if self.rule not in RULES:
            raise BadInput(f"unknown conversion rule {self.rule!r}; one of {', '.join(RULES)}", field="rule")
        if self.d not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {self.d}", field="d")
        unknown = [j for j in self.joints if j not in JOINTS]
        if unknown or not self.joints:
            raise BadInput(f"joints must be among {', '.join(JOINTS)}, got {self.joints}", field="joints")
        lacking = [j for j in self.joints if j in self.body_spec().welded]
        if lacking:
            raise BadInput(f"the other cannot feel joints its body lacks: {lacking}", field="joints")
        check_transmission(self.transmission)
        if self.behaviour not in BEHAVIOURS:
            raise BadInput(f"behaviour must be one of {', '.join(BEHAVIOURS)}, got {self.behaviour!r}", field="behaviour")
        if self.weights is not None and len(self.weights) != len(self.joints):
            raise BadInput(f"need one weight per joint ({len(self.joints)}), got {len(self.weights)}", field="weights")
        for name, v, lo, hi in (("noise", self.noise, 0.0, 1.0), ("jnd", self.jnd, 0.0, 1.0),
                                ("gamma", self.gamma, 0.25, 4.0), ("drift", self.drift, -0.05, 0.05),
                                ("dont_know", self.dont_know, 0.0, 1.0),
                                ("tau_max", self.tau_max, 1e-6, 1e6), ("g_max", self.g_max, 1e-6, 1e6)):
            if not (np.isfinite(v) and lo <= v <= hi):
                raise BadInput(f"{name} must be in [{lo}, {hi}], got {v}", field=name)
        return self


TRANSMISSION_KEYS = ("gear", "efficiency", "coupling", "stribeck", "fatigue", "drag", "bias")


def check_transmission(t: dict | None) -> None:
    if t is None:
        return
    if not isinstance(t, dict) or not set(t) <= set(TRANSMISSION_KEYS):
        raise BadInput(f"transmission must be a map of {', '.join(TRANSMISSION_KEYS)}", field="transmission")
    for j, v in (t.get("gear") or {}).items():
        if j not in JOINTS or not (isinstance(v, (int, float)) and 0.05 <= v <= 20):
            raise BadInput(f"transmission gear[{j}] must be a joint's ratio in [0.05, 20], got {v!r}", field="transmission")
    eff = t.get("efficiency", 1.0)
    if not (isinstance(eff, (int, float)) and 0.2 <= eff <= 1.0):
        raise BadInput(f"transmission efficiency must be in [0.2, 1], got {eff!r}", field="transmission")
    for key, c in (t.get("coupling") or {}).items():
        src, _, dst = key.partition(">")
        if src not in JOINTS or dst not in JOINTS or src == dst or not (isinstance(c, (int, float)) and -2 <= c <= 2):
            raise BadInput(f"transmission coupling {key!r}: 'joint>joint' with a factor in [-2, 2]", field="transmission")
    for j, v in (t.get("stribeck") or {}).items():
        if j not in JOINTS or not (isinstance(v, (list, tuple)) and len(v) == 3 and all(
                isinstance(x, (int, float)) and 0 <= x <= 100 for x in v) and v[2] > 0):
            raise BadInput(f"transmission stribeck[{j}] must be [F_c, F_s, v_s] (N m, N m, rad/s > 0)",
                           field="transmission")
    for key, lo, hi in (("drag", 0.0, 1.0), ("bias", -1.0, 1.0)):
        for j, v in (t.get(key) or {}).items():
            if not (isinstance(v, (int, float)) and lo <= v <= hi):
                raise BadInput(f"transmission {key}[{j}] must be in [{lo}, {hi}], got {v!r}", field="transmission")
    f = t.get("fatigue", 0.0)
    if not (isinstance(f, (int, float)) and 0 <= f <= 1):
        raise BadInput(f"transmission fatigue must be in [0, 1] per question, got {f!r}", field="transmission")


def transmitted(tau: np.ndarray, motion: Clip, joints, t: dict | None, asked: int = 0) -> np.ndarray:
    """What an other feels of its joint torques ``tau`` (T x joints) through a transmission (none of it is in the body
    estimator's model):

    * ``stribeck``: friction ``(F_c + (F_s - F_c) exp(-(qd / v_s)^2)) tanh(qd / 0.05)`` added
      (static friction above the sliding one near rest; the estimator's is Coulomb's alone);
    * ``gear``: each joint's torque felt times its ratio, and ``efficiency`` eta: driving
      (``tau qd > 0``) the motor feels ``tau / eta``, back-driven ``tau eta``;
    * ``coupling`` ``{"src>dst": c}``: a tendon-like share of joint src's torque felt at dst;
    * ``fatigue``: everything felt ``(1 + fatigue * asked)`` times as heavy after ``asked`` questions;
    * ``drag`` ``{joint: c}``: quadratic drag ``c qd |qd|`` added; ``bias`` ``{joint: b}``: a
      constant ``b`` N m added (a counterweight set wrong).
    """
    if not t:
        return tau
    out = np.array(tau, float)
    names = list(joints)
    if t.get("stribeck") or t.get("drag") or t.get("efficiency", 1.0) < 1.0:
        qd = np.column_stack([np.gradient(np.radians(motion.column(j)), 1.0 / motion.fps) if j in motion.channels
                              else np.zeros(len(out)) for j in names])
        for j, (fc, fs, vs) in (t.get("stribeck") or {}).items():
            if j in names:
                v = qd[:, names.index(j)]
                out[:, names.index(j)] += (fc + (fs - fc) * np.exp(-(v / vs) ** 2)) * np.tanh(v / 0.05)
        for j, c in (t.get("drag") or {}).items():
            if j in names:
                v = qd[:, names.index(j)]
                out[:, names.index(j)] += c * v * np.abs(v)
        eta = float(t.get("efficiency", 1.0))
        out = np.where(out * qd > 0, out / eta, out * eta)
    for j, b in (t.get("bias") or {}).items():
        if j in names:
            out[:, names.index(j)] += b
    for j, ratio in (t.get("gear") or {}).items():
        if j in names:
            out[:, names.index(j)] *= ratio
    felt = out.copy()
    for key, c in (t.get("coupling") or {}).items():
        src, _, dst = key.partition(">")
        if src in names and dst in names:
            felt[:, names.index(dst)] += c * out[:, names.index(src)]
    return felt * (1.0 + float(t.get("fatigue", 0.0)) * asked)


KEPT_MOTIONS = 1024  # (body, joints, motion) whose torques the process keeps (_PERFORMED)
KEPT_BYTES = 64 << 20  # and at most this many bytes of them (a motion's over 4 MB answered, not kept)


#: (body, joints, motion) -> the body's torques: a body never changes, rule identification asks about
#: pairs of the same 20 motions again and again (two inverse dynamics a question before), and others of
#: the same body (the same population with another answer noise or rule) share them
_PERFORMED = Once(KEPT_MOTIONS, KEPT_BYTES)


class SimulatedOther:
    """An other agent with hidden parameters (see module docstring)."""

    def __init__(self, name: str, params: OtherParams | None = None, asked: int = 0):
        self.name = name
        self.params = (params or OtherParams()).check()
        self.asked = asked
        self._body: Any = None  # built at its first perform (its torques may all be kept already)
        # what the body is: the key of its kept torques
        self._body_key = json.dumps([self.params.mass, self.params.body], sort_keys=True, default=str)

    @property
    def body(self):
        if self._body is None:
            self._body = small_humanoid(self.params.body_spec(), name=f"other:{self.name}")
        return self._body

    def feel(self, motion: Clip) -> np.ndarray:
        """The torques (T x joints) this other's body produces performing ``motion``, as it
        feels them (:func:`transmitted`, after ``asked`` questions so far)."""
        return transmitted(self._torques(motion), motion, self.params.joints, self.params.transmission, self.asked)

    def _torques(self, motion: Clip) -> np.ndarray:
        """The body's torques of ``motion``, kept (``_PERFORMED``); a copy: what a caller does to
        it changes nothing kept."""
        joints = tuple(self.params.joints)

        def compute():
            performed, _ = perform(self.body, motion)
            return performed.select([f"tau.{j}" for j in joints])

        return _PERFORMED.once((self._body_key, joints, motion.fingerprint()), compute).copy()

    def g(self, motion: Clip) -> float:
        p = self.params
        return f_conv(self.feel(motion), p.rule, p.tau_max, p.weights)

    def _rng(self):
        self.asked += 1
        return np.random.default_rng([self.params.seed, self.asked])

    def answer_open(self, motion: Clip) -> str:
        """A word of Table 3.1 for how heavy ``motion`` felt."""
        p = self.params
        g = self.g(motion)
        if p.gamma != 1.0 or p.drift:  # its own word boundaries, drifting (answers like people's)
            g = p.g_max * (max(g, 0.0) / p.g_max) ** p.gamma * (1.0 + p.drift * self.asked)
        k = f_div(g, p.d, p.g_max)
        rng = self._rng()
        if p.behaviour == "nonsense":
            return str(rng.choice(["purple", "banana", "42", "the moon"]))
        if p.dont_know > 0 and rng.random() < p.dont_know:
            return "I don't know"
        if p.behaviour == "contradict":  # a random word each time: its answers cannot all be true
            return word(int(rng.integers(1, p.d + 1)), p.d)
        if p.noise > 0 and rng.random() < p.noise:
            k = int(np.clip(k + rng.choice([-1, 1]), 1, p.d))
        return word(k, p.d)

    def answer_compare(self, first: Clip, second: Clip) -> str:
        """Which felt heavier: ``'>'`` (the first), ``'<'`` (the second) or ``'equal'``."""
        p = self.params
        ans = compare(self.g(first), self.g(second), p.jnd)
        rng = self._rng()
        if p.behaviour == "nonsense":
            return "maybe"
        if p.behaviour == "contradict":
            return str(rng.choice([">", "<", "equal"]))
        if p.noise > 0 and rng.random() < p.noise:
            ans = str(rng.choice([a for a in (">", "<", "equal") if a != ans]))
        return ans

    def reveal(self) -> dict:
        """The hidden parameters, for evaluation only."""
        return {"name": self.name, "asked": self.asked, **asdict(self.params)}

    def to_dict(self) -> dict:
        return {"name": self.name, "asked": self.asked, "params": asdict(self.params)}

    @classmethod
    def from_dict(cls, d: dict) -> SimulatedOther:
        return cls(d["name"], OtherParams(**d["params"]), asked=int(d.get("asked", 0)))
