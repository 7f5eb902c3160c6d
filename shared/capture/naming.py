"""A proto-symbol space's word on the stretches of a take (thesis eq. 2.6), for
:mod:`shared.capture.segment`: whether the space's nearest motion for a stretch is the target's.

A *namer* answers for a space: :class:`SpaceNamer` for a space read in this process, the capture
service's for a space of the pss service (the same three things over the bus): the space's
labels, the shortest clip it reads, and for a clip its nearest proto-symbols' labels and
recognition distances (eq. 2.4) and its open-set answer.
"""

from __future__ import annotations

import numpy as np

from shared.errors import BadInput
from shared.motion.clip import Clip
from shared.pss.symbol import shortest_seconds

SPACE_RATIO = 1.0  # a stretch's recognition distance to the target's motion / to the nearest other, at most


class SpaceNamer:
    """A proto-symbol space read in this process, as segmentation asks it (the ``space`` of
    :func:`shared.capture.segment.segment`; the capture service asks the pss service the same
    over the bus): the space's labels, a clip's recognition distances (eq. 2.4) to the nearest
    proto-symbols and their labels, and a clip's open-set answer (eq. 2.6)."""

    def __init__(self, space):
        self.space, self.labels = space, list(space.labels)
        self.shortest = shortest_seconds(space.params.n_states, space.params.fps)
        self.sensor_channels = list(space.features.sensor_channels)

    def nearest(self, clip: Clip) -> tuple[np.ndarray, np.ndarray]:
        """(labels, distances) of the space's proto-symbols for ``clip`` (here all of them)."""
        rec = self.space.recognize(clip, top=1)
        return np.asarray(self.labels), rec.distances if rec.recognition_distances is None else rec.recognition_distances

    def recognise(self, clip: Clip) -> tuple[str | None, str, float]:
        """The label (None: "none of these"), the nearest label and its confidence."""
        rec = self.space.recognize(clip, top=1)
        return rec.label, rec.nearest_label, rec.confidence


class Named:
    """A proto-symbol space's word on a stretch of the take (eq. 2.6): the stretch abstracted
    into an HMM and its recognition distance (eq. 2.4) to the target's motion over that to the
    nearest other motion the space holds (below 1: the space's nearest motion is the target's),
    accepted up to ``limit``. Each stretch is recognised once (about 10 ms in this process); ``seen``
    keeps the ratios across calls on the same growing take (a stretch's frames never change)."""

    def __init__(self, namer, label: str, take: Clip, fps: float, limit: float = SPACE_RATIO, seen: dict | None = None):
        self.namer, self.label, self.take, self.step, self.limit = namer, label, take, take.fps / fps, limit
        readable(namer, take)
        labels = np.asarray(namer.labels)
        if not (labels == label).any() or (labels == label).all():
            raise BadInput(f"the space must hold the target's motion {label!r} and at least one other "
                           f"(it holds {', '.join(sorted(set(namer.labels)))})", field="space")
        self.seen: dict[tuple[int, int], float] = {} if seen is None else seen

    def ratio(self, s: int, e: int) -> float:
        if (s, e) not in self.seen:
            part = self.take.frames(int(round(s * self.step)), int(round(e * self.step)))
            if part.duration < self.namer.shortest:  # too short for the space's HMMs
                self.seen[s, e] = np.inf  # no motion the space could name
            else:
                labels, d = self.namer.nearest(part.with_data(part.data, name="stretch"))
                self.seen[s, e] = distance_ratio(np.asarray(labels), np.asarray(d, float), self.label)
        return self.seen[s, e]


def readable(namer, clip: Clip) -> None:
    """Refuse a space that models sensor channels (torques, a centre of gravity) the clip does not
    have: it recognises only clips that have them (a take from motion capture has none)."""
    missing = [c for c in namer.sensor_channels if c not in clip.channels]
    if missing:
        raise BadInput(f"the space models sensor channels a take from motion capture does not have "
                       f"({', '.join(missing[:4])}{', ...' if len(missing) > 4 else ''}): give a space built from "
                       "motion clips alone", field="space")


def distance_ratio(labels: np.ndarray, d: np.ndarray, label: str) -> float:
    """The nearest proto-symbol of ``label``'s distance over the nearest other's, from the
    ``labels`` and distances ``d`` of the nearest proto-symbols (all of them, or the nearest few:
    with none of ``label`` among them the ratio is infinite; with no other, the farthest listed
    stands for the nearest other, which is farther still: the ratio given is at least the true
    one, and below 1 exactly when the true one is)."""
    mine = labels == label
    if not mine.any():
        return float("inf")
    other = float(d[~mine].min()) if (~mine).any() else float(d.max())
    return float(d[mine].min()) / max(other, 1e-12)


def target_label(namer, target: Clip, label: str | None = None) -> tuple[str, str | None]:
    """The space's name for the target's motion: ``label`` when given, else the target's own
    label when the space holds it, else what the space recognises the target as (its open-set
    answer: a target the space says it holds none of is refused). A note when it was recognised."""
    labels = set(namer.labels)
    name = label if label is not None else target.label if target.label in labels else None
    if name is not None:
        if name not in labels:
            raise BadInput(f"the space holds no motion {name!r} (it holds {', '.join(sorted(labels))})", field="label")
        return name, None
    known, nearest, confidence = namer.recognise(target)
    if known is None:
        raise BadInput(f"the space holds no motion like the target (nearest {nearest!r}, refused as none of "
                       "these): give --label, or a space that holds it", field="space")
    return known, f"the space recognises the target as {known!r} (confidence {confidence:.2f})"
