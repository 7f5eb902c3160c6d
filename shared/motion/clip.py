"""A motion clip: frames x named channels, a frame rate, a skeleton and channel groups.

The thesis writes a motion pattern as ``M = [theta[0] ... theta[T]]`` (joint angles) and a
sensor pattern ``S`` (joint torques, centre of gravity); ``O = [M; S]`` when both are modelled
together. A :class:`Clip` holds all of them in one array; ``groups`` says which channel is
which (``motion``: joint angles and root translation, ``sensor``: torques, centre of gravity).
Angles are continuous (never wrapped frame by frame) and in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from shared.errors import BadInput
from shared.motion.skeleton import Skeleton


def time_normalised(x, n: int) -> np.ndarray:
    """Frames ``x`` (frames x columns) resampled to ``n`` frames of normalised time (first to
    first, last to last; linear)."""
    x = np.asarray(x, float)
    if len(x) == n:
        return x.copy()
    src, dst = np.linspace(0.0, 1.0, len(x)), np.linspace(0.0, 1.0, n)
    return np.column_stack([np.interp(dst, src, x[:, c]) for c in range(x.shape[1])]).reshape(n, x.shape[1])


@dataclass
class Clip:
    data: np.ndarray
    channels: list[str]
    fps: float
    skeleton: Skeleton | None = None
    groups: dict[str, list[str]] = field(default_factory=dict)
    name: str = ""
    label: str | None = None
    source: str | None = None
    read_as: dict = field(default_factory=dict)  # what the reader decided about the file (units, up axis, ...)

    def __post_init__(self):
        self.data = np.asarray(self.data, dtype=np.float64)
        if self.data.ndim != 2:
            raise BadInput(f"clip {self.name!r}: data must be frames x channels, got shape {self.data.shape}")
        if self.data.shape[1] != len(self.channels):
            raise BadInput(
                f"clip {self.name!r}: {self.data.shape[1]} data columns but {len(self.channels)} channel names"
            )
        if not np.all(np.isfinite(self.data)):
            raise BadInput(f"clip {self.name!r} contains NaN or Inf")
        if len(set(self.channels)) != len(self.channels):
            raise BadInput(f"clip {self.name!r}: duplicate channel names")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise BadInput(f"clip {self.name!r}: frame rate must be positive, got {self.fps}")
        if not self.groups:
            self.groups = {"motion": list(self.channels)}
        for g, chs in self.groups.items():
            missing = [c for c in chs if c not in self.channels]
            if missing:
                raise BadInput(f"clip {self.name!r}: group {g!r} names unknown channels {missing[:3]}")

    # ------------------------------------------------------------------ access
    @property
    def n_frames(self) -> int:
        return self.data.shape[0]

    @property
    def duration(self) -> float:
        return (self.n_frames - 1) / self.fps if self.n_frames else 0.0

    def fingerprint(self) -> tuple:
        """What the motion is, as the key of anything computed from its frames alone (the frame
        rate, the channels and a digest of the frames; not its name): small and the same for
        one motion under two names."""
        import hashlib  # imported when first used (shared.digest)

        data = np.ascontiguousarray(self.data)
        return float(self.fps), tuple(self.channels), data.shape, hashlib.blake2b(data.tobytes(), digest_size=16).digest()

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.channels.index(name)]

    def select(self, channels: list[str]) -> np.ndarray:
        idx = [self.channels.index(c) for c in channels]
        return self.data[:, idx]

    def group(self, name: str) -> list[str]:
        return list(self.groups.get(name, []))

    def with_data(self, data: np.ndarray, **changes) -> Clip:
        return replace(self, data=np.asarray(data, dtype=float), **changes)

    def frames(self, start: int, stop: int | None = None) -> Clip:
        return self.with_data(self.data[start:stop].copy())

    def add_channels(self, names: list[str], values: np.ndarray, group: str) -> Clip:
        """A new clip with extra channels (e.g. torques) appended to ``group``."""
        values = np.asarray(values, dtype=float)
        if values.shape != (self.n_frames, len(names)):
            raise BadInput(f"extra channels must be {self.n_frames} x {len(names)}, got {values.shape}")
        groups = {g: list(c) for g, c in self.groups.items()}
        groups.setdefault(group, []).extend(names)
        return replace(self, data=np.hstack([self.data, values]), channels=self.channels + list(names), groups=groups)

    # ------------------------------------------------------------------ time
    def resample(self, fps: float) -> Clip:
        """Linear resampling to ``fps`` over the same duration (angles are continuous, so
        linear interpolation never crosses a wrap)."""
        if not (np.isfinite(fps) and fps > 0):
            raise BadInput(f"frame rate must be positive, got {fps}")
        if self.n_frames < 2 or fps == self.fps:
            return replace(self, data=self.data.copy())
        n_new = int(round(self.duration * fps)) + 1
        t_old = np.arange(self.n_frames) / self.fps
        t_new = np.arange(n_new) / fps
        t_new = np.minimum(t_new, t_old[-1])
        # np.interp for every channel at once: each new frame between two old ones
        pos = np.interp(t_new, t_old, np.arange(self.n_frames, dtype=float))
        i0 = np.minimum(np.floor(pos).astype(int), self.n_frames - 2)
        w = (pos - i0)[:, None]
        out = self.data[i0] * (1.0 - w) + self.data[i0 + 1] * w
        return replace(self, data=out, fps=float(fps))

    def positions(self) -> np.ndarray:
        """Joint positions in metres by forward kinematics (T, J, 3)."""
        if self.skeleton is None:
            raise BadInput(f"clip {self.name!r} has no skeleton")
        return self.skeleton.forward_kinematics(self.data, self.channels)
