"""An independent forward kinematics of BVH files, as Blender reads them: the reference the
motion-capture measurements and tests compare mirrorcoach's reader with.

Nothing of ``shared/`` is used: its own parser, its own rotations. Blender's reading: a joint's
position channels are its whole local position (its OFFSET when it has none), its rotation
channels compose in file order about the parent-aligned axes (intrinsic), every number in the
file's own unit and axes. Positions of joints, in file units, file axes, (T, J, 3), joints in
file order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _axis_matrices(axis: str, deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    m = np.zeros((len(a), 3, 3))
    i = "XYZ".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    m[:, i, i] = 1.0
    m[:, j, j] = c
    m[:, k, k] = c
    m[:, j, k] = -s
    m[:, k, j] = s
    return m


def read_positions(path) -> tuple[list[str], np.ndarray]:
    """(joint names, positions (T, J, 3)) of a BVH file, in its own units and axes."""
    text = Path(path).read_text(encoding="latin-1")
    head, motion = text.split("MOTION", 1)
    toks = head.replace("{", " { ").replace("}", " } ").split()
    names, parents, offsets, chans = [], [], [], []
    stack, i = [], 0
    while i < len(toks):
        t = toks[i]
        if t in ("ROOT", "JOINT"):
            names.append(toks[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            chans.append([])
            stack.append(len(names) - 1)
            i += 2
        elif t == "End":
            depth = 0  # skip the End Site block
            while True:
                i += 1
                if toks[i] == "{":
                    depth += 1
                elif toks[i] == "}":
                    depth -= 1
                    if depth == 0:
                        break
            i += 1
        elif t == "OFFSET":
            offsets[stack[-1]] = np.array([float(x) for x in toks[i + 1:i + 4]])
            i += 4
        elif t == "CHANNELS":
            n = int(toks[i + 1])
            chans[stack[-1]] = toks[i + 2:i + 2 + n]
            i += 2 + n
        elif t == "}":
            stack.pop()
            i += 1
        else:
            i += 1
    lines = [ln for ln in motion.splitlines() if ln.strip()]
    start = next(k for k, ln in enumerate(lines) if ln.strip().lower().startswith("frame time"))
    data = np.array([[float(x) for x in ln.split()] for ln in lines[start + 1:]])
    n = len(data)
    pos = np.zeros((n, len(names), 3))
    glob = np.zeros((len(names), n, 3, 3))
    col = 0
    for j, ch in enumerate(chans):
        local_t = np.tile(offsets[j], (n, 1))
        rot = np.tile(np.eye(3), (n, 1, 1))
        for c in ch:
            v = data[:, col]
            col += 1
            if c.endswith("position"):
                local_t[:, "XYZ".index(c[0].upper())] = v
            else:
                rot = rot @ _axis_matrices(c[0].upper(), v)
        p = parents[j]
        if p < 0:
            pos[:, j] = local_t
            glob[j] = rot
        else:
            pos[:, j] = pos[:, p] + np.einsum("tab,tb->ta", glob[p], local_t)
            glob[j] = glob[p] @ rot
    return names, pos
