"""Feet kept on the ground where the reference motion has them there (the stance of an emphatic motion).

An emphatic motion (eq. 4.3, in the residual form of ``shared.coaching.session``) moves every channel
away from the learner's attempt: the root's height and the legs' angles each on their own, so
its feet float or sink where the target's stand (the dg sneak at alpha 2: the weight-bearing foot
30 cm above the floor, the centre of gravity 0.3-0.45 m beside the one foot left near it). A
person shown it cannot do it, and no balance test can pass it, although nothing about its
emphasis needs the feet in the air.

:func:`plant_feet` puts them back, the cleanup animators apply after editing captured motion
(Kovar, Schreiner & Gleicher, "Footskate cleanup for motion capture editing", SCA 2002), by the
smallest change (damped least squares on MuJoCo's point and centre-of-gravity Jacobians) of the
root's height and of the joint angles between the root and the feet, frame by frame:

* a point of a foot that bears weight in the reference (within :data:`CONTACT_BAND` of its lowest
  point, the band the support test uses) goes to the reference's height, and stands where the
  reference's stands relative to the centre of gravity (the body over its feet as the target's);
* a lifted point stays no lower than the reference's while that is near the floor (the same feet
  bear weight as in the reference), and never below the floor;
* the changes are smoothed over 0.2 s, so the motion stays a motion (the balance test
  differentiates it twice), and no joint ends further past its limit than the motion had it.

The arms, the trunk and a lifted leg keep their emphasis; a standing leg keeps what standing
where the target stands allows.
"""

from __future__ import annotations

import threading

import mujoco
import numpy as np

from shared.bodies.body import CONTACT_BAND, Body, foot_anchors, foot_points, qpos_trajectory
from shared.motion.clip import Clip
from shared.motion.skeleton import Skeleton

#: damping of the least squares, per unit squared: a joint angle's change of 1 rad weighs like a
#: foot 3 cm off its place, the root's height like one 1 cm off (the root moves first)
LEG_DAMPING = 1e-3
ROOT_DAMPING = 1e-4
ITERATIONS = 6
SMOOTH_S = 0.2


def _leg_dofs(body: Body) -> list:
    """The hinges between the root and the feet (the body's tree walked up from each foot)."""
    m = body.model
    chain = set()
    for f in body.feet:
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f)
        while b > 0 and m.body_parentid[b] > 0:  # the root body (child of the world) is not a leg
            chain.add(b)
            b = int(m.body_parentid[b])
    return [d for d in body.dofs if d.scale is None and m.jnt_bodyid[int(m.dof_jntid[d.dof])] in chain]


def _centres_of_gravity(body: Body, q: np.ndarray) -> np.ndarray:
    """The whole body's centre of gravity (T, 3) by kinematics alone."""
    m = body.model
    data = mujoco.MjData(m)
    out = np.empty((len(q), 3))
    for t in range(len(q)):
        data.qpos[:] = q[t]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        out[t] = data.subtree_com[0]
    return out


def _smoothed(delta: np.ndarray, fps: float) -> np.ndarray:
    """The changes ramped in and out of every stance (a Hann window of ``SMOOTH_S``) instead of jumping."""
    w = max(3, int(round(SMOOTH_S * fps)) | 1)
    kernel = np.hanning(w + 2)[1:-1]
    kernel /= kernel.sum()
    pad = np.pad(delta, ((w // 2, w // 2), (0, 0)), mode="edge")
    return np.stack([np.convolve(pad[:, c], kernel, mode="valid") for c in range(delta.shape[1])], axis=1)


_REFERENCES: dict = {}  # the last references' stance geometry: a repair plants many motions on one target
_REFERENCES_LOCK = threading.Lock()  # the simulator answers requests in threads


def _reference(body: Body, reference: Clip, fps: float, n: int):
    """The reference on the motion's ``n`` frames: the support points (``foot_anchors``), their
    positions (n, points, 3) and the centre of gravity (n, 3); kept for the last 4 references."""
    key = (id(body.model), reference.fingerprint(), fps, n)
    with _REFERENCES_LOCK:
        hit = _REFERENCES.get(key)
    if hit is not None and hit[0] is body.model:
        return hit[1:]
    ref = reference.resample(fps) if reference.fps != fps else reference
    grid = np.linspace(0, ref.n_frames - 1, n).round().astype(int)
    ref_q = qpos_trajectory(body, ref)[grid]
    anchors = foot_anchors(body)
    out = (anchors, foot_points(body, ref_q, anchors), _centres_of_gravity(body, ref_q))
    with _REFERENCES_LOCK:
        while len(_REFERENCES) >= 4:
            _REFERENCES.pop(next(iter(_REFERENCES)))
        _REFERENCES[key] = (body.model, *out)
    return out


def plant_feet(body: Body, reference: Clip, motion: Clip) -> tuple[Clip, dict]:
    """``motion`` with its feet where ``reference`` has them on the ground (module docstring).

    Returns the motion (same channels and frames) and what changed: the largest change of the
    root's height (m) and of a leg angle (degrees), how many frames had a foot on the ground,
    and how far (m) the planted points stay from the reference's height (95th percentile).
    Bodies without feet or a free root, and motions without the root's vertical translation
    channel, come back unchanged (``{"planted": False, "why": ...}``)."""
    up = body.up_axis
    root_up = f"{body.root}.t{'xyz'[up]}" if body.root else None
    q = qpos_trajectory(body, motion)  # a motion without the body's joints is refused here (BadInput)
    if not body.feet or root_up is None or root_up not in motion.channels:
        return motion, {"planted": False, "why": "no feet, no free root or no root height channel"}
    m = body.model
    n = motion.n_frames
    anchors, ref_pts, ref_cog = _reference(body, reference, motion.fps, n)
    ground = float(ref_pts[..., up].min())
    stance = ref_pts[..., up] < ground + CONTACT_BAND  # (n, points)
    goal = ref_pts[..., up]
    legs = [d for d in _leg_dofs(body) if d.channel in motion.channels]
    if isinstance(body.skeleton, Skeleton):  # a joint the body drives on another Euler branch than the
        # motion's numbers (a wrap, a twin) would take its change in the wrong angles: it keeps its own
        cont = body.skeleton.continuous_angles(motion.data, motion.channels, keep_first=True)
        legs = [d for d in legs if np.allclose(cont[:, motion.channels.index(d.channel)],
                                               motion.data[:, motion.channels.index(d.channel)])]
    free = next(j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE)
    cols = [int(m.jnt_dofadr[free]) + up] + [d.dof for d in legs]  # velocity columns of the unknowns
    adr = [int(m.jnt_qposadr[free]) + up] + [d.qpos for d in legs]  # their positions in qpos
    damp = np.diag([ROOT_DAMPING] + [LEG_DAMPING] * len(legs))
    lo = np.array([-np.inf] + [np.radians(d.limits[0]) if d.limits else -np.inf for d in legs])
    hi = np.array([np.inf] + [np.radians(d.limits[1]) if d.limits else np.inf for d in legs])
    data = mujoco.MjData(m)
    jacp = np.empty((3, m.nv))
    delta = np.zeros((n, len(cols)))

    def points(qt):
        data.qpos[:] = qt
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        return [(b, data.xpos[b] + data.xmat[b].reshape(3, 3) @ local) for b, local in anchors]

    plane = [i for i in range(3) if i != up]
    jacc = np.empty((3, m.nv))
    for t in range(n):
        x0 = q[t, adr].copy()
        # the limits bind only what the motion itself keeps within them
        lo_t, hi_t = np.minimum(lo, x0), np.maximum(hi, x0)
        qt = q[t].copy()
        for _ in range(ITERATIONS):
            rows, res = [], []
            pts = points(qt)
            c = data.subtree_com[0].copy()
            mujoco.mj_jacSubtreeCom(m, data, jacc, 0)
            for k, (b, p) in enumerate(pts):
                # a standing point at the reference's height; a lifted one no lower than the
                # reference's while that is near the floor (the same feet bear weight) nor below it
                floor = goal[t, k] if goal[t, k] < ground + 3 * CONTACT_BAND else ground
                target = goal[t, k] if stance[t, k] else (floor if p[up] < floor else None)
                if target is None:
                    continue
                mujoco.mj_jac(m, data, jacp, None, p, b)
                rows.append(jacp[up, cols])
                res.append(p[up] - target)
                if stance[t, k]:  # where the foot stands under the body
                    for i in plane:
                        rows.append(jacp[i, cols] - jacc[i, cols])  # weighed like its height
                        res.append((p[i] - c[i]) - (ref_pts[t, k, i] - ref_cog[t, i]))
            if not rows:
                break
            j, r = np.array(rows), np.array(res)
            x = qt[adr]
            step = np.linalg.solve(j.T @ j + damp, -(j.T @ r + damp @ (x - x0)))
            qt[adr] = np.clip(x + step, lo_t, hi_t)
        delta[t] = qt[adr] - x0
    delta = _smoothed(delta, motion.fps)
    data_out = motion.data.copy()
    assert body.skeleton is not None  # (feet to plant: a person's body)
    data_out[:, motion.channels.index(root_up)] += delta[:, 0] / body.skeleton.unit_m
    for k, d in enumerate(legs):
        i = motion.channels.index(d.channel)
        before = data_out[:, i].copy()
        data_out[:, i] += np.degrees(delta[:, k + 1])
        if d.limits is not None:
            data_out[:, i] = np.clip(data_out[:, i], np.minimum(d.limits[0], before), np.maximum(d.limits[1], before))
    planted = motion.with_data(data_out)
    q[:, adr] += delta  # the planted motion's positions, as the body is driven by them
    after = foot_points(body, q, anchors)[..., up]
    miss = np.abs(after - goal)[stance]
    return planted, {"planted": True, "stance_frames": int(stance.any(axis=1).sum()),
                     "root_height_change_m": float(np.abs(delta[:, 0]).max()),
                     "leg_angle_change_deg": float(np.degrees(np.abs(delta[:, 1:]).max())) if legs else 0.0,
                     "stance_error_m": float(np.percentile(miss, 95)) if miss.size else 0.0}
