"""What a motion file means: its length unit, its up axis and what its translation channels
add to (issue 12). Readers call these after parsing, so every clip inside mirrorcoach is a
Y-up body in known units whose translation channels add to the joint offsets.

* **Length unit.** A file states no unit (BVH) or one that is often wrong (ASF ``:units
  length``). A person is 1.0-2.2 m tall in the rest pose, and the usual units map that onto
  disjoint ranges of file units (cm 100-220, in 39-87, CMU 17.7-39, m 1.0-2.2), so the body's
  height picks the unit. A body of no human height in any of them is refused with a clear
  error (a 5 m "human" must not reach the simulator); ``units=`` overrides.
* **Up axis.** BVH says nothing; Blender exports Z-up. The feet (joints named foot, ankle or
  toe) lie below the root along the up axis in the rest pose. A Z-up body is turned to Y-up
  by rotating every offset, every translation channel and (through the joints' ``pre``
  rotation, ``L' = R0 L R0^T``) every local rotation by ``R0`` = -90 deg about x; the channels'
  angles are kept. ``up=`` overrides.
* **Translation channels against OFFSET.** Blender reads a joint's position channels as its
  whole local position (the offset is their rest value); some files add them to the offset.
  Where the first frame tells (channels near the offset: replace; near zero: add) that is
  followed, otherwise Blender's reading; ``translations=`` overrides. Inside mirrorcoach the
  channels always add to the offset (a "replace" file is stored as the difference), and the
  BVH writer writes Blender's form.
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
    raise ClipFormatError(path, f"the body is {height_units:.4g} units tall in its rest pose{said}: no human height "
                                f"({lo:g}-{hi:g} m) in {', '.join(UNITS)}; give the unit (--units) if this is a person")


def detect_up(skeleton, path=None) -> int:
    """1 (Y up) or 2 (Z up) from where the feet are in the rest pose (Y if no feet are named)."""
    feet = [i for i, j in enumerate(skeleton.joints) if FOOT_RE.search(j.name)]
    if not feet:
        return 1
    p = rest_points(skeleton, ends=False)
    down = p[feet].mean(axis=0) - p[0]
    axis = int(np.argmax(np.abs(down)))
    if down[axis] >= 0 or axis == 0:
        raise ClipFormatError(path or skeleton.name, "cannot tell the up axis: the feet are not below the root "
                                                     "along y or z in the rest pose; give --up y|z")
    return axis


def turn_z_up_to_y_up(skeleton, data: np.ndarray, channels: list[str]):
    """The same motion on a Y-up skeleton (see module docstring); returns (skeleton, data)."""
    from shared.skeleton import Joint, Skeleton

    data = np.array(data, dtype=float)
    col = {c: i for i, c in enumerate(channels)}
    joints = []
    for j in skeleton.joints:
        t = [col.get(f"{j.name}.t{a}") for a in "xyz"]
        if any(k is not None for k in t):
            if any(k is None for k in t):
                raise ClipFormatError(skeleton.name, f"joint {j.name!r} has only some of its position channels; "
                                                     "cannot turn it to Y up (give --up y to read it as it is)")
            data[:, t] = data[:, t] @ Z_TO_Y.T
        joints.append(Joint(j.name, j.parent, Z_TO_Y @ j.offset, list(j.dofs), j.euler, Z_TO_Y @ j.pre,
                            None if j.end is None else Z_TO_Y @ j.end, dict(j.limits)))
    return Skeleton(skeleton.name, joints, skeleton.unit_m, 1, skeleton.source_format), data


def translation_mode(joint, first: np.ndarray, height_units: float, mode: str | None) -> str:
    """``"add"`` or ``"replace"`` for one joint's position channels (see module docstring)."""
    if mode in ("add", "replace"):
        return mode
    off = np.asarray(joint.offset, float)
    scale = max(float(np.linalg.norm(off)), 1e-9)
    if scale < 1e-6 * max(height_units, 1e-9):
        return "replace"  # no offset: both readings agree
    if np.linalg.norm(first - off) < 0.5 * scale:
        return "replace"
    if np.linalg.norm(first) < 0.5 * scale:
        return "add"
    return "replace"  # the data does not tell: Blender's reading
