"""Acclaim ASF (skeleton) and AMC (motion) files, HDM05 and CMU flavours.

Both flavours: CRLF or LF line ends, Latin-1 bytes in comment lines (files are decoded as
Latin-1, which never fails), ``:units length`` in inches scaled (HDM05: 0.45 means one unit
is 1/0.45 inch), angles in degrees that may run continuously past 360 (kept as they are).
Bad files raise :class:`~shared.errors.ClipFormatError` naming the file and line.
"""

from __future__ import annotations

import bisect
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from shared.errors import ClipFormatError
from shared.motion.clip import Clip
from shared.motion.clipfiles import find_skeleton  # noqa: F401  (kept here: where readers look for it)
from shared.motion.skeleton import Joint, Skeleton, euler_matrix

INCH_M = 0.0254
#: degrees per unit of the ASF ``:units angle`` words (gradians: 400 to the turn)
ANGLE_UNITS = {"deg": 1.0, "degree": 1.0, "degrees": 1.0, "rad": 180.0 / math.pi, "radian": 180.0 / math.pi,
               "radians": 180.0 / math.pi, "grad": 0.9, "gradian": 0.9, "gradians": 0.9}
_DOF_MAP = {"rx": "rx", "ry": "ry", "rz": "rz", "tx": "tx", "ty": "ty", "tz": "tz", "l": None}


def _lines(path: Path) -> list[str]:
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise ClipFormatError(path, f"cannot read file: {e.strerror or e}") from None
    return raw.decode("latin-1").splitlines()


def _floats(path, lineno, parts, n=None) -> list[float]:
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ClipFormatError(path, f"expected numbers, got {' '.join(parts)!r}", lineno) from None
    if n is not None and len(vals) != n:
        raise ClipFormatError(path, f"expected {n} numbers, got {len(vals)}", lineno)
    if not all(map(math.isfinite, vals)):
        raise ClipFormatError(path, "non-finite number", lineno)
    return vals


def read_asf(path, units: str | None = None) -> Skeleton:
    """Read an ASF skeleton (see :mod:`shared.motion.skeleton` for the joint convention). Its
    ``:units length`` is taken when it makes a human height, else the unit that does
    (:func:`shared.io.conventions.choose_unit`); ``units`` overrides both."""
    path = Path(path)
    lines = _lines(path)
    section = None
    length_unit = 1.0
    angle_scale = 1.0  # degrees per file unit of angle
    root: dict[str, Any] = {"order": ["tx", "ty", "tz", "rx", "ry", "rz"], "axis": "xyz", "position": [0, 0, 0], "orientation": [0, 0, 0]}
    bones: dict[str, dict] = {}
    bone_order: list[str] = []
    hierarchy: dict[str, list[str]] = {}
    cur: dict | None = None
    in_limits = False
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith(":"):
            head = s.split()
            section = head[0][1:].lower()
            in_limits = False
            continue
        parts = s.split()
        key = parts[0].lower()
        if section == "units":
            if key == "length":
                length_unit = _floats(path, lineno, parts[1:], 1)[0]
                if length_unit <= 0:
                    raise ClipFormatError(path, f":units length {parts[1]}: the length unit must be positive", lineno)
            elif key == "angle":
                word = parts[1].lower() if len(parts) > 1 else ""
                if word not in ANGLE_UNITS:
                    raise ClipFormatError(path, f":units angle {word or '(none)'}: unknown angle unit (use one of "
                                                f"{', '.join(sorted(ANGLE_UNITS))})", lineno)
                angle_scale = ANGLE_UNITS[word]
        elif section == "root":
            if key == "order":
                order = [p.lower() for p in parts[1:]]
                if any(p not in _DOF_MAP or _DOF_MAP[p] is None for p in order):
                    raise ClipFormatError(path, f"unknown root channel in {s!r}", lineno)
                root["order"] = order
            elif key == "axis":
                root["axis"] = parts[1].lower()
            elif key in ("position", "orientation"):
                root[key] = _floats(path, lineno, parts[1:], 3)
        elif section == "bonedata":
            if key == "begin":
                cur = {"limits": [], "dof": [], "axis": [0, 0, 0], "axis_order": "xyz"}
                in_limits = False
            elif key == "end":
                if cur is None or "name" not in cur:
                    raise ClipFormatError(path, "bone block without a name", lineno)
                for req in ("direction", "length"):
                    if req not in cur:
                        raise ClipFormatError(path, f"bone {cur['name']!r} has no {req}", lineno)
                bones[cur["name"]] = cur
                bone_order.append(cur["name"])
                cur = None
                in_limits = False
            elif cur is None:
                raise ClipFormatError(path, f"{parts[0]!r} outside a begin/end bone block", lineno)
            elif key == "name":
                cur["name"] = parts[1]
            elif key == "direction":
                cur["direction"] = _floats(path, lineno, parts[1:], 3)
            elif key == "length":
                cur["length"] = _floats(path, lineno, parts[1:], 1)[0]
            elif key == "axis":
                cur["axis"] = _floats(path, lineno, parts[1:4], 3)
                cur["axis_order"] = parts[4].lower() if len(parts) > 4 else "xyz"
            elif key == "dof":
                dofs = [p.lower() for p in parts[1:]]
                bad = [d for d in dofs if d not in _DOF_MAP]
                if bad:
                    raise ClipFormatError(path, f"unknown degree of freedom {bad[0]!r}", lineno)
                cur["dof"] = [d for d in dofs if _DOF_MAP[d]]
            elif key == "limits" or in_limits:
                in_limits = True
                txt = s[len("limits"):] if key == "limits" else s
                for a, b in re.findall(r"\(\s*([-+\w.]+)\s+([-+\w.]+)\s*\)", txt):
                    cur["limits"].append((_limit(a), _limit(b)))
            elif key == "id" or key == "bodymass" or key == "cofmass":
                pass
            else:
                raise ClipFormatError(path, f"unknown bone field {parts[0]!r}", lineno)
        elif section == "hierarchy":
            if key in ("begin", "end"):
                continue
            hierarchy[parts[0]] = parts[1:]
    if not bones:
        raise ClipFormatError(path, "no :bonedata found (is this an ASF file?)")
    parent: dict[str, str] = {}
    for p, kids in hierarchy.items():
        for k in kids:
            if k not in bones:
                raise ClipFormatError(path, f"hierarchy names unknown bone {k!r}")
            parent[k] = p
    order = ["root"]
    queue = ["root"]
    while queue:  # parents first, in hierarchy order
        p = queue.pop(0)
        for k in hierarchy.get(p, []):
            order.append(k)
            queue.append(k)
    missing = [b for b in bone_order if b not in order]
    if missing:
        raise ClipFormatError(path, f"bones not connected to the root: {missing[:3]}")
    def bone_vec(name):
        if name == "root":
            return np.zeros(3)
        b = bones[name]
        d = np.asarray(b["direction"], float)
        nrm = np.linalg.norm(d)
        return d / nrm * b["length"] if nrm > 0 else np.zeros(3)

    joints: list[Joint] = []
    index: dict[str, int] = {}
    for name in order:
        if name == "root":
            pre = euler_matrix(root["axis"], np.asarray(root["orientation"]) * angle_scale)
            j = Joint(name="root", parent=-1, offset=np.asarray(root["position"], float), dofs=list(root["order"]),
                      euler=root["axis"], pre=pre)
        else:
            b = bones[name]
            pre = euler_matrix(b["axis_order"], np.asarray(b["axis"]) * angle_scale)
            limits = {}
            if len(b["limits"]) == len(b["dof"]):
                limits = {d: lim for d, lim in zip(b["dof"], b["limits"])}
            j = Joint(name=name, parent=index[parent[name]], offset=bone_vec(parent[name]), dofs=list(b["dof"]),
                      euler=b["axis_order"], pre=pre, limits=limits)
            if not hierarchy.get(name):
                j.end = bone_vec(name)
        index[name] = len(joints)
        joints.append(j)
    from shared.io import conventions as cv

    sk = Skeleton(name=path.stem, joints=joints, unit_m=1.0, up_axis=1, source_format="asf")
    sk.unit_m = cv.choose_unit(path, cv.rest_extent(sk, 1), units, declared_m=INCH_M / length_unit)
    sk.__dict__["amc_angle_scale"] = angle_scale  # the AMC's angles are in the ASF's unit (read_amc)
    return sk


def _limit(tok: str) -> float:
    t = tok.lower()
    if t in ("inf", "+inf"):
        return float("inf")
    if t == "-inf":
        return float("-inf")
    return float(tok)


def _is_number(token: str) -> bool:
    try:
        float(token)
        return True
    except ValueError:
        return False


def read_amc(path, skeleton: Skeleton, fps: float = 120.0, label: str | None = None) -> Clip:
    """Read an AMC motion for ``skeleton``. HDM05 and CMU AMC files carry no frame rate:
    HDM05 is 120 fps (the default), CMU 120 fps as well."""
    path = Path(path)
    lines = _lines(path)
    channels = skeleton.channels()
    col = {c: i for i, c in enumerate(channels)}
    bone_cols = {j.name: [col[f"{j.name}.{d}"] for d in j.dofs] for j in skeleton.joints}
    nch = len(channels)
    regular = _regular_frames(lines, bone_cols, nch)
    if regular is not None:
        return _amc_clip(path, skeleton, *regular, fps=fps, label=label)
    # one pass over the lines checks the layout; the numbers are converted at once at the end
    tokens: list[str] = []  # every value, in file order
    where: list[int] = []  # its flat index frame * nch + column
    starts: list[tuple[int, int]] = []  # (first token, line number) of every bone line, for errors
    n_frames = 0
    expected_frame = None
    declared = None
    for lineno, line in enumerate(lines, 1):
        parts = line.split()
        if not parts or parts[0][0] == "#":
            continue
        if parts[0][0] == ":":
            if parts[0].lower() in (":radians", ":degrees"):
                declared = parts[0][1:].lower()
            continue
        if len(parts) == 1 and parts[0].isdigit():
            n = int(parts[0])
            if expected_frame is not None and n != expected_frame:
                raise ClipFormatError(path, f"frame {n} where frame {expected_frame} was expected", lineno)
            n_frames += 1
            expected_frame = n + 1
            continue
        if not n_frames:
            raise ClipFormatError(path, f"bone line {parts[0]!r} before the first frame number", lineno)
        cols = bone_cols.get(parts[0])
        if cols is None:
            raise ClipFormatError(path, f"bone {parts[0]!r} is not in skeleton {skeleton.name!r}", lineno)
        if len(parts) - 1 != len(cols):
            raise ClipFormatError(path, f"expected {len(cols)} numbers, got {len(parts) - 1}", lineno)
        starts.append((len(tokens), lineno))
        tokens += parts[1:]
        base = (n_frames - 1) * nch
        where += [base + c for c in cols]
    if not n_frames:
        raise ClipFormatError(path, "no frames found (is this an AMC file?)")
    try:
        values = np.array(tokens, dtype=float)
        bad = None if np.all(np.isfinite(values)) else int(np.flatnonzero(~np.isfinite(values))[0])
    except ValueError:
        bad = next(k for k, t in enumerate(tokens) if not _is_number(t))
    if bad is not None:  # name the line, as a reader of the file would look for it
        k = bisect.bisect_right(starts, (bad, float("inf"))) - 1
        end = starts[k + 1][0] if k + 1 < len(starts) else len(tokens)
        _floats(path, starts[k][1], tokens[starts[k][0]:end])  # raises, naming the number and the line
        raise ClipFormatError(path, "unreadable number", starts[k][1])
    flat = np.zeros(n_frames * nch)
    flat[np.array(where, dtype=np.int64)] = values
    return _amc_clip(path, skeleton, flat.reshape(n_frames, nch), declared, fps=fps, label=label)


def _amc_clip(path: Path, skeleton: Skeleton, data: np.ndarray, declared: str | None, fps: float,
              label: str | None) -> Clip:
    channels = skeleton.channels()
    # angles in the unit the AMC declares (:RADIANS / :DEGREES), else its ASF's; lengths stay file units
    scale = {"radians": 180.0 / math.pi, "degrees": 1.0}.get(declared or "", skeleton.__dict__.get("amc_angle_scale", 1.0))
    if scale != 1.0:
        rot = [i for i, c in enumerate(channels) if c.rsplit(".", 1)[1] in ("rx", "ry", "rz")]
        data[:, rot] *= scale
    cls = label if label is not None else path.parent.name
    return Clip(data=data, channels=channels, fps=fps, skeleton=skeleton, groups={"motion": list(channels)},
                name=path.stem, label=cls, source=str(path))


def _regular_frames(lines: list[str], bone_cols: dict[str, list[int]], nch: int) -> tuple[np.ndarray, str | None] | None:
    """The frames (and the declared angle unit) of an AMC whose every frame lists the bones of its
    first frame in the same order with the same counts of numbers, its frames numbered one by
    one, nothing but comments and ``:`` keywords before the first: HDM05's and CMU's files. The
    whole body is split into words once and each bone's numbers are one slice of them (every
    frame is the same number of words), converted at once: a third of the time of reading it line
    by line. ``None`` for any other file, which :func:`read_amc` then reads line by line (and
    names what is wrong with it)."""
    declared = None
    first = None
    for i, line in enumerate(lines):
        head = line.lstrip()[:1]
        if not head or head == "#":
            continue
        if head == ":":
            word = line.split()[0].lower()
            if word in (":radians", ":degrees"):
                declared = word[1:]
            continue
        if not line.strip().isdigit():
            return None
        first = i
        break
    if first is None:
        return None
    bones: list[str] = []
    frame_words = 1
    for line in lines[first + 1:]:
        parts = line.split()
        if not parts:
            continue
        if parts[0].isdigit() and len(parts) == 1:
            break
        cols = bone_cols.get(parts[0])
        if cols is None or len(parts) - 1 != len(cols) or parts[0] in bones:
            return None
        bones.append(parts[0])
        frame_words += len(parts)
    words = " ".join(lines[first:]).split()
    n_frames, rest = divmod(len(words), frame_words)
    if not bones or rest or len(list(filter(str.strip, lines[first:]))) != n_frames * (1 + len(bones)):
        return None
    start = int(words[0])
    if words[0::frame_words] != [str(k) for k in range(start, start + n_frames)]:
        return None
    at = 1
    value_at: list[int] = []
    for bone in bones:
        if words[at::frame_words] != [bone] * n_frames:
            return None
        value_at += range(at + 1, at + 1 + len(bone_cols[bone]))
        at += 1 + len(bone_cols[bone])
    try:
        values = np.array([words[k::frame_words] for k in value_at], dtype=float)
    except ValueError:
        return None
    if not np.all(np.isfinite(values)):
        return None
    data = np.zeros((n_frames, nch))
    data[:, [c for bone in bones for c in bone_cols[bone]]] = values.T
    return data, declared


def write_amc(clip: Clip, path) -> None:
    """Write an AMC file for a clip whose skeleton came from an ASF file."""
    if clip.skeleton is None or clip.skeleton.source_format != "asf":
        raise ClipFormatError(path, "AMC needs a clip on an ASF skeleton; write BVH or NPZ instead")
    sk = clip.skeleton
    values = {c: clip.data[:, i] for i, c in enumerate(clip.channels)}
    out = [":FULLY-SPECIFIED", ":DEGREES"]
    for t in range(clip.n_frames):
        out.append(str(t + 1))
        for j in sk.joints:
            if j.dofs:
                vals = [values[f"{j.name}.{d}"][t] if f"{j.name}.{d}" in values else 0.0 for d in j.dofs]
                out.append(j.name + " " + " ".join(f"{v:.10g}" for v in vals))
    Path(path).write_text("\n".join(out) + "\n", encoding="latin-1")


