"""Human bodies for MuJoCo, built from a mocap skeleton (ASF or BVH) with ``mujoco.MjSpec``.

One MuJoCo body per bone. Frames follow :mod:`shared.motion.skeleton` exactly, so MuJoCo's forward
kinematics equals ours: bone ``i``'s frame is ``F_i = G_parent C_i M_i`` (``C_i`` the bone's
axis rotation, ``M_i`` its Euler rotation), its body quaternion relative to the parent's frame
is ``C_parent^T C_i``, and its position is the bone offset expressed in the parent's frame
(``C_parent^T offset``). Each rotational channel is one hinge about a unit axis of the bone
frame, in the order the Euler convention composes them (upper-case sequence: intrinsic, in
order; lower-case: extrinsic, reversed). The root is a free joint. Gravity points down the
skeleton's up axis, so no axis conversion is needed.

Segment masses: de Leva (1996) over the segments :mod:`shared.bodies.segments` finds from the
skeleton's tree and proportions. Inertias come from capsule geometry along each bone with
that mass.
Joint limits are the skeleton's (ASF ``limits``), checked in the feasibility report.
"""

from __future__ import annotations

import mujoco
import numpy as np

from shared.bodies.body import Body, DofMap, check_mass
from shared.bodies.segments import SEGMENTS, map_segments, segment_masses, stature
from shared.errors import BadInput
from shared.motion.skeleton import Skeleton

MIN_MASS = 0.01  # kg: a bone with joints but no segment of its own (MuJoCo needs mass to move)

def _hinge_order(seq: str, dofs: list[str]) -> list[str]:
    """Rotation channels ('x', 'y', 'z') in the order MuJoCo must apply the hinges."""
    axes = [a for a in seq.lower() if f"r{a}" in dofs]
    return axes if seq.isupper() else axes[::-1]


#: the most joints a simulated person may have: mocap skeletons have 20-70 (150 with every finger
#: joint); a 200-joint chain compiles in 0.2 s, a 1,000-joint one in 25 s
MAX_BODY_JOINTS = 200


def human_body(skeleton: Skeleton, mass: float = 70.0, name: str | None = None) -> Body:
    """A MuJoCo body of ``mass`` kg from a mocap skeleton (see module docstring)."""
    spec, seg_of, unmapped, missing = human_spec(skeleton, mass, name)
    sk = skeleton
    try:
        model = spec.compile()
    except ValueError as e:
        raise BadInput(f"cannot build a MuJoCo body from skeleton {sk.name!r}: {e}") from None
    return _body_of(model, sk, seg_of, unmapped, missing, name)


def human_spec(skeleton: Skeleton, mass: float = 70.0, name: str | None = None):
    """The ``mujoco.MjSpec`` of :func:`human_body` before it is compiled (contacts off; a caller
    that simulates the body adds a floor and turns them on), with the bones' segments, the
    unusual bones and the segments the skeleton lacks."""
    mass = check_mass(mass)
    if skeleton is None or not skeleton.joints:
        raise BadInput("a human body needs a skeleton with joints")
    if len(skeleton.joints) > MAX_BODY_JOINTS:
        raise BadInput(f"skeleton {skeleton.name!r} has {len(skeleton.joints)} joints; a simulated person has at most "
                       f"{MAX_BODY_JOINTS}", field="skeleton", limit=MAX_BODY_JOINTS)
    sk = skeleton
    from shared.io.conventions import HUMAN_HEIGHT_M

    height = stature(sk)
    if not HUMAN_HEIGHT_M[0] <= height <= HUMAN_HEIGHT_M[1]:
        raise BadInput(f"skeleton {sk.name!r} is {height:.3g} m tall (its bones from foot to head): not a person "
                       f"({HUMAN_HEIGHT_M[0]:g}-{HUMAN_HEIGHT_M[1]:g} m); is its length unit right? (--units)")
    unit = sk.unit_m
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # inverse dynamics of the motion alone: no self-contacts
    spec.modelname = name or sk.name or "human"
    g = np.zeros(3)
    g[sk.up_axis] = -9.81
    spec.option.gravity = g
    bodies: dict = {}
    seg_of, unmapped = map_segments(sk)
    masses, missing = segment_masses(seg_of, mass)
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
        if j.parent >= 0:  # position channels (6-channel skeletons) slide the bone in its parent's frame: p =
            for a in "xyz":  # p_parent + G_parent (offset + t); in the bone's own frame that axis is C_j^T e_a
                if f"t{a}" in j.dofs:
                    b.add_joint(name=f"{j.name}.t{a}", type=mujoco.mjtJoint.mjJNT_SLIDE,
                                axis=pre.T @ np.eye(3)["xyz".index(a)])
        for a in ([] if j.parent < 0 else _hinge_order(j.euler, j.dofs)):  # the root turns with its free joint
            axis = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[a]
            b.add_joint(name=f"{j.name}.r{a}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis)
        radius = SEGMENTS.get(seg_of[j.name][0], ("", 0.02))[1]
        m = max(masses[j.name], MIN_MASS if (j.dofs or j.parent < 0) else 0.0)
        local = pre.T @ (seg_vec * unit)
        length = float(np.linalg.norm(local))
        if m > 0:
            if length > 0.01:
                b.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=np.r_[0.1 * local, 0.9 * local],
                           size=[min(radius, 0.4 * length), 0, 0], mass=m)
            else:
                b.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], mass=m)
        bodies[i] = b
    return spec, seg_of, unmapped, missing


def _body_of(model: mujoco.MjModel, sk: Skeleton, seg_of: dict, unmapped: list, missing: list,
             name: str | None) -> Body:
    dofs = []
    for j in sk.joints[1:]:
        for a in "xyz":
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{j.name}.t{a}")
            if jid >= 0:
                dofs.append(DofMap(f"{j.name}.t{a}", int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid]),
                                   scale=sk.unit_m))
    for j in sk.joints:
        for a in "xyz":
            ch = f"{j.name}.r{a}"
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, ch)
            if jid >= 0:
                lim = j.limits.get(f"r{a}") if j.limits else None
                dofs.append(DofMap(ch, int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid]),
                                   None if lim is None else (float(lim[0]), float(lim[1]))))
    feet = [b for b, (seg, _) in seg_of.items() if seg == "foot"]
    root = sk.joints[0].name
    return Body(name=name or f"human:{sk.name}", kind="human", model=model, dofs=dofs,
                mass=float(model.body_subtreemass[0]), skeleton=sk, root=root, feet=feet, up_axis=sk.up_axis,
                unmapped=unmapped, missing_segments=missing)
