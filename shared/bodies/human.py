"""Human bodies for MuJoCo, built from a mocap skeleton (ASF or BVH) with ``mujoco.MjSpec``.

One MuJoCo body per bone. Frames follow :mod:`shared.skeleton` exactly, so MuJoCo's forward
kinematics equals ours: bone ``i``'s frame is ``F_i = G_parent C_i M_i`` (``C_i`` the bone's
axis rotation, ``M_i`` its Euler rotation), its body quaternion relative to the parent's frame
is ``C_parent^T C_i``, and its position is the bone offset expressed in the parent's frame
(``C_parent^T offset``). Each rotational channel is one hinge about a unit axis of the bone
frame, in the order the Euler convention composes them (upper-case sequence: intrinsic, in
order; lower-case: extrinsic, reversed). The root is a free joint. Gravity points down the
skeleton's up axis, so no axis conversion is needed.

Segment masses: de Leva (1996), *Adjustments to Zatsiorsky-Seluyanov's segment inertia
parameters*, J. Biomechanics 29(9):1223-1230, table 4 (male), as fractions of the body mass;
a segment split over several bones (trunk, head and neck, hand, foot) is shared as documented
in ``SEGMENT_SHARE``. Inertias come from capsule geometry along each bone with that mass.
Joint limits are the skeleton's (ASF ``limits``), checked in the feasibility report.
"""

from __future__ import annotations

import re

import mujoco
import numpy as np

from shared.bodies.body import Body, DofMap, check_mass
from shared.errors import BadInput
from shared.skeleton import Skeleton

# de Leva (1996) male segment masses, percent of body mass
DE_LEVA = {"head": 6.94, "upper_trunk": 15.96, "middle_trunk": 16.33, "lower_trunk": 11.17, "upper_arm": 2.71,
           "forearm": 1.62, "hand": 0.61, "thigh": 14.16, "shank": 4.33, "foot": 1.37}

# bone name (side prefix l/r removed, lower case) -> (segment, share of the segment, capsule radius m)
SEGMENT_SHARE = {
    "root": ("lower_trunk", 1.0, 0.12), "hips": ("lower_trunk", 1.0, 0.12), "pelvis": ("lower_trunk", 1.0, 0.12),
    "lowerback": ("middle_trunk", 0.5, 0.12), "upperback": ("middle_trunk", 0.5, 0.12),
    "spine": ("middle_trunk", 0.5, 0.12), "spine1": ("middle_trunk", 0.5, 0.12),
    "thorax": ("upper_trunk", 15.96 / 15.96 - 2 * 0.5 / 15.96, 0.12), "chest": ("upper_trunk", 0.94, 0.12),
    "clavicle": ("upper_trunk", 0.5 / 15.96, 0.04), "collar": ("upper_trunk", 0.03, 0.04), "shoulder": ("upper_trunk", 0.03, 0.04),
    "lowerneck": ("head", 0.15, 0.05), "upperneck": ("head", 0.15, 0.05), "neck": ("head", 0.3, 0.05),
    "head": ("head", 0.70, 0.09),
    "humerus": ("upper_arm", 1.0, 0.045), "uparm": ("upper_arm", 1.0, 0.045), "arm": ("upper_arm", 1.0, 0.045),
    "radius": ("forearm", 1.0, 0.035), "lowarm": ("forearm", 1.0, 0.035), "forearm": ("forearm", 1.0, 0.035),
    "wrist": ("hand", 0.33, 0.03), "hand": ("hand", 0.49, 0.03), "fingers": ("hand", 0.10, 0.015),
    "thumb": ("hand", 0.08, 0.015),
    "femur": ("thigh", 1.0, 0.07), "upleg": ("thigh", 1.0, 0.07), "thigh": ("thigh", 1.0, 0.07),
    "tibia": ("shank", 1.0, 0.05), "leg": ("shank", 1.0, 0.05), "shin": ("shank", 1.0, 0.05),
    "foot": ("foot", 0.8, 0.04), "toes": ("foot", 0.2, 0.025), "toebase": ("foot", 0.2, 0.025),
    "hipjoint": ("lower_trunk", 0.0, 0.02),
}
MIN_MASS = 0.01  # kg: a bone with joints but no segment of its own (MuJoCo needs mass to move)


def _segment(bone: str) -> tuple[str, float, float] | None:
    key = bone.lower()
    if key not in SEGMENT_SHARE:
        key = re.sub(r"^(l|r|left|right)_?", "", key)
    return SEGMENT_SHARE.get(key)


def _hinge_order(seq: str, dofs: list[str]) -> list[str]:
    """Rotation channels ('x', 'y', 'z') in the order MuJoCo must apply the hinges."""
    axes = [a for a in seq.lower() if f"r{a}" in dofs]
    return axes if seq.isupper() else axes[::-1]


def human_body(skeleton: Skeleton, mass: float = 70.0, name: str | None = None) -> Body:
    """A MuJoCo body of ``mass`` kg from a mocap skeleton (see module docstring)."""
    mass = check_mass(mass)
    if skeleton is None or not skeleton.joints:
        raise BadInput("a human body needs a skeleton with joints")
    sk = skeleton
    from shared.io.conventions import HUMAN_HEIGHT_M

    height = sk.rest_height()
    if not HUMAN_HEIGHT_M[0] <= height <= HUMAN_HEIGHT_M[1]:
        raise BadInput(f"skeleton {sk.name!r} is {height:.3g} m tall in its rest pose: not a person "
                       f"({HUMAN_HEIGHT_M[0]:g}-{HUMAN_HEIGHT_M[1]:g} m); is its length unit right? (--units)")
    unit = sk.unit_m
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # inverse dynamics of the motion alone: no self-contacts
    spec.modelname = name or sk.name or "human"
    g = np.zeros(3)
    g[sk.up_axis] = -9.81
    spec.option.gravity = g
    bodies = {}
    unknown = []
    for i, j in enumerate(sk.joints):
        kids = sk.children(i)
        if kids:
            seg_vec = np.mean([sk.joints[k].offset for k in kids], axis=0)
        elif j.end is not None:
            seg_vec = j.end
        else:
            seg_vec = np.zeros(3)
        pre = np.asarray(j.pre, float)
        if j.parent < 0:
            b = spec.worldbody.add_body(name=j.name)
            b.add_freejoint(name=f"{j.name}.free")
        else:
            p = sk.joints[j.parent]
            ppre = np.asarray(p.pre, float)
            rel = ppre.T @ pre
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, rel.reshape(-1))
            b = bodies[j.parent].add_body(name=j.name, pos=ppre.T @ (j.offset * unit), quat=quat)
        for a in ([] if j.parent < 0 else _hinge_order(j.euler, j.dofs)):  # the root turns with its free joint
            axis = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[a]
            b.add_joint(name=f"{j.name}.r{a}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis)
        seg = _segment(j.name)
        if seg is None:
            unknown.append(j.name)
            seg = ("", 0.0, 0.02)
        segment, share, radius = seg
        m = max(mass * DE_LEVA.get(segment, 0.0) / 100.0 * share, MIN_MASS if (j.dofs or j.parent < 0) else 0.0)
        local = pre.T @ (seg_vec * unit)
        length = float(np.linalg.norm(local))
        if m > 0:
            if length > 0.01:
                b.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=np.r_[0.1 * local, 0.9 * local],
                           size=[min(radius, 0.4 * length), 0, 0], mass=m)
            else:
                b.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], mass=m)
        bodies[i] = b
    try:
        model = spec.compile()
    except ValueError as e:
        raise BadInput(f"cannot build a MuJoCo body from skeleton {sk.name!r}: {e}") from None
    dofs = []
    for j in sk.joints:
        for a in "xyz":
            ch = f"{j.name}.r{a}"
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, ch)
            if jid >= 0:
                lim = j.limits.get(f"r{a}") if j.limits else None
                dofs.append(DofMap(ch, int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid]),
                                   None if lim is None else (float(lim[0]), float(lim[1]))))
    feet = [j.name for j in sk.joints if re.sub(r"^(l|r|left|right)_?", "", j.name.lower()) in ("foot", "toes", "toebase")]
    root = sk.joints[0].name
    return Body(name=name or f"human:{sk.name}", kind="human", model=model, dofs=dofs,
                mass=float(model.body_subtreemass[0]), skeleton=sk, root=root, feet=feet, up_axis=sk.up_axis)
