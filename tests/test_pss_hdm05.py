"""The Proto-symbol Space on real HDM05 motion capture (train bd + bk, test dg)."""

from __future__ import annotations

import numpy as np
import pytest

from shared.bodies.arm import arm_model, with_arm_torques
from shared.errors import BadInput
from shared.pss.space import ProtoSymbolSpace


def _angle_rmse_deg(a, b, channels):
    """Joint-rotation RMSE in degrees after time normalisation: the angle of each joint's
    rotation from one clip to the other (any Euler branch of the same rotation is 0 apart)."""
    t = np.linspace(0, 1, a.n_frames)
    y = np.column_stack([np.interp(t, np.linspace(0, 1, b.n_frames), b.column(c)) for c in channels])
    joints = sorted({c.rsplit(".", 1)[0] for c in channels})
    idx = [a.skeleton.index(j) for j in joints]
    la = a.skeleton.local_matrices(a.select(channels), channels)[:, idx]
    lb = a.skeleton.local_matrices(y, channels)[:, idx]
    cos = (np.einsum("tjab,tjab->tj", la, lb) - 1.0) / 2.0
    d = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return float(np.sqrt(np.mean(d * d)))


def _own_point_errors(space, train, names):
    angles = space.features.angle_channels
    errs, others = [], []
    for name in names:
        i = space.symbol(name)
        clip = next(c for c in train if c.name == name).resample(space.params.fps)
        errs.append(_angle_rmse_deg(clip, space.generate(space.points[i]), angles))
        other = next(c for c in train if c.label != clip.label).resample(space.params.fps)
        others.append(_angle_rmse_deg(clip, other, angles))
        mc = space.generate(space.points[i], method="monte_carlo", seed=2)
        assert _angle_rmse_deg(clip, mc, angles) < others[-1]
    return np.array(errs), np.array(others)


def test_generation_from_a_clips_own_point_reproduces_it(dev_space, dev_split, capsys):
    train = dev_split[0]
    names = ["HDM_bd_squat1Reps_001_120", "HDM_bk_kickLFront1Reps_007_120", "HDM_bd_throwBasketball_001_120"]
    e7, others = _own_point_errors(dev_space, train, names)
    assert np.all(e7 < others)  # closer to itself than to another motion
    # the dev space has 12-13 states because its shortest clip (a hop) has 14-15 frames at 30 fps;
    # a space of longer motions can afford 15 states and reproduces its clips at least as closely
    longer = [c for c in train if c.label in ("squat1Reps", "kickLFront1Reps", "throwBasketball")]
    space15 = ProtoSymbolSpace.build(longer, n_states=15, dim=3)
    e15, _ = _own_point_errors(space15, longer, names)
    with capsys.disabled():
        print(f"\njoint-angle RMSE of F_gen(own point) vs clip (deg): {dev_space.params.n_states} states {np.round(e7, 1)}, "
              f"15 states {np.round(e15, 1)}")
    assert e15.mean() <= e7.mean() + 0.2 and e15.max() < 12.0 and np.all(e15 < others / 2)


def test_midpoint_recognises_between_and_emphasis_moves_away(dev_space):
    a, b = dev_space.symbol("HDM_bd_squat1Reps_001_120"), dev_space.symbol("HDM_bd_kickLFront1Reps_001_120")
    mid = dev_space.generate(weights=dev_space.mix_weights({dev_space.names[a]: 0.5, dev_space.names[b]: 0.5}))
    r = dev_space.recognize(mid)
    d_ab = dev_space.distances[a, b]
    assert r.distances[a] < d_ab and r.distances[b] < d_ab
    pa, pb = dev_space.points[a], dev_space.points[b]
    s = float((r.point - pa) @ (pb - pa) / ((pb - pa) @ (pb - pa)))
    assert 0.15 < s < 0.85  # the midpoint lies between its two motions
    # extrapolation with alpha = 2 (eq. 4.3): target t, learner p
    t, p = dev_space.symbol("HDM_bd_squat1Reps_001_120"), dev_space.symbol("HDM_bk_squat1Reps_013_120")
    emph = dev_space.generate(weights=dev_space.emphatic_weights(dev_space.names[t], dev_space.names[p], 2.0))
    re = dev_space.recognize(emph)
    assert re.distances[p] > dev_space.distances[t, p]  # further from the learner than the target is
    assert re.nearest_label == "squat1Reps"  # still nearest the same kind of motion (an exaggeration no
    # performer showed may be "none of these": the open set's novelty model sees it beyond them)


@pytest.fixture(scope="module")
def torque_space(dev_split):
    model = arm_model(body_mass=2.4)
    train = [with_arm_torques(c, model) for c in dev_split[0]]
    test = [with_arm_torques(c, model) for c in dev_split[1]]
    return ProtoSymbolSpace.build(train, dim=3), train, test


def test_association_estimates_torques_from_motion_alone(torque_space, capsys):
    space, train, test = torque_space
    s = space.features.sensor_channels
    assert s == ["tau.shoulder_pitch", "tau.shoulder_roll", "tau.elbow"]
    g_train = np.mean([np.abs(c.resample(30).select(s)).sum(axis=1).mean() for c in train])
    err, base, ok = [], [], 0
    for c in test:
        motion = c.with_data(c.select(c.group("motion")), channels=c.group("motion"), groups={"motion": c.group("motion")})
        a = space.associate(motion, "sensor")
        assert a.whole.group("sensor") == s and a.aligned.n_frames == c.resample(30).n_frames
        true = c.resample(30).select(s)
        g = np.abs(true).sum(axis=1).mean()  # eq. 3.8 without tau_MAX
        g_hat = np.abs(a.aligned.select(s)).sum(axis=1).mean()
        err.append(abs(g - g_hat) / g)  # eq. 3.9
        base.append(abs(g - g_train) / g)
        ok += a.recognition.label == c.label
    with capsys.disabled():
        print(f"\nassociation motion -> torque on dg: |g - g_hat| / g = {np.mean(err):.3f} "
              f"(training mean torque: {np.mean(base):.3f}); recognised from motion alone {ok}/{len(test)}")
    assert np.mean(err) < np.mean(base)
    assert ok / len(test) >= 0.7


def test_association_says_when_it_extrapolates(torque_space):
    """A motion like the space's own lies within its proto-symbols' spacing; the same motion
    played three times faster with its arms swung twice as far does not, and says so."""
    from shared.reports.evaluation import transformed

    space, _, test = torque_space
    near = [space.associate(c.with_data(c.select(c.group("motion")), channels=c.group("motion"),
                                        groups={"motion": c.group("motion")}), "sensor") for c in test[::10]]
    assert np.isfinite([a.reach for a in near]).all()
    assert np.median([a.reach for a in near]) <= 1.0
    c = test[0]
    motion = c.with_data(c.select(c.group("motion")), channels=c.group("motion"), groups={"motion": c.group("motion")})
    arms = [i for i, ch in enumerate(motion.channels) if ch.split(".")[0] in ("lhumerus", "rhumerus", "lradius", "rradius")]
    wild = motion.data.copy()
    wild[:, arms] *= 2.0
    far = space.associate(transformed(motion.with_data(wild), "played at 1.4x speed"), "sensor")
    assert far.reach > max(a.reach for a in near) and far.extrapolating


def test_association_from_the_first_part_of_a_motion(dev_space, dev_split):
    test = dev_split[1]
    ok, later = 0, 0
    for c in test:
        part = c.frames(0, int(0.8 * c.n_frames))
        a = dev_space.associate(part, "frames")
        ok += a.recognition.label == c.label
        # the whole is generated from bd/bk proto-symbols, with their timing, on every channel
        assert a.whole.channels == dev_space.features.motion_channels and a.whole.n_frames >= dev_space.params.n_states
        early = dev_space.associate(c.frames(0, int(0.5 * c.n_frames)), "frames")
        later += a.progress >= early.progress
    assert ok / len(test) > 0.35  # chance is 1/11
    assert later / len(test) > 0.8  # a longer start is read as further through the motion


def test_space_saves_and_loads_identically(dev_space, dev_split, tmp_path):
    path = dev_space.save(tmp_path / "dev.npz")
    back = ProtoSymbolSpace.load(path)
    assert np.array_equal(back.points, dev_space.points) and np.array_equal(back.distances, dev_space.distances)
    assert back.names == dev_space.names and back.labels == dev_space.labels
    x = dev_space.points[:3].mean(axis=0)
    for method in ("expected", "monte_carlo"):
        assert np.array_equal(back.generate(x, method=method, seed=5).data, dev_space.generate(x, method=method, seed=5).data)
    c = dev_split[1][0]
    assert np.array_equal(back.recognize(c).point, dev_space.recognize(c).point)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_a_space_built_from_files_read_when_taken_is_the_same_space(hdm05, torque_space):
    """A lazy sequence of files (each read when taken, none kept) builds the space a list of the
    same clips builds: each file read twice, in order; the features' statistics clip by clip are
    the statistics of all the frames stacked (sensor channels too)."""
    from shared.io import LazyClips, load_clip
    from shared.pss.features import MotionFeatures

    files = sorted((hdm05 / "amc").rglob("*.amc"))[::12]
    held = [load_clip(f) for f in files]
    reads = []
    a = ProtoSymbolSpace.build(held, dim=2)
    b = ProtoSymbolSpace.build(LazyClips(files, on_read=reads.append), dim=2)
    assert reads == list(range(len(files))) * 2
    assert b.names == a.names and b.labels == a.labels and [s.performers for s in b.symbols] == [s.performers for s in a.symbols]
    assert np.allclose(b.distances, a.distances, rtol=1e-10, atol=0)
    assert np.allclose(b.points, a.points, rtol=1e-8, atol=1e-10)
    train = torque_space[1][:15]
    f = MotionFeatures.for_clips(train)
    sensors = np.vstack([c.select(f.sensor_channels) for c in train])
    assert f.sensor_channels and np.allclose(f.sensor_mean, sensors.mean(axis=0), rtol=1e-10, atol=1e-12)
    assert np.allclose(f.sensor_scale, np.maximum(sensors.std(axis=0), 1e-6 * max(1.0, np.abs(sensors).max())), rtol=1e-9)
    positions = np.vstack([f._raw_positions(c, *f._root_terms(c)) for c in train])
    assert np.allclose(f.position_mean, positions.mean(axis=0), atol=1e-10)
    assert np.allclose(f.position_scale, np.maximum(positions.std(axis=0), 1e-3), rtol=1e-8)


def test_a_space_of_full_covariances_builds_recognises_and_adds(dev_split):
    """Full covariances take the plain banks (no stacked diagonal arrays): the decision's HMM
    features, a recognition and an add still work."""
    train = [c for c in dev_split[0] if "squat" in c.name][:3] + [c for c in dev_split[0] if "kick" in c.name][:3]
    space = ProtoSymbolSpace.build(train, covariance_type="full", n_states=3)
    assert space.recognition_weights is None and space._symbol_features().shape[0] == len(train)
    probe = next(c for c in dev_split[1] if "squat" in c.name)
    assert space.recognize(probe).nearest_label == probe.label
    grown = space.added([probe])
    assert len(grown.symbols) == len(train) + 1 and grown._symbol_features().shape[0] == len(train) + 1


def test_rebuild_from_a_modified_database(dev_space, dev_split):
    small = ProtoSymbolSpace.build(dev_split[0][:6], dim=2, n_states=dev_space.params.n_states)
    grown = small.rebuilt(add=[dev_split[1][0]], remove=[small.names[0]])
    assert len(grown.symbols) == 6 and dev_split[1][0].name in grown.names and small.names[0] not in grown.names
    with pytest.raises(BadInput):
        small.rebuilt(add=[dev_split[0][1]])  # already there


def test_space_refuses_bad_clips(dev_space, dev_split):
    c = dev_split[1][0]
    with pytest.raises(BadInput, match=r"lasts 0\.06 s .* at least 0\.2\d s"):  # 8 frames at 120 fps
        dev_space.recognize(c.frames(0, 8))
    bad = c.with_data(c.data.copy())
    bad.data[5, 10] = np.nan
    with pytest.raises(BadInput, match="NaN"):
        dev_space.recognize(bad)
    wrong = c.with_data(c.data[:, :10], channels=c.channels[:10], groups={"motion": c.channels[:10]})
    with pytest.raises(BadInput, match="lacks"):
        dev_space.recognize(wrong)
    with pytest.raises(BadInput):
        ProtoSymbolSpace.build([])


def test_a_short_motion_played_faster_keeps_its_label(dev_space, dev_split):
    """The states are 85 % of the shortest training clip's frames, so a hop as short played 1.2x as
    fast had fewer frames at the space's rate than states and was refused: it is read at a higher
    rate (a frame per state) and keeps its nearest label (here hops played 1.8x as fast); a motion
    under half the states' time is refused, saying how long it must last."""
    from shared.pss.symbol import shortest_seconds

    fps, states = dev_space.params.fps, dev_space.params.n_states
    hops = [c for c in dev_split[1] if c.label == "hopBothLegs1hops"]
    fast = [c.with_data(c.data, fps=c.fps * 1.8).resample(c.fps) for c in hops]
    short = [f for f in fast if f.resample(fps).n_frames < states]
    assert short  # (the case: before, each of these was refused as having fewer frames than states)
    assert [dev_space.recognize(f).nearest_label for f in short] == ["hopBothLegs1hops"] * len(short)
    assert all(f.duration >= shortest_seconds(states, fps) for f in short)
    tiny = hops[0].frames(0, int(shortest_seconds(states, fps) * hops[0].fps) - 1)
    with pytest.raises(BadInput, match="at least"):
        dev_space.recognize(tiny)


@pytest.mark.slow
def test_the_scale_benchmark_runs_and_reports_every_column(hdm05, tmp_path):
    """``python -m bench.scale`` at two small sizes (a fresh process each, the game studio's
    clips): every row has its build, decision, add and peak, and the report is written."""
    import json
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "bench.scale", "--hdm05", str(hdm05), "--sizes", "10,14",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    rows = json.loads((tmp_path / "scale.json").read_text())["rows"]
    assert [row["clips"] for row in rows] == [10, 14]
    for row in rows:
        assert row["frames"] > 0 and row["build_s"] > 0 and row["total_s"] >= row["build_s"] and row["peak_mb"] > 0
        assert row["add_one_s"] > 0 and row["add_next_s"] > 0
    md = (tmp_path / "scale.md").read_text()
    assert "| 10 |" in md and "| 14 |" in md



def test_a_space_built_with_a_pose_floor_recognises_with_it_and_keeps_its_proto_symbols(dev_space, dev_split, tmp_path):
    """``pose_floor`` (a space for other styles): recognition compares proto-symbols with the
    position group's pose outputs (joints, root height and up vector) floored at it and every
    output capped at the ceiling; the travel velocities are not floored, and the proto-symbols
    keep the variances they were trained with (the same as a space without the floor: generation,
    association and coaching read those). A clip to recognise is seen the same way. The floor is
    saved with the space; the default space has none; a bad floor is refused."""
    from shared.errors import BadInput
    from shared.pss.space import RECOGNITION_VAR_CEILING, STYLE_POSE_FLOOR
    from shared.pss.symbol import pose_indices

    assert dev_space.params.recognition_pose_floor is None
    space = ProtoSymbolSpace.build(dev_split[0], dim=3, pose_floor=STYLE_POSE_FLOOR)
    f = space.features
    assert space.params.recognition_pose_floor == STYLE_POSE_FLOOR
    rg = f.group_indices(space.recognition_groups)
    pose = np.flatnonzero(np.isin(rg, pose_indices(f)))
    travel = np.setdiff1d(np.arange(len(rg)), pose)
    assert len(travel) == 3 and len(pose) == len(rg) - 3
    seen = np.stack([m.covars for m in space.recognition_models()])
    assert seen[:, :, pose].min() >= STYLE_POSE_FLOOR and seen.max() <= RECOGNITION_VAR_CEILING
    assert seen[:, :, travel].min() < STYLE_POSE_FLOOR  # not floored
    trained = np.stack([s.hmm.covars for s in space.symbols])
    assert np.array_equal(trained, np.stack([s.hmm.covars for s in dev_space.symbols]))  # trained as without it
    assert trained[:, :, rg[pose]].min() < STYLE_POSE_FLOOR
    unfloored = np.stack([m.covars for m in dev_space.recognition_models()])
    assert unfloored[:, :, pose].min() < STYLE_POSE_FLOOR
    clip_hmm = space.abstract(dev_split[1][0]).marginal(rg)
    assert clip_hmm.covars[:, pose].min() < STYLE_POSE_FLOOR <= space.as_recognised(clip_hmm).covars[:, pose].min()
    back = ProtoSymbolSpace.load(space.save(tmp_path / "styles.npz"))
    assert back.params.recognition_pose_floor == STYLE_POSE_FLOOR
    assert np.array_equal(np.stack([m.covars for m in back.recognition_models()]), seen)
    derived = dev_space.with_pose_floor(STYLE_POSE_FLOOR)  # the same space without training it again
    a, b = derived.recognize(dev_split[1][0]), space.recognize(dev_split[1][0])
    assert a.nearest == b.nearest and a.label == b.label and np.array_equal(derived.points, space.points)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(BadInput, match="pose floor"):
            ProtoSymbolSpace.build(dev_split[0][:3], pose_floor=bad)


def test_a_space_built_without_the_open_set_associates_alike_and_says_none_of_these_by_distance(torque_space, tmp_path):
    """``open_set=False`` (the estimator's spaces, used for association only): the novelty model
    and the discriminant ratio are not fitted nor saved; recognition still answers, its "none of
    these" the distance rule's alone, and says so; association is the default space's."""
    _, train, test = torque_space
    some = [c for k, c in enumerate(train) if [x.label for x in train[:k]].count(c.label) < 2]  # two of each class
    full = ProtoSymbolSpace.build(some, dim=3)
    plain = ProtoSymbolSpace.build(some, dim=3, open_set=False)
    assert plain.novelty_model is None and plain.discriminant is None and full.novelty_model is not None
    back = ProtoSymbolSpace.load(plain.save(tmp_path / "plain.npz"))
    assert back.novelty_model is None and back.discriminant is None
    assert "without the novelty model" in back.info()["open_set"]
    assert "without" not in full.info()["open_set"] and "novelty model" in full.info()["open_set"]
    c = test[0]
    probe = c.with_data(c.select(c.group("motion")), channels=c.group("motion"), groups={"motion": c.group("motion")})
    r = back.recognize(c)
    assert r.decision.model_novelty == 0.0 and r.decision.ratio_novelty == 0.0
    assert r.nearest == full.recognize(c).nearest
    a, b = back.associate(probe, "sensor"), full.associate(probe, "sensor")
    assert np.array_equal(a.weights, b.weights) and np.array_equal(a.aligned.data, b.aligned.data)
