"""Small humanoid robots for chapter 3 (thesis 3.3.3, 3.4): the *self* and the *other*.

Both have the same layout and differ in mass (thesis: 2.4 kg and 4.8 kg). Modelled joints:
right shoulder pitch and roll, right elbow, right knee (the closed-question experiment uses the
knee as its fourth joint). The torso is fixed to the world; every link's mass is a fixed share
of the robot's mass (``LINK_SHARE``), so every torque, gravity and inertial alike, scales
exactly with the mass. Motion channels are the joint names, in degrees.
"""

from __future__ import annotations

import mujoco
import numpy as np

from shared.bodies.body import Body, DofMap, check_mass
from shared.errors import NotFound

JOINTS = ("shoulder_pitch", "shoulder_roll", "elbow", "knee")
LIMITS = {"shoulder_pitch": (-180.0, 180.0), "shoulder_roll": (-100.0, 100.0), "elbow": (-150.0, 5.0),
          "knee": (-5.0, 150.0)}
LINK_SHARE = {"torso": 0.55, "upper_arm": 0.07, "forearm": 0.06, "thigh": 0.12, "shin": 0.10}  # rest: head, left side (fixed)
ROBOTS = {"self": 2.4, "other": 4.8}  # the thesis's two robots, kg


def small_humanoid(mass: float = 2.4, name: str = "robot", upper: float = 0.10, fore: float = 0.10,
                   thigh: float = 0.11, shin: float = 0.11) -> Body:
    """A small humanoid of ``mass`` kg (link lengths in metres)."""
    mass = check_mass(mass)
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # inverse dynamics of the motion alone: no self-contacts
    spec.modelname = name
    spec.option.gravity = [0, 0, -9.81]
    torso = spec.worldbody.add_body(name="torso", pos=[0, 0, 0.3])
    torso.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.04, 0.06, 0.08], mass=LINK_SHARE["torso"] * mass)
    ua = torso.add_body(name="upper_arm", pos=[0, -0.08, 0.06])
    ua.add_joint(name="shoulder_pitch", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    ua.add_joint(name="shoulder_roll", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0])
    ua.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, -upper], size=[0.015, 0, 0],
                mass=LINK_SHARE["upper_arm"] * mass)
    fa = ua.add_body(name="forearm", pos=[0, 0, -upper])
    fa.add_joint(name="elbow", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    fa.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, -fore], size=[0.012, 0, 0],
                mass=LINK_SHARE["forearm"] * mass)
    th = torso.add_body(name="thigh", pos=[0, -0.03, -0.08])
    th.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, -thigh], size=[0.02, 0, 0],
                mass=LINK_SHARE["thigh"] * mass)
    sh = th.add_body(name="shin", pos=[0, 0, -thigh])
    sh.add_joint(name="knee", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    sh.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, -shin], size=[0.018, 0, 0],
                mass=LINK_SHARE["shin"] * mass)
    model = spec.compile()
    dofs = []
    for j in JOINTS:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        dofs.append(DofMap(j, int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid]), LIMITS[j]))
    moving = float(np.sum(model.body_mass[1:]))
    return Body(name=name, kind="robot", model=model, dofs=dofs, mass=moving / sum(LINK_SHARE.values()))


def robot(name: str, mass: float | None = None) -> Body:
    """The thesis's robots by name (``self`` 2.4 kg, ``other`` 4.8 kg), or any name with a mass."""
    if mass is None:
        if name not in ROBOTS:
            raise NotFound(f"no robot named {name!r}; known: {', '.join(ROBOTS)} (or give a mass)")
        mass = ROBOTS[name]
    return small_humanoid(mass, name=name)
