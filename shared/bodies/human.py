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
a segment is shared equally by the bones a naming scheme maps to it (:func:`map_segments`;
fingers belong to the hand, toes to the foot), and the mass of segments a skeleton lacks is
spread over the others so that the body weighs what was asked. Inertias come from capsule
geometry along each bone with that mass.
Joint limits are the skeleton's (ASF ``limits``), checked in the feasibility report.
"""

from __future__ import annotations

import re

import mujoco
import numpy as np

from shared.bodies.body import Body, DofMap, check_mass
from shared.errors import BadInput
from shared.skeleton import Skeleton

MIN_MASS = 0.01  # kg: a bone with joints but no segment of its own (MuJoCo needs mass to move)

# ---------------------------------------------------------------------------- naming schemes
# Skeletons name bones after the bone (Mixamo ``LeftUpLeg``, ASF ``lfemur``, UE ``thigh_l``,
# Character Creator ``CC_Base_L_Thigh``) or after the joint the bone starts at (CMU BVH
# ``LeftHip`` is the thigh, ``LeftShoulder`` the upper arm). A name is reduced to a side and a
# keyword, and the keyword is read in the scheme the whole skeleton uses.
_PREFIX = re.compile(r"^(mixamorig\d*[:_]|cc_base_|bip0?1[ _]|def[-_]|org[-_]|joint[-_]|jnt[-_]|bone[-_])+")
_BONE_NAMED = {
    "hips": "pelvis", "hip": "pelvis", "pelvis": "pelvis", "root": "pelvis",
    "spine": "spine", "waist": "spine", "chest": "spine", "abdomen": "spine", "torso": "spine", "lowerback": "spine",
    "upperback": "spine", "thorax": "spine", "back": "spine",
    "neck": "neck", "lowerneck": "neck", "upperneck": "neck", "necktwist": "neck", "head": "head",
    "clavicle": "clavicle", "collar": "clavicle", "shoulder": "clavicle",
    "upperarm": "upper_arm", "uparm": "upper_arm", "arm": "upper_arm", "humerus": "upper_arm",
    "forearm": "forearm", "lowerarm": "forearm", "lowarm": "forearm", "radius": "forearm", "elbow": "forearm",
    "hand": "hand", "wrist": "hand", "fingers": "hand", "finger": "hand", "thumb": "hand",
    "upleg": "thigh", "upperleg": "thigh", "thigh": "thigh", "femur": "thigh",
    "leg": "shank", "lowerleg": "shank", "calf": "shank", "shin": "shank", "tibia": "shank", "knee": "shank",
    "foot": "foot", "ankle": "foot", "toe": "foot", "toes": "foot", "toebase": "foot", "ball": "foot",
    "hipjoint": "hipjoint",
}
_BONE_PREFIXES = (("spine", "spine"), ("chest", "spine"), ("neck", "neck"), ("head", "head"), ("toe", "foot"),
                  ("foot", "foot"), ("hand", "hand"), ("finger", "hand"), ("thumb", "hand"), ("index", "hand"),
                  ("middle", "hand"), ("ring", "hand"), ("pinky", "hand"))
#: words that name a finger only below a hand (``MiddleSpineJoint`` is a spine)
_FINGER_WORDS = {"finger", "thumb", "index", "middle", "ring", "pinky"}
# joint-named schemes (CMU BVH): the bone that starts at the joint
_JOINT_NAMED = {"hip": "thigh", "knee": "shank", "ankle": "foot", "shoulder": "upper_arm", "elbow": "forearm",
                "wrist": "hand", "collar": "clavicle"}
# segment -> (de Leva share, capsule radius m)
_SEGMENTS = {
    "pelvis": ("lower_trunk", 0.12), "spine": ("trunk", 0.12), "neck": ("neck", 0.05), "head": ("head", 0.09),
    "clavicle": ("clavicle", 0.04), "upper_arm": ("upper_arm", 0.045), "forearm": ("forearm", 0.035),
    "hand": ("hand", 0.03), "thigh": ("thigh", 0.07), "shank": ("shank", 0.05), "foot": ("foot", 0.04),
    "hipjoint": ("", 0.02),
}
# de Leva (1996) male, percent of body mass; the middle and upper trunk shared by the spine
# bones less what the clavicles take; head 6.94 % split head 70 % / neck 30 %
_PERCENT = {"lower_trunk": 11.17, "trunk": 16.33 + 15.96 - 2 * 0.5, "clavicle": 0.5, "neck": 0.3 * 6.94,
            "head": 0.7 * 6.94, "upper_arm": 2.71, "forearm": 1.62, "hand": 0.61, "thigh": 14.16, "shank": 4.33,
            "foot": 1.37}
_SIDED = {"clavicle", "upper_arm", "forearm", "hand", "thigh", "shank", "foot"}


def name_parts(bone: str) -> tuple[str, str]:
    """(side ``"l"``/``"r"``/``""``, keyword) of a bone name in any of the schemes above."""
    n = _PREFIX.sub("", bone.lower())
    side = ""
    for pat in (r"^(left|right)[_. ]?", r"[_. ](left|right)$", r"^(l|r)[_. ]", r"[_. ](l|r)$", r"[_. ](l|r)[_. ]"):
        m = re.search(pat, n)
        if m:
            side, n = m.group(1)[0], (n[:m.start()] + " " + n[m.end():]).strip()
            break
    else:
        m = re.match(r"^(l|r)(?=[a-z]{3})", n)  # ASF lfemur, CMU lhand
        if m and re.sub(r"\d+$", "", n[1:]) in set(_BONE_NAMED) | set(_JOINT_NAMED) | {"fingers", "thumb", "toes"}:
            side, n = m.group(1), n[1:]
    n = re.sub(r"[^a-z0-9]+", "", n)
    n = re.sub(r"(end|twist\d*|roll|nub|site)$", "", n)
    if n.endswith("joint") and n not in ("joint", "hipjoint"):  # MiddleSpineJoint, LeftKneeJoint: the bone's word
        n = n[:-len("joint")]
    return side, n


def map_segments(sk: Skeleton) -> tuple[dict[str, tuple[str, str]], list[str]]:
    """Every bone's (segment, side) and the bones no scheme names. A bone no scheme names
    belongs to its parent's segment (fingers to the hand, toes to the foot)."""
    parts = {j.name: name_parts(j.name) for j in sk.joints}
    to_head: set[int] = set()  # the joints from the root to the first joint named head (topology)
    head = next((i for i, j in enumerate(sk.joints) if "head" in parts[j.name][1]), None)
    while head is not None and head >= 0:
        to_head.add(head)
        head = sk.joints[head].parent
    words = {w for _, w in parts.values()}
    joint_named = "knee" in words or "elbow" in words  # CMU BVH and the like name bones after joints
    out: dict[str, tuple[str, str]] = {}
    unmapped = []
    for i, j in enumerate(sk.joints):
        side, w = parts[j.name]
        kids = [parts[sk.joints[k].name][1] for k in sk.children(i)]
        if joint_named and w == "hipjoint" and "knee" in kids:  # LeftHipJoint -> LeftKneeJoint: the thigh
            w = "hip"
        base = re.sub(r"\d+$", "", w)
        seg = None
        for cand in (w, base):
            if joint_named and cand in _JOINT_NAMED:
                seg = _JOINT_NAMED[cand]
            elif cand in _BONE_NAMED:
                seg = _BONE_NAMED[cand]
            if seg:
                break
        if seg is None:  # a word inside the name; finger words only below a hand
            below_hand = i > 0 and out[sk.joints[j.parent].name][0] in ("hand", "forearm")
            seg = next((s for p, s in _BONE_PREFIXES if p in base and (p not in _FINGER_WORDS or below_hand)), None)
        if i == 0:
            seg = "pelvis"
        if seg is None:  # reported (Body.unmapped); by topology: on the way to the head it is the trunk,
            unmapped.append(j.name)  # elsewhere it continues its parent's segment
            seg, side = out[sk.joints[j.parent].name]
            if i in to_head and seg == "pelvis":
                seg = "spine"
        out[j.name] = (seg, side if seg in _SIDED else "")
    return out, unmapped


def segment_masses(seg_of: dict[str, tuple[str, str]], mass: float) -> tuple[dict[str, float], list[str]]:
    """Every bone's mass (kg) from :func:`map_segments`: de Leva's percentage of each segment
    shared equally by its bones; and the segments the skeleton lacks (their mass is spread
    over the others in proportion, so that the body weighs ``mass``)."""
    groups: dict[tuple[str, str], list[str]] = {}
    for bone, (seg, side) in seg_of.items():
        if _SEGMENTS[seg][0]:
            groups.setdefault((_SEGMENTS[seg][0], side), []).append(bone)
    sided = {_SEGMENTS[k][0] for k in _SIDED}
    want = [(p, s) for p in _PERCENT for s in (("l", "r") if p in sided else ("",))]
    missing = [f"{s + ' ' if s else ''}{p}" for p, s in want if (p, s) not in groups]
    present = sum(_PERCENT[p] for p, s in want if (p, s) in groups)
    out = {b: 0.0 for b in seg_of}
    for (p, s), bones in groups.items():
        if (p, s) in want:
            for b in bones:
                out[b] = mass * _PERCENT[p] / present / len(bones)
    return out, missing


def stature(sk: Skeleton) -> float:
    """The body's standing height in metres from its bone lengths alone, whatever its rest pose
    (a game studio's skeleton rests with its bones along X): the longest way from a foot (a
    joint named foot or ankle) up to the root, plus the way from the root up to the head and
    its end site. The skeleton's rest-pose height when it names no head or feet."""
    from shared.io.conventions import FOOT_RE, HEAD_RE

    def up_to_root(i):
        total = 0.0
        while i > 0:
            total += float(np.linalg.norm(sk.joints[i].offset))
            i = sk.joints[i].parent
        return total

    feet = [i for i, j in enumerate(sk.joints) if FOOT_RE.search(j.name) and not FOOT_RE.search(
        sk.joints[j.parent].name if j.parent >= 0 else "")]
    heads = [i for i, j in enumerate(sk.joints) if HEAD_RE.search(j.name)]
    if not feet or not heads:
        return sk.rest_height()
    h = heads[0]
    top = up_to_root(h) + (0.0 if sk.joints[h].end is None or sk.children(h) else float(np.linalg.norm(sk.joints[h].end)))
    return (max(up_to_root(f) for f in feet) + top) * sk.unit_m


def _hinge_order(seq: str, dofs: list[str]) -> list[str]:
    """Rotation channels ('x', 'y', 'z') in the order MuJoCo must apply the hinges."""
    axes = [a for a in seq.lower() if f"r{a}" in dofs]
    return axes if seq.isupper() else axes[::-1]


#: the most joints a simulated person may have: mocap skeletons have 20-70 (150 with every finger
#: joint); a 200-joint chain compiles in 0.2 s, a 1,000-joint one in 25 s (issue 17, row 1)
MAX_BODY_JOINTS = 200


def human_body(skeleton: Skeleton, mass: float = 70.0, name: str | None = None) -> Body:
    """A MuJoCo body of ``mass`` kg from a mocap skeleton (see module docstring)."""
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
    bodies = {}
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
        radius = _SEGMENTS.get(seg_of[j.name][0], ("", 0.02))[1]
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
    try:
        model = spec.compile()
    except ValueError as e:
        raise BadInput(f"cannot build a MuJoCo body from skeleton {sk.name!r}: {e}") from None
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
