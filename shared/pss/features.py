"""From a clip to the feature frames an HMM sees, and back.

HDM05 angles run continuously past 360 degrees and differ between actors by whole turns, so
raw angles make poor HMM outputs (DESIGN.md: 1-NN DTW 44 % on raw angles, 64 % on sin/cos).
The representation here is turn-invariant and invertible:

* every joint that turns about three axes -> its rotation, not its Euler angles: the first two
  columns of its local rotation ``M = C^T L C`` in the space skeleton's joint frame (``L`` the
  rotation in the world-aligned rest frame, ``C`` the space's axis pre-rotation; 6 values, the
  continuous 6-D representation of Zhou et al., CVPR 2019). One rotation has two Euler triples
  (and each angle is defined modulo 360), and files and tools pick either: on sin/cos of the
  angles the same HDM05 squat as AMC and as the BVH written from it lay 258 apart, a different
  take 36.5. On ``L`` they are the same numbers, whatever the Euler order, axis
  convention or branch of the file; so are the HMM distances (eq. 2.4) the coach's ``d_p``
  and the estimator decide on;
* every other rotation channel ``theta`` (joints turning about one or two axes, whose Euler
  angles are unique modulo 360) -> ``(sin theta, cos theta)``, read in the space's own
  convention: a clip whose skeleton composes the joint's rotation otherwise (a BVH written
  from an AMC clip: ZXY angles of the folded rotation) has that rotation re-expressed as the
  reference skeleton's Euler angles (the branch that keeps the channels the joint lacks at 0);
  spaces saved before the rotations read every angle this way (``rotations="sincos"``);
* the root's orientation without its heading: the root's swing (its rotation with the twist
  about the vertical removed) as the unit vector it turns the vertical into (3 values). The
  rotation is the body's, not the root joint's: the root's frame turned onto the body's axes
  (:func:`shared.bodies.segments.body_frame`, trunk up and feet forward, saved with the space
  as ``frame``), so a studio whose hips rest with X up reads the same heading as HDM05; a
  space saved before it (no ``frame``) keeps the root's own frame;
* the root's height in metres;
* the root's horizontal velocity in its own heading frame (forward, lateral, m/s) and its
  yaw rate (rad/s): where a person faces and stands on the floor is not part of a motion,
  how they move over it is;
* sensor channels (torques, centre of gravity) standardised with the space's mean and scale.

These are the channel groups generation reads (``motion`` and ``sensor``). Angles are the
wrong channels for *telling motions apart* (sin/cos of Euler angles make distant poses look
alike and near poses far; DESIGN.md), so a space of clips with a skeleton also models a
``position`` group that recognition reads and generation ignores:

* every joint and end site in the body's heading frame (relative to the root, turned by
  minus the root's heading about the vertical), divided by the body's length (ankle to the
  head's base along the bones, :func:`shared.bodies.segments.stature`: no end site and no
  rest pose enters; a space saved before it divides by the rest pose's height), so where a
  person stands or faces and how tall they are do not enter;
* the root's height, swing vector, forward and lateral velocity (in body lengths, each a mean
  over ``travel_window`` seconds around the frame: where the body travels, not the sway of
  each step; the raw velocities in spaces saved before it) and yaw rate;
* all of it z-scored per channel with the space's mean and scale.

One HMM models all groups (its states align on every channel); :meth:`feature_indices`
says which outputs belong to which group.

:meth:`MotionFeatures.decode` inverts the map: rotations by Gram-Schmidt on the two columns,
then the skeleton's Euler angles on the branch nearest the frame before
(:func:`shared.motion.skeleton.continuous_euler`); angles by ``atan2`` then unwrapped over time;
heading and floor position integrated from the yaw rate and the velocity (starting at 0).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.bodies.segments import body_frame, stature
from shared.errors import BadInput
from shared.motion.clip import Clip
from shared.motion.skeleton import Skeleton, other_skeleton
from shared.pss.foreign import is_foreign, read_points, same_layout

if TYPE_CHECKING:  # scipy's Rotation costs 0.4 s to import; only generation (decode) needs it
    from scipy.spatial.transform import Rotation

_UP = np.array([0.0, 1.0, 0.0])
#: seconds the position group's travel velocities are averaged over (every new space). Chosen on
#: the game studio's 8 training styles of bench.styles' half split (leave one style out: closed
#: set 44.3 % raw, 52.3 % at 0.5 s, 58.0 % at 1 s and 2 s, 56.8 % at 3 s; ties to the shorter
#: window; dg held at 100 %; scored by the nearest proto-symbol's label, 84.1-85.2 % with the
#: discriminant in it: docs/pss.md). Not clean: the held-out styles were scored at four windows
#: before (best 2 s), HDM05's bd and bk splits at 0, 1 and 2 s (2 s lost a bd clip).
TRAVEL_WINDOW = 1.0
#: the position group's outputs of how the body travels over the floor (the rest of the group is its pose)
TRAVEL_FEATURES = ("pos(root).v_forward", "pos(root).v_lateral", "pos(root).yaw_rate")


def moving_mean(x: np.ndarray, width: int) -> np.ndarray:
    """Centred mean over ``width`` frames (odd) of each column, the ends repeated beyond the
    clip (scipy's ``uniform_filter1d(x, width, axis=0, mode="nearest")``, without scipy's
    import in a one-clip command)."""
    h = width // 2
    if h < 1 or len(x) == 0:
        return np.array(x, float)
    padded = np.concatenate([np.repeat(x[:1], h, axis=0), x, np.repeat(x[-1:], h, axis=0)])
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(padded, axis=0)])
    return (c[width:] - c[:-width]) / width


def _yaw_and_swing(rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Swing-twist about the vertical of rotation matrices (T, 3, 3): ``R = Ry(psi) S``;
    returns psi (rad, modulo 2 pi) and ``S @ up``.

    The twist's quaternion is ``(q_w, 0, q_y, 0)`` normalised, so ``psi = 2 atan2(q_y, q_w)``;
    ``4 q_w q_y = R_02 - R_20`` and ``4 q_w^2 = 1 + trace R`` give it without a quaternion."""
    psi = 2.0 * np.arctan2(rot[:, 0, 2] - rot[:, 2, 0], 1.0 + np.trace(rot, axis1=1, axis2=2))
    r_up = rot[:, :, 1]  # R @ up
    c, s = np.cos(psi), np.sin(psi)
    # Ry(-psi) @ v: x' = c x - s z, z' = s x + c z
    up = np.column_stack([c * r_up[:, 0] - s * r_up[:, 2], r_up[:, 1], s * r_up[:, 0] + c * r_up[:, 2]])
    return psi, up


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
    from scipy.spatial.transform import Rotation

    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    axis = np.cross(np.broadcast_to(_UP, v.shape), v)
    s = np.linalg.norm(axis, axis=1)
    c = np.clip(v @ _UP, -1.0, 1.0)
    ang = np.arctan2(s, c)
    axis = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-12)[:, None], np.array([1.0, 0.0, 0.0]))
    return Rotation.from_rotvec(axis * ang[:, None])


def _needed(sk: Skeleton | None) -> Skeleton:
    if sk is None:
        raise BadInput("this feature map has no skeleton (its space was built from clips without one)")
    return sk


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
    rotations : {"6d", "sincos"}
        How three-axis joints enter: their rotation (``"6d"``, every new space) or sin/cos of
        their Euler angles (``"sincos"``, spaces saved before the rotations).
    """

    def __init__(self, skeleton: Skeleton | None, motion_channels: list[str], sensor_channels: list[str] | None = None,
                 sensor_mean=None, sensor_scale=None, position_mean=None, position_scale=None, rotations: str = "6d",
                 frame=None, travel_window: float = 0.0):
        self.skeleton = skeleton
        #: seconds the position group's travel velocities are averaged over (0: as they are)
        self.travel_window = float(travel_window)
        #: the body frame ``B`` of the space's skeleton (:func:`shared.bodies.segments.body_frame`);
        #: None for spaces saved before it (the root's own frame, heights from the rest pose)
        self.frame = None if frame is None else np.asarray(frame, float).reshape(3, 3)
        self.motion_channels = list(motion_channels)
        self.sensor_channels = list(sensor_channels or [])
        root = skeleton.root.name if skeleton is not None else None
        self.root = root
        self.angle_channels = [c for c in self.motion_channels
                               if c.split(".")[-1] in ("rx", "ry", "rz") and c.rsplit(".", 1)[0] != root]
        if rotations not in ("6d", "sincos"):
            raise BadInput(f"rotations must be '6d' or 'sincos', got {rotations!r}")
        self.rotations = rotations
        per_joint: dict[str, list[str]] = {}
        for c in self.angle_channels:
            per_joint.setdefault(c.rsplit(".", 1)[0], []).append(c)
        #: joints whose rotation (not its Euler angles) is modelled
        self.rot_joints = [j for j, chs in per_joint.items() if len(chs) == 3] if (
            rotations == "6d" and skeleton is not None) else []
        #: their axis pre-rotations ``C`` in the space's skeleton (R, 3, 3)
        self.rot_pre = np.array([skeleton.joints[skeleton.index(j)].pre for j in self.rot_joints]
                                if skeleton is not None else [], dtype=np.float64).reshape(-1, 3, 3)
        self.sincos_channels = [c for c in self.angle_channels if c.rsplit(".", 1)[0] not in self.rot_joints]
        self.plain_channels = [c for c in self.motion_channels
                               if c not in self.angle_channels and c.rsplit(".", 1)[0] != root]
        rdofs = set(skeleton.root.dofs) if skeleton is not None else set()
        self.root_rot = bool(rdofs & {"rx", "ry", "rz"}) and any(c.startswith(f"{root}.r") for c in self.motion_channels)
        self.root_trans = bool(rdofs & {"tx", "ty", "tz"}) and any(c.startswith(f"{root}.t") for c in self.motion_channels)
        n_s = len(self.sensor_channels)
        self.sensor_mean = np.zeros(n_s) if sensor_mean is None else np.asarray(sensor_mean, float)
        self.sensor_scale = np.ones(n_s) if sensor_scale is None else np.asarray(sensor_scale, float)
        names = [f"rot({j}).{r}{k}" for j in self.rot_joints for k in (0, 1) for r in "xyz"]
        for c in self.sincos_channels:
            names += [f"sin({c})", f"cos({c})"]
        names += list(self.plain_channels)
        if self.root_rot:
            names += ["root.up_x", "root.up_y", "root.up_z"]
        if self.root_trans:
            names += ["root.height", "root.v_forward", "root.v_lateral"]
        if self.root_rot and self.root_trans:
            names += ["root.yaw_rate"]
        self.motion_feature_names = names
        self.position_feature_names = self._position_names() if position_mean is not None else []
        n_p = len(self.position_feature_names)
        self.position_mean = np.zeros(n_p) if position_mean is None else np.asarray(position_mean, float)
        self.position_scale = np.ones(n_p) if position_scale is None else np.asarray(position_scale, float)
        if self.position_mean.shape != (n_p,) or self.position_scale.shape != (n_p,):
            raise BadInput(f"position standardisation needs {n_p} values per statistic")
        self.feature_names = names + self.position_feature_names + [f"std({c})" for c in self.sensor_channels]
        self._angle_joints: tuple | None = None  # (names, Euler orders, pre-rotations) of the angle joints, for _foreign

    # ---------------------------------------------------------------- the position group
    def _position_names(self) -> list[str]:
        sk = self.skeleton
        if sk is None or not (self.root_rot and self.root_trans):
            return []
        pts = [j.name for j in sk.joints[1:]]
        parents = {j.parent for j in sk.joints}
        pts += [f"{j.name}.end" for i, j in enumerate(sk.joints) if j.end is not None and i not in parents]
        names = [f"pos({p}).{a}" for p in pts for a in "xyz"]
        return names + ["pos(root).height", "pos(root).up_x", "pos(root).up_y", "pos(root).up_z", *TRAVEL_FEATURES]

    @property
    def has_position(self) -> bool:
        return bool(self.position_feature_names)

    @property
    def sk(self) -> Skeleton:
        """The space's skeleton, for the features that need one (a map without one has none of them)."""
        return _needed(self.skeleton)

    def body(self, clip: Clip) -> Skeleton | None:
        """The skeleton to read a clip with: its own (its bone lengths, Euler orders and axis
        conventions) when it has the space's joints, else the space's (None: a space without one)."""
        sk = clip.skeleton
        if sk is not None and self.skeleton is not None and same_layout(sk, self.skeleton):
            return sk
        return self.skeleton

    def _whole(self, clip: Clip) -> Skeleton | None:
        """The skeleton a clip's root and joints' positions are read with: :meth:`body`, or the clip's
        own when it is another studio's (:mod:`shared.pss.foreign`)."""
        return clip.skeleton if is_foreign(clip.skeleton, self.skeleton) else self.body(clip)

    def positions(self, clip: Clip) -> np.ndarray:
        """The position group alone (T, P), z-scored: no joint angle read, so a clip on another
        person's skeleton has it too (:mod:`shared.pss.foreign`)."""
        root, heading = self._root_terms(clip)
        x = (self._raw_positions(clip, root, heading) - self.position_mean) / self.position_scale
        if not np.all(np.isfinite(x)):
            raise BadInput(f"clip {clip.name!r} contains NaN or Inf")
        return x

    def _raw_positions(self, clip: Clip, root_terms: np.ndarray, psi: np.ndarray) -> np.ndarray:
        """The position group before z-scoring: joints in the heading frame ``psi``, in body heights."""
        sk = _needed(self._whole(clip))
        p = sk.forward_kinematics(clip.data, clip.channels)  # (T, J + ends, 3) metres, Y up, in sk's order
        if sk is not self.skeleton:  # the same joints in another order (a BVH lists them depth first), or another's
            p = read_points(p, sk, self.sk)
        height = sk.rest_height() if self.frame is None else stature(sk, head_top=False)
        rel = (p[:, 1:] - p[:, :1]) / height
        c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
        x = c * rel[..., 0] - s * rel[..., 2]
        z = s * rel[..., 0] + c * rel[..., 2]
        body = np.stack([x, rel[..., 1], z], axis=-1).reshape(len(p), -1)
        up, height_m, v_fwd, v_lat, yaw = (root_terms[:, 0:3], root_terms[:, 3], root_terms[:, 4], root_terms[:, 5],
                                          root_terms[:, 6])
        if self.travel_window > 0:
            width = max(1, int(round(self.travel_window * clip.fps))) | 1
            v_fwd, v_lat = moving_mean(np.column_stack([v_fwd, v_lat]), width).T
        return np.column_stack([body, height_m / height, up, v_fwd / height, v_lat / height, yaw])

    # ---------------------------------------------------------------- fitting
    @classmethod
    def for_clips(cls, clips, sensor: bool = True, on_clip=None) -> MotionFeatures:
        """The feature map for a set of clips: their common motion channels and, if every clip
        has them and ``sensor`` is true, their common sensor channels (standardised).

        ``clips`` is any sequence (``len`` and indexing); each clip is taken once, in order, and
        not kept: a lazy sequence that reads a clip when indexed (:class:`shared.io.LazyClips`)
        has one clip in memory at a time. ``on_clip(clip)`` is called with each as it is read."""
        if not len(clips):
            raise BadInput("no clips")
        first = clips[0]
        motion = first.group("motion")
        layout = first.skeleton
        sensors = first.group("sensor") if sensor else []
        frame = None if first.skeleton is None else body_frame(first.skeleton, first.data, first.channels)
        base = cls(first.skeleton, motion, [], None, None, frame=frame, travel_window=TRAVEL_WINDOW)
        positions = bool(base._position_names())
        # the mean and deviation over every frame of every clip, clip by clip (a stack of all the
        # frames held 0.5 GB for 1,000 game-studio clips); shifted by the first clip's mean
        sums: dict[str, Any] = {"sensor": None, "position": None}  # [shift, total, squares] once a clip came
        count, largest = 0, 0.0

        def add(key: str, values: np.ndarray) -> None:
            if sums[key] is None:
                shift = values.mean(axis=0)
                sums[key] = [shift, np.zeros_like(shift), np.zeros_like(shift)]
            shift, total, squares = sums[key]
            d = values - shift
            total += d.sum(axis=0)
            squares += (d * d).sum(axis=0)

        for i in range(len(clips)):
            c = first if i == 0 else clips[i]
            same = (c.skeleton is not None and same_layout(c.skeleton, layout)) if layout else c.group("motion") == motion
            if not same:
                raise BadInput(f"clip {c.name!r} has another body layout than {first.name!r} (joints or motion channels); "
                               "a space needs one")
            if sensors:
                if c.group("sensor") != sensors:
                    raise BadInput("clips differ in their sensor channels")
                v = c.select(sensors)
                add("sensor", v)
                largest = max(largest, float(np.abs(v).max()))
            if positions:
                add("position", base._raw_positions(c, *base._root_terms(c)))
            count += c.n_frames
            if on_clip is not None:
                on_clip(c)

        def moments(key: str) -> tuple[np.ndarray, np.ndarray]:
            shift, total, squares = sums[key]
            mean_d = total / count
            return shift + mean_d, np.sqrt(np.maximum(squares / count - mean_d * mean_d, 0.0))

        mean = scale = p_mean = p_scale = None
        if sensors:
            mean, std = moments("sensor")
            scale = np.maximum(std, 1e-6 * max(1.0, largest))
        if positions:
            p_mean, std = moments("position")
            p_scale = np.maximum(std, 1e-3)
        return cls(first.skeleton, motion, sensors, mean, scale, p_mean, p_scale, frame=frame,
                   travel_window=TRAVEL_WINDOW)

    # ---------------------------------------------------------------- other conventions
    def _foreign(self, clip: Clip) -> Skeleton | None:
        """The clip's own skeleton when it composes some joint's rotation otherwise than the
        space's (another Euler order or axis pre-rotation), else None."""
        body = self.body(clip)
        if body is None or body is self.skeleton:  # (a space without a skeleton: None)
            return None
        ref = self._angle_joints
        if ref is None:  # the space's own convention of the joints that carry angle channels, once
            names = list(dict.fromkeys(c.rsplit(".", 1)[0] for c in self.angle_channels))
            joints = [self.sk.joints[self.sk.index(n)] for n in names]
            ref = self._angle_joints = (names, [j.euler for j in joints],
                                        np.array([j.pre for j in joints]).reshape(len(joints), 3, 3))
        names, eulers, pres = ref
        index = {j.name: i for i, j in enumerate(body.joints)}
        if any(n not in index for n in names):
            return body  # encode() names the missing channels
        theirs = [body.joints[index[n]] for n in names]
        if [j.euler for j in theirs] != eulers:
            return body
        if names and np.abs(np.array([j.pre for j in theirs]).reshape(len(names), 3, 3) - pres).max() > 1e-6:
            return body
        return None

    def _angles(self, clip: Clip, body: Skeleton | None) -> np.ndarray:
        """The sin/cos angle channels (T, n) in degrees, in the space's convention (module
        docstring); ``body`` is :meth:`_foreign`'s answer for the clip."""
        if body is None:
            return clip.select(self.sincos_channels)
        from scipy.spatial.transform import Rotation

        local = body.local_matrices(clip.data, clip.channels)
        out = np.zeros((clip.n_frames, len(self.sincos_channels)))
        col = {c: i for i, c in enumerate(self.sincos_channels)}
        for name in dict.fromkeys(c.rsplit(".", 1)[0] for c in self.sincos_channels):
            ref = self.sk.joints[self.sk.index(name)]
            m = ref.pre.T @ local[:, body.index(name)] @ ref.pre
            seq = ref.euler
            one = Rotation.from_matrix(m).as_euler(seq)
            axes = seq.lower()
            have = np.array([f"{name}.r{a}" in col for a in axes])
            if len(set(axes)) == 3 and not have.all():  # Tait-Bryan with a channel the joint lacks: the
                # twin (a + pi, pi - b, c + pi) is the same rotation; take it where it keeps that channel at 0
                two = one + np.array([np.pi, 0.0, np.pi])
                two[:, 1] = np.pi - one[:, 1]
                off = [np.sum(np.abs(np.angle(np.exp(1j * x[:, ~have]))), axis=1) for x in (one, two)]
                one = np.where((off[1] < off[0])[:, None], two, one)
            for k, a in enumerate(axes):
                if have[k]:
                    out[:, col[f"{name}.r{a}"]] = np.rad2deg(one[:, k])
        return out

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    def feature_indices(self, group: str) -> np.ndarray:
        """Indices of one channel group's outputs: ``motion``, ``position`` or ``sensor``."""
        n_m = len(self.motion_feature_names)
        n_p = len(self.position_feature_names)
        if group == "motion":
            return np.arange(n_m)
        if group == "position":
            return np.arange(n_m, n_m + n_p)
        if group == "sensor":
            return np.arange(n_m + n_p, self.n_features)
        raise BadInput(f"unknown channel group {group!r}")

    def group_indices(self, groups) -> np.ndarray:
        """Indices of several groups, in output order."""
        return np.sort(np.concatenate([self.feature_indices(g) for g in groups]))

    # ---------------------------------------------------------------- encode
    def encode(self, clip: Clip, groups: tuple[str, ...] = ("motion", "position", "sensor")) -> np.ndarray:
        """Feature frames (T, D) of a clip, its groups in output order; ``groups=("motion",)``
        gives the motion part only."""
        foreign = self._foreign(clip)
        if foreign is not None:  # the same joints, rotations under their own names (no rotation channel: no turn)
            joints = dict.fromkeys(c.rsplit(".", 1)[0] for c in self.angle_channels)
            missing = [f"{j}.{d}" for j in joints for d in foreign.joints[foreign.index(j)].dofs
                       if d.startswith("r") and f"{j}.{d}" not in clip.channels]
            missing += [c for c in self.motion_channels if c not in clip.channels and c not in self.angle_channels]
        else:
            missing = [c for c in self.motion_channels if c not in clip.channels]
        if missing:
            raise BadInput(f"clip {clip.name!r} lacks {len(missing)} channels of this space, e.g. {missing[:3]}"
                           + other_skeleton(self.skeleton, clip.skeleton))
        cols = []
        if self.rot_joints:
            cols.append(self._rotations(clip))
        if self.sincos_channels:
            a = np.deg2rad(self._angles(clip, foreign))
            cols.append(np.stack([np.sin(a), np.cos(a)], axis=2).reshape(len(a), -1))
        if self.plain_channels:
            cols.append(clip.select(self.plain_channels))
        root, heading = self._root_terms(clip) if (self.root_rot or self.root_trans) else (None, None)
        if root is not None:
            cols.append(root)
        if "position" in groups and self.has_position:
            assert root is not None and heading is not None  # (positions are had with the root's terms)
            cols.append((self._raw_positions(clip, root, heading) - self.position_mean) / self.position_scale)
        if "sensor" in groups and self.sensor_channels:
            miss = [c for c in self.sensor_channels if c not in clip.channels]
            if miss:
                raise BadInput(f"clip {clip.name!r} lacks sensor channels {miss[:3]}")
            cols.append((clip.select(self.sensor_channels) - self.sensor_mean) / self.sensor_scale)
        x = np.hstack(cols) if cols else np.zeros((clip.n_frames, 0))
        if not np.all(np.isfinite(x)):
            raise BadInput(f"clip {clip.name!r} contains NaN or Inf")
        return x

    def _rotations(self, clip: Clip) -> np.ndarray:
        """The three-axis joints' rotations (T, 6 R): the first two columns of each one's local
        rotation in the space skeleton's joint frame, ``M = C^T L C`` with ``L`` the clip's
        rotation in the world-aligned rest frame (module docstring)."""
        body = _needed(self.body(clip))
        local = body.local_matrices(clip.data, clip.channels, body.derived(
            ("rows", tuple(self.rot_joints)), lambda: np.array([body.index(j) for j in self.rot_joints])))
        m = np.swapaxes(self.rot_pre, 1, 2) @ local @ self.rot_pre  # C^T L C: the space's own joint frame
        return np.ascontiguousarray(m[..., :2].transpose(0, 1, 3, 2)).reshape(clip.n_frames, -1)

    def _decode_rotations(self, x: np.ndarray, values: dict) -> None:
        """Euler channels of the three-axis joints from their 6-D rotations (T, 6 R): Gram-Schmidt
        gives ``M``, and ``M`` the skeleton's Euler angles on a continuous branch."""
        from scipy.spatial.transform import Rotation

        from shared.motion.skeleton import continuous_euler

        cols = x.reshape(len(x), len(self.rot_joints), 2, 3)
        a, b = cols[:, :, 0], cols[:, :, 1]
        e1 = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
        b = b - np.sum(e1 * b, axis=-1, keepdims=True) * e1
        e2 = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-12)
        local = np.stack([e1, e2, np.cross(e1, e2)], axis=-1)  # columns of M
        for k, name in enumerate(self.rot_joints):
            j = self.sk.joints[self.sk.index(name)]
            m = local[:, k]  # already in the joint's own frame (M = C^T L C)
            ang = continuous_euler(Rotation.from_matrix(m).as_euler(j.euler, degrees=True), j.euler)
            for i, ax in enumerate(j.euler.lower()):
                values[f"{name}.r{ax}"] = ang[:, i]

    def _root_features(self, clip: Clip) -> np.ndarray:
        return self._root_terms(clip)[0]

    def _root_terms(self, clip: Clip) -> tuple[np.ndarray, np.ndarray]:
        """The root's motion features and its unwrapped heading (rad) per frame."""
        sk = _needed(self._whole(clip))
        r = sk.root.name
        out = []
        rot = sk.root_matrices(clip.data, clip.channels)
        if self.frame is not None:  # the body's axes, whatever rest frame the studio gave the root
            rot = rot @ (self.frame if sk is self.skeleton else body_frame(sk, clip.data, clip.channels))
        psi, up = _yaw_and_swing(rot)
        if self.root_rot:
            out.append(up)
        if self.root_trans:
            t = np.column_stack([clip.column(f"{r}.{d}") if f"{r}.{d}" in clip.channels else np.zeros(clip.n_frames)
                                 for d in ("tx", "ty", "tz")])
            t = (sk.root.offset + t) * sk.unit_m  # the root's position: its offset plus its channels
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
        return np.hstack(out), np.unwrap(psi)

    # ---------------------------------------------------------------- decode
    def decode(self, x: np.ndarray, fps: float, name: str = "generated") -> Clip:
        """A clip (motion and sensor channels) from feature frames (T, D)."""
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.n_features:
            raise BadInput(f"feature frames must be T x {self.n_features}, got {x.shape}")
        n = len(x)
        values: dict[str, np.ndarray] = {}
        k = 6 * len(self.rot_joints)
        if self.rot_joints:
            self._decode_rotations(x[:, :k], values)
        for c in self.sincos_channels:
            values[c] = np.rad2deg(np.unwrap(np.arctan2(x[:, k], x[:, k + 1])))
            k += 2
        for c in self.plain_channels:
            values[c] = x[:, k]
            k += 1
        if self.root_rot or self.root_trans:
            k = self._decode_root(x, k, fps, values)
        k += len(self.position_feature_names)  # recognition channels: generation does not read them
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
        sk = self.sk
        root = sk.root
        n = len(x)
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
                values[f"{root.name}.{d}"] = v / sk.unit_m - root.offset["xyz".index(d[1])]
        if self.root_rot:
            from scipy.spatial.transform import Rotation

            rot = Rotation.from_euler("y", psi[:, None]) * _swing_from_vector(up)
            if self.frame is not None:  # from the body's axes back to the root's
                rot = rot * Rotation.from_matrix(self.frame.T)
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
            "rotations": self.rotations,
            **({} if self.frame is None else {"frame": self.frame.tolist()}),
            **({"travel_window": self.travel_window} if self.travel_window else {}),
            **({"position_mean": self.position_mean.tolist(), "position_scale": self.position_scale.tolist()}
               if self.has_position else {}),
        })

    @classmethod
    def from_json(cls, text: str) -> MotionFeatures:
        d = json.loads(text)
        sk = Skeleton.from_json(d["skeleton"]) if d["skeleton"] else None
        return cls(sk, d["motion_channels"], d["sensor_channels"], d["sensor_mean"], d["sensor_scale"],
                   d.get("position_mean"), d.get("position_scale"), d.get("rotations", "sincos"), d.get("frame"),
                   d.get("travel_window", 0.0))
