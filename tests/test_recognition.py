"""Recognition as a user means it: position channels, the decided label, its
confidence, "none of these", old space files, and the compiled forward kinematics."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shared.errors import BadInput
from shared.io import find_clips, load_clip, save_clip
from shared.motion.skeleton import Skeleton
from shared.pss.recognition import Calibration, calibrate, conformal_threshold, decide, softmax_confidence
from shared.pss.space import FORMAT, ProtoSymbolSpace
from shared.reports.evaluation import dtw_recognition, pss_recognition

FORMAT1 = Path(__file__).parent / "data" / "space_format1.npz"  # written by mirrorcoach 0.1 (commit 8906865)


# ---------------------------------------------------------------------------- forward kinematics
def test_compiled_forward_kinematics_equals_the_scipy_reference(dev_clips, tmp_path):
    for c in dev_clips[::40]:
        c = c.resample(30)
        fast = c.skeleton.forward_kinematics(c.data, c.channels)
        ref = c.skeleton.forward_kinematics_reference(c.data, c.channels)
        assert fast.shape == ref.shape and np.abs(fast - ref).max() < 1e-9
        values = {ch: c.data[:, i] for i, ch in enumerate(c.channels)}
        ref_local = np.stack([r.as_matrix() for r in c.skeleton.local_rotations(values, c.n_frames)], axis=1)
        assert np.abs(c.skeleton.local_matrices(c.data, c.channels) - ref_local).max() < 1e-12
        assert np.abs(c.skeleton.root_matrices(c.data, c.channels)
                      - c.skeleton.global_root_rotation(c.data, c.channels).as_matrix()).max() < 1e-12
    # BVH: intrinsic upper-case Euler orders and no ASF axis pre-rotation
    save_clip(dev_clips[0], tmp_path / "a.bvh")
    b = load_clip(tmp_path / "a.bvh")
    assert b.skeleton.joints[1].euler.isupper()
    assert np.abs(b.positions() - b.skeleton.forward_kinematics_reference(b.data, b.channels)).max() < 1e-9


def test_a_skeleton_out_of_order_is_refused_not_computed(dev_clips):
    sk = Skeleton.from_json(dev_clips[0].skeleton.to_json())
    sk.joints[3].parent = 7  # a joint before its parent (or a cycle): the compiled loop must never see it
    with pytest.raises(BadInput, match="after its parent"):
        sk.forward_kinematics(dev_clips[0].data, dev_clips[0].channels)


# ---------------------------------------------------------------------------- position channels
def _moved(clip, yaw_deg: float, shift_m: float):
    """The same motion performed elsewhere in the room, facing elsewhere."""
    sk = clip.skeleton
    root = sk.root
    rot = sk.global_root_rotation(clip.data, clip.channels)
    turn = Rotation.from_euler("y", yaw_deg, degrees=True)
    pre = Rotation.from_matrix(root.pre)
    local = pre.inv() * (turn * rot) * pre
    ang = local.as_euler(root.euler, degrees=True)
    data = clip.data.copy()
    for k, ax in enumerate(root.euler.lower()):
        data[:, clip.channels.index(f"{root.name}.r{ax}")] = np.rad2deg(np.unwrap(np.deg2rad(ang[:, k])))
    t = np.column_stack([clip.column(f"{root.name}.t{a}") for a in "xyz"])
    t = turn.apply(t) + np.array([shift_m / sk.unit_m, 0.0, 0.0])
    for k, a in enumerate("xyz"):
        data[:, clip.channels.index(f"{root.name}.t{a}")] = t[:, k]
    return clip.with_data(data, name=clip.name + "-moved")


def test_position_channels_do_not_depend_on_where_a_person_stands_or_faces(dev_space, dev_split):
    f = dev_space.features
    pos = f.feature_indices("position")
    assert len(pos) > 0 and set(pos).isdisjoint(f.feature_indices("motion"))
    c = dev_split[1][0].resample(30)
    moved = _moved(c, yaw_deg=90.0, shift_m=1.0)
    assert np.abs(moved.positions() - c.positions()).max() > 0.5  # really elsewhere in the room
    assert np.abs(f.encode(moved)[:, pos] - f.encode(c)[:, pos]).max() < 1e-6
    a, b = dev_space.recognize(c), dev_space.recognize(moved)
    assert a.nearest_label == b.nearest_label and np.allclose(a.recognition_distances, b.recognition_distances, rtol=1e-4)


def test_generation_reads_the_motion_channels_and_ignores_the_position_group(dev_space):
    clip = dev_space.generate(dev_space.points[0])
    assert clip.channels == dev_space.features.motion_channels and np.all(np.isfinite(clip.data))


# ---------------------------------------------------------------------------- the label
def test_unseen_actor_is_recognised_next_to_dtw(dev_space, dev_split, capsys):
    train, test = dev_split
    ours = pss_recognition(dev_space, test)
    dtw = dtw_recognition(dev_space, train, test)
    n = len(test)
    with capsys.disabled():
        print(f"\nrecognition bd+bk -> dg, {n} clips: PSS {ours.accuracy:.3f} ({1e3 * ours.seconds_per_clip:.1f} ms/clip), "
              f"1-NN DTW on positions {dtw.accuracy:.3f}")
    assert len(ours.per_class) == 11
    assert ours.accuracy >= 0.95
    assert round(ours.accuracy * n) >= round(dtw.accuracy * n) - 1  # never below the peer by more than one clip


def test_recognition_gives_a_calibrated_confidence_and_names_the_label(dev_space, dev_split):
    cal = dev_space.calibration
    assert cal.scheme == "across performers" and cal.temperature > 0 and cal.n_calibration > 100
    recs = [dev_space.recognize(c) for c in dev_split[1][:12]]
    for r in recs:
        assert 0.0 <= r.confidence <= 1.0
        assert r.label in (None, r.nearest_label)
        assert r.nearest[0][1] == r.nearest_label
    # a generated half squat, half kick is less certain than the real clips are
    a, b = dev_space.symbol("HDM_bd_squat1Reps_001_120"), dev_space.symbol("HDM_bd_kickLFront1Reps_001_120")
    mid = dev_space.recognize(dev_space.generate(weights=dev_space.mix_weights({dev_space.names[a]: 0.5,
                                                                                dev_space.names[b]: 0.5})))
    assert mid.confidence < np.median([r.confidence for r in recs])


def test_a_motion_of_no_known_class_comes_back_as_none_of_these(dev_space, dev_split):
    c = dev_split[1][0].resample(30)
    rng = np.random.default_rng(3)
    data = c.data.copy()
    angles = [i for i, ch in enumerate(c.channels) if ch.split(".")[-1].startswith("r") and not ch.startswith("root")]
    walk = np.cumsum(rng.normal(0.0, 6.0, size=(c.n_frames, len(angles))), axis=0)  # flailing: no class of HDM05
    data[:, angles] += walk
    r = dev_space.recognize(c.with_data(data, name="flail"))
    assert r.label is None and r.novelty > 1.0 and r.nearest_label
    # the confidence falls with it: at most how often the space's known motions look this unusual
    assert r.confidence <= r.decision.credibility <= 0.05
    from shared.cli.app import recognition_text
    from shared.pss.recognition import rejected_by

    tests = rejected_by(r.decision)
    assert tests and set(tests) <= {"distance", "ratio", "model"}
    text = recognition_text({"known": False, "nearest_label": r.nearest_label, "novelty": r.novelty, "point": r.point,
                             "nearest": [], "rejected_by": tests})
    assert text.startswith("none of these: ") and f"(novelty {r.novelty:.2f} > 1)" in text


def test_none_of_these_names_the_test_that_rejected():
    from shared.cli.app import recognition_text
    from shared.pss.recognition import Decision, rejected_by

    d = Decision(None, "squat", 0.6, 1.4, distance_novelty=0.7, model_novelty=1.4, ratio_novelty=1.1)
    assert rejected_by(d) == ["ratio", "model"]
    assert rejected_by(Decision("squat", "squat", 0.9, 0.8, 0.8, 0.2, 0.5)) == []
    base = {"known": False, "nearest_label": "squat", "novelty": 1.4, "point": [0.0, 0.0, 0.0], "nearest": []}
    says = {"distance": "farther from its nearest class (squat)", "ratio": "not clearly nearer to squat than to the next",
            "model": "novelty model finds it between"}
    for test, words in says.items():
        text = recognition_text({**base, "rejected_by": [test]})
        assert words in text and all(w not in text for t, w in says.items() if t != test), text
    assert "farther from every class" in recognition_text(base)  # a service that does not say which


def test_open_set_rule_as_documented():
    d = np.array([[0, 1, 9, 9], [1, 0, 9, 9], [9, 9, 0, 1], [9, 9, 1, 0]], float)
    cal = calibrate(d, ["a", "a", "b", "b"], ["p", "q", "p", "q"])
    assert cal.scheme == "across performers" and cal.threshold == np.inf  # 2 per class: too few to reject
    assert conformal_threshold(np.arange(1, 100), 0.98) == 98.0  # ceil(100 * 0.98) = 98th smallest
    c = Calibration(["a", "b"], 1.0, threshold=2.0, ratio_threshold=0.5, n_calibration=100, scheme="across performers")
    assert decide(np.array([1.0, 5.0]), ["a", "b"], c).label == "a"
    far = decide(np.array([3.0, 9.0]), ["a", "b"], c)
    assert far.label is None and far.nearest_label == "a" and far.novelty == pytest.approx(1.5)
    between = decide(np.array([1.0, 1.2]), ["a", "b"], c)  # not clearly nearer one class than the other
    assert between.label is None and between.novelty == pytest.approx(1.0 / 1.2 / 0.5)


def test_a_rejected_motion_keeps_at_most_its_credibility_as_confidence(dev_space, tmp_path):
    """A motion the open set rejects has as confidence at most its credibility, the conformal
    p-value of the test that rejects it (at most 1 - the level there); an accepted motion keeps
    the softmax; a calibration written before the scores decides its confidence as before."""
    import dataclasses

    from shared.pss.recognition import conformal_p_value

    scores = np.random.default_rng(0).uniform(0.0, 1.0, 99)
    for s in (-1.0, 0.3, 0.99, 2.0):
        assert conformal_p_value(scores, s) == (1 + np.sum(scores >= s)) / 100
        assert conformal_p_value(scores, s, larger_is_unusual=False) == (1 + np.sum(scores <= s)) / 100
    q = 0.98
    t = conformal_threshold(scores, q)
    assert conformal_p_value(scores, t + 1e-9) <= 1 - q + 1e-12 and conformal_p_value([], 5.0) == 1.0
    c = Calibration(["a", "b"], 1.0, threshold=t, ratio_threshold=np.inf, n_calibration=99, scheme="across performers",
                    scores=[float(v) for v in scores])
    near = np.array([0.5 * t, 5.0])
    ok = decide(near, ["a", "b"], c)
    assert ok.label == "a" and ok.confidence == pytest.approx(softmax_confidence(near, 1.0)[0])
    farther = np.array([1.5 * t, 50.0])  # past a's threshold, and far from b: the softmax alone says a
    assert softmax_confidence(farther, 1.0)[0] > 0.99
    far = decide(farther, ["a", "b"], c)
    assert far.label is None and far.confidence == far.credibility == pytest.approx(1 / 100)
    assert decide(farther, ["a", "b"], dataclasses.replace(c, scores=None)).confidence > 0.99
    # the space keeps the distance rule's scores in its file
    assert dev_space.calibration.scores and len(dev_space.calibration.scores) == dev_space.calibration.n_calibration
    back = ProtoSymbolSpace.load(dev_space.save(tmp_path / "s.npz"))
    assert back.calibration.scores == pytest.approx(dev_space.calibration.scores)


def test_the_distance_test_scales_each_class_by_its_own_spread_across_performers():
    """A class whose performers differ much (a) tolerates a farther motion than one whose
    performers agree (b): the nearest class's distance is divided by that class's median
    cross-performer distance before the threshold (normalised conformal scores)."""
    rng = np.random.default_rng(3)
    where = {("a", "p"): 0.0, ("a", "q"): 2.0, ("b", "p"): 100.0, ("b", "q"): 100.5}
    x, labels, perf = [], [], []
    for (c, who), centre in where.items():
        x += list(centre + rng.uniform(-0.01, 0.01, 30))
        labels += [c] * 30
        perf += [who] * 30
    x = np.array(x)
    cal = calibrate(np.abs(x[:, None] - x[None]), labels, perf)
    assert cal.class_scales == pytest.approx([2.0, 0.5], abs=0.03)
    assert cal.threshold == pytest.approx(1.0, abs=0.03)
    near_a = decide(np.abs(3.5 - x), labels, cal)  # 1.5 beyond a's farther performer: 0.75 of a's spread
    near_b = decide(np.abs(102.0 - x), labels, cal)  # 1.5 beyond b's: three times b's spread
    assert near_a.label == "a" and near_a.distance_novelty == pytest.approx(0.75, abs=0.03)
    assert near_b.label is None and near_b.nearest_label == "b" and near_b.distance_novelty == pytest.approx(3.0, abs=0.1)
    # a calibration written before the class scales keeps its raw threshold
    old = Calibration(cal.classes, cal.temperature, 1.0, cal.ratio_threshold, cal.n_calibration, cal.scheme)
    assert decide(np.abs(3.5 - x), labels, old).label is None


def test_a_space_file_written_before_the_class_spreads_keeps_its_raw_threshold(dev_space, dev_split, tmp_path):
    clip = dev_split[1][0]
    assert dev_space.calibration.class_scales and "one spread" not in dev_space.info()["open_set"]
    with np.load(dev_space.save(tmp_path / "s.npz"), allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    header = json.loads(str(arrays["header"]))
    del header["calibration"]["class_scales"]
    del header["discriminant"]  # (nor the discriminant ratio: its ratio test is on eq. 2.4 distances)
    arrays = {k: v for k, v in arrays.items() if not k.startswith("discriminant_")}
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "old.npz", **arrays)
    old = ProtoSymbolSpace.load(tmp_path / "old.npz")
    assert old.calibration.class_scales is None and "one spread for all classes" in old.info()["open_set"]
    del header["novelty"]  # the oldest file: its summary names every rule it lacks, and still fits the contract
    np.savez(tmp_path / "oldest.npz", **{**{k: v for k, v in arrays.items() if not k.startswith("novelty_")},
                                         "header": np.array(json.dumps(header))})
    from schemas.pss import INFO_EP
    from services.pss.service import space_info

    oldest = space_info("oldest", ProtoSymbolSpace.load(tmp_path / "oldest.npz"))
    assert "without the novelty model" in oldest["open_set"] and INFO_EP.reply.validate(oldest)["open_set"] == oldest["open_set"]
    from shared.pss.recognition import class_distances

    r = old.recognize(clip)
    c = old.calibration
    first, second = np.sort(class_distances(np.asarray(r.recognition_distances), np.asarray(old.labels), c.classes))[:2]
    raw = max(first / c.threshold, first / second / c.ratio_threshold)  # the rule as written: no class scale
    assert r.decision.distance_novelty == pytest.approx(raw)
    k = c.classes.index(r.nearest_label)
    scaled = max(first / dev_space.calibration.class_scales[k] / c.threshold, first / second / c.ratio_threshold)
    assert abs(scaled - raw) > 1e-6  # (the new rule would have said something else)
    # a damaged calibration (class spreads that do not match its classes, an unknown field): a clear error
    for bad in ({**header["calibration"], "class_scales": [1.0]}, {**header["calibration"], "colour": 1}):
        arrays["header"] = np.array(json.dumps({**header, "calibration": bad}))
        np.savez(tmp_path / "bad.npz", **arrays)
        with pytest.raises(BadInput, match="calibration is unreadable"):
            ProtoSymbolSpace.load(tmp_path / "bad.npz")


def test_a_space_of_one_clip_per_motion_gets_the_one_example_pose_floor_by_default(bundled):
    """``default_pose_floor`` (what ``offline build`` and ``space build`` give a space when no floor
    is asked for): the one-example floor when most motions hold one clip, else none; with it every
    pose output of every proto-symbol is compared at the ceiling, the travel velocities as trained."""
    from shared.pss.space import ONE_EXAMPLE_POSE_FLOOR, RECOGNITION_VAR_CEILING, default_pose_floor
    from shared.pss.symbol import pose_indices

    assert default_pose_floor(["a", "b", "c"]) == ONE_EXAMPLE_POSE_FLOOR
    assert default_pose_floor(["a", "a", "b", "c", "d"]) == ONE_EXAMPLE_POSE_FLOOR  # most hold one
    assert default_pose_floor(["a", "a", "b", "b", "c"]) is None
    assert default_pose_floor([]) is None
    firsts = [load_clip(next(iter(find_clips([d])))) for d in sorted((bundled / "amc").iterdir()) if d.is_dir()]
    floor = default_pose_floor([c.label for c in firsts])
    assert floor == ONE_EXAMPLE_POSE_FLOOR >= RECOGNITION_VAR_CEILING
    space = ProtoSymbolSpace.build(firsts, pose_floor=floor)
    f = space.features
    rg = f.group_indices(space.recognition_groups)
    pose = np.isin(rg, pose_indices(f))
    seen = np.stack([m.covars for m in space.recognition_models()])
    assert np.all(seen[:, :, pose] == RECOGNITION_VAR_CEILING)
    assert seen[:, :, ~pose].min() < RECOGNITION_VAR_CEILING


def test_a_space_of_one_clip_per_motion_borrows_its_confidence_temperature(bundled):
    """A space whose motions hold one clip each (one of them two) has two rows to fit a temperature
    on; fitted on them it read 0.9995 on its wrong labels. It takes ``ONE_EXAMPLE_TEMPERATURE`` times
    its median distance instead, and its wrong labels read less sure than its right ones. Its open
    set cannot reject (nothing to calibrate on), and its summary says so."""
    from shared.pss.recognition import ONE_EXAMPLE_TEMPERATURE, can_reject
    from shared.pss.space import default_pose_floor, performer

    clips = [load_clip(f) for f in find_clips([bundled / "amc"])]
    wrong, right = [], []
    for who in ("HDM_bd", "HDM_bk"):
        mine = [c for c in clips if performer(c) == who]
        firsts = list({c.label: c for c in reversed(mine)}.values())
        extra = next(c for c in mine if all(c is not f for f in firsts))
        chosen = [*firsts, extra]
        space = ProtoSymbolSpace.build(chosen, pose_floor=default_pose_floor([c.label for c in chosen]))
        cal = space.calibration
        median = np.median(space.recognition_matrix[np.triu_indices(len(space.symbols), 1)])
        assert cal.scheme == "one proto-symbol per motion" and cal.n_calibration == 2
        assert not can_reject(cal, space.discriminant, space.novelty_model)
        info = space.info()
        assert info["rejects"] is False and "it never rejects: 2 known motions to calibrate on, too few" in info["open_set"]
        assert cal.temperature == pytest.approx(ONE_EXAMPLE_TEMPERATURE * median)
        for c in (c for c in clips if performer(c) != who):
            r = space.recognize(c)
            (right if r.nearest_label == c.label else wrong).append(r.confidence)
    assert wrong and right and max(wrong) < 0.9 and np.mean(wrong) < np.mean(right)


# ---------------------------------------------------------------------------- files of 0.1
def test_a_space_file_of_format_1_still_loads_generates_and_recognises(bundled, tmp_path):
    space = ProtoSymbolSpace.load(FORMAT1)
    assert space.format == "mirrorcoach.space/1" and not space.features.has_position
    assert "format 1" in space.info()["recognition"]
    squat = next(load_clip(f) for f in find_clips([bundled / "amc" / "squat1Reps"]) if "_dg_" in f.name)
    r = space.recognize(squat)
    assert r.nearest_label == "squat1Reps" and r.label == "squat1Reps"  # 16 clips: too few to ever reject
    assert np.all(np.isfinite(space.generate(space.points[0]).data))
    # saved again, it keeps its format (it has no position channels) and loads back identically
    back = ProtoSymbolSpace.load(space.save(tmp_path / "again.npz"))
    assert back.format == "mirrorcoach.space/1" and np.array_equal(back.points, space.points)
    assert back.recognize(squat).nearest_label == "squat1Reps"


def test_a_space_file_of_an_unknown_format_is_a_clear_error(tmp_path):
    with np.load(FORMAT1, allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    header = json.loads(str(arrays["header"]))
    header["format"] = "mirrorcoach.space/9"
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "future.npz", **arrays)
    with pytest.raises(BadInput, match="unknown space format 'mirrorcoach.space/9'.*reads"):
        ProtoSymbolSpace.load(tmp_path / "future.npz")
    shutil.copy(FORMAT1, tmp_path / "copy.npz")
    assert ProtoSymbolSpace.load(tmp_path / "copy.npz").format != FORMAT


def test_a_space_file_with_a_damaged_header_is_a_clear_error(tmp_path):
    """A header missing a field or holding one of the wrong kind is refused as an unreadable space
    file (a missing name ended in a KeyError traceback)."""
    with np.load(FORMAT1, allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    header = json.loads(str(arrays["header"]))
    for k, (key, value) in enumerate((("name", None), ("params", "x"), ("symbols", [{}]), ("embedding", 3))):
        damaged = dict(header)
        if value is None:
            damaged.pop(key)
        else:
            damaged[key] = value
        np.savez(tmp_path / f"damaged{k}.npz", **{**arrays, "header": np.array(json.dumps(damaged))})
        with pytest.raises(BadInput, match=f"damaged{k}.npz: not a readable space file .*build the space again"):
            ProtoSymbolSpace.load(tmp_path / f"damaged{k}.npz")


def _with_member(src: Path, dst: Path, name: str, write, compression: int = 0) -> Path:
    """``src``'s archive with member ``name`` written by ``write(file)`` instead."""
    import zipfile

    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", compression) as zout:
        for info in zin.infolist():
            if info.filename != name:
                zout.writestr(info.filename, zin.read(info.filename))
        with zout.open(name, "w", force_zip64=True) as f:
            write(f)
    return dst


def test_a_space_file_that_would_inflate_beyond_memory_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """An array header declaring a trillion elements in a member of a few bytes made numpy ask for
    7 TiB (a MemoryError traceback from `offline recognize`); a deflated member over the space's
    limit, or an array of Python objects, is refused as well, each before numpy reads it."""
    from shared.pss import spacefile

    def header_of(shape, descr="<f8"):
        def write(f):
            np.lib.format.write_array_header_2_0(f, {"descr": descr, "fortran_order": False, "shape": shape})
            f.write(b"\0" * 64)
        return write

    huge = _with_member(FORMAT1, tmp_path / "huge.npz", "means.npy", header_of((10 ** 12,)))
    with pytest.raises(BadInput, match=r"huge.npz: not a readable space file \(member 'means.npy' declares an array "
                                       r"of shape \(1000000000000,\) \(8000000000000 bytes\) but holds 64 bytes"):
        ProtoSymbolSpace.load(huge)
    objects = _with_member(FORMAT1, tmp_path / "objects.npz", "points.npy", header_of((8,), "|O"))
    with pytest.raises(BadInput, match="objects.npz: .*'points.npy' holds Python objects"):
        ProtoSymbolSpace.load(objects)
    monkeypatch.setattr(spacefile, "MAX_SPACE_BYTES", 8 * 1024 * 1024)
    zeros = np.zeros(2 * 1024 * 1024)  # 16 MiB of zeros: a few KB deflated
    bomb = _with_member(FORMAT1, tmp_path / "bomb.npz", "distances.npy", lambda f: np.lib.format.write_array(f, zeros),
                        compression=8)
    assert bomb.stat().st_size < FORMAT1.stat().st_size + 64 * 1024
    with pytest.raises(BadInput, match=r"bomb.npz: .*unpack to \d+ bytes, over the limit of 8388608 bytes"):
        ProtoSymbolSpace.load(bomb)
    shutil.copy(FORMAT1, tmp_path / "fine.npz")  # under the limit: read as before
    assert len(ProtoSymbolSpace.load(tmp_path / "fine.npz").symbols) > 0


def test_channel_weights_are_saved_with_the_space_and_older_files_recognise_unweighted(dev_space, dev_split, tmp_path):
    from shared.pss.distance import ModelBank

    w = dev_space.recognition_weights
    assert w is not None and w.shape == (len(dev_space.features.group_indices(("position",))),)
    assert np.isfinite(w).all() and w.min() >= 0 and w.max() > 1.5 * w.min()  # the channels are not all alike
    clip = dev_split[1][0]
    r = dev_space.recognize(clip)
    back = ProtoSymbolSpace.load(dev_space.save(tmp_path / "w.npz"))
    assert np.array_equal(back.recognition_weights, w)
    assert np.allclose(back.recognize(clip).recognition_distances, r.recognition_distances)
    # a format-2 file written before the weights: recognised with eq. 2.4 unweighted, as when it was written
    with np.load(tmp_path / "w.npz", allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files if k != "recognition_weights"}
    np.savez(tmp_path / "old.npz", **arrays)
    old = ProtoSymbolSpace.load(tmp_path / "old.npz")
    assert np.all(old.recognition_weights == 1.0)
    idx = old.features.group_indices(("position",))
    hmm = old.as_recognised(old.abstract(clip).marginal(idx))
    assert np.allclose(old.recognize(clip).recognition_distances, ModelBank(old.recognition_models()).distances(hmm))


# ---------------------------------------------------------------------------- the novelty model (open set)
def _synthetic_classes(rng, classes=3, performers=2, n=10, dim=20, shift=0.3):
    centres = rng.normal(0.0, 3.0, size=(classes + 1, dim))
    centres[-1] = centres[:2].mean(axis=0)  # the last class is never learnt: it lies between two known ones
    style = rng.normal(0.0, shift, size=(performers + 1, dim))  # the last performer is never seen

    def sample(c, p, k):
        return centres[c] + style[p] + rng.normal(0.0, 0.5, size=(k, dim))

    x = np.vstack([sample(c, p, n) for c in range(classes) for p in range(performers)])
    labels = [f"c{c}" for c in range(classes) for p in range(performers) for _ in range(n)]
    perf = [f"p{p}" for c in range(classes) for p in range(performers) for _ in range(n)]
    return x, labels, perf, sample


def test_novelty_model_as_documented():
    from shared.pss.novelty import NoveltyModel, _margins, _ridge

    rng = np.random.default_rng(0)
    x, labels, perf, sample = _synthetic_classes(rng)
    m = NoveltyModel.fit(x, labels, perf)
    assert m.scheme == "across performers" and len(m.scores) == len(x) and 0 < m.threshold < np.inf
    assert m.threshold == pytest.approx(-conformal_threshold(-np.array(m.scores), m.quantile))
    # the kept arrays give scikit-learn's own decision (the reference) without importing it
    scaler, ridge = _ridge(x, np.array(labels))
    new = sample(0, 2, 50)
    assert np.allclose(m.margins(new), _margins(ridge.decision_function(scaler.transform(new))), atol=1e-6)
    # a known class from an unseen performer stays known; a class never learnt, between known ones,
    # is "none of these" (far from every class is the distance rule's to catch: a linear model extrapolates)
    known = np.array([m.novelty(v) for c in range(3) for v in sample(c, 2, 30)])
    unknown = np.array([m.novelty(v) for v in sample(3, 2, 30)])
    assert (known > 1).mean() <= 0.1 and (unknown > 1).mean() >= 0.9
    # one performer: calibrated leave-one-out; 30 margins are too few for the default level (a
    # 97 % bound needs 32: it never rejects) and enough for 95 %; one class: nothing to tell apart
    solo = [i for i, p in enumerate(perf) if p == "p0"]
    m1 = NoveltyModel.fit(x[solo], [labels[i] for i in solo], None)
    assert m1.scheme == "leave one out" and len(m1.scores) == len(solo) == 30 and m1.threshold == -np.inf
    assert m1.novelty(sample(3, 2, 1)[0]) == 0.0
    m95 = NoveltyModel.fit(x[solo], [labels[i] for i in solo], None, quantile=0.95)
    assert np.isfinite(m95.threshold) and m95.threshold == pytest.approx(-conformal_threshold(-np.array(m95.scores), 0.95))
    assert NoveltyModel.fit(x[:10], labels[:10], perf[:10]) is None
    # two classes: one calibration margin per proto-symbol (a two-class ridge scores a vector)
    two = [i for i, lab in enumerate(labels) if lab in ("c0", "c1")]
    m2 = NoveltyModel.fit(x[two], [labels[i] for i in two], [perf[i] for i in two])
    assert len(m2.scores) == len(two) and np.isfinite(m2.threshold)
    # decide: either test rejects (the distance rule's thresholds here never do)
    c = Calibration(["c0", "c1", "c2"], 1.0, threshold=np.inf, ratio_threshold=np.inf, n_calibration=0,
                    scheme="across performers")
    d = np.array([1.0, 5.0, 5.0])
    assert decide(d, ["c0", "c1", "c2"], c, m, sample(0, 2, 1)[0]).label == "c0"
    out = decide(d, ["c0", "c1", "c2"], c, m, sample(3, 2, 1)[0])
    assert out.label is None and out.nearest_label == "c0" and out.novelty > 1


def test_the_novelty_model_is_saved_with_the_space_and_older_files_keep_their_rule(dev_space, dev_split, tmp_path):
    m = dev_space.novelty_model
    assert m is not None and m.scheme == "across performers" and sorted(m.classes) == sorted(set(dev_space.labels))
    clips = dev_split[1][:6]
    before = [dev_space.recognize(c) for c in clips]
    back = ProtoSymbolSpace.load(dev_space.save(tmp_path / "n.npz"))
    assert np.array_equal(back.novelty_model.coef, m.coef) and back.novelty_model.threshold == m.threshold
    assert [back.recognize(c).novelty for c in clips] == pytest.approx([r.novelty for r in before])
    # a file written before the model: its open set is the distance rule it was written with
    with np.load(tmp_path / "n.npz", allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files if not k.startswith(("novelty_", "discriminant_"))}
    header = json.loads(str(arrays["header"]))
    header.pop("discriminant")  # written before the novelty model, so before the discriminant ratio too
    broken = {**header, "novelty": {"classes": ["x"]}}  # a novelty header without its threshold: a clear error
    with np.load(tmp_path / "n.npz", allow_pickle=False) as z:
        np.savez(tmp_path / "broken.npz", **{**{k: np.array(z[k]) for k in z.files},
                                              "header": np.array(json.dumps(broken))})
    with pytest.raises(BadInput, match="novelty model is unreadable"):
        ProtoSymbolSpace.load(tmp_path / "broken.npz")
    header.pop("novelty")
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "old.npz", **arrays)
    old = ProtoSymbolSpace.load(tmp_path / "old.npz")
    assert old.novelty_model is None
    for c in clips:
        r = old.recognize(c)
        assert r.novelty == pytest.approx(decide(r.recognition_distances, old.labels, old.calibration).novelty)


# ---------------------------------------------------------------------------- the discriminant ratio (open set)
def test_the_discriminant_ratio_is_scikit_learns_shrinkage_lda(dev_space):
    """The projection solved in the proto-symbols' span gives the class-mean distances of
    scikit-learn's LDA with the same shrunk covariance (the reference: squared distances differ
    between classes as twice its decision values do; on a slice of the real features so that
    scikit-learn's full covariance stays quick), on features over their within-class spread."""
    from sklearn.covariance import ShrunkCovariance
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

    from shared.pss.recognition import DiscriminantRatio

    x = dev_space._symbol_features()[:, ::8]
    y = np.array(dev_space.labels)
    m = DiscriminantRatio.fit(x, y, dev_space.performers)
    assert 0 < m.shrinkage < 1 and m.projection.shape == (x.shape[1], len(set(y)) - 1)
    within = x - np.stack([x[y == c].mean(axis=0) for c in m.classes])[np.searchsorted(m.classes, y)]
    varies = within.std(axis=0) > 1e-6 * x.std(axis=0).max()
    assert varies.mean() > 0.5 and np.allclose(m.scale[varies], within.std(axis=0)[varies])
    assert np.allclose(m.scale[~varies], np.where(x.std(axis=0) > 1e-12, x.std(axis=0), 1.0)[~varies])
    scaled = (x - m.mean) / m.scale
    lda = LinearDiscriminantAnalysis(solver="lsqr", covariance_estimator=ShrunkCovariance(shrinkage=m.shrinkage))
    lda.fit(scaled, y)  # priors: the class shares, so its covariance is the pooled within-class one
    assert list(lda.classes_) == m.classes
    decision = lda.decision_function(scaled) - np.log(lda.priors_)  # equal priors, as the class means are compared
    d2 = np.stack([m.class_distances(v, m.classes) for v in x]) ** 2
    assert np.allclose(d2 - d2[:, :1], -2 * (decision - decision[:, :1]), rtol=1e-4, atol=1e-6 * np.abs(d2).max())


def test_discriminant_ratio_as_documented():
    from shared.pss.recognition import DiscriminantRatio

    rng = np.random.default_rng(1)
    x, labels, perf, sample = _synthetic_classes(rng, n=20)
    m = DiscriminantRatio.fit(x, labels, perf)
    assert m.scheme == "across performers" and len(m.scores) == len(x) and 0 < m.threshold < 1
    assert m.threshold == pytest.approx(conformal_threshold(m.scores, m.quantile))
    # a known class from an unseen performer stays known; a class never learnt, between two
    # known ones, is "none of these"
    known = np.array([m.novelty(v) for c in range(3) for v in sample(c, 2, 30)])
    unknown = np.array([m.novelty(v) for v in sample(3, 2, 30)])
    assert (known > 1).mean() <= 0.1 and (unknown > 1).mean() >= 0.9
    # one performer: a five-fold cross-fit; one class: nothing to tell apart; too few scores: never rejects
    solo = [i for i, p in enumerate(perf) if p == "p0"]
    m1 = DiscriminantRatio.fit(x[solo], [labels[i] for i in solo], None)
    assert m1.scheme == "5-fold cross-fit" and len(m1.scores) == len(solo) and np.isfinite(m1.threshold)
    assert DiscriminantRatio.fit(x[:20], labels[:20], perf[:20]) is None
    few = DiscriminantRatio.fit(x[::4], labels[::4], perf[::4])  # 15 calibration scores for a 98 % bound
    assert few.threshold == np.inf and few.novelty(sample(3, 2, 1)[0]) == 0.0
    # decide: with a discriminant ratio, the ratio test is its, not eq. 2.4's
    c = Calibration(["c0", "c1", "c2"], 1.0, threshold=np.inf, ratio_threshold=0.5, n_calibration=100,
                    scheme="across performers")
    d = np.array([1.0, 1.2, 5.0])  # eq. 2.4 says: not clearly nearer c0 than c1
    assert decide(d, ["c0", "c1", "c2"], c).label is None
    inside = decide(d, ["c0", "c1", "c2"], c, None, sample(0, 2, 1)[0], m)
    assert inside.label == "c0" and inside.distance_novelty == 0.0 and 0 < inside.ratio_novelty < 1
    between = decide(d, ["c0", "c1", "c2"], c, None, sample(3, 2, 1)[0], m)
    assert between.label is None and between.ratio_novelty > 1 and between.novelty == between.ratio_novelty
    # the label: eq. 2.4's nearest class unless the discriminant, every class holding 2 or more
    # proto-symbols, puts the motion nearer another class's mean by more than eq. 2.4 separates them
    assert m.smallest_class == 40
    c1 = sample(1, 2, 1)[0]
    near = np.array([1.0, 1.05, 5.0])  # eq. 2.4: c0 barely before c1
    de = m.class_distances(c1, c.classes)
    assert de.argmin() == 1 and de[0] / de[1] > 1.05
    moved = decide(near, ["c0", "c1", "c2"], c, None, c1, m)
    assert moved.nearest_label == "c1"
    assert decide(near, ["c0", "c1", "c2"], c, None, c1, dataclasses.replace(m, smallest_class=1)).nearest_label == "c0"
    alone = decide(near, ["c0", "c1", "c2"], c)
    assert alone.nearest_label == "c0"
    # the confidence is the label's: the largest share (eq. 2.4's softmax gave c1 less than c0's)
    assert moved.confidence > 1 / 3 and moved.confidence > softmax_confidence(near, 1.0)[1]
    assert alone.confidence == pytest.approx(softmax_confidence(near, 1.0)[0])


def test_the_label_weighs_eq_2_4_and_the_discriminant_as_documented():
    from shared.pss.recognition import nearest_class

    dc, de = np.array([1.0, 1.1, 3.0]), np.array([3.0, 1.0, 2.0])
    assert nearest_class(dc, de, 0.0) == 0 and nearest_class(dc, de, 1.0) == 1  # 1 + 3 against 1.1 + 1
    assert nearest_class(dc, np.array([2.0, 1.0, 1.5]), 0.05) == 0  # 1 + 0.1 against 1.1 + 0.05
    assert nearest_class(2.0 * dc, 10.0 * de, 1.0) == nearest_class(dc, de, 1.0)  # neither scale counts
    assert nearest_class(np.array([0.0, 1.0]), np.array([2.0, 1.0])) == 0  # a motion on a proto-symbol
    assert nearest_class(np.array([1.0, np.inf]), np.array([1.0, np.inf])) == 0  # a class the space lacks


def test_the_confidence_reads_the_labels_score_in_eq_2_4_units():
    from shared.pss.confidence import label_distances, nearest_class

    dc, de = np.array([1.0, 1.1, 3.0]), np.array([3.0, 1.0, 2.0])
    assert label_distances(dc, de, 0.0) == pytest.approx(dc)  # no discriminant: eq. 2.4 itself
    assert label_distances(dc, 7.0 * dc) == pytest.approx(dc)  # the discriminant agrees at the same ratios
    for w in (0.25, 1.0, 4.0):  # its smallest is the label, its scale eq. 2.4's
        ld = label_distances(dc, de, w)
        assert int(np.argmin(ld)) == nearest_class(dc, de, w) and np.min(ld) >= np.min(dc)
    assert label_distances(2.0 * dc, 10.0 * de) == pytest.approx(2.0 * label_distances(dc, de))
    assert np.isinf(label_distances(np.array([1.0, np.inf]), np.array([1.0, np.inf]))[1])
    on = label_distances(np.array([0.0, 5.0, 9.0]), np.array([1.0, 3.0, 4.0]))  # a motion on a proto-symbol
    assert int(np.argmin(on)) == 0 and on[1] > on[0] and softmax_confidence(on, 1.0)[0] > 0.9


def test_the_discriminant_ratio_is_saved_with_the_space_and_older_files_keep_their_rule(dev_space, dev_split, tmp_path):
    one = ProtoSymbolSpace.build([c for c in dev_split[0] if c.label == "squat1Reps"][:4])
    assert one.discriminant is None and one.novelty_model is None
    assert one.info()["open_set"].startswith("none of these: the distance rule alone (one class: no other class to be "
                                             "nearer to); it never rejects:")  # four of one class
    assert "never" not in dev_space.info()["open_set"]
    m = dev_space.discriminant
    assert m is not None and m.scheme == "across performers" and m.classes == sorted(set(dev_space.labels))
    assert "the discriminant ratio" in dev_space.info()["open_set"]
    clips = dev_split[1][:6]
    before = [dev_space.recognize(c) for c in clips]
    assert all(r.decision.ratio_novelty > 0 for r in before)
    back = ProtoSymbolSpace.load(dev_space.save(tmp_path / "d.npz"))
    assert np.array_equal(back.discriminant.projection, m.projection) and back.discriminant.threshold == m.threshold
    assert back.discriminant.smallest_class == m.smallest_class >= 2  # every class has two performers' clips
    assert [back.recognize(c).novelty for c in clips] == pytest.approx([r.novelty for r in before])
    with np.load(tmp_path / "d.npz", allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    header = json.loads(str(arrays["header"]))
    # written before the label weighed the discriminant: the nearest proto-symbol alone labels
    older = {**header, "discriminant": {k: v for k, v in header["discriminant"].items() if k != "smallest_class"}}
    np.savez(tmp_path / "older.npz", **{**arrays, "header": np.array(json.dumps(older))})
    assert ProtoSymbolSpace.load(tmp_path / "older.npz").discriminant.smallest_class == 1
    # damaged: a projection that does not fit its classes, a header without its threshold, a
    # model of fewer features than the space's motions have
    fewer = {f"discriminant_{k}": getattr(m, k)[:100] for k in ("mean", "scale", "projection")}
    for _what, bad_arrays, bad_header in (
            ("projection", {**arrays, "discriminant_projection": m.projection[:, :2]}, header),
            ("header", arrays, {**header, "discriminant": {"classes": m.classes}}),
            ("features", {**arrays, **fewer}, header)):
        np.savez(tmp_path / "bad.npz", **{**bad_arrays, "header": np.array(json.dumps(bad_header))})
        with pytest.raises(BadInput, match="discriminant ratio is unreadable"):
            ProtoSymbolSpace.load(tmp_path / "bad.npz")
    # a file written before it: its ratio test stays on eq. 2.4 distances, and space info says so
    header.pop("discriminant")
    old_arrays = {k: v for k, v in arrays.items() if not k.startswith("discriminant_")}
    np.savez(tmp_path / "old.npz", **{**old_arrays, "header": np.array(json.dumps(header))})
    old = ProtoSymbolSpace.load(tmp_path / "old.npz")
    assert old.discriminant is None and "ratio on eq. 2.4 distances" in old.info()["open_set"]
    from shared.pss.recognition import hmm_features

    idx = old.features.group_indices(old.recognition_groups)
    for c in clips:
        r = old.recognize(c)
        h = r.hmm.marginal(idx)
        want = decide(r.recognition_distances, old.labels, old.calibration, old.novelty_model,
                      hmm_features(h.means, h.covars))
        assert r.decision.ratio_novelty == 0.0 and r.novelty == pytest.approx(want.novelty)


# ---------------------------------------------------------------------------- what must not change a label
def test_the_robustness_changes_are_the_motion_moved_turned_sped_and_scaled(dev_split):
    from scipy.spatial.transform import Rotation

    from shared.reports.evaluation import transformed

    clip = dev_split[1][0].resample(30)
    p = clip.positions()
    moved = transformed(clip, "pelvis moved 3 m sideways").positions()
    assert np.allclose(moved - p, [3.0, 0.0, 0.0], atol=1e-9)
    turned = transformed(clip, "turned 90 degrees").positions()
    assert np.abs(turned - p @ Rotation.from_euler("y", 90, degrees=True).as_matrix().T).max() < 1e-9
    scaled = transformed(clip, "body scaled 1.2x").positions()
    assert np.abs(scaled - 1.2 * p).max() < 1e-9
    fast = transformed(clip, "played at 1.4x speed")
    assert fast.fps == clip.fps and abs(fast.n_frames - clip.n_frames / 1.4) <= 1


def test_where_a_person_stands_and_faces_changes_no_label(dev_space, dev_split):
    from shared.reports.evaluation import robustness

    res = robustness(dev_space, dev_split[1][::6])
    assert res["pelvis moved 3 m sideways"]["changed"] == 0 and res["turned 90 degrees"]["changed"] == 0
    assert res["as is"]["as_shown"] >= 0.9


def test_travel_velocities_are_averaged_over_a_window_and_older_files_keep_them_raw(dev_space, dev_split, tmp_path):
    """The position group's forward and lateral velocity are centred means over
    TRAVEL_WINDOW seconds (scipy's uniform filter is the reference); every other channel is
    as before; the window is saved with the space, and a file written before it reads its
    velocities raw."""
    import json

    from scipy.ndimage import uniform_filter1d

    from shared.pss.features import TRAVEL_WINDOW, MotionFeatures, moving_mean

    f = dev_space.features
    assert f.travel_window == TRAVEL_WINDOW > 0
    d = json.loads(f.to_json())
    del d["travel_window"]
    raw = MotionFeatures.from_json(json.dumps(d))
    assert raw.travel_window == 0
    c = dev_split[1][0].resample(30)
    a, b = f._raw_positions(c, *f._root_terms(c)), raw._raw_positions(c, *raw._root_terms(c))
    names = f._position_names()
    cols = [names.index("pos(root).v_forward"), names.index("pos(root).v_lateral")]
    width = int(round(TRAVEL_WINDOW * 30)) | 1
    np.testing.assert_allclose(a[:, cols], uniform_filter1d(b[:, cols], width, axis=0, mode="nearest"), atol=1e-12)
    rest = [k for k in range(a.shape[1]) if k not in cols]
    np.testing.assert_array_equal(a[:, rest], b[:, rest])
    assert np.std(a[:, cols[0]]) < np.std(b[:, cols[0]])  # the sway of the steps averaged out
    rng = np.random.default_rng(2)
    for n, w in ((1, 31), (5, 31), (40, 3), (40, 1)):
        x = rng.normal(size=(n, 2))
        np.testing.assert_allclose(moving_mean(x, w), uniform_filter1d(x, w, axis=0, mode="nearest"), atol=1e-12)
    assert ProtoSymbolSpace.load(dev_space.save(tmp_path / "w.npz")).features.travel_window == TRAVEL_WINDOW


def test_recognition_caps_state_variances_and_older_files_do_not(dev_space, dev_split, tmp_path):
    import json

    from shared.pss.space import RECOGNITION_VAR_CEILING

    assert dev_space.params.recognition_var_ceiling == RECOGNITION_VAR_CEILING
    assert max(float(m.covars.max()) for m in dev_space.recognition_models()) <= RECOGNITION_VAR_CEILING
    assert max(float(m.covars.max()) for m in dev_space.models_on(("position",))) > RECOGNITION_VAR_CEILING
    path = dev_space.save(tmp_path / "c.npz")
    assert ProtoSymbolSpace.load(path).params.recognition_var_ceiling == RECOGNITION_VAR_CEILING
    with np.load(path, allow_pickle=False) as z:  # a file written before the ceiling
        arrays = {k: np.array(z[k]) for k in z.files}
    header = json.loads(str(arrays["header"]))
    del header["params"]["recognition_var_ceiling"]
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "old.npz", **arrays)
    old = ProtoSymbolSpace.load(tmp_path / "old.npz")
    assert old.params.recognition_var_ceiling is None
    assert all(np.array_equal(a.covars, b.covars) and np.array_equal(a.means, b.means)
               for a, b in zip(old.recognition_models(), old.models_on(("position",))))  # not capped
    assert max(float(m.covars.max()) for m in old.recognition_models()) > RECOGNITION_VAR_CEILING


def test_a_clip_is_added_without_rebuilding_the_rest(dev_space, dev_split):
    from shared.pss.distance import distance_matrix

    new = dev_split[1][:2]
    placed = dev_space.added(new)
    n = len(dev_space.symbols)
    assert len(placed.symbols) == n + 2 and np.array_equal(placed.points[:n], dev_space.points)
    from shared.pss.mds import raw_stress

    # the stress and stress-1 grown by the new points' pairs are those of the whole configuration
    assert placed.embedding.stress == pytest.approx(raw_stress(placed.distances, placed.points), rel=1e-9)
    iu = np.triu_indices(n + 2, 1)
    assert placed.embedding.stress1 == pytest.approx(np.sqrt(placed.embedding.stress / np.sum(placed.distances[iu] ** 2)),
                                                     rel=1e-9)
    full = dev_space.rebuilt(add=new)  # the same proto-symbols, every point embedded again
    assert np.allclose(placed.distances, full.distances)
    ref = distance_matrix(placed.recognition_models(), dev_space.recognition_weights)  # the space's weights kept
    assert np.allclose(placed.recognition_matrix, ref)
    assert placed.recognize(new[0]).nearest[0][0] == new[0].name  # its own proto-symbol is now the nearest
    with pytest.raises(BadInput):
        placed.added([new[0]])  # a name the space already has


def test_a_loaded_space_adds_a_clip_by_one_row_with_the_same_result(dev_space, dev_split, tmp_path):
    """The recognition distances are saved with the space: a space read back from its file
    extends them by the new rows (no N^2 recomputation) and gives what the space in memory gives."""
    path = dev_space.save(tmp_path / "s.npz")
    loaded = ProtoSymbolSpace.load(path)
    assert loaded._recognition_matrix is not None
    np.testing.assert_array_equal(loaded.recognition_matrix, dev_space.recognition_matrix)
    new = dev_split[1][2:3]
    a, b = dev_space.added(new), loaded.added(new)
    np.testing.assert_allclose(b.recognition_matrix, a.recognition_matrix, rtol=1e-12)
    ra, rb = a.recognize(new[0]), b.recognize(new[0])
    assert (ra.label, ra.nearest_label) == (rb.label, rb.nearest_label)
    assert rb.confidence == pytest.approx(ra.confidence, abs=1e-9)


def test_a_clip_added_to_a_stored_space_is_a_journal_entry_read_back_the_same(dev_space, dev_split, tmp_path):
    """The store keeps an added clip as a small journal entry beside the space's file (the file
    is not rewritten); a new store reads file + entries as the same space; a rewrite folds the
    journal in, and an entry of an older file generation is skipped, never applied."""
    from shared.pss import store as store_module
    from shared.pss.store import SpaceStore

    st = SpaceStore(tmp_path)
    st.commit("s", dev_space)
    base = st.path("s").read_bytes()
    new = dev_split[1][3:5]
    one = st.get("s").added(new[:1])
    st.append("s", one, len(dev_space.symbols))
    two = one.added(new[1:])
    st.append("s", two, len(one.symbols))
    assert st.path("s").read_bytes() == base and [p.name for p in st.journal("s")] == ["s.0001.add", "s.0002.add"]
    with np.load(st.journal("s")[1]) as z:  # one row of distances and the decision, not the N x N matrices
        assert z["distances"].shape == (1, len(two.symbols)) and z["recognition_matrix"].shape == (1, len(two.symbols))
    assert all(p.stat().st_size < len(base) / 5 for p in st.journal("s"))
    again = SpaceStore(tmp_path).get("s")
    assert [x.name for x in again.symbols] == [x.name for x in two.symbols]
    np.testing.assert_array_equal(again.distances, two.distances)
    np.testing.assert_array_equal(again.points, two.points)
    np.testing.assert_array_equal(again.recognition_matrix, two.recognition_matrix)
    for clip in dev_split[1][:4]:
        a, b = again.recognize(clip), two.recognize(clip)
        assert (a.label, a.nearest_label) == (b.label, b.nearest_label) and a.confidence == pytest.approx(b.confidence)
    stale = tmp_path / "stale.add"
    stale.write_bytes(st.journal("s")[0].read_bytes())
    st.commit("s", two)  # a rewrite: the file holds everything, the journal goes
    assert st.journal("s") == []
    stale.rename(tmp_path / "s.0001.add")  # as a crash between the rename and the removal would leave it
    assert len(SpaceStore(tmp_path).get("s").symbols) == len(two.symbols)
    # a long journal is folded into the file
    old_max = store_module.JOURNAL_MAX
    try:
        store_module.JOURNAL_MAX = 1
        st2 = SpaceStore(tmp_path / "b")
        st2.commit("t", dev_space)
        one = st2.get("t").added(new[:1])
        st2.append("t", one, len(dev_space.symbols))
        st2.append("t", one.added(new[1:]), len(one.symbols))
        assert st2.journal("t") == [] and len(SpaceStore(tmp_path / "b").get("t").symbols) == len(dev_space.symbols) + 2
    finally:
        store_module.JOURNAL_MAX = old_max
    st.delete("s")
    assert not list(tmp_path.glob("s.*"))


def test_the_calibration_s_vectorised_steps_equal_their_plain_loops(dev_space):
    """calibrate's class distances per proto-symbol (blocks of rows, every class at once) and its
    leave-one-out class spreads (order statistics) against the plain loops they replaced."""
    from shared.pss.recognition import (
        KNOWN_QUANTILE,
        _class_spread,
        _class_spreads_without_each,
        calibrate,
        class_distances,
        conformal_threshold,
    )

    d = dev_space.recognition_matrix
    labels, perf = np.asarray(dev_space.labels), np.asarray(dev_space.performers)
    classes = sorted(set(labels))
    near, truth, ratios = [], [], []
    for i in range(len(labels)):
        cand = (np.arange(len(labels)) != i) & (perf != perf[i])
        if (cand & (labels == labels[i])).any():
            dc = class_distances(d[i, cand], labels[cand], classes)
            truth.append(classes.index(labels[i]))
            near.append(dc[truth[-1]])
            other = np.delete(dc, truth[-1])
            if np.isfinite(other).any():
                ratios.append(near[-1] / max(float(np.min(other)), 1e-12))
    cal = calibrate(d, list(labels), list(perf))
    assert cal.n_calibration == len(near)
    assert cal.ratio_threshold == pytest.approx(conformal_threshold(ratios, KNOWN_QUANTILE), rel=1e-12)
    near, truth = np.array(near), np.array(truth)
    np.testing.assert_allclose(cal.class_scales, [_class_spread(near, truth, k) for k in range(len(classes))])
    np.testing.assert_allclose(_class_spreads_without_each(near, truth),
                               [_class_spread(near, truth, truth[j], skip=j) for j in range(len(near))])
    assert cal == dev_space.calibration  # the space's own, fitted the same way
