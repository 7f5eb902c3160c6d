"""Motion files in other tools' conventions: units, up axis, position channels on
every joint, ROOT OFFSET with position channels. Each test writes small files in one
convention from a real HDM05 clip and checks that mirrorcoach reads back the same body and
motion (positions in metres), or refuses with an error naming the file."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shared.errors import BadInput, ClipFormatError
from shared.io import load_clip, save_clip
from shared.io.conventions import UNITS
from shared.motion.skeleton import Joint, Skeleton

SQUAT = "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc"
ROT_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # Y-up world -> Z-up world


@pytest.fixture(scope="module")
def plain(bundled, tmp_path_factory):
    """The squat as a plain Y-up BVH (mirrorcoach's own writer: metres), read back."""
    path = tmp_path_factory.mktemp("conv") / "squat.bvh"
    save_clip(load_clip(bundled / SQUAT).resample(30), path)
    return load_clip(path)


def _write_raw(path, sk: Skeleton, data: np.ndarray, channels: list[str], fps: float) -> None:
    """A BVH with exactly these offsets and channel values (no convention applied)."""
    out = ["HIERARCHY"]

    def emit(i, depth):
        j, pad = sk.joints[i], "  " * depth
        out.append(f"{pad}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}\n{pad}{{")
        out.append(f"{pad}  OFFSET " + " ".join(f"{v:.6f}" for v in j.offset))
        names = {"tx": "Xposition", "ty": "Yposition", "tz": "Zposition", "rx": "Xrotation", "ry": "Yrotation",
                 "rz": "Zrotation"}
        out.append(f"{pad}  CHANNELS {len(j.dofs)} " + " ".join(names[d] for d in j.dofs))
        kids = sk.children(i)
        for k in kids:
            emit(k, depth + 1)
        if not kids:
            end = j.end if j.end is not None else np.zeros(3)
            out.append(f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET " + " ".join(f"{v:.6f}" for v in end) + f"\n{pad}  }}")
        out.append(f"{pad}}}")

    emit(0, 0)
    order = [f"{j.name}.{d}" for i in _depth_first(sk) for j in [sk.joints[i]] for d in j.dofs]
    cols = [channels.index(c) for c in order]
    out += ["MOTION", f"Frames: {len(data)}", f"Frame Time: {1.0 / fps:.10f}"]
    out += [" ".join(f"{v:.6f}" for v in row[cols]) for row in data]
    path.write_text("\n".join(out) + "\n")


def _depth_first(sk):
    order, stack = [], [0]
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed(sk.children(i)))
    return order


def _variant(plain, *, scale=1.0, turn=None, every_joint_moves=False, add_form=False, root_offset=None):
    """The plain clip's skeleton and motion rewritten in another convention."""
    sk, data, chans = plain.skeleton, plain.data.copy(), list(plain.channels)
    r = np.eye(3) if turn is None else turn
    joints = []
    for j in sk.joints:
        dofs = list(j.dofs)
        off = r @ j.offset * scale
        if every_joint_moves and j.parent >= 0:
            dofs = ["tx", "ty", "tz"] + dofs
        if j.parent < 0 and root_offset is not None:
            off = np.asarray(root_offset, float)
        joints.append(Joint(j.name, j.parent, off, dofs, j.euler, np.eye(3), None if j.end is None else r @ j.end * scale))
    new = Skeleton(sk.name, joints, 1.0, 1, "bvh")
    out_cols, out_data = [], []
    for j, nj in zip(sk.joints, joints):
        if "tx" in nj.dofs:
            t = np.column_stack([data[:, chans.index(f"{j.name}.t{a}")] if f"{j.name}.t{a}" in chans else np.zeros(len(data))
                                 for a in "xyz"])
            t = (t + j.offset) @ r.T * scale  # the whole local position (Blender's reading)
            if j.parent < 0 and root_offset is not None and add_form:
                t = t - nj.offset  # a file whose channels add to its (non-zero) ROOT OFFSET
            elif add_form:
                t = t - nj.offset
            out_cols += [f"{j.name}.t{a}" for a in "xyz"]
            out_data.append(t)
        rot = [d for d in nj.dofs if d.startswith("r")]
        if rot:
            ang = np.column_stack([data[:, chans.index(f"{j.name}.{d}")] for d in rot])
            if turn is not None:  # the same local rotation seen in the turned world: R L R^T
                seq = j.euler
                m = Rotation.from_euler(seq, ang, degrees=True).as_matrix()
                ang = np.rad2deg(np.unwrap(np.deg2rad(Rotation.from_matrix(r @ m @ r.T).as_euler(seq, degrees=True)), axis=0))
            out_cols += [f"{j.name}.{d}" for d in rot]
            out_data.append(ang)
    return new, np.hstack(out_data), out_cols


def _same_motion(a, b, tol_m=2e-4):
    pa, pb = a.positions(), b.positions()
    assert pa.shape == pb.shape
    err = np.abs(pa - pb).max()
    assert err < tol_m, f"positions differ by {err:.3g} m"


@pytest.mark.parametrize("unit", ["m", "in", "cmu", "mm"])
def test_a_bvh_in_other_length_units_is_the_same_body(plain, tmp_path, unit):
    sk, data, chans = _variant(plain, scale=plain.skeleton.unit_m / UNITS[unit])
    _write_raw(tmp_path / "u.bvh", sk, data, chans, plain.fps)
    back = load_clip(tmp_path / "u.bvh")
    assert back.read_as["units"].startswith(unit) and "from the body" in back.read_as["units"]
    assert back.skeleton.rest_height() == pytest.approx(plain.skeleton.rest_height(), rel=1e-4)
    _same_motion(back, plain)
    forced = load_clip(tmp_path / "u.bvh", units="cm")  # the option overrides what the body says
    assert forced.skeleton.unit_m == 0.01 and forced.read_as["units"] == "cm"


def test_a_body_of_no_human_height_is_refused_with_the_files_name(plain, tmp_path):
    sk, data, chans = _variant(plain, scale=2.0 * plain.skeleton.unit_m)  # a 3.4 cm "person" in any unit but m
    _write_raw(tmp_path / "giant.bvh", sk, data, chans, plain.fps)
    with pytest.raises(ClipFormatError, match=r"giant\.bvh.*no human height.*--units"):
        load_clip(tmp_path / "giant.bvh")
    tiny = load_clip(tmp_path / "giant.bvh", units="cm")  # read as told ...
    from shared.bodies.human import human_body

    with pytest.raises(BadInput, match="not a person"):  # ... but never simulated as a person
        human_body(tiny.skeleton)


def test_the_cmu_sample_in_two_unit_conventions_is_one_body(cmu):
    a, b = load_clip(cmu / "131_01.bvh"), load_clip(cmu / "scaled_131_01.bvh")
    assert a.read_as["units"].startswith("cmu") and b.read_as["units"].startswith("m ")
    assert a.skeleton.rest_height() == pytest.approx(b.skeleton.rest_height(), rel=1e-3)
    assert 1.3 < a.skeleton.rest_height() < 1.45
    n = min(a.n_frames, b.n_frames)
    assert np.abs(a.positions()[:n] - b.positions()[:n]).max() < 1e-3


def test_a_z_up_bvh_is_turned_to_y_up(plain, tmp_path):
    sk, data, chans = _variant(plain, turn=ROT_Z_UP)
    _write_raw(tmp_path / "z.bvh", sk, data, chans, plain.fps)
    back = load_clip(tmp_path / "z.bvh")
    assert back.read_as["up"].startswith("z, turned to y")
    _same_motion(back, plain)
    as_is = load_clip(tmp_path / "z.bvh", up="y")  # told otherwise, it is read as it is: lying down
    assert np.abs(as_is.positions() - plain.positions()).max() > 0.5
    # written again by mirrorcoach, it is a plain Y-up BVH of the same motion
    save_clip(back, tmp_path / "again.bvh")
    again = load_clip(tmp_path / "again.bvh")
    assert again.read_as["up"].startswith("y")
    _same_motion(again, plain)


@pytest.mark.parametrize("form", ["replace", "add"])
def test_position_channels_on_every_joint(plain, tmp_path, form):
    sk, data, chans = _variant(plain, every_joint_moves=True, add_form=form == "add")
    _write_raw(tmp_path / "six.bvh", sk, data, chans, plain.fps)
    back = load_clip(tmp_path / "six.bvh")
    assert form in back.read_as["translations"]
    _same_motion(back, plain)
    # a joint that really slides moves its children with it, in its parent's frame
    moved = back.data.copy()
    k = back.channels.index("ltibia.ty")
    moved[:, k] += 0.05 / back.skeleton.unit_m
    i_tib, i_foot = back.skeleton.index("ltibia"), back.skeleton.index("lfoot")
    d = back.with_data(moved).positions() - back.positions()
    assert np.allclose(np.linalg.norm(d[:, i_tib], axis=1), 0.05, atol=1e-9)
    assert np.allclose(d[:, i_foot], d[:, i_tib], atol=1e-9)
    ref = back.skeleton.forward_kinematics_reference(moved, back.channels)
    assert np.abs(back.with_data(moved).positions() - ref).max() < 1e-9


@pytest.mark.parametrize("form", ["replace", "add"])
def test_root_offset_with_root_channels_read_as_the_first_frame_tells(plain, tmp_path, form):
    sk, data, chans = _variant(plain, root_offset=[0.0, 0.95 / plain.skeleton.unit_m, 0.0],
                               add_form=form == "add")
    _write_raw(tmp_path / "root.bvh", sk, data, chans, plain.fps)
    back = load_clip(tmp_path / "root.bvh")
    assert back.read_as["translations"] == [form]
    _same_motion(back, plain)
    other = "add" if form == "replace" else "replace"
    wrong = load_clip(tmp_path / "root.bvh", translations=other)  # the option wins, and it matters
    assert np.abs(wrong.positions() - plain.positions()).max() > 0.5


def test_an_asf_whose_declared_unit_is_wrong_is_read_by_the_bodys_height(bundled, tmp_path):
    src = (bundled / "asf" / "HDM_bd.asf").read_bytes().decode("latin-1")
    k = 0.0254 / 0.45  # HDM05's unit in metres: the same lengths written in metres
    text = re.sub(r"(\n\s*length\s+)([-0-9.eE]+)", lambda m: f"{m.group(1)}{float(m.group(2)) * k:.6f}", src)
    text = text.replace(f"length {0.45 * k:.6f}", "length 0.45", 1)  # keep the (now wrong) declaration
    assert ":units" in text and "length 0.45" in text
    (tmp_path / "asf").mkdir()
    (tmp_path / "asf" / "HDM_bd.asf").write_bytes(text.encode("latin-1"))
    amc = tmp_path / "HDM_bd_squat1Reps_001_120.amc"
    amc.write_bytes((bundled / SQUAT).read_bytes())
    ours, orig = load_clip(amc), load_clip(bundled / SQUAT)
    assert ours.skeleton.unit_m == 1.0
    assert ours.skeleton.rest_height() == pytest.approx(orig.skeleton.rest_height(), rel=1e-5)
    pa, pb = ours.positions(), orig.positions()  # the body's pose (root translations are AMC numbers)
    assert np.abs((pa - pa[:, :1]) - (pb - pb[:, :1])).max() < 1e-5  # lengths printed to 6 decimals


def test_the_same_motion_is_recognised_alike_whatever_file_carried_it(bundled, tmp_path):
    from shared.io import find_clips
    from shared.pss.space import ProtoSymbolSpace

    clips = [load_clip(f) for f in find_clips([bundled / "amc"]) if "_dg_" not in f.name]
    space = ProtoSymbolSpace.build(clips)
    amc = load_clip(bundled / SQUAT)
    save_clip(amc, tmp_path / "s.bvh")  # ZXY angles of the folded rotation, metres, joints depth first
    save_clip(amc, tmp_path / "s.npz")
    bvh, npz = load_clip(tmp_path / "s.bvh"), load_clip(tmp_path / "s.npz")
    assert bvh.channels != amc.channels and bvh.skeleton.unit_m != amc.skeleton.unit_m
    assert space.features.body(bvh) is bvh.skeleton  # the same joints, listed depth first
    ra, rb, rn = (space.recognize(c) for c in (amc, bvh, npz))
    scale = float(np.median(space.recognition_matrix[np.triu_indices(len(space.symbols), 1)]))
    assert ra.nearest[0][0] == rb.nearest[0][0] == rn.nearest[0][0] == amc.name
    assert np.abs(ra.recognition_distances - rb.recognition_distances).max() < 1e-3 * scale
    assert np.array_equal(ra.recognition_distances, rn.recognition_distances)
    # and the same proto-symbol in the space's geometry: the BVH's ZXY angles are read back as the
    # space's own ASF angles (eq. 2.4 distance ~0 where the raw angles gave ~270)
    from shared.pss.distance import hmm_distance

    geo = space.features.group_indices(("motion", "sensor"))
    h = [space.abstract(c).marginal(geo) for c in (amc, bvh, npz)]
    g_scale = float(np.median(space.distances[np.triu_indices(len(space.symbols), 1)]))
    assert hmm_distance(h[0], h[1]) < 1e-3 * g_scale and hmm_distance(h[0], h[2]) < 1e-9
    assert np.allclose(ra.point, rb.point, atol=1e-3 * g_scale)
    mixed = ProtoSymbolSpace.build([bvh] + [c for c in clips if c.name != amc.name][:6])  # formats mixed in one space
    assert mixed.recognize(amc).nearest[0][0] == bvh.name  # the AMC clip finds its own BVH


# ---------------------------------------------------------------------------- naming schemes
_HDM05 = ["root", "lhipjoint", "rhipjoint", "lowerback", "upperback", "thorax", "lowerneck", "upperneck", "head",
          "lclavicle", "lhumerus", "lradius", "lwrist", "lhand", "lfingers", "lthumb", "lfemur", "ltibia", "lfoot",
          "ltoes"]
_SCHEMES = {
    "mixamo": ["mixamorig:Hips", "mixamorig:LeftHipJoint", "mixamorig:RightHipJoint", "mixamorig:Spine",
               "mixamorig:Spine1", "mixamorig:Spine2", "mixamorig:Neck", "mixamorig:Neck1", "mixamorig:Head",
               "mixamorig:LeftShoulder", "mixamorig:LeftArm", "mixamorig:LeftForeArm", "mixamorig:LeftHand",
               "mixamorig:LeftHandMiddle1", "mixamorig:LeftHandMiddle2", "mixamorig:LeftHandThumb1",
               "mixamorig:LeftUpLeg", "mixamorig:LeftLeg", "mixamorig:LeftFoot", "mixamorig:LeftToeBase"],
    "unreal": ["pelvis", "hipjoint_l", "hipjoint_r", "spine_01", "spine_02", "spine_03", "neck_01", "neck_02", "head",
               "clavicle_l", "upperarm_l", "lowerarm_l", "hand_l", "middle_01_l", "middle_02_l", "thumb_01_l",
               "thigh_l", "calf_l", "foot_l", "ball_l"],
    "character_creator": ["CC_Base_Hip", "CC_Base_L_HipJoint", "CC_Base_R_HipJoint", "CC_Base_Waist",
                          "CC_Base_Spine01", "CC_Base_Spine02", "CC_Base_NeckTwist01", "CC_Base_NeckTwist02",
                          "CC_Base_Head", "CC_Base_L_Clavicle", "CC_Base_L_Upperarm", "CC_Base_L_Forearm",
                          "CC_Base_L_Hand", "CC_Base_L_Mid1", "CC_Base_L_Mid2", "CC_Base_L_Thumb1", "CC_Base_L_Thigh",
                          "CC_Base_L_Calf", "CC_Base_L_Foot", "CC_Base_L_ToeBase"],
    "joint_prefix": ["joint_Hips", "joint_LeftHipJoint", "joint_RightHipJoint", "joint_Spine", "joint_Spine1",
                     "joint_Chest", "joint_Neck", "joint_Neck1", "joint_Head", "joint_LeftShoulder", "joint_LeftArm",
                     "joint_LeftForeArm", "joint_LeftHand", "joint_LeftFingers", "joint_LeftFingers2",
                     "joint_LeftThumb", "joint_LeftUpLeg", "joint_LeftLeg", "joint_LeftFoot", "joint_LeftToe"],
}


def _mirror(name: str) -> str:
    """The right side's name in the scheme of a left-side name."""
    for a, b in (("Left", "Right"), ("_L_", "_R_"), ("_l", "_r")):
        if a in name:
            return name.replace(a, b)
    return name


def _renamed(sk: Skeleton, names: dict[str, str]) -> Skeleton:
    return Skeleton(sk.name, [Joint(names.get(j.name, j.name), j.parent, j.offset, j.dofs, j.euler, j.pre, j.end,
                                    j.limits) for j in sk.joints], sk.unit_m, sk.up_axis, sk.source_format)


@pytest.mark.parametrize("scheme", sorted(_SCHEMES))
def test_human_bodies_from_any_naming_scheme_weigh_what_they_should(plain, scheme):
    from shared.bodies.human import human_body

    names = {}
    for ours, theirs in zip(_HDM05, _SCHEMES[scheme]):
        names[ours] = theirs
        if ours.startswith("l") and ours not in ("lowerback", "lowerneck"):
            names["r" + ours[1:]] = _mirror(theirs)
    sk = _renamed(plain.skeleton, names)
    assert len(set(names.values())) == len(names) == len(sk.joints)
    ref, body = human_body(plain.skeleton), human_body(sk)
    d = body.describe()
    assert d["mass"] == pytest.approx(70.0, abs=0.05) and not d["missing_segments"]
    assert len(body.feet) == 4 and set(body.feet) == {names[f] for f in ("lfoot", "rfoot", "ltoes", "rtoes")}
    m_ref = {j.name: float(ref.model.body(j.name).mass[0]) for j in plain.skeleton.joints}
    m_new = {j.name: float(body.model.body(j.name).mass[0]) for j in sk.joints}
    for seg in (("lfemur",), ("ltibia",), ("lhumerus",), ("head",), ("lfoot", "ltoes"), ("rfemur",)):
        assert sum(m_new[names[b]] for b in seg) == pytest.approx(sum(m_ref[b] for b in seg), rel=0.05), seg


def _without(sk: Skeleton, drop: set[str]) -> Skeleton:
    """The skeleton with the joints ``drop`` (and all below them) cut off; a parent that loses
    its children ends where they began."""
    gone = set()
    for i, j in enumerate(sk.joints):
        if j.name in drop or j.parent in gone:
            gone.add(i)
    keep = [i for i in range(len(sk.joints)) if i not in gone]
    new = {old: n for n, old in enumerate(keep)}
    out = []
    for i in keep:
        j = sk.joints[i]
        cut = [k for k in gone if sk.joints[k].parent == i]
        end = sk.joints[cut[0]].offset if cut and not [k for k in sk.children(i) if k in new] else j.end
        out.append(Joint(j.name, new.get(j.parent, -1), j.offset, j.dofs, j.euler, j.pre, end, j.limits))
    return Skeleton(sk.name, out, sk.unit_m, sk.up_axis, sk.source_format)


def test_a_limb_the_body_has_not_is_a_missing_segment_and_a_tail_is_reported(plain):
    from shared.bodies.human import MIN_MASS, human_body

    legless = human_body(_without(plain.skeleton, {"lfoot", "rtibia"})).describe()
    assert {"l foot", "r shank", "r foot"} <= set(legless["missing_segments"]) and "l shank" not in legless[
        "missing_segments"]
    assert legless["mass"] == pytest.approx(70.0, abs=0.05)
    sk = plain.skeleton  # a tail of three bones (0.6 m) behind the pelvis: a limb no person has
    tail = [Joint(f"tail{n}", len(sk.joints) + n - 1 if n else 0, np.array([0.0, 0.0, -0.2 / sk.unit_m]), ["rx"],
                  "xyz", np.eye(3), np.array([0.0, 0.0, -0.2 / sk.unit_m]) if n == 2 else None) for n in range(3)]
    tailed = Skeleton(sk.name, sk.joints + tail, sk.unit_m, sk.up_axis, sk.source_format)
    ref, body = human_body(sk), human_body(tailed)
    assert body.unmapped == ["tail0", "tail1", "tail2"] and not body.describe()["missing_segments"]
    assert body.mass == pytest.approx(70.0, abs=0.05)
    assert all(body.model.body(f"tail{n}").mass[0] == MIN_MASS for n in range(3))  # no segment's mass
    assert all(body.model.body(j.name).mass[0] == pytest.approx(ref.model.body(j.name).mass[0], rel=0.01)
               for j in sk.joints)


def test_a_report_where_nothing_was_checked_does_not_say_feasible(plain):
    from shared.bodies.body import perform
    from shared.bodies.human import human_body

    clip = plain.frames(0, 40)
    feetless = _without(plain.skeleton, {"lfoot", "rfoot"})
    chans = [c for c in clip.channels if c.rsplit(".", 1)[0] in {j.name for j in feetless.joints}]
    _, report = perform(human_body(feetless), clip.with_data(clip.select(chans), channels=chans, skeleton=feetless,
                                                             groups={"motion": chans}))
    assert report["feasible"] is None and len(report["not_checked"]) == 2  # a BVH body has no joint limits either
    assert "no feet" in report["not_checked"][1]
    _, report = perform(human_body(plain.skeleton), clip)  # feet, no limits: balance checked, limits said
    assert report["feasible"] in (True, False) and report["support"]["checked"]
    assert report["not_checked"] == ["joint limits (the body has none for this clip's channels)"]


def test_a_write_error_names_the_users_file_not_a_temporary_one(plain, tmp_path):
    target = tmp_path / "squat.amc"
    with pytest.raises(ClipFormatError) as e:
        save_clip(plain, target)  # a BVH body cannot become AMC
    assert e.value.path == str(target) and ".tmp" not in str(e.value.message) and "ASF" in e.value.message
    assert not list(tmp_path.iterdir())  # and nothing is left behind


# ---------------------------------------------------------------------------- Blender, the real client
def test_blender_reads_our_bvh_as_we_do_and_its_export_is_the_same_motion(plain, mixed_space, tmp_path, blender):
    import json
    import subprocess
    from pathlib import Path

    ours = tmp_path / "ours.bvh"
    clip = plain.frames(0, 30)
    save_clip(clip, ours)
    script = Path(__file__).parent / "blender" / "bvh_round_trip.py"
    r = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "3", "--python", str(script), "--",
                        str(ours), str(tmp_path / "blender.json"), str(tmp_path / "blender.bvh")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    got = json.loads((tmp_path / "blender.json").read_text())
    mine = load_clip(ours)
    p = mine.positions() / mine.skeleton.unit_m  # file units, Y up
    names = [j.name for j in mine.skeleton.joints]
    frames = sorted(got["frames"], key=int)
    assert len(frames) == mine.n_frames and got["fps"] == pytest.approx(mine.fps)
    for t, f in enumerate(frames):
        for k, name in enumerate(names):
            x, y, z = got["frames"][f][name]  # Blender: Z up, Y back (axis_forward -Z, axis_up Y)
            assert np.allclose([x, z, -y], p[t, k], atol=1e-3 * max(1.0, np.abs(p).max()) * 1e-1), (f, name)
    # Blender's own export, read back: the same body and motion, and the same proto-symbol
    back = load_clip(tmp_path / "blender.bvh")
    pb = back.positions()
    rows = [back.skeleton.index(n) for n in names]
    assert np.abs(pb[:, rows] - mine.positions()[:, :len(names)]).max() < 2e-3
    _same_proto_symbol(mixed_space, back, mine)


def test_a_six_channel_body_slides_its_bones_in_mujoco_as_in_our_kinematics(plain, tmp_path):
    import mujoco

    from shared.bodies.body import perform, qpos_trajectory
    from shared.bodies.human import human_body
    from tests.test_bodies import _replay_accelerations

    sk, data, chans = _variant(plain, every_joint_moves=True)
    _write_raw(tmp_path / "six.bvh", sk, data, chans, plain.fps)
    clip = load_clip(tmp_path / "six.bvh")
    moved = clip.data.copy()
    k = clip.channels.index("ltibia.ty")
    moved[:, k] += 0.05 / clip.skeleton.unit_m * np.sin(np.linspace(0, np.pi, clip.n_frames))  # up to 5 cm
    clip = clip.with_data(moved)
    body = human_body(clip.skeleton)
    assert "ltibia.ty" in body.channels and body.describe()["mass"] == pytest.approx(70.0, abs=0.05)
    q = qpos_trajectory(body, clip)
    ours = clip.skeleton.forward_kinematics(clip.data, clip.channels, ends=False)
    ids = [mujoco.mj_name2id(body.model, mujoco.mjtObj.mjOBJ_BODY, j.name) for j in clip.skeleton.joints]
    d = mujoco.MjData(body.model)
    worst = 0.0
    for t in range(5, clip.n_frames - 5, 3):
        d.qpos[:] = q[t]
        mujoco.mj_kinematics(body.model, d)
        worst = max(worst, float(np.abs(d.xpos[ids] - ours[t]).max()))
    assert worst < 0.01, f"{worst:.4f} m"  # positions smoothed before differentiation, as for every body
    assert _replay_accelerations(body, clip) < 1e-8
    performed, _ = perform(body, clip)
    assert "tau.ltibia.ty" in performed.channels  # the force that slides the shank, in N


@pytest.fixture(scope="module")
def mixed_space(plain, bundled):
    from shared.io import find_clips
    from shared.pss.space import ProtoSymbolSpace

    others = [load_clip(f) for f in find_clips([bundled / "amc"]) if "_bd_" in f.name and "squat" not in f.name][:5]
    return ProtoSymbolSpace.build([plain] + others)


def _same_proto_symbol(space, a, b):
    """Eq. 2.4 between the two clips' HMMs on the space's geometry, against the space's own scale."""
    from shared.pss.distance import hmm_distance

    geo = space.features.group_indices(("motion", "sensor"))
    d = hmm_distance(space.abstract(a).marginal(geo), space.abstract(b).marginal(geo))
    scale = float(np.median(space.distances[np.triu_indices(len(space.symbols), 1)]))
    assert d < 2e-3 * scale, f"distance {d:.3g} (space median {scale:.3g})"


@pytest.mark.parametrize("variant", ["m", "in", "cmu", "z-up", "six-replace", "six-add", "root-offset-add"])
def test_every_convention_gives_the_same_body_mass_and_proto_symbol(plain, mixed_space, tmp_path, variant):
    from shared.bodies.human import human_body

    u = plain.skeleton.unit_m
    kw = {"m": dict(scale=u), "in": dict(scale=u / 0.0254), "cmu": dict(scale=u / UNITS["cmu"]),
          "z-up": dict(turn=ROT_Z_UP), "six-replace": dict(every_joint_moves=True),
          "six-add": dict(every_joint_moves=True, add_form=True),
          "root-offset-add": dict(root_offset=[0.0, 0.95 / u, 0.0], add_form=True)}[variant]
    sk, data, chans = _variant(plain, **kw)
    _write_raw(tmp_path / "v.bvh", sk, data, chans, plain.fps)
    clip = load_clip(tmp_path / "v.bvh")
    assert human_body(clip.skeleton).describe()["mass"] == pytest.approx(70.0, abs=0.05)
    _same_proto_symbol(mixed_space, clip, plain)


def test_mujoco_warnings_reach_the_report_instead_of_a_log_line_only(tmp_path, monkeypatch):
    from shared.bodies.body import perform
    from shared.bodies.robot import robot
    from tests.test_bodies import _robot_motion

    monkeypatch.chdir(tmp_path)
    body = robot("self")
    body.model.body_mass[2:] = 1e-14  # a body MuJoCo cannot trust: inertia matrix near singular
    body.model.body_inertia[2:] = 1e-16
    _, report = perform(body, _robot_motion())
    assert report["mujoco_warnings"].get("inertia", 0) > 0
    assert report["feasible"] is not True and any("MuJoCo warned" in w for w in report["not_checked"])
    _, fine = perform(robot("other"), _robot_motion())
    assert fine["mujoco_warnings"] == {}
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()  # the warning went to the log, not into the working folder
