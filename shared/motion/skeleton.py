"""Kinematic skeletons shared by the ASF and BVH readers, forward kinematics and the PSS.

One representation serves both formats. A joint ``j`` sits at
``p_j = p_parent + R_parent @ offset_j`` and turns by the local rotation
``L_j = C_j @ M_j @ C_j^T`` where ``C_j`` is the ASF ``axis`` pre-rotation (identity for BVH)
and ``M_j`` composes the joint's Euler channels in the joint's own order
(``euler``: a scipy sequence, lower case extrinsic as ASF, upper case intrinsic as BVH).
The global rotation is ``R_j = R_parent @ L_j``. A leaf joint's bone ends at
``p_j + R_j @ end_j`` (BVH ``End Site``).

For ASF the joint of bone ``b`` is placed at the start of the bone (the end of its parent)
and carries bone ``b``'s rotation; its children are offset by ``direction * length`` of ``b``
in the world-aligned rest frame. That is exactly the BVH convention with ``C = I`` after
folding ``C`` into the local rotation, which is how :mod:`shared.io.bvh` writes ASF clips.

Channel names are uniform across formats: ``<joint>.<dof>`` with dof one of
``tx ty tz rx ry rz`` (BVH ``Xposition`` becomes ``tx``, ``Zrotation`` becomes ``rz``).
Angles are in degrees, lengths in the skeleton's own unit; ``unit_m`` converts to metres.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

ROT_DOFS = ("rx", "ry", "rz")
TRANS_DOFS = ("tx", "ty", "tz")
#: no body has more; a bound on the work a skeleton from outside can ask for (row 1:
#: a 10,000-joint skeleton held a simulator worker 39 s)
MAX_JOINTS = 1000


@dataclass
class Joint:
    name: str
    parent: int
    offset: np.ndarray
    dofs: list[str]
    euler: str = "xyz"
    pre: np.ndarray = field(default_factory=lambda: np.eye(3))
    end: np.ndarray | None = None
    limits: dict[str, tuple[float, float]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "parent": self.parent,
            "offset": [float(v) for v in self.offset],
            "dofs": list(self.dofs),
            "euler": self.euler,
            "pre": [[float(v) for v in row] for row in self.pre],
            "end": None if self.end is None else [float(v) for v in self.end],
            "limits": {k: [float(a), float(b)] for k, (a, b) in self.limits.items()},
        }

    @classmethod
    def from_dict(cls, d: dict) -> Joint:
        return cls(
            name=str(d["name"]),
            parent=int(d["parent"]),
            offset=np.asarray(d["offset"], dtype=float),
            dofs=[str(x) for x in d["dofs"]],
            euler=str(d["euler"]),
            pre=np.asarray(d["pre"], dtype=float),
            end=None if d["end"] is None else np.asarray(d["end"], dtype=float),
            limits={k: (float(v[0]), float(v[1])) for k, v in d.get("limits", {}).items()},
        )


@dataclass
class Skeleton:
    """A kinematic tree; joints are stored parents first."""

    name: str
    joints: list[Joint]
    unit_m: float = 1.0
    up_axis: int = 1
    source_format: str = "asf"

    # ----------------------------------------------------------------- structure
    def derived(self, key, make):
        """``make()``, a value computed from the skeleton alone, once per skeleton object and
        ``key`` (a skeleton is not changed once read; :meth:`from_json` makes a new one)."""
        cache = self.__dict__.setdefault("_derived", {})
        if key not in cache:
            cache[key] = make()
        return cache[key]

    def index(self, name: str) -> int:
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise KeyError(name)

    @property
    def root(self) -> Joint:
        return self.joints[0]

    def channels(self) -> list[str]:
        return [f"{j.name}.{d}" for j in self.joints for d in j.dofs]

    def children(self, i: int) -> list[int]:
        return [k for k, j in enumerate(self.joints) if j.parent == i]

    def check(self) -> Skeleton:
        """A tree a reader could have made, or :class:`BadInput` naming the first fault: 1 to
        ``MAX_JOINTS`` joints with unique names, one root first and every joint after its
        parent (so no cycle), known degrees of freedom, an Euler order of x, y, z, finite
        offsets and pre-rotations, a positive unit and an up axis 0-2 (a
        space whose skeleton had a parent cycle was broken for good)."""
        from shared.errors import BadInput

        def fail(msg):
            raise BadInput(f"skeleton {self.name!r}: {msg}", field="skeleton")

        if not 1 <= len(self.joints) <= MAX_JOINTS:
            fail(f"must have 1 to {MAX_JOINTS} joints, has {len(self.joints)}")
        if len({j.name for j in self.joints}) != len(self.joints):
            fail("joint names must be unique")
        for i, j in enumerate(self.joints):
            if not (-1 <= j.parent < i) or (j.parent < 0) != (i == 0):
                fail(f"joint {j.name!r} does not come after its parent (a skeleton lists one root first, "
                     "then every joint after its parent)")
            if len(set(j.dofs)) != len(j.dofs) or not set(j.dofs) <= set(ROT_DOFS + TRANS_DOFS):
                fail(f"joint {j.name!r}: degrees of freedom must be distinct ones of {', '.join(ROT_DOFS + TRANS_DOFS)}")
            if len(j.euler) != 3 or sorted(j.euler.lower()) != ["x", "y", "z"]:
                fail(f"joint {j.name!r}: Euler order {j.euler!r} is not a permutation of xyz")
            shapes = [(j.offset, (3,)), (j.pre, (3, 3))] + ([] if j.end is None else [(j.end, (3,))])
            if any(np.shape(a) != sh or not np.all(np.isfinite(a)) for a, sh in shapes):
                fail(f"joint {j.name!r}: offset, end and pre-rotation must be finite 3-vectors and a 3x3 matrix")
        if not (np.isfinite(self.unit_m) and self.unit_m > 0) or self.up_axis not in (0, 1, 2):
            fail("unit_m must be positive and up_axis 0, 1 or 2")
        return self

    # ----------------------------------------------------------------- rotations
    def local_rotations(self, values: dict[str, np.ndarray], n_frames: int, joints=None) -> list[Rotation]:
        """Local rotation ``L_j = C_j M_j C_j^T`` of every joint (or of ``joints``) for every frame."""
        from scipy.spatial.transform import Rotation  # imported here: it costs 0.2 s, reading a clip needs none

        out = []
        for j in self.joints if joints is None else joints:
            seq = j.euler
            if not seq:
                out.append(Rotation.identity(n_frames))
                continue
            angles = np.zeros((n_frames, len(seq)))
            for k, ax in enumerate(seq.lower()):
                ch = f"{j.name}.r{ax}"
                if ch in values:
                    angles[:, k] = values[ch]
            m = Rotation.from_euler(seq, angles, degrees=True)
            if not np.allclose(j.pre, np.eye(3)):
                c = Rotation.from_matrix(j.pre)
                m = c * m * c.inv()
            out.append(m)
        return out

    def forward_kinematics(self, data: np.ndarray, channels: list[str], *, ends: bool = True) -> np.ndarray:
        """Joint positions in metres, shape (T, J [+ leaves], 3).

        ``data`` holds the clip's frames over ``channels``; channels the skeleton does not
        know are ignored, missing ones are zero. A joint's translation channels (the root's,
        and any other joint's: BVH files that give every joint 6 channels) add to its offset
        in its parent's frame: ``p_j = p_parent + R_parent (offset_j + t_j)`` (readers bring
        files that mean "replace the offset" to this form, :mod:`shared.io.bvh`). Compiled (numba, :mod:`shared.motion.kinematics`);
        :meth:`forward_kinematics_reference` is the same map through scipy's ``Rotation``
        and is what this one is tested against.
        """
        from shared.motion.kinematics import fk_positions

        data = np.asarray(data, dtype=float)
        n = data.shape[0]
        k = self._fk_arrays(tuple(channels), ends)
        padded = np.concatenate([data, np.zeros((n, 1))], axis=1)  # column -1: a missing channel is 0
        pos = fk_positions(np.ascontiguousarray(np.deg2rad(padded[:, k["cols"]])), k["axes"], k["intrinsic"], k["pre"],
                           k["parent"], k["offset"], np.ascontiguousarray(padded[:, k["tcols"]]), k["end_joint"],
                           k["end_offset"])
        return pos * self.unit_m

    def local_matrices(self, data: np.ndarray, channels: list[str],
                       joints: slice | np.ndarray = slice(None)) -> np.ndarray:
        """Every joint's (or the ``joints`` slice's or index array's) local rotation ``L_j = C_j M_j C_j^T``
        (T, J, 3, 3): the rotation in the world-aligned rest frame, whatever Euler order or
        axis convention the file used."""
        from shared.motion.kinematics import local_rotations

        data = np.asarray(data, dtype=float)
        k = self._fk_arrays(tuple(channels), False)
        padded = np.concatenate([data, np.zeros((data.shape[0], 1))], axis=1)
        return local_rotations(np.ascontiguousarray(np.deg2rad(padded[:, k["cols"][joints]])),
                               np.ascontiguousarray(k["axes"][joints]), np.ascontiguousarray(k["intrinsic"][joints]),
                               np.ascontiguousarray(k["pre"][joints]))

    def _fk_arrays(self, channels: tuple[str, ...], ends: bool) -> dict:
        """The skeleton packed for :func:`shared.motion.kinematics.fk_positions`, cached per channel
        layout (:meth:`derived`)."""
        return self.derived(("fk arrays", channels, ends), lambda: self._pack(channels, ends))

    def _pack(self, channels: tuple[str, ...], ends: bool) -> dict:
        nj = len(self.check().joints)
        col = {c: i for i, c in enumerate(channels)}
        axes = np.full((nj, 3), -1, dtype=np.int64)
        cols = np.full((nj, 3), -1, dtype=np.int64)
        for i, j in enumerate(self.joints):
            for k, ax in enumerate(j.euler.lower()):
                axes[i, k] = "xyz".index(ax)
                cols[i, k] = col.get(f"{j.name}.r{ax}", -1)
        parents = {j.parent for j in self.joints}
        ends_at = [i for i, j in enumerate(self.joints) if ends and j.end is not None and i not in parents]
        return {
            "cols": cols, "axes": axes, "intrinsic": np.array([j.euler.isupper() for j in self.joints]),
            "pre": np.stack([j.pre for j in self.joints]).astype(float),
            "parent": np.array([j.parent for j in self.joints], dtype=np.int64),
            "offset": np.stack([j.offset for j in self.joints]).astype(float),
            "tcols": np.array([[col.get(f"{j.name}.{d}", -1) for d in TRANS_DOFS] for j in self.joints], dtype=np.int64),
            "end_joint": np.array(ends_at, dtype=np.int64),
            "end_offset": np.array([self.joints[i].end for i in ends_at], dtype=float).reshape(-1, 3),
        }

    def continuous_angles(self, data: np.ndarray, channels: list[str], keep_first: bool = False) -> np.ndarray:
        """``data`` with every joint's rotation channels made continuous over time
        (:func:`continuous_euler`; the same rotations, so forward kinematics is unchanged).
        ``keep_first`` keeps the first frame's numbers as they are (a file read as written);
        otherwise the first frame is the answer nearest the rest pose."""
        out = np.array(data, dtype=float)
        col = {c: i for i, c in enumerate(channels)}
        for j in self.joints:
            seq = "".join(a for a in j.euler.lower() if f"{j.name}.r{a}" in col)
            if not seq:
                continue
            cols = [col[f"{j.name}.r{a}"] for a in seq]
            order = j.euler if len(seq) == 3 else seq
            out[:, cols] = continuous_euler(out[:, cols], order, out[0, cols] if keep_first else None)
        return out

    def root_matrices(self, data: np.ndarray, channels: list[str]) -> np.ndarray:
        """The root's rotation matrices (T, 3, 3) ``C M C^T`` (no scipy import): the same map
        as :meth:`global_root_rotation`."""
        return self.local_matrices(data, channels, slice(0, 1))[:, 0]

    def rest_height(self) -> float:
        """The body's height in its rest pose (all channels 0), in metres, along its up axis."""
        def height() -> float:
            rest = self.forward_kinematics(np.zeros((1, len(self.channels()))), self.channels())[0]
            return max(float(np.ptp(rest[:, self.up_axis])), 1e-6)

        return self.derived("rest height", height)

    def forward_kinematics_reference(self, data: np.ndarray, channels: list[str], *, ends: bool = True) -> np.ndarray:
        """:meth:`forward_kinematics` through scipy's ``Rotation`` (the reference it is tested against)."""
        data = np.asarray(data, dtype=float)
        n = data.shape[0]
        values = {c: data[:, i] for i, c in enumerate(channels)}
        local = self.local_rotations(values, n)
        glob = []
        pos = np.zeros((n, len(self.joints), 3))
        end_pos = []
        for i, j in enumerate(self.joints):
            t = np.stack([values.get(f"{j.name}.{d}", np.zeros(n)) for d in TRANS_DOFS], axis=1)
            if j.parent < 0:
                pos[:, i] = j.offset + t
                glob.append(local[i])
            else:
                pos[:, i] = pos[:, j.parent] + glob[j.parent].apply(j.offset + t)
                glob.append(glob[j.parent] * local[i])
            if ends and j.end is not None and not self.children(i):
                end_pos.append(pos[:, i] + glob[i].apply(j.end))
        if end_pos:
            pos = np.concatenate([pos, np.stack(end_pos, axis=1)], axis=1)
        return pos * self.unit_m

    def global_root_rotation(self, data: np.ndarray, channels: list[str]) -> Rotation:
        values = {c: np.asarray(data)[:, i] for i, c in enumerate(channels)}
        return self.local_rotations(values, np.asarray(data).shape[0], joints=[self.root])[0]

    # ----------------------------------------------------------------- persistence
    def to_json(self) -> str:
        return json.dumps(
            {
                "name": self.name,
                "unit_m": self.unit_m,
                "up_axis": self.up_axis,
                "source_format": self.source_format,
                "joints": [j.to_dict() for j in self.joints],
            }
        )

    @classmethod
    def from_json(cls, text: str) -> Skeleton:
        try:
            d = json.loads(text)
        except RecursionError:  # a payload nested past the parser's stack: refused like any bad JSON
            raise ValueError("the skeleton JSON nests too deeply") from None
        return cls(
            name=str(d["name"]),
            joints=[Joint.from_dict(j) for j in d["joints"]],
            unit_m=float(d["unit_m"]),
            up_axis=int(d.get("up_axis", 1)),
            source_format=d.get("source_format", "asf"),
        ).check()

    def __eq__(self, other) -> bool:  # dataclass eq would compare arrays element-wise
        return isinstance(other, Skeleton) and self.to_json() == other.to_json()


def other_skeleton(ours: Skeleton | None, theirs: Skeleton | None) -> str:
    """A clip's lacking channels said more plainly when its skeleton names fewer than half of
    ``ours``'s joints: it is on another skeleton (joints are matched by name); else ""."""
    if ours is None or theirs is None:
        return ""
    mine, its = [j.name for j in ours.joints], [j.name for j in theirs.joints]
    shared = len(set(mine) & set(its))
    if shared * 2 >= len(mine):
        return ""
    return (f": it is on another skeleton, {shared} of the {len(mine)} joints it is compared with are in it by name "
            f"(those: {', '.join(mine[:5])}, ...; its own: {', '.join(its[:5])}, ...); joints are matched by name, so "
            f"the clips compared must come from one skeleton (one capture set-up or dataset)")


def continuous_euler(angles_deg, seq: str, start=None) -> np.ndarray:
    """One joint's Euler angles (T, k) in degrees, continuous over time, the same rotations.

    Re-expressing a rotation as Euler angles has two answers for a Tait-Bryan sequence (``(a,
    b, c)`` and its twin ``(a + 180, 180 - b, c + 180)``) and each angle is defined modulo 360;
    a file or a conversion that picks the principal branch frame by frame jumps where a joint
    passes 90 degrees in its middle angle or 180 in another (a humerus lifted overhead). Here
    every frame takes the answer nearest the frame before (the first frame: nearest ``start``,
    default the rest pose, all zeros), so velocities, torques and centre of gravity see the
    motion and never a change of branch. With fewer than three channels, or a sequence that
    repeats an axis, each angle is only unwrapped (its other answers are other rotations)."""
    a = np.asarray(angles_deg, dtype=float)
    if a.ndim != 2 or a.shape[0] == 0:
        return a.copy()
    s = np.zeros(a.shape[1]) if start is None else np.asarray(start, dtype=float)
    if a.shape[1] == 3 and len(set(seq.lower())) == 3:
        from shared.motion.kinematics import continuous_tait_bryan

        return continuous_tait_bryan(np.ascontiguousarray(a), np.ascontiguousarray(s))
    first = s + (a[0] - s + 180.0) % 360.0 - 180.0
    return np.rad2deg(np.unwrap(np.deg2rad(np.vstack([first, a[1:]])), axis=0))


def euler_matrix(seq: str, angles_deg) -> np.ndarray:
    """One rotation matrix from Euler angles in degrees, with scipy's convention (upper-case
    ``seq``: intrinsic axes, lower-case: extrinsic), without importing scipy (ASF axes)."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    if len(seq) != len(a):
        raise ValueError(f"{len(a)} angles for Euler sequence {seq!r}")
    mats = []
    for ax, t in zip(seq.lower(), a):
        c, s = np.cos(t), np.sin(t)
        mats.append({"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
                     "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                     "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[ax])
    out = np.eye(3)
    for m in (mats if seq.isupper() else mats[::-1]):
        out = out @ m
    return out
