"""Forward kinematics compiled with numba: the hot path of the position channel group.

:meth:`shared.motion.skeleton.Skeleton.forward_kinematics` packs a skeleton into arrays and calls
:func:`fk_positions`; the numpy/scipy path (:meth:`Skeleton.forward_kinematics_reference`)
is the reference it is tested against. Kept out of :mod:`shared.motion.skeleton` so that reading a
clip does not import numba.
"""

from __future__ import annotations

import numpy as np

from shared.compiled import kernel


@kernel(cache=True, nogil=True)
def _mul(a, b, out):
    """3x3 product by hand (numba's ``@`` calls BLAS, whose overhead dominates at 3x3)."""
    for i in range(3):
        for k in range(3):
            out[i, k] = a[i, 0] * b[0, k] + a[i, 1] * b[1, k] + a[i, 2] * b[2, k]


@kernel(cache=True, nogil=True)
def _joint_local(angles, axes, intrinsic, pre, m, out):
    """``out = C M C^T`` for one joint and frame; ``m`` is a scratch 3x3.

    ``M`` is built in place from the identity: a rotation by ``a`` about axis ``code`` only mixes
    the two other columns (intrinsic, ``M = R1 R2 R3``: right-multiplied) or rows (extrinsic,
    ``M = R3 R2 R1``: left-multiplied), so each axis costs 6 products instead of a 3x3 product
    (3x faster than building each axis's matrix; the same numbers, since the products it leaves
    out are by 0 and 1)."""
    for i in range(3):
        for k in range(3):
            m[i, k] = 1.0 if i == k else 0.0
    for k in range(3):
        code = axes[k]
        if code < 0:
            continue
        c, s = np.cos(angles[k]), np.sin(angles[k])
        i, j = (code + 1) % 3, (code + 2) % 3
        for r in range(3):
            if intrinsic:  # M R: columns i and j
                a, b = m[r, i], m[r, j]
                m[r, i] = a * c + b * s
                m[r, j] = b * c - a * s
            else:  # R M: rows i and j
                a, b = m[i, r], m[j, r]
                m[i, r] = c * a - s * b
                m[j, r] = s * a + c * b
    for r in range(3):  # C M C^T
        t0 = pre[r, 0] * m[0, 0] + pre[r, 1] * m[1, 0] + pre[r, 2] * m[2, 0]
        t1 = pre[r, 0] * m[0, 1] + pre[r, 1] * m[1, 1] + pre[r, 2] * m[2, 1]
        t2 = pre[r, 0] * m[0, 2] + pre[r, 1] * m[1, 2] + pre[r, 2] * m[2, 2]
        for q in range(3):
            out[r, q] = t0 * pre[q, 0] + t1 * pre[q, 1] + t2 * pre[q, 2]


@kernel(cache=True, nogil=True)
def fk_positions(ang, axes, intrinsic, pre, parent, offset, trans, end_joint, end_offset):
    """Joint and end-site positions (T, J + E, 3) in the skeleton's unit.

    ``ang`` (T, J, 3) radians in each joint's Euler order, ``axes`` (J, 3) axis codes
    (0 x, 1 y, 2 z, -1 none), ``intrinsic`` (J,), ``pre`` (J, 3, 3) the ASF axis
    pre-rotation ``C`` (``L = C M C^T``), ``parent`` (J,) (-1 for the root), ``offset``
    (J, 3), ``trans`` (T, J, 3) every joint's translation channels (added to its offset in its
    parent's frame; the root's in the world), ``end_joint`` (E,) and ``end_offset`` (E, 3).
    """
    n, nj = ang.shape[0], ang.shape[1]
    ne = end_joint.shape[0]
    out = np.zeros((n, nj + ne, 3))
    glob = np.zeros((nj, 3, 3))
    m = np.zeros((3, 3))
    tmp = np.zeros((3, 3))
    local = np.zeros((3, 3))
    for t in range(n):
        for j in range(nj):
            _joint_local(ang[t, j], axes[j], intrinsic[j], pre[j], m, local)
            p = parent[j]
            ox = offset[j, 0] + trans[t, j, 0]
            oy = offset[j, 1] + trans[t, j, 1]
            oz = offset[j, 2] + trans[t, j, 2]
            if p < 0:
                glob[j] = local
                out[t, j, 0] = ox
                out[t, j, 1] = oy
                out[t, j, 2] = oz
            else:
                _mul(glob[p], local, tmp)
                glob[j] = tmp
                g = glob[p]
                for a in range(3):
                    out[t, j, a] = out[t, p, a] + g[a, 0] * ox + g[a, 1] * oy + g[a, 2] * oz
        for e in range(ne):
            j = end_joint[e]
            g = glob[j]
            for a in range(3):
                out[t, nj + e, a] = (out[t, j, a] + g[a, 0] * end_offset[e, 0] + g[a, 1] * end_offset[e, 1]
                                     + g[a, 2] * end_offset[e, 2])
    return out


@kernel(cache=True, nogil=True)
def local_rotations(ang, axes, intrinsic, pre):
    """Every joint's local rotation ``L = C M C^T`` (T, J, 3, 3) (arguments as :func:`fk_positions`)."""
    n, nj = ang.shape[0], ang.shape[1]
    out = np.empty((n, nj, 3, 3))
    m = np.zeros((3, 3))
    for t in range(n):
        for j in range(nj):
            _joint_local(ang[t, j], axes[j], intrinsic[j], pre[j], m, out[t, j])
    return out


@kernel(cache=True, nogil=True)
def _wrap180(x):
    return (x + 180.0) % 360.0 - 180.0


@kernel(cache=True, nogil=True)
def continuous_tait_bryan(ang, start):
    """The rotations of Tait-Bryan angles ``ang`` (T, 3) in degrees on the branch nearest the
    previous frame: each frame takes whichever of ``(a, b, c)`` and its twin
    ``(a + 180, 180 - b, c + 180)`` (the same rotation), each angle moved by whole turns, lies
    nearest the frame before; the first frame is compared with ``start``. The rotations are
    unchanged; only their Euler triple is chosen (see :func:`shared.motion.skeleton.continuous_euler`)."""
    n = ang.shape[0]
    out = np.empty((n, 3))
    prev = start.copy()
    cand = np.empty((2, 3))
    for t in range(n):
        cand[0, 0] = ang[t, 0]
        cand[0, 1] = ang[t, 1]
        cand[0, 2] = ang[t, 2]
        cand[1, 0] = ang[t, 0] + 180.0
        cand[1, 1] = 180.0 - ang[t, 1]
        cand[1, 2] = ang[t, 2] + 180.0
        best = 0
        best_d = 1e300
        for k in range(2):
            d = 0.0
            for a in range(3):
                w = _wrap180(cand[k, a] - prev[a])
                d += w * w
            if d < best_d:
                best_d = d
                best = k
        for a in range(3):
            out[t, a] = prev[a] + _wrap180(cand[best, a] - prev[a])
            prev[a] = out[t, a]
    return out


# ---------------------------------------------------------------- numpy twins (shared.compiled)
def _axis_matrices(code: int, a: np.ndarray) -> np.ndarray:
    """:func:`_axis` for a vector of angles: (T, 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    i, j = (code + 1) % 3, (code + 2) % 3
    out = np.zeros(a.shape + (3, 3))
    out[:, code, code] = 1.0
    out[:, i, i] = c
    out[:, j, j] = c
    out[:, i, j] = -s
    out[:, j, i] = s
    return out


@local_rotations.numpy
def _local_rotations_numpy(ang, axes, intrinsic, pre):
    n, nj = ang.shape[0], ang.shape[1]
    out = np.empty((n, nj, 3, 3))
    for j in range(nj):
        m = np.broadcast_to(np.eye(3), (n, 3, 3))
        for k in range(3):
            if axes[j, k] < 0:
                continue
            r = _axis_matrices(int(axes[j, k]), ang[:, j, k])
            m = m @ r if intrinsic[j] else r @ m
        out[:, j] = pre[j] @ m @ pre[j].T
    return out


@fk_positions.numpy
def _fk_positions_numpy(ang, axes, intrinsic, pre, parent, offset, trans, end_joint, end_offset):
    n, nj = ang.shape[0], ang.shape[1]
    local = _local_rotations_numpy(ang, axes, intrinsic, pre)
    out = np.zeros((n, nj + len(end_joint), 3))
    glob = np.empty((nj, n, 3, 3))
    for j in range(nj):
        p = parent[j]
        o = offset[j] + trans[:, j]
        if p < 0:
            glob[j] = local[:, j]
            out[:, j] = o
        else:
            glob[j] = glob[p] @ local[:, j]
            out[:, j] = out[:, p] + np.einsum("tab,tb->ta", glob[p], o)
    for e, j in enumerate(end_joint):
        out[:, nj + e] = out[:, j] + glob[j] @ end_offset[e]
    return out


def _two_state_chain(c0: int, following: np.ndarray) -> np.ndarray:
    """``c[0] = c0``, ``c[t + 1] = following[t, c[t]]``: a chain over two states without a loop
    over its steps. A step whose two rows agree sets the state, one that maps 0 to 0 and 1 to 1
    keeps it, one that swaps them flips it; so each state is the one last set, flipped by the
    swaps after it (the frame-by-frame loop took 25 ms of reading a 1,000-frame BVH)."""
    n = len(following) + 1
    sets = np.r_[True, following[:, 0] == following[:, 1]]
    last_set = np.maximum.accumulate(np.where(sets, np.arange(n), 0))
    flips = np.r_[0, np.cumsum((following[:, 0] == 1) & (following[:, 1] == 0))]
    return np.r_[c0, following[:, 0]][last_set] ^ ((flips - flips[last_set]) & 1)


@continuous_tait_bryan.numpy
def _continuous_tait_bryan_numpy(ang, start):
    """The same choice frame by frame: which twin is nearest depends only on the previous
    frame's chosen triple modulo whole turns, so the choices are a chain over two candidates
    (:func:`_two_state_chain`, from precomputed distances) and the output a cumulative sum of
    wrapped steps."""
    n = ang.shape[0]
    if n == 0:
        return np.empty((0, 3))
    cand = np.stack([ang, ang * [1.0, -1.0, 1.0] + [180.0, 180.0, 180.0]], axis=1)  # (T, 2, 3)

    def wrap(x):
        return (x + 180.0) % 360.0 - 180.0

    first = (wrap(cand[0] - start) ** 2).sum(axis=1)
    # step[t, j, k]: squared distance from candidate j of frame t to candidate k of frame t + 1
    step = (wrap(cand[1:, None, :, :] - cand[:-1, :, None, :]) ** 2).sum(axis=3)
    c = _two_state_chain(0 if first[0] <= first[1] else 1, (step[:, :, 1] < step[:, :, 0]).astype(np.int64))
    chosen = cand[np.arange(n), c]
    out = np.empty((n, 3))
    out[0] = start + wrap(chosen[0] - start)
    out[1:] = out[0] + np.cumsum(wrap(np.diff(chosen, axis=0)), axis=0)
    return out
