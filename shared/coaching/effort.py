"""The learner's felt effort in the coaching loop (thesis 6.5.1): chapter 3 asked by the coach.

The thesis closes (6.5.1, 6.6) by joining its two halves: a coach that knows what the learner's
body feels can choose a demonstration that body can perform. Here the coach runs chapter 3's
**interval estimator** (:func:`shared.estimation.conversation.scale_of`, the open question of
3.3 with the self's own torques as the shared motion's reference) on the learner:

* **Effort** of a motion on a body: eq. 3.8 on its inverse-dynamics torques,
  ``E(M) = mean_t sum_j |tau_j(t)|`` (N m, ``tau_max`` 1; :func:`effort`). The coach feels a
  motion on its own body (built from the target's skeleton, :mod:`shared.bodies.human`) relative
  to the target: ``g_self(M) = E(M) / E(target)``, so the target weighs 1 to the coach.
* **The question**: after each trial the learner says how heavy the demonstration it just tried
  felt, a word of :data:`LANGUAGE` (4 words over ``[0, 1]``; 1 "light" ... 4 "at my limit, or
  beyond": the top bin is open-ended, eq. 3.4). A simulated learner feels ``g_L = g_self /
  strength`` (:class:`shared.agents.learner.LearnerParams`); a person answers with `coach
  attempt --felt K`.
* **The estimate**: every answer ``(g_self, k)`` bounds the learner's scale ``s`` with
  ``g_L = s g_self`` (the interval method); before a demonstration is shown its felt effort is
  predicted as ``s_hat g_self(demo)``, and above ``g_max`` (beyond what the learner's body can
  give) alpha is lowered like any infeasible emphasis (:func:`shared.coaching.session.trial`).

Nothing here assumes that this helps: ``mirrorcoach reproduce ch6`` measures it per learner
family on learners whose strength is limited (``effort`` in the report).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from shared.errors import BadInput
from shared.estimation.conversation import Language, scale_interval, scale_of
from shared.estimation.symbols import f_conv, f_div
from shared.motion.clip import Clip

#: the words of felt effort shared by coach and learner: 4 bins over [0, 1], the target at 1 on the coach's body
LANGUAGE = Language(d=4, g_max=1.0, tau_max=1.0, joints=[], rule="eq3.8")


def effort(torques: np.ndarray) -> float:
    """``E = mean_t sum_j |tau_j|`` (eq. 3.8 with ``tau_max`` 1 N m) of a T x J torque pattern."""
    return f_conv(np.asarray(torques, float), "eq3.8", 1.0)


def performed_effort(performed: Clip) -> float:
    """:func:`effort` of a clip as :func:`shared.bodies.body.perform` returns it (its ``tau.*`` channels)."""
    return effort(performed.select([c for c in performed.channels if c.startswith("tau.")]))


def word(g: float) -> int:
    """The word (bin 1..d of :data:`LANGUAGE`, eq. 3.4) for a felt effort ``g``."""
    return f_div(float(g), LANGUAGE.d, LANGUAGE.g_max)


@dataclass
class EffortEstimate:
    """What the coach knows of the learner's felt effort (module docstring)."""

    target: float  # E(target) on the coach's body, N m
    answers: list = field(default_factory=list)  # [g_self of the motion asked about, the learner's word]
    last: float | None = None  # g_self of the last demonstration shown (what the next answer is about)

    def __post_init__(self):
        if not (np.isfinite(self.target) and self.target > 0):
            raise BadInput(f"the target's effort on the coach's body must be positive, got {self.target}")

    def g_self(self, e: float) -> float:
        return float(e) / self.target

    def add(self, k: int) -> None:
        """The learner's word about the last demonstration shown."""
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= LANGUAGE.d:
            raise BadInput(f"felt effort must be a word 1..{LANGUAGE.d}, got {k!r}", field="felt")
        if self.last is None:
            raise BadInput("felt effort answers a demonstration, and none has been shown yet", field="felt")
        self.answers.append([self.last, k])

    def scale(self) -> float:
        return scale_of(self.answers, LANGUAGE)

    def interval(self) -> tuple[float, float]:
        return scale_interval(self.answers, LANGUAGE)

    def predicted(self, e: float) -> float:
        """The learner's felt effort of a motion of effort ``e`` on the coach's body."""
        return self.scale() * self.g_self(e)

    def beyond(self, e: float) -> str | None:
        """Why a motion of effort ``e`` is beyond the learner's strength, or None (also None
        before any answer: nothing is known yet)."""
        if not self.answers:
            return None
        g = self.predicted(e)
        if g <= LANGUAGE.g_max:
            return None
        return (f"the learner would feel it at {g:.2f} of its strength (estimated from {len(self.answers)} "
                f"answer(s), eq. 3.4-3.5)")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict | None) -> EffortEstimate | None:
        return None if d is None else cls(float(d["target"]), [list(a) for a in d.get("answers", [])], d.get("last"))
