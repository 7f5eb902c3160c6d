"""Coaching ports on local objects (no bus): a local PSS space per session and a MuJoCo body
built from the target's skeleton. Used by tests and by quick experiments; the coach service
has the same ports on the bus."""

from __future__ import annotations

import numpy as np

from shared.bodies.body import perform
from shared.bodies.human import human_body
from shared.bodies.stance import plant_feet
from shared.bodies.tracking import perform_tracked
from shared.coaching.effort import performed_effort
from shared.motion.clip import Clip
from shared.pss.space import ProtoSymbolSpace


class LocalCoachPorts:
    def __init__(self, skeleton=None, space_params: dict | None = None):
        self.spaces: dict[str, ProtoSymbolSpace] = {}
        self.body = None if skeleton is None else human_body(skeleton)
        self.space_params = space_params or {}
        self._last: tuple | None = None  # (clip, effort) of the last clip performed

    def build(self, space, target: Clip):
        t = target.with_data(target.data, name="target", label="target")
        self.spaces[space] = ProtoSymbolSpace.build([t], **self.space_params)

    def add_attempt(self, space, name, attempts):
        self.spaces[space] = self.spaces[space].rebuilt(add=attempts, as_one=name)

    def distance(self, space, a, b):
        sp = self.spaces[space]
        return float(sp.distances[sp.symbol(a), sp.symbol(b)])

    def points(self, space):
        sp = self.spaces[space]
        return {s.name: np.asarray(p) for s, p in zip(sp.symbols, sp.points)}

    def generate(self, space, mix):
        sp = self.spaces[space]
        return sp.generate(weights=sp.mix_weights(mix))

    def perform(self, clip, track=True):
        if self.body is None:
            return {"joint_limit_violations": {}, "support": {"checked": False}, "frames": clip.n_frames,
                    "not_checked": ["joint limits and balance (no body for this target)"], "feasible": None}, None
        out, report = perform_tracked(self.body, clip, track=track)
        self._last = (clip, performed_effort(out))  # the check and the effort policy ask about the same clip
        return report, out.select(["cog.x", "cog.y", "cog.z"])

    def plant(self, clip, reference):
        if self.body is None:
            return clip, {"planted": False, "why": "no body for this target"}
        return plant_feet(self.body, reference, clip)

    def effort(self, clip):
        if self.body is None:
            return None
        if self._last is not None and self._last[0] is clip:
            return self._last[1]
        return performed_effort(perform(self.body, clip)[0])
