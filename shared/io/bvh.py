"""Biovision BVH: read, and write so that any animation tool opens a generated motion.

A BVH file read here gives channels named ``<joint>.<dof>`` (``Zrotation`` -> ``rz``) and a
skeleton whose joints compose their rotation channels in file order (intrinsic, as BVH
specifies). The file's length unit, up axis and what its position channels mean are read off
the body (:mod:`shared.io.conventions`) unless given: ``units`` (cm, m, mm, in, cmu), ``up``
(y, z) and ``translations`` (add, replace, auto).

Writing a clip whose skeleton came from BVH writes its own channels unchanged, its lengths in
metres (so a read - write - read round trip gives the same numbers to the printed precision).
Every BVH mirrorcoach writes is in metres: Blender, which reads a BVH number as one of its
units (a metre), imports it at a person's size with its default scale of 1; a tool that takes
BVH as centimetres needs a scale of 100 on import. Writing a clip on an
ASF skeleton folds each bone's ``axis`` pre-rotation into its local rotation
(``L = C M C^T``), writes ``Zrotation Xrotation Yrotation`` for every joint (angles unwrapped
over time, on the branch nearest the frame before) and converts lengths to metres; forward kinematics of
the written file gives the same joint positions as the ASF/AMC original.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shared.errors import ClipFormatError
from shared.motion.clip import Clip
from shared.motion.skeleton import MAX_JOINTS, Joint, Skeleton, continuous_euler

_BVH_TO_DOF = {
    "xposition": "tx", "yposition": "ty", "zposition": "tz",
    "xrotation": "rx", "yrotation": "ry", "zrotation": "rz",
}
_DOF_TO_BVH = {"tx": "Xposition", "ty": "Yposition", "tz": "Zposition", "rx": "Xrotation", "ry": "Yrotation", "rz": "Zrotation"}
BVH_UNIT_M = 1.0  # metres: what Blender reads (module docstring)
DECIMALS = 6


class _Tokens:
    def __init__(self, path: Path, lines: list[str]):
        self.path = path
        self.toks: list[tuple[str, int]] = []
        for n, line in enumerate(lines, 1):
            for t in line.replace("{", " { ").replace("}", " } ").split():
                self.toks.append((t, n))
        self.i = 0

    def peek(self) -> str:
        return self.toks[self.i][0] if self.i < len(self.toks) else ""

    def line(self) -> int:
        return self.toks[min(self.i, len(self.toks) - 1)][1] if self.toks else 1

    def next(self, expect: str | None = None) -> str:
        if self.i >= len(self.toks):
            raise ClipFormatError(self.path, f"unexpected end of file{f' (expected {expect!r})' if expect else ''}", self.line())
        t, n = self.toks[self.i]
        if expect is not None and t.upper() != expect.upper():
            raise ClipFormatError(self.path, f"expected {expect!r}, got {t!r}", n)
        self.i += 1
        return t

    def number(self) -> float:
        t, n = self.toks[self.i] if self.i < len(self.toks) else ("", self.line())
        try:
            v = float(t)
        except ValueError:
            raise ClipFormatError(self.path, f"expected a number, got {t!r}", n) from None
        self.i += 1
        return v


#: limits of a hierarchy a reader accepts: human rigs with fingers and face bones stay far below
MAX_DEPTH = 200


def read_bvh(path, label: str | None = None, *, units: str | None = None, up: str | None = None,
             translations: str | None = None) -> Clip:
    path = Path(path)
    try:
        text = path.read_bytes().decode("latin-1")
    except OSError as e:
        raise ClipFormatError(path, f"cannot read file: {e.strerror or e}") from None
    lines = text.splitlines()
    del text  # a long take's text is held once, as its lines
    motion_line = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION"), None)
    if motion_line is None:
        raise ClipFormatError(path, "no MOTION section (is this a BVH file?)")
    tk = _Tokens(path, lines[:motion_line])
    tk.next("HIERARCHY")
    joints: list[Joint] = []
    channels: list[str] = []

    def parse_joint(parent: int, depth: int = 0):
        if depth > MAX_DEPTH or len(joints) >= MAX_JOINTS:
            raise ClipFormatError(path, f"more than {MAX_JOINTS} joints or nested deeper than {MAX_DEPTH} "
                                        "(no body is; is this a BVH file?)", tk.line())
        name = tk.next()
        tk.next("{")
        tk.next("OFFSET")
        offset = np.array([tk.number() for _ in range(3)])
        dofs: list[str] = []
        if tk.peek().upper() == "CHANNELS":
            tk.next()
            ln = tk.line()
            try:
                n = int(tk.next())
            except ValueError:
                raise ClipFormatError(path, "CHANNELS needs a count", ln) from None
            if not 0 <= n <= 6:
                raise ClipFormatError(path, f"CHANNELS {n}: a joint has 0 to 6 channels", ln)
            for _ in range(n):
                ln = tk.line()
                c = tk.next()
                if c.lower() not in _BVH_TO_DOF:
                    raise ClipFormatError(path, f"unknown channel {c!r}", ln)
                dofs.append(_BVH_TO_DOF[c.lower()])
        seq = "".join(d[1].upper() for d in dofs if d.startswith("r"))
        if len(set(seq)) != len(seq):
            raise ClipFormatError(path, f"joint {name!r} names a rotation channel twice", ln if dofs else tk.line())
        seq += "".join(a for a in "XYZ" if a not in seq)  # CHANNELS 0-2 rotations: the others stay at 0
        j = Joint(name=name, parent=parent, offset=offset, dofs=dofs, euler=seq)
        idx = len(joints)
        joints.append(j)
        channels.extend(f"{name}.{d}" for d in dofs)
        while True:
            t = tk.peek().upper()
            if t == "JOINT":
                tk.next()
                parse_joint(idx, depth + 1)
            elif t == "END":
                tk.next()
                tk.next("Site")
                tk.next("{")
                tk.next("OFFSET")
                j.end = np.array([tk.number() for _ in range(3)])
                tk.next("}")
            elif t == "}":
                tk.next()
                return
            else:
                raise ClipFormatError(path, f"unexpected {tk.peek() or 'end of file'!r} in joint {name!r}", tk.line())

    tk.next("ROOT")
    parse_joint(-1)
    body = lines[motion_line + 1:]
    n_frames = None
    frame_time = None
    k = 0
    while k < len(body) and (n_frames is None or frame_time is None):
        s = body[k].strip()
        ln = motion_line + 2 + k
        if s.lower().startswith("frames:"):
            try:
                n_frames = int(s.split(":", 1)[1])
            except ValueError:
                raise ClipFormatError(path, "bad 'Frames:' line", ln) from None
        elif s.lower().startswith("frame time:"):
            try:
                frame_time = float(s.split(":", 1)[1])
            except ValueError:
                raise ClipFormatError(path, "bad 'Frame Time:' line", ln) from None
        elif s:
            raise ClipFormatError(path, f"expected 'Frames:' and 'Frame Time:', got {s[:40]!r}", ln)
        k += 1
    if n_frames is None or frame_time is None or frame_time <= 0:
        raise ClipFormatError(path, "missing or invalid 'Frames:' / 'Frame Time:'")
    # the frames straight into one array (a row array per line held a long take twice)
    data = np.empty((max(min(n_frames, len(body) - k), 0), len(channels)))
    n_rows = 0
    for i, s in enumerate(body[k:], start=motion_line + 2 + k):
        if not s.strip():
            continue
        try:
            vals = np.array(s.split(), dtype=float)
        except ValueError:
            raise ClipFormatError(path, "frame line with a non-number", i) from None
        if vals.size != len(channels):
            raise ClipFormatError(path, f"frame has {vals.size} values, the hierarchy declares {len(channels)} channels", i)
        if not np.all(np.isfinite(vals)):
            raise ClipFormatError(path, "frame line with a non-finite value", i)
        if n_rows < len(data):
            data[n_rows] = vals
        n_rows += 1
    if n_rows != n_frames:
        raise ClipFormatError(path, f"'Frames: {n_frames}' but {n_rows} frame lines")
    if not n_rows:
        raise ClipFormatError(path, "no frames")
    del lines, body
    if len(set(j.name for j in joints)) != len(joints):
        raise ClipFormatError(path, "two joints share a name")
    sk, data, channels, read_as = _conventions(path, Skeleton(name=path.stem, joints=joints, unit_m=1.0, up_axis=1,
                                                              source_format="bvh"), data, channels,
                                               units, up, translations)
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 1e-3 * fps:  # "0.008333" means 120 fps, not 120.0048
        fps = float(round(fps))
    return Clip(data=data, channels=channels, fps=fps, skeleton=sk, groups={"motion": list(channels)}, name=path.stem,
                label=label if label is not None else path.parent.name, source=str(path), read_as=read_as)


def _conventions(path, sk: Skeleton, data: np.ndarray, channels: list[str], units, up, translations):
    """The body's root found, translation channels to the add form, the body to Y up, the unit
    chosen and the angles continuous (see :mod:`shared.io.conventions`); returns the skeleton,
    the data, the channels and what was decided."""
    from shared.io import conventions as cv

    cv.check_reading(path, units, up, translations)
    sk, data, channels, rest, folded = cv.fold_scene_root(sk, data, channels)
    col = {c: i for i, c in enumerate(channels)}
    size = max(float(np.ptp(cv.rest_points(sk), axis=0).max()), 1e-9)
    modes = {}
    for j in sk.joints:
        t = [k for k in (col.get(f"{j.name}.t{a}") for a in "xyz") if k is not None]
        if len(t) == 3:
            if j.parent >= 0:  # the root waits for the up axis and the unit: its floor decides
                modes[j.name] = translations if translations in ("add", "replace") else \
                    cv.joint_translation_mode(data[:, t], rest[j.name], size)
                if modes[j.name] == "replace":
                    data[:, t] -= rest[j.name]
        elif t and translations != "add" and np.any(j.offset):
            raise ClipFormatError(path, f"joint {j.name!r} has only some of its position channels and an offset; "
                                        "say how they combine (--translations add|replace)")
    axis = {"y": 1, "z": 2}[up] if up else cv.detect_up(sk, data, channels, path)
    root_rest = rest[sk.root.name]
    if axis == 2:
        sk, data = cv.turn_z_up_to_y_up(sk, data, channels)
        root_rest = cv.Z_TO_Y @ root_rest
    heights = cv.standing_heights(sk, data, channels)
    height = float(heights[1])
    if up and not units and not cv.human_height(height):  # told the up axis of a body lying down: its length
        height = float(heights.max())
    sk.unit_m = cv.choose_unit(path, height, units)
    root = sk.root
    t = [k for k in (col.get(f"{root.name}.t{a}") for a in "xyz") if k is not None]
    if len(t) == 3:
        modes[root.name] = translations if translations in ("add", "replace") else \
            cv.root_translation_mode(sk, data, channels, root_rest, 1, size)
        if modes[root.name] == "replace":
            data[:, t] -= root_rest
    data = sk.continuous_angles(data, channels, keep_first=True)
    unit = next(k for k, v in cv.UNITS.items() if v == sk.unit_m)
    read_as = {"units": unit + ("" if units else " (from the body's height)"),
               "up": ("z, turned to y" if axis == 2 else "y") + ("" if up else " (from the motion)"),
               "translations": sorted(set(modes.values())) or ["none"],
               "root": root.name + (f" (the scene node{'s' if len(folded) > 1 else ''} {', '.join(folded)} "
                                    "above it folded in)" if folded else "")}
    return sk, data, channels, read_as


def _read_back_as_is(j: Joint) -> bool:
    """A BVH reader reads ``j``'s channels back as they are: no rotation before its own, and its
    rotation channels' order begins its (intrinsic) Euler order, as the reader sets it. An AMC
    root (extrinsic ``xyz``), or a skeleton built with one, is not: its rotations are converted
    to ZXY instead."""
    order = "".join(d[1].upper() for d in j.dofs if d.startswith("r"))
    return np.array_equal(j.pre, np.eye(3)) and (not order or (j.euler.isupper() and j.euler.startswith(order)))


def to_bvh_form(clip: Clip) -> tuple[Skeleton, np.ndarray, list[str]]:
    """The clip's skeleton and motion in BVH form: C folded into ZXY rotations, metres."""
    sk = clip.skeleton
    if sk is None:
        raise ClipFormatError(clip.source or clip.name, "a BVH file needs a skeleton; this clip has none")
    plain = all(_read_back_as_is(j) for j in sk.joints)
    if sk.source_format == "bvh" and plain:
        chans = sk.channels()
        scale = sk.unit_m / BVH_UNIT_M
        data = np.column_stack([clip.column(c) if c in clip.channels else np.zeros(clip.n_frames) for c in chans])
        for i, c in enumerate(chans):  # position channels as Blender reads them: the whole local position
            name, dof = c.rsplit(".", 1)
            if dof in ("tx", "ty", "tz"):
                data[:, i] = (data[:, i] + sk.joints[sk.index(name)].offset["xyz".index(dof[1])]) * scale
        if scale == 1.0:
            return sk, data, chans
        joints = [Joint(j.name, j.parent, j.offset * scale, list(j.dofs), j.euler, j.pre,
                        None if j.end is None else j.end * scale, dict(j.limits)) for j in sk.joints]
        return Skeleton(sk.name, joints, BVH_UNIT_M, sk.up_axis, "bvh"), data, chans
    scale = sk.unit_m / BVH_UNIT_M
    values = {c: clip.data[:, i] for i, c in enumerate(clip.channels)}
    local = sk.local_rotations(values, clip.n_frames)
    joints, cols, chans = [], [], []
    for j, rot in zip(sk.joints, local):
        moves = j.parent < 0 or any(f"{j.name}.{d}" in values for d in ("tx", "ty", "tz"))
        dofs = (["tx", "ty", "tz"] if moves else []) + ["rz", "rx", "ry"]
        nj = Joint(name=j.name, parent=j.parent, offset=j.offset * scale, dofs=dofs, euler="ZXY",
                   end=None if j.end is None else j.end * scale, limits={})
        if moves:  # Blender's reading: the channels are the whole local position
            for k, d in enumerate(("tx", "ty", "tz")):
                cols.append((values.get(f"{j.name}.{d}", np.zeros(clip.n_frames)) + j.offset[k]) * scale)
        cols.extend(continuous_euler(rot.as_euler("ZXY", degrees=True), "ZXY").T)  # one branch over the take
        joints.append(nj)
        chans.extend(f"{j.name}.{d}" for d in dofs)
    out = Skeleton(name=sk.name, joints=joints, unit_m=BVH_UNIT_M, up_axis=sk.up_axis, source_format="bvh")
    return out, np.column_stack(cols), chans


def write_bvh(clip: Clip, path) -> None:
    """Write the motion channels of ``clip`` as BVH (sensor channels are not part of BVH;
    keep them with NPZ)."""
    header, rows = bvh_lines(clip)
    Path(path).write_text("\n".join(header + [f"Frames: {len(rows)}", f"Frame Time: {1.0 / clip.fps:.12g}"] + rows)
                          + "\n")


def bvh_lines(clip: Clip) -> tuple[list[str], list[str]]:
    """The BVH text of ``clip``: its header (``HIERARCHY`` to ``MOTION``) and one line per frame
    (what a motion capture suite broadcasts in real time after the header)."""
    sk, data, chans = to_bvh_form(clip)
    out = ["HIERARCHY"]

    def fmt(v):  # rounded first, so that a tiny negative number never prints as "-0.000000"
        return " ".join(f"{x:.{DECIMALS}f}" for x in np.round(np.asarray(v, dtype=float), DECIMALS) + 0.0)

    def emit(i: int, depth: int):
        j = sk.joints[i]
        pad = "\t" * depth
        out.append(f"{pad}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        out.append(pad + "{")
        out.append(f"{pad}\tOFFSET {fmt(j.offset)}")
        if j.dofs:
            out.append(f"{pad}\tCHANNELS {len(j.dofs)} " + " ".join(_DOF_TO_BVH[d] for d in j.dofs))
        kids = sk.children(i)
        for k in kids:
            emit(k, depth + 1)
        if not kids:
            end = j.end if j.end is not None else np.zeros(3)
            out.append(f"{pad}\tEnd Site")
            out.append(f"{pad}\t{{")
            out.append(f"{pad}\t\tOFFSET {fmt(end)}")
            out.append(f"{pad}\t}}")
        out.append(pad + "}")

    emit(0, 0)
    # BVH frame lines list channels in the order the hierarchy declares them (depth first)
    declared: list[str] = []
    stack = [0]
    while stack:
        i = stack.pop()
        declared.extend(f"{sk.joints[i].name}.{d}" for d in sk.joints[i].dofs)
        stack.extend(reversed(sk.children(i)))
    data = data[:, [chans.index(c) for c in declared]]
    out.append("MOTION")
    return out, [fmt(row) for row in data]
