"""Small humanoid robots for chapter 3 (thesis 3.3.3, 3.4): the *self* and the *other*.

The thesis's two robots have the same layout and differ in mass (2.4 kg and 4.8 kg). Modelled
joints: right shoulder pitch and roll, right elbow, right knee (the closed-question experiment
uses the knee as its fourth joint). The torso is fixed to the world; by default every link's
mass is a fixed share of the robot's mass (``LINK_SHARE``), so every torque, gravity and
inertial alike, scales exactly with the mass. Motion channels are the joint names, in degrees.

Real bodies differ unevenly (thesis 3.3.5 and 7.2), so a :class:`BodySpec` can also
change the link lengths, the links' shares of the mass, add a payload held in the right hand
(a point mass at the end of the forearm), viscous damping (MuJoCo joint damping, in the
torques ``mj_inverse`` reports), joint springs with a rest angle and rotor inertia (MuJoCo
``stiffness``/``springref`` and ``armature``, in those torques too; outside the body estimator's
model) and Coulomb friction (``friction * tanh(qdot / 0.05 rad/s)``,
added to the torques by :func:`shared.bodies.body.perform`) per joint, and leave joints out (a
missing joint is welded at 0: the body cannot move it and feels nothing there; a *fused* joint is
welded at another angle, a joint layout outside the body estimator's model: the self imitates it
by holding its own joint at 0, and its links then lie elsewhere than the self thinks).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from shared.bodies.body import Body, DofMap, check_mass
from shared.errors import BadInput, NotFound

JOINTS = ("shoulder_pitch", "shoulder_roll", "elbow", "knee")
LIMITS = {"shoulder_pitch": (-180.0, 180.0), "shoulder_roll": (-100.0, 100.0), "elbow": (-150.0, 5.0),
          "knee": (-5.0, 150.0)}
LINK_SHARE = {"torso": 0.55, "upper_arm": 0.07, "forearm": 0.06, "thigh": 0.12, "shin": 0.10}  # rest: head, left side (fixed)
LENGTHS = {"upper": 0.10, "fore": 0.10, "thigh": 0.11, "shin": 0.11}  # m
FUSIBLE = ("elbow", "knee")  # a fused joint turns its link's frame: exact where the link has no other hinge
ROBOTS = {"self": 2.4, "other": 4.8}  # the thesis's two robots, kg
HAND_RADIUS = 0.02  # m, the payload's sphere


@dataclass
class BodySpec:
    """A small humanoid's body (defaults: the thesis's even robot of ``mass`` kg)."""

    mass: float = 2.4
    lengths: dict[str, float] = field(default_factory=dict)  # upper, fore, thigh, shin (m); missing: LENGTHS
    shares: dict[str, float] = field(default_factory=dict)  # link -> share of the mass; missing: LINK_SHARE
    payload: float = 0.0  # kg held in the right hand (end of the forearm)
    elbow_mass: float = 0.0  # kg, a point mass at the elbow (used by the self's regressor, shared.estimation.body)
    damping: dict[str, float] = field(default_factory=dict)  # joint -> viscous damping, N m s / rad
    friction: dict[str, float] = field(default_factory=dict)  # joint -> Coulomb friction, N m
    missing: list[str] = field(default_factory=list)  # joints the body does not have
    # beyond the body estimator's model: joint springs, their rest angles, rotor inertia
    stiffness: dict[str, float] = field(default_factory=dict)  # joint -> spring, N m / rad (MuJoCo stiffness)
    rest: dict[str, float] = field(default_factory=dict)  # joint -> the spring's rest angle, degrees (springref)
    armature: dict[str, float] = field(default_factory=dict)  # joint -> rotor inertia, kg m^2 (MuJoCo armature)
    fused: dict[str, float] = field(default_factory=dict)  # joint -> the angle it is welded at, degrees (no joint there)

    def check(self) -> BodySpec:
        check_mass(self.mass)
        for group in ("lengths", "shares", "damping", "friction", "stiffness", "rest", "armature", "fused"):
            if not isinstance(getattr(self, group), dict):
                raise BadInput(f"body {group} must be a map, got {type(getattr(self, group)).__name__}", field=group)
        if not isinstance(self.missing, list):
            raise BadInput(f"body missing must be a list of joints, got {type(self.missing).__name__}", field="missing")
        for group, table, lo, hi in (("lengths", self.lengths, 0.02, 1.0), ("shares", self.shares, 0.0, 1.0),
                                     ("damping", self.damping, 0.0, 100.0), ("friction", self.friction, 0.0, 100.0),
                                     ("stiffness", self.stiffness, 0.0, 100.0), ("rest", self.rest, -180.0, 180.0),
                                     ("armature", self.armature, 0.0, 1.0), ("fused", self.fused, -180.0, 180.0)):
            known = LENGTHS if group == "lengths" else LINK_SHARE if group == "shares" else JOINTS
            for k, v in table.items():
                if k not in known:
                    raise BadInput(f"body {group}: unknown {k!r}; one of {', '.join(known)}", field=group)
                if not (isinstance(v, (int, float)) and np.isfinite(v) and lo <= v <= hi):
                    raise BadInput(f"body {group}[{k}] must be in [{lo}, {hi}], got {v}", field=group)
        for name, v in (("payload", self.payload), ("elbow_mass", self.elbow_mass)):
            if not (isinstance(v, (int, float)) and np.isfinite(v) and 0.0 <= v <= 100.0):
                raise BadInput(f"body {name} must be in [0, 100] kg, got {v}", field=name)
        bad = [j for j in self.missing if j not in JOINTS]
        if bad:
            raise BadInput(f"body missing joints must be among {', '.join(JOINTS)}, got {bad}", field="missing")
        unfusible = [j for j in self.fused if j not in FUSIBLE]
        if unfusible:
            raise BadInput(f"only a joint alone on its link can be fused ({', '.join(FUSIBLE)}), got {unfusible}",
                           field="fused")
        both = [j for j in self.fused if j in self.missing]
        if both:
            raise BadInput(f"a joint is either missing (welded at 0) or fused at an angle, not both: {both}", field="fused")
        return self

    @property
    def welded(self) -> list[str]:
        """The joints the body cannot move: missing (at 0) and fused (at their angle)."""
        return list(self.missing) + [j for j in self.fused if j not in self.missing]

    def to_dict(self) -> dict:
        return asdict(self)


def small_humanoid(mass: float | BodySpec = 2.4, name: str = "robot", link_masses: dict[str, float] | None = None,
                   points: tuple = ()) -> Body:
    """A small humanoid of ``mass`` kg, or of a :class:`BodySpec`. ``link_masses`` (kg per
    link) overrides the shares: the self's regressor builds bodies with one link's mass only, or
    with ``points`` alone, each ``(link, (x, y, z) m in the link's frame, kg)`` a point mass."""
    spec_in = mass if isinstance(mass, BodySpec) else BodySpec(mass=check_mass(mass))
    b = spec_in.check()
    length = {**LENGTHS, **b.lengths}
    share = {**LINK_SHARE, **b.shares}
    masses = {k: share[k] * b.mass for k in LINK_SHARE} if link_masses is None else {k: link_masses.get(k, 0.0) for k in LINK_SHARE}
    tiny = 1e-9  # a link "without mass" in a regressor column: MuJoCo needs a positive mass
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # inverse dynamics of the motion alone: no self-contacts
    spec.modelname = name
    spec.option.gravity = [0, 0, -9.81]

    def joint(parent, jname: str, axis):
        if jname not in b.welded:
            parent.add_joint(name=jname, type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis, damping=b.damping.get(jname, 0.0),
                             stiffness=b.stiffness.get(jname, 0.0), springref=np.radians(b.rest.get(jname, 0.0)),
                             armature=b.armature.get(jname, 0.0))

    def link(parent, lname: str, pos, length_key: str, radius: float, joints=()):
        """A capsule link hanging down from ``pos`` in its parent, with its hinges."""
        turn = np.array([1.0, 0.0, 0.0, 0.0])  # fused joints: the link welded at their angles
        for jname, axis in joints:
            if jname in b.fused:
                half = np.radians(b.fused[jname]) / 2
                q = np.r_[np.cos(half), np.sin(half) * np.asarray(axis, float)]
                mujoco.mju_mulQuat(turn, turn.copy(), q)
        body = parent.add_body(name=lname, pos=pos, quat=turn)
        for jname, axis in joints:
            joint(body, jname, axis)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, -length[length_key]],
                      size=[radius, 0, 0], mass=max(masses[lname], tiny))
        return body

    torso = spec.worldbody.add_body(name="torso", pos=[0, 0, 0.3])
    torso.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.04, 0.06, 0.08], mass=max(masses["torso"], tiny))
    ua = link(torso, "upper_arm", [0, -0.08, 0.06], "upper", 0.015,
              (("shoulder_pitch", [0, 1, 0]), ("shoulder_roll", [1, 0, 0])))
    fa = link(ua, "forearm", [0, 0, -length["upper"]], "fore", 0.012, (("elbow", [0, 1, 0]),))
    if b.elbow_mass > 0:
        fa.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=[0, 0, 0], size=[0.001, 0, 0], mass=b.elbow_mass)
    if b.payload > 0:
        fa.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=[0, 0, -length["fore"]], size=[HAND_RADIUS, 0, 0],
                    mass=b.payload)
    th = link(torso, "thigh", [0, -0.03, -0.08], "thigh", 0.02)
    sh = link(th, "shin", [0, 0, -length["thigh"]], "shin", 0.018, (("knee", [0, 1, 0]),))
    links = {"upper_arm": ua, "forearm": fa, "thigh": th, "shin": sh}
    for lname, pos, kg in points:
        links[lname].add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=list(pos), size=[0.001, 0, 0], mass=kg)
    model = spec.compile()
    dofs = []
    for j in JOINTS:
        if j in b.welded:
            continue
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        dofs.append(DofMap(j, int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid]), LIMITS[j]))
    return Body(name=name, kind="robot", model=model, dofs=dofs,
                mass=b.mass if link_masses is None else float(sum(link_masses.values())),
                friction={j: v for j, v in b.friction.items() if v > 0 and j not in b.welded})


def robot(name: str, mass: float | None = None) -> Body:
    """The thesis's robots by name (``self`` 2.4 kg, ``other`` 4.8 kg), or any name with a mass."""
    if mass is None:
        if name not in ROBOTS:
            raise NotFound(f"no robot named {name!r}; known: {', '.join(ROBOTS)} (or give a mass)")
        mass = ROBOTS[name]
    return small_humanoid(mass, name=name)
