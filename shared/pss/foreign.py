"""Clips on another studio's skeleton, read as the space's: a studio's skeleton, its own joints
mapped to the space's, must not change the label.

A space compares joints by name (:mod:`shared.pss.features`): a clip whose skeleton names fewer
than half of the space's joints (a game studio's ``UpperLeg_L`` for HDM05's ``lfemur``, CMU's BVH
``LeftHip`` for the same thigh) is **foreign**. Its joint angles cannot be compared (another rest
pose, other bones, other axes), but where its body's parts are can: both skeletons are read as a
person's body segments (:func:`shared.bodies.segments.segments_of`: topology and proportions,
names only for sides), and every point of the space's skeleton (joint or end site) is placed on
the foreign body by **landmarks**, the points every person's skeleton has: the pelvis, the starts
of the spine, neck and head, of each thigh, shank and foot, of each upper arm, forearm and hand,
the place each arm leaves the trunk, and the tips of the head, hands and feet. A point of the
space's skeleton lies, in its rest pose, at some fraction of the way between the two landmarks
of its segment (the hip joint of HDM05's ``lhipjoint`` at 1 between the pelvis and the thigh's
start, its ``thorax`` part of the way up the spine); the same fraction of the foreign body's way
between the same landmarks is where it reads that point, frame by frame.

So the **position group** of a foreign clip (its joints in the heading frame, in body heights,
and the root's terms) is what recognition's label and segmentation compare: recognition then
abstracts the clip into an HMM of the position group alone and places it by the position
distances rescaled to the space's (:func:`shared.pss.association.recognize_by_positions`, as
association places a motion whose sensor channels are missing). Points off a segment's line (a thumb beside the fingers)
are read on it: measured on HDM05's clips read through a renamed copy of their own skeleton
(``bench/results/recognition`` robustness table, "another skeleton")."""

from __future__ import annotations

import numpy as np

from shared.bodies.segments import segments_of
from shared.errors import BadInput
from shared.motion.skeleton import Skeleton

#: each segment's way: the landmarks it runs between (start, end); ``base`` is where an arm leaves the trunk
_WAY = {"pelvis": (("pelvis", "start"), ("spine", "start")), "spine": (("spine", "start"), ("neck", "start")),
        "neck": (("neck", "start"), ("head", "start")), "head": (("head", "start"), ("head", "tip")),
        "hipjoint": (("pelvis", "start"), ("thigh", "start")), "thigh": (("thigh", "start"), ("shank", "start")),
        "shank": (("shank", "start"), ("foot", "start")), "foot": (("foot", "start"), ("foot", "tip")),
        "clavicle": (("clavicle", "start"), ("upper_arm", "start")),
        "upper_arm": (("upper_arm", "start"), ("forearm", "start")),
        "forearm": (("forearm", "start"), ("hand", "start")), "hand": (("hand", "start"), ("hand", "tip"))}
#: a landmark a skeleton lacks is read as the next one along its chain (no neck: the head's start)
_INSTEAD = {("neck", "start"): ("head", "start"), ("spine", "start"): ("neck", "start"), ("clavicle", "start"): ("arm", "base")}


def point_names(sk: Skeleton) -> list[str]:
    """The points of ``sk``'s forward kinematics in order: its joints, then the end sites of its leaves."""
    parents = {j.parent for j in sk.joints}
    return [j.name for j in sk.joints] + [f"{j.name}.end" for i, j in enumerate(sk.joints)
                                         if j.end is not None and i not in parents]


def same_layout(a: Skeleton, b: Skeleton) -> bool:
    """The same joints under the same parents, whatever order lists them."""
    def layout(sk):
        return sk.derived("layout", lambda: frozenset((j.name, sk.joints[j.parent].name if j.parent >= 0 else None)
                                                      for j in sk.joints))

    return a is b or layout(a) == layout(b)


def is_foreign(sk: Skeleton | None, ref: Skeleton | None) -> bool:
    """Whether ``sk`` names fewer than half of ``ref``'s joints (:func:`shared.motion.skeleton.other_skeleton`)."""
    if sk is None or ref is None:
        return False
    def names(s: Skeleton) -> frozenset:
        return s.derived("joint names", lambda: frozenset(j.name for j in s.joints))

    return 2 * len(names(sk) & names(ref)) < len(ref.joints)


def _rest(sk: Skeleton) -> np.ndarray:
    chans = sk.channels()
    return sk.forward_kinematics(np.zeros((1, len(chans))), chans)[0]


def landmarks(sk: Skeleton) -> dict[tuple, int]:
    """``(segment, side, "start" | "tip" | "base") -> point`` of ``sk``'s forward kinematics
    (:func:`point_names`): a segment's start is its first joint (the one nearest the root), its
    tip the point of its part of the tree farthest from that start in the rest pose, an arm's
    base the trunk joint it leaves from."""
    seg = segments_of(sk)
    names = point_names(sk)
    owner = [sk.index(n[:-4]) if n.endswith(".end") else sk.index(n) for n in names]
    rest = _rest(sk)
    out: dict[tuple, int] = {}
    for i, j in enumerate(sk.joints):
        s, side = seg[j.name]
        parent = seg[sk.joints[j.parent].name] if j.parent >= 0 else None
        if parent != (s, side) and (s, side, "start") not in out:
            out[s, side, "start"] = i
            if s in ("clavicle", "upper_arm") and (("arm", side, "base") not in out) and j.parent >= 0:
                out["arm", side, "base"] = j.parent
    for (s, side, kind), i in list(out.items()):
        if kind == "start" and s in ("head", "hand", "foot"):
            inside = [k for k, o in enumerate(owner) if seg[sk.joints[o].name] == (s, side)]
            out[s, side, "tip"] = max(inside, key=lambda k: float(np.linalg.norm(rest[k] - rest[i])))
    return out


def _landmark(marks: dict, seg: str, side: str, kind: str) -> int | None:
    """A landmark of one side (the trunk's have no side), or the one read instead of it."""
    key = (seg, "" if seg in ("pelvis", "spine", "neck", "head") else side, kind)
    if key in marks:
        return marks[key]
    if kind == "base":  # no clavicle: the arm leaves the trunk where its upper arm starts
        return _landmark(marks, "upper_arm", side, "start")
    instead = _INSTEAD.get((seg, kind))
    return _landmark(marks, instead[0], side, instead[1]) if instead else None


def point_map(sk: Skeleton, ref: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each point of ``ref`` (:func:`point_names`) lies on the body of ``sk``: points
    ``a``, ``b`` of ``sk``'s forward kinematics and the fraction ``t`` (``(1 - t) p_a + t p_b``;
    module docstring). :class:`BadInput` when either is not a person's skeleton."""
    return _for_reference(sk, ref, "point map", lambda: _point_map(sk, ref))


def _for_reference(sk: Skeleton, ref: Skeleton, kind: str, make):
    """``make()``, once per skeleton and reference skeleton object (:meth:`Skeleton.derived`; the
    reference is kept with its value, so its id is not reused while the value is)."""
    kept = sk.derived(kind, dict)
    if id(ref) not in kept or kept[id(ref)][0] is not ref:
        kept[id(ref)] = (ref, make())
    return kept[id(ref)][1]


def _point_map(sk: Skeleton, ref: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mine, theirs = landmarks(ref), landmarks(sk)
    for marks, who in ((mine, ref), (theirs, sk)):
        needed = [(s, side) for s in ("thigh", "shank", "foot", "upper_arm", "forearm", "hand") for side in "lr"]
        if any((s, side, "start") not in marks for s, side in needed) or ("head", "", "start") not in marks:
            raise BadInput(f"skeleton {who.name!r} is not a person's (two legs and two arms below a head): its "
                           "joints cannot be read as another skeleton's", field="skeleton")
    seg, rest = segments_of(ref), _rest(ref)
    names = point_names(ref)
    a, b, t = np.zeros(len(names), int), np.zeros(len(names), int), np.zeros(len(names))
    def sided(i: int) -> str:  # a joint's side, or the side of the limb below it (a hip joint has none of its own)
        side = seg[ref.joints[i].name][1]
        return side or next((x for x in (sided(k) for k in ref.children(i)) if x), "")

    for k, n in enumerate(names):
        i = ref.index(n[:-4] if n.endswith(".end") else n)
        s, side = seg[ref.joints[i].name][0], sided(i)
        if s not in _WAY:  # a limb no person has (a tail, a prop): read at the pelvis
            s, side = "pelvis", ""
        (s0, k0), (s1, k1) = _WAY[s]
        ends = [_landmark(mine, s0, side, k0), _landmark(mine, s1, side, k1)]
        there = [_landmark(theirs, s0, side, k0), _landmark(theirs, s1, side, k1)]
        if None in ends or None in there:
            raise BadInput(f"skeleton {sk.name!r}: no {s} landmarks to read {ref.name!r}'s {n} on", field="skeleton")
        way = rest[ends[1]] - rest[ends[0]]
        span = float(way @ way)
        t[k] = float(np.clip((rest[k] - rest[ends[0]]) @ way / span, 0.0, 1.0)) if span > 1e-12 else 0.0
        a[k], b[k] = there
    return a, b, t


def read_points(p: np.ndarray, sk: Skeleton, ref: Skeleton) -> np.ndarray:
    """``sk``'s forward kinematics ``p`` (T, points, 3) as ``ref``'s points (module docstring;
    the same joints in another order are only reordered)."""
    if same_layout(sk, ref):
        def order() -> np.ndarray:
            row = {n: i for i, n in enumerate(point_names(sk))}
            return np.array([row[n] for n in point_names(ref)])

        return p[:, _for_reference(sk, ref, "point order", order)]
    a, b, t = point_map(sk, ref)
    return p[:, a] * (1.0 - t)[None, :, None] + p[:, b] * t[None, :, None]
