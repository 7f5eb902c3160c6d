"""A body in MuJoCo and what performing a motion with it feels like.

:class:`Body` wraps a compiled ``mujoco.MjModel`` with the map from a clip's motion channels
to its joints. :func:`perform` computes, for a motion clip:

* (a robot holds the joints a motion does not name at 0; a human body needs every channel)
* joint torques by inverse dynamics (``mj_inverse``); positions are smoothed by a
  Savitzky-Golay filter (cubic, window ``~0.1 s``, at least 5 frames), velocities and
  accelerations are central differences of the smoothed positions computed with
  ``mj_differentiatePos`` (so the free root's quaternion is differentiated correctly);
  the free root's 6 generalised forces are the residual (unmodelled ground reaction) and are
  not reported as torques;
* the centre of gravity (``subtree_com`` of the world body) and its ground projection;
* a feasibility report: joint-limit violations (per channel, frames outside the limits) and,
  for bodies with feet, frames whose centre-of-gravity projection leaves the support area
  (convex hull of the foot points in contact with the ground, plus a margin).

The result is the clip with sensor channels ``tau.<joint>`` (N m) and ``cog.x|y|z`` (m, in
the clip's own axes) plus the report.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

import mujoco
import numpy as np

from shared.errors import BadInput
from shared.motion.clip import Clip
from shared.motion.skeleton import Skeleton


def _mujoco_warning(message: str) -> None:
    """MuJoCo's warnings go to the process log (not to a MUJOCO_LOG.TXT in whatever folder the
    process runs in); the run-time ones also reach the perform report (``mujoco_warnings``)."""
    logging.getLogger("mujoco").warning(message.strip())


mujoco.set_mju_user_warning(_mujoco_warning)

GRAVITY = 9.81
FRICTION_VELOCITY = 0.05  # rad/s: Coulomb friction is smoothed as friction * tanh(qdot / this)


def coulomb(qdot: np.ndarray) -> np.ndarray:
    """The smoothed sign of a joint velocity that scales Coulomb friction."""
    return np.tanh(np.asarray(qdot, float) / FRICTION_VELOCITY)


@dataclass
class DofMap:
    """One motion channel driving one joint of the model: a hinge (degrees) or a slide
    (``scale``: metres per channel unit, for the position channels of 6-channel skeletons)."""

    channel: str  # e.g. "rhumerus.rx" or "shoulder_pitch"
    qpos: int
    dof: int
    limits: tuple[float, float] | None = None  # degrees
    scale: float | None = None  # a slide joint: metres per channel unit


@dataclass
class Body:
    """A compiled MuJoCo body and how a clip drives it.

    ``root`` names the clip's root joint when the body floats (a free joint fed by the root's
    translation and rotation channels); ``feet`` lists bodies whose points make the support area.
    """

    name: str
    kind: str  # "robot" or "human"
    model: mujoco.MjModel
    dofs: list[DofMap]
    mass: float
    skeleton: Skeleton | None = None
    root: str | None = None
    feet: list[str] = field(default_factory=list)
    up_axis: int = 2
    unmapped: list[str] = field(default_factory=list)  # unusual bones: a limb no person has (human bodies)
    missing_segments: list[str] = field(default_factory=list)  # de Leva segments the skeleton lacks
    friction: dict[str, float] = field(default_factory=dict)  # channel -> Coulomb friction, N m (robots)
    #: the tracking test's model with a floor and its sole points (shared.bodies.tracking), built when first asked
    tracking: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def channels(self) -> list[str]:
        return [d.channel for d in self.dofs]

    def describe(self) -> dict:
        return {"name": self.name, "kind": self.kind, "mass": float(self.mass), "channels": self.channels,
                "n_bodies": int(self.model.nbody - 1), "floating": self.root is not None, "feet": list(self.feet),
                "unmapped_bones": list(self.unmapped), "missing_segments": list(self.missing_segments)}


def smooth_window(fps: float, n: int) -> int:
    """Savitzky-Golay window: about 0.1 s, odd, at least 5 frames, at most the clip."""
    w = max(5, int(round(0.1 * fps)) | 1)
    return min(w, n if n % 2 else n - 1)


def qpos_trajectory(body: Body, clip: Clip) -> np.ndarray:
    """Joint positions (T, nq) from the clip, in radians and metres."""
    from scipy.signal import savgol_filter

    m = body.model
    missing = [c for c in body.channels if c not in clip.channels]
    held = body.kind == "robot" and len(missing) < len(body.channels)  # a robot holds unnamed joints at 0
    if missing and not held:
        raise BadInput(f"the motion lacks {len(missing)} of body {body.name!r}'s joint channels, e.g. {missing[:3]}",
                       body=body.name)
    n = clip.n_frames
    if n < 5:
        raise BadInput(f"a motion needs at least 5 frames to differentiate, got {n}")
    w = smooth_window(clip.fps, n)
    q = np.tile(m.qpos0, (n, 1))
    # Euler angles continuous before anything is smoothed or differentiated: a wrap of 360 degrees or
    # a change of Euler branch is no motion (a file crossing +-180 gave hip torques of 47,000 N m)
    if isinstance(body.skeleton, Skeleton):
        clip = clip.with_data(body.skeleton.continuous_angles(clip.data, clip.channels, keep_first=True))
    else:
        rot = [i for i, c in enumerate(clip.channels) if c.rsplit(".", 1)[-1] in ("rx", "ry", "rz")]
        data = clip.data.copy()
        data[:, rot] = np.rad2deg(np.unwrap(np.deg2rad(data[:, rot]), axis=0))
        clip = clip.with_data(data)
    driven = [d for d in body.dofs if d.channel in clip.channels]
    if driven:  # one filter call for every channel: the edge fits are shared
        angles = savgol_filter(clip.select([d.channel for d in driven]), w, 3, axis=0, mode="interp")
        for k, d in enumerate(driven):
            q[:, d.qpos] = np.radians(angles[:, k]) if d.scale is None else angles[:, k] * d.scale
    if body.root is not None:
        sk = body.skeleton
        assert sk is not None  # (a free root: a person's body, built from a skeleton)
        r = body.root
        trans = np.stack([clip.column(f"{r}.t{a}") if f"{r}.t{a}" in clip.channels else np.zeros(n) for a in "xyz"], axis=1)
        trans = savgol_filter(trans, w, 3, axis=0, mode="interp")
        root_joint = sk.joints[sk.index(r)]
        q[:, 0:3] = (root_joint.offset + trans) * sk.unit_m
        root_rot = [c for c in clip.channels if c.startswith(f"{r}.r")]
        smooth = savgol_filter(clip.select(root_rot), w, 3, axis=0, mode="interp") if root_rot else np.zeros((n, 0))
        values = {c: smooth[:, k] for k, c in enumerate(root_rot)}
        glob = sk.local_rotations(values, n, joints=[root_joint])[0]
        from scipy.spatial.transform import Rotation

        frame = glob * Rotation.from_matrix(root_joint.pre)  # the root body's frame: L_root C_root
        xyzw = frame.as_quat()
        q[:, 3:7] = np.column_stack([xyzw[:, 3], xyzw[:, :3]])
    return q


def qpos_derivatives(model, q: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocities and accelerations (T, nv) by central differences (``mj_differentiatePos``)."""
    n = len(q)
    dt = 1.0 / fps
    if model.nq == model.nv:  # hinges and slides only: MuJoCo's (q2 - q1) / dt, every frame at once
        fwd = (q[1:] - q[:-1]) / dt
    else:
        fwd = np.empty((n - 1, model.nv))
        for t in range(n - 1):
            mujoco.mj_differentiatePos(model, fwd[t], dt, q[t], q[t + 1])
    v = np.empty((n, model.nv))
    v[1:-1] = 0.5 * (fwd[:-1] + fwd[1:])
    v[0], v[-1] = fwd[0], fwd[-1]
    a = np.empty_like(v)
    a[1:-1] = (fwd[1:] - fwd[:-1]) / dt
    a[0], a[-1] = a[1], a[-2]
    return v, a


_SCRATCH = threading.local()


def scratch_data(model) -> mujoco.MjData:
    """An ``MjData`` of ``model`` for this thread, reset (as new: warnings cleared), kept for the
    next call: making one costs about as much as ``mj_inverse`` on 50 frames. The last 16 models
    a thread used keep theirs."""
    kept = getattr(_SCRATCH, "data", None)
    if kept is None:
        kept = _SCRATCH.data = {}
    hit = kept.pop(id(model), None)
    if hit is None or hit[0] is not model:
        hit = (model, mujoco.MjData(model))
    else:
        mujoco.mj_resetData(model, hit[1])
    kept[id(model)] = hit  # the most recent last
    while len(kept) > 16:
        kept.pop(next(iter(kept)))
    return hit[1]


def mj_inverse_series(model, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                      warnings: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``mj_inverse`` frame by frame: generalised forces (T, nv) and the centre of gravity (T, 3).
    ``warnings``, if given, receives MuJoCo's warning counts (``inertia``, ``badqacc``, ...)."""
    data = scratch_data(model)
    tau = np.empty((len(q), model.nv))
    cog = np.empty((len(q), 3))
    # the data's arrays looked up once (views of its memory): each lookup made a new array object,
    # most of the Python around the call (0.36 -> 0.27 ms for 61 frames, the same numbers)
    qpos, qvel, qacc, frc, com = data.qpos, data.qvel, data.qacc, data.qfrc_inverse, data.subtree_com[0]
    inverse = mujoco.mj_inverse
    for t in range(len(q)):
        qpos[:] = q[t]
        qvel[:] = v[t]
        qacc[:] = a[t]
        inverse(model, data)
        tau[t] = frc
        cog[t] = com
    if warnings is not None:
        for name, w in mujoco.mjtWarning.__members__.items():
            if w != mujoco.mjtWarning.mjNWARNING and data.warning[int(w)].number:
                warnings[name.removeprefix("mjWARN_").lower()] = int(data.warning[int(w)].number)
    return tau, cog


def inverse_dynamics(body: Body, q: np.ndarray, fps: float, warnings: dict | None = None):
    """(qvel, qacc, qfrc_inverse, centre of gravity (T, 3)) for a joint trajectory."""
    v, a = qpos_derivatives(body.model, q, fps)
    tau, cog = mj_inverse_series(body.model, q, v, a, warnings)
    return v, a, tau, cog


def _root_wrench(body: Body, q: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The ground reaction the motion needs: the free root's generalised forces from inverse
    dynamics as a world force ``F`` (T, 3) and a world moment ``M`` (T, 3) about the root's
    origin ``r`` (T, 3); ``None`` for a body without a free root."""
    m = body.model
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    if not free:
        return None
    qa, da = int(m.jnt_qposadr[free[0]]), int(m.jnt_dofadr[free[0]])
    rot = np.empty(9)
    moment = np.empty((len(q), 3))
    for t in range(len(q)):
        mujoco.mju_quat2Mat(rot, q[t, qa + 3:qa + 7])
        moment[t] = rot.reshape(3, 3) @ tau[t, da + 3:da + 6]  # a free joint's rotational forces are in its body's frame
    return tau[:, da:da + 3], moment, q[:, qa:qa + 3]


def _centre_of_pressure(force: np.ndarray, moment: np.ndarray, origin: np.ndarray, up: int, ground: float) -> np.ndarray:
    """The point ``p`` on the ground plane about which the ground reaction has no horizontal
    moment (the zero-moment point): ``[M + (origin - p) x F]_horizontal = 0``, linear in ``p``:
    one 2 x 2 system per frame, all frames solved at once (NaN where it is singular)."""
    plane = [i for i in range(3) if i != up]

    def horizontal(pa: float, pb: float) -> np.ndarray:
        p = np.empty((len(force), 3))
        p[:, plane[0]], p[:, plane[1]], p[:, up] = pa, pb, ground
        return (moment + np.cross(origin - p, force))[:, plane]

    f0 = horizontal(0.0, 0.0)
    a = np.stack([horizontal(1.0, 0.0) - f0, horizontal(0.0, 1.0) - f0], axis=2)  # (T, 2, 2): the columns
    out = np.full((len(force), 2), np.nan)
    ok = np.abs(np.linalg.det(a)) > 1e-9
    if ok.any():
        out[ok] = np.linalg.solve(a[ok], -f0[ok][..., None])[..., 0]
    return out


def _hull_distances(contact: np.ndarray, points: list[np.ndarray]) -> list[float]:
    """Signed distance (m) of each ground point outside the convex hull of ``contact``
    (negative inside), the points on one hull; a segment's distance when the contact points do
    not span an area."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        eq = ConvexHull(contact).equations
        return [float(np.max(eq[:, :2] @ c + eq[:, 2])) for c in points]
    except (QhullError, ValueError):  # fewer than 3 points or collinear: distance to the segment
        a, b = contact.min(axis=0), contact.max(axis=0)
        ab = b - a
        out = []
        for c in points:
            s = np.clip(np.dot(c - a, ab) / max(np.dot(ab, ab), 1e-12), 0, 1)
            out.append(float(np.linalg.norm(c - (a + s * ab))))
        return out


def runs_of(flags: np.ndarray) -> list[list[int]]:
    """The [start, stop) runs of the frames ``flags`` marks."""
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(int), 0]))
    return [[int(a), int(b)] for a, b in zip(edges[::2], edges[1::2])]


def foot_anchors(body: Body) -> list[tuple[int, np.ndarray]]:
    """The points whose hull is the support area, as (MuJoCo body id, point in that body's frame):
    each foot bone's origin, the far end of its segment (its centre of mass mirrored through the
    origin: the ball of the foot, the tips of the toes) and, for a bone that starts at the ankle
    (its parent is no foot bone), the heel: the point under the ankle at the height of the sole
    in the rest pose (between 2 and 20 cm below it; a rest pose without flat feet has none)."""
    m = body.model
    data = mujoco.MjData(m)
    mujoco.mj_kinematics(m, data)  # the rest pose
    up = body.up_axis
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f) for f in body.feet]
    out = []
    for b in ids:
        out += [(b, np.zeros(3)), (b, 2 * m.body_ipos[b].copy())]
    for b in ids:
        if int(m.body_parentid[b]) in ids:
            continue
        ends = [data.xpos[k] + data.xmat[k].reshape(3, 3) @ (2 * m.body_ipos[k]) for k in ids
                if k == b or int(m.body_parentid[k]) == b]
        sole = min(e[up] for e in ends)
        drop = float(data.xpos[b][up] - sole)
        if 0.02 <= drop <= 0.2:
            heel = data.xpos[b].copy()
            heel[up] = sole
            out.append((b, data.xmat[b].reshape(3, 3).T @ (heel - data.xpos[b])))
    return out


def foot_points(body: Body, q: np.ndarray, anchors: list | None = None) -> np.ndarray:
    """The support area's points (T, anchors, 3) in metres (:func:`foot_anchors`)."""
    m = body.model
    data = mujoco.MjData(m)
    anchors = foot_anchors(body) if anchors is None else anchors
    pts = np.empty((len(q), len(anchors), 3))
    qpos, xpos, xmat = data.qpos, data.xpos, data.xmat.reshape(-1, 3, 3)  # views, looked up once
    for t in range(len(q)):
        qpos[:] = q[t]
        mujoco.mj_kinematics(m, data)
        for k, (b, local) in enumerate(anchors):
            pts[t, k] = xpos[b] + xmat[b] @ local
    return pts


#: a foot point within this height of the lowest one bears weight (the support area, the stance)
CONTACT_BAND = 0.05


def _support_report(body: Body, q: np.ndarray, cog: np.ndarray, margin: float = 0.05,
                    wrench: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> dict:
    """Frames whose centre-of-gravity ground projection is outside the support area (static
    balance) and, with the root's ``wrench`` (:func:`_root_wrench`), frames whose centre of
    pressure (zero-moment point) is outside it or whose ground would have to pull (dynamic
    balance: no controller can follow such a frame without tipping, whatever its gains)."""
    if not body.feet:
        return {"checked": False}

    up = body.up_axis
    plane = [i for i in range(3) if i != up]
    pts = foot_points(body, q)
    ground = pts[..., up].min()
    outside, airborne, worst = 0, 0, 0.0
    flags = np.zeros(len(q), bool)
    dyn = np.zeros(len(q), bool)
    cop = None if wrench is None else _centre_of_pressure(*wrench, up, ground)
    weight = float(body.mass) * 9.81
    for t in range(len(q)):
        contact = pts[t][pts[t][:, up] < ground + CONTACT_BAND][:, plane]
        c = cog[t, plane]
        if len(contact) == 0:
            airborne += 1
            continue
        push = 0.0 if wrench is None else float(wrench[0][t, up])
        # the centre of pressure is judged where the ground pushes, on the same hull as the centre of gravity
        pressed = cop is not None and push > 0.1 * weight and bool(np.all(np.isfinite(cop[t])))
        dists = _hull_distances(contact, [c, cop[t]] if pressed and cop is not None else [c])
        if dists[0] > margin:
            outside += 1
            flags[t] = True
            worst = max(worst, dists[0] - margin)
        # the ground pulls (more than a tenth of the weight), or its push acts outside the feet
        dyn[t] = push < -0.1 * weight or (pressed and dists[1] > margin)
    out = {"checked": True, "frames_outside_support": outside, "frames_airborne": airborne,
           "max_distance_outside_m": worst, "margin_m": margin,
           # which frames, as [start, stop) runs: where a demonstration must keep its balance
           "outside_runs": runs_of(flags)}
    if wrench is not None:
        out.update(dynamic_checked=True, frames_dynamic_outside=int(dyn.sum()), dynamic_runs=runs_of(dyn))
    return out


def perform(body: Body, clip: Clip, q: np.ndarray | None = None) -> tuple[Clip, dict]:
    """The clip performed by ``body``: torques, centre of gravity and a feasibility report
    (:func:`shared.bodies.tracking.perform_tracked` adds the simulated test). ``q``: the clip's
    :func:`qpos_trajectory` when the caller has it."""
    q = qpos_trajectory(body, clip) if q is None else q
    warned: dict = {}
    v, _, tau, cog = inverse_dynamics(body, q, clip.fps, warned)
    for d in body.dofs:  # Coulomb friction, which mj_inverse does not model (damping it does)
        if d.channel in body.friction:
            tau[:, d.dof] += body.friction[d.channel] * coulomb(v[:, d.dof])
    limits = {}
    limited = [(d, d.limits) for d in body.dofs if d.limits is not None and d.channel in clip.channels]
    for d, (lo, hi) in limited:
        x = clip.column(d.channel)
        bad = int(np.sum((x < lo - 1.0) | (x > hi + 1.0)))
        if bad:
            limits[d.channel] = {"frames": bad, "min": float(x.min()), "max": float(x.max()), "limits": [lo, hi]}
    support = _support_report(body, q, cog, wrench=_root_wrench(body, q, tau))
    not_checked = []
    if not limited:
        not_checked.append("joint limits (the body has none for this clip's channels)")
    if not support.get("checked"):
        not_checked.append("balance (no feet found on the body"
                           + (f"; unusual bones: {', '.join(body.unmapped[:5])}" if body.unmapped else "") + ")")
    if warned:  # MuJoCo's numbers are suspect: the reply says so instead of a log line only
        not_checked.append("dynamics (MuJoCo warned: " + ", ".join(f"{k} x{n}" for k, n in warned.items()) + ")")
    failed = bool(limits) or bool(support.get("checked") and support["frames_outside_support"] > 0)
    report = {"body": body.name, "mass": float(body.mass), "frames": clip.n_frames,
              "joint_limit_violations": limits, "support": support, "not_checked": not_checked,
              "mujoco_warnings": warned,
              # nothing checked (or numbers MuJoCo warned about) is not "feasible": None says so
              "feasible": False if failed else (None if len(not_checked) >= 2 or warned else True)}
    names = [f"tau.{d.channel}" for d in body.dofs] + ["cog.x", "cog.y", "cog.z"]
    values = np.column_stack([tau[:, [d.dof for d in body.dofs]], cog])
    base = clip.select(clip.group("motion")) if clip.group("motion") else clip.data
    motion = clip.with_data(base, channels=clip.group("motion") or list(clip.channels),
                            groups={"motion": clip.group("motion") or list(clip.channels)})
    return motion.add_channels(names, values, "sensor"), report


def check_mass(mass: float) -> float:
    if not (isinstance(mass, (int, float)) and np.isfinite(mass) and 0.1 <= mass <= 500):
        raise BadInput(f"body mass must be between 0.1 and 500 kg, got {mass}", field="mass")
    return float(mass)
