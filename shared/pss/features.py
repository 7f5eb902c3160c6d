"""From a clip to the feature frames an HMM sees, and back.

HDM05 angles run continuously past 360 degrees and differ between actors by whole turns, so
raw angles make poor HMM outputs (DESIGN.md: 1-NN DTW 44 % on raw angles, 64 % on sin/cos).
The representation here is turn-invariant and invertible:

* every joint rotation channel ``theta`` -> ``(sin theta, cos theta)``;
* the root's orientation without its heading: the root's swing (its rotation with the twist
  about the vertical removed) as the unit vector it turns the vertical into (3 values);
* the root's height in metres;
* the root's horizontal velocity in its own heading frame (forward, lateral, m/s) and its
  yaw rate (rad/s): where a person faces and stands on the floor is not part of a motion,
  how they move over it is;
* sensor channels (torques, centre of gravity) standardised with the space's mean and scale.

:meth:`MotionFeatures.decode` inverts the map: angles by ``atan2`` then unwrapped over time,
heading and floor position integrated from the yaw rate and the velocity (starting at 0).
"""

from __future__ import annotations

import json

import numpy as np
from scipy.spatial.transform import Rotation

from shared.clip import Clip
from shared.errors import BadInput
from shared.skeleton import Skeleton

_UP = np.array([0.0, 1.0, 0.0])


def _yaw_and_swing(rot: Rotation) -> tuple[np.ndarray, np.ndarray]:
    """Swing-twist about the vertical: ``R = Ry(psi) S``; returns psi (rad) and ``S @ up``."""
    q = rot.as_quat()  # x, y, z, w
    psi = 2.0 * np.arctan2(q[:, 1], q[:, 3])
    swing = Rotation.from_euler("y", -psi[:, None]) * rot
    return psi, swing.apply(_UP)


def _forward_diff(a: np.ndarray) -> np.ndarray:
    """``a[t+1] - a[t]`` per frame, the last frame repeating the one before."""
    if len(a) < 2:
        return np.zeros_like(a)
    d = np.diff(a, axis=0)
    return np.concatenate([d, d[-1:]], axis=0)


def _integrate(rate: np.ndarray, fps: float) -> np.ndarray:
    """Inverse of :func:`_forward_diff` (times ``fps``), starting at 0."""
    return np.concatenate([[0.0], np.cumsum(rate[:-1]) / fps])


def _swing_from_vector(v: np.ndarray) -> Rotation:
    """The rotation about a horizontal axis taking the vertical to ``v`` (a swing)."""
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    axis = np.cross(np.broadcast_to(_UP, v.shape), v)
    s = np.linalg.norm(axis, axis=1)
    c = np.clip(v @ _UP, -1.0, 1.0)
    ang = np.arctan2(s, c)
    axis = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-12)[:, None], np.array([1.0, 0.0, 0.0]))
    return Rotation.from_rotvec(axis * ang[:, None])


class MotionFeatures:
    """The invertible feature map of one space (all its clips share one skeleton layout).

    Parameters
    ----------
    skeleton : Skeleton
        Reference skeleton (its channel layout; bone lengths do not enter the features).
    motion_channels : list of str
        The clip's motion channels the space uses (angles and root translation).
    sensor_channels : list of str
        Sensor channels modelled together with the motion (``O = [M; S]``), may be empty.
    sensor_mean, sensor_scale : arrays
        Standardisation of the sensor channels (fitted by :meth:`fit`).
    """

    def __init__(self, skeleton: Skeleton | None, motion_channels: list[str], sensor_channels: list[str] | None = None,
                 sensor_mean=None, sensor_scale=None):
        self.skeleton = skeleton
        self.motion_channels = list(motion_channels)
        self.sensor_channels = list(sensor_channels or [])
        root = skeleton.root.name if skeleton is not None else None
        self.root = root
        self.angle_channels = [c for c in self.motion_channels
                               if c.split(".")[-1] in ("rx", "ry", "rz") and c.rsplit(".", 1)[0] != root]
        self.plain_channels = [c for c in self.motion_channels
                               if c not in self.angle_channels and c.rsplit(".", 1)[0] != root]
        rdofs = set(skeleton.root.dofs) if skeleton is not None else set()
        self.root_rot = bool(rdofs & {"rx", "ry", "rz"}) and any(c.startswith(f"{root}.r") for c in self.motion_channels)
        self.root_trans = bool(rdofs & {"tx", "ty", "tz"}) and any(c.startswith(f"{root}.t") for c in self.motion_channels)
        n_s = len(self.sensor_channels)
        self.sensor_mean = np.zeros(n_s) if sensor_mean is None else np.asarray(sensor_mean, float)
        self.sensor_scale = np.ones(n_s) if sensor_scale is None else np.asarray(sensor_scale, float)
        names = []
        for c in self.angle_channels:
            names += [f"sin({c})", f"cos({c})"]
        names += list(self.plain_channels)
        if self.root_rot:
            names += ["root.up_x", "root.up_y", "root.up_z"]
        if self.root_trans:
            names += ["root.height", "root.v_forward", "root.v_lateral"]
        if self.root_rot and self.root_trans:
            names += ["root.yaw_rate"]
        self.motion_feature_names = names
        self.feature_names = names + [f"std({c})" for c in self.sensor_channels]

    # ---------------------------------------------------------------- fitting
    @classmethod
    def for_clips(cls, clips: list[Clip], sensor: bool = True) -> "MotionFeatures":
        """The feature map for a set of clips: their common motion channels and, if every clip
        has them and ``sensor`` is true, their common sensor channels (standardised)."""
        if not clips:
            raise BadInput("no clips")
        first = clips[0]
        motion = first.group("motion")
        for c in clips[1:]:
            if c.group("motion") != motion:
                raise BadInput(f"clip {c.name!r} has other motion channels than {first.name!r}; a space needs one body layout")
        sensors = first.group("sensor") if sensor else []
        if sensors and any(c.group("sensor") != sensors for c in clips):
            raise BadInput("clips differ in their sensor channels")
        mean = scale = None
        if sensors:
            allv = np.vstack([c.select(sensors) for c in clips])
            mean = allv.mean(axis=0)
            scale = np.maximum(allv.std(axis=0), 1e-6 * max(1.0, float(np.abs(allv).max())))
        return cls(first.skeleton, motion, sensors, mean, scale)

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    def feature_indices(self, group: str) -> np.ndarray:
        n_m = len(self.motion_feature_names)
        if group == "motion":
            return np.arange(n_m)
        if group == "sensor":
            return np.arange(n_m, self.n_features)
        raise BadInput(f"unknown channel group {group!r}")

    # ---------------------------------------------------------------- encode
    def encode(self, clip: Clip, groups: tuple[str, ...] = ("motion", "sensor")) -> np.ndarray:
        """Feature frames (T, D) of a clip; ``groups=("motion",)`` gives the motion part only."""
        missing = [c for c in self.motion_channels if c not in clip.channels]
        if missing:
            raise BadInput(f"clip {clip.name!r} lacks {len(missing)} channels of this space, e.g. {missing[:3]}")
        cols = []
        if self.angle_channels:
            a = np.deg2rad(clip.select(self.angle_channels))
            cols.append(np.stack([np.sin(a), np.cos(a)], axis=2).reshape(len(a), -1))
        if self.plain_channels:
            cols.append(clip.select(self.plain_channels))
        if self.root_rot or self.root_trans:
            cols.append(self._root_features(clip))
        if "sensor" in groups and self.sensor_channels:
            miss = [c for c in self.sensor_channels if c not in clip.channels]
            if miss:
                raise BadInput(f"clip {clip.name!r} lacks sensor channels {miss[:3]}")
            cols.append((clip.select(self.sensor_channels) - self.sensor_mean) / self.sensor_scale)
        x = np.hstack(cols) if cols else np.zeros((clip.n_frames, 0))
        if not np.all(np.isfinite(x)):
            raise BadInput(f"clip {clip.name!r} contains NaN or Inf")
        return x

    def _root_features(self, clip: Clip) -> np.ndarray:
        sk = self.skeleton
        r = sk.root.name
        out = []
        rot = sk.global_root_rotation(clip.data, clip.channels)
        psi, up = _yaw_and_swing(rot)
        if self.root_rot:
            out.append(up)
        if self.root_trans:
            t = np.column_stack([clip.column(f"{r}.{d}") if f"{r}.{d}" in clip.channels else np.zeros(clip.n_frames)
                                 for d in ("tx", "ty", "tz")]) * sk.unit_m
            heading = np.unwrap(psi) if self.root_rot else np.zeros(clip.n_frames)
            vel = _forward_diff(t) * clip.fps
            c, s = np.cos(heading), np.sin(heading)
            # heading frame: forward = Ry(psi) z, lateral = Ry(psi) x; forward differences so
            # that decode's cumulative sum inverts them exactly
            v_fwd = s * vel[:, 0] + c * vel[:, 2]
            v_lat = c * vel[:, 0] - s * vel[:, 2]
            out.append(np.column_stack([t[:, 1], v_fwd, v_lat]))
            if self.root_rot:
                out.append(_forward_diff(heading[:, None]) * clip.fps)
        return np.hstack(out)

    # ---------------------------------------------------------------- decode
    def decode(self, x: np.ndarray, fps: float, name: str = "generated") -> Clip:
        """A clip (motion and sensor channels) from feature frames (T, D)."""
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.n_features:
            raise BadInput(f"feature frames must be T x {self.n_features}, got {x.shape}")
        n = len(x)
        values: dict[str, np.ndarray] = {}
        k = 0
        for c in self.angle_channels:
            values[c] = np.rad2deg(np.unwrap(np.arctan2(x[:, k], x[:, k + 1])))
            k += 2
        for c in self.plain_channels:
            values[c] = x[:, k]
            k += 1
        if self.root_rot or self.root_trans:
            k = self._decode_root(x, k, fps, values)
        motion = list(self.motion_channels)
        data = [values.get(c, np.zeros(n)) for c in motion]
        chans = list(motion)
        groups = {"motion": list(motion)}
        if self.sensor_channels:
            s = x[:, k:k + len(self.sensor_channels)] * self.sensor_scale + self.sensor_mean
            data += list(s.T)
            chans += self.sensor_channels
            groups["sensor"] = list(self.sensor_channels)
        return Clip(np.column_stack(data), chans, fps, self.skeleton, groups, name=name)

    def _decode_root(self, x, k, fps, values) -> int:
        sk = self.skeleton
        root = sk.root
        n = len(x)
        up = None
        if self.root_rot:
            up = x[:, k:k + 3]
            k += 3
        psi = np.zeros(n)
        if self.root_trans:
            height, v_fwd, v_lat = x[:, k], x[:, k + 1], x[:, k + 2]
            k += 3
            if self.root_rot:
                psi = _integrate(x[:, k], fps)
                k += 1
            c, s = np.cos(psi), np.sin(psi)
            px = _integrate(s * v_fwd + c * v_lat, fps)
            pz = _integrate(c * v_fwd - s * v_lat, fps)
            for d, v in zip(("tx", "ty", "tz"), (px, height, pz)):
                values[f"{root.name}.{d}"] = v / sk.unit_m
        if self.root_rot:
            rot = Rotation.from_euler("y", psi[:, None]) * _swing_from_vector(up)
            c = Rotation.from_matrix(root.pre)
            m = c.inv() * rot * c
            seq = root.euler
            ang = np.rad2deg(np.unwrap(np.deg2rad(m.as_euler(seq, degrees=True)), axis=0))
            for i, ax in enumerate(seq.lower()):
                values[f"{root.name}.r{ax}"] = ang[:, i]
        return k

    # ---------------------------------------------------------------- persistence
    def to_json(self) -> str:
        return json.dumps({
            "skeleton": None if self.skeleton is None else self.skeleton.to_json(),
            "motion_channels": self.motion_channels,
            "sensor_channels": self.sensor_channels,
            "sensor_mean": self.sensor_mean.tolist(),
            "sensor_scale": self.sensor_scale.tolist(),
        })

    @classmethod
    def from_json(cls, text: str) -> "MotionFeatures":
        d = json.loads(text)
        sk = Skeleton.from_json(d["skeleton"]) if d["skeleton"] else None
        return cls(sk, d["motion_channels"], d["sensor_channels"], d["sensor_mean"], d["sensor_scale"])
