"""A humanoid skeleton's body segments, from its tree and bone lengths (names only as hints),
and the frame of its body: no MuJoCo here, so recognition and reading can use it.

Segment masses: de Leva (1996), *Adjustments to Zatsiorsky-Seluyanov's segment inertia
parameters*, J. Biomechanics 29(9):1223-1230, table 4 (male), as fractions of the body mass;
a segment is shared equally by the bones :func:`map_segments` finds for it (fingers belong to
the hand, toes to the foot), and the mass of segments a skeleton lacks is spread over the
others so that the body weighs what was asked.
"""

from __future__ import annotations

import re

import numpy as np

from shared.io.conventions import HEAD_RE
from shared.motion.skeleton import Skeleton

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
SEGMENTS = {
    "pelvis": ("lower_trunk", 0.12), "spine": ("trunk", 0.12), "neck": ("neck", 0.05), "head": ("head", 0.09),
    "clavicle": ("clavicle", 0.04), "upper_arm": ("upper_arm", 0.045), "forearm": ("forearm", 0.035),
    "hand": ("hand", 0.03), "thigh": ("thigh", 0.07), "shank": ("shank", 0.05), "foot": ("foot", 0.04),
    "hipjoint": ("", 0.02), "unusual": ("", 0.02),
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


def _segments_by_name(sk: Skeleton) -> tuple[dict[str, tuple[str, str]], list[str]]:
    """Every bone's (segment, side) read from its name alone, and the bones no scheme names (they
    continue their parent's segment; on the way from the root to the head, the trunk). The
    hints :func:`map_segments` falls back on where a skeleton's topology is not a person's."""
    parts = {j.name: name_parts(j.name) for j in sk.joints}
    to_head: set[int] = set()  # the joints from the root to the first joint named head
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
        if seg is None:
            unmapped.append(j.name)
            seg, side = out[sk.joints[j.parent].name]
            if i in to_head and seg == "pelvis":
                seg = "spine"
        out[j.name] = (seg, side if seg in _SIDED else "")
    return out, unmapped


# ---------------------------------------------------------------------------- topology
#: a branch is a limb when its longest way to a tip is at least this share of the skeleton's
#: longest way from the root (HDM05, CMU, the game studio: the head 0.23-0.34, a thumb 0.13)
LIMB_SHARE = 0.18
#: de Leva (1996) segment lengths (male, mm): thigh 422.2 / shank 434.0, upper arm 281.7 / forearm 268.9
_LIMB_RATIO = {"leg": 422.2 / 434.0, "arm": 281.7 / 268.9}
#: a limb's segments along its chain: (before the two long bones, first, second, after)
_LIMB_SEGMENTS = {"leg": ("hipjoint", "thigh", "shank", "foot"), "arm": ("clavicle", "upper_arm", "forearm", "hand")}


class _Tree:
    """A skeleton's tree with lengths in metres: ``off[i]`` the length of joint ``i``'s offset
    from its parent, ``reach[i]`` the longest way from joint ``i`` to a tip (through its
    children or its end site)."""

    def __init__(self, sk: Skeleton):
        n = len(sk.joints)
        self.kids: list[list[int]] = [[] for _ in range(n)]
        for i, j in enumerate(sk.joints[1:], 1):
            self.kids[j.parent].append(i)
        self.off = np.array([float(np.linalg.norm(j.offset)) for j in sk.joints]) * sk.unit_m
        end = np.array([0.0 if j.end is None else float(np.linalg.norm(j.end)) for j in sk.joints]) * sk.unit_m
        self.reach = end.copy()
        for i in reversed(range(n)):
            for k in self.kids[i]:
                self.reach[i] = max(self.reach[i], self.off[k] + self.reach[k])

    def branch(self, k: int) -> float:
        """The longest way through child ``k`` from its parent to a tip."""
        return float(self.off[k] + self.reach[k])

    def limb_tips(self, big: float) -> np.ndarray:
        """For every joint, the tips below it reached through limb-sized branches only."""
        tips = np.ones(len(self.kids), int)
        for i in reversed(range(len(self.kids))):
            kids = [k for k in self.kids[i] if self.branch(k) >= big]
            if kids:
                tips[i] = sum(tips[k] for k in kids)
        return tips

    def chain(self, k: int) -> list[int]:
        """The limb from joint ``k`` to its farthest tip."""
        out = [k]
        while self.kids[out[-1]]:
            out.append(max(self.kids[out[-1]], key=self.branch))
        return out

    def subtree(self, i: int) -> list[int]:
        out, todo = [], [i]
        while todo:
            out.append(todo.pop())
            todo.extend(self.kids[out[-1]])
        return out


#: de Leva (1996) lengths (male, mm) of a limb's segments around its two long bones, as shares of
#: the neighbouring long bone: hip joint centre from the pelvis' centre ~90 of the thigh's 422,
#: clavicle ~170 of the upper arm's 282; foot (ankle to toe tip) ~200 of the shank's 434, hand
#: (wrist to finger tip) ~190 of the forearm's 269
_LIMB_ENDS = {"leg": (90 / 422.2, 200 / 434.0), "arm": (170 / 281.7, 190 / 268.9)}


def _bones(tree: _Tree, chain: list[int]) -> np.ndarray:
    """Each chain joint's bone length (to the next joint of the chain, or its farthest tip)."""
    return np.array([float(tree.off[chain[n + 1]]) if n + 1 < len(chain) else float(tree.reach[i])
                     for n, i in enumerate(chain)])


def _split_limb(tree: _Tree, chain: list[int], kind: str, hints: list[str]) -> list[str]:
    """A leg's or an arm's bones along its chain, segment by segment.

    The bones' names (``hints``) decide when they name all the limb's bones, one of its long
    segments among them, in the order a limb has them (hip joint or clavicle, thigh or upper
    arm, shank or forearm, foot or hand). Otherwise proportions alone do: the two consecutive runs of bones whose
    lengths are nearest de Leva's ratio (thigh/shank, upper arm/forearm), the bones before
    and after them shorter than their neighbour and as near de Leva's shares as they can be,
    each run of as few bones as possible, a hand or a foot at the end."""
    names = _LIMB_SEGMENTS[kind]
    rank = [names.index(h) if h in names else -1 for h in hints]
    if -1 not in rank and rank == sorted(rank) and (1 in rank or 2 in rank):
        return list(hints)
    pre, first, second, post = names
    length = _bones(tree, chain)
    n, total = len(chain), float(length.sum()) or 1.0
    if n == 1:
        return [first]
    counted = length > 0.05 * total  # zero-length helpers (twist joints on the chain) count for nothing
    share_pre, share_post = _LIMB_ENDS[kind]

    def off_share(got: float, want: float) -> float:
        return 0.2 * abs(np.log(got / want)) if got > 0.02 * total else 0.0

    best, cut = np.inf, (0, 1, 2)
    for a in range(n - 1):
        for b in range(a + 1, n):
            for c in range(b + 1, n + 1):
                s1, s2 = length[a:b].sum(), length[b:c].sum()
                if s1 <= 0 or s2 <= 0:
                    continue
                cost = (abs(np.log(s1 / s2) - np.log(_LIMB_RATIO[kind]))
                        + 0.3 * (max(counted[a:b].sum() - 1, 0) + max(counted[b:c].sum() - 1, 0))
                        + off_share(length[:a].sum(), share_pre * s1) + off_share(length[c:].sum(), share_post * s2)
                        + (length[:a].sum() >= s1) + (length[c:].sum() >= s2)  # a clavicle, a hand: shorter
                        + 0.3 * (c == n))  # a limb ends in a hand or a foot
                if cost < best - 1e-12:
                    best, cut = cost, (a, b, c)
    a, b, c = cut
    return [pre] * a + [first] * (b - a) + [second] * (c - b) + [post] * (n - c)


def _head_start(tree: _Tree, chain: list[int]) -> int:
    """Where the head begins along the chain from the trunk (the joints before it are the neck):
    the last joint with a bone of a head's size; when the chain ends in a marker (a joint with
    no bone), the marker's parent if the marker sits a head's height above it (a crown marker),
    else the marker itself (a head joint with no end site)."""
    bone, off = _bones(tree, chain), tree.off[chain]
    last = len(chain) - 1
    if last > 0 and bone[last] < 0.1 * max(off.max(), 1e-9):
        return last - 1 if off[last] >= 0.6 * off.max() else last
    return max(i for i, b in enumerate(bone) if b >= 0.3 * bone.max()) if bone.max() > 0 else last


def _side(sk: Skeleton, bones: list[int]) -> str:
    """A limb's side from its bones' names (a hint: the majority of l/r words), or ``""``."""
    votes = [name_parts(sk.joints[i].name)[0] for i in bones]
    left, right = votes.count("l"), votes.count("r")
    return "l" if left > right else "r" if right > left else ""


def _segments_by_topology(sk: Skeleton) -> tuple[dict[str, tuple[str, str]], list[str]] | None:
    """Every bone's (segment, side) from the skeleton's tree and bone lengths, or None when the
    tree is not a person's (not two legs below two arms and a head).

    The trunk is the way from the root towards the most limbs (a limb: a branch whose longest
    way to a tip is at least :data:`LIMB_SHARE` of the skeleton's). The two limbs that leave it
    lowest are the legs, the three that leave it highest the arms and the head (the head the
    shortest of them, or the one named so); trunk joints up to the legs are the pelvis, the
    rest the spine. Each limb is cut into segments by :func:`_split_limb`; its side branches
    (fingers, toes, twist bones) join the segment they leave from. A limb-sized branch that is
    none of these (a tail, a prop) is returned as unusual."""
    tree = _Tree(sk)
    hint, _ = _segments_by_name(sk)
    big = LIMB_SHARE * float(tree.reach[0])
    if big <= 0:
        return None
    tips = tree.limb_tips(big)
    trunk = [0]
    while True:
        kids = [k for k in tree.kids[trunk[-1]] if tree.branch(k) >= big and tips[k] >= 2]
        if len(kids) != 1:
            break
        trunk.append(kids[0])
    limbs = [(t, k) for t, i in enumerate(trunk) for k in tree.kids[i]
             if tree.branch(k) >= big and (t + 1 == len(trunk) or k != trunk[t + 1])]
    by_level = sorted(limbs, key=lambda tk: -tk[0])
    cut = 3
    while cut < len(by_level) and by_level[cut][0] == by_level[cut - 1][0]:
        cut += 1  # limbs leaving the trunk at one joint are all upper or all lower
    upper, lower = [k for _, k in by_level[:cut]], [k for _, k in by_level[cut:]]
    if len(upper) < 3 or len(lower) < 2:
        return None

    def pair(ks: list):  # the two most alike (a left and a right)
        def unlike(ab) -> float:
            return abs(np.log(tree.branch(ab[0]) / tree.branch(ab[1]))) + 0.1 * abs(len(tree.chain(ab[0])) - len(tree.chain(ab[1])))

        return list(min(((a, b) for n, a in enumerate(ks) for b in ks[n + 1:]), key=unlike))

    named_head = [k for k in upper if any(HEAD_RE.search(sk.joints[i].name) for i in tree.chain(k))]
    head = named_head[0] if len(named_head) == 1 else None
    arms = pair([k for k in upper if k != head])
    if head is None:
        head = min((k for k in upper if k not in arms), key=tree.branch)
    legs = pair(lower)
    seg: dict[int, tuple[str, str]] = {}
    leg_level = max(t for t, k in limbs if k in legs)
    for t, i in enumerate(trunk):
        seg[i] = ("pelvis" if t <= leg_level else "spine", "")
    for kind, two in (("leg", legs), ("arm", arms)):
        sides = [_side(sk, tree.chain(k)) for k in two]
        if sides[0] == sides[1] or "" in sides:  # no names to go by: a side each (masses are symmetric)
            sides = ["l", "r"]
        for k, side in zip(two, sides):
            chain = tree.chain(k)
            for i, name in zip(chain, _split_limb(tree, chain, kind, [hint[sk.joints[i].name][0] for i in chain])):
                seg[i] = (name, side if name in _SIDED else "")
    chain = tree.chain(head)
    top = _head_start(tree, chain)
    for n, i in enumerate(chain):
        seg[i] = ("head" if n >= top else "neck", "")
    unusual = []
    for _, k in limbs:
        if k not in (head, *arms, *legs):
            unusual.extend(tree.subtree(k))
    for i in range(1, len(sk.joints)):  # side branches continue the segment they leave from
        if i not in seg:
            p = sk.joints[i].parent
            seg[i] = ("unusual", "") if i in unusual else seg[p]
    return {sk.joints[i].name: s for i, s in seg.items()}, [sk.joints[i].name for i in sorted(unusual)]


def map_segments(sk: Skeleton) -> tuple[dict[str, tuple[str, str]], list[str]]:
    """Every bone's (segment, side) and the unusual bones, from the skeleton's topology and
    proportions (:func:`_segments_by_topology`; names only break ties and give sides). A tree
    that is not a person's (no two legs below two arms and a head: a half body, a robot) is
    read from its bone names instead (:func:`_segments_by_name`), and the bones no name
    places are the unusual ones (they continue their parent's segment there). Unusual bones
    are reported (``Body.unmapped``); a limb no person has carries no segment's mass."""
    topo = _segments_by_topology(sk)
    return topo if topo is not None else _segments_by_name(sk)


def segment_masses(seg_of: dict[str, tuple[str, str]], mass: float) -> tuple[dict[str, float], list[str]]:
    """Every bone's mass (kg) from :func:`map_segments`: de Leva's percentage of each segment
    shared equally by its bones; and the segments the skeleton lacks (their mass is spread
    over the others in proportion, so that the body weighs ``mass``)."""
    groups: dict[tuple[str, str], list[str]] = {}
    for bone, (seg, side) in seg_of.items():
        if SEGMENTS[seg][0]:
            groups.setdefault((SEGMENTS[seg][0], side), []).append(bone)
    sided = {SEGMENTS[k][0] for k in _SIDED}
    want = [(p, s) for p in _PERCENT for s in (("l", "r") if p in sided else ("",))]
    missing = [f"{s + ' ' if s else ''}{p}" for p, s in want if (p, s) not in groups]
    present = sum(_PERCENT[p] for p, s in want if (p, s) in groups)
    out = {b: 0.0 for b in seg_of}
    for (p, s), bones in groups.items():
        if (p, s) in want:
            for b in bones:
                out[b] = mass * _PERCENT[p] / present / len(bones)
    return out, missing


def stature(sk: Skeleton, head_top: bool = True) -> float:
    """The body's standing height in metres from its bone lengths alone, whatever its rest pose
    (a game studio's skeleton rests with its bones along X): the longest way from an ankle (the
    first joint of a foot, :func:`map_segments`) up to the root, plus the way from the root up
    to the head and (``head_top``) over it to its farthest tip. Without the head's top it is a
    length no end site enters (studios put end sites anywhere). The skeleton's rest-pose height
    when it has no feet or no head."""
    return sk.derived(("stature", head_top), lambda: _stature(sk, head_top))


def _stature(sk: Skeleton, head_top: bool) -> float:
    seg = segments_of(sk)
    tree = _Tree(sk)

    def up_to_root(i):
        total = 0.0
        while i > 0:
            total += float(tree.off[i])
            i = sk.joints[i].parent
        return total

    def first(name):
        return [i for i, j in enumerate(sk.joints) if seg[j.name][0] == name and (
            j.parent < 0 or seg[sk.joints[j.parent].name][0] != name)]

    feet, heads = first("foot"), first("head")
    if not feet or not heads:
        return sk.rest_height()
    top = float(tree.reach[heads[0]]) if head_top else 0.0
    return max(up_to_root(f) for f in feet) + up_to_root(heads[0]) + top


# ---------------------------------------------------------------------------- the body's frame
def _axis_rotations() -> np.ndarray:
    """The 24 rotations that map coordinate axes onto coordinate axes (signed permutations, det +1)."""
    from itertools import permutations, product

    out = []
    for perm in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, sign) in enumerate(zip(perm, signs)):
                m[row, col] = sign
            if np.linalg.det(m) > 0:
                out.append(m)
    out.sort(key=lambda m: -np.trace(m))  # the identity first: it wins ties
    return np.array(out)


AXIS_ROTATIONS = _axis_rotations()
#: frames a body frame is estimated on (spread over the take)
FRAME_SAMPLES = 120


def segments_of(sk: Skeleton) -> dict[str, tuple[str, str]]:
    """:func:`map_segments` of a skeleton, once per skeleton object."""
    return sk.derived("segments", lambda: map_segments(sk)[0])


def _feet(sk: Skeleton) -> list[tuple[int, int]]:
    """(ankle, toe) joints of each foot with more than one joint (:func:`map_segments`)."""
    seg = segments_of(sk)
    names = [j.name for j in sk.joints]
    out = []
    for a, j in enumerate(sk.joints):
        if seg[j.name][0] != "foot" or (j.parent >= 0 and seg[names[j.parent]][0] == "foot"):
            continue
        depth, todo, best = {a: 0}, [a], a
        while todo:
            k = todo.pop()
            for c in sk.children(k):
                if seg[names[c]][0] == "foot":
                    depth[c] = depth[k] + 1
                    todo.append(c)
                    best = c if depth[c] > depth[best] else best
        if best != a:
            out.append((a, best))
    return out


def _nearest_axes(up: np.ndarray, fwd: np.ndarray) -> int:
    """Index in :data:`AXIS_ROTATIONS` of the rotation whose Y and Z columns lie nearest
    ``up`` and ``fwd`` (the identity on ties)."""
    fwd = fwd - (fwd @ up) * up / max(float(up @ up), 1e-12)
    score = AXIS_ROTATIONS[:, :, 1] @ up + AXIS_ROTATIONS[:, :, 2] @ fwd
    return int(np.argmax(score + 1e-6 * (np.arange(len(score)) == 0)))


def body_frame(sk: Skeleton, data: np.ndarray | None = None, channels: list[str] | None = None) -> np.ndarray:
    """``B`` (3 x 3): the body's axes in its root's frame, so that ``R B`` (``R`` the root's
    world rotation) has the body's up as its Y column and the way its feet point as its Z
    column, as an HDM05 or CMU pelvis has with ``B = I``. One of the 24 axis rotations.

    Studios give the root another frame (a game studio's hips rest with their bones along X,
    so its ``R`` turns X up to stand); a heading read from ``R`` alone then turns with the
    body's lean, not with where it faces. ``B`` takes the way from the root up the trunk and
    the way the feet point (ankle to toes, :func:`map_segments`), read in the root's frame:
    in the rest pose when it stands (the legs hang opposite the trunk), else in each of the
    take's frames (``data``), the most frequent answer winning (a bow or a squat bends the
    trunk in a few frames; a single average would follow it). Without a standing rest pose or
    a take, or a tree that is not a person's, ``B = I``. Cached per skeleton once decided."""
    if "_body_frame" in sk.__dict__:
        return sk.__dict__["_body_frame"]
    seg = segments_of(sk)
    spine = [i for i, j in enumerate(sk.joints) if seg[j.name][0] == "spine"]
    feet = _feet(sk)
    if not spine or not feet or not {"thigh", "head"} <= {s for s, _ in seg.values()}:
        return np.eye(3)  # not a person's tree: the root's own frame
    depth = {0: 0}
    for i, j in enumerate(sk.joints[1:], 1):
        depth[i] = depth[j.parent] + 1
    chest = max(spine, key=lambda i: depth[i])
    chans = sk.channels()
    rest = sk.forward_kinematics(np.zeros((1, len(chans))), chans, ends=False)
    r0 = sk.root_matrices(np.zeros((1, len(chans))), chans)

    def answers(p, rot):  # per frame: the axis rotation nearest the trunk and the feet in the root's frame
        local = np.swapaxes(rot, 1, 2)
        up = np.einsum("tij,tj->ti", local, p[:, chest] - p[:, 0])
        fwd = np.einsum("tij,tj->ti", local, np.mean([p[:, t] - p[:, a] for a, t in feet], axis=0))
        return [_nearest_axes(u, f) for u, f in zip(up, fwd)]

    trunk = rest[0, chest] - rest[0, 0]
    legs = np.mean([rest[0, a] - rest[0, 0] for a, _ in feet], axis=0)
    standing = trunk @ legs < -0.5 * np.linalg.norm(trunk) * np.linalg.norm(legs)
    if standing:
        best = answers(rest, r0)[0]
    elif data is not None and len(data):
        assert channels is not None  # (the data's columns)
        data = np.asarray(data, float)
        idx = np.unique(np.linspace(0, len(data) - 1, min(len(data), FRAME_SAMPLES)).round().astype(int))
        votes = answers(sk.forward_kinematics(data[idx], channels, ends=False), sk.root_matrices(data[idx], channels))
        best = max(set(votes), key=lambda k: (votes.count(k), -k))
    else:
        return np.eye(3)
    sk.__dict__["_body_frame"] = AXIS_ROTATIONS[best]
    return AXIS_ROTATIONS[best]
