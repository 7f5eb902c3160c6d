"""From torques to words: ``F_symbolize = F_div(F_conv(S))`` (thesis 3.3.2, eq. 3.7, 3.8, 3.13-3.16).

* ``F_conv`` turns a torque pattern ``S`` (frames x joints, N m) into a scalar ``g``. The
  thesis's open-question experiment uses eq. 3.8, ``g = (1/T) int (|tau_1|+...+|tau_J|)/tau_MAX dt``;
  its closed-question experiment compares four candidate rules (eq. 3.13-3.16):
  ``f1`` mean torque over time and joints, ``f2`` sum over joints of each joint's maximum,
  ``f3`` maximum over time of the summed torque, ``f4`` maximum over joints of each joint's
  maximum. We take torque magnitudes ``|tau|`` (the thesis writes ``tau`` for the effort felt).
  Weighted variants (a weight per joint) extend the candidate set.
* ``F_div`` splits ``[0, g_max]`` into ``d`` equal bins and returns the 1-based bin ``k``.
* Table 3.1 gives the words for ``d`` = 2, 4, 6; ``d`` = 8 extends it the same way.
"""

from __future__ import annotations

import numpy as np

from shared.errors import BadInput

RULES = ("eq3.8", "f1", "f2", "f3", "f4")

WORDS = {
    2: ("light", "heavy"),
    4: ("light", "bit light", "bit heavy", "heavy"),
    5: ("very light", "light", "medium", "heavy", "very heavy"),  # ours: Table 3.1 has no d = 5 (figs. 3.14 uses it)
    6: ("very light", "light", "bit light", "bit heavy", "heavy", "very heavy"),
    7: ("very light", "light", "bit light", "medium", "bit heavy", "heavy", "very heavy"),  # ours, for fig. 3.15
    8: ("extremely light", "very light", "light", "bit light", "bit heavy", "heavy", "very heavy", "extremely heavy"),
}
COMPARISONS = (">", "<", "equal")


def f_conv(tau: np.ndarray, rule: str = "eq3.8", tau_max: float = 1.0, weights=None) -> float:
    """``g = F_conv(S)`` for a torque pattern ``tau`` (T x J): eq. 3.8 or one of f1-f4
    (eq. 3.13-3.16), on ``|tau| / tau_max`` with optional per-joint ``weights``."""
    tau = np.asarray(tau, float)
    if tau.ndim != 2 or tau.shape[0] < 1 or tau.shape[1] < 1:
        raise BadInput(f"a torque pattern must be frames x joints, got shape {tau.shape}")
    if not np.all(np.isfinite(tau)):
        raise BadInput("torque pattern contains NaN or Inf")
    if not (np.isfinite(tau_max) and tau_max > 0):
        raise BadInput(f"tau_max must be positive, got {tau_max}")
    a = np.abs(tau) / tau_max
    if weights is not None:
        w = np.asarray(weights, float)
        if w.shape != (tau.shape[1],) or np.any(w < 0) or not np.all(np.isfinite(w)):
            raise BadInput(f"need {tau.shape[1]} non-negative joint weights, got {w.tolist()}")
        a = a * w
    if rule == "eq3.8":
        return float(np.mean(np.sum(a, axis=1)))
    if rule == "f1":
        return float(np.mean(a))
    if rule == "f2":
        return float(np.sum(np.max(a, axis=0)))
    if rule == "f3":
        return float(np.max(np.sum(a, axis=1)))
    if rule == "f4":
        return float(np.max(a))
    raise BadInput(f"unknown conversion rule {rule!r}; one of {', '.join(RULES)}")


def f_div(g: float, d: int, g_max: float = 1.0) -> int:
    """The 1-based bin ``k`` of ``g`` among ``d`` equal bins of ``[0, g_max]`` (values past the
    ends fall in the first or last bin)."""
    if d not in WORDS:
        raise BadInput(f"density d must be one of {sorted(WORDS)}, got {d}")
    return int(np.clip(np.floor(g / g_max * d), 0, d - 1)) + 1


def word(k: int, d: int) -> str:
    """Table 3.1: the word for bin ``k`` (1-based) at density ``d``."""
    if d not in WORDS or not 1 <= k <= d:
        raise BadInput(f"no word for k={k} at density d={d}")
    return WORDS[d][k - 1]


def index_of(w: str, d: int) -> int:
    """The bin of a word (exact Table 3.1 spelling; the dialogue agent parses variants)."""
    if d not in WORDS:
        raise BadInput(f"density d must be one of {sorted(WORDS)}, got {d}")
    try:
        return WORDS[d].index(w) + 1
    except ValueError:
        raise BadInput(f"{w!r} is not a word at density {d}; the words are: {', '.join(WORDS[d])}") from None


def compare(g1: float, g2: float, jnd: float = 0.05) -> str:
    """``'>'``, ``'<'`` or ``'equal'`` (eq. 3.11-3.12): equal when the two differ by at most
    ``jnd`` (a just-noticeable difference, relative to the larger)."""
    if abs(g1 - g2) <= jnd * max(abs(g1), abs(g2), 1e-12):
        return "equal"
    return ">" if g1 > g2 else "<"


#: the parsed answer "I don't know" to an open question (a person may not know)
DONT_KNOW = "don't know"
_DONT_KNOW = {"i don t know", "i dont know", "don t know", "dont know", "not sure", "i m not sure", "no idea",
              "i can t tell", "cannot tell", "can t tell", "i don t know really", "hard to say"}
_FILLERS = ("it felt ", "it was ", "felt ", "that was ", "it's ", "its ", "quite ")
_SYNONYMS = {"a bit ": "bit ", "a little ": "bit ", "slightly ": "bit ", "little bit ": "bit ", "a little bit ": "bit ",
             "bit of a ": "bit ", "really ": "very ", "super ": "extremely "}
_COMPARE = {">": ">", "<": "<", "=": "equal", "equal": "equal", "same": "equal", "the same": "equal", "equally": "equal",
            "first": ">", "the first": ">", "the first one": ">", "first one": ">",
            "second": "<", "the second": "<", "the second one": "<", "second one": "<"}


def parse_answer(text: str, kind: str, d: int = 4) -> str:
    """The canonical answer in a person's (or agent's) words: a Table 3.1 word at density ``d``
    for an open question (:data:`DONT_KNOW` for "I don't know", "not sure", ...), ``'>'``, ``'<'`` or ``'equal'`` for a comparative one. Accepts case,
    spacing and punctuation variants and a few phrasings ("a bit heavy", "it felt light",
    "the first", "same"); anything else is a :class:`BadInput` listing the accepted answers."""
    if not isinstance(text, str):
        raise BadInput("an answer must be text")
    t = " ".join("".join(ch if ch.isalnum() or ch in "<>= " else " " for ch in text.lower()).split())
    if kind == "compare":
        if t in _COMPARE:
            return _COMPARE[t]
        raise BadInput(f"{text!r} is not an answer to 'which felt heavier?'; accepted: > (the first), < (the second), "
                       "equal (the same)", field="answer")
    if kind != "open":
        raise BadInput(f"unknown question kind {kind!r}")
    if t in _DONT_KNOW:
        return DONT_KNOW
    if d not in WORDS:
        raise BadInput(f"density d must be one of {sorted(WORDS)}, got {d}")
    t = t + " "
    for f in _FILLERS:
        if t.startswith(f):
            t = t[len(f):]
    for a, b in sorted(_SYNONYMS.items(), key=lambda kv: -len(kv[0])):
        if t.startswith(a):
            t = b + t[len(a):]
    t = t.strip()
    if t in WORDS[d]:
        return t
    raise BadInput(f"{text!r} is not one of the {d} words; accepted: {', '.join(WORDS[d])}", field="answer")
