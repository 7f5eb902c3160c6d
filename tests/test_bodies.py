"""MuJoCo bodies: the chapter-3 robots and human bodies from the HDM05 skeletons."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shared.bodies.body import perform, qpos_derivatives, qpos_trajectory
from shared.bodies.human import human_body
from shared.bodies.robot import robot, small_humanoid
from shared.errors import BadInput, NotFound
from shared.motion.clip import Clip


def _robot_motion(n=61, fps=30.0):
    t = np.linspace(0, 2, n)
    data = np.column_stack([60 * np.sin(t), 20 * np.sin(2 * t), -40 - 30 * np.cos(t), 30 + 20 * np.sin(t)])
    return Clip(data, ["shoulder_pitch", "shoulder_roll", "elbow", "knee"], fps, name="m")


def _torques(clip):
    return clip.select([c for c in clip.group("sensor") if c.startswith("tau.")])


def test_the_other_robot_feels_exactly_twice_the_selfs_torques():
    self_, other = robot("self"), robot("other")
    assert (self_.mass, other.mass) == pytest.approx((2.4, 4.8))
    still = Clip(np.tile([45.0, 10.0, -60.0, 30.0], (20, 1)), _robot_motion().channels, 30.0, name="still")
    g_self, g_other = _torques(perform(self_, still)[0]), _torques(perform(other, still)[0])
    assert np.abs(g_self).max() > 0.05  # gravity torques are there
    np.testing.assert_allclose(g_other, 2 * g_self, rtol=1e-9, atol=1e-12)
    moving = _robot_motion()
    np.testing.assert_allclose(_torques(perform(other, moving)[0]), 2 * _torques(perform(self_, moving)[0]), rtol=1e-9, atol=1e-12)


def _replay_accelerations(body, clip):
    """Feed the inverse-dynamics forces back through mj_forward: the accelerations come back."""
    m = body.model
    q = qpos_trajectory(body, clip)
    v, a = qpos_derivatives(m, q, clip.fps)
    d = mujoco.MjData(m)
    worst = 0.0
    for t in range(0, len(q), 7):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[t], v[t], a[t]
        mujoco.mj_inverse(m, d)
        f = d.qfrc_inverse.copy()
        d.qacc[:] = 0
        d.qfrc_applied[:] = f
        mujoco.mj_forward(m, d)
        worst = max(worst, float(np.abs(d.qacc - a[t]).max() / (1 + np.abs(a[t]).max())))
        d.qfrc_applied[:] = 0
    return worst


def test_inverse_dynamics_reproduces_the_accelerations(bundled):
    from shared.io import load_clip

    assert _replay_accelerations(robot("self"), _robot_motion()) < 1e-8
    clip = load_clip(bundled / "amc/kickLFront1Reps/HDM_bd_kickLFront1Reps_001_120.amc")
    assert _replay_accelerations(human_body(clip.skeleton), clip) < 1e-8


def test_mujoco_kinematics_of_a_human_body_match_the_skeleton(bundled):
    from shared.io import load_clip

    clip = load_clip(bundled / "amc/rotateArmsBothBackward1Reps/HDM_bd_rotateArmsBothBackward1Reps_001_120.amc")
    body = human_body(clip.skeleton)
    q = qpos_trajectory(body, clip)
    ours = clip.skeleton.forward_kinematics(clip.data, clip.channels, ends=False)
    ids = [mujoco.mj_name2id(body.model, mujoco.mjtObj.mjOBJ_BODY, j.name) for j in clip.skeleton.joints]
    d = mujoco.MjData(body.model)
    worst = 0.0
    for t in range(10, clip.n_frames - 10, 10):  # away from the smoothing filter's ends
        d.qpos[:] = q[t]
        mujoco.mj_kinematics(body.model, d)
        worst = max(worst, float(np.abs(d.xpos[ids] - ours[t]).max()))
    assert worst < 0.01, f"{worst:.4f} m"  # the positions are smoothed (~0.1 s window) before differentiation


@pytest.mark.slow
@pytest.mark.parametrize("actor", ["bd", "bk", "dg"])
def test_a_human_body_per_hdm05_actor_performs_every_dev_clip(hdm05, dev_clips, actor):
    from shared.io import read_asf

    sk = read_asf(hdm05 / "asf" / f"HDM_{actor}.asf")
    body = human_body(sk, mass=70.0)
    assert body.mass == pytest.approx(70.0, rel=0.01)
    assert sum(sk.joints[sk.index(f)].name in body.feet for f in body.feet) == 4
    clips = [c for c in dev_clips if f"_{actor}_" in c.name]
    assert len(clips) > 40
    peak = []
    for c in clips:
        out, report = perform(body, c)
        tau = _torques(out)
        assert tau.shape == (c.n_frames, len(body.dofs)) and np.all(np.isfinite(tau))
        cog = out.select(["cog.x", "cog.y", "cog.z"])
        assert 0.6 < cog[0, 1] < 1.3, c.name  # standing at the start: the centre of gravity is near the hips (y up)
        assert cog[:, 1].min() > 0.0, c.name  # never below the floor, even lying down
        assert report["support"]["checked"]
        peak.append(np.abs(tau).max())
    # a 70 kg person's joint torques: tens to a few hundred N m, not thousands
    assert 20 < np.median(peak) < 600, np.median(peak)


def test_bodies_refuse_bad_input(bundled):
    from shared.io import load_clip

    with pytest.raises(NotFound):
        robot("nobody")
    for mass in (0.0, -1.0, 1e6, float("nan")):
        with pytest.raises(BadInput, match="mass"):
            small_humanoid(mass)
    clip = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc")
    with pytest.raises(BadInput, match="lacks"):
        perform(robot("self"), clip)  # a human clip on the robot: wrong joints
    with pytest.raises(BadInput, match="at least 5 frames"):
        perform(robot("self"), _robot_motion().frames(0, 4))
    with pytest.raises(BadInput, match="mass"):
        human_body(clip.skeleton, mass=0.01)


def test_a_body_from_the_bvh_skeleton_agrees_with_the_asf_one(bundled, tmp_path):
    from shared.io import load_clip, save_clip

    amc = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc")
    save_clip(amc, tmp_path / "s.bvh")
    bvh = load_clip(tmp_path / "s.bvh")
    pa, _ = perform(human_body(amc.skeleton), amc)
    pb, _ = perform(human_body(bvh.skeleton), bvh)
    cog = ["cog.x", "cog.y", "cog.z"]
    assert np.abs(pa.select(cog) - pb.select(cog)).max() < 1e-3  # same masses, same kinematics
    # joints with the same degrees of freedom feel the same torques
    for ch in ("tau.lowerback.rx", "tau.ltibia.rx"):
        assert np.abs(pa.column(ch)).max() == pytest.approx(np.abs(pb.column(ch)).max(), rel=0.1), ch


def _arms_swung(still: Clip, hz: float) -> Clip:
    """A pose held still (30 fps) with both upper arms swung 40 degrees at ``hz``."""
    data = still.data.copy()
    for arm in ("lhumerus.rx", "rhumerus.rx"):
        data[:, still.channels.index(arm)] += 40.0 * np.sin(2 * np.pi * hz * np.arange(still.n_frames) / 30.0)
    return still.with_data(data)


def test_the_dynamic_balance_check_sees_what_the_static_one_cannot(bundled):
    """The centre of pressure (zero-moment point) from the free root's inverse dynamics: for a
    pose held still it is the centre of gravity's ground projection (the weight, straight
    down); arms swung fast keep the centre of gravity over the feet but need a centre of
    pressure outside them, more often the faster they swing."""
    from shared.bodies.body import _centre_of_pressure, _root_wrench, inverse_dynamics, perform, qpos_trajectory
    from shared.bodies.human import human_body
    from shared.io import load_clip

    clip = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc").resample(30)
    body = human_body(clip.skeleton)
    still = clip.with_data(np.repeat(clip.data[10:11], 60, axis=0))
    q = qpos_trajectory(body, still)
    _, _, tau, cog = inverse_dynamics(body, q, still.fps)
    force, moment, origin = _root_wrench(body, q, tau)
    plane = [i for i in range(3) if i != body.up_axis]
    np.testing.assert_allclose(force[:, body.up_axis], body.mass * 9.81, rtol=1e-6)
    np.testing.assert_allclose(_centre_of_pressure(force, moment, origin, body.up_axis, 0.0), cog[:, plane], atol=1e-6)
    assert perform(body, still)[1]["support"]["frames_dynamic_outside"] == 0
    counts = []
    for hz in (0.5, 2.5):
        s = perform(body, _arms_swung(still, hz))[1]["support"]
        assert s["frames_outside_support"] == 0  # statically balanced throughout
        counts.append(s["frames_dynamic_outside"])
    assert counts[1] > counts[0] and counts[1] > 20, counts


def test_the_centre_of_pressure_and_the_hull_distances_equal_their_frame_by_frame_reference(bundled):
    """All frames' centres of pressure solved at once are each frame's own 2 x 2 solve, to the
    bit (a frame whose system is singular stays NaN); points judged on one hull are judged as each
    alone on it, and a contact that spans no area (two points) gives each point's distance to
    the segment."""
    from scipy.spatial import ConvexHull

    from shared.bodies.body import _centre_of_pressure, _hull_distances, _root_wrench, inverse_dynamics, qpos_trajectory
    from shared.bodies.human import human_body
    from shared.io import load_clip

    clip = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc").resample(30)
    body = human_body(clip.skeleton)
    q = qpos_trajectory(body, clip)
    force, moment, origin = _root_wrench(body, q, inverse_dynamics(body, q, clip.fps)[2])
    force[3] = 0.0  # no force: a singular system
    up, ground = body.up_axis, -0.01
    plane = [i for i in range(3) if i != up]
    reference = np.full((len(force), 2), np.nan)
    for t in range(len(force)):
        def horizontal(pa, pb, t=t):
            p = np.empty(3)
            p[plane[0]], p[plane[1]], p[up] = pa, pb, ground
            return (moment[t] + np.cross(origin[t] - p, force[t]))[plane]
        f0 = horizontal(0.0, 0.0)
        a = np.column_stack([horizontal(1.0, 0.0) - f0, horizontal(0.0, 1.0) - f0])
        if abs(np.linalg.det(a)) > 1e-9:
            reference[t] = np.linalg.solve(a, -f0)
    cop = _centre_of_pressure(force, moment, origin, up, ground)
    assert np.isnan(cop[3]).all() and np.isfinite(np.delete(cop, 3, axis=0)).all()
    np.testing.assert_array_equal(cop, reference)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    points = [np.array([0.5, 0.5]), np.array([2.0, 0.5]), np.array([0.5, -0.25])]
    eq = ConvexHull(square).equations
    assert _hull_distances(square, points) == [float(np.max(eq[:, :2] @ p + eq[:, 2])) for p in points] == [-0.5, 1.0, 0.25]
    assert _hull_distances(square[:2], points) == [0.5, np.hypot(1.0, 0.5), 0.25]


def test_a_tracking_controller_on_a_simulated_floor_needs_a_hand_only_where_the_motion_is_too_fast(bundled):
    """The simulated test (shared/bodies/tracking.py): the body stands on a MuJoCo floor and a
    tracking controller follows the motion, the floor pushing where the soles touch; a pose
    held still needs no helping hand and is followed to the millimetre, arms swung slowly need
    none either, swung fast (the centre of gravity over the feet throughout) they need one in
    many frames; a squat played three times as fast needs one in more frames than at its speed.
    A robot with no feet to stand on, or a motion longer than it simulates, says the test was not run."""
    from copy import deepcopy

    from shared.bodies.tracking import perform_tracked
    from shared.coaching.feasibility import worse_than_target
    from shared.io import load_clip

    clip = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc").resample(30)
    body = human_body(clip.skeleton)
    still = clip.with_data(np.repeat(clip.data[10:11], 60, axis=0))
    held = perform_tracked(body, still)[1]
    s = held["support"]
    assert s["tracking_checked"] and s["frames_tracking_helped"] == 0 and s["max_root_error_m"] < 0.01, s
    helped = []
    for hz in (0.5, 2.5):
        s = perform_tracked(body, _arms_swung(still, hz))[1]["support"]
        assert s["frames_outside_support"] == 0
        helped.append(s["frames_tracking_helped"])
    assert helped[0] == 0 and helped[1] > 20, helped
    own, fast = (perform_tracked(body, clip.with_data(clip.data, fps=30.0 * k))[1]["support"] for k in (1, 3))
    assert fast["frames_tracking_helped"] / clip.n_frames > own["frames_tracking_helped"] / clip.n_frames + 0.3
    assert "tracking_checked" not in perform(body, still)[1]["support"]  # only when asked
    # the coach's check names the test: a demonstration helped in every frame where the target is not
    shown = deepcopy(held)
    shown["support"]["tracking_runs"] = [[0, held["frames"]]]
    why = worse_than_target(shown, held, still)
    assert why is not None and "tracking controller" in why and "100%" in why
    assert worse_than_target(shown, held, still, dynamic=False) is None
    arm = small_humanoid()
    t = np.linspace(0, 2, 60)
    robot_clip = Clip(np.column_stack([30 * np.sin(t)] * 4), ["shoulder_pitch", "shoulder_roll", "elbow", "knee"], 30.0)
    assert any("tracking" in n for n in perform_tracked(arm, robot_clip)[1]["not_checked"])
    # the root's orientation given on either side of the quaternion's double cover, frame by frame: the same
    from shared.bodies.tracking import track, tracking_model

    model, q = tracking_model(body), qpos_trajectory(body, clip)
    flipped = q.copy()
    flipped[1::2, 3:7] *= -1
    a, b = (track(body, x, clip.fps, model) for x in (q, flipped))
    assert a["frames_helped"] == b["frames_helped"] and np.allclose(a["help"], b["help"])
    # a request never runs for minutes: a motion longer than the simulation follows says so
    long = still.with_data(np.repeat(clip.data[10:11], 130, axis=0), fps=1.0)
    report = perform_tracked(body, long)[1]
    assert "tracking_checked" not in report["support"] and any("at most 120 s" in n for n in report["not_checked"])


def test_the_support_area_has_heels_so_a_person_standing_still_is_balanced(hdm05):
    """Every foot bone gives its origin and the far end of its segment (the ball, the toe tips);
    a bone that starts at the ankle gives the heel too, under the ankle at the sole's height in
    the rest pose. Without heels a person standing to reach up (dg's grabHighR) had the centre
    of gravity outside the support on all 64 of its frames; with them on none."""
    from shared.bodies.body import foot_anchors, foot_points
    from shared.io import load_clip

    clip = load_clip(sorted((hdm05 / "amc/grabHighR").glob("HDM_dg_*.amc"))[0]).resample(30)
    body = human_body(clip.skeleton)
    anchors = foot_anchors(body)
    assert len(anchors) == 2 * len(body.feet) + 2  # two heels, one per ankle
    rest = foot_points(body, body.model.qpos0[None, :], anchors)[0]
    up = body.up_axis
    heels = rest[2 * len(body.feet):]
    ankles = [rest[2 * body.feet.index(f)] for f in ("lfoot", "rfoot")]
    for heel, ankle in zip(heels, ankles):
        assert 0.02 <= ankle[up] - heel[up] <= 0.2  # under the ankle, at the sole
        np.testing.assert_allclose(np.delete(heel, up), np.delete(ankle, up), atol=1e-9)
    support = perform(body, clip)[1]["support"]
    assert support["frames_outside_support"] == 0, support


def _floating(clip, lift_cm: float, frames: slice):
    """``clip`` with its root raised by ``lift_cm`` in ``frames`` (0.3 s ramps): the feet float."""
    data = clip.data.copy()
    bump = np.zeros(clip.n_frames)
    bump[frames] = 1.0
    k = np.hanning(11)
    bump = np.convolve(bump, k / k.sum(), mode="same")
    unit_cm = 100 * clip.skeleton.unit_m
    data[:, clip.channels.index("root.ty")] += bump * lift_cm / unit_cm
    return clip.with_data(data)


def test_planting_puts_the_feet_back_where_the_reference_stands(bundled):
    """A squat whose hips rise 12 cm mid-motion has both feet in the air (the emphatic sneak's
    fault); planting brings them back to the reference's height within 2 cm by the root's height
    and the legs' angles, leaves the arms and the trunk as they were, and a motion already
    standing where the reference does comes back all but unchanged."""
    from shared.bodies.body import foot_anchors, foot_points
    from shared.bodies.stance import plant_feet
    from shared.io import load_clip

    ref = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc").resample(30)
    body = human_body(ref.skeleton)
    up = body.up_axis
    lifted = _floating(ref, 12.0, slice(15, 30))
    anchors = foot_anchors(body)
    heights = lambda c: foot_points(body, qpos_trajectory(body, c), anchors)[..., up]  # noqa: E731
    ground = heights(ref).min()
    standing = heights(ref) < ground + 0.05
    assert np.abs(heights(lifted) - heights(ref))[standing].max() > 0.10
    planted, changes = plant_feet(body, ref, lifted)
    assert changes["planted"] and changes["stance_error_m"] < 0.02
    again, _ = plant_feet(body, ref, lifted)  # the reference's stance kept from the first call: the same motion
    np.testing.assert_array_equal(again.data, planted.data)
    assert np.abs(heights(planted) - heights(ref))[standing].max() < 0.03
    assert 0.08 < changes["root_height_change_m"] < 0.14
    above = [i for i, c in enumerate(ref.channels) if c.split(".")[0] in ("lhumerus", "rhumerus", "thorax", "head")]
    np.testing.assert_array_equal(planted.data[:, above], lifted.data[:, above])
    assert planted.channels == lifted.channels and planted.n_frames == lifted.n_frames
    same, info = plant_feet(body, ref, ref)
    assert info["root_height_change_m"] < 0.01 and info["leg_angle_change_deg"] < 2.0
    robot_like = human_body(ref.skeleton)
    robot_like.feet = []
    assert plant_feet(robot_like, ref, lifted) == (lifted, {"planted": False,
                                                            "why": "no feet, no free root or no root height channel"})
