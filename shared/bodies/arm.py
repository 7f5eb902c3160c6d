"""A small robot arm in MuJoCo: a torque channel for the PSS until the simulator service
brings whole bodies.

The arm is the right arm of a small humanoid like the thesis's (ch. 3.3.3): shoulder pitch,
shoulder roll and elbow, two capsule links, total arm mass settable (the thesis's robots
weigh 2.4 kg and 4.8 kg in all; the arm carries a fixed share of it). Torques come from
inverse dynamics (``mj_inverse``) with joint velocities and accelerations from
Savitzky-Golay derivatives (window 7 frames, cubic) of the joint angles.

``arm_angles`` maps a human clip's right arm onto the robot: shoulder pitch = ``rhumerus.rx``,
shoulder roll = ``rhumerus.rz``, elbow = ``rradius.rx`` (ASF/AMC channel names).
"""

from __future__ import annotations

import mujoco
import numpy as np
from scipy.signal import savgol_filter

from shared.errors import BadInput
from shared.motion.clip import Clip

JOINTS = ("shoulder_pitch", "shoulder_roll", "elbow")
HUMAN_MAP = {"shoulder_pitch": "rhumerus.rx", "shoulder_roll": "rhumerus.rz", "elbow": "rradius.rx"}
ARM_SHARE = 0.08  # share of the body mass in one arm (upper arm + forearm + hand)


def arm_model(body_mass: float = 2.4, upper: float = 0.10, fore: float = 0.10) -> mujoco.MjModel:
    """MJCF of the arm; link masses split 55/45 between upper arm and forearm."""
    if not (np.isfinite(body_mass) and 0.05 <= body_mass <= 500):
        raise BadInput(f"body mass must be between 0.05 and 500 kg, got {body_mass}")
    m = body_mass * ARM_SHARE
    xml = f"""
<mujoco model="small_humanoid_right_arm">
  <option gravity="0 0 -9.81" timestep="0.002"/>
  <worldbody>
    <body name="upper_arm" pos="0 0 0">
      <joint name="shoulder_pitch" type="hinge" axis="0 1 0"/>
      <joint name="shoulder_roll" type="hinge" axis="1 0 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 {-upper}" size="0.015" mass="{0.55 * m}"/>
      <body name="forearm" pos="0 0 {-upper}">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 {-fore}" size="0.012" mass="{0.45 * m}"/>
      </body>
    </body>
  </worldbody>
</mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def derivatives(q: np.ndarray, fps: float, window: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Velocities and accelerations by Savitzky-Golay differentiation (cubic, ``window`` frames)."""
    n = len(q)
    if n < 5:
        raise BadInput(f"a motion needs at least 5 frames to differentiate, got {n}")
    w = min(window, n if n % 2 else n - 1)
    dt = 1.0 / fps
    qd = savgol_filter(q, w, 3, deriv=1, delta=dt, axis=0, mode="interp")
    qdd = savgol_filter(q, w, 3, deriv=2, delta=dt, axis=0, mode="interp")
    return qd, qdd


def inverse_dynamics(model: mujoco.MjModel, q: np.ndarray, fps: float) -> np.ndarray:
    """Joint torques (T, nv) that realise the joint trajectory ``q`` (radians)."""
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[1] != model.nq:
        raise BadInput(f"joint trajectory must be T x {model.nq}, got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise BadInput("joint trajectory contains NaN or Inf")
    from shared.bodies.body import mj_inverse_series

    qd, qdd = derivatives(q, fps)
    return mj_inverse_series(model, q, qd, qdd)[0]


def arm_angles(clip: Clip) -> np.ndarray:
    """The robot arm's joint angles (radians) for a human clip's right arm."""
    missing = [c for c in HUMAN_MAP.values() if c not in clip.channels]
    if missing:
        raise BadInput(f"clip {clip.name!r} has no right-arm channels {missing}")
    return np.deg2rad(np.column_stack([clip.column(HUMAN_MAP[j]) for j in JOINTS]))


def with_arm_torques(clip: Clip, model: mujoco.MjModel | None = None) -> Clip:
    """The clip with sensor channels ``tau.<joint>`` (N m) of the robot arm performing it."""
    model = model or arm_model()
    tau = inverse_dynamics(model, arm_angles(clip), clip.fps)
    return clip.add_channels([f"tau.{j}" for j in JOINTS], tau, group="sensor")
