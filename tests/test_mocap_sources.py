"""Motion capture from other studios read right with no options: the game studio's
files of ``../shared/data/bandai1`` (static floor root, 6 channels on every joint, cm, bones
along local X), the CMU conversions, HDM05, files Blender authors, and bad files. Positions are
checked against an independent forward kinematics of the file (:mod:`bench.bvh_reference`)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bench.bvh_reference import read_positions
from shared.errors import ClipFormatError
from shared.io import load_clip, save_clip

BANDAI = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "bandai1" / "bvh"
SQUAT = "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc"


@pytest.fixture(scope="module")
def bandai() -> list[Path]:
    files = sorted(BANDAI.glob("*.bvh"))
    if len(files) < 170:
        pytest.fail(f"the game studio's BVH files are not at {BANDAI} (see ../shared/data/bandai1/SOURCE.md)")
    return files


def _against_reference(path: Path, clip) -> float:
    """Largest distance (m) of any joint from the independent forward kinematics (in the
    clip's axes: a Z-up file is read turned to Y up)."""
    from shared.io.conventions import Z_TO_Y

    names, ref = read_positions(path)
    if clip.read_as["up"].startswith("z"):
        ref = ref @ Z_TO_Y.T
    p = clip.skeleton.forward_kinematics(clip.data, clip.channels, ends=False)
    return float(np.abs(ref[:, [names.index(j.name) for j in clip.skeleton.joints]] * clip.skeleton.unit_m - p).max())


def test_the_game_studios_files_read_with_no_options_upright_at_a_persons_height(bandai):
    for path in bandai[::6]:  # 29 files of 15 styles and 12 contents
        clip = load_clip(path)
        assert clip.read_as["units"].startswith("cm") and clip.read_as["up"].startswith("y")
        assert clip.skeleton.root.name == "Hips" and "joint_Root" in clip.read_as["root"], path.name
        assert "joint_Root.tx" not in clip.channels
        assert _against_reference(path, clip) < 1e-3, path.name
        p = clip.positions()
        head, toe = clip.skeleton.index("Head"), clip.skeleton.index("Toes_L")
        assert np.median(p[:, head, 1] - p[:, toe, 1]) > 1.0  # upright, a person's size
        assert 0.6 < np.median(p[:, 0, 1]) < 1.2  # the hips at a person's hip height over the floor (y = 0)


def test_each_joints_translations_are_decided_in_the_file_and_an_option_still_wins(bandai):
    path = next(f for f in bandai if "_walk_normal_" in f.name)
    clip = load_clip(path)
    assert clip.read_as["translations"] == ["replace"]  # the hips' channels replace their OFFSET (-452 cm)
    wrong = load_clip(path, translations="add", units="cm")  # every bone twice its length: no unit fits alone
    assert np.median(wrong.positions()[:, 0, 1]) > 1.5  # the hips 1.8 m up: why the file decides
    assert np.abs(wrong.positions() - clip.positions()).max() > 1.0


def test_the_cmu_conversions_match_the_independent_kinematics(cmu):
    for name in ("131_01.bvh", "scaled_131_01.bvh"):
        clip = load_clip(cmu / name)
        assert _against_reference(cmu / name, clip) < 1e-3


def test_a_take_lying_down_keeps_the_up_axis_of_its_upright_rest_pose(hdm05, tmp_path):
    amc = next((hdm05 / "amc" / "lieDownFloor").glob("HDM_bd_*.amc"))
    save_clip(load_clip(amc), tmp_path / "lie.bvh")
    assert load_clip(tmp_path / "lie.bvh").read_as["up"].startswith("y")


# ---------------------------------------------------------------------------- one motion, one representation
def test_the_same_motion_as_amc_bvh_and_npz_is_one_proto_symbol(hdm05, tmp_path):
    from shared.pss.distance import hmm_distance
    from shared.pss.space import ProtoSymbolSpace

    clips = [load_clip(f) for f in sorted((hdm05 / "amc").rglob("HDM_bd_*.amc"))]
    space = ProtoSymbolSpace.build(clips)
    geo = space.features.group_indices(("motion",))
    for label in ("squat1Reps", "rotateArmsBothBackward1Reps", "throwBasketball"):
        a, b = [c for c in clips if c.label == label][:2]
        save_clip(a, tmp_path / "a.bvh")
        save_clip(a, tmp_path / "a.npz")
        bvh, npz = load_clip(tmp_path / "a.bvh"), load_clip(tmp_path / "a.npz")
        h = [space.abstract(c).marginal(geo) for c in (a, bvh, npz, b)]
        assert hmm_distance(h[0], h[1]) < 0.01 * hmm_distance(h[0], h[3]), label
        assert hmm_distance(h[0], h[2]) < 0.01 * hmm_distance(h[0], h[3]), label


def test_blenders_re_export_is_the_same_proto_symbol(hdm05, tmp_path, blender):
    from shared.pss.distance import hmm_distance
    from shared.pss.space import ProtoSymbolSpace

    clips = [load_clip(f) for f in sorted((hdm05 / "amc").rglob("HDM_bd_squat1Reps_*.amc"))[:3]]
    space = ProtoSymbolSpace.build(clips)
    geo = space.features.group_indices(("motion",))
    save_clip(clips[0], tmp_path / "a.bvh")
    script = Path(__file__).parent / "blender" / "bvh_round_trip.py"
    r = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "3", "--python", str(script), "--",
                        str(tmp_path / "a.bvh"), str(tmp_path / "b.json"), str(tmp_path / "blender.bvh")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    h = [space.abstract(c).marginal(geo) for c in (clips[0], load_clip(tmp_path / "blender.bvh"), clips[1])]
    assert hmm_distance(h[0], h[1]) < 0.01 * hmm_distance(h[0], h[2])


def test_the_same_rotation_on_another_euler_branch_is_the_same_features_and_torques(hdm05):
    from scipy.spatial.transform import Rotation

    from shared.bodies.body import perform
    from shared.bodies.human import human_body
    from shared.pss.features import MotionFeatures

    clip = load_clip(hdm05 / SQUAT).resample(30)
    data = clip.data.copy()
    j = clip.skeleton.joints[clip.skeleton.index("lhumerus")]
    cols = [clip.channels.index(f"lhumerus.r{a}") for a in j.euler]
    twin = data[:, cols] + np.array([180.0, 0.0, 180.0])
    twin[:, 1] = 180.0 - data[:, cols[1]]
    half = len(data) // 2
    data[half:, cols] = twin[half:]  # the second half on the other branch, plus whole turns on the first
    data[:half, cols[0]] += 360.0
    other = clip.with_data(data)
    r1 = Rotation.from_euler(j.euler, clip.data[:, cols], degrees=True)
    r2 = Rotation.from_euler(j.euler, data[:, cols], degrees=True)
    assert (r1 * r2.inv()).magnitude().max() < 1e-9  # the same rotations
    f = MotionFeatures.for_clips([clip])
    assert np.abs(f.encode(clip) - f.encode(other)).max() < 1e-9
    body = human_body(clip.skeleton)
    t1, _ = perform(body, clip)
    t2, _ = perform(body, other)
    s = t1.group("sensor")
    assert np.abs(t1.select(s) - t2.select(s)).max() < 1e-6 * np.abs(t1.select(s)).max()


def test_generation_gives_back_the_rotations_on_a_continuous_branch(hdm05):
    from shared.pss.features import MotionFeatures

    clip = load_clip(hdm05 / SQUAT).resample(30)
    f = MotionFeatures.for_clips([clip])
    back = f.decode(f.encode(clip), clip.fps)
    rows = [clip.skeleton.index(j) for j in f.rot_joints]
    la = clip.skeleton.local_matrices(clip.data, clip.channels)[:, rows]
    lb = clip.skeleton.local_matrices(back.select(clip.channels), clip.channels)[:, rows]
    assert np.abs(la - lb).max() < 1e-9
    ang = back.select([f"{j}.r{a}" for j in f.rot_joints for a in "xyz"])
    assert np.abs(np.diff(ang, axis=0)).max() < 30.0  # no jump of a branch or a turn between frames


def test_a_clip_on_another_studios_skeleton_is_read_by_where_its_body_parts_are(hdm05, bandai, tmp_path):
    """A studio's own skeleton must not change the label. HDM05 clips moved onto the game
    studio's joints (:func:`shared.reports.evaluation.on_studio_skeleton`: other names, fewer joints,
    no joint angle of HDM05's) keep their label in a space of HDM05's skeleton, the joints both have
    read where they are, in memory and as the BVH we write; a take on the studio's joints is cut as
    the HDM05 take is; the studio's own files are read; and what needs joint angles refuses them, naming both skeletons."""
    from shared.capture.segment import segment
    from shared.capture.takes import join, score
    from shared.errors import BadInput
    from shared.pss.foreign import landmarks, point_names, read_points
    from shared.pss.space import ProtoSymbolSpace
    from shared.reports.evaluation import STUDIO_JOINTS, on_studio_skeleton

    def clips(who, cls, n=3):
        return [load_clip(f) for f in sorted((hdm05 / "amc" / cls).glob(f"HDM_{who}_*.amc"))[:n]]

    classes = ("squat1Reps", "kickLFront1Reps", "elbowToKnee1RepsLelbowStart", "rotateArmsBothBackward1Reps")
    space = ProtoSymbolSpace.build([c for who in ("bd", "bk") for k in classes for c in clips(who, k)])
    test = [c for k in classes for c in clips("dg", k, 2)]
    moved = [on_studio_skeleton(c) for c in test]
    assert moved[0].skeleton.name == "game studio" and not set(moved[0].channels) & set(test[0].channels)
    for c, m in zip(test, moved):
        assert space.recognize(m).nearest_label == space.recognize(c).nearest_label == c.label
    # the landmarks (the joints both skeletons start their segments at) are read exactly; the others on their
    # segment's line
    c, m = test[0], moved[0]
    p = c.skeleton.forward_kinematics(c.data, c.channels)
    got = read_points(m.skeleton.forward_kinematics(m.data, m.channels), m.skeleton, c.skeleton)
    names = point_names(c.skeleton)
    kept = [names.index(STUDIO_JOINTS[i][1]) for k, i in landmarks(m.skeleton).items() if k[2] != "base"]
    assert len(kept) >= 20
    assert np.abs(got[:, kept] - p[:, kept]).max() < 1e-6
    err = np.linalg.norm(got - p, axis=2) / c.skeleton.rest_height()
    assert np.median(err) < 0.01 and err.max() < 0.1
    # written as BVH (its root an AMC root's extrinsic rotation) and read back: the same body, the same label
    save_clip(m, tmp_path / "studio.bvh")
    back = load_clip(tmp_path / "studio.bvh")
    q, at = back.skeleton.forward_kinematics(back.data, back.channels), point_names(back.skeleton)
    here = m.skeleton.forward_kinematics(m.data, m.channels)
    assert max(np.abs(q[:, at.index(n)] - here[:, i]).max() for i, n in enumerate(point_names(m.skeleton))) < 1e-4
    assert space.recognize(back).nearest_label == c.label
    # a take on the studio's joints is cut where the same take on HDM05's is
    target, squat = clips("bk", "squat1Reps", 2)
    take, truth = join([squat] * 3, seed=1)
    for t in (take, on_studio_skeleton(take)):
        found = segment(t, target, expected=3)
        assert score([(r.start, r.end) for r in found.repetitions], truth)["f1"] == 1.0, found.verdict
    studio = load_clip(bandai[0])
    assert space.recognize(studio).nearest_label in classes
    with pytest.raises(BadInput, match="another body layout"):  # a space's clips share one skeleton
        ProtoSymbolSpace.build([*clips("bd", "squat1Reps", 2), studio, *clips("bd", "kickLFront1Reps", 2)])
    with pytest.raises(BadInput, match=r"another skeleton, 0 of the 31 joints .*root, lhipjoint.*its own: Hips"):
        space.associate(studio.frames(0, 60), "frames")  # its joint angles are needed: refused
    dropped = test[0].with_data(test[0].data[:, 6:], channels=test[0].channels[6:],
                                groups={"motion": test[0].channels[6:]})  # one skeleton, channels lacking: said as before
    with pytest.raises(BadInput, match=r"lacks 6 channels of this space, e.g. \['root.tx'") as err_info:
        space.recognize(dropped)
    assert "another skeleton" not in str(err_info.value)


@pytest.mark.slow
def test_a_game_studios_own_motions_are_none_of_a_spaces_motions(dev_space, bandai):
    """The open set beyond HDM05: the game studio's 174 clips (its own skeleton, read by its
    landmarks; bows, waves, punches, runs, walks, a right-foot kick: none of HDM05's classes) are
    "none of these" for the space of HDM05's performers bd and bk at least as often as the goal asks
    of unknown motions (90 %; measured 170 of 174: docs/pss.md)."""
    shown = [dev_space.recognize(load_clip(f)) for f in bandai]
    assert all(r.another_skeleton for r in shown)
    assert np.mean([r.label is None for r in shown]) >= 0.9, [(r.nearest_label, r.confidence) for r in shown if r.label]


# ---------------------------------------------------------------------------- bodies
def test_a_body_from_the_game_studios_skeleton_is_a_person_and_walks_with_human_torques(bandai):
    from shared.bodies.body import perform
    from shared.bodies.human import human_body
    from shared.bodies.segments import map_segments

    clip = load_clip(next(f for f in bandai if "_walk_normal_" in f.name))
    body = human_body(clip.skeleton)
    d = body.describe()
    assert d["mass"] == pytest.approx(70.0, abs=0.05) and not d["missing_segments"] and not d["unmapped_bones"]
    seg, _ = map_segments(clip.skeleton)
    share: dict = {}
    for jn in (j.name for j in clip.skeleton.joints):
        share[seg[jn]] = share.get(seg[jn], 0.0) + float(body.model.body(jn).mass[0]) / 70.0
    assert max(v for (s, _), v in share.items() if s not in ("pelvis", "spine")) < 0.20
    assert share[("pelvis", "")] < 0.2
    performed, report = perform(body, clip)
    tau = performed.select([c for c in performed.group("sensor") if c.startswith("tau.") and c[-3:-1] == ".r"])
    assert np.abs(tau).max() < 500.0


@pytest.mark.parametrize("source", ["hdm05", "cmu", "game studio"])
def test_bodies_are_segmented_by_their_tree_and_proportions_when_no_bone_has_a_name(source, bundled, cmu, bandai):
    from shared.bodies.human import human_body
    from shared.bodies.segments import map_segments
    from shared.motion.skeleton import Joint, Skeleton

    path = {"hdm05": bundled / SQUAT, "cmu": cmu / "131_01.bvh", "game studio": bandai[0]}[source]
    sk = load_clip(path).skeleton
    anon = Skeleton(sk.name, [Joint(f"b{i:02d}", j.parent, j.offset, j.dofs, j.euler, j.pre, j.end, j.limits)
                              for i, j in enumerate(sk.joints)], sk.unit_m, sk.up_axis, sk.source_format)
    named, blind = human_body(sk), human_body(anon)
    assert not blind.unmapped and not blind.missing_segments and blind.mass == pytest.approx(70.0, abs=0.05)
    assert len(blind.feet) == len(named.feet) >= 2
    seg, _ = map_segments(sk)
    by = {}  # kg per (segment, side) as the names say; forearm and hand as one (where the wrist ends)
    for k, j in enumerate(sk.joints):
        s, side = seg[j.name]
        key = ("forearm+hand" if s in ("forearm", "hand") else s, side)
        m = by.setdefault(key, [0.0, 0.0])
        m[0] += float(named.model.body(j.name).mass[0])
        m[1] += float(blind.model.body(f"b{k:02d}").mass[0])
    assert {s for s, _ in by} >= {"pelvis", "spine", "neck", "head", "clavicle", "upper_arm", "forearm+hand", "thigh",
                                  "shank", "foot"}
    for key, (m_named, m_blind) in by.items():
        assert m_blind == pytest.approx(m_named, rel=0.01, abs=0.02), key


def test_bones_named_joint_are_read_by_their_word_and_their_place(bundled):
    from shared.bodies.human import human_body
    from shared.io import load_skeleton
    from shared.motion.skeleton import Joint, Skeleton

    sk = load_skeleton(bundled / "asf" / "HDM_bd.asf")
    names = {"lowerback": "LowerSpineJoint", "upperback": "MiddleSpineJoint", "thorax": "UpperSpineJoint",
             "lowerneck": "LowerNeckJoint", "upperneck": "UpperNeckJoint", "head": "HeadJoint",
             "lfemur": "LeftHipJoint", "ltibia": "LeftKneeJoint", "lfoot": "LeftAnkleJoint", "rfemur": "RightHipJoint",
             "rtibia": "RightKneeJoint", "rfoot": "RightAnkleJoint"}
    renamed = Skeleton(sk.name, [Joint(names.get(j.name, j.name), j.parent, j.offset, j.dofs, j.euler, j.pre, j.end,
                                       j.limits) for j in sk.joints], sk.unit_m, sk.up_axis, sk.source_format)
    ref, body = human_body(sk), human_body(renamed)
    root = sk.joints[0].name
    pelvis = float(body.model.body(root).mass[0])
    assert pelvis == pytest.approx(float(ref.model.body(root).mass[0]), rel=0.05) and pelvis < 0.2 * 70.0
    assert "MiddleSpineJoint" not in body.unmapped


# ---------------------------------------------------------------------------- bad and unusual files
def _bvh(tmp_path, hierarchy: str, frames: list[str]) -> Path:
    p = tmp_path / "odd.bvh"
    p.write_text(f"HIERARCHY\n{hierarchy}\nMOTION\nFrames: {len(frames)}\nFrame Time: 0.0333333\n" + "\n".join(frames) + "\n")
    return p


def test_channels_0_and_fewer_rotation_channels_are_legal(tmp_path):
    leg = ("JOINT LeftUpLeg { OFFSET 10 -5 0 CHANNELS 2 Zrotation Xrotation JOINT LeftLeg { OFFSET 0 -45 0 "
           "CHANNELS 0 JOINT LeftFoot { OFFSET 0 -45 0 CHANNELS 1 Xrotation End Site { OFFSET 0 -8 10 } } } }")
    h = ("ROOT Hips { OFFSET 0 0 0 CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation "
         f"{leg} JOINT Spine {{ OFFSET 0 20 0 CHANNELS 3 Zrotation Xrotation Yrotation JOINT Head {{ OFFSET 0 55 0 "
         "CHANNELS 0 End Site { OFFSET 0 20 0 } } } }")
    rows = [f"0 98 0 0 {k} 0 10 {k} 0 0 0 {2 * k}" for k in range(6)]
    clip = load_clip(_bvh(tmp_path, h, rows))
    assert clip.read_as["units"].startswith("cm") and "LeftLeg.rx" not in clip.channels
    assert clip.n_frames == 6 and _against_reference(tmp_path / "odd.bvh", clip) < 1e-9
    with pytest.raises(ClipFormatError, match=r"odd\.bvh.*CHANNELS 9"):
        load_clip(_bvh(tmp_path, h.replace("CHANNELS 0 JOINT LeftFoot", "CHANNELS 9 JOINT LeftFoot"), rows))


def _asf_variant(bundled, tmp_path, sub, name="HDM_bd.asf") -> Path:
    text = (bundled / "asf" / "HDM_bd.asf").read_bytes().decode("latin-1")
    (tmp_path / "asf").mkdir(exist_ok=True)
    out = tmp_path / "asf" / name
    out.write_bytes(sub(text).encode("latin-1"))
    return out


def test_asf_unit_errors_name_the_file(bundled, tmp_path):
    from shared.io import read_asf

    zero = _asf_variant(bundled, tmp_path, lambda t: re.sub(r"length 0\.45", "length 0", t, count=1), "zero.asf")
    with pytest.raises(ClipFormatError, match=r"zero\.asf.*length unit must be positive"):
        read_asf(zero)
    odd = _asf_variant(bundled, tmp_path, lambda t: re.sub(r"angle deg", "angle turns", t, count=1), "odd.asf")
    with pytest.raises(ClipFormatError, match=r"odd\.asf.*unknown angle unit"):
        read_asf(odd)


@pytest.mark.parametrize("unit,per_degree", [("rad", np.pi / 180.0), ("grad", 1.0 / 0.9)])
def test_asf_angle_units_apply_to_the_amc_values(bundled, tmp_path, unit, per_degree):
    from shared.io import read_asf

    text = (bundled / "asf" / "HDM_bd.asf").read_bytes().decode("latin-1")
    assert "angle deg" in text

    def convert(t):  # the ASF's own angles (axis, limits) in the new unit too
        t = t.replace("angle deg", f"angle {unit}", 1)
        t = re.sub(r"(\n\s*axis\s+)([-0-9.eE]+)\s+([-0-9.eE]+)\s+([-0-9.eE]+)",
                   lambda m: m.group(1) + " ".join(f"{float(v) * per_degree:.12g}" for v in m.groups()[1:]), t)
        return re.sub(r"(\n\s*orientation\s+)([-0-9.eE]+)\s+([-0-9.eE]+)\s+([-0-9.eE]+)",
                      lambda m: m.group(1) + " ".join(f"{float(v) * per_degree:.12g}" for v in m.groups()[1:]), t)

    asf = _asf_variant(bundled, tmp_path, convert)
    sk = read_asf(asf)
    orig = load_clip(bundled / SQUAT)
    rot = [i for i, c in enumerate(orig.channels) if c.rsplit(".", 1)[1].startswith("r")]
    lines, data = [], orig.data.copy()
    data[:, rot] *= per_degree
    for t, row in enumerate(data):  # the AMC in the ASF's unit, with no declaration of its own
        lines.append(str(t + 1))
        k = 0
        for j in sk.joints:
            if j.dofs:
                lines.append(j.name + " " + " ".join(f"{v:.12g}" for v in row[k:k + len(j.dofs)]))
                k += len(j.dofs)
    amc = tmp_path / "HDM_bd_squat1Reps_001_120.amc"
    amc.write_text("\n".join(lines) + "\n")
    back = load_clip(amc)
    assert np.abs(back.positions() - orig.positions()).max() < 1e-6


# ---------------------------------------------------------------------------- files for other tools
def test_the_bvh_we_write_is_in_metres_whatever_the_input_units(cmu, tmp_path):
    save_clip(load_clip(cmu / "131_01.bvh"), tmp_path / "out.bvh")  # CMU's own unit in, metres out
    back = load_clip(tmp_path / "out.bvh")
    assert back.read_as["units"].startswith("m ") and 1.2 < back.skeleton.rest_height() < 1.5


def test_a_file_blender_authors_in_inches_z_up_with_xyz_eulers_reads_as_the_same_motion(bundled, tmp_path, blender):
    clip = load_clip(bundled / SQUAT).frames(0, 60)
    save_clip(clip, tmp_path / "ours.bvh")
    script = Path(__file__).parent / "blender" / "bvh_round_trip.py"
    r = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "3", "--python", str(script), "--",
                        str(tmp_path / "ours.bvh"), str(tmp_path / "b.json"), str(tmp_path / "authored.bvh"),
                        str(1.0 / 0.0254), "XYZ"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    back = load_clip(tmp_path / "authored.bvh")
    assert back.read_as["units"].startswith("in") and back.read_as["up"].startswith("z")
    mine = load_clip(tmp_path / "ours.bvh")
    names = [j.name for j in mine.skeleton.joints]
    pb = back.positions()[:, [back.skeleton.index(n) for n in names]]
    assert np.abs(pb - mine.positions()[:, :len(names)]).max() < 2e-3


def test_the_body_frame_is_the_pelvis_axes_whatever_the_take(hdm05, bandai):
    """HDM05's pelvis is the body's frame already (B = I), also in a take that bends down or
    lies on the floor; the game studio's hips turn X up (one B for all its files)."""
    from shared.bodies.segments import body_frame

    for name in ("depositFloorR", "lieDownFloor", "squat1Reps"):
        f = next((hdm05 / "amc").rglob(f"HDM_bd_{name}_*.amc"))
        c = load_clip(f)
        c.skeleton.__dict__.pop("_body_frame", None)  # decided from this take, not an earlier one
        assert np.allclose(body_frame(c.skeleton, c.data, c.channels), np.eye(3)), name
    frames = {tuple(body_frame(c.skeleton, c.data, c.channels).ravel()) for c in map(load_clip, bandai[::12])}
    assert len(frames) == 1
    b = np.array(frames.pop()).reshape(3, 3)
    assert np.allclose(b[:, 1], [1, 0, 0])  # the hips' X is the body's up


def _author_game_studio(blender: str, clip, tmp_path: Path) -> Path:
    save_clip(clip, tmp_path / "ours.bvh")
    script = Path(__file__).parent / "blender" / "author_game_studio.py"
    r = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "3", "--python", str(script), "--",
                        str(tmp_path / "ours.bvh"), str(tmp_path / "authored.bvh")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return tmp_path / "authored.bvh"


@pytest.mark.slow
def test_a_studios_root_frame_changes_neither_the_recognition_features_nor_the_label(bundled, tmp_path, blender):
    """The same squat with its skeleton re-rested along X by Blender (the root's frame turned):
    the body frame puts the heading where the body faces, so the recognition features and the
    label are the original's."""
    from shared.bodies.segments import body_frame
    from shared.pss.space import ProtoSymbolSpace

    clips = [load_clip(f) for f in sorted((bundled / "amc").rglob("*.amc")) if "_dg_" not in f.name]
    space = ProtoSymbolSpace.build(clips)
    probe = load_clip(next((bundled / "amc" / "squat1Reps").glob("HDM_dg_*.amc")))
    studio = load_clip(_author_game_studio(blender, probe, tmp_path))
    assert not np.allclose(body_frame(studio.skeleton, studio.data, studio.channels), np.eye(3))
    pos = space.features.feature_indices("position")
    a, b = (space.features.encode(c.resample(30))[:, pos] for c in (probe, studio))
    joints = [k for k, n in enumerate(space.features.position_feature_names) if ".end)" not in n]
    assert np.abs(a - b)[:, joints].max() < 1e-2  # z-scored; Blender puts its own end sites
    ra, rb = space.recognize(probe), space.recognize(studio)
    assert ra.label == rb.label == "squat1Reps"
    assert rb.recognition_distances.min() < 1.05 * ra.recognition_distances.min() + 1e-6


def test_a_file_blender_authors_in_a_game_studios_conventions_reads_as_the_same_motion(bundled, tmp_path, blender):
    """Blender authors the squat with a static root at the floor, every bone's rest along its
    parent's X, 6 channels on every joint (positions replacing the offset), Z up, centimetres."""
    from shared.bodies.human import human_body

    clip = load_clip(bundled / SQUAT).frames(0, 60)
    _author_game_studio(blender, clip, tmp_path)
    text = (tmp_path / "authored.bvh").read_text()
    assert text.count("CHANNELS 6") == text.count("JOINT") + 1 and "ROOT joint_Root" in text
    back = load_clip(tmp_path / "authored.bvh")
    assert back.read_as["units"].startswith("cm") and back.read_as["up"].startswith("z")
    assert "joint_Root" in back.read_as["root"] and back.skeleton.joints[0].name == "root"
    assert back.read_as["translations"] == ["replace"]
    assert _against_reference(tmp_path / "authored.bvh", back) < 1e-3
    mine = load_clip(tmp_path / "ours.bvh")
    names = [j.name for j in mine.skeleton.joints]
    pb = back.positions()[:, [back.skeleton.index(n) for n in names]]
    assert np.abs(pb - mine.positions()[:, :len(names)]).max() < 1e-3
    ref, body = human_body(mine.skeleton), human_body(back.skeleton)
    assert not body.unmapped and not body.missing_segments
    assert all(body.model.body(n).mass[0] == pytest.approx(ref.model.body(n).mass[0], rel=0.01) for n in names)
    # the simulated test (a tracking controller on a floor) stands the authored body on its feet as ours
    from shared.bodies.tracking import perform_tracked

    for fast in (1, 2):  # as recorded, and twice as fast (then it needs a hand: in both alike)
        a, b = (perform_tracked(bd, c.with_data(c.data, fps=c.fps * fast))[1]["support"]
                for bd, c in ((ref, mine), (body, back)))
        assert a["tracking_checked"] and b["tracking_checked"] and b["max_root_error_m"] < 0.05, b
        # the frames that need a hand, which the coach's check counts, within a tenth of the clip (the
        # feet differ a little: Blender puts its own end sites, so the soles' points move)
        assert abs(a["frames_tracking_helped"] - b["frames_tracking_helped"]) <= 6, (a, b)
        assert (a["frames_tracking_helped"] == 0) == (fast == 1) == (b["frames_tracking_helped"] == 0), (a, b)
