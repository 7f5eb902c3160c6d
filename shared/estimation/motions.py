"""The shared motions of chapter 3, on the small humanoid's joints (degrees, 30 fps).

* :func:`basic_motions`: the 4 basic motions of fig. 3.4 (open questions: right shoulder pitch,
  shoulder roll, elbow) or fig. 3.10 (closed questions, with the right knee): raise the arm
  forward, raise it sideways, bend the elbow, and a combined reach (plus a squat-like knee bend
  in the 4-joint set). Each goes out and back in 2 s.
* :func:`unknown_motions`: ``n`` random motions for evaluation, drawn with
  ``default_rng([seed, i])`` (default seed 2012, the thesis's year): for every joint, 3 random
  via-points within the joint's comfortable range joined by a smooth (PCHIP) curve over 2-4 s.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.interpolate import PchipInterpolator

from shared.motion.clip import Clip

ARM = ["shoulder_pitch", "shoulder_roll", "elbow"]
ALL = ARM + ["knee"]
FPS = 30.0
RANGE = {"shoulder_pitch": (0.0, 120.0), "shoulder_roll": (-10.0, 90.0), "elbow": (-120.0, 0.0), "knee": (0.0, 100.0)}
UNKNOWN_SEED = 2012


def _clip(name: str, profile: dict[str, np.ndarray], joints: list[str], label: str | None = None) -> Clip:
    n = len(next(iter(profile.values())))
    data = np.column_stack([profile.get(j, np.zeros(n)) for j in joints])
    return Clip(data, list(joints), FPS, name=name, label=label or name)


def _out_and_back(n: int = 61) -> np.ndarray:
    return np.sin(np.linspace(0, np.pi, n)) ** 2


def basic_motions(joints: list[str] | None = None) -> list[Clip]:
    joints = list(joints or ARM)
    b = _out_and_back()
    motions = [
        _clip("raise_forward", {"shoulder_pitch": 90 * b}, joints),
        _clip("raise_sideways", {"shoulder_roll": 80 * b}, joints),
        _clip("bend_elbow", {"shoulder_pitch": 30 * b, "elbow": -110 * b}, joints),
        _clip("reach", {"shoulder_pitch": 60 * b, "shoulder_roll": 40 * b, "elbow": -60 * b}, joints),
    ]
    if "knee" in joints:
        motions[3] = _clip("reach_and_bend", {"shoulder_pitch": 60 * b, "shoulder_roll": 40 * b, "elbow": -60 * b,
                                              "knee": 70 * b}, joints)
    return motions


def unknown_motions(n: int = 10, seed: int = UNKNOWN_SEED, joints: list[str] | None = None) -> list[Clip]:
    return [Clip(data.copy(), list(js), FPS, name=name, label=name)
            for name, js, data in _unknown_profiles(n, seed, tuple(joints or ARM))]


@lru_cache(maxsize=64)
def _unknown_profiles(n: int, seed: int, joints: tuple[str, ...]) -> list[tuple[str, tuple[str, ...], np.ndarray]]:
    """The curves of :func:`unknown_motions`, interpolated once per process (every rule
    identification and every conversation's random probes ask for the same ones)."""
    out = []
    for i in range(n):
        r = np.random.default_rng([seed, i])
        duration = float(r.uniform(2.0, 4.0))
        frames = int(round(duration * FPS)) + 1
        t = np.linspace(0, duration, frames)
        prof = []
        for j in joints:
            lo, hi = RANGE[j]
            knots = np.linspace(0, duration, 5)
            values = np.r_[0.0, r.uniform(lo, hi, size=3), 0.0]
            values[0] = values[-1] = np.clip(0.0, lo, hi)
            prof.append(PchipInterpolator(knots, values)(t))
        data = np.column_stack(prof)
        data.flags.writeable = False
        out.append((f"unknown_{i + 1:02d}", joints, data))
    return out
