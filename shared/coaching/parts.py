"""Body-part emphasis (the thesis's future work, 6.6): which body part carries the error, and an
emphatic motion that exaggerates that part only.

The error of an attempt is split by body part (arms, legs, trunk; ``shared.agents.learner.
body_part``) as the share of the squared joint-angle difference to the target, both resampled
to a common normalised time axis and the attempt averaged over its repetitions. The partial
emphatic motion takes the worst part's channels from the whole-body emphatic motion and every
other channel from the target.
"""

from __future__ import annotations

import re

import numpy as np

from shared.errors import BadInput
from shared.motion.clip import Clip, time_normalised

N_PHASE = 100  # samples of normalised time a motion is compared on (learners and body parts)

BODY_PARTS = {
    "arms": r"(clavicle|humerus|radius|wrist|hand|fingers|thumb|shoulder|elbow|arm|collar)",
    "legs": r"(hipjoint|femur|tibia|foot|toes|knee|leg|thigh|shin|ankle)",
    "trunk": r"(root|lowerback|upperback|thorax|neck|head|spine|chest|hips|pelvis)",
}


def body_part(channel: str) -> str:
    """Which body part a motion channel belongs to (arms, legs, trunk)."""
    joint = channel.split(".")[0].lower()
    for part, pat in BODY_PARTS.items():
        if re.search(pat, joint):
            return part
    return "trunk"


def to_phase(clip: Clip, channels: list[str], n: int = N_PHASE) -> np.ndarray:
    """The clip's ``channels`` resampled to ``n`` samples of normalised time (n x C)."""
    missing = [c for c in channels if c not in clip.channels]
    if missing:
        raise BadInput(f"the demonstration lacks {len(missing)} of the target's channels, e.g. {missing[:3]}")
    x = clip.select(channels)
    if len(x) < 2:
        raise BadInput("a demonstration needs at least 2 frames")
    return time_normalised(x, n)


def rotation_channels(clip: Clip) -> list[str]:
    return [c for c in (clip.group("motion") or clip.channels) if not c.split(".")[-1].startswith("t")]


def error_shares(target: Clip, attempts: list[Clip]) -> dict[str, float]:
    """Share of the squared joint-angle error per body part (sums to 1)."""
    chans = rotation_channels(target)
    t = to_phase(target, chans)
    a = np.mean([to_phase(x, chans) for x in attempts], axis=0)
    sq = np.sum((a - t) ** 2, axis=0)
    shares = {p: 0.0 for p in BODY_PARTS}
    for c, v in zip(chans, sq):
        shares[body_part(c)] += float(v)
    total = sum(shares.values()) or 1.0
    return {p: v / total for p, v in shares.items()}


def partial_emphasis(target: Clip, emphatic: Clip, part: str) -> Clip:
    """The target with ``part``'s rotation channels taken from the emphatic motion (time
    normalised onto the target's frames)."""
    out = target.data.copy()
    grid = np.linspace(0, 1, target.n_frames)
    src = np.linspace(0, 1, emphatic.n_frames)
    for c in rotation_channels(target):
        if body_part(c) == part and c in emphatic.channels:
            out[:, target.channels.index(c)] = np.interp(grid, src, emphatic.column(c))
    return target.with_data(out, name=f"{emphatic.name}_{part}")
