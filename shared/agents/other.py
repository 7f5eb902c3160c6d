"""A simulated *other* (thesis ch. 3): a body of its own, a hidden way of turning torques into
a feeling, and words for it.

The other performs a motion on its own MuJoCo body (:func:`shared.bodies.body.perform`), takes
the torques of its ``joints`` and

* answers an **open question** ("how heavy did that feel?") with a word of Table 3.1:
  ``k = F_div(F_conv(S))`` with its hidden rule, ``tau_max``, ``g_max`` and density ``d``;
  with answer noise ``p``, an answer is one bin off (up or down, at random) with probability ``p``;
* for robustness tests it can misbehave (``behaviour``): answer ``nonsense``, ``contradict``
  itself (a random word each time), or stay ``silent`` (the simulator never answers for it);
* answers a **comparative question** about two motions with ``'>'``, ``'<'`` or ``'equal'``
  (eq. 3.11-3.12), equal within its just-noticeable difference ``jnd``.

Its parameters are hidden: only :meth:`SimulatedOther.reveal` shows them, for evaluation.
Every random draw comes from ``default_rng([seed, question number])``, so a conversation
replays identically.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from shared.bodies.body import perform
from shared.bodies.robot import JOINTS, BodySpec, small_humanoid
from shared.clip import Clip
from shared.errors import BadInput
from shared.symbols import RULES, WORDS, compare, f_conv, f_div, word

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
    body: dict | None = None  # how its body differs unevenly (BodySpec fields but mass; issue 13), None: even
    kind: str = ""  # the population kind it was drawn from (shared.agents.population), for reports

    def body_spec(self) -> BodySpec:
        extra = dict(self.body or {})
        if "mass" in extra:
            raise BadInput("give the other's mass as params.mass, not in params.body", field="body")
        try:
            return BodySpec(mass=self.mass, **extra).check()
        except TypeError as e:
            raise BadInput(f"bad body description: {e}", field="body") from None

    def check(self) -> "OtherParams":
        if self.rule not in RULES:
            raise BadInput(f"unknown conversion rule {self.rule!r}; one of {', '.join(RULES)}", field="rule")
        if self.d not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {self.d}", field="d")
        unknown = [j for j in self.joints if j not in JOINTS]
        if unknown or not self.joints:
            raise BadInput(f"joints must be among {', '.join(JOINTS)}, got {self.joints}", field="joints")
        lacking = [j for j in self.joints if j in self.body_spec().missing]
        if lacking:
            raise BadInput(f"the other cannot feel joints its body lacks: {lacking}", field="joints")
        if self.behaviour not in BEHAVIOURS:
            raise BadInput(f"behaviour must be one of {', '.join(BEHAVIOURS)}, got {self.behaviour!r}", field="behaviour")
        if self.weights is not None and len(self.weights) != len(self.joints):
            raise BadInput(f"need one weight per joint ({len(self.joints)}), got {len(self.weights)}", field="weights")
        for name, v, lo, hi in (("noise", self.noise, 0.0, 1.0), ("jnd", self.jnd, 0.0, 1.0),
                                ("tau_max", self.tau_max, 1e-6, 1e6), ("g_max", self.g_max, 1e-6, 1e6)):
            if not (np.isfinite(v) and lo <= v <= hi):
                raise BadInput(f"{name} must be in [{lo}, {hi}], got {v}", field=name)
        return self


class SimulatedOther:
    """An other agent with hidden parameters (see module docstring)."""

    def __init__(self, name: str, params: OtherParams | None = None, asked: int = 0):
        self.name = name
        self.params = (params or OtherParams()).check()
        self.body = small_humanoid(self.params.body_spec(), name=f"other:{name}")
        self.asked = asked

    def feel(self, motion: Clip) -> np.ndarray:
        """The torques (T x joints) this other's body produces performing ``motion``."""
        performed, _ = perform(self.body, motion)
        return performed.select([f"tau.{j}" for j in self.params.joints])

    def g(self, motion: Clip) -> float:
        p = self.params
        return f_conv(self.feel(motion), p.rule, p.tau_max, p.weights)

    def _rng(self):
        self.asked += 1
        return np.random.default_rng([self.params.seed, self.asked])

    def answer_open(self, motion: Clip) -> str:
        """A word of Table 3.1 for how heavy ``motion`` felt."""
        p = self.params
        k = f_div(self.g(motion), p.d, p.g_max)
        rng = self._rng()
        if p.behaviour == "nonsense":
            return str(rng.choice(["purple", "I don't know", "banana", "42"]))
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
    def from_dict(cls, d: dict) -> "SimulatedOther":
        return cls(d["name"], OtherParams(**d["params"]), asked=int(d.get("asked", 0)))
