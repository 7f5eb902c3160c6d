"""Simulated learners (thesis ch. 4-6, SPEC section 6). **A simulation, not a person.**

The thesis coached people. We coach simulated learners whose behaviour is a small, documented
model; nothing below is fitted to human data. A learner belongs to one of five **families**
(:data:`FAMILIES`), so that a finding of chapters 4-6 can be checked in learner worlds that do
not assume it, two of them null worlds in which no demonstration can beat the target itself:

* ``thesis``: the model described below (perception threshold, gain below 1, overshoot measured
  against the first motion shown). It was built so that emphasis can help: a gain below 1 or a
  threshold alone makes a demonstration beyond the target move the learner further.
* ``error_based``: error-based adaptation with a state-space model from the motor-learning
  literature (Thoroughman & Shadmehr 2000; Smith, Ghazizadeh & Shadmehr 2006, one rate):
  ``m <- m0 + A (m - m0) + B_eff P(D - p)`` where ``p`` is the learner's own last performance
  (what it did, motor noise included; its memory before the first attempt), ``A`` the
  *retention* (drift back to its habit ``m0``) and ``B_eff = clip(gain * a_r(adverb), 0, 1)``
  the error sensitivity, with ``a_r = 1 + r (A_adverb - 1)`` and ``r`` the learner's
  *adverb response*, drawn in [-1.5, 1.5]: a word may make this learner take up more of the
  error (r > 0) or less (r < 0; "much more" then hurts). It never knows the target, nor which
  motion was the target: it corrects towards whatever it is shown;
* ``two_rate``: the two-state model of Smith, Ghazizadeh & Shadmehr (2006, PLoS Biology 4(6)
  e179, "Interacting adaptive processes with different timescales underlie short-term motor
  learning") with the parameters of their simulations, the same for every learner:
  ``x_f <- A_f x_f + B_f e``, ``x_s <- A_s x_s + B_s e``, ``m = m0 + x_f + x_s``, with
  ``A_f = 0.59, B_f = 0.21, A_s = 0.992, B_s = 0.02`` per trial (:data:`TWO_RATE`) and ``e``
  the perceived error ``P(D - p)`` as in ``error_based``. Words are ignored: the model has none;
* ``copy`` (null model): the memory becomes the demonstration exactly, with no threshold and
  words ignored. Whatever is shown is what it does next, so an emphatic motion can only leave it
  further from the target than the target itself would;
* ``fixed_step`` (null model, blind to the size of the difference shown): it moves a fixed
  ``step`` (degrees RMS over the imitated channels) in the direction of ``D - m`` (every
  channel, no perception threshold: a threshold per channel would let a larger difference
  change which channels move, and so the direction), or all the way when the difference is
  shorter, words ignored. Showing ``m + k (D - m)`` for any ``k >= 1`` moves it exactly as
  ``D`` does while the step is the shorter; the best direction to step in is towards the
  target, so no demonstration brings it closer than the target itself, and near the target an
  emphatic motion makes it step past.

Every family shares the personal deviation, perception threshold (not ``copy`` nor ``fixed_step``), motor noise,
tempo and attempts below; the ``thesis`` family's rules follow.

State. A learner holds its *motor memory* ``m``: its current version of the target motion,
as joint-angle trajectories of the target's motion channels on a normalised time axis of
``N_PHASE`` samples. The body's orientation in the room (the root's rotation channels) is not
imitated: it follows the target. It starts at the target plus a *personal deviation*: on one or two body
parts (arms, legs, trunk) it moves with a reduced amplitude ``s`` (0.5-0.8 of the target's
range about its mean) and a constant offset ``o`` (up to 8 degrees).

Imitation. Shown a demonstration ``D`` (any clip with the target's channels, resampled to the
phase axis) with an adverb, the learner updates ``m <- m + gamma_eff * P(D - m)`` where

* ``P`` is perception: per channel, a difference whose RMS is below the *perception
  threshold* ``tau`` degrees is not noticed, larger ones are shrunk by ``tau`` (soft threshold).
  This is why showing the target again helps little once the error is small;
* ``gamma_eff = min(gamma * a(adverb) * (1 + o_s * x), 1)`` with ``gamma`` the *learning gain*,
  ``a`` the adverb factor (``1 + sens * (A - 1)``, ``A`` = 1.10 / 1.20 / 1.35 for "a little
  more" / "more" / "much more"; "more like this" counts as "more"; ``sens`` the learner's
  sensitivity to words) and the *overshoot* term: ``x`` is how exaggerated the
  demonstration looks, the RMS of ``D - R`` over the RMS of ``R - m``, with ``R`` the first
  motion the learner was shown (taken to be the target; so ``x`` is about ``alpha`` for an
  emphatic motion ``x_t + alpha (x_t - x_p)``, 0 for the target, at most 5), and ``o_s`` the
  learner's overshoot susceptibility. A moderately emphasised demonstration therefore moves
  the learner further than the target alone; a strongly emphasised one makes it overshoot
  past the target, and the error grows again.

Attempts. Each trial returns 5 repetitions: the memory played at the learner's tempo
(duration factor ``tempo``) plus smooth motor noise on the joint angles (Gaussian, ``sigma`` degrees, low-passed
over ~0.2 s), at the target's frame rate.

Strength (any family; thesis 6.5.1). A learner may have a body of limited ``strength``: the
effort (:func:`shared.coaching.effort.effort`, eq. 3.8 on the inverse-dynamics torques of a
body built from the target's skeleton) it can give, in multiples of the target's. It feels a
demonstration at ``g = E(D) / (E(target) strength)``; beyond its strength (``g > 1``) it takes in
only the part it can follow, ``m + (D - m) / g``, before its family's rule. After each
demonstration it can say how heavy it felt (:attr:`SimulatedLearner.felt`, a word of
:data:`shared.coaching.effort.LANGUAGE`). Without ``strength`` (the default) none of this applies.

Every learner is drawn from :func:`population` with a seed; its parameters are documented in
:class:`LearnerParams` and readable through :meth:`SimulatedLearner.reveal`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from shared.coaching.effort import performed_effort, word
from shared.coaching.parts import BODY_PARTS, body_part, to_phase
from shared.errors import BadInput
from shared.motion.clip import Clip, time_normalised

REPETITIONS = 5
#: the largest joint angle (degrees) or position a demonstration may hold
MAX_VALUE = 1e5


def _bounded(phase: np.ndarray, what: str) -> np.ndarray:
    """``phase`` if every value is within ``MAX_VALUE``: a 1e300 demonstration turned a
    learner's memory to infinities for good."""
    if not np.all(np.abs(phase) <= MAX_VALUE):
        raise BadInput(f"the {what} has values beyond {MAX_VALUE:g} (degrees or centimetres): not a motion a person "
                       "makes", field=what)
    return phase
#: the learner families (see the module docstring)
FAMILIES = ("thesis", "error_based", "two_rate", "copy", "fixed_step")
#: Smith, Ghazizadeh & Shadmehr (2006), the parameters of their simulations, per trial
TWO_RATE = {"A_f": 0.59, "B_f": 0.21, "A_s": 0.992, "B_s": 0.02}
ADVERB_FACTOR = {None: 1.0, "": 1.0, "a little more": 1.10, "more": 1.20, "much more": 1.35, "more like this": 1.20}
ADVERBS = tuple(a for a in ADVERB_FACTOR if a)

@dataclass
class LearnerParams:
    """A learner's hidden parameters (see the module docstring for their roles)."""

    gain: float = 0.3  # gamma: share of a perceived difference taken up per trial
    threshold: float = 3.0  # tau: perception threshold, degrees RMS per channel
    overshoot: float = 0.3  # o_s: susceptibility to exaggerated demonstrations
    noise: float = 1.0  # sigma: motor noise, degrees
    tempo: float = 1.0  # duration of the learner's attempts relative to the target
    adverb_sensitivity: float = 1.0  # sens
    deviation: dict = field(default_factory=lambda: {"legs": {"scale": 0.6, "offset": 0.0}})
    seed: int = 0
    family: str = "thesis"  # one of FAMILIES
    retention: float = 0.9  # A of the error_based family
    step: float = 4.0  # fixed_step: degrees RMS per trial
    adverb_response: float = 1.0  # error_based: r, how a word changes the error taken up (< 0: less)
    strength: float | None = None  # effort its body can give, in multiples of the target's (None: unlimited)

    def check(self) -> LearnerParams:
        if self.family not in FAMILIES:
            raise BadInput(f"learner family must be one of {', '.join(FAMILIES)}, got {self.family!r}", field="family")
        for name, lo, hi in (("gain", 0.0, 1.0), ("threshold", 0.0, 90.0), ("overshoot", 0.0, 5.0),
                             ("noise", 0.0, 30.0), ("tempo", 0.5, 2.0), ("adverb_sensitivity", 0.0, 5.0),
                             ("retention", 0.0, 1.0), ("step", 0.0, 90.0), ("adverb_response", -3.0, 3.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and lo <= v <= hi):
                raise BadInput(f"learner {name} must be in [{lo}, {hi}], got {v}", field=name)
        if self.strength is not None and not (isinstance(self.strength, (int, float)) and not isinstance(self.strength, bool)
                                              and np.isfinite(self.strength) and 0.1 <= self.strength <= 100.0):
            raise BadInput(f"learner strength must be in [0.1, 100] (or none), got {self.strength!r}", field="strength")
        for part, dev in self.deviation.items():
            if part not in BODY_PARTS or not isinstance(dev, dict) or not {"scale", "offset"} <= set(dev):
                raise BadInput(f"deviation must map arms/legs/trunk to {{scale, offset}}, got {part!r}", field="deviation")
            for key, lo, hi in (("scale", 0.0, 3.0), ("offset", -90.0, 90.0)):
                v = dev[key]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and lo <= v <= hi):
                    raise BadInput(f"deviation {part}.{key} must be in [{lo:g}, {hi:g}], got {v!r}", field="deviation")
        return self


def population(n: int, seed: int = 0, family: str = "thesis", replicate: int = 0) -> list[LearnerParams]:
    """``n`` learners drawn reproducibly: learner ``i`` uses ``default_rng([seed, i])``.

    gain U(0.15, 0.45); threshold U(1.5, 6) deg; overshoot U(0.1, 0.6); noise U(0.3, 1.5) deg;
    tempo U(0.9, 1.1); adverb sensitivity U(0.5, 1.5); deviation on 1 or 2 random body parts
    with amplitude scale U(0.5, 0.8) and offset U(-8, 8) deg; retention U(0.8, 1.0); step
    U(2, 8) deg; adverb response U(-1.5, 1.5). The same learner ``i`` has the same draws in every ``family`` (only the rules
    differ). ``replicate`` > 0 gives the same learners fresh motor noise (a new session that is
    not a replay of an earlier one).
    """
    if not 1 <= n <= 10_000:
        raise BadInput(f"population size must be 1..10000, got {n}")
    if family not in FAMILIES:
        raise BadInput(f"learner family must be one of {', '.join(FAMILIES)}, got {family!r}", field="family")
    out = []
    for i in range(n):
        r = np.random.default_rng([seed, i])
        parts = list(r.choice(list(BODY_PARTS), size=int(r.integers(1, 3)), replace=False))
        out.append(LearnerParams(
            gain=float(r.uniform(0.15, 0.45)), threshold=float(r.uniform(1.5, 6.0)),
            overshoot=float(r.uniform(0.1, 0.6)), noise=float(r.uniform(0.3, 1.5)), tempo=float(r.uniform(0.9, 1.1)),
            adverb_sensitivity=float(r.uniform(0.5, 1.5)),
            deviation={p: {"scale": float(r.uniform(0.5, 0.8)), "offset": float(r.uniform(-8, 8))} for p in parts},
            seed=int(r.integers(0, 2**31 - 1)), family=family))
        out[-1].retention, out[-1].step = float(r.uniform(0.8, 1.0)), float(r.uniform(2.0, 8.0))
        out[-1].adverb_response = float(r.uniform(-1.5, 1.5))
        if replicate:
            out[-1].seed = int(np.random.default_rng([out[-1].seed, replicate]).integers(0, 2**31 - 1))
    return out


class SimulatedLearner:
    """A learner of one target motion (see module docstring)."""

    def __init__(self, name: str, target: Clip, params: LearnerParams | None = None, memory: np.ndarray | None = None,
                 trials: int = 0, reference: np.ndarray | None = None, fast: np.ndarray | None = None):
        self.name = name
        self.params = (params or LearnerParams()).check()
        self.target = target
        self.channels = target.group("motion") or list(target.channels)
        self.target_phase = _bounded(to_phase(target, self.channels), "target")
        self._rotation_mask = np.array([0.0 if c.split(".")[-1].startswith("t") else 1.0 for c in self.channels])
        # the body's orientation in the room (the root's rotation channels) is not part of the
        # form a learner copies: it follows the target, and Euler triples of a root near
        # gimbal lock would otherwise read as huge differences
        root = target.skeleton.root.name if target.skeleton is not None else None
        self._imitated = np.array([0.0 if root and c.startswith(f"{root}.r") else 1.0 for c in self.channels])
        self.memory = self._initial() if memory is None else np.asarray(memory, float)
        self.trials = trials
        self.reference = None if reference is None else np.asarray(reference, float)
        # two_rate: the fast state x_f (the slow one is m - m0 - x_f)
        self.fast = np.zeros_like(self.memory) if fast is None else np.asarray(fast, float)
        if self.params.strength is not None and target.skeleton is None:
            raise BadInput("a learner with a strength needs a target with a skeleton (its body is built from it)",
                           field="strength")
        self.felt: int | None = None  # its word for the last demonstration's effort (strength only)
        self._body: Any = None  # the learner's own body (shared.bodies.body.Body), built on first use
        self._target_effort: float | None = None

    def _initial(self) -> np.ndarray:
        m = self.target_phase.copy()
        mean = m.mean(axis=0)
        for c, ch in enumerate(self.channels):
            dev = self.params.deviation.get(body_part(ch))
            if dev is not None and not ch.split(".")[-1].startswith("t") and self._imitated[c]:  # joint rotations only
                m[:, c] = mean[c] + dev["scale"] * (m[:, c] - mean[c]) + dev["offset"]
        return m

    # ------------------------------------------------------------------ the model
    def perceive(self, diff: np.ndarray) -> np.ndarray:
        """Soft threshold per channel on the RMS of the difference (degrees)."""
        rms = np.sqrt(np.mean(diff**2, axis=0))
        keep = np.where(rms > self.params.threshold, 1.0 - self.params.threshold / np.maximum(rms, 1e-12), 0.0)
        return diff * keep

    def imitate(self, demonstration: Clip, adverb: str | None = None) -> list[Clip]:
        """Watch ``demonstration`` (told ``adverb``), update the motor memory by the learner's
        family's rule (module docstring), and return the next attempt: ``REPETITIONS`` clips."""
        if adverb not in ADVERB_FACTOR:
            raise BadInput(f"unknown adverb {adverb!r}; one of: {', '.join(ADVERBS)} (or none)", field="adverb")
        p = self.params
        demo = _bounded(to_phase(demonstration, self.channels), "demonstration")
        self.felt = None
        if p.strength is not None:
            g = self.felt_effort(demonstration)
            self.felt = word(g)
            if g > 1.0:  # beyond its strength: it follows only the part it can (module docstring)
                demo = self.memory + (demo - self.memory) / g
        a = 1.0 + p.adverb_sensitivity * (ADVERB_FACTOR[adverb] - 1.0)
        if p.family == "thesis":
            if self.reference is None:  # the first motion shown is taken to be the target
                self.reference = demo
            diff = self.perceive((demo - self.memory) * self._imitated)
            own = float(np.sqrt(np.mean(((self.reference - self.memory) * self._imitated) ** 2)))
            shown = float(np.sqrt(np.mean(((demo - self.reference) * self._imitated) ** 2)))
            exaggeration = min(shown / max(own, 1e-9), 5.0)
            gain = min(p.gain * a * (1.0 + p.overshoot * exaggeration), 1.0)  # never past what it saw
            self.memory = self.memory + gain * diff
        elif p.family == "error_based":
            habit = self._initial()
            error = self.perceive((demo - self.performed()) * self._imitated)
            response = 1.0 + p.adverb_response * (ADVERB_FACTOR[adverb] - 1.0)
            self.memory = habit + p.retention * (self.memory - habit) + float(np.clip(p.gain * response, 0.0, 1.0)) * error
        elif p.family == "two_rate":
            habit = self._initial()
            error = self.perceive((demo - self.performed()) * self._imitated)
            k = TWO_RATE
            slow = self.memory - habit - self.fast
            self.fast = k["A_f"] * self.fast + k["B_f"] * error
            self.memory = habit + self.fast + k["A_s"] * slow + k["B_s"] * error
        elif p.family == "copy":
            self.memory = self.memory + (demo - self.memory) * self._imitated
        else:  # fixed_step: direction only, no threshold (module docstring)
            diff = (demo - self.memory) * self._imitated
            size = float(np.sqrt(np.mean(diff[:, self._imitated.astype(bool)] ** 2)))
            self.memory = self.memory + diff * (min(1.0, p.step / size) if size > 0 else 0.0)
        self.trials += 1
        return self.attempts()

    def felt_effort(self, clip: Clip) -> float:
        """How heavy ``clip`` feels to this learner's body: ``E(clip) / (E(target) strength)``."""
        if self.params.strength is None or self.target.skeleton is None:
            raise BadInput("felt effort needs a learner with a strength and a target with a skeleton")
        if self._body is None:
            from shared.bodies.human import human_body  # MuJoCo: loaded only for learners with a strength

            self._body = human_body(self.target.skeleton)
            self._target_effort = self._effort(self.target)
        target_effort = self._target_effort
        assert target_effort is not None  # (set with the body)
        return self._effort(clip) / (target_effort * float(self.params.strength))

    def _effort(self, clip: Clip) -> float:
        from shared.bodies.body import perform

        return performed_effort(perform(self._body, clip)[0])

    def performed(self) -> np.ndarray:
        """The learner's own last performance on the phase axis (its attempts' mean, motor
        noise included); its memory before the first attempt."""
        if self.trials == 0:
            return self.memory
        return np.mean([to_phase(c, self.channels) for c in self.attempts()], axis=0)

    def attempts(self) -> list[Clip]:
        """``REPETITIONS`` performances of the current memory (motor noise, own tempo)."""
        p = self.params
        rng = np.random.default_rng([p.seed, self.trials])
        t = self.target
        n = max(5, int(round(t.n_frames * p.tempo)))
        base = time_normalised(self.memory, n)
        width = max(1, int(round(0.2 * t.fps)))
        kernel = np.hanning(2 * width + 1)
        kernel /= np.sqrt(np.sum(kernel**2))
        out = []
        for r in range(REPETITIONS):
            white = rng.standard_normal((n + 2 * width, base.shape[1]))
            smooth = np.column_stack([np.convolve(white[:, c], kernel, mode="valid") for c in range(base.shape[1])])
            data = t.data[np.linspace(0, t.n_frames - 1, n).round().astype(int)].copy()
            idx = [t.channels.index(c) for c in self.channels]
            noise = p.noise * smooth[:n] * self._rotation_mask * self._imitated  # motor noise: joint angles only
            data[:, idx] = base + noise
            out.append(Clip(data, list(t.channels), t.fps, t.skeleton, {g: list(v) for g, v in t.groups.items()},
                            name=f"{self.name}_trial{self.trials}_rep{r + 1}", label=t.label))
        return out

    def error(self) -> float:
        """RMS difference (degrees) between the motor memory and the target: the truth a
        coach never sees, for evaluation."""
        m = self._imitated.astype(bool)
        return float(np.sqrt(np.mean((self.memory[:, m] - self.target_phase[:, m]) ** 2)))

    def reveal(self) -> dict:
        return {"name": self.name, "trials": self.trials, "error_deg": self.error(), **asdict(self.params)}
