"""What a motion file means: its length unit, its up axis, which joint is the body's root and
what its translation channels add to. Readers call these after parsing, so
every clip inside mirrorcoach is a Y-up body in known units, rooted at the pelvis, whose
translation channels add to the joint offsets. Everything is read off the *motion* (the posed
frames), per file, because a rest pose says little: game studios' skeletons rest with every
bone along its local X axis, and their root is a static node on the floor.

* **The body's root.** A file root with a single child that never turns (its rotation
  channels constant over the take, or none) is a floor, scene or trajectory node, not the body:
  it is folded into its child (its constant rotation and first position composed into the
  child's offset, translations and rotations, its path over the floor added to the child's
  translation channels), so the pelvis is the root every later step and the simulator see. ``read_as["root"]`` says what was folded.
* **Translation channels against OFFSET, per joint.** Blender reads a joint's position channels
  as its whole local position (the offset is their rest value); other files add them to the
  offset. For a joint below the root the reading that keeps the skeleton consistent wins: the
  channels stay near the offset (replace) or near zero (add); when they move, the reading whose
  bone length stays more constant over the take. For the root the floor decides: the reading
  that puts the body's lowest point over the take nearer the height 0 of the file's floor (and
  the body nearer the origin), i.e. the hips at a person's height above the floor.
  ``translations=`` overrides both. Inside mirrorcoach the channels always add to the offset
  (a "replace" joint is stored as the difference), and the BVH writer writes Blender's form.
* **Up axis.** BVH says nothing; Blender exports Z-up. The head lies above the feet (joints
  named head, and foot, ankle or toe): the axis and sign of that direction is up. A Z-up body is turned to Y-up by rotating every offset, every translation channel and
  (through the joints' ``pre`` rotation, ``L' = R0 L R0^T``) every local rotation by ``R0`` =
  -90 deg about x; the channels' angles are kept. An upright rest pose (head above feet along
  one axis) is taken first, since a take may lie down on the floor; a body without such names
  falls back to its feet below its root. ``up=`` overrides.
* **Length unit.** A file states no unit (BVH) or one that is often wrong (ASF ``:units
  length``). A person stands 1.0-2.2 m tall, and the usual units map that onto disjoint ranges
  of file units (cm 100-220, in 39-87, CMU 17.7-39, m 1.0-2.2), so the body's height picks the
  unit: for BVH its standing height over the take (head to lowest point, 90th percentile of the
  frames), for ASF its rest pose. A body of no human height in any unit is refused with a clear
  error (a 5 m "human" must not reach the simulator); ``units=`` overrides.
* **Euler angles** are made continuous over the take (:func:`shared.motion.skeleton.continuous_euler`:
  the same rotations, each frame on the branch nearest the frame before), so nothing
  downstream differentiates a jump of 360 degrees or a change of branch.

Every option is one of ``mirrorcoach``'s root options, so every command that reads clips takes
them: ``mirrorcoach --up z --units cm space build ...``.
"""

from __future__ import annotations

import re

import numpy as np

from shared.errors import ClipFormatError

#: metres per file unit; "cmu": the CMU/HDM05 ASF unit (inches / 0.45)
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "cmu": 0.0254 / 0.45}
HUMAN_HEIGHT_M = (1.0, 2.2)
FOOT_RE = re.compile(r"foot|ankle|toe", re.IGNORECASE)
#: Z-up -> Y-up: -90 degrees about x, (x, y, z) -> (x, z, -y)
Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def rest_points(skeleton, ends: bool = True) -> np.ndarray:
    """Joint (and end-site) positions of the rest pose (all channels 0) in the file's own units."""
    chans = skeleton.channels()
    return skeleton.forward_kinematics(np.zeros((1, len(chans))), chans, ends=ends)[0] / skeleton.unit_m


def rest_extent(skeleton, up_axis: int = 1) -> float:
    """Height of the rest pose along ``up_axis`` in the file's own units."""
    return float(np.ptp(rest_points(skeleton)[:, up_axis]))


UP_AXES = ("y", "z")
TRANSLATIONS = ("auto", "add", "replace")


def check_reading(path, units: str | None, up: str | None, translations: str | None) -> None:
    """The reading options (``--units``, ``--up``, ``--translations``) are ones a reader knows."""
    if units is not None and units not in UNITS:
        raise ClipFormatError(path, f"unknown unit {units!r} (use one of {', '.join(UNITS)})")
    if up is not None and up not in UP_AXES:
        raise ClipFormatError(path, f"up must be y or z, got {up!r}")
    if translations is not None and translations not in TRANSLATIONS:
        raise ClipFormatError(path, f"translations must be add, replace or auto, got {translations!r}")


def human_height(height_units: float) -> bool:
    """Whether a height in file units is a person's in some unit of :data:`UNITS`."""
    return any(HUMAN_HEIGHT_M[0] <= height_units * m <= HUMAN_HEIGHT_M[1] for m in UNITS.values())


def choose_unit(path, height_units: float, units: str | None, declared_m: float | None = None) -> float:
    """Metres per file unit: ``units`` if given, else the declared unit if it makes a human
    height, else the one unit that does; a clear error when none does."""
    if units is not None:
        if units not in UNITS:
            raise ClipFormatError(path, f"unknown unit {units!r} (use one of {', '.join(UNITS)})")
        return UNITS[units]
    lo, hi = HUMAN_HEIGHT_M
    if declared_m is not None and lo <= height_units * declared_m <= hi:
        return declared_m
    fits = [(name, m) for name, m in UNITS.items() if lo <= height_units * m <= hi]
    if len(fits) == 1:
        return fits[0][1]
    said = "" if declared_m is None else f" ({height_units * declared_m:.3g} m in the unit the file declares)"
    raise ClipFormatError(path, f"the body is {height_units:.4g} units tall{said}: no human height "
                                f"({lo:g}-{hi:g} m) in {', '.join(UNITS)}; if this is a person, give the unit (--units, a "
                                "root option: mirrorcoach --units cm COMMAND ...)")


HEAD_RE = re.compile(r"head", re.IGNORECASE)
#: frames of a take the conventions are read on (evenly spread; forward kinematics of a few suffices)
POSED_FRAMES = 120
UP_HINT = "read it with --up y|z (a root option: mirrorcoach --up z COMMAND ...)"


def _posed(sk, data: np.ndarray, channels: list[str]) -> np.ndarray:
    """Joint and end-site positions relative to the root (T', J + E, 3) in file units, on at
    most :data:`POSED_FRAMES` frames of the take (the root's own translation does not enter)."""
    idx = np.unique(np.linspace(0, len(data) - 1, min(len(data), POSED_FRAMES)).round().astype(int))
    p = sk.forward_kinematics(data[idx], channels) / sk.unit_m
    return p - p[:, :1]


def _named(sk, pattern) -> list[int]:
    """Rows of :func:`_posed` (joints, then end sites of leaves) whose joint's name matches."""
    parents = {j.parent for j in sk.joints}
    rows = [i for i, j in enumerate(sk.joints) if pattern.search(j.name)]
    ends = [i for i, j in enumerate(sk.joints) if j.end is not None and i not in parents]
    rows += [len(sk.joints) + k for k, i in enumerate(ends) if pattern.search(sk.joints[i].name)]
    return rows


def detect_up(sk, data: np.ndarray, channels: list[str], path=None) -> int:
    """1 (Y up) or 2 (Z up): the axis along which the head stands above the feet in an upright
    rest pose, else over the posed frames (a game studio's rest pose lies along X; a take may
    lie down on the floor); the rest pose's feet below the root when no head is named; Y when
    nothing is named at all."""
    feet, head = _named(sk, FOOT_RE), _named(sk, HEAD_RE)
    if feet and head:
        rest = rest_points(sk)
        v = rest[head].mean(axis=0) - rest[feet].mean(axis=0)
        axis = int(np.argmax(np.abs(v)))
        if axis in (1, 2) and v[axis] > 0.8 * np.linalg.norm(v):  # an upright rest pose tells (a take may lie down)
            return axis
        p = _posed(sk, data, channels)
        v = (p[:, head].mean(axis=1) - p[:, feet].mean(axis=1)).mean(axis=0)
        where = "the head is not above the feet along y or z in the motion"
    elif feet:
        v = -(rest_points(sk, ends=False)[[f for f in feet if f < len(sk.joints)]].mean(axis=0) - rest_points(sk)[0])
        where = "the feet are not below the root along y or z in the rest pose"
    else:
        return 1
    axis = int(np.argmax(np.abs(v)))
    if v[axis] <= 0 or axis == 0:
        sign = "-" if v[axis] < 0 else "+"
        raise ClipFormatError(path or sk.name, f"cannot tell the up axis: {where} (it points along {sign}"
                                               f"{'xyz'[axis]}); {UP_HINT}")
    return axis


def standing_heights(sk, data: np.ndarray, channels: list[str]) -> np.ndarray:
    """The body's standing height over the take in file units along x, y and z (3,): from its
    lowest point to its head (or its highest point when no joint is named head), 90th
    percentile of the frames."""
    p = _posed(sk, data, channels)
    head = _named(sk, HEAD_RE)
    top = p[:, head].max(axis=1) if head else p.max(axis=1)
    return np.percentile(top - p.min(axis=1), 90, axis=0)


def fold_scene_root(sk, data: np.ndarray, channels: list[str]):
    """A file root with one child that never turns (a floor, scene or trajectory node), folded
    into the child (module docstring). Returns (skeleton, data, channels, the replace-offsets of translated joints,
    the names folded)."""
    from shared.motion.skeleton import Joint, Skeleton, continuous_euler

    rest = {j.name: np.asarray(j.offset, float) for j in sk.joints}  # what "replace" channels stand in for
    folded: list[str] = []
    size = max(float(np.ptp(rest_points(sk), axis=0).max()), 1e-9)
    while len(sk.joints) > 1:
        root, kids = sk.joints[0], sk.children(0)
        if len(kids) != 1:
            break
        child = sk.joints[kids[0]]
        col = {c: i for i, c in enumerate(channels)}
        rcols = [col[f"{root.name}.{d}"] for d in root.dofs if d.startswith("r")]
        tcols = [col.get(f"{child.name}.t{a}") for a in "xyz"]
        troot = np.column_stack([data[:, col[f"{root.name}.t{a}"]] if f"{root.name}.t{a}" in col else
                                 np.zeros(len(data)) for a in "xyz"])
        moves = np.ptp(troot, axis=0).max() > 1e-6 * size
        if (rcols and np.ptp(data[:, rcols], axis=0).max() > 1e-6 * size) or (
                moves and any(c is None for c in tcols)):
            break  # a turning scene node, or a moving one over a joint that cannot take its path: kept
        t0 = troot[0]
        p0 = t0 if np.linalg.norm(t0 - root.offset) < np.linalg.norm(t0) else root.offset + t0
        r0 = sk.local_matrices(data[:1], channels, slice(0, 1))[0, 0]
        turned = not np.allclose(r0, np.eye(3), atol=1e-9)
        rot = [f"{child.name}.r{a}" for a in child.euler.lower()]
        if turned and not all(c in col for c in rot):
            break  # a turned scene node over a joint that cannot turn freely: kept as it is
        data = np.array(data, dtype=float)
        hips = [c for c in tcols if c is not None]
        if len(hips) == len(tcols):  # a trajectory node's path becomes the hips' own
            data[:, hips] = data[:, hips] @ r0.T + (troot - t0)
        if turned:
            from scipy.spatial.transform import Rotation

            local = sk.local_matrices(data, channels)[:, kids[0]]
            m = np.asarray(child.pre).T @ (r0 @ local) @ np.asarray(child.pre)
            ang = np.rad2deg(Rotation.from_matrix(m).as_euler(child.euler))
            data[:, [col[c] for c in rot]] = continuous_euler(ang, child.euler)
        rest[child.name] = r0 @ rest[child.name]
        keep = [i for i, c in enumerate(channels) if not c.startswith(f"{root.name}.")]
        joints = []
        for j in sk.joints[1:]:
            if j is child:
                joints.append(Joint(j.name, -1, p0 + r0 @ j.offset, list(j.dofs), j.euler, j.pre, j.end, dict(j.limits)))
            else:
                joints.append(Joint(j.name, j.parent - 1, j.offset, list(j.dofs), j.euler, j.pre, j.end, dict(j.limits)))
        folded.append(root.name)
        sk = Skeleton(sk.name, joints, sk.unit_m, sk.up_axis, sk.source_format)
        data, channels = data[:, keep], [channels[i] for i in keep]
    return sk, data, channels, rest, folded


def joint_translation_mode(t: np.ndarray, rest: np.ndarray, size: float) -> str:
    """``"add"`` or ``"replace"`` for one non-root joint's position channels ``t`` (T, 3)
    against its offset ``rest``: near the offset over the take, replace; near zero, add; else
    the reading whose bone length varies less (module docstring)."""
    scale = float(np.linalg.norm(rest))
    if scale < 1e-6 * max(size, 1e-9):
        return "replace"  # no offset: both readings agree
    near_rest = float(np.median(np.linalg.norm(t - rest, axis=1)))
    near_zero = float(np.median(np.linalg.norm(t, axis=1)))
    if min(near_rest, near_zero) < 0.05 * scale:
        return "replace" if near_rest <= near_zero else "add"
    spread_replace = float(np.std(np.linalg.norm(t, axis=1)))
    spread_add = float(np.std(np.linalg.norm(t + rest, axis=1)))
    return "add" if spread_add < 0.5 * spread_replace else "replace"


#: how well a take's floor is known, as a share of the body's size (feet end sites sit a few cm
#: above or below a studio's floor)
FLOOR_TOLERANCE = 0.05


def root_translation_mode(sk, data: np.ndarray, channels: list[str], rest: np.ndarray, up_axis: int,
                          size: float) -> str:
    """``"add"`` or ``"replace"`` for the root's position channels: the reading that puts the
    body's lowest point over the take nearer the file's floor (height 0) and the body nearer
    the origin (module docstring). Ties read as Blender does (replace): a root offset of
    zero, or one too small for the floor to tell (the readings' scores within 5 % of the
    body's size: a floor is known to a few centimetres); ``size`` is the body's rest extent
    in file units."""
    r = sk.root
    if float(np.linalg.norm(rest)) < 1e-6 * size:
        return "replace"
    t = data[:, [channels.index(f"{r.name}.t{a}") for a in "xyz"]]
    idx = np.unique(np.linspace(0, len(data) - 1, min(len(data), POSED_FRAMES)).round().astype(int))
    low = _posed(sk, data, channels)[..., up_axis].min(axis=1)
    plane = [a for a in range(3) if a != up_axis]

    def score(root_pos):
        floor = float(np.min(root_pos[idx, up_axis] + low))
        return abs(floor) + 0.25 * float(np.linalg.norm(root_pos[:, plane].mean(axis=0)))

    return "add" if score(r.offset + t) < score(r.offset + t - rest) - FLOOR_TOLERANCE * size else "replace"


def turn_z_up_to_y_up(skeleton, data: np.ndarray, channels: list[str]):
    """The same motion on a Y-up skeleton (see module docstring); returns (skeleton, data)."""
    from shared.motion.skeleton import Joint, Skeleton

    data = np.array(data, dtype=float)
    col = {c: i for i, c in enumerate(channels)}
    joints = []
    for j in skeleton.joints:
        t = [col.get(f"{j.name}.t{a}") for a in "xyz"]
        if any(k is not None for k in t):
            if any(k is None for k in t):
                raise ClipFormatError(skeleton.name, f"joint {j.name!r} has only some of its position channels; "
                                                     "cannot turn it to Y up (give --up y to read it as it is)")
            xyz = [k for k in t if k is not None]
            data[:, xyz] = data[:, xyz] @ Z_TO_Y.T
        joints.append(Joint(j.name, j.parent, Z_TO_Y @ j.offset, list(j.dofs), j.euler, Z_TO_Y @ j.pre,
                            None if j.end is None else Z_TO_Y @ j.end, dict(j.limits)))
    return Skeleton(skeleton.name, joints, skeleton.unit_m, 1, skeleton.source_format), data


