"""Clips: ASF/AMC, BVH and NPZ on real HDM05 files, round trips and bad files."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from shared.errors import BadInput, ClipFormatError
from shared.io import find_clips, find_skeleton, load_clip, read_asf, save_clip
from shared.motion.clip import Clip, time_normalised

SQUAT = "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc"
PAST_360 = "amc/depositFloorR/HDM_bd_depositFloorR_002_120.amc"


def _positions_by_name(clip):
    pos = clip.skeleton.forward_kinematics(clip.data, clip.channels, ends=False)
    return {j.name: pos[:, i] for i, j in enumerate(clip.skeleton.joints)}


def test_asf_reads_hdm05_skeleton(hdm05):
    sk = read_asf(hdm05 / "asf/HDM_bd.asf")
    assert len(sk.joints) == 31 and sk.joints[0].name == "root"
    assert len(sk.channels()) == 62  # 6 root + 56 joint angles
    assert sk.unit_m == pytest.approx(0.0254 / 0.45)
    femur = sk.joints[sk.index("lfemur")]
    assert femur.dofs == ["rx", "ry", "rz"] and femur.limits["rx"] == (-160.0, 20.0)
    # the femur starts where the hip joint bone ends
    assert np.linalg.norm(femur.offset) == pytest.approx(2.28399, rel=1e-5)


def test_values_derived_from_a_skeleton_are_made_once_per_skeleton(hdm05):
    from shared.bodies.segments import _stature, stature

    sk, other = read_asf(hdm05 / "asf/HDM_bd.asf"), read_asf(hdm05 / "asf/HDM_bk.asf")
    made = []
    assert sk.derived("k", lambda: made.append(1) or 7) == 7 and sk.derived("k", lambda: made.append(1) or 8) == 7
    assert len(made) == 1 and other.derived("k", lambda: 9) == 9  # per skeleton object
    # cached derived values equal what they are made from (two performers: no stale value shared)
    assert stature(sk) == stature(sk) != stature(other)
    assert [stature(sk), stature(sk, head_top=False)] == [_stature(sk, True), _stature(sk, False)]  # one key each
    assert sk.rest_height() == sk.derived("rest height", lambda: None) > 0


def test_amc_reads_crlf_latin1_and_keeps_angles_past_360(hdm05):
    raw = (hdm05 / PAST_360).read_bytes()
    assert b"\r\n" in raw and any(b > 127 for b in raw[:200])  # the file really has both quirks
    c = load_clip(hdm05 / PAST_360)
    assert c.fps == 120 and c.label == "depositFloorR" and c.skeleton.name == "HDM_bd"
    rx = c.column("root.rx")
    assert np.abs(rx).max() > 360  # not wrapped
    assert np.abs(np.diff(rx)).max() < 30  # and continuous
    # first frame values are the file's own numbers
    text = raw.decode("latin-1").splitlines()
    first = next(ln for ln in text if ln.startswith("root "))
    assert c.data[0, :6] == pytest.approx([float(v) for v in first.split()[1:]])



def test_amc_frames_read_at_once_are_those_read_line_by_line(hdm05, tmp_path, monkeypatch):
    """HDM05's files take the reader's path that converts all frames at once; a file whose frames
    list their bones in different orders or sets takes the line-by-line one: the same numbers."""
    import shared.io.asf_amc as amc

    files = [hdm05 / SQUAT, hdm05 / PAST_360, *sorted((hdm05 / "amc").glob("*/HDM_dg_*.amc"))[:3]]
    lines = amc._lines(hdm05 / SQUAT)
    skeleton = read_asf(hdm05 / "asf/HDM_bd.asf")
    bone_cols = {j.name: [0] * len(j.dofs) for j in skeleton.joints}
    assert amc._regular_frames(lines, bone_cols, 1) is not None  # the path a regular file takes
    # frame 2's first two bones swapped, frame 3 without its last bone: irregular, read line by line
    at = [i for i, line in enumerate(lines) if line.strip().isdigit()]
    mixed = lines[:at[1] + 1] + [lines[at[1] + 2], lines[at[1] + 1]] + lines[at[1] + 3:at[3] - 1] + lines[at[3]:]
    (tmp_path / "mixed.amc").write_text("\n".join(mixed) + "\n", encoding="latin-1")
    assert amc._regular_frames(amc._lines(tmp_path / "mixed.amc"), bone_cols, 1) is None
    at_once = [load_clip(f) for f in files]
    mixed_clip = load_clip(tmp_path / "mixed.amc", skeleton=hdm05 / "asf/HDM_bd.asf")
    monkeypatch.setattr(amc, "_regular_frames", lambda *args: None)  # the line-by-line reader alone
    for f, clip in zip(files, at_once, strict=True):
        by_line = load_clip(f)
        assert clip.channels == by_line.channels and clip.fps == by_line.fps and clip.label == by_line.label
        assert np.array_equal(clip.data, by_line.data), f.name
    assert np.array_equal(mixed_clip.data[:2], at_once[0].data[:2])
    last = lines[at[3] - 1].split()[0]  # the bone frame 3 lacks is 0 there, as the file says nothing of it
    columns = [i for i, c in enumerate(mixed_clip.channels) if c.startswith(last + ".")]
    assert np.all(mixed_clip.data[2, columns] == 0) and np.any(at_once[0].data[2, columns] != 0)
    assert np.array_equal(np.delete(mixed_clip.data[2], columns), np.delete(at_once[0].data[2], columns))
def test_skeleton_is_found_in_the_usual_layouts(hdm05, tmp_path):
    assert find_skeleton(hdm05 / SQUAT).name == "HDM_bd.asf"  # amc/<class>/x.amc + asf/
    beside = tmp_path / "beside"
    beside.mkdir()
    shutil.copy(hdm05 / "asf/HDM_bk.asf", beside / "07.asf")
    shutil.copy(hdm05 / SQUAT, beside / "07_01.amc")  # CMU naming: 07_01.amc -> 07.asf
    assert find_skeleton(beside / "07_01.amc") == beside / "07.asf"
    sib = tmp_path / "cmu"
    (sib / "asf").mkdir(parents=True)
    (sib / "amc").mkdir()
    shutil.copy(hdm05 / "asf/HDM_bk.asf", sib / "asf" / "07.asf")
    shutil.copy(hdm05 / SQUAT, sib / "amc" / "07_02.amc")
    assert find_skeleton(sib / "amc" / "07_02.amc") == sib / "asf" / "07.asf"
    lonely = tmp_path / "lonely"
    lonely.mkdir()
    shutil.copy(hdm05 / SQUAT, lonely / "x_1.amc")
    with pytest.raises(ClipFormatError, match="--skeleton"):
        load_clip(lonely / "x_1.amc")
    c = load_clip(lonely / "x_1.amc", skeleton=hdm05 / "asf/HDM_dg.asf")  # the override
    assert c.skeleton.name == "HDM_dg"


def test_amc_to_bvh_keeps_every_joint_position(hdm05, tmp_path):
    c = load_clip(hdm05 / SQUAT)
    save_clip(c, tmp_path / "s.bvh")
    b = load_clip(tmp_path / "s.bvh")
    assert b.n_frames == c.n_frames and b.fps == 120
    pa, pb = _positions_by_name(c), _positions_by_name(b)
    err = max(np.abs(pa[n] - pb[n]).max() for n in pa)
    assert err < 1e-5  # metres; the BVH prints 6 decimals of centimetres and degrees


def test_bvh_round_trip_is_exact_to_print_precision(hdm05, tmp_path):
    save_clip(load_clip(hdm05 / SQUAT), tmp_path / "a.bvh")
    a = load_clip(tmp_path / "a.bvh")
    save_clip(a, tmp_path / "b.bvh")
    b = load_clip(tmp_path / "b.bvh")
    assert b.channels == a.channels
    np.testing.assert_allclose(b.data, a.data, atol=5e-7, rtol=0)
    assert (tmp_path / "a.bvh").read_text() == (tmp_path / "b.bvh").read_text()


def test_npz_and_amc_round_trips(hdm05, tmp_path):
    c = load_clip(hdm05 / SQUAT)
    c = c.add_channels(["tau.a", "tau.b"], np.random.default_rng(0).normal(size=(c.n_frames, 2)), "sensor")
    save_clip(c, tmp_path / "c.npz")
    n = load_clip(tmp_path / "c.npz")
    assert np.array_equal(n.data, c.data) and n.channels == c.channels and n.groups == c.groups
    assert n.skeleton == c.skeleton and n.fps == c.fps and n.label == c.label
    m = load_clip(hdm05 / SQUAT)
    save_clip(m, tmp_path / "HDM_bd_x_1.amc")
    back = load_clip(tmp_path / "HDM_bd_x_1.amc", skeleton=hdm05 / "asf/HDM_bd.asf")
    np.testing.assert_allclose(back.data, m.data, atol=1e-6)


def test_resample_keeps_duration_and_values(hdm05):
    c = load_clip(hdm05 / SQUAT)
    r = c.resample(30)
    assert r.fps == 30 and r.duration == pytest.approx(c.duration, abs=1 / 30)
    assert r.n_frames == int(round(c.duration * 30)) + 1
    np.testing.assert_allclose(r.data[::1][: (c.n_frames - 1) // 4 + 1], c.data[::4][: (c.n_frames - 1) // 4 + 1], atol=1e-9)
    with pytest.raises(BadInput):
        c.resample(0)


def test_time_normalised_frames_keep_their_ends_and_are_a_new_array():
    """Frames resampled to n of normalised time: first to first, last to last, a straight line
    stays straight; the same length is a copy (callers may change what they get)."""
    x = np.column_stack([np.linspace(0.0, 9.0, 10), np.linspace(5.0, -4.0, 10)])
    y = time_normalised(x, 4)
    np.testing.assert_allclose(y, [[0, 5], [3, 2], [6, -1], [9, -4]], atol=1e-12)
    same = time_normalised(x, 10)
    assert np.array_equal(same, x) and same is not x
    assert time_normalised(x[:, :1], 7).shape == (7, 1)


@pytest.mark.parametrize(
    "name, content, line, words",
    [
        ("trunc.bvh", "HIERARCHY\nROOT hip\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\nMOTION\n", 5, "end of file"),
        ("badnum.bvh", "HIERARCHY\nROOT hip\n{\nOFFSET 0 zero 0\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n\n", 4, "number"),
        ("count.bvh", "HIERARCHY\nROOT hip\n{\nOFFSET 0 0 0\nCHANNELS 1 Xposition\nEnd Site\n{\nOFFSET 0 1 0\n}\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1\n2 3\n", 15, "values"),
        ("nomotion.bvh", "HIERARCHY\n", None, "MOTION"),
        ("bad.amc", ":FULLY-SPECIFIED\n:DEGREES\n1\nroot 0 0 0 0 0 zero\n", 4, "numbers"),
        ("bone.amc", ":FULLY-SPECIFIED\n1\nnosuchbone 1 2 3\n", 3, "nosuchbone"),
        ("empty.amc", "", None, "no frames"),
        ("nan.amc", "1\nroot 0 0 0 0 0 nan\n", 2, "non-finite"),
        # the numbers are converted at once: a bad one is still traced to its own line
        ("late.amc", "1\nroot 0 0 0 0 0 0\nlfemur 1 2 3\n2\nroot 0 0 0 0 0 0\nlfemur 1 x 3\nrfemur 1 2 3\n", 6, "numbers"),
        ("lateinf.amc", "1\nroot 0 0 0 0 0 0\n2\nroot 0 0 0 0 0 0\nrfemur 1 2 1e999\n", 5, "non-finite"),
        ("count.amc", "1\nroot 0 0 0 0 0 0\nlfemur 1 2\n", 3, "expected 3 numbers"),
        ("order.amc", "1\nroot 0 0 0 0 0 0\n3\n", 3, "frame 3 where frame 2"),
        ("early.amc", ":DEGREES\nroot 0 0 0 0 0 0\n", 2, "before the first frame"),
    ],
)
def test_bad_files_name_file_and_line(hdm05, tmp_path, name, content, line, words):
    p = tmp_path / name
    p.write_text(content)
    with pytest.raises(ClipFormatError) as err:
        load_clip(p, skeleton=hdm05 / "asf/HDM_bd.asf") if name.endswith(".amc") else load_clip(p)
    msg = str(err.value)
    assert str(p) in msg and words in msg
    if line is not None:
        assert err.value.line == line and f"{p}:{line}" in msg


def test_missing_and_unknown_files(tmp_path):
    with pytest.raises(ClipFormatError, match="no such file"):
        load_clip(tmp_path / "nothing.amc")
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(ClipFormatError, match="unknown clip format"):
        load_clip(tmp_path / "x.txt")
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(ClipFormatError, match="NPZ"):
        load_clip(tmp_path / "x.npz")


def test_a_clips_fingerprint_is_its_frames_not_its_name():
    """The key of what is computed from a motion alone: one motion under two names is one
    key; a changed frame, another frame rate or other channels are another."""
    data = np.arange(12.0).reshape(4, 3)
    clip = Clip(data, ["a", "b", "c"], 30.0, name="first")
    assert clip.fingerprint() == Clip(data.copy(), ["a", "b", "c"], 30.0, name="second").fingerprint()
    changed = data.copy()
    changed[2, 1] += 1e-9
    for other in (Clip(changed, ["a", "b", "c"], 30.0), Clip(data, ["a", "b", "c"], 60.0),
                  Clip(data, ["a", "c", "b"], 30.0), Clip(data[:3], ["a", "b", "c"], 30.0)):
        assert other.fingerprint() != clip.fingerprint()


def test_clip_rejects_inconsistent_shapes():
    with pytest.raises(BadInput):
        Clip(np.zeros((3, 2)), ["a"], 30)
    with pytest.raises(BadInput):
        Clip(np.zeros((3, 2)), ["a", "a"], 30)
    with pytest.raises(BadInput):
        Clip(np.zeros((3, 1)), ["a"], 0)


@pytest.mark.parametrize("seq", ["XYZ", "ZYX", "xyz", "zxy", "YXZ"])
def test_euler_matrix_matches_scipy(seq):
    from scipy.spatial.transform import Rotation

    from shared.motion.skeleton import euler_matrix

    angles = np.random.default_rng(len(seq) + ord(seq[0])).uniform(-180, 180, size=3)
    np.testing.assert_allclose(euler_matrix(seq, angles), Rotation.from_euler(seq, angles, degrees=True).as_matrix(),
                               atol=1e-12)


def _npz_variant(src, dst, meta_change=None, data=None):
    import json

    with np.load(src, allow_pickle=False) as z:
        meta, arr = json.loads(str(z["meta"])), np.array(z["data"])
    meta = meta_change(meta) if meta_change else meta
    np.savez_compressed(dst, data=arr if data is None else data, meta=np.array(json.dumps(meta)))
    return dst


@pytest.mark.parametrize("name, change, data, words", [
    ("fps_text", lambda m: dict(m, fps="abc"), None, "'fps' must be a number"),
    ("fps_nan", lambda m: dict(m, fps=float("nan")), None, "not a frame rate"),
    ("meta_list", lambda m: [1, 2], None, "must be a JSON object"),
    ("channels_numbers", lambda m: dict(m, channels=list(range(len(m["channels"])))), None, "channel name must be text"),
    ("groups_list", lambda m: dict(m, groups=[1]), None, "'groups' must be a map"),
    ("data_shape", None, np.zeros((3, 5)), "data of shape (3, 5)"),
    ("skeleton_broken", lambda m: dict(m, skeleton={"joints": "x"}), None, "unreadable skeleton"),
])
def test_npz_with_an_odd_header_is_a_clear_error(bundled, tmp_path, name, change, data, words):
    """Odd NPZ headers were tracebacks."""
    save_clip(load_clip(next(iter(find_clips([bundled / "amc"])))), tmp_path / "ok.npz")
    f = _npz_variant(tmp_path / "ok.npz", tmp_path / f"{name}.npz", change, data)
    with pytest.raises(ClipFormatError) as err:
        load_clip(f)
    assert words in str(err.value) and str(f) in str(err.value)


def test_npz_zip_bomb_is_refused_before_it_is_inflated(tmp_path, monkeypatch):
    import zipfile

    from shared.io import npz

    monkeypatch.setattr(npz, "MAX_DATA_BYTES", 1024 * 1024)
    with zipfile.ZipFile(tmp_path / "bomb.npz", "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("data.npy", b"\0" * (4 * 1024 * 1024))  # 4 MiB of zeros: about 4 KB on disk
        zf.writestr("meta.npy", b"x")
    assert (tmp_path / "bomb.npz").stat().st_size < 64 * 1024
    with pytest.raises(ClipFormatError, match="unpacks to 4194304 bytes, over the limit"):
        load_clip(tmp_path / "bomb.npz")


def test_npz_whose_array_header_declares_more_than_it_holds_is_refused(bundled, tmp_path):
    """numpy allocates what an array's header declares before reading it: a header of a trillion
    elements in a member of a few bytes was a MemoryError traceback."""
    import zipfile

    save_clip(load_clip(next(iter(find_clips([bundled / "amc"])))), tmp_path / "ok.npz")
    with zipfile.ZipFile(tmp_path / "ok.npz") as zin, zipfile.ZipFile(tmp_path / "huge.npz", "w") as zout:
        zout.writestr("meta.npy", zin.read("meta.npy"))
        with zout.open("data.npy", "w") as f:
            np.lib.format.write_array_header_2_0(f, {"descr": "<f8", "fortran_order": False, "shape": (10 ** 6, 10 ** 6)})
            f.write(b"\0" * 64)
    with pytest.raises(ClipFormatError, match=r"'data.npy' declares an array of shape \(1000000, 1000000\)"):
        load_clip(tmp_path / "huge.npz")


def test_a_bvh_nested_deeper_than_any_body_is_a_clear_error(tmp_path):
    """10,000 nested joints were a RecursionError."""
    n = 10_000
    lines = ["HIERARCHY", "ROOT hip", "{", "OFFSET 0 0 0", "CHANNELS 3 Xposition Yposition Zposition"]
    for i in range(n):
        lines += [f"JOINT j{i}", "{", "OFFSET 0 0.01 0", "CHANNELS 1 Zrotation"]
    lines += ["}"] * (n + 1) + ["MOTION", "Frames: 1", "Frame Time: 0.0333", " ".join(["0"] * (3 + n))]
    (tmp_path / "deep.bvh").write_text("\n".join(lines))
    with pytest.raises(ClipFormatError, match="nested deeper than 200"):
        load_clip(tmp_path / "deep.bvh")


def test_a_clip_file_too_large_to_read_whole_is_refused_before_reading(tmp_path):
    from shared.io import MAX_CLIP_FILE_BYTES

    big = tmp_path / "huge.bvh"
    with open(big, "wb") as f:  # sparse: no disk and no memory spent
        f.truncate(MAX_CLIP_FILE_BYTES + 1)
    with pytest.raises(ClipFormatError, match="clip files are read whole, up to 512 MiB"):
        load_clip(big)


def test_skeletons_are_cached_by_content_not_path(hdm05, tmp_path):
    """One read per ASF content: the same file elsewhere (a service receiving it as bytes) is
    the same skeleton; an edited file is read again, never a stale copy."""
    from shared.io import ASF_CACHE_SIZE, load_skeleton

    src = (hdm05 / "asf/HDM_bd.asf").read_text(encoding="latin-1")
    (tmp_path / "a.asf").write_text(src, encoding="latin-1")
    (tmp_path / "b.asf").write_text(src, encoding="latin-1")
    a = load_skeleton(tmp_path / "a.asf")
    assert load_skeleton(tmp_path / "b.asf") is a
    lines = src.splitlines()
    bones = next(i for i, ln in enumerate(lines) if ln.startswith(":bonedata"))
    k = next(i for i, ln in enumerate(lines) if i > bones and ln.strip().startswith("length"))
    lines[k] = "     length 9.0"  # a longer first bone
    (tmp_path / "a.asf").write_text("\n".join(lines) + "\n", encoding="latin-1")
    edited = load_skeleton(tmp_path / "a.asf")
    assert edited is not a and edited.rest_height() != a.rest_height()
    for i in range(ASF_CACHE_SIZE):  # bounded: the first one is read again once others pushed it out
        (tmp_path / f"c{i}.asf").write_text(src + f"# {i}\n", encoding="latin-1")
        load_skeleton(tmp_path / f"c{i}.asf")
    assert load_skeleton(tmp_path / "b.asf") is not a


def test_an_npz_written_part_by_part_reads_back_as_the_stacked_array(tmp_path):
    """savez_stacked writes a Stacked value part by part: np.load reads what np.savez of the
    stacked array would give; a part of another shape is refused."""
    from shared.io.npz import Stacked, savez_stacked

    rng = np.random.default_rng(3)
    parts = [rng.normal(size=(4, 5)) for _ in range(7)]
    with open(tmp_path / "a.npz", "wb") as f:
        savez_stacked(f, {"m": Stacked(parts), "x": np.arange(3), "h": np.array("text")})
    with np.load(tmp_path / "a.npz", allow_pickle=False) as z:
        assert np.array_equal(z["m"], np.stack(parts)) and np.array_equal(z["x"], np.arange(3)) and str(z["h"]) == "text"
    with pytest.raises(ValueError, match="a part of shape"), open(tmp_path / "b.npz", "wb") as f:
        savez_stacked(f, {"m": Stacked(parts + [np.zeros((4, 6))])})
