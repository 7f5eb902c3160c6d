"""Continuous takes made of real clips, with their true boundaries (for measuring segmentation
and for replaying a session without a capture suit).

:func:`join` puts repetitions one after another as a person performs them in front of a capture
system: each repetition's last pose held for a rest (with the small sway of a person standing),
then a short move into the next repetition's first pose. The clips must share one skeleton (one
performer); angles are joined continuously (a clip that starts a whole turn away from where the
last ended is shifted by that turn).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shared.errors import BadInput
from shared.motion.clip import Clip

REST = (1.0, 2.0)  # seconds of rest between repetitions (uniform)
MOVE = 0.5  # seconds to move from one repetition's last pose to the next one's first
SWAY = 0.3  # degrees (standard deviation, smoothed) of the sway while resting


def _sway(n: int, channels: int, r: np.random.Generator) -> np.ndarray:
    if n == 0:
        return np.zeros((0, channels))
    noise = r.normal(0.0, 1.0, (n + 30, channels))
    kernel = np.hanning(31)
    kernel /= np.sqrt((kernel ** 2).sum())
    smooth = np.stack([np.convolve(noise[:, c], kernel, mode="valid") for c in range(channels)], axis=1)
    return SWAY * smooth[:n]


def other_body(first: Clip, clip: Clip) -> str:
    """Why ``clip`` cannot be a repetition of ``first``'s performer in one take ("" when it can):
    other channels, or a skeleton with other joints or other bones (each joint's offset from its
    parent, to a thousandth of the longest; the root's place in the world may differ)."""
    if clip.channels != first.channels:
        return "other channels"
    a, b = first.skeleton, clip.skeleton
    if a is None or b is None:
        return ""
    if [j.name for j in a.joints] != [j.name for j in b.joints]:
        return "other joints"
    bones = [k for k, j in enumerate(a.joints) if j.parent >= 0]
    ours = np.array([a.joints[k].offset for k in bones]) * a.unit_m
    theirs = np.array([b.joints[k].offset for k in bones]) * b.unit_m
    if bones and not np.allclose(ours, theirs, rtol=0.0, atol=1e-3 * max(float(np.abs(ours).max()), 1e-9)):
        return "other bones"
    return ""


def join(clips: list[Clip], seed: int = 0, rest: tuple[float, float] = REST, lead: float = 1.0,
         name: str = "take") -> tuple[Clip, list[tuple[float, float]]]:
    """One take of ``clips`` with rests between them (and ``lead`` seconds of rest before the
    first and after the last), and each clip's (start, end) in seconds within it. Clips are
    resampled to the first one's frame rate."""
    if not clips:
        raise BadInput("no clips to join")
    first = clips[0]
    fps = first.fps
    r = np.random.default_rng(seed)
    angle = [i for i, c in enumerate(first.channels) if c.split(".")[-1].startswith("r")]
    parts, bounds = [], []
    t = 0
    prev = None

    def rest_frames(pose: np.ndarray, seconds: float) -> np.ndarray:
        n = int(round(seconds * fps))
        out = np.repeat(pose[None, :], n, axis=0)
        if angle:
            out[:, angle] += _sway(n, len(angle), r)
        return out

    for clip in clips:
        why = other_body(first, clip)
        if why:
            raise BadInput(f"clip {clip.name!r} has {why} than {first.name!r}: one performer's clips only")
        data = clip.resample(fps).data.copy()
        if prev is not None and angle:  # continue the angles where the last clip ended (whole turns)
            turns = np.round((prev[angle] - data[0, angle]) / 360.0) * 360.0
            data[:, angle] += turns
        if prev is None:
            lead_part = rest_frames(data[0], lead)
        else:
            hold = rest_frames(prev, float(r.uniform(*rest)))
            n_move = max(int(round(MOVE * fps)), 1)
            w = (0.5 - 0.5 * np.cos(np.linspace(0, np.pi, n_move + 2)[1:-1]))[:, None]
            lead_part = np.vstack([hold, (1 - w) * prev[None, :] + w * data[0][None, :]])
        parts.append(lead_part)
        t += len(lead_part)
        bounds.append((t / fps, (t + len(data)) / fps))
        parts.append(data)
        t += len(data)
        prev = data[-1]
    assert prev is not None  # (there is a first clip)
    parts.append(rest_frames(prev, lead))
    take = first.with_data(np.vstack(parts), name=name, label=first.label)
    return take, bounds


class JoinedTakes(Sequence):
    """``clips`` taken ``repetitions`` at a time, in order (the last take wrapping round to the
    first clips), each group :func:`join`-ed into one take: what ``capture serve --repetitions``
    plays, one take per connection, as a person performs a trial's repetitions with rests between
    them. A take is joined when it is asked for (a long list of clips is never held joined); take
    ``k``'s rests are drawn with seed ``k``, so the same clips give the same takes. Every take's
    clips must be one performer's (:func:`other_body`): checked here, before anything plays."""

    def __init__(self, clips: Sequence[Clip], repetitions: int):
        if repetitions < 1:
            raise BadInput(f"repetitions must be at least 1, got {repetitions}", field="repetitions")
        if not clips:
            raise BadInput("no clips to join")
        self.clips, self.repetitions = list(clips), int(repetitions)
        for k in range(len(self)):
            group = self.group(k)
            for c in group[1:]:
                why = other_body(group[0], c)
                if why:
                    raise BadInput(f"take {k + 1} would join {group[0].name!r} and {c.name!r}, of {why}: the clips of "
                                   f"one take must be one performer's (give each performer's clips "
                                   f"{self.repetitions} at a time)")

    def group(self, k: int) -> list[Clip]:
        """The clips of take ``k`` (from 0)."""
        return [self.clips[(k * self.repetitions + i) % len(self.clips)] for i in range(self.repetitions)]

    def joined(self, k: int) -> tuple[Clip, list[tuple[float, float]]]:
        """Take ``k`` and its repetitions' (start, end) in seconds (:func:`join`)."""
        if not 0 <= k < len(self):
            raise IndexError(k)
        return join(self.group(k), seed=k, name=f"take{k + 1}")

    def __len__(self) -> int:
        return -(-len(self.clips) // self.repetitions)

    def __getitem__(self, k):  # type: ignore[override]  # (an index; slices are not taken)
        return self.joined(k)[0]


def score(found: list[tuple[float, float]], truth: list[tuple[float, float]], iou: float = 0.5) -> dict:
    """Repetitions found against the true ones: a found one matches the true one it overlaps
    most if their intersection over union is at least ``iou`` (each true one matched once).
    Precision, recall, F1 and every matched boundary's error in seconds."""
    used, errors, hits = set(), [], 0
    for s, e in found:
        best, best_iou = None, 0.0
        for k, (ts, te) in enumerate(truth):
            if k in used:
                continue
            inter = max(0.0, min(e, te) - max(s, ts))
            union = max(e, te) - min(s, ts)
            if union > 0 and inter / union > best_iou:
                best, best_iou = k, inter / union
        if best is not None and best_iou >= iou:
            used.add(best)
            hits += 1
            errors += [abs(s - truth[best][0]), abs(e - truth[best][1])]
    precision = hits / len(found) if found else (1.0 if not truth else 0.0)
    recall = hits / len(truth) if truth else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {"found": len(found), "true": len(truth), "matched": hits, "precision": precision, "recall": recall,
            "f1": f1, "boundary_errors": errors}
